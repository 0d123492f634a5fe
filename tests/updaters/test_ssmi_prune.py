"""multiclass-bayes (generator) prunes and expands as SSMI's tree does: checked against a
transcription of ``SemanticOcTree::updateNode`` / ``updateNodeRecurs`` / ``pruneNode`` /
``expandNode`` (SSMI-Mapping, ``SemanticOcTree.hxx``) on a node tree, voxel by voxel."""

from __future__ import annotations

import numpy as np
import pytest

from evsmap.errors import InvalidDataError
from evsmap.mapping.generator import WHITE
from evsmap.mapping.keys import TREE_DEPTH, pack, unpack
from evsmap.mapping.ssmi_kernel import LOGINIT, free, hit
from evsmap.registry import UPDATERS

# SSMI's clamping tightened so that free space saturates (and prunes) within a few frames
OPTIONS = {"clamp_min": 0.192, "clamp_max": 0.97}
BASE = 32768


class _Node:
    """An SSMI node: value, colour, semantics; ``children`` None or a list of 8."""

    def __init__(self, data=None):
        self.data = data if data is not None else {
            "value": np.float32(0), "cols": np.full(3, WHITE, np.uint32),
            "lo": np.full(3, LOGINIT, np.float32), "others": np.float32(LOGINIT),
            "rgb": np.full(3, 255, np.uint8)}
        self.children = None

    def copy_data(self):
        return {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in self.data.items()}


def _rows(data):
    return (data["cols"][None].copy(), data["lo"][None].copy(),
            np.array([data["others"]], np.float32), np.array([data["value"]], np.float32),
            data["rgb"][None].copy())


def _back(rows):
    cols, lo, others, value, rgb = rows
    return {"value": value[0], "cols": cols[0], "lo": lo[0], "others": others[0], "rgb": rgb[0]}


