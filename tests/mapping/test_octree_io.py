import os

import numpy as np
import pytest

from evsmap.errors import DataFormatError, InvalidDataError
from evsmap.mapping.keys import KEY_OFFSET, pack
from evsmap.mapping.octree_io import (
    bt_bytes,
    logodds,
    ot_bytes,
    parse_ot,
    read_bt,
    read_ot,
    to_max_likelihood,
    write_bt,
    write_ot,
)
from evsmap.mapping.tree import Tree, build_color_tree, build_tree, expand_leaves
from evsmap.testing import require_module

RES = 0.1
OFFSETS = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)])
SEM = np.dtype([("cls", "u1", (3,)), ("conf", ">f4", (3,)), ("others", "<f8")])


@pytest.fixture(scope="module")
def octomap():
    return require_module("octomap")


def octomap_nodes(tree, colour=False):
    """(depth, first-corner code, value, is_leaf[, colour]) in tree_iterator (pre-)order."""
    d, c, v, leaf, col = [], [], [], [], []
    for it in tree.begin_tree():
        dd = it.getDepth()
        k = it.getKey()
        sh = 16 - dd
        d.append(dd)
        c.append([(k[j] >> sh) << sh for j in range(3)])
        v.append(it.getValue())
        leaf.append(it.isLeaf())
        if colour:
            col.append(it.getColor())
    out = (np.array(d), pack(np.array(c)), np.array(v, np.float32), np.array(leaf, bool))
    return (*out, np.array(col, np.uint8)) if colour else out


def fill(tree, rng, scans=6, points=300):
    for _ in range(scans):
        pts = rng.uniform([-1, -1, 1.0], [1, 1, 1.2], size=(points, 3))
        tree.insertPointCloud(pts, np.zeros(3), maxrange=-1.0, lazy_eval=False, discretize=False)
    for x, y, z in np.ndindex(8, 8, 8):  # a solid block: a depth-13 leaf
        k = tree.coordToKey(np.array([0.0, 0.0, 0.0]))
        k[0], k[1], k[2] = KEY_OFFSET + 64 + x, KEY_OFFSET + 64 + y, KEY_OFFSET + 64 + z
        tree.updateNode(k, True)
    return tree


def ours_from(tree, colour=False):
    """Our tree built from the finest-level expansion of an octomap tree's leaves."""
    nodes = octomap_nodes(tree, colour)
    d, c, v, leaf = nodes[:4]
    if colour:
        fc, fv, fcol = expand_leaves(d[leaf], c[leaf], v[leaf], nodes[4][leaf])
        return build_color_tree(fc, fv, fcol)
    fc, fv, _ = expand_leaves(d[leaf], c[leaf], v[leaf])
    return build_tree(fc, fv)


@pytest.fixture(scope="module")
def om_tree(octomap):
    return fill(octomap.OcTree(RES), np.random.default_rng(3))


def test_ot_bytes_identical_to_octomap(octomap, om_tree, tmp_path):
    t = ours_from(om_tree)
    assert t.num_nodes == om_tree.size()
    path = tmp_path / "ours.ot"
    n = write_ot(path, t, RES)
    data = path.read_bytes()
    assert n == len(data) == os.path.getsize(path)
    assert data == om_tree.write()
    assert data.count(b"\n", 0, 200) >= 7 and b"\nres 0.1\ndata\n" in data
    assert len(data) - data.index(b"data\n") - 5 == 5 * t.num_nodes  # 5 B per node
    back = octomap.OcTree.read(str(path).encode())
    assert back.size() == t.num_nodes and back.getNumLeafNodes() == t.num_leaves
    assert [p.name for p in tmp_path.iterdir()] == ["ours.ot"]  # no temp file left


def test_read_ot_written_by_octomap(om_tree, tmp_path):
    path = tmp_path / "octomap.ot"
    assert om_tree.write(str(path).encode())
    tree_id, res, t = read_ot(path)
    assert (tree_id, res) == ("OcTree", RES)
    d, c, v, leaf = octomap_nodes(om_tree)
    assert t.num_nodes == om_tree.size() and t.num_leaves == om_tree.getNumLeafNodes()
    assert np.array_equal(t.depth, d) and np.array_equal(t.code, c)
    assert np.array_equal(t.value, v) and np.array_equal(t.is_leaf, leaf)
    assert t.identical(ours_from(om_tree))


