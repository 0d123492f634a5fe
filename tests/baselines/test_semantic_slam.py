"""semantic_slam's octomap_generator as :mod:`baselines.semantic_slam` runs it, checked against
OctoMap itself (octomap-python) and against fusions worked out by hand from its C++."""

from __future__ import annotations

import numpy as np
import pytest

from baselines import semantic_slam_kernels as k
from baselines.semantic_slam_node import pack_rgb, unpack_rgb, voc_colormap
from evsmap.data import Frame, Intrinsics, SemanticObservation
from evsmap.mapping.keys import KEY_OFFSET
from evsmap.registry import UPDATERS

WHITE = k.WHITE
f32 = np.float32


def _fuse(rule, c1, f1, c2, f2):
    n = 3 if rule == "bayes" else 1
    out_c, out_f = np.zeros(n, np.uint32), np.zeros(n, np.float32)
    fn = k.fuse_bayes if rule == "bayes" else k.fuse_max
    fn(np.array(c1, np.uint32), np.array(f1, np.float32), np.array(c2, np.uint32),
       np.array(f2, np.float32), out_c, out_f)
    return out_c.tolist(), out_f


# ------------------------------------------------------------------------------ fusion
def test_bayes_fusion_by_hand():
    # s1 = (A .5, B .3, C .1), s2 = (B .6, D .2, A .1)
    c, f = _fuse("bayes", [1, 2, 3], [0.5, 0.3, 0.1], [2, 4, 1], [0.6, 0.2, 0.1])
    o1 = f32(f32(f32(f32(1) - f32(.5)) - f32(.3)) - f32(.1))
    o2 = f32(f32(f32(f32(1) - f32(.6)) - f32(.2)) - f32(.1))
    c_second = f32(0.8 * float(o2))  # C is missing from s2: alpha * others2
    o2 = f32(float(o2) - 0.8 * float(o2))
    d_first = f32(0.8 * float(o1))  # D is new: alpha * others1
    o1 = f32(float(o1) - 0.8 * float(o1))
    raw = {1: f32(f32(.5) * f32(.1)), 2: f32(f32(.3) * f32(.6)), 3: f32(f32(.1) * c_second),
           4: f32(d_first * f32(.2))}
    total = f32(o1 * o2)
    for cls in (1, 2, 3, 4):
        total = f32(total + raw[cls])
    want = {cls: f32(v / total) for cls, v in raw.items()}
    assert c == [2, 1, 4]  # B, A, D; C (the smallest) drops out
    assert f.tolist() == [want[2], want[1], want[4]]


def test_bayes_fusion_ties_go_to_the_later_candidate():
    # disjoint classes at 0.2 each: class 1 (0.2 x alpha 0.4) and the new class 4 (alpha 0.4
    # x 0.2) tie, as do 2 and 5. std::sort (an insertion sort, stable ascending) with the top 3
    # taken from the back puts the later of two equal candidates first
    c, f = _fuse("bayes", [1, 2, 3], [0.2, 0.2, 0.2], [4, 5, 6], [0.2, 0.2, 0.2])
    assert c == [4, 1, 5]
    assert f[0] == f[1] > f[2]
    # the classwise variant (semantic_slam_fusion.fuse_bayes) keeps the earlier instead
    from baselines.semantic_slam_fusion import fuse_bayes

    cls, _ = fuse_bayes(np.array([[1, 2, 3]]), np.array([[.2, .2, .2]]),
                        np.array([[4, 5, 6]]), np.array([[.2, .2, .2]]))
    assert cls[0].tolist() == [1, 4, 2]


def test_bayes_fusion_floors_at_epsilon():
    # confident disagreement: posteriors below 0.001 are raised to float(0.001)
    c, f = _fuse("bayes", [1, 2, 3], [0.998, 0.001, 0.001], [4, 5, 6], [0.998, 0.001, 0.001])
    assert f32(0.001) in f.tolist()
    assert all(v >= f32(0.001) for v in f.tolist())
    assert c[0] in (1, 4)


def test_max_fusion_rules():
    c, f = _fuse("max", [7], [0.6], [7], [0.8])
    assert c == [7] and f[0] == f32(float(f32(f32(0.6) + f32(0.8))) / 2.0)
    c, f = _fuse("max", [7], [0.6], [9], [0.8])
    assert c == [9] and f[0] == f32(float(f32(0.8)) * 0.9)
    c, _ = _fuse("max", [7], [0.8], [9], [0.8])  # a tie keeps s2 (the observation)
    assert c == [9]


