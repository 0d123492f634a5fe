import numpy as np
import pytest

from evsmap.data import SemanticObservation
from evsmap.interfaces import (
    OCCUPIED,
    UNKNOWN,
    MapStats,
    MapUpdater,
    PointQuery,
    Segmenter,
    check_file_format,
)
from evsmap.registry import Registry, get_reader


class DepthBands(Segmenter):
    """Labels pixels by depth band: a segmenter that is not a network."""

    num_classes = 4
    class_names = ("near", "mid", "far", "none")

    @property
    def module(self):
        return None

    def predict(self, frame, *, k=3):
        band = np.clip((frame.depth // 1.5).astype(np.int64), 0, 2)
        band[frame.depth == 0] = 3
        onehot = np.eye(self.num_classes, dtype=np.float32)[band]
        return SemanticObservation.from_probabilities(onehot, k=k)


class VoxelSet(MapUpdater):
    """Remembers which voxels received an endpoint."""

    uses_semantics = True

    def __init__(self, *, resolution: float = 0.1):
        self.resolution = resolution
        self.cells: dict[tuple, int] = {}

    def integrate(self, frame, observation=None):
        from evsmap.geometry import backproject

        pts = backproject(frame.depth, frame.intrinsics, frame.pose)
        keys = np.floor(pts / self.resolution).astype(np.int64)
        labels = observation.argmax[frame.depth > 0] if observation is not None else None
        for i, key in enumerate(map(tuple, keys.tolist())):
            self.cells[key] = int(labels[i]) if labels is not None else -1

    def stats(self):
        return MapStats(nodes=len(self.cells), leaves=len(self.cells),
                        octomap_memory_bytes=32 * len(self.cells))

    def write(self, path, file_format="full"):
        check_file_format(self, file_format)
        data = np.array([(*k, v) for k, v in self.cells.items()], dtype=np.int64)
        np.save(path, data)
        return path.stat().st_size

    def query(self, points):
        keys = np.floor(np.asarray(points) / self.resolution).astype(np.int64)
        found = [self.cells.get(tuple(k)) for k in keys.tolist()]
        state = np.array([UNKNOWN if f is None else OCCUPIED for f in found], np.int8)
        label = np.array([-1 if f is None else f for f in found], np.int16)
        prob = np.where(state == OCCUPIED, 1.0, np.nan).astype(np.float32)
        return PointQuery(state, prob, label)


def test_interfaces_compose_through_a_registry(tmp_path):
    segs, upds = Registry("segmenter"), Registry("updater")
    segs.add("depth-bands", lambda *, scale=1.0: DepthBands())
    upds.add("voxel-set", VoxelSet)
    seq = get_reader("synthetic", frames=2, width=40, height=30)
    seg, upd = segs.create("depth-bands"), upds.create("voxel-set", resolution=0.2)
    for frame in seq:
        upd.integrate(frame, seg(frame))
    assert upd.stats().nodes > 10
    size = upd.write(tmp_path / "map.npy")
    assert size == (tmp_path / "map.npy").stat().st_size
    frame = seq[0]
    from evsmap.geometry import backproject

    pts = backproject(frame.depth, frame.intrinsics, frame.pose)[:5]
    q = upd.query(np.vstack([pts, [[100.0, 100.0, 100.0]]]))
    assert (q.state[:5] == OCCUPIED).all() and q.state[5] == UNKNOWN
    assert np.isnan(q.probability[5]) and q.label[5] == -1


def test_incomplete_plugins_cannot_be_built():
    class Half(Segmenter):
        num_classes = 1
        class_names = ("x",)

    with pytest.raises(TypeError, match="abstract"):
        Half()


def test_a_segmenter_that_is_not_a_network_says_so_through_the_interface():
    from evsmap.errors import InvalidDataError

    seg = DepthBands()
    assert (seg.weights, seg.backend, seg.default_size, seg.input_names) == \
        (None, "torch", None, ())
    assert dict(seg.last_timings) == {}
    with pytest.raises(InvalidDataError, match="DepthBands is not a network"):
        seg.example_inputs(48, 64)


def test_a_network_segmenter_fills_the_interface():
    from evsmap.registry import get_segmenter

    seg = get_segmenter("feagnet-v1")
    assert seg.default_size == (480, 640) and seg.input_names == ("rgb", "depth")
    rgb, depth = seg.example_inputs(24, 32)
    assert tuple(rgb.shape) == (1, 3, 24, 32) and tuple(depth.shape) == (1, 1, 24, 32)
    outdoor = get_segmenter("feagnet-s")  # Cityscapes: RGB only, 512 x 1024
    assert outdoor.default_size == (512, 1024) and outdoor.input_names == ("rgb",)


def test_updaters_without_a_leaf_map_refuse_the_leaf_queries():
    from evsmap.errors import InvalidDataError

    updater = VoxelSet()
    assert updater.has_leaf_map is False and updater.memory_nbytes() is None
    with pytest.raises(InvalidDataError, match="VoxelSet exposes no leaf map"):
        updater.occupied_labels()


def test_an_octree_updater_measures_its_own_arrays(tmp_path):
    from evsmap.registry import get_updater

    seq = get_reader("synthetic", frames=2, width=64, height=48)
    updater = get_updater("orgb", resolution=0.1)
    for frame in seq:
        updater.integrate(frame)
    m = updater.map
    expected = m.codes.nbytes + m.logodds.nbytes + sum(m.payload(n).nbytes
                                                       for n in m.payload_names)
    assert updater.has_leaf_map and updater.memory_nbytes() == expected > 0
    codes, labels = updater.occupied_labels()
    assert len(codes) == len(labels) > 0


def test_sequence_metadata_is_typed():
    from evsmap.data import FrameList, Intrinsics

    seq = get_reader("synthetic", frames=1, width=64, height=48)
    assert seq.has_poses and seq.num_classes == len(seq.class_names) == 40
    bare = FrameList("x", Intrinsics(fx=50, fy=50, cx=32, cy=24, width=64, height=48), [])
    assert bare.has_poses and bare.class_names == () and bare.num_classes is None
    bare.meta["poses"] = False  # what a segmentation dataset's reader sets
    assert not bare.has_poses


def test_mapping_refuses_a_sequence_without_poses():
    from evsmap.data import FrameList, Intrinsics
    from evsmap.errors import EvsmapError
    from evsmap.measure.mapping import map_sequence

    seq = FrameList("stills", Intrinsics(fx=50, fy=50, cx=32, cy=24, width=64, height=48), [],
                    meta={"poses": False, "layout": "nyuv2"})
    with pytest.raises(EvsmapError, match="stills: nyuv2 has no camera poses"):
        map_sequence(seq, VoxelSet(), updater_name="voxel-set")


def test_every_updater_takes_a_file_format_and_refuses_one_it_cannot_write(tmp_path):
    from evsmap.errors import InvalidDataError
    from evsmap.measure.evaluators import write_map

    updater = VoxelSet()
    assert write_map(updater, tmp_path / "p.npy", "published") == \
        (tmp_path / "p.npy").stat().st_size
    with pytest.raises(InvalidDataError, match="VoxelSet writes no colour file"):
        updater.write(tmp_path / "c.npy", "colour")
    with pytest.raises(InvalidDataError, match="file format must be one of"):
        write_map(updater, tmp_path / "x.npy", "png")


def test_map_statistics_come_from_the_interface():
    updater = VoxelSet()
    assert updater.pruned_share() is None and updater.occupied_voxels() is None