def test_bt_bytes_identical_and_readable(octomap, tmp_path):
    om = fill(octomap.OcTree(RES), np.random.default_rng(7))
    t = ours_from(om)
    path = tmp_path / "ours.bt"
    n = write_bt(path, t, RES)
    ref = om.writeBinary()  # converts the live tree to max likelihood and prunes it
    assert path.read_bytes() == ref and n == len(ref)
    assert to_max_likelihood(t).num_nodes == om.size()
    back = octomap.OcTree(RES)
    assert back.readBinary(str(path).encode())
    assert back.size() == om.size() and back.getNumLeafNodes() == om.getNumLeafNodes()
    # reading: the same nodes and values as octomap's readBinary
    tree_id, res, rt = read_bt(path)
    assert (tree_id, res) == ("OcTree", RES)
    d, c, v, leaf = octomap_nodes(back)
    assert np.array_equal(rt.depth, d) and np.array_equal(rt.code, c)
    assert np.array_equal(rt.value, v) and np.array_equal(rt.is_leaf, leaf)
    lo, hi = logodds(0.1192), logodds(0.971)
    assert set(np.unique(rt.value[rt.is_leaf])) <= {lo, hi} and rt.value[0] == hi


def test_bt_prune_stops_at_first_level_without_pruning(octomap):
    """OctoMap's prune() stops at the first level that prunes nothing: 8 depth-15 leaves with
    different values, all occupied after max likelihood, stay 8 leaves in the .bt."""
    om = octomap.OcTree(RES)
    codes, vals = [], []
    for b in range(8):
        for i in range(8):
            kk = np.array([KEY_OFFSET + 64, KEY_OFFSET, KEY_OFFSET]) + 2 * OFFSETS[b] + OFFSETS[i]
            key = om.coordToKey(np.zeros(3))
            key[0], key[1], key[2] = (int(x) for x in kk)
            om.updateNode(key, float(0.1 * (b + 1)))
            codes.append(pack(kk[None])[0])
            vals.append(np.float32(0.1 * (b + 1)))
    t = build_tree(np.array(codes), np.array(vals, np.float32))
    assert ot_bytes(t, RES) == om.write()
    data = bt_bytes(t, RES)
    assert data == om.writeBinary() and om.size() == 23
    # a full bottom-up prune would have collapsed them
    ml = np.full(t.num_nodes, logodds(0.971), np.float32)
    assert t.prune(ml, min_depth=1).num_nodes == 15


def test_colour_ot_identical(octomap, tmp_path):
    rng = np.random.default_rng(2)
    om = fill(octomap.ColorOcTree(RES), rng, scans=3)
    for i, it in enumerate(om.begin_leafs()):
        if i % 3:
            om.setNodeColor(it.getCoordinate(), *(int(x) for x in rng.integers(0, 255, 3)))
        if i % 5 == 0:
            om.integrateNodeColor(it.getCoordinate(), 40, 50, 60)
    om.updateInnerOccupancy()
    t = ours_from(om, colour=True)
    path = tmp_path / "c.ot"
    write_ot(path, t, RES, tree_id="ColorOcTree")
    data = path.read_bytes()
    assert data == om.write()
    assert len(data) - data.index(b"data\n") - 5 == 8 * t.num_nodes  # 8 B per node
    back = octomap.ColorOcTree.read(str(path).encode())
    assert back.size() == t.num_nodes and back.getNumLeafNodes() == t.num_leaves
    tree_id, _, rt = read_ot(path)
    assert tree_id == "ColorOcTree" and rt.identical(t)
    assert rt.payload.shape == (t.num_nodes, 3) and rt.payload.dtype == np.uint8
    assert bt_bytes(t, RES, tree_id="ColorOcTree") == om.writeBinary()


def test_colour_ot_without_payload_is_white():
    t = build_tree(pack(np.array([[1, 2, 3]])), np.ones(1, np.float32))
    _, _, rt = parse_ot(ot_bytes(t, RES, tree_id="ColorOcTree"))
    assert np.all(rt.payload == 255)


