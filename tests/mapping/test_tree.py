import numpy as np
import pytest

from evsmap.errors import InvalidDataError
from evsmap.mapping.keys import KEY_OFFSET, morton, pack, unpack
from evsmap.mapping.tree import (
    Tree,
    build_color_tree,
    build_tree,
    expand_leaves,
    octomap_colour_average,
    unmorton,
)
from evsmap.testing import require_module

OFFSETS = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)])  # child order


def block(corner, size):
    """Packed keys of a size^3 block of finest voxels starting at ``corner``."""
    g = np.stack(np.meshgrid(*[np.arange(size)] * 3, indexing="ij"), -1).reshape(-1, 3)
    return pack(np.asarray(corner) + g)


def check_invariants(t: Tree) -> None:
    """Pre-order, masks, first-corner keys and max inner values are consistent."""
    m = t.morton
    order = np.lexsort((t.depth, m))
    assert np.array_equal(order, np.arange(t.num_nodes))
    keys = t.keys
    low = (1 << (16 - t.depth.astype(np.int64)))[:, None] - 1
    assert not np.any(keys & low)
    parent = t.parents()
    assert parent[0] == -1 and np.all(parent[1:] >= 0)
    assert np.all(t.depth[parent[1:]] == t.depth[1:] - 1)
    mask = np.zeros(t.num_nodes, np.uint8)
    np.bitwise_or.at(mask, parent[1:], (1 << t.child_index()[1:]).astype(np.uint8))
    assert np.array_equal(mask, t.child_mask)
    inner = np.flatnonzero(t.child_mask)
    mx = np.full(t.num_nodes, -np.inf, np.float32)
    np.maximum.at(mx, parent[1:], t.value[1:])
    assert np.array_equal(mx[inner], t.value[inner])


def test_unmorton_inverts_morton():
    k = np.random.default_rng(0).integers(0, 65536, (1000, 3))
    assert np.array_equal(unmorton(morton(k)), k)


def test_eight_equal_siblings_prune_to_one_leaf():
    base = np.array([KEY_OFFSET, KEY_OFFSET, KEY_OFFSET])
    t = build_tree(pack(base + OFFSETS), np.full(8, 0.85, np.float32))
    assert t.num_nodes == 16 and t.num_leaves == 1  # root .. depth 15
    assert t.depth[-1] == 15 and t.child_mask[-1] == 0 and t.value[-1] == np.float32(0.85)
    assert np.array_equal(t.keys[-1], base)
    check_invariants(t)


def test_seven_siblings_do_not_prune():
    base = np.array([KEY_OFFSET, KEY_OFFSET, KEY_OFFSET])
    t = build_tree(pack(base + OFFSETS[1:]), np.full(7, 0.85, np.float32))
    assert t.num_nodes == 16 + 7 and t.num_leaves == 7
    assert t.child_mask[15] == 0xFE  # the depth-15 node lacks child 0
    check_invariants(t)


def test_unequal_values_block_pruning():
    base = np.array([KEY_OFFSET, KEY_OFFSET, KEY_OFFSET])
    v = np.full(8, 0.4, np.float32)
    v[5] = np.nextafter(np.float32(0.4), np.float32(1))
    t = build_tree(pack(base + OFFSETS), v)
    assert t.num_leaves == 8
    assert t.value[15] == v[5]  # inner = max


def test_payload_as_equal_column_blocks_pruning():
    base = np.array([100, 200, 300]) * 2
    codes = pack(base + OFFSETS)
    v = np.zeros(8, np.float32)
    sem = np.zeros((8, 2), np.uint8)
    sem[3, 1] = 7
    t = build_tree(codes, v, payload=sem, equal_columns=[v, sem])
    assert t.num_leaves == 8
    # not an equal column: prunes, the pruned leaf carries child 0's payload
    t2 = build_tree(codes, v, payload=sem)
    assert t2.num_leaves == 1 and np.array_equal(t2.payload[-1], sem[0])
    # equal payloads prune
    t3 = build_tree(codes, v, payload=np.ones((8, 2), np.uint8), equal_columns=[v, sem * 0])
    assert t3.num_leaves == 1


def test_structured_payload_equal_column():
    base = np.array([10, 20, 30]) * 2
    dt = np.dtype([("cls", "u1"), ("conf", "f4")])
    pay = np.zeros(8, dt)
    pay["conf"] = 0.5
    v = np.ones(8, np.float32)
    assert build_tree(pack(base + OFFSETS), v, payload=pay, equal_columns=[v, pay]).num_leaves == 1
    pay["conf"][7] = 0.25
    assert build_tree(pack(base + OFFSETS), v, payload=pay, equal_columns=[v, pay]).num_leaves == 8


