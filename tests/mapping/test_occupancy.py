"""Occupancy map: OctoMap's sensor model and update, payload bookkeeping, queries, and agreement
with OctoMap (octomap-python) on the real TUM fr1_xyz frames."""

from __future__ import annotations

import numpy as np
import pytest

from evsmap.interfaces import FREE, OCCUPIED, UNKNOWN, PointQuery
from evsmap.mapping.keys import KEY_OFFSET, pack
from evsmap.mapping.occupancy import OccupancyMap, OccupancyParams, ScanUpdate, logodds
from evsmap.mapping.raycast import frame_points, scan_keys
from evsmap.testing import require_module

octomap = require_module("octomap")

RES = 0.05
MAX_RANGE = 4.0


def octomap_leaves(tree) -> tuple[np.ndarray, np.ndarray]:
    """Finest-level codes (sorted) and float32 log-odds of an OctoMap tree, with pruned leaves
    expanded to the 8**k voxels they stand for."""
    keys, depth, value = [], [], []
    for leaf in tree.begin_leafs():
        key = leaf.getKey()
        keys.append((key[0], key[1], key[2]))
        depth.append(leaf.getDepth())
        value.append(leaf.getValue())
    keys = np.array(keys, dtype=np.int64).reshape(-1, 3)
    depth = np.array(depth, dtype=np.int64)
    value = np.array(value, dtype=np.float32)
    codes, values = [np.zeros(0, np.int64)], [np.zeros(0, np.float32)]
    for d in np.unique(depth):  # a handful of depths
        sel = depth == d
        diff = 16 - int(d)
        corner = (keys[sel] >> diff) << diff
        r = np.arange(1 << diff)
        cube = np.stack(np.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)
        codes.append(pack((corner[:, None, :] + cube[None]).reshape(-1, 3)))
        values.append(np.repeat(value[sel], len(cube)))
    codes, values = np.concatenate(codes), np.concatenate(values)
    order = np.argsort(codes)
    return codes[order], values[order]


def compare_with_octomap(ours: OccupancyMap, tree) -> dict[str, float]:
    """Classify every finest voxel known to either map; agreement of states and log-odds."""
    codes, values = octomap_leaves(tree)
    union = np.union1d(codes, ours.codes)
    pos = np.minimum(np.searchsorted(codes, union), max(len(codes) - 1, 0))
    known = codes[pos] == union if len(codes) else np.zeros(len(union), bool)
    theirs = np.full(len(union), UNKNOWN, dtype=np.int8)
    threshold = tree.getOccupancyThresLog()
    theirs[known] = np.where(values[pos[known]] >= threshold, OCCUPIED, FREE)
    mine = ours.classify(union)
    both = np.isin(union, ours.codes) & known
    same_value = ours.logodds[np.searchsorted(ours.codes, union[both])] == values[pos[both]]
    return {"voxels": len(union), "agreement": float(np.mean(mine == theirs)),
            "value_agreement": float(np.mean(same_value)) if both.any() else 1.0,
            "ours_leaves": ours.num_leaves, "octomap_voxels": len(codes)}


# ---------------------------------------------------------------- parameters


def test_default_params_are_octomaps():
    p = OccupancyParams()
    tree = octomap.OcTree(0.1)
    assert p.hit_logodds == tree.getProbHitLog()
    assert p.miss_logodds == tree.getProbMissLog()
    assert p.clamp_min_logodds == tree.getClampingThresMinLog()
    assert p.clamp_max_logodds == tree.getClampingThresMaxLog()
    assert p.threshold_logodds == tree.getOccupancyThresLog() == 0.0
    assert p.hit_logodds == pytest.approx(0.847, abs=1e-3)
    assert p.clamp_min_logodds == pytest.approx(-2.0, abs=1e-3)
    assert logodds(0.5) == 0.0


@pytest.mark.parametrize("kwargs, match", [
    ({"prob_hit": 1.0}, "prob_hit"), ({"prob_hit": 0.4}, "prob_hit must be above 0.5"),
    ({"prob_miss": 0.6}, "prob_miss must be below 0.5"), ({"clamp_min": 0.0}, "clamp_min"),
    ({"clamp_min": 0.9, "clamp_max": 0.8}, "clamp_min .* must be below"),
    ({"occupancy_threshold": "x"}, "number"), ({"prob_miss": float("nan")}, "prob_miss"),
])
def test_params_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        OccupancyParams(**kwargs)


def test_map_validation():
    with pytest.raises(ValueError, match="resolution"):
        OccupancyMap(0.0)
    with pytest.raises(ValueError, match="params"):
        OccupancyMap(0.1, params={"prob_hit": 0.7})
    m = OccupancyMap(0.1)
    with pytest.raises(ValueError, match="sorted, unique and disjoint"):
        m.apply(np.array([5, 7]), np.array([7]))