def semantic_tree(seed=0):
    rng = np.random.default_rng(seed)
    codes = np.unique(pack(rng.integers(KEY_OFFSET - 20, KEY_OFFSET + 20, (3000, 3))))
    pay = np.zeros(len(codes), SEM)
    pay["cls"] = rng.integers(0, 3, (len(codes), 3))
    pay["conf"] = rng.choice([0.25, 0.5], (len(codes), 3))
    pay["others"] = rng.random(len(codes))
    vals = rng.choice(np.float32([-2, 3.5]), len(codes))
    return build_tree(codes, vals, payload=pay, equal_columns=[vals, pay["cls"]])


def test_custom_semantic_payload_round_trip(tmp_path):
    t = semantic_tree()
    path = tmp_path / "sem.ot"
    n = write_ot(path, t, 0.02, tree_id="SemanticOcTree")
    assert n == path.stat().st_size
    rec = 4 + SEM.itemsize + 1
    data = path.read_bytes()
    assert len(data) - data.index(b"data\n") - 5 == rec * t.num_nodes
    tree_id, res, rt = read_ot(path, payload_format=SEM)
    assert (tree_id, res) == ("SemanticOcTree", 0.02)
    assert rt.identical(t)
    assert rt.payload.dtype.names == SEM.names
    # a mapping from tree type to layout works too; the bytes are little-endian
    _, _, rt2 = read_ot(path, payload_format={"SemanticOcTree": SEM.newbyteorder("<")})
    assert np.array_equal(rt2.payload, t.payload)
    # a plain (M, k) payload
    p2 = np.arange(t.num_nodes * 4, dtype=np.uint16).reshape(-1, 4)
    t2 = Tree(t.depth, t.code, t.child_mask, t.value, p2)
    write_ot(path, t2, 0.02, tree_id="Plain")
    _, _, rt3 = read_ot(path, payload_format=np.dtype(("<u2", (4,))))
    assert rt3.identical(t2)


def test_unknown_tree_id_names_file_and_id(tmp_path):
    path = tmp_path / "sem.ot"
    write_ot(path, semantic_tree(), RES, tree_id="SemanticOcTree")
    with pytest.raises(DataFormatError, match=r"sem\.ot.*SemanticOcTree"):
        read_ot(path)
    with pytest.raises(DataFormatError, match="SemanticOcTree"):
        read_ot(path, payload_format={"Other": SEM})


def test_empty_tree_files(octomap, tmp_path):
    t = Tree.empty()
    om = octomap.OcTree(RES)
    assert ot_bytes(t, RES) == om.write()
    assert bt_bytes(t, RES) == om.writeBinary()
    write_bt(tmp_path / "e.bt", t, RES)
    assert read_bt(tmp_path / "e.bt").tree.num_nodes == 0
    write_ot(tmp_path / "e.ot", t, RES)
    assert read_ot(tmp_path / "e.ot").tree.num_nodes == 0


def test_resolution_header_like_octomap(octomap):
    t = build_tree(pack(np.array([[KEY_OFFSET] * 3])), np.ones(1, np.float32))
    for res in (0.02, 0.05, 0.123456789, 1.0):
        om = octomap.OcTree(res)
        om.updateNode(om.coordToKey(np.array([0.0, 0.0, 0.0])), 1.0)
        assert ot_bytes(t, res) == om.write()


