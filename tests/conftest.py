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


@pytest.fixture(scope="session", autouse=True)
def _session_cache(tmp_path_factory):
    """One evsmap cache (ONNX exports, segmentations, rendered sequences, calibrations) for the
    whole test session, never the user's ``~/.cache/evsmap``: tests start from nothing and leave
    nothing behind. A cache set from outside (``EVSMAP_CACHE_DIR``) is kept."""
    import os

    if os.environ.get("EVSMAP_CACHE_DIR"):
        yield
        return
    os.environ["EVSMAP_CACHE_DIR"] = str(tmp_path_factory.mktemp("evsmap-cache"))
    try:
        yield
    finally:
        os.environ.pop("EVSMAP_CACHE_DIR", None)