# ---------------------------------------------------------------- updates


def test_one_scan_sets_hit_and_miss_logodds():
    m = OccupancyMap(0.1)
    up = m.insert_scan(np.array([[0.45, 0.05, 0.05]]), np.array([0.05, 0.05, 0.05]))
    assert isinstance(up, ScanUpdate)
    assert m.num_leaves == 5 and up.num_new == 5 and up.new_mask.all()
    p = m.params
    assert m.logodds[up.occupied_index].tolist() == [np.float32(p.hit_logodds)]
    assert np.all(m.logodds[up.free_index] == np.float32(p.miss_logodds))
    assert m.classify(m.codes).tolist() == [FREE] * 4 + [OCCUPIED]
    assert m.state_counts() == {"free": 4, "occupied": 1}


def test_each_voxel_updated_once_per_scan():
    m = OccupancyMap(0.1)
    rng = np.random.default_rng(0)
    points = np.array([0.85, 0.05, 0.05]) + rng.uniform(-0.04, 0.04, (300, 3))
    m.insert_scan(points, np.array([0.05, 0.05, 0.05]))
    hit, miss = np.float32(m.params.hit_logodds), np.float32(m.params.miss_logodds)
    assert set(m.logodds.tolist()) == {float(hit), float(miss)}


def test_repeated_scans_clamp_exactly_like_octomap():
    origin = np.array([0.05, 0.05, 0.05])
    points = np.array([[0.95, 0.05, 0.05], [0.05, 0.75, 0.05]])
    m = OccupancyMap(0.1)
    tree = octomap.OcTree(0.1)
    for _ in range(12):
        m.insert_scan(points, origin)
        tree.insertPointCloud(points, origin, -1.0, False, False)
        codes, values = octomap_leaves(tree)
        assert np.array_equal(codes, m.codes) and np.array_equal(values, m.logodds)
    assert m.logodds.max() == np.float32(m.params.clamp_max_logodds)
    assert m.logodds.min() == np.float32(m.params.clamp_min_logodds)
    # a clamped free voxel flips back after hits: -2.0 + 0.847 * 3 > 0
    for _ in range(3):
        m.insert_scan(np.array([[0.35, 0.05, 0.05]]), origin)
        tree.insertPointCloud(np.array([[0.35, 0.05, 0.05]]), origin, -1.0, False, False)
    assert m.query(np.array([[0.35, 0.05, 0.05]])).state.tolist() == [OCCUPIED]
    codes, values = octomap_leaves(tree)
    assert np.array_equal(codes, m.codes) and np.array_equal(values, m.logodds)


@pytest.mark.parametrize("discretize", [False, True], ids=["rays", "discretized"])
def test_multi_scan_random_clouds_match_octomap_exactly(discretize):
    rng = np.random.default_rng(11)
    m = OccupancyMap(0.1)
    tree = octomap.OcTree(0.1)
    for _ in range(6):
        origin = rng.normal(size=3) * 0.3
        points = origin + rng.normal(size=(800, 3)) * 1.2
        m.insert_scan(points, origin, max_range=2.0, discretize=discretize)
        tree.insertPointCloud(points, origin, 2.0, False, discretize)
    codes, values = octomap_leaves(tree)
    assert np.array_equal(codes, m.codes)
    assert np.array_equal(values, m.logodds)


def test_scan_update_indices_and_payload_alignment():
    rng = np.random.default_rng(4)
    m = OccupancyMap(0.1)
    colour = m.add_payload("rgb", np.uint8, (3,), fill=7)
    m.add_payload("tag", np.int64, fill=-1)
    assert colour.shape == (0, 3) and m.payload_names == ("rgb", "tag")
    with pytest.raises(ValueError, match="already"):
        m.add_payload("rgb", np.uint8)
    with pytest.raises(KeyError, match="no payload"):
        m.payload("nope")
    seen: set[int] = set()
    for scan in range(4):
        origin = rng.normal(size=3) * 0.2
        points = origin + rng.normal(size=(200, 3))
        keys = scan_keys(points, origin, 0.1)
        up = m.insert_scan(points, origin)
        assert np.array_equal(m.codes[up.occupied_index], keys.occupied)
        assert np.array_equal(m.codes[up.free_index], keys.free)
        created = set(m.codes[up.new_mask].tolist())
        assert created == set(np.union1d(keys.free, keys.occupied).tolist()) - seen
        assert up.num_new == len(created)
        assert np.array_equal(up.occupied_new, up.new_mask[up.occupied_index])
        seen |= created
        tag = m.payload("tag")
        rgb = m.payload("rgb")
        assert len(tag) == len(rgb) == m.num_leaves
        # created leaves start at the fill value; older ones keep what was written
        assert np.all(tag[up.new_mask] == -1) and np.all(rgb[up.new_mask] == 7)
        assert np.array_equal(tag[~up.new_mask], m.codes[~up.new_mask])
        tag[up.new_mask] = m.codes[up.new_mask]
        rgb[up.occupied_index] = scan
    assert np.array_equal(m.payload("tag"), m.codes)
    assert m.num_leaves == len(seen)


