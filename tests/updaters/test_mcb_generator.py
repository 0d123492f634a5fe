"""multiclass-bayes on the octomap_generator front end: SSMI's node rules, the shared front end
with classic-semantic, pruning, files and memory as SSMI keeps them."""

from __future__ import annotations

import math

import numpy as np
import pytest

from evsmap.data import Frame, Intrinsics, SemanticObservation
from evsmap.errors import InvalidDataError
from evsmap.mapping.generator import WHITE, pack_rgb, voc_colormap
from evsmap.mapping.ssmi_kernel import LOGINIT, free, hit, tree_constants
from evsmap.registry import READERS, SEGMENTERS, UPDATERS

f32 = np.float32
PSI, PHI, LMIN, LMAX, MIN_OCC = tree_constants(psi=1.0, phi=-0.1, clamp_min=1e-4,
                                               clamp_max=0.9999)


def _node(n=1):
    return (np.full((n, 3), WHITE, np.uint32), np.full((n, 3), LOGINIT, np.float32),
            np.full(n, LOGINIT, np.float32), np.zeros(n, np.float32),
            np.full((n, 3), 255, np.uint8))


def _hit(state, obs, rgb=(10, 20, 30)):
    return hit(*state, 0, np.uint32(obs), np.uint8(rgb[0]), np.uint8(rgb[1]), np.uint8(rgb[2]),
               PSI, PHI, LMIN, LMAX)


def _occ(cols, lo, others):
    # getOccFromSem with glibc's expf/logf (math.exp rounded to float equals expf here)
    occ = f32(math.exp(others))
    for c, v in zip(cols, lo, strict=True):
        if c != WHITE:
            occ = f32(occ + f32(math.exp(v)))
    return f32(math.log(occ))


def test_constants_are_ssmis_floats():
    assert LMIN == f32(math.log(f32(1e-4) / (1 - f32(1e-4))))
    assert MIN_OCC == f32(math.log(4.0) + float(LMIN))
    assert PSI == f32(1.0) and PHI == f32(-0.1)


def test_first_hit_is_init_semantics_then_fuse_obs():
    s = _node()
    assert _hit(s, 7)
    cols, lo, others, value, rgb = s
    first = f32(f32(f32(math.log(0.1)) + f32(0)) + PSI)
    rest = f32(f32(f32(math.log(0.9)) + f32(0)) + PHI)
    assert cols[0].tolist() == [7, WHITE, WHITE] and lo[0, 0] == first and others[0] == rest
    assert lo[0, 1] == LOGINIT and value[0] == _occ(cols[0], lo[0], others[0])
    assert rgb[0].tolist() == [10, 20, 30]
    # a second class enters from the pre-update others: others + log 0.8 + psi, unsorted
    _hit(s, 9, rgb=(30, 40, 50))
    entering = f32(f32(rest + f32(math.log(0.8))) + PSI)
    expected_first = f32(first + PHI)
    assert set(cols[0, :2].tolist()) == {7, 9}
    by_class = dict(zip(cols[0, :2].tolist(), lo[0, :2].tolist(), strict=True))
    assert by_class[9] == entering and by_class[7] == expected_first
    assert lo[0, 0] >= lo[0, 1]  # most likely first
    assert others[0] == f32(rest + f32(f32(math.log(0.2)) + PHI))
    assert rgb[0].tolist() == [20, 30, 40]  # averageNodeColor: (prev + new) / 2


def test_a_fourth_class_folds_the_weakest_into_others():
    s = _node()
    for c in (1, 2, 3):
        _hit(s, c)
    cols, lo, others, value, _ = s
    before = (cols[0].copy(), lo[0].copy(), others[0])
    _hit(s, 4)
    assert len(set(cols[0].tolist())) == 3 and WHITE not in cols[0]
    # the dropped entry went into others by log(exp(others) + exp(l)), then clamped
    assert others[0] > before[2] + f32(math.log(0.2)) - 0.2


