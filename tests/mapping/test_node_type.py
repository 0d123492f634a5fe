"""Node types and their registry: checks at declaration, loud duplicates, reading ``.ot`` files
by id, and a custom node type through an updater's write / restore."""

from __future__ import annotations

import numpy as np
import pytest

from evsmap.errors import DataFormatError, DuplicateNameError, InvalidDataError, UnknownNameError
from evsmap.mapping.front_end import DirectScan
from evsmap.mapping.keys import pack
from evsmap.mapping.node_type import COLOR_OCTREE, NODE_TYPES, OCTREE, Column, NodeType
from evsmap.mapping.octree_io import read_ot, write_ot
from evsmap.mapping.tree import build_tree
from evsmap.registry import READERS, UPDATERS
from evsmap.updaters.base import OctreeUpdater

VISITS_ID = "TestVisitCountOcTree"


class VisitCounter(OctreeUpdater):
    """A tree whose node counts the frames that hit it; inner nodes hold the most visits."""

    def update_payload(self, scan: DirectScan) -> None:
        """Every hit voxel counts one more visit."""
        _, voxels, _ = self.endpoint_voxels(scan.points)
        self.map.payload("visits")[voxels] += 1

    def inner_payload(self, children: np.ndarray, group: np.ndarray,
                      n_groups: int) -> np.ndarray:
        out = np.zeros(n_groups, dtype=children.dtype)
        np.maximum.at(out, group, children)
        return out


@pytest.fixture
def visits():
    node_type = NODE_TYPES.add(NodeType(
        VISITS_ID, record=np.dtype("<u2"), columns=(Column("visits", np.uint16),),
        prune_on=("visits",), node_bytes=24, description="visits per voxel (test)"))
    yield node_type
    NODE_TYPES.remove(VISITS_ID)


@pytest.fixture(scope="module")
def frames():
    seq = READERS.create("synthetic", frames=3, width=120, height=90)
    return [seq.frame(i) for i in range(len(seq))]


def test_builtin_types_are_registered_by_their_ot_id():
    # an updater's module registers its node type when it is imported, which creating it does
    for name in ("multiclass-bayes", "classic-semantic", "classic-semantic-max"):
        for front_end in ("generator", "direct"):
            UPDATERS.create(name, front_end=front_end)
    assert NODE_TYPES.get("OcTree") is OCTREE and NODE_TYPES.get("ColorOcTree") is COLOR_OCTREE
    assert {"MultiClassBayesOcTree", "MultiClassBayesGeneratorOcTree", "SemanticOcTreeBayes",
            "SemanticOcTreeMax", "SemanticSlamOcTreeBayes",
            "SemanticSlamOcTreeMax"} <= set(NODE_TYPES.names())
    assert UPDATERS.create("orgb").node_type is COLOR_OCTREE
    assert UPDATERS.create("multiclass-bayes").tree_id == "MultiClassBayesGeneratorOcTree"
    assert UPDATERS.create("multiclass-bayes",
                           front_end="direct").tree_id == "MultiClassBayesOcTree"


def test_duplicate_id_raises_and_the_first_stays(visits):
    other = NodeType(VISITS_ID, description="another")
    with pytest.raises(DuplicateNameError, match=f"{VISITS_ID}.*already registered"):
        NODE_TYPES.add(other)
    assert NODE_TYPES.get(VISITS_ID) is visits
    NODE_TYPES.add(visits)  # the same object again is no conflict
    with pytest.raises(DuplicateNameError):
        NODE_TYPES.add(NodeType("ColorOcTree"))


def test_unknown_id_lists_the_known_ones():
    with pytest.raises(UnknownNameError, match=r"'NoSuchOcTree'.*known: .*ColorOcTree"):
        NODE_TYPES.get("NoSuchOcTree")


def test_reading_an_unknown_id_is_a_clear_error(tmp_path):
    codes = np.arange(8, dtype=np.int64)
    tree = build_tree(codes, np.zeros(8, np.float32), payload=np.arange(8, dtype=np.uint16))
    path = tmp_path / "x.ot"
    write_ot(path, tree, 0.1, tree_id="NoSuchOcTree")
    with pytest.raises(DataFormatError) as err:
        read_ot(path)
    message = str(err.value)
    assert "x.ot" in message and "'NoSuchOcTree'" in message and "ColorOcTree" in message
    assert "imported" in message  # says how a plug-in's type becomes known


@pytest.mark.parametrize("kwargs, match", [
    ({"tree_id": "two words"}, "one ASCII identifier"),
    ({"tree_id": "X", "columns": (Column("a", np.int8), Column("a", np.int8))}, "repeat"),
    ({"tree_id": "X", "label": "classes"}, "label names no column"),
    ({"tree_id": "X", "prune_on": ("c",)}, "prune_on names no column"),
    ({"tree_id": "X", "node_bytes": 0}, "node_bytes"),
    ({"tree_id": "X", "message_tree_id": "two words"}, "message_tree_id"),
])
def test_declaration_errors(kwargs, match):
    with pytest.raises(InvalidDataError, match=match):
        NodeType(**kwargs)


