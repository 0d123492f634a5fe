"""Shared helpers for the segmenter tests: one intra-op thread, small frames, seeded networks."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
import torch

from evsmap.data import Frame, Intrinsics
from evsmap.registry import SEGMENTERS

SIZE = (64, 96)
"""Network input size of the tests: the smallest every registered network accepts (its 1/32
feature map is 2x3; FEAGNet-S/V1 and FC-HarDNet reject 32x64)."""


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    """One intra-op thread: on a busy 2-core runner, OpenMP threads spin-waiting for each other
    at every small op make tiny forward passes many times slower."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def _make_frame(height: int = 60, width: int = 80, *, seed: int = 0,
                depth: np.ndarray | None = None) -> Frame:
    """Random uint8 RGB, depth in metres (0.5-6 m) with about 10 % invalid (0) pixels."""
    rng = np.random.default_rng(seed)
    rgb = rng.integers(0, 256, size=(height, width, 3), dtype=np.uint8)
    if depth is None:
        depth = rng.uniform(0.5, 6.0, size=(height, width)).astype(np.float32)
        depth[rng.random((height, width)) < 0.1] = 0.0
    intrinsics = Intrinsics(fx=0.8 * width, fy=0.8 * width, cx=width / 2 - 0.5,
                            cy=height / 2 - 0.5, width=width, height=height)
    return Frame(rgb=rgb, depth=depth, intrinsics=intrinsics, pose=np.eye(4), timestamp=0.0)


def _create(name: str, *, seed: int = 0, **options):
    """``SEGMENTERS.create(name, input_size=SIZE, **options)`` with seeded initial weights."""
    torch.manual_seed(seed)
    options.setdefault("input_size", SIZE)
    return SEGMENTERS.create(name, **options)


@pytest.fixture(scope="module")
def segmenter() -> Callable[[str], object]:
    """``segmenter(name)``: one seeded torch-backend instance per name, shared in the module
    (tests must not change its weights)."""
    cache: dict[str, object] = {}

    def get(name: str):
        if name not in cache:
            cache[name] = _create(name)
        return cache[name]

    return get


@pytest.fixture(scope="session")
def make_frame() -> Callable[..., Frame]:
    """``make_frame(height=60, width=80, *, seed=0, depth=None)``: a random valid frame."""
    return _make_frame


@pytest.fixture(scope="session")
def create() -> Callable[..., object]:
    """``create(name, *, seed=0, **options)``: a seeded segmenter at input size SIZE."""
    return _create
