from __future__ import annotations

from pathlib import Path

import pytest

from evsmap.paths import default_data_root


@pytest.fixture(scope="session")
def data_root() -> Path:
    root = default_data_root()
    if root is None:
        pytest.skip("real sample data not found (set EVSMAP_DATA_ROOT or check out ../shared)")
    return root


@pytest.fixture(scope="session")
def tum_dir(data_root: Path) -> Path:
    path = data_root / "tum_fr1_xyz"
    if not path.is_dir():
        pytest.skip(f"{path} not present")
    return path
