"""Benchmarks use pytest-benchmark's own timing (warm-up, rounds, median/IQR); run them with
``nox -s bench``. Thread counts and library versions go into the saved JSON's machine_info."""

from __future__ import annotations

import platform

import numpy as np
import pytest


def pytest_benchmark_update_machine_info(config, machine_info):
    from evsmap.open3d_loader import load_open3d

    open3d = load_open3d()
    import torch

    machine_info["evsmap"] = {
        "numpy": np.__version__, "open3d": open3d.__version__, "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(), "python": platform.python_version(),
    }


@pytest.fixture(scope="session")
def tum_frames():
    """All 37 real TUM fr1_xyz frames (0.021 s association tolerance keeps the 37th)."""
    from evsmap.registry import READERS
    from evsmap.testing import require_sample

    path = require_sample("tum-fr1-xyz")
    seq = READERS.create("tum", path=str(path), max_time_difference=0.021)
    return [seq[i] for i in range(len(seq))]


@pytest.fixture(scope="session")
def paper_network():
    """``paper_network(name, **options)``: the registered segmenter with its random initial
    weights drawn from seed 0, built once per name and options. The weights are the same in
    every run, so the ONNX exports (keyed by a digest of the weights) are cached across runs."""
    import torch

    from evsmap.registry import SEGMENTERS

    cache: dict[tuple, object] = {}

    def get(name: str, **options):
        key = (name, tuple(sorted(options.items())))
        if key not in cache:
            torch.manual_seed(0)
            cache[key] = SEGMENTERS.create(name, **options)
        return cache[key]

    return get


def pytest_configure(config):
    config.addinivalue_line(
        "markers", "gate: a pass/fail performance goal (a ratio of speeds measured in one run); "
                   "runs only with --benchmark-only, as in `nox -s bench`")


def pytest_collection_modifyitems(config, items):
    """Skip the gates unless benchmarks run on their own (--benchmark-only): a gate times
    several networks for tens of seconds and only means something on an otherwise idle run."""
    if config.getoption("benchmark_only", default=False):
        return
    skip = pytest.mark.skip(reason="performance gate: runs only with --benchmark-only "
                                   "(nox -s bench)")
    for item in items:
        if item.get_closest_marker("gate") is not None:
            item.add_marker(skip)