def test_corrupt_files_raise_data_format_error(tmp_path):
    t = semantic_tree(1)
    good_ot = ot_bytes(t, RES)
    good_bt = bt_bytes(t, RES)
    cases = {
        "trunc.ot": good_ot[:-3],
        "trail.ot": good_ot + b"\0",
        "hdr.ot": good_ot.replace(b"# Octomap OcTree file", b"# Not an octree", 1),
        "size.ot": good_ot.replace(f"size {t.num_nodes}".encode(),
                                   f"size {t.num_nodes - 1}".encode(), 1),
        "noid.ot": good_ot.replace(b"id OcTree\n", b"", 1),
        "nodata.ot": good_ot[:good_ot.index(b"data\n")],
        "badres.ot": good_ot.replace(b"res 0.1", b"res abc", 1),
        "empty.ot": b"",
        "trunc.bt": good_bt[:-1],
        "trunc2.bt": good_bt[:-2],
        "trail.bt": good_bt + b"\0\0",
        "size.bt": good_bt.replace(b"size ", b"size 1", 1),
        "bt_as.ot": good_bt,
    }
    # a chain of 18 single-child nodes is deeper than 16 levels
    chain = np.array([(0.0, 1)] * 17 + [(0.0, 0)], dtype=[("v", "<f4"), ("m", "u1")]).tobytes()
    cases["deep.ot"] = good_ot[:good_ot.index(b"size ")] + b"size 18\nres 0.1\ndata\n" + chain
    for name, data in cases.items():
        p = tmp_path / name
        p.write_bytes(data)
        reader = read_bt if name.endswith(".bt") else read_ot
        with pytest.raises(DataFormatError, match=name.replace(".", r"\.")):
            reader(p)
    with pytest.raises(DataFormatError, match="missing"):
        read_ot(tmp_path / "missing.ot")
    (tmp_path / "a_file").write_text("x")  # a file where the folder above should be
    with pytest.raises(DataFormatError, match=r"x\.ot"):
        write_ot(tmp_path / "a_file" / "x.ot", t, RES)
    write_ot(tmp_path / "new_dir" / "x.ot", t, RES)  # a missing folder is made (fileio)
    assert read_ot(tmp_path / "new_dir" / "x.ot") is not None


def test_random_corruption_never_leaks_numpy_errors(tmp_path):
    rng = np.random.default_rng(9)
    t = semantic_tree(2)
    for kind, good in (("ot", ot_bytes(t, RES)), ("bt", bt_bytes(t, RES))):
        start = good.index(b"data\n") + 5
        for i in range(40):
            bad = bytearray(good)
            pos = rng.integers(start, len(bad), 3)
            bad[pos[0]] = int(rng.integers(0, 256))
            bad[pos[1]] = int(rng.integers(0, 256))
            bad = bytes(bad[: len(bad) - int(rng.integers(0, 3))])
            p = tmp_path / f"r{i}.{kind}"
            p.write_bytes(bad)
            try:
                (read_ot if kind == "ot" else read_bt)(p)
            except DataFormatError as e:
                assert p.name in str(e)


def test_write_is_atomic_overwrite_and_validates(tmp_path):
    t = semantic_tree(3)
    path = tmp_path / "m.ot"
    path.write_bytes(b"old")
    write_ot(path, t, RES)
    assert read_ot(path).tree.num_nodes == t.num_nodes
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.ot"]
    with pytest.raises(InvalidDataError):
        write_ot(path, t, -1.0)
    with pytest.raises(InvalidDataError):
        write_ot(path, t, RES, tree_id="two words")
    with pytest.raises(InvalidDataError):
        write_ot(path, build_tree(np.array([1]), np.ones(1)), RES, tree_id="Custom")
    assert read_ot(path).tree.num_nodes == t.num_nodes  # failed writes left the file alone


@pytest.mark.parametrize("first_set", [False, True])
def test_colour_of_pruned_node_like_octomap(octomap, first_set):
    """ColorOcTree::pruneNode: child 0's colour, or the average child colour if child 0's is
    set."""
    om = octomap.ColorOcTree(RES)
    base = np.array([KEY_OFFSET + 10, KEY_OFFSET, KEY_OFFSET])
    cols = np.full((8, 3), 255, np.uint8)
    keys = []
    for i in range(8):
        k = om.coordToKey(np.zeros(3))
        k[0], k[1], k[2] = (int(x) for x in base + OFFSETS[i])
        keys.append(k)
        om.updateNode(k, float(0.1 * i))
    for i in range(8):
        if i or first_set:
            cols[i] = [10 * i + 1, 20 + i, 200 - 3 * i]
            om.setNodeColor(keys[i], *(int(x) for x in cols[i]))
    for k in keys:  # all reach the clamping max: the parent is pruned
        om.updateNode(k, 10.0)
    om.updateInnerOccupancy()
    t = build_color_tree(pack(base + OFFSETS),
                         np.full(8, om.getClampingThresMaxLog(), np.float32), cols)
    assert t.num_nodes == om.size() == 16
    assert ot_bytes(t, RES, tree_id="ColorOcTree") == om.write()
