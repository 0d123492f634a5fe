"""Benchmarks use pytest-benchmark's own timing (warm-up, rounds, median/IQR); run them with
``nox -s bench``. Thread counts and library versions go into the saved JSON's machine_info."""

from __future__ import annotations

import platform

import numpy as np
import pytest


def pytest_benchmark_update_machine_info(config, machine_info):
    import open3d
    import torch

    machine_info["evsmap"] = {
        "numpy": np.__version__, "open3d": open3d.__version__, "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(), "python": platform.python_version(),
    }


@pytest.fixture(scope="session")
def shared_data():
    from evsmap.paths import default_data_root

    root = default_data_root()
    if root is None:
        pytest.skip("real sample data not found (set EVSMAP_DATA_ROOT)")
    return root
