"""The compiled multiclass-bayes frame update stores exactly what the numpy reference stores."""

from __future__ import annotations

import numpy as np
import pytest

import evsmap.mapping.occupancy as occupancy
import evsmap.updaters.multiclass_bayes as mb
from evsmap.registry import READERS, SEGMENTERS
from evsmap.testing import missing


@pytest.fixture(autouse=True)
def _compiled_kernel():
    if mb.frame_update is None:
        missing("numba cannot be imported: the compiled multiclass-bayes update is untested")


def _maps(frames, observations, resolution, **options):
    out = []
    for kernels in ("compiled", "reference"):
        # what UPDATERS.create("multiclass-bayes", front_end="direct", ...) builds
        m = mb.MultiClassBayesMap(resolution=resolution, max_range=4.0, kernels=kernels,
                                  **options)
        for frame, obs in zip(frames, observations, strict=True):
            m.integrate(frame, obs)
        out.append(m)
    return out


def _assert_same(a, b):
    assert np.array_equal(a.map.codes, b.map.codes)
    assert np.array_equal(a.map.logodds, b.map.logodds)
    for name in ("classes", "class_logodds", "others"):
        assert np.array_equal(a.map.payload(name), b.map.payload(name)), name


@pytest.fixture(scope="module")
def tum_observed(tum_dir):
    import torch

    seq = READERS.create("tum", path=str(tum_dir))
    frames = [seq.frame(i) for i in range(0, len(seq), 4)]
    torch.manual_seed(0)
    net = SEGMENTERS.create("feagnet-v1")  # untrained: many classes, ties and near-ties
    return frames, [net.predict(f) for f in frames]


@pytest.mark.parametrize("resolution", [0.05, 0.02])
def test_kernel_equals_numpy_on_real_frames(tum_observed, resolution):
    frames, observations = tum_observed
    kernel, reference = _maps(frames, observations, resolution)
    _assert_same(kernel, reference)
    known = kernel.map.payload("classes")[:, 0] >= 0
    assert known.sum() > 1000  # observed many times: the hit rule ran on most of them


VARIANTS = [
    {},
    {"leaf_update": "average"},
    {"leaf_update": "average", "pairing": "ssmi"},
    {"leaf_update": "average", "occupancy": "octomap"},
    {"occupancy": "octomap"},
]


@pytest.mark.parametrize("variant", VARIANTS, ids=lambda v: ",".join(
    f"{k}={x}" for k, x in v.items()) or "paper")
def test_kernel_equals_numpy_with_other_parameters(variant):
    seq = READERS.create("synthetic", frames=5, width=160, height=120)
    oracle = SEGMENTERS.create("oracle", seed=4, accuracy=0.6)
    frames = [seq.frame(i) for i in range(len(seq))]
    observations = [oracle.predict(f) for f in frames]
    kernel, reference = _maps(frames, observations, 0.1, theta=0.3, psi=0.8,
                              phi=-0.2, **variant)
    _assert_same(kernel, reference)
    assert (kernel.map.payload("classes")[:, 0] >= 0).sum() > 100


def test_growing_the_leaf_arrays_with_and_without_the_kernel(monkeypatch, tum_observed):
    frames, observations = tum_observed
    grown = []
    for kernel in (occupancy.grow_rows, None):
        monkeypatch.setattr(occupancy, "grow_rows", kernel)
        m = mb.MultiClassBayesMap(resolution=0.05, max_range=4.0, kernels="reference")
        for frame, obs in zip(frames[:3], observations[:3], strict=True):
            m.integrate(frame, obs)
        grown.append(m)
    _assert_same(*grown)