def test_saturated_hit_changes_nothing_and_free_floors():
    s = _node()
    cols, lo, others, value, rgb = s
    cols[0] = [5, WHITE, WHITE]
    lo[0] = [LMAX, LMIN, LMIN]
    others[0] = LMIN
    value[0] = _occ(cols[0], lo[0], others[0])
    assert not _hit(s, 5) and rgb[0].tolist() == [255, 255, 255]
    # misses: phi on every set entry and others, floored; colour averaged with white
    s2 = _node()
    _hit(s2, 3, rgb=(0, 0, 0))
    assert free(*s2, 0, PHI, LMIN, MIN_OCC)
    assert s2[4][0].tolist() == [127, 127, 127]
    # a node without semantics: value + phi floored at minOccupancyLogOdds, then no change
    s3 = _node()
    for _ in range(200):
        free(*s3, 0, PHI, LMIN, MIN_OCC)
    assert s3[3][0] == MIN_OCC and not free(*s3, 0, PHI, LMIN, MIN_OCC)


def _frames(n=4):
    seq = READERS.create("synthetic", frames=n, width=96, height=72)
    oracle = SEGMENTERS.create("oracle")
    return [(f, oracle.predict(f)) for f in seq]


def test_same_front_end_and_counts_as_classic_semantic():
    frames = _frames()
    for front_end in ("generator", "direct"):
        maps = [UPDATERS.create(n, front_end=front_end, resolution=0.05)
                for n in ("multiclass-bayes", "classic-semantic")]
        for m in maps:
            for f, o in frames:
                m.integrate(f, o)
        assert {m.front_end for m in maps} == {front_end}
        counts = [m.front_end_counts() for m in maps]
        assert counts[0] == counts[1] and len(counts[0]["centroids"]) == len(frames)


def test_colour_file_opens_in_octomap_with_the_node_count(tmp_path):
    octomap = pytest.importorskip("octomap")
    m = UPDATERS.create("multiclass-bayes", resolution=0.05)
    for f, o in _frames():
        m.integrate(f, o)
    stats = m.stats()
    path = tmp_path / "colour.ot"
    m.write(path, file_format="colour")
    tree = octomap.ColorOcTree.read(str(path).encode())
    assert tree.size() == stats.nodes
    palette = {tuple(c) for c in voc_colormap(256).tolist()}
    occupied = {tuple(int(v) for v in leaf.getColor()) for leaf in tree.begin_leafs()
                if leaf.getValue() > 0}
    assert len(occupied & palette) >= 3  # class colours (and a few averaged ones)
    # the saved file is SSMI's: setWriteSemantics(false) before its shutdown write, so the
    # colour file byte for byte
    pub = tmp_path / "published.ot"
    m.write(pub, file_format="published")
    assert pub.read_bytes() == path.read_bytes()
    # the octomap_full message's nodes: 36 B a node (35 + the child mask), under its own id
    msg = tmp_path / "message.ot"
    n_bytes = m.write(msg, file_format="message")
    header = msg.read_bytes().split(b"data\n", 1)[0]
    assert b"id SSMISemanticOcTreeMessage" in header
    assert n_bytes - len(header) - 5 == 36 * stats.nodes
    assert stats.octomap_memory_bytes == 320 + 48 * stats.nodes + 64 * (stats.nodes
                                                                        - stats.leaves)


def test_full_file_restores_and_mapping_continues(tmp_path):
    m = UPDATERS.create("multiclass-bayes", resolution=0.05)
    frames = _frames(3)
    for f, o in frames:
        m.integrate(f, o)
    path = tmp_path / "full.ot"
    m.write(path)
    again = UPDATERS.create("multiclass-bayes", resolution=0.05).restore(path)
    assert again.stats() == m.stats()
    # the file holds colours; the class count comes with the next observation
    m.integrate(*frames[0])
    again.integrate(*frames[0])
    codes, labels = m.occupied_labels()
    codes2, labels2 = again.occupied_labels()
    assert np.array_equal(codes, codes2) and np.array_equal(labels, labels2)
    assert (labels >= 0).mean() > 0.5  # most occupied voxels carry a class of the colour map