def _reference_bayes(s1, s2):
    """SemanticsBayesian::semanticFusion transcribed line by line with numpy float32 scalars
    (double constants promoted as C++ does), independent of the compiled kernel."""
    alpha, eps = 0.8, 0.001
    colors = [c for c, _ in s1]
    conf = [f32(f) for _, f in s1]
    conf2 = []
    o1, o2 = f32(1.0), f32(1.0)
    for i in range(3):
        o1 = f32(o1 - f32(s1[i][1]))
        o2 = f32(o2 - f32(s2[i][1]))
    if float(o1) <= eps:
        o1 = f32(eps)
    if float(o2) <= eps:
        o2 = f32(eps)
    for i in range(3):
        match = [f32(f) for c, f in s2 if c == colors[i]]
        if match:
            conf2.append(match[0])
        else:
            conf2.append(f32(alpha * float(o2)))
            o2 = f32(float(o2) - alpha * float(o2))
    for c, f in s2:
        if c not in colors[:3]:
            colors.append(c)
            conf.append(f32(alpha * float(o1)))
            o1 = f32(float(o1) - alpha * float(o1))
            conf2.append(f32(f))
    total = f32(o1 * o2)
    for i in range(len(colors)):
        conf[i] = f32(conf[i] * conf2[i])
        total = f32(total + conf[i])
    for i in range(len(colors)):
        conf[i] = f32(conf[i] / total)
        if float(conf[i]) < eps:
            conf[i] = f32(eps)
    ranked = sorted(zip(conf, range(len(colors)), strict=True),
                    key=lambda t: t[0])  # stable ascending
    return [(colors[i], c) for c, i in ranked[::-1][:3]]


def test_bayes_fusion_sequences_match_the_transcribed_cpp():
    """Long fusion sequences of one voxel - agreeing runs that push confidences to the EPSILON
    floors, contrary runs, classes entering and leaving, exact ties - compiled kernel against
    a line-by-line transcription, bit for bit."""
    rng = np.random.default_rng(7)
    for _ in range(40):
        state = None
        for _ in range(25):
            if rng.random() < 0.3:  # exact ties: equal confidences
                obs_c = rng.choice(6, 3, replace=False)
                obs_f = np.full(3, f32(rng.choice([0.2, 0.3, 0.25])))
            else:
                obs_c = rng.choice(6, 3, replace=False) if rng.random() < 0.5 else \
                    np.array([1, 2, 3])
                obs_f = np.sort(rng.dirichlet([4, 1, 1, 1])[:3])[::-1].astype(np.float32)
            obs = [(int(c), f32(f)) for c, f in zip(obs_c, obs_f, strict=True)]
            if state is None:
                state = obs
                continue
            want = _reference_bayes(state, obs)
            c, f = _fuse("bayes", [c for c, _ in state], [v for _, v in state],
                         [c for c, _ in obs], [v for _, v in obs])
            assert c == [w[0] for w in want]
            assert f.tolist() == [float(w[1]) for w in want]
            state = list(zip(c, f.tolist(), strict=True))


# ------------------------------------------------------------------------------ voxel grid
def test_voxel_grid_averages_packed_colours_as_floats():
    voc = pack_rgb(voc_colormap(40))
    a, b = voc[5], voc[12]
    pts = np.array([[0.01, 0.01, 1.01], [0.02, 0.03, 1.02], [0.31, 0.0, 1.0]], np.float32)
    colours = np.array([[a], [b], [a]], np.uint32)
    conf = np.array([[0.9], [0.5], [0.7]], np.float32)
    fields = np.concatenate([colours.view(np.float32), conf], axis=1)
    rgb = np.array([[10, 20, 30], [11, 21, 31], [0, 0, 0]], np.uint8)
    cent, avg, crgb = k.voxel_grid(pts, f32(1) / f32(0.1), fields, rgb)
    assert len(cent) == 2
    mixed = np.ascontiguousarray(avg[:, :1]).view(np.uint32)[:, 0]
    # the float bits behave as an integer average: neither class's colour
    assert abs(int(mixed[0]) - (int(a) + int(b)) / 2) <= 1
    assert mixed[0] not in (a, b)
    assert mixed[1] == a  # a single point keeps its colour
    assert avg[0, 1] == f32(f32(f32(0.9) + f32(0.5)) / f32(2))
    assert crgb[0].tolist() == [10, 20, 30]  # (10 + 11) / 2 = 10.5, truncated
    assert np.array_equal(cent[0], (pts[0] + pts[1]) / f32(2))


