import numpy as np
import pytest

from evsmap.data import SemanticObservation
from evsmap.interfaces import OCCUPIED, UNKNOWN, MapStats, MapUpdater, PointQuery, Segmenter
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

    def write(self, path):
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