def test_default_codec_needs_matching_names():
    nt = NodeType("X", record=np.dtype([("a", "<i2"), ("b", "<f4")]),
                  columns=(Column("a", np.int16),))
    with pytest.raises(InvalidDataError, match="give it encode and decode"):
        nt.to_record({"a": np.zeros(2, np.int16)}, 2)


def test_custom_node_type_round_trips_through_write_and_restore(visits, frames, tmp_path):
    updater = VisitCounter(node_type=visits, resolution=0.1)
    assert updater.name == VISITS_ID and updater.tree_id == VISITS_ID
    assert not updater.uses_semantics
    for frame in frames:
        updater.integrate(frame)
    counts = updater.map.payload("visits")
    assert 1 <= counts.max() <= len(frames) and counts.min() == 0  # rays only: never hit
    assert (counts > 0).sum() > 1000
    path = tmp_path / "v.ot"
    size = updater.write(path)
    # the registry gives the reader the layout: 4 B value + 2 B visits + 1 B mask per node
    kind, resolution, tree = read_ot(path)
    assert (kind, resolution) == (VISITS_ID, 0.1)
    assert size == path.stat().st_size and tree.num_nodes == updater.stats().nodes
    assert tree.payload.dtype == np.uint16
    data = path.read_bytes()
    assert len(data) - data.index(b"data\n") - 5 == 7 * tree.num_nodes
    # inner nodes aggregate with the tree's rule: the max of their children
    assert tree.payload[0] == counts.max()
    # memory model: node_bytes per node
    stats = updater.stats()
    assert stats.octomap_memory_bytes == 320 + 24 * stats.nodes + 64 * (stats.nodes
                                                                         - stats.leaves)
    again = VisitCounter(node_type=visits, resolution=0.1).restore(path)
    assert np.array_equal(again.map.codes, updater.map.codes)
    assert np.array_equal(again.map.payload("visits"), counts)
    again.write(tmp_path / "again.ot")
    assert (tmp_path / "again.ot").read_bytes() == data
    # mapping continues from the restored state exactly as from the original
    updater.integrate(frames[0])
    again.integrate(frames[0])
    assert np.array_equal(again.map.payload("visits"), updater.map.payload("visits"))


def test_registered_types_pickle_by_id(visits):
    import pickle

    updater = UPDATERS.create("classic-semantic", front_end="direct")
    assert pickle.loads(pickle.dumps(updater)).node_type is updater.node_type
    assert pickle.loads(pickle.dumps(visits)) is visits
    with pytest.raises(TypeError, match="not registered"):
        pickle.dumps(NodeType("Unregistered"))


def test_restore_refuses_another_node_type(visits, frames, tmp_path):
    orgb = UPDATERS.create("orgb", resolution=0.1)
    orgb.integrate(frames[0])
    orgb.write(tmp_path / "c.ot")
    with pytest.raises(DataFormatError, match="a ColorOcTree file, not a TestVisitCountOcTree"):
        OctreeUpdater(node_type=visits, resolution=0.1).restore(tmp_path / "c.ot")


def test_pruning_compares_the_prune_on_columns(visits):
    updater = OctreeUpdater(node_type=visits, resolution=0.1)
    siblings = pack(np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)]))
    updater.map.insert_leaves(siblings + pack(np.array([[32768, 32768, 32768]])))
    assert updater.map.num_leaves == 8
    assert updater.stats().leaves == 1  # 8 equal leaves (value 0, visits 0) prune
    updater.map.payload("visits")[3] = 1
    assert updater.stats().leaves == 8


def test_a_node_type_is_data_its_rules_are_the_trees():
    """OctoMap's split: a node type holds data, codec and pruning predicate; the rules are the
    tree's (OctreeUpdater's typed methods)."""
    import dataclasses

    fields = {f.name for f in dataclasses.fields(NodeType)}
    assert not fields & {"update", "inner", "pruned", "publish", "message", "colour_only"}
    with pytest.raises(TypeError):
        NodeType("WithARule", update=lambda *a: None)


def test_evsmaps_own_node_types_read_by_id_in_a_fresh_interpreter(tmp_path):
    """A multiclass-bayes map's file reads by its id without the caller importing an updater
    module (it failed with "unknown tree id 'MultiClassBayesGeneratorOcTree'")."""
    import subprocess
    import sys

    updater = UPDATERS.create("multiclass-bayes", resolution=0.2)
    seq = READERS.create("synthetic", frames=1, width=60, height=45)
    frame = seq.frame(0)
    from evsmap.registry import SEGMENTERS

    updater.integrate(frame, SEGMENTERS.create("oracle").predict(frame))
    updater.write(tmp_path / "m.ot")
    code = ("import sys; from evsmap.mapping.octree_io import read_ot; "
            "kind, res, tree = read_ot(sys.argv[1]); "
            "assert 'evsmap.updaters.mcb_generator' not in sys.modules; "
            "print(kind, tree.payload.dtype.itemsize, tree.num_nodes)")
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path / "m.ot")],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    kind, itemsize, nodes = out.stdout.split()
    from evsmap.mapping.mcb_nodes import RECORD

    assert kind == "MultiClassBayesGeneratorOcTree" and int(itemsize) == RECORD.itemsize
    assert int(nodes) == updater.stats().nodes
    assert "MultiClassBayesOcTree" in NODE_TYPES and "MultiClassBayesOcTree" in NODE_TYPES.names()