def test_voxel_grid_output_order_is_pcls_leaf_index():
    # PCL's leaf index grows with x fastest, then y, then z
    pts = np.array([[0.05, 0.05, 0.25], [0.05, 0.25, 0.05], [0.25, 0.05, 0.05],
                    [0.05, 0.05, 0.05]], np.float32)
    cent, _, _ = k.voxel_grid(pts, f32(1) / f32(0.1), np.zeros((4, 0), np.float32),
                              np.zeros((4, 3), np.uint8))
    assert np.array_equal(cent, pts[[3, 2, 1, 0]])


# ------------------------------------------------------------------------------ the tree
def _pool(capacity=1 << 14, slots=3, default=1.0):
    state = np.array([-1, 0, 0], np.int64)
    return (state, np.full((capacity, 8), -1, np.int32), np.zeros(capacity, np.float32),
            np.full((capacity, 3), 255, np.uint8), np.full((capacity, slots), WHITE, np.uint32),
            np.full((capacity, slots), default, np.float32)), np.zeros(capacity, np.int64)


def test_node_pool_is_octomaps_update_node():
    """Random hits and misses, one updateNode each (lazy_eval false): the same tree as OctoMap's
    own OcTree - pruning, expansion, early abort on saturated voxels, inner max."""
    octomap = pytest.importorskip("octomap")
    rng = np.random.default_rng(3)
    res = 0.1
    ref = octomap.OcTree(res)
    pool, free = _pool()
    params = [f32(np.log(0.7 / 0.3)), f32(np.log(0.4 / 0.6)),
              f32(ref.getClampingThresMinLog()), f32(ref.getClampingThresMaxLog())]
    keys = rng.integers(0, 4, size=(3000, 3)) + KEY_OFFSET
    # long runs of misses (free space saturates and prunes) with hits mixed in
    hits = rng.random(3000) < np.where(np.arange(3000) % 600 < 400, 0.05, 0.7)
    for key, hit in zip(keys, hits, strict=True):
        ref.updateNode(((key - KEY_OFFSET + 0.5) * res).astype(np.float64), bool(hit), False)
    assert k.update_nodes(keys, hits, 0, *pool, free, *params, f32(1)) == len(keys)
    depth, kk, mask, value, *_ = k.export(*pool, True, f32(1))
    assert len(depth) == ref.size()
    assert int(np.count_nonzero(mask == 0)) == ref.getNumLeafNodes()
    ours = sorted((int(d), float(v)) for d, v, m in zip(depth, value, mask, strict=True)
                  if m == 0)
    theirs = sorted((int(leaf.getDepth()), float(leaf.getValue()))
                    for leaf in ref.begin_leafs())
    assert ours == theirs


def test_a_pruned_block_takes_an_observation_whole():
    pool, free = _pool()
    lo, hi = f32(-2.0), f32(3.5)
    keys = np.array([[KEY_OFFSET + x, KEY_OFFSET + y, KEY_OFFSET + z] for z in range(2)
                     for y in range(2) for x in range(2)], np.int64)
    for _ in range(10):  # 8 saturated free siblings: pruned into one node
        k.update_nodes(keys, np.zeros(8, bool), 0, *pool, free, f32(0.85), f32(-0.4), lo, hi,
                       f32(1))
    state, children = pool[0], pool[1]
    assert k.search(children, state[0], *keys[0]) == k.search(children, state[0], *keys[7])
    colour = np.array([[pack_rgb(voc_colormap(4))[3], WHITE, WHITE]], np.uint32)
    done = k.fuse_points(keys[:1], np.ones(1, bool), np.zeros((1, 3), np.uint8), colour,
                         np.array([[0.9, 0, 0]], np.float32), False, *pool, True)
    assert done == 1
    depth, _, mask, _, _, colours, _ = k.export(*pool, True, f32(1))
    leaves = mask == 0
    assert leaves.sum() == 1 and depth[leaves][0] == 15  # still one pruned node ...
    assert colours[leaves][0, 0] == colour[0, 0]  # ... now holding the class for all 8


