"""The update-thread control (:mod:`evsmap.mapping.threads`), and the parallel kernels giving the
same arrays at one thread and at two."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from evsmap.mapping import kernels, threads
from evsmap.mapping.keys import KEY_MAX, KEY_OFFSET
from evsmap.testing import missing


@pytest.fixture(autouse=True)
def _restore_threads():
    yield
    threads.set_update_threads(None)


@pytest.fixture
def compiled():
    if kernels.trace is None:
        missing("numba cannot be imported: the parallel kernels are untested")


def test_set_and_read_the_thread_count(monkeypatch):
    monkeypatch.delenv(threads.ENV, raising=False)
    assert threads.set_update_threads(1) == 1 == threads.update_threads()
    assert threads.set_update_threads(10_000) == threads.max_threads()  # capped
    assert threads.set_update_threads(None) == threads.max_threads()  # default: all
    for bad in (0, -2, 1.5, True, "2"):
        with pytest.raises(ValueError, match="positive integer"):
            threads.set_update_threads(bad)


def test_the_environment_variable_sets_the_default(monkeypatch):
    monkeypatch.setenv(threads.ENV, "1")
    assert threads.update_threads() == 1
    threads.set_update_threads(threads.max_threads())  # an explicit setting wins
    assert threads.update_threads() == threads.max_threads()
    threads.set_update_threads(None)
    monkeypatch.setenv(threads.ENV, "many")
    with pytest.raises(ValueError, match=threads.ENV):
        threads.update_threads()


def test_threading_info_names_the_layer_and_the_threads(compiled):
    threads.set_update_threads(1)
    with threads.kernel_threads():
        kernels.sorted_index(np.arange(4), np.arange(4))  # a parallel kernel has run
    info = threads.threading_info()
    assert info["threads"] == 1
    assert info["layer"] in ("omp", "workqueue", "tbb")


def test_the_setting_applies_in_the_thread_that_launches_the_kernels(compiled):
    import numba

    threads.set_update_threads(1)
    seen = []

    def work():
        with threads.kernel_threads() as n:
            seen.append((n, numba.get_num_threads()))

    t = threading.Thread(target=work)
    t.start()
    t.join()
    assert seen == [(1, 1)]


def _at(n, kernel, *args):
    threads.set_update_threads(n)
    with threads.kernel_threads():
        return kernel(*args)


def _same(a, b):
    for x, y in zip(a, b, strict=True):
        assert np.array_equal(x, y)


def _both(kernel, *args):
    """The kernel's outputs at one thread and at two (as a tuple each)."""
    out = []
    for n in (1, 2):
        r = _at(n, kernel, *args)
        out.append(r if isinstance(r, tuple) else (r,))
    return out


def test_parallel_kernels_give_the_same_arrays_at_one_and_two_threads(compiled):
    rng = np.random.default_rng(3)
    # points over several blocks, some outside the key range and some NaN
    points = rng.normal(0, 1.5, (3 * (1 << 16) + 17, 3)).astype(np.float32)
    points[::997] = np.nan
    points[5] = 1e9
    a, b = _both(kernels.group_points, points, 20.0, KEY_OFFSET, KEY_MAX, 1 << 26)
    _same(a, b)
    assert a[3] and len(a[2]) > 1000
    assert np.array_equal(a[2], np.unique(a[2]))

    depth = rng.uniform(0.3, 4.0, (240, 320)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.3] = 0
    pose = np.eye(4)
    pose[:3, 3] = (0.5, -1.0, 2.0)
    _same(*_both(kernels.depth_points, depth, 300.0, 300.0, 160.0, 120.0, pose))

    grid = rng.random(211 * 77 * 13) < 0.2
    codes = _both(kernels.grid_codes, grid, 100, 200, 300, 77, 13)
    _same(*codes)
    index = np.flatnonzero(grid)
    k0, rem = np.divmod(index, 77 * 13)
    k1, k2 = np.divmod(rem, 13)
    assert np.array_equal(codes[0][0], ((k0 + 100) << 32) | ((k1 + 200) << 16) | (k2 + 300))

    sorted_codes = np.unique(rng.integers(0, 1 << 40, 50_000))
    queries = np.concatenate([sorted_codes[::3], rng.integers(-5, 1 << 41, 20_000)])
    found = _both(kernels.sorted_index, sorted_codes, queries)
    _same(*found)
    assert np.array_equal(found[0][0], np.searchsorted(sorted_codes, queries))
    assert np.array_equal(found[0][1], np.isin(queries, sorted_codes))

    old = rng.normal(size=(40_000, 3)).astype(np.float32)
    created = np.sort(rng.choice(50_000, 10_000, replace=False))
    fill = rng.normal(size=(10_000, 3)).astype(np.float32)
    grown = []
    for n in (1, 2):
        out = np.empty((50_000, 3), dtype=np.float32)
        _at(n, kernels.grow_rows, old, created, fill, out)
        grown.append(out)
    assert np.array_equal(grown[0], grown[1])
    kept = np.ones(50_000, dtype=bool)
    kept[created] = False
    assert np.array_equal(grown[0][kept], old) and np.array_equal(grown[0][created], fill)


def test_the_parallel_ray_walk_marks_the_same_grid(compiled):
    from evsmap.mapping import raycast

    rng = np.random.default_rng(8)
    ends = rng.uniform(-2, 2, (20_000, 3)).astype(np.float32)
    origin = np.array([0.1, 0.2, 0.3], dtype=np.float32)
    free = []
    for n in (1, 2):
        threads.set_update_threads(n)
        with threads.kernel_threads():
            free.append(raycast.scan_keys(ends, origin, 0.02, max_range=1.5).free)
    assert np.array_equal(free[0], free[1]) and len(free[0]) > 10_000