def test_nested_collapse_over_two_levels():
    corner = np.array([KEY_OFFSET + 64, KEY_OFFSET, KEY_OFFSET - 8])  # a depth-14 block
    codes = block(corner, 4)
    t = build_tree(codes, np.full(64, -2.0, np.float32))
    assert t.num_nodes == 15 and t.num_leaves == 1 and t.depth[-1] == 14
    assert np.array_equal(t.keys[-1], corner)
    # one different voxel keeps the other seven depth-15 blocks pruned
    v = np.full(64, -2.0, np.float32)
    v[-1] = 1.0
    t = build_tree(codes, v)
    assert t.num_leaves == 7 + 8
    assert np.all(t.value[:15] == np.float32(1.0))  # max goes up to the root
    check_invariants(t)


def test_inner_value_is_max_and_other_ufunc():
    codes = pack(np.array([[0, 0, 0], [65535, 65535, 65535], [KEY_OFFSET] * 3]))
    v = np.array([-1.0, 2.0, 0.5], np.float32)
    t = build_tree(codes, v)
    assert t.value[0] == np.float32(2.0)
    check_invariants(t)
    t = build_tree(codes, v, inner_value=np.minimum)
    assert t.value[0] == np.float32(-1.0)


def test_inner_payload_and_prune_payload_options():
    base = np.array([8, 8, 8])
    codes = pack(base + OFFSETS)
    pay = np.arange(8, dtype=np.float64)[:, None] * np.array([1.0, 2.0])

    def mean(child, group, n):
        s = np.zeros((n, child.shape[1]))
        np.add.at(s, group, child)
        return s / np.bincount(group, minlength=n)[:, None]

    v = np.ones(8, np.float32)
    t = build_tree(codes, v, payload=pay, inner_payload=mean, prune_payload="inner")
    assert np.allclose(t.payload[-1], [3.5, 7.0])
    t = build_tree(codes, v, payload=pay, inner_payload=mean)  # "first"
    assert np.array_equal(t.payload[-1], pay[0])
    assert np.allclose(t.payload[0], [0.0, 0.0])  # root: inner of inner (first child only)
    t = build_tree(codes[:7], v[:7], payload=pay[:7], inner_payload=mean)
    assert np.allclose(t.payload[15], pay[:7].mean(axis=0))
    t = build_tree(codes[:7], v[:7], payload=pay[:7])  # no aggregator: zeros
    assert np.array_equal(t.payload[:16], np.zeros((16, 2)))
    with pytest.raises(InvalidDataError):
        build_tree(codes, v, payload=pay, prune_payload="inner")


def test_colour_average_matches_octomap_rule():
    c = np.array([[255, 255, 255], [10, 20, 31], [11, 20, 30], [0, 0, 0]], np.uint8)
    out = octomap_colour_average(c, np.array([0, 0, 0, 1]), 3)
    assert out.tolist() == [[10, 20, 30], [0, 0, 0], [255, 255, 255]]


def test_random_round_trip_through_expand():
    rng = np.random.default_rng(5)
    # clustered voxels with few distinct values -> pruning at several levels
    k = np.concatenate([rng.integers(KEY_OFFSET - 40, KEY_OFFSET + 40, (20000, 3)),
                        unpack(block([KEY_OFFSET + 128] * 3, 16))])
    codes = np.unique(pack(k))
    v = np.where(rng.random(len(codes)) < 0.02, np.float32(0.85), np.float32(-2.0))
    in_block = np.isin(codes, block([KEY_OFFSET + 128] * 3, 16))
    v[in_block] = np.float32(3.5)
    perm = rng.permutation(len(codes))
    t = build_tree(codes[perm], v[perm])
    check_invariants(t)
    assert t.num_leaves < len(codes) and np.min(t.depth[t.is_leaf]) <= 12
    c2, v2, _ = t.expand()
    o = np.argsort(c2)
    assert np.array_equal(c2[o], codes) and np.array_equal(v2[o], v)
    # building from the expansion is the same tree
    assert build_tree(c2, v2).identical(t)
    # and OctoMap-style pruning of an already canonical tree changes nothing
    assert t.prune().identical(t)


def test_from_nodes_and_expand_leaves():
    rng = np.random.default_rng(1)
    codes = np.unique(pack(rng.integers(KEY_OFFSET - 8, KEY_OFFSET + 8, (300, 3))))
    t = build_tree(codes, rng.choice(np.float32([0.0, 1.0]), len(codes)))
    perm = rng.permutation(t.num_nodes)
    t2 = Tree.from_nodes(t.depth[perm], t.code[perm], t.value[perm])
    assert t2.identical(t)
    d, c, v, _ = t.leaves()
    c3, v3, _ = expand_leaves(d, c, v)
    assert np.array_equal(np.sort(c3), codes)
    with pytest.raises(InvalidDataError):
        expand_leaves(np.array([2]), np.array([0]), np.array([0.0]))