def test_two_points_in_one_voxel_fuse_twice_in_order():
    pool, free = _pool()
    key = np.array([[KEY_OFFSET, KEY_OFFSET, KEY_OFFSET]], np.int64)
    k.update_nodes(key, np.ones(1, bool), 0, *pool, free, f32(0.85), f32(-0.4), f32(-2),
                   f32(3.5), f32(1))
    voc = pack_rgb(voc_colormap(8))
    obs_c = np.array([[voc[1], voc[2], voc[3]], [voc[2], voc[1], voc[4]]], np.uint32)
    obs_f = np.array([[0.5, 0.3, 0.1], [0.6, 0.2, 0.1]], np.float32)
    k.fuse_points(np.repeat(key, 2, 0), np.ones(2, bool), np.zeros((2, 3), np.uint8), obs_c,
                  obs_f, False, *pool, True)
    n = k.search(pool[1], pool[0][0], *key[0])
    c, f = _fuse("bayes", obs_c[0], obs_f[0], obs_c[1], obs_f[1])
    assert pool[4][n].tolist() == c and pool[5][n].tolist() == f.tolist()


# ------------------------------------------------------------------------------ frames
def _wall_frame(distance: float, label: int = 3) -> tuple[Frame, SemanticObservation]:
    h, w = 24, 32
    intr = Intrinsics(fx=20.0, fy=20.0, cx=w / 2, cy=h / 2, width=w, height=h)
    depth = np.full((h, w), distance, np.float32)
    frame = Frame(rgb=np.full((h, w, 3), 90, np.uint8), depth=depth, intrinsics=intr,
                  pose=np.eye(4), timestamp=0.0, name="wall")
    classes = np.stack([np.full((h, w), label), np.full((h, w), label + 1),
                        np.full((h, w), label + 2)], axis=-1).astype(np.int16)
    probs = np.broadcast_to(np.array([0.7, 0.2, 0.1], np.float32), (h, w, 3)).copy()
    return frame, SemanticObservation(classes=classes, probs=probs, num_classes=10)


def test_rays_are_cut_at_the_raycast_range():
    frame, obs = _wall_frame(3.0)
    m = UPDATERS.create("classic-semantic", resolution=0.1)
    m.integrate(frame, obs)
    axis = np.array([[0.05, 0.05, z] for z in np.arange(0.05, 3.2, 0.1)])
    state = m.query(axis).state
    z = axis[:, 2]
    assert np.all(state[(z > 0.2) & (z < 1.9)] == 0)  # free up to 2 m
    assert np.all(state[(z > 2.15) & (z < 2.95)] == -1)  # never cleared beyond it
    # the wall, a hit without a ray: 3 m at the node's resolution 0.1f (0.10000000149) is key
    # floor(29.9999995) = 29, the voxel below 3 m (with a double 0.1 it would be the one above)
    assert m.resolution == float(np.float32(0.1))
    assert state[np.argmin(np.abs(z - 2.95))] == 1
    # evsmap's classwise variant casts to max range, clearing the whole way
    c = UPDATERS.create("classic-semantic", resolution=0.1, front_end="direct")
    c.integrate(frame, obs)
    assert np.all(c.query(axis).state[(z > 0.2) & (z < 2.95)] == 0)


def test_points_beyond_max_range_are_not_inserted():
    frame, obs = _wall_frame(6.0)
    m = UPDATERS.create("classic-semantic", resolution=0.1)
    m.integrate(frame, obs)
    assert m.num_nodes == 0 and m.centroids > 0 and m.fusions == 0


def test_labels_read_back_through_the_colour_map():
    frame, obs = _wall_frame(1.5, label=6)
    m = UPDATERS.create("classic-semantic", resolution=0.1)
    m.integrate(frame, obs)
    q = m.query(np.array([[0.05, 0.05, 1.45]]))  # 1.5 m at 0.1f: the voxel below 1.5 m
    assert q.state[0] == 1 and q.label[0] == 6
    codes = np.array([WHITE, pack_rgb(voc_colormap(10))[4]], np.uint32)
    assert m.colour_classes(codes).tolist() == [-1, 4]