class _SSMITree:
    """SemanticOcTree's update, expansion and pruning, node by node (leaf data rules: the
    compiled ``hit`` / ``free``, checked against the C++ elsewhere)."""

    def __init__(self, u):
        self.u = u
        self.root = None

    def _pos(self, key, depth):
        bit = TREE_DEPTH - 1 - depth
        return ((key[0] >> bit) & 1) | (((key[1] >> bit) & 1) << 1) | (((key[2] >> bit) & 1) << 2)

    def search(self, key):
        """The node holding ``key`` and its depth, or (None, -1)."""
        n = self.root
        for d in range(TREE_DEPTH):
            if n is None:
                return None, -1
            if n.children is None:
                return n, d
            n = n.children[self._pos(key, d)]
        return n, (TREE_DEPTH if n is not None else -1)

    def update(self, key, occupied, obs=WHITE, rgb=(255, 255, 255)):
        found, _ = self.search(key)
        rows = _rows(found.data if found is not None else _Node().data)
        u = self.u
        if occupied:
            changed = hit(*rows, 0, np.uint32(obs), *rgb, u.psi, u.phi, u.min_logodds,
                          u.max_logodds)
        else:
            changed = free(*rows, 0, u.phi, u.min_logodds, u.min_occupancy)
        if found is not None and not changed:
            return  # checkNeedsUpdate: no change
        created = self.root is None
        if created:
            self.root = _Node()
        self._recurs(self.root, created, key, 0, _back(rows))

    def _recurs(self, node, just_created, key, depth, leaf_data):
        if depth == TREE_DEPTH:
            node.data = leaf_data
            return
        pos = self._pos(key, depth)
        created = False
        if node.children is None or node.children[pos] is None:
            if node.children is None and not just_created:  # expandNode
                node.children = [_Node(node.copy_data()) for _ in range(8)]
            else:
                if node.children is None:
                    node.children = [None] * 8
                node.children[pos] = _Node()
                created = True
        self._recurs(node.children[pos], created, key, depth + 1, leaf_data)
        self._prune(node)

    def _prune(self, node):
        kids = node.children
        if kids is None or any(k is None or k.children is not None for k in kids):
            return
        first = kids[0].data
        first_free = first["value"] <= self.u.min_occupancy
        for k in kids[1:]:
            d = k.data
            same = (np.array_equal(d["cols"], first["cols"])
                    and np.array_equal(d["lo"], first["lo"]) and d["others"] == first["others"])
            if d["value"] != first["value"] or not (same or first_free):
                return
        node.data = kids[0].copy_data()
        if (node.data["rgb"] != 255).any():
            set_ = [k.data["rgb"].astype(np.int64) for k in kids if (k.data["rgb"] != 255).any()]
            node.data["rgb"] = (sum(set_) // len(set_)).astype(np.uint8)
        node.children = None


def _frames(rng, n_frames, side):
    """Frame 0 hits every voxel of the lower half in x once (random classes and colours); free
    space then saturates it in 2 misses and the upper half in 1, so blocks of equal values
    prune at 1 and 2 levels, each leaf of the lower half with its own colour; from frame 10 on,
    a few hits land anywhere and expand what was pruned."""
    region = np.stack(np.meshgrid(*[np.arange(side)] * 3, indexing="ij"), -1).reshape(-1, 3)
    region = region + BASE
    lower = region[region[:, 0] < BASE + side // 2]
    classes = np.array([0x800000, 0x008000], np.uint32)
    for f in range(n_frames):
        if f == 0:
            hits = lower
        elif f >= 10 and f % 3 == 0:
            hits = region[rng.integers(0, len(region), int(rng.integers(1, 3)))]
        else:
            hits = region[:0]
        colours = classes[rng.integers(0, 2, len(hits))]
        rgb = rng.integers(0, 255, (len(hits), 3)).astype(np.uint8)
        free_keys = region[rng.random(len(region)) < 0.8]
        free_codes = np.setdiff1d(pack(free_keys), pack(hits))
        yield pack(hits), colours, rgb, free_codes


def _compare(u, ref):
    m = u.map
    keys = unpack(m.codes)
    level = m.payload("pruned_level")
    for i, key in enumerate(keys):
        node, depth = ref.search(tuple(int(k) for k in key))
        d = node.data
        assert level[i] == TREE_DEPTH - depth, f"voxel {key}: held {level[i]} levels up"
        assert np.float32(m.logodds[i]).tobytes() == np.float32(d["value"]).tobytes()
        assert np.array_equal(m.payload("sem_colors")[i], d["cols"])
        assert m.payload("class_logodds")[i].tobytes() == d["lo"].tobytes()
        assert m.payload("others")[i] == d["others"]
        assert np.array_equal(m.payload("rgb")[i], d["rgb"]), f"voxel {key}: colour"


def _run(pruned_leaves, seed, n_frames=30, side=8):
    u = UPDATERS.create("multiclass-bayes", pruned_leaves=pruned_leaves, **OPTIONS)
    ref = _SSMITree(u)
    rng = np.random.default_rng(seed)
    for hit_codes, colours, rgb, free_codes in _frames(rng, n_frames, side):
        u.apply_updates(hit_codes, colours, rgb, free_codes)
        for code, c, r in zip(unpack(hit_codes), colours, rgb, strict=True):
            ref.update(tuple(int(k) for k in code), True, int(c), tuple(int(v) for v in r))
        for code in unpack(free_codes):
            ref.update(tuple(int(k) for k in code), False)
        yield u, ref


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_leaves_equal_ssmis_tree_after_every_frame(seed):
    levels = set()
    for u, ref in _run("copies", seed):
        _compare(u, ref)
        levels.update(np.unique(u.map.payload("pruned_level")).tolist())
    assert {1, 2} <= levels, "the case prunes blocks of 8 and of 64 leaves"


def test_keeping_each_leafs_own_colour_is_another_map():
    differs = False
    for u, ref in _run("own", 0):
        try:
            _compare(u, ref)
        except AssertionError:
            differs = True
            break
    assert differs


def test_pruned_levels_come_back_with_a_restored_map(tmp_path):
    *_, (u, _) = _run("copies", 1, n_frames=25)
    u.write(tmp_path / "m.ot")
    again = UPDATERS.create("multiclass-bayes", **OPTIONS).restore(tmp_path / "m.ot")
    assert np.array_equal(again.map.codes, u.map.codes)
    assert np.array_equal(again.map.payload("pruned_level"), u.map.payload("pruned_level"))
    assert np.array_equal(again.map.payload("rgb"), u.map.payload("rgb"))


def test_pruned_leaves_is_checked():
    with pytest.raises(InvalidDataError, match="pruned_leaves"):
        UPDATERS.create("multiclass-bayes", pruned_leaves="average")
