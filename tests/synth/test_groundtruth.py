import numpy as np

from evsmap.classes import NYU40
from evsmap.synth.groundtruth import ground_truth_voxels
from evsmap.synth.scene import Room, _Builder
from evsmap.synth.sequence import SyntheticSequence


def tiny_room() -> Room:
    b = _Builder("tiny", np.random.default_rng(0), (2.0, 2.0, 2.0))
    b.shell()
    b.box("picture", (1.0, 0.01, 1.0), (0.4, 0.02, 0.4))  # on the y=0 wall
    b.box("table", (1.05, 1.05, 0.475), (0.4, 0.4, 0.95))  # a block standing on the floor
    return b.room


def test_surfaces_hidden_by_other_parts_are_not_counted():
    room = tiny_room()
    vox = ground_truth_voxels(room, 0.1)
    label_at = {tuple(k): lab for k, lab in zip(vox.keys.tolist(), vox.labels.tolist(),
                                                strict=True)}
    # the wall voxel behind the picture centre holds the picture, not the wall
    assert label_at[(10, 0, 10)] == NYU40["picture"]
    # the table top is occupied; under its middle neither floor nor table bottom (hidden)
    assert label_at[(10, 10, 9)] == NYU40["table"]
    assert (10, 10, 0) not in label_at
    assert label_at[(3, 3, 0)] == NYU40["floor"]
    # an ordinary wall voxel and the ceiling
    assert label_at[(0, 5, 15)] == NYU40["wall"]
    assert label_at[(5, 5, int(np.floor(2.0 / 0.1)))] == NYU40["ceiling"]
    # nothing outside the interior and nothing in the open middle of the room
    assert vox.keys.min() >= -1 and vox.keys.max() <= 20
    assert (5, 5, 10) not in label_at


def test_counts_scale_with_resolution_and_cover_rendered_surfaces():
    seq = SyntheticSequence(scene="office", seed=2, frames=4, width=80, height=60)
    coarse, fine = seq.ground_truth(0.10), seq.ground_truth(0.05)
    assert 3.0 < len(fine) / len(coarse) < 5.0  # surfaces: ~4x per halving
    frame = seq[2]
    from evsmap.geometry import backproject

    pts = backproject(frame.depth, seq.intrinsics, frame.pose)
    keys = np.floor(pts / 0.05).astype(np.int64)
    known = {tuple(k) for k in fine.keys.tolist()}
    # a surface lying on a voxel boundary (walls at x = 0, the floor at z = 0) may fall on
    # either side of it in float32 depth, so a hit may be one voxel off along an axis
    offsets = [(0, 0, 0), (1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]
    hits = np.array([any((k[0] + a, k[1] + b, k[2] + c) in known for a, b, c in offsets)
                     for k in keys.tolist()])
    exact = np.array([tuple(k) in known for k in keys.tolist()])
    assert hits.mean() > 0.995
    assert exact.mean() > 0.6