def test_free_blocks_prune_whatever_their_semantics():
    m = UPDATERS.create("multiclass-bayes", resolution=0.05)
    for f, o in _frames(2):
        m.integrate(f, o)
    mp = m.map
    mp.payload("sem_colors")[:, 0] = np.arange(mp.num_leaves) % 7  # semantics all differ
    mp.logodds_for_writing()[:] = m.min_occupancy  # every leaf free, the same value
    free_nodes = m.stats().nodes
    mp.logodds_for_writing()[:] = m.min_occupancy + np.float32(0.5)  # same value, not free
    busy_nodes = m.stats().nodes
    mp.payload("sem_colors")[:] = [3, WHITE, WHITE]  # same value and semantics
    mp.payload("class_logodds")[:] = [1.0, LOGINIT, LOGINIT]
    mp.payload("others")[:] = -2.0
    same_nodes = m.stats().nodes
    assert free_nodes == same_nodes < busy_nodes


def test_generator_only_options_are_one_clear_error():
    with pytest.raises(InvalidDataError, match="front_end=direct only"):
        UPDATERS.create("multiclass-bayes", leaf_update="average")
    with pytest.raises(InvalidDataError, match="front_end must be one of"):
        UPDATERS.create("multiclass-bayes", front_end="voxel")


def test_a_mixed_leaf_keeps_its_averaged_colour_as_a_class():
    # two classes in one voxel: PCL averages the packed colours, SSMI stores the result
    h, w = 8, 8
    intr = Intrinsics(fx=8.0, fy=8.0, cx=w / 2, cy=h / 2, width=w, height=h)
    depth = np.full((h, w), 1.0, np.float32)
    frame = Frame(rgb=np.full((h, w, 3), 50, np.uint8), depth=depth, intrinsics=intr,
                  pose=np.eye(4), timestamp=0.0, name="mixed")
    classes = np.zeros((h, w, 1), np.int16)
    classes[:, ::2] = 5
    classes[:, 1::2] = 12
    obs = SemanticObservation(classes=classes, probs=np.ones((h, w, 1), np.float32),
                              num_classes=20)
    m = UPDATERS.create("multiclass-bayes", resolution=2.0)  # one voxel holds every point
    m.integrate(frame, obs)
    palette = pack_rgb(voc_colormap(20))
    stored = set(m.map.payload("sem_colors")[:, 0].tolist()) - {WHITE}
    assert stored and not stored & {int(palette[5]), int(palette[12])}
    assert set(m.map.payload("classes")[:, 0].tolist()) <= {-1}


_READ_IN_OCTOMAP = """
import sys, octomap
tree = octomap.ColorOcTree.read(sys.argv[1].encode())
print("none" if tree is None else tree.size())
"""


def test_octomap_refuses_the_message_file_and_evsmap_reads_it(tmp_path):
    """No .ot claims a tree id whose node layout it lacks: OctoMap's reader gets an id it does
    not know (and says so) instead of 36-byte nodes under ``ColorOcTree`` (a crash)."""
    import subprocess
    import sys

    pytest.importorskip("octomap")
    from evsmap.mapping.octree_io import read_ot
    from evsmap.updaters.mcb_generator import MESSAGE_TREE_ID

    m = UPDATERS.create("multiclass-bayes", resolution=0.05)
    for f, o in _frames(2):
        m.integrate(f, o)
    path = tmp_path / "message.ot"
    m.write(path, file_format="message")
    run = subprocess.run([sys.executable, "-c", _READ_IN_OCTOMAP, str(path)],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode >= 0, f"octomap's reader crashed (signal {-run.returncode})"
    assert "none" in run.stdout or run.returncode != 0
    tree_id, _, tree = read_ot(path)
    assert tree_id == MESSAGE_TREE_ID and tree.num_nodes == m.stats().nodes


def test_only_ssmi_sends_a_message_other_than_its_file(tmp_path):
    m = UPDATERS.create("classic-semantic", resolution=0.05)
    with pytest.raises(InvalidDataError, match="no map message"):
        m.write(tmp_path / "m.ot", file_format="message")