def test_published_file_opens_as_a_colour_octree(tmp_path):
    octomap = pytest.importorskip("octomap")
    frame, obs = _wall_frame(1.5, label=6)
    m = UPDATERS.create("classic-semantic", resolution=0.1)
    m.integrate(frame, obs)
    size = m.write(tmp_path / "p.ot", file_format="published")
    tree = octomap.ColorOcTree.read(str(tmp_path / "p.ot").encode())
    assert tree.size() == m.stats().nodes and size < m.write(tmp_path / "f.ot")
    seen = {tuple(int(v) for v in leaf.getColor()) for leaf in tree.begin_leafs()
            if leaf.getValue() > 0}
    assert seen == {tuple(voc_colormap(10)[6].tolist())}


def test_full_file_restores_and_mapping_continues(tmp_path):
    frames = [_wall_frame(d, label=2 + i % 3) for i, d in enumerate((1.2, 1.5, 2.5, 1.3))]
    a = UPDATERS.create("classic-semantic", resolution=0.1)
    for f, o in frames[:2]:
        a.integrate(f, o)
    a.write(tmp_path / "m.ot")
    b = UPDATERS.create("classic-semantic", resolution=0.1).restore(tmp_path / "m.ot")
    assert b.tree().identical(a.tree())
    for f, o in frames[2:]:
        a.integrate(f, o)
        b.integrate(f, o)
    assert b.tree().identical(a.tree())


def test_bad_options_are_one_clear_error():
    from evsmap.errors import InvalidDataError

    with pytest.raises(InvalidDataError, match="front_end"):
        UPDATERS.create("classic-semantic", front_end="pcl")
    with pytest.raises(InvalidDataError, match="raycast_range"):
        UPDATERS.create("classic-semantic", raycast_range=-1.0)
    with pytest.raises(InvalidDataError, match="discretize"):
        UPDATERS.create("classic-semantic-max", discretize=False)
    UPDATERS.create("classic-semantic", discretize=False, front_end="direct")


def test_unpack_inverts_pack():
    rgb = voc_colormap(40)
    assert np.array_equal(unpack_rgb(pack_rgb(rgb)), rgb)
    assert voc_colormap(3).tolist() == [[0, 0, 0], [128, 0, 0], [0, 128, 0]]


def test_parameters_reach_octomap_as_the_ros_node_rounds_them():
    # octomap_generator keeps them in float members and passes them through float setters
    m = UPDATERS.create("classic-semantic")
    assert m.resolution == 0.05000000074505806
    assert np.float32(m.params.hit_logodds) == np.float32(0.847297788)
    assert np.float32(m.params.clamp_max_logodds) == np.float32(3.47609973)
    assert m.max_range == float(np.float32(5.0)) and m.raycast_range == float(np.float32(2.0))


def test_voxel_grid_sums_a_leaf_in_pcls_sorted_order():
    from evsmap.mapping.stdsort import std_sort_order

    rng = np.random.default_rng(3)
    # 60 points in two leaves, interleaved: std::sort leaves each leaf's points in an order of
    # its own, and float sums of these values depend on it
    n = 60
    pts = np.empty((n, 3), np.float32)
    pts[:, 0] = np.where(np.arange(n) % 2 == 0, 0.01, 0.11) + rng.uniform(0, 0.08, n)
    pts[:, 1:] = rng.uniform(0.0, 0.0999, (n, 2)).astype(np.float32) + np.float32(1.0)
    pts = pts.astype(np.float32)
    none = np.zeros((n, 0), np.float32)
    rgb = np.zeros((n, 3), np.uint8)
    inv = f32(1) / f32(0.1)
    cent, _, _ = k.voxel_grid(pts, inv, none, rgb)
    idx = np.floor(pts[:, 0] * inv).astype(np.int64)
    order = std_sort_order(idx)
    for leaf, row in zip(np.unique(idx), cent, strict=True):
        acc = np.zeros(3, np.float32)
        members = order[idx[order] == leaf]
        for i in members:
            acc = (acc + pts[i]).astype(np.float32)
        assert np.array_equal(row, (acc / f32(len(members))).astype(np.float32))
    input_order, _, _ = k.voxel_grid(pts, inv, none, rgb, False)
    assert not np.array_equal(cent, input_order)  # the order shows in the last bits