def test_empty_and_bad_input():
    t = build_tree(np.zeros(0, np.int64), np.zeros(0, np.float32))
    assert t.num_nodes == 0 and t.num_leaves == 0 and t.memory_bytes() == 0
    c, v, p = t.expand()
    assert len(c) == 0 and p is None
    with pytest.raises(InvalidDataError):
        build_tree(np.array([5, 5]), np.zeros(2, np.float32))
    with pytest.raises(InvalidDataError):
        build_tree(np.array([5, 6]), np.zeros(3, np.float32))
    with pytest.raises(InvalidDataError):
        build_tree(np.array([5, 6]), np.zeros(2), equal_columns=[np.zeros(3)])


# ---------------------------------------------------------------- against octomap-python


def octomap_nodes(tree):
    """(depth, first-corner code, value, is_leaf) of all nodes of an octomap tree, in its
    tree_iterator order (pre-order)."""
    rows = []
    for it in tree.begin_tree():
        d = it.getDepth()
        k = it.getKey()
        sh = 16 - d
        rows.append((d, ((k[0] >> sh) << sh << 32) | ((k[1] >> sh) << sh << 16)
                     | ((k[2] >> sh) << sh), it.getValue(), it.isLeaf()))
    d, c, v, leaf = map(np.array, zip(*rows, strict=True))
    return d, c.astype(np.int64), v.astype(np.float32), leaf.astype(bool)


def octomap_test_tree(octomap, res=0.1, seed=3):
    rng = np.random.default_rng(seed)
    t = octomap.OcTree(res)
    for _ in range(6):
        pts = rng.uniform([-1, -1, 1.0], [1, 1, 1.2], size=(300, 3))
        t.insertPointCloud(pts, np.zeros(3), maxrange=-1.0, lazy_eval=False, discretize=False)
    for x, y, z in np.ndindex(8, 8, 8):  # a solid block -> a depth-13 leaf
        k = octomap.OcTreeKey()
        k[0], k[1], k[2] = KEY_OFFSET + 64 + x, KEY_OFFSET + 64 + y, KEY_OFFSET + 64 + z
        t.updateNode(k, True)
    return t


def test_matches_octomap_structure_and_memory():
    octomap = require_module("octomap")
    ot = octomap_test_tree(octomap)
    d, c, v, leaf = octomap_nodes(ot)
    assert d[leaf].min() <= 13
    fc, fv, _ = expand_leaves(d[leaf], c[leaf], v[leaf])
    t = build_tree(fc, fv)
    assert t.num_nodes == ot.size() and t.num_leaves == ot.getNumLeafNodes()
    assert np.array_equal(t.depth, d) and np.array_equal(t.code, c)
    assert np.array_equal(t.value, v) and np.array_equal(t.is_leaf, leaf)
    base = octomap.OcTree(0.1).memoryUsage()  # sizeof(OcTreeBaseImpl)
    assert ot.memoryUsageNode() == 16
    assert t.memory_bytes(base_bytes=base) == ot.memoryUsage()
    assert t.memory_bytes() == 16 * t.num_nodes + 64 * t.num_inner


def test_colour_tree_matches_octomap_colours():
    octomap = require_module("octomap")
    rng = np.random.default_rng(4)
    ct = octomap.ColorOcTree(0.1)
    for _ in range(3):
        pts = rng.uniform([-1, -1, 1.0], [1, 1, 1.2], size=(200, 3))
        ct.insertPointCloud(pts, np.zeros(3), maxrange=-1.0, lazy_eval=False, discretize=False)
    for i, it in enumerate(ct.begin_leafs()):
        if i % 3:
            ct.setNodeColor(it.getCoordinate(), *(int(x) for x in rng.integers(0, 255, 3)))
    ct.updateInnerOccupancy()
    rows = [(it.getDepth(), it.getKey(), it.getValue(), it.getColor(), it.isLeaf())
            for it in ct.begin_tree()]
    d = np.array([r[0] for r in rows])
    col = np.array([r[3] for r in rows], np.uint8)
    leaf = np.array([r[4] for r in rows])
    keys = np.array([[(r[1][j] >> (16 - r[0])) << (16 - r[0]) for j in range(3)] for r in rows])
    v = np.array([r[2] for r in rows], np.float32)
    fc, fv, fcol = expand_leaves(d[leaf], pack(keys[leaf]), v[leaf], col[leaf])
    t = build_color_tree(fc, fv, fcol)
    assert np.array_equal(t.code, pack(keys)) and np.array_equal(t.payload, col)
    assert np.array_equal(t.value, v)
