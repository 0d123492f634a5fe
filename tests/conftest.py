from __future__ import annotations

from pathlib import Path

import pytest

from evsmap.paths import default_data_root
from evsmap.testing import require_sample


@pytest.fixture(scope="session")
def data_root() -> Path:
    """The data root; tests that need one sample ask for it by fixture (below)."""
    return default_data_root()


@pytest.fixture(scope="session")
def tum_dir() -> Path:
    return require_sample("tum-fr1-xyz")


@pytest.fixture(scope="session")
def sevenscenes_dir() -> Path:
    return require_sample("sevenscenes-100")


@pytest.fixture(scope="session")
def nyuv2_samples_dir() -> Path:
    return require_sample("nyuv2-samples")


@pytest.fixture(scope="session")
def lidar_bag() -> Path:
    return require_sample("lidar-odometry-bag")
