"""libstdc++'s std::sort order (PCL's VoxelGrid sums a leaf's points in it)."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from evsmap.mapping.stdsort import std_sort_order

DATA = Path(__file__).parent / "data" / "std_sort_orders.npz"
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))


def _fixture_cases():
    data = np.load(DATA)
    starts = np.r_[0, np.cumsum(data["lengths"])]
    for i, depth in enumerate(data["depths"]):
        a, b = starts[i], starts[i + 1]
        yield data["keys"][a:b], int(depth), data["orders"][a:b]


def test_the_orders_a_compiled_std_sort_left():
    checked = 0
    for keys, depth, expected in _fixture_cases():
        order = std_sort_order(keys.astype(np.int64), depth)
        np.testing.assert_array_equal(order, expected, err_msg=f"n={len(keys)} depth={depth}")
        checked += 1
    assert checked > 50


def test_equal_keys_are_not_left_in_input_order():
    # the reason for the port: a stable sort would differ from std::sort on these
    keys, _, expected = next((k, d, o) for k, d, o in _fixture_cases()
                             if len(k) == 1000 and d < 0 and len(np.unique(k)) < 10)
    assert not np.array_equal(np.argsort(keys, kind="stable"), expected)
    assert np.all(np.diff(keys[std_sort_order(keys.astype(np.int64))]) >= 0)


@pytest.mark.skipif(shutil.which("g++") is None, reason="needs g++ to compile std::sort")
def test_fresh_cases_against_the_compiler_here(tmp_path):
    from std_sort_fixture import build, reference_orders

    rng = np.random.default_rng(11)
    items = [(rng.integers(0, d, n), depth) for n, d, depth in
             ((5000, 40, -1), (777, 700, -1), (64, 3, -1), (900, 90, 2), (300, 5, 0))]
    for (keys, depth), expected in zip(items, reference_orders(build(tmp_path), items),
                                       strict=True):
        np.testing.assert_array_equal(std_sort_order(keys.astype(np.int64), depth), expected)
