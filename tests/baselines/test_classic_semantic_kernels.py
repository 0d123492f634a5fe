"""The compiled classwise frame update of ``classic-semantic``
(:mod:`baselines.classic_semantic_kernels`) stores exactly what its numpy reference
(:func:`baselines.classic_semantic.fuse_frame`) stores: on random frames full of ties and empty
slots, and on real TUM frames down to the written map files."""

from __future__ import annotations

import numpy as np
import pytest

import baselines.classic_semantic as cs
from baselines.classic_semantic_kernels import frame_update
from evsmap.mapping import fusion
from evsmap.registry import READERS, SEGMENTERS

RULES = {"classic-semantic": "bayes", "classic-semantic-max": "max"}
CLASSES = 8  # few classes: many shared classes between map and frame, many equal means


def _random_map(rng, n_leaves, slots):
    """Leaf payloads as fusion leaves them: valid slots first, distinct classes, confidences
    on a coarse grid (ties), empty slots (-1, 0), some leaves without semantics or colour."""
    classes = np.full((n_leaves, slots), -1, np.int16)
    conf = np.zeros((n_leaves, slots), np.float32)
    filled = rng.integers(0, slots + 1, n_leaves)
    for i in np.flatnonzero(filled):
        classes[i, :filled[i]] = rng.choice(CLASSES, filled[i], replace=False)
        conf[i, :filled[i]] = np.sort(rng.choice([0.1, 0.2, 0.25, 0.3, 0.4], filled[i]))[::-1]
    rgb = rng.integers(0, 256, (n_leaves, 3)).astype(np.uint8)
    rgb[rng.random(n_leaves) < 0.3] = 255
    return classes, conf, rgb


def _random_frame(rng, n_leaves, n_pixels=6000, n_points=4000, n_voxels=1200, k=3):
    """A frame's top-k (distinct classes, -1 entries, probabilities on a 0.05 grid with zeros)
    and its points grouped into distinct hit voxels (1 to many points each)."""
    obs_cls = np.stack([rng.permutation(CLASSES)[:k] for _ in range(n_pixels)]).astype(np.int16)
    obs_cls[rng.random((n_pixels, k)) < 0.1] = -1
    probs = rng.integers(0, 7, (n_pixels, k)) * 0.05
    obs_p = np.sort(probs, axis=1)[:, ::-1].astype(np.float32)
    colours = rng.integers(0, 256, (n_pixels, 3)).astype(np.uint8)
    pixels = rng.choice(n_pixels, n_points, replace=False)
    local = np.concatenate([np.arange(n_voxels), rng.integers(0, n_voxels, n_points - n_voxels)])
    local = rng.permutation(local)
    voxels = rng.choice(n_leaves, n_voxels, replace=False)
    return voxels, local, pixels, obs_cls, obs_p, colours


def _both(state, frame, with_colours, bayes):
    kernel = [a.copy() for a in state]
    reference = [a.copy() for a in state]
    colours = frame[-1]
    assert frame_update(*kernel, *frame[:-1], colours if with_colours else colours[:0],
                        with_colours, bayes, fusion.PROB_MIN, fusion.DENSE_LIMIT)
    cs.fuse_frame(*reference, *frame[:-1], colours if with_colours else None)
    return kernel, reference


@pytest.mark.parametrize("rule", ["bayes", "max"])
@pytest.mark.parametrize("with_colours", [True, False], ids=["rgb", "no-rgb"])
def test_kernel_equals_numpy_on_random_frames(rule, with_colours):
    rng = np.random.default_rng(20)
    slots = 3 if rule == "bayes" else 1
    state = _random_map(rng, 5000, slots)
    original_rgb = state[2].copy()
    for _ in range(6):  # frames in sequence: later frames fuse into fused states
        kernel, reference = _both(state, _random_frame(rng, 5000), with_colours, rule == "bayes")
        for got, want in zip(kernel, reference, strict=True):
            assert np.array_equal(got, want)
        state = kernel
    classes, conf, rgb = state
    assert (classes == -1).any() and (classes[:, 0] >= 0).sum() > 2000
    if slots == 3:  # equal confidences met the tie rules
        both = (classes[:, 0] >= 0) & (classes[:, 1] >= 0)
        assert (conf[both, 0] == conf[both, 1]).any()
    assert np.array_equal(rgb, original_rgb) != with_colours


@pytest.mark.parametrize("shape", [(4000, 3), (4000, 6), (4000, 3, 3)])
def test_numpy_sums_a_row_left_to_right(shape):
    # the kernel adds the reference's row sums (residuals, posteriors' total, matched
    # confidences) left to right; float32 results rarely show the order, so it is pinned here
    rng = np.random.default_rng(7)
    x = rng.random(shape) * rng.choice([1e-3, 1.0, 1e3], shape)
    x = np.where(rng.random(shape) < 0.3, 0.0, x)
    left_to_right = x[..., 0]
    for j in range(1, shape[-1]):
        left_to_right = left_to_right + x[..., j]
    assert np.array_equal(x.sum(axis=-1), left_to_right)


def test_beyond_the_dense_limit_the_kernel_changes_nothing():
    rng = np.random.default_rng(3)
    state = _random_map(rng, 2000, 3)
    frame = _random_frame(rng, 2000, n_voxels=500)
    before = [a.copy() for a in state]
    assert not frame_update(*state, *frame, True, True, fusion.PROB_MIN, 500 * CLASSES - 1)
    for got, want in zip(state, before, strict=True):
        assert np.array_equal(got, want)


@pytest.fixture(scope="module")
def tum_observed(tum_dir):
    import torch

    seq = READERS.create("tum", path=str(tum_dir))
    frames = [seq.frame(i) for i in range(0, len(seq), 4)]
    torch.manual_seed(0)
    net = SEGMENTERS.create("feagnet-v1")  # untrained: many classes, ties and near-ties
    return frames, [net.predict(f) for f in frames]


@pytest.mark.parametrize("name", ["classic-semantic", "classic-semantic-max"])
@pytest.mark.parametrize("resolution", [0.05, 0.02])
def test_kernel_equals_numpy_on_real_frames(tmp_path, tum_observed, name, resolution):
    frames, observations = tum_observed
    maps, files = [], []
    for kernels in ("compiled", "reference"):
        # what UPDATERS.create(name, front_end="direct", ...) builds
        m = cs.ClassicSemanticMap(fusion_rule=RULES[name], resolution=resolution,
                                  max_range=4.0, kernels=kernels)
        for frame, obs in zip(frames, observations, strict=True):
            m.integrate(frame, obs)
        maps.append(m)
        written = []
        for file_format in ("full", "published"):
            path = tmp_path / f"{kernels}-{file_format}.ot"
            m.write(path, file_format)
            written.append(path.read_bytes())
        files.append(written)
    kernel, reference = (m.map for m in maps)
    assert np.array_equal(kernel.codes, reference.codes)
    for column in ("rgb", "sem_classes", "sem_conf"):
        assert np.array_equal(kernel.payload(column), reference.payload(column)), column
    assert files[0] == files[1]
    assert (kernel.payload("sem_classes")[:, 0] >= 0).sum() > 1000