def test_codes_and_logodds_are_read_only_views():
    m = OccupancyMap(0.1)
    m.insert_scan(np.array([[0.3, 0.0, 0.0]]), np.zeros(3))
    with pytest.raises(ValueError):
        m.logodds[0] = 1.0
    with pytest.raises(ValueError):
        m.codes[0] = 1


# ---------------------------------------------------------------- queries


def test_classify_and_query():
    res = 0.1
    codes = pack(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]]) + KEY_OFFSET)
    m = OccupancyMap.from_leaves(res, codes[::-1], np.array([0.5, 0.0, -0.4], np.float32)[::-1])
    assert np.array_equal(m.codes, codes)
    unknown = pack(np.array([[5, 5, 5]]) + KEY_OFFSET)
    assert m.classify(np.concatenate([codes, unknown])).tolist() == [OCCUPIED, OCCUPIED, FREE,
                                                                     UNKNOWN]  # 0.0 >= 0.0
    q = m.query(np.array([[0.05, 0.05, 0.05], [0.15, 0.01, 0.09], [0.25, 0.0, 0.0],
                          [-0.05, 0.0, 0.0], [np.nan, 0.0, 0.0], [1e6, 0.0, 0.0]]))
    assert isinstance(q, PointQuery)
    assert q.state.dtype == np.int8 and q.probability.dtype == np.float32
    assert q.label.dtype == np.int16 and np.all(q.label == -1)
    assert q.state.tolist() == [OCCUPIED, OCCUPIED, FREE, UNKNOWN, UNKNOWN, UNKNOWN]
    assert q.probability[:3] == pytest.approx([1 / (1 + np.exp(-0.5)), 0.5,
                                               1 / (1 + np.exp(0.4))], abs=1e-6)
    assert np.all(np.isnan(q.probability[3:]))
    with pytest.raises(ValueError, match="unique"):
        OccupancyMap.from_leaves(res, np.array([1, 1]), np.zeros(2))


def test_query_matches_octomap_search():
    rng = np.random.default_rng(8)
    origin = np.zeros(3)
    points = rng.normal(size=(500, 3))
    m = OccupancyMap(0.1)
    m.insert_scan(points, origin)
    tree = octomap.OcTree(0.1)
    tree.insertPointCloud(points, origin, -1.0, False, False)
    probes = rng.uniform(-1.5, 1.5, (300, 3))
    q = m.query(probes)
    for p, state, prob in zip(probes, q.state, q.probability, strict=True):
        node = tree.search(p)
        try:
            occupancy = node.getOccupancy()
        except octomap.NullPointerException:  # no node there
            assert state == UNKNOWN and np.isnan(prob)
            continue
        assert state == (OCCUPIED if tree.isNodeOccupied(node) else FREE)
        assert prob == pytest.approx(occupancy, abs=1e-6)


# ---------------------------------------------------------------- real data vs OctoMap


@pytest.fixture(scope="module")
def tum_scans(tum_dir):
    from evsmap.registry import READERS

    # 37 depth images; a 0.021 s association tolerance keeps all of them
    seq = READERS.create("tum", path=str(tum_dir), max_time_difference=0.021)
    assert len(seq) == 37
    return [frame_points(frame) for frame in seq]


@pytest.mark.parametrize("discretize, every", [(True, 1), (False, 4)],
                         ids=["discretized-all-frames", "rays-every-4th-frame"])
def test_tum_fr1_xyz_agrees_with_octomap(tum_scans, discretize, every, record_property):
    ours = OccupancyMap(RES)
    tree = octomap.OcTree(RES)
    for points, origin in tum_scans[::every]:
        ours.insert_scan(points, origin, max_range=MAX_RANGE, discretize=discretize)
        tree.insertPointCloud(points, origin, MAX_RANGE, False, discretize)
    stats = compare_with_octomap(ours, tree)
    record_property("agreement", stats)
    print(f"\nTUM fr1_xyz {RES} m discretize={discretize}: {stats}")
    assert stats["voxels"] > 10_000
    assert stats["agreement"] >= 0.995, stats
    assert stats["value_agreement"] >= 0.995, stats
