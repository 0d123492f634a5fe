import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from evsmap.errors import DataFormatError, EvsmapError
from evsmap.readers.tum import TUM_CAMERAS, TumSequence, associate, read_list, write_tum
from evsmap.synth.sequence import SyntheticSequence


def test_real_fr1_xyz_frames(tum_dir):
    seq = TumSequence(path=tum_dir)
    assert seq.intrinsics == TUM_CAMERAS["fr1"]
    # 37 depth and 37 RGB images; one depth image has its only free RGB partner 0.0202 s away
    # (beyond the 0.02 s tolerance) once the others are matched one-to-one, so 36 frames.
    assert seq.meta["listed_depth"] == 37 and seq.meta["listed_rgb"] == 37
    assert len(seq) == 36
    assert seq.meta["dropped"] == {"no_rgb_within_tolerance": 1, "no_pose": 0}
    assert len(TumSequence(path=tum_dir, max_time_difference=0.021)) == 37
    # TUM's own greedy associate.py strands more frames on this stretch
    assert len(TumSequence(path=tum_dir, association="greedy")) == 32

    gt = np.array([[float(v) for v in row] for row in read_list(tum_dir / "groundtruth.txt", 8)])
    lo, hi = gt[:, 1:4].min(axis=0), gt[:, 1:4].max(axis=0)
    for frame in seq:
        assert frame.rgb.shape == (480, 640, 3) and frame.depth.shape == (480, 640)
        valid = frame.depth[frame.depth > 0]
        assert valid.size > 0.5 * frame.depth.size
        assert 0.3 < valid.min() and valid.max() < 10.0  # Kinect v1 range
        assert np.all(frame.pose[:3, 3] >= lo - 1e-9) and np.all(frame.pose[:3, 3] <= hi + 1e-9)
        # interpolated between the two bracketing motion-capture samples
        k = np.searchsorted(gt[:, 0], frame.timestamp)
        a, b = gt[k - 1, 1:4], gt[k, 1:4]
        assert np.all(frame.pose[:3, 3] >= np.minimum(a, b) - 1e-12)
        assert np.all(frame.pose[:3, 3] <= np.maximum(a, b) + 1e-12)


def test_association_optimal_vs_greedy():
    depth = np.array([0.0, 1.0, 2.0])
    rgb = np.array([0.6, 1.45, 2.55])
    # well separated: both methods give the diagonal
    assert associate(depth, rgb, 0.7) == [(0, 0), (1, 1), (2, 2)]
    # greedy takes the closest pair (1 <-> 0.9) and strands depth 0
    depth = np.array([0.0, 1.0])
    rgb = np.array([0.9, 1.7])
    assert associate(depth, rgb, 1.0, method="greedy") == [(1, 0)]
    assert associate(depth, rgb, 1.0) == [(0, 0), (1, 1)]
    with pytest.raises(EvsmapError, match="association method"):
        associate(depth, rgb, 1.0, method="hungarian")


def test_synth_round_trip_is_exact(tmp_path):
    seq = SyntheticSequence(scene="bedroom", seed=4, frames=5, width=96, height=72, noise=True)
    write_tum(seq, tmp_path, quaternions=seq.quaternions)
    back = TumSequence(path=tmp_path)
    assert back.meta["has_labels"] and len(back) == len(seq)
    assert back.intrinsics == seq.intrinsics
    for a, b in zip(seq, back, strict=True):
        np.testing.assert_array_equal(a.depth, b.depth)
        np.testing.assert_array_equal(a.labels, b.labels)
        np.testing.assert_array_equal(a.pose, b.pose)
        np.testing.assert_array_equal(a.rgb, b.rgb)
        assert a.timestamp == b.timestamp


@pytest.fixture
def small_tum(tmp_path, tum_dir) -> Path:
    """A copy of the first 4 real frames under a freiburg1-style name."""
    root = tmp_path / "rgbd_dataset_freiburg1_test"
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    for name in ("rgb.txt", "depth.txt"):
        rows = read_list(tum_dir / name, 2)[:4]
        (root / name).write_text("# header\n" + "".join(f"{t} {p}\n" for t, p in rows))
        for _, p in rows:
            shutil.copy(tum_dir / p, root / p)
    shutil.copy(tum_dir / "groundtruth.txt", root / "groundtruth.txt")
    return root


def test_bad_inputs_are_named(small_tum):
    assert len(TumSequence(path=small_tum)) >= 3
    depth_file = sorted((small_tum / "depth").iterdir())[0]
    Image.fromarray(np.zeros((480, 640), np.uint8)).save(depth_file)
    seq = TumSequence(path=small_tum)
    with pytest.raises(DataFormatError, match=rf"{depth_file.name}.*16-bit"):
        seq[0]
    depth_file.write_bytes(b"\x89PNG not really")
    with pytest.raises(DataFormatError, match=rf"{depth_file.name}.*corrupt"):
        seq[0]
    (small_tum / "groundtruth.txt").write_text("# nothing\n")
    with pytest.raises(DataFormatError, match="groundtruth.txt: no poses"):
        TumSequence(path=small_tum)
    (small_tum / "groundtruth.txt").write_text("1.0 2.0 3.0\n")
    with pytest.raises(DataFormatError, match=r"groundtruth.txt:1: expected 8 fields"):
        TumSequence(path=small_tum)
    (small_tum / "groundtruth.txt").write_text("1.0 0 0 0 0 0 x 1\n")
    with pytest.raises(DataFormatError, match=r"groundtruth.txt: pose row 1 .* not 8 numbers"):
        TumSequence(path=small_tum)
    (small_tum / "groundtruth.txt").write_text("1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 0 0\n")
    with pytest.raises(DataFormatError, match=r"pose row 2 .* zero quaternion"):
        TumSequence(path=small_tum)
    (small_tum / "groundtruth.txt").unlink()
    with pytest.raises(DataFormatError, match="groundtruth.txt: file not found"):
        TumSequence(path=small_tum)


def test_poses_outside_groundtruth_are_dropped(small_tum):
    rows = read_list(small_tum / "groundtruth.txt", 8)
    first_depth = float(read_list(small_tum / "depth.txt", 2)[0][0])
    later = [r for r in rows if float(r[0]) > first_depth + 0.01]
    (small_tum / "groundtruth.txt").write_text("".join(" ".join(r) + "\n" for r in later))
    seq = TumSequence(path=small_tum)
    assert seq.meta["dropped"]["no_pose"] >= 1
    assert seq.timestamps[0] > first_depth


def test_camera_choice(small_tum, tmp_path):
    renamed = tmp_path / "mystery"
    small_tum.rename(renamed)
    with pytest.raises(EvsmapError, match="cannot tell which TUM camera"):
        TumSequence(path=renamed)
    assert TumSequence(path=renamed, camera="fr3").intrinsics == TUM_CAMERAS["fr3"]
    with pytest.raises(EvsmapError, match="unknown TUM camera 'fr9'"):
        TumSequence(path=renamed, camera="fr9")
