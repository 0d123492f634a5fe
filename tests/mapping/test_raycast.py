"""Ray casting: hand cases, a brute-force reference and OctoMap (octomap-python) itself."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

import evsmap.mapping.raycast as raycast
from evsmap.data import Frame, Intrinsics
from evsmap.mapping.keys import KEY_OFFSET, pack, unpack
from evsmap.mapping.raycast import ScanKeys, frame_points, octomap_keys, scan_keys
from evsmap.testing import missing, require_module

octomap = require_module("octomap")


def k(*ijk: int) -> int:
    """Code of the voxel with key offsets ``ijk`` from the map centre."""
    return int(pack(np.array([ijk]) + KEY_OFFSET)[0])


def codes(*voxels: tuple[int, int, int]) -> list[int]:
    return sorted(k(*v) for v in voxels)


def octomap_scan(points, origin, res, max_range=-1.0, discretize=False) -> ScanKeys:
    """Free and occupied finest voxels of an OctoMap tree after one scan (pruned leaves
    expanded)."""
    tree = octomap.OcTree(res)
    tree.insertPointCloud(np.asarray(points, dtype=np.float64), np.asarray(origin, np.float64),
                          max_range, False, discretize)
    out = {True: [], False: []}
    for leaf in tree.begin_leafs():
        key = leaf.getKey()
        diff = 16 - leaf.getDepth()
        corner = (np.array([key[0], key[1], key[2]], dtype=np.int64) >> diff) << diff
        r = np.arange(1 << diff)
        cube = np.stack(np.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3) + corner
        out[bool(tree.isNodeOccupied(leaf))].append(pack(cube))

    def cat(parts):
        return np.sort(np.concatenate(parts)) if parts else np.zeros(0, dtype=np.int64)

    return ScanKeys(cat(out[False]), cat(out[True]))


def reference_ray(origin, end, res) -> set[int]:
    """Voxels a segment passes through, by brute force: the voxel at the midpoint of every
    interval between consecutive voxel-border crossings (exact for rays that do not pass within
    rounding distance of a voxel edge)."""
    o = np.asarray(origin, dtype=np.float64)
    d = np.asarray(end, dtype=np.float64) - o
    ts = [0.0, 1.0]
    for axis in range(3):
        if d[axis] == 0:
            continue
        lo, hi = sorted((o[axis], o[axis] + d[axis]))
        borders = np.arange(np.floor(lo / res), np.floor(hi / res) + 2) * res
        t = (borders - o[axis]) / d[axis]
        ts.extend(t[(t > 0) & (t < 1)])
    ts = np.unique(ts)
    mids = (ts[1:] + ts[:-1]) / 2
    keys = np.floor((o + mids[:, None] * d) / res).astype(np.int64) + KEY_OFFSET
    return set(pack(keys).tolist())


def test_ray_along_x_frees_four_and_occupies_one():
    res = 0.1
    got = scan_keys(np.array([[0.45, 0.05, 0.05]]), np.array([0.05, 0.05, 0.05]), res)
    assert got.free.tolist() == codes((0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0))
    assert got.occupied.tolist() == codes((4, 0, 0))
    # the same along -y, from a non-central origin
    got = scan_keys(np.array([[0.01, -0.47, 0.02]]), np.array([0.03, 0.08, 0.02]), res)
    assert got.free.tolist() == codes(*[(0, j, 0) for j in range(-4, 1)])
    assert got.occupied.tolist() == codes((0, -5, 0))


def test_diagonal_rays_match_brute_force_reference():
    rng = np.random.default_rng(1)
    res = 0.05
    for _ in range(200):
        origin = rng.uniform(-0.5, 0.5, 3).astype(np.float32).astype(np.float64)
        end = (origin + rng.normal(size=3) * rng.uniform(0.1, 2.0)).astype(np.float32)
        end = end.astype(np.float64)
        got = scan_keys(end[None], origin, res)
        ref = reference_ray(origin, end, res)
        end_code = int(pack(octomap_keys(end[None].astype(np.float32), res)[0])[0])
        assert got.occupied.tolist() == [end_code]
        assert set(got.free.tolist()) == ref - {end_code}
        # dense sampling never finds a voxel the DDA missed
        t = np.linspace(0.0, 1.0, 20001)[:-1]
        samples = origin + t[:, None] * (end - origin)
        sampled = set(pack(np.floor(samples / res).astype(np.int64) + KEY_OFFSET).tolist())
        assert sampled - {end_code} <= set(got.free.tolist())


def test_point_in_origin_voxel_frees_nothing():
    got = scan_keys(np.array([[0.09, 0.01, 0.02]]), np.array([0.01, 0.02, 0.03]), 0.1)
    assert got.free.size == 0
    assert got.occupied.tolist() == codes((0, 0, 0))


def test_max_range_cuts_ray_and_only_frees():
    origin = np.array([0.05, 0.05, 0.05])
    points = np.array([[1.05, 0.05, 0.05]])  # 1 m away
    got = scan_keys(points, origin, 0.1, max_range=0.52)
    # cut end at x = 0.57 (voxel 5), which is not freed; nothing is occupied
    assert got.free.tolist() == codes(*[(i, 0, 0) for i in range(5)])
    assert got.occupied.size == 0
    ref = octomap_scan(points, origin, 0.1, max_range=0.52)
    assert np.array_equal(got.free, ref.free) and np.array_equal(got.occupied, ref.occupied)
    # a point exactly within range is a normal measurement
    got = scan_keys(points, origin, 0.1, max_range=1.01)
    assert got.occupied.tolist() == codes((10, 0, 0)) and got.free.size == 10


def test_occupied_wins_over_free_within_one_scan():
    origin = np.array([0.05, 0.05, 0.05])
    points = np.array([[0.95, 0.05, 0.05], [0.45, 0.05, 0.05]])  # 2nd end lies on the 1st ray
    got = scan_keys(points, origin, 0.1)
    assert k(4, 0, 0) in got.occupied.tolist()
    assert k(4, 0, 0) not in got.free.tolist()
    assert got.free.tolist() == codes(*[(i, 0, 0) for i in range(9) if i != 4])
    assert not np.isin(got.free, got.occupied).any()


def test_many_points_one_voxel_give_one_key():
    rng = np.random.default_rng(2)
    points = np.array([0.3, 0.2, 0.1]) + rng.uniform(0, 0.099, (500, 3))
    got = scan_keys(points, np.zeros(3), 0.1)
    assert got.occupied.tolist() == codes((3, 2, 1))
    assert len(set(got.free.tolist())) == got.free.size  # unique
    assert np.all(np.diff(got.free) > 0)


def test_ties_step_along_the_highest_axis_first():
    # an exact xy diagonal through voxel corners: OctoMap steps along y before x at every tie
    got = scan_keys(np.array([[3.5, 3.5, 0.5]]), np.array([0.5, 0.5, 0.5]), 1.0)
    assert got.free.tolist() == codes((0, 0, 0), (0, 1, 0), (1, 1, 0), (1, 2, 0), (2, 2, 0),
                                      (2, 3, 0))
    assert got.occupied.tolist() == codes((3, 3, 0))
    ref = octomap_scan([[3.5, 3.5, 0.5]], [0.5, 0.5, 0.5], 1.0)
    assert np.array_equal(got.free, ref.free)
    # a 3D diagonal: z, then y, then x
    got = scan_keys(np.array([[2.5, 2.5, 2.5]]), np.array([0.5, 0.5, 0.5]), 1.0)
    assert got.free.tolist() == codes((0, 0, 0), (0, 0, 1), (0, 1, 1), (1, 1, 1), (1, 1, 2),
                                      (1, 2, 2))
    ref = octomap_scan([[2.5, 2.5, 2.5]], [0.5, 0.5, 0.5], 1.0)
    assert np.array_equal(got.free, ref.free)


def test_points_outside_the_key_range_are_skipped_like_octomap():
    points = np.array([[400.0, 0.0, 0.0], [0.05, 0.0, 0.0], [np.nan, 0.0, 0.0]])
    got = scan_keys(points, np.array([0.005, 0.005, 0.005]), 0.01)
    ref = octomap_scan(points[:2], [0.005, 0.005, 0.005], 0.01)
    assert np.array_equal(got.free, ref.free) and np.array_equal(got.occupied, ref.occupied)
    assert got.occupied.size == 1
    empty = scan_keys(np.zeros((0, 3)), np.zeros(3), 0.1)
    assert empty.free.size == 0 and empty.occupied.size == 0
    with pytest.raises(ValueError, match="resolution"):
        scan_keys(points, np.zeros(3), 0.0)


@pytest.fixture(params=["compiled", "reference"])
def dda(request):
    """Both ray walkers: the compiled kernel and the pure-numpy merge."""
    if request.param == "compiled" and raycast.trace is None:
        missing("numba cannot be imported: the compiled ray walker is untested")
    return request.param


@pytest.mark.parametrize("discretize", [False, True], ids=["rays", "discretized"])
@pytest.mark.parametrize("case", range(8))
def test_matches_octomap_on_random_clouds(case, discretize, dda):
    rng = np.random.default_rng(100 + case)
    res = [0.05, 0.1, 0.02, 0.037][case % 4]
    max_range = [-1.0, 2.0, 1.0, 0.7][case % 4]
    points = rng.normal(size=(1000, 3)) * rng.uniform(0.3, 1.5)
    origin = rng.normal(size=3) * 0.4
    if case % 2 == 0:  # ends and origin on voxel borders and centres: many exact ties
        points = np.round(points / res) * res
        origin = np.round(origin / res) * res + (res / 2 if case % 4 == 0 else 0.0)
    got = scan_keys(points, origin, res, max_range=max_range, discretize=discretize,
                    kernels=dda)
    ref = octomap_scan(points, origin, res, max_range=max_range, discretize=discretize)
    assert ref.free.size > 100
    assert np.array_equal(got.occupied, ref.occupied)
    assert np.array_equal(got.free, ref.free)


def test_chunking_and_dedup_paths_agree(monkeypatch):
    rng = np.random.default_rng(7)
    points = rng.normal(size=(3000, 3)) * 1.5
    origin = np.array([0.1, -0.2, 0.05])
    expected = scan_keys(points, origin, 0.05, max_range=2.0, kernels="reference")
    monkeypatch.setattr(raycast, "CHUNK_ELEMENTS", 5000)
    small = scan_keys(points, origin, 0.05, max_range=2.0, kernels="reference")
    monkeypatch.setattr(raycast, "DENSE_GRID_LIMIT", 0)  # np.unique in packed-code space
    sparse = scan_keys(points, origin, 0.05, max_range=2.0, kernels="reference")
    results = [small, sparse]
    if raycast.trace is not None:  # the compiled kernel, with the unique path and the grid
        results.append(scan_keys(points, origin, 0.05, max_range=2.0))
        monkeypatch.setattr(raycast, "DENSE_GRID_LIMIT", 1 << 28)
        results.append(scan_keys(points, origin, 0.05, max_range=2.0))
    for got in results:
        assert np.array_equal(got.free, expected.free)
        assert np.array_equal(got.occupied, expected.occupied)


def test_memory_stays_bounded_for_long_rays():
    # 40,000 rays of ~5 m at 2 cm (about 15 million crossings); the chunking keeps the peak low
    rng = np.random.default_rng(3)
    direction = rng.normal(size=(40_000, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    points = direction * rng.uniform(4.0, 5.0, (40_000, 1))
    tracemalloc.start()
    try:
        got = scan_keys(points, np.zeros(3), 0.02, max_range=5.0)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert got.free.size > 1_000_000
    assert peak < 500e6, f"peak {peak / 1e6:.0f} MB"  # about 290 MB: 128 MB of it the grid


def test_frame_points_and_origin():
    intr = Intrinsics(100.0, 100.0, 3.5, 2.5, 8, 6)
    depth = np.full((6, 8), 2.0, dtype=np.float32)
    depth[0, 0] = 0.0
    pose = np.eye(4)
    pose[:3, 3] = [1.0, 2.0, 3.0]
    frame = Frame(rgb=np.zeros((6, 8, 3), np.uint8), depth=depth, intrinsics=intr, pose=pose,
                  timestamp=0.0)
    points, origin = frame_points(frame)
    assert points.shape == (47, 3) and origin.tolist() == [1.0, 2.0, 3.0]
    assert np.allclose(points[:, 2], 5.0)
    points, _ = frame_points(frame, stride=2)
    assert points.shape == (4 * 3 - 1, 3)  # rows 0,2,4 x cols 0,2,4,6 minus the invalid pixel
    with pytest.raises(ValueError):
        frame_points(frame, stride=0)


def test_octomap_keys_use_the_reciprocal_like_octomap():
    tree = octomap.OcTree(0.05)
    rng = np.random.default_rng(5)
    pts = (rng.integers(-200, 200, (2000, 3)) * 0.05).astype(np.float32)  # on voxel borders
    keys, ok = octomap_keys(pts, 0.05)
    assert ok.all()
    ref = np.array([[tree.coordToKey(p.astype(np.float64))[i] for i in range(3)] for p in pts])
    assert np.array_equal(keys, ref)
    assert np.array_equal(unpack(pack(keys)), keys)
