"""Fixtures: tiny official-layout copies of NYUv2, SUN RGB-D and Cityscapes (built by
``datasets_fixtures``)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from datasets_fixtures import write_city_tree, write_nyu_source, write_sun_source

from evsmap.datasets import cityscapes as cs
from evsmap.datasets import nyuv2


@pytest.fixture(scope="session")
def nyu_source(tmp_path_factory) -> tuple[Path, dict[str, np.ndarray]]:
    root = tmp_path_factory.mktemp("nyu_source")
    return root, write_nyu_source(root)


@pytest.fixture(scope="session")
def nyu_prepared_session(nyu_source, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("nyu_prep") / "nyuv2"
    nyuv2.prepare_nyuv2(nyu_source[0], out)
    return out


@pytest.fixture
def nyu_prepared(nyu_prepared_session, tmp_path) -> Path:
    """A private copy (tests may break it)."""
    out = tmp_path / "nyuv2"
    shutil.copytree(nyu_prepared_session, out)
    return out


@pytest.fixture
def sun_source(tmp_path) -> tuple[Path, dict]:
    root = tmp_path / "sun_source"
    return root, write_sun_source(root)


@pytest.fixture(scope="session")
def city_tree(tmp_path_factory) -> tuple[Path, dict]:
    root = tmp_path_factory.mktemp("cityscapes")
    return root, write_city_tree(root)


@pytest.fixture(scope="session")
def city_prepared(city_tree, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("city_prep") / "cityscapes"
    cs.prepare_cityscapes(city_tree[0], out)
    return out


@pytest.fixture
def small_city(tmp_path) -> tuple[Path, dict]:
    """One val frame in a private tree (tests may break it)."""
    root = tmp_path / "city"
    truth = write_city_tree(root, {"val": [("lindau", "lindau_000000_000019")]})
    return root, truth
