"""Microsoft 7-Scenes reader: the real 100-frame sample, small folders built here in the same
layout (bad frames, scene folders), ``evsmap info`` / ``evsmap map`` on them, and the occupancy
of ``evsmap map --updater octomap-cpp`` / ``--updater orgb`` against the C++ OctoMap itself."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from evsmap.cli.main import main
from evsmap.errors import DataFormatError, EvsmapError
from evsmap.interfaces import FREE, OCCUPIED, UNKNOWN
from evsmap.mapping.keys import TREE_DEPTH, pack, unpack
from evsmap.mapping.octree_io import read_ot
from evsmap.readers.detect import detect_reader
from evsmap.readers.images import read_uint16, write_png
from evsmap.readers.sevenscenes import (
    INTRINSICS_FILE,
    SEVENSCENES_INTRINSICS,
    SevenScenesSequence,
    is_sevenscenes_folder,
    read_pose,
)
from evsmap.registry import READERS
from evsmap.testing import require_module

N_SAMPLE = 100


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


# ---------------------------------------------------------------- the real sample


@pytest.fixture(scope="module")
def sample(sevenscenes_dir) -> SevenScenesSequence:
    return READERS.create("sevenscenes", path=str(sevenscenes_dir))


def test_real_sample_frames(sample, sevenscenes_dir):
    assert len(sample) == N_SAMPLE
    assert sample.meta["layout"] == "sevenscenes"
    assert sample.meta["intrinsics_source"] == INTRINSICS_FILE
    assert sample.intrinsics == SEVENSCENES_INTRINSICS  # the file holds 585 / 320 / 240
    intr = sample.intrinsics
    assert (intr.fx, intr.fy, intr.cx, intr.cy, intr.width, intr.height) == \
        (585.0, 585.0, 320.0, 240.0, 640, 480)
    invalid_65535 = 0
    for i, frame in enumerate(sample):
        number = f"{i:06d}"
        assert frame.name == f"frame-{number}.depth.png"
        assert frame.rgb.shape == (480, 640, 3) and frame.rgb.dtype == np.uint8
        assert frame.depth.shape == (480, 640) and frame.depth.dtype == np.float32
        assert frame.timestamp == pytest.approx(i / 30.0)
        raw = read_uint16(sevenscenes_dir / f"frame-{number}.depth.png")
        ok = (raw > 0) & (raw < 65535)
        invalid_65535 += int((raw == 65535).sum())
        # metres = millimetres / 1000; 0 and 65535 -> 0 (invalid)
        np.testing.assert_array_equal(frame.depth[ok], raw[ok].astype(np.float32) / 1000.0)
        assert np.all(frame.depth[~ok] == 0)
        valid = frame.depth[ok]
        assert 0.5 < valid.min() and valid.max() < 5.0  # Kinect v1 indoors
        # the pose is the text file's: translation as written, rotation the nearest rotation
        # to the written block (KinectFusion's blocks are ~1e-4 off orthonormal)
        written = np.loadtxt(sevenscenes_dir / f"frame-{number}.pose.txt")
        assert np.array_equal(frame.pose[:3, 3], written[:3, 3])
        assert np.array_equal(frame.pose[3], [0.0, 0.0, 0.0, 1.0])
        np.testing.assert_allclose(frame.pose[:3, :3], written[:3, :3], atol=2e-4, rtol=0)
        u, _, vt = np.linalg.svd(written[:3, :3])
        np.testing.assert_allclose(frame.pose[:3, :3], u @ vt, atol=1e-15, rtol=0)
    assert invalid_65535 > 0  # the sample does have 65535 pixels


def test_real_sample_is_detected(sevenscenes_dir, tmp_path):
    assert is_sevenscenes_folder(sevenscenes_dir)
    assert detect_reader(sevenscenes_dir) == "sevenscenes"
    assert not is_sevenscenes_folder(tmp_path)
    assert not is_sevenscenes_folder(sevenscenes_dir / "frame-000000.pose.txt")


def test_info_on_real_sample(capsys, sevenscenes_dir):
    code, out, _ = run(capsys, "info", str(sevenscenes_dir), "--json")
    assert code == 0
    info = json.loads(out)
    assert info["reader"] == "sevenscenes" and info["layout"] == "sevenscenes"
    assert info["frames"] == N_SAMPLE
    assert (info["width"], info["height"]) == (640, 480)
    assert info["intrinsics"] == {"fx": 585.0, "fy": 585.0, "cx": 320.0, "cy": 240.0,
                                  "width": 640, "height": 480}
    # millimetre depth is exact on info's 1/5000 m histogram
    assert info["depth"]["min_m"] == pytest.approx(0.801)
    assert info["depth"]["max_m"] == pytest.approx(3.602)
    assert 0.85 < info["depth"]["valid_fraction"] < 0.95
    assert info["poses"]["duration_s"] == pytest.approx(99 / 30)
    assert 0.3 < info["poses"]["path_length_m"] < 1.0
    assert info["labels"] is None

    code, out, _ = run(capsys, "info", str(sevenscenes_dir))
    assert code == 0
    assert "layout: sevenscenes, reader: sevenscenes" in out
    assert "frames      100" in out
    assert "640x480  fx 585.00 fy 585.00 cx 320.00 cy 240.00  (camera-intrinsics.txt)" in out


def test_module_does_not_import_open3d_or_torch():
    code = ("import sys, evsmap.readers.sevenscenes; "
            "bad = [m for m in ('open3d', 'torch') if m in sys.modules]; "
            "assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)


# ---------------------------------------------------------------- small folders

H, W = 480, 640


def pose_text(pose: np.ndarray) -> str:
    return "".join(" ".join(f"{v:.18e}" for v in row) + "\n" for row in pose)


def make_sequence(folder: Path, frames: int = 3, *, color: str = "png",
                  intrinsics: bool = False) -> Path:
    """``frames`` frames of a camera looking at a wall 1.5 m away while moving along x, in the
    7-Scenes layout; frame 1 has a 65535 pixel and a 0 pixel."""
    folder.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for i in range(frames):
        stem = folder / f"frame-{i:06d}"
        depth = np.full((H, W), 1500, dtype=np.uint16)
        depth[:, W // 2:] = 2000
        if i == 1:
            depth[10, 20] = 65535
            depth[11, 20] = 0
        write_png(Path(f"{stem}.depth.png"), depth)
        rgb = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
        if color == "png":
            write_png(Path(f"{stem}.color.png"), rgb)
        else:
            from PIL import Image

            Image.fromarray(rgb).save(f"{stem}.color.jpg", quality=90)
        pose = np.eye(4)
        pose[0, 3] = 0.05 * i
        Path(f"{stem}.pose.txt").write_text(pose_text(pose))
    if intrinsics:
        (folder / INTRINSICS_FILE).write_text("5.2e+02 0 3.1e+02\n0 5.3e+02 2.5e+02\n0 0 1\n")
    return folder


def test_png_colour_without_intrinsics_file(tmp_path):
    root = make_sequence(tmp_path / "office" / "seq-03")
    seq = READERS.create("sevenscenes", path=str(root))
    assert seq.name == "office/seq-03"
    assert seq.intrinsics == SEVENSCENES_INTRINSICS
    assert seq.meta["intrinsics_source"] == "7-Scenes default depth camera"
    frame = seq[1]
    assert frame.rgb.shape == (H, W, 3)
    assert frame.depth[0, 0] == np.float32(1.5) and frame.depth[0, W - 1] == np.float32(2.0)
    assert frame.depth[10, 20] == 0 and frame.depth[11, 20] == 0  # 65535 and 0: invalid
    assert (frame.depth > 0).sum() == H * W - 2
    assert frame.pose[0, 3] == 0.05 and frame.timestamp == pytest.approx(1 / 30)


def test_jpeg_colour_and_intrinsics_file(tmp_path):
    root = make_sequence(tmp_path / "seq", 2, color="jpg", intrinsics=True)
    seq = SevenScenesSequence(path=root)
    assert seq.meta["intrinsics_source"] == INTRINSICS_FILE
    intr = seq.intrinsics
    assert (intr.fx, intr.fy, intr.cx, intr.cy, intr.width, intr.height) == \
        (520.0, 530.0, 310.0, 250.0, W, H)
    assert seq[0].rgb.shape == (H, W, 3)
    (root / INTRINSICS_FILE).write_text("520 1 310\n0 530 250\n0 0 1\n")
    with pytest.raises(DataFormatError, match=r"camera-intrinsics.txt: expected K"):
        SevenScenesSequence(path=root)


@pytest.mark.parametrize("token", ["nan", "-inf", "-1.#IND", "1.#QNAN0"])
def test_non_finite_pose_is_a_bad_frame(tmp_path, token):
    root = make_sequence(tmp_path / "seq", 3)
    bad = root / "frame-000001.pose.txt"
    bad.write_text(bad.read_text().replace("0.000000000000000000e+00", token, 1))
    seq = SevenScenesSequence(path=root)
    assert len(seq) == 3  # listed; the error comes from reading the frame
    assert seq[0].name == "frame-000000.depth.png" and len(seq[2].rgb) == H
    with pytest.raises(DataFormatError) as exc:
        seq.frame(1)
    message = str(exc.value)
    assert str(bad) in message and "non-finite pose" in message and "\n" not in message


@pytest.fixture
def bad_pose_sequence(tmp_path) -> tuple[Path, Path]:
    root = make_sequence(tmp_path / "seq", 4)
    bad = root / "frame-000002.pose.txt"
    bad.write_text(bad.read_text().replace("1.000000000000000000e+00", "nan", 1))
    return root, bad


def test_non_finite_pose_stops_map_and_info(capsys, bad_pose_sequence):
    root, bad = bad_pose_sequence
    for command in ("map", "info"):
        argv = ["map", str(root), "--updater", "orgb"] if command == "map" else ["info", str(root)]
        code, _, err = run(capsys, *argv)
        assert code == 2, command
        assert len(err.strip().splitlines()) == 1 and bad.name in err and "Traceback" not in err


def test_non_finite_pose_skip_bad(capsys, bad_pose_sequence):
    root, bad = bad_pose_sequence
    code, out, _ = run(capsys, "map", str(root), "--updater", "orgb", "--skip-bad", "--json")
    assert code == 0
    record = json.loads(out)
    assert record["frames"] == 3
    skipped = record["extra"]["skipped"]
    assert skipped["count"] == 1 and skipped["frames"][0]["index"] == 2
    assert bad.name in skipped["frames"][0]["reason"]
    assert "non-finite pose" in skipped["frames"][0]["reason"]
    code, out, _ = run(capsys, "info", str(root), "--skip-bad")
    assert code == 0
    assert "frames      3" in out and "skipped 1 bad frame(s): #2" in out


def test_missing_depth_file_is_a_one_line_error(capsys, tmp_path):
    root = make_sequence(tmp_path / "seq", 3)
    missing = root / "frame-000001.depth.png"
    missing.unlink()
    seq = SevenScenesSequence(path=root)
    assert len(seq) == 3 and seq.meta["incomplete_frames"] == 1
    with pytest.raises(DataFormatError, match=r"frame-000001.depth.png: file not found"):
        seq.frame(1)
    code, _, err = run(capsys, "info", str(root))
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and str(missing) in err and "file not found" in err
    code, _, err = run(capsys, "map", str(root), "--updater", "octomap-cpp")
    assert code == 2 and len(err.strip().splitlines()) == 1 and missing.name in err
    code, out, _ = run(capsys, "info", str(root), "--skip-bad")
    assert code == 0 and "frames      2" in out
    # a frame without any colour file names both names
    (root / "frame-000002.color.png").unlink()
    with pytest.raises(DataFormatError, match=r"color.png: file not found \(nor .*color.jpg\)"):
        seq = SevenScenesSequence(path=root)
        seq.frame(2)


def test_scene_folder_with_two_sequences(capsys, tmp_path):
    scene = tmp_path / "chess"
    make_sequence(scene / "seq-01", 2)
    make_sequence(scene / "seq-02", 3)
    assert is_sevenscenes_folder(scene) and detect_reader(scene) == "sevenscenes"
    first = READERS.create("sevenscenes", path=str(scene))
    assert len(first) == 2 and first.name == "chess/seq-01"
    assert first.meta["sequences"] == ["seq-01", "seq-02"]
    assert first.meta["sequence"] == "seq-01"
    for choice in ("seq-02", "seq-2", "02", 2):
        second = READERS.create("sevenscenes", path=str(scene), sequence=choice)
        assert len(second) == 3 and second.name == "chess/seq-02"
    with pytest.raises(EvsmapError, match=r"no sequence 'seq-07'.*seq-01, seq-02"):
        READERS.create("sevenscenes", path=str(scene), sequence="seq-07")
    with pytest.raises(EvsmapError, match=r"applies to a scene folder"):
        READERS.create("sevenscenes", path=str(scene / "seq-01"), sequence="seq-02")
    assert len(READERS.create("sevenscenes", path=str(scene / "seq-01"), sequence=1)) == 2

    code, out, _ = run(capsys, "info", str(scene), "-r", "sequence=2", "--json")
    assert code == 0
    info = json.loads(out)
    assert info["frames"] == 3 and info["name"] == "chess/seq-02"
    code, out, _ = run(capsys, "map", str(scene), "--updater", "orgb", "--json")
    assert code == 0 and json.loads(out)["frames"] == 2


def test_ambiguous_scene_folder_says_so_in_errors(capsys, tmp_path):
    scene = tmp_path / "stairs"
    (scene / "seq-01").mkdir(parents=True)  # an empty first sequence
    make_sequence(scene / "seq-02", 2)
    code, _, err = run(capsys, "info", str(scene))
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "seq-01: no frame-NNNNNN" in err
    assert "holds 2 sequences: seq-01, seq-02" in err and "-r sequence=NAME" in err
    code, out, _ = run(capsys, "info", str(scene), "-r", "sequence=seq-02")
    assert code == 0 and "frames      2" in out


def test_zipped_scene_and_other_folders(tmp_path):
    scene = tmp_path / "fire"
    scene.mkdir()
    (scene / "seq-01.zip").write_bytes(b"PK")
    assert is_sevenscenes_folder(scene)
    with pytest.raises(DataFormatError, match="unzip them first"):
        SevenScenesSequence(path=scene)
    with pytest.raises(DataFormatError, match="not a folder"):
        SevenScenesSequence(path=tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataFormatError, match="not a 7-Scenes folder"):
        SevenScenesSequence(path=tmp_path / "empty")


def test_read_pose_refuses_non_rotations(tmp_path):
    path = tmp_path / "frame-000000.pose.txt"
    pose = np.eye(4)
    pose[0, 0] = 1.1
    path.write_text(pose_text(pose))
    with pytest.raises(DataFormatError, match="not a rotation"):
        read_pose(path)
    path.write_text("1 0 0\n0 1 0\n")
    with pytest.raises(DataFormatError, match=r"expected a 4x4 camera-to-world pose"):
        read_pose(path)
    path.write_text(pose_text(np.eye(4)).replace("1.000000000000000000e+00", "one", 1))
    with pytest.raises(DataFormatError, match=r"not a number: 'one'"):
        read_pose(path)


def test_tum_folder_is_not_sevenscenes(tum_dir):
    assert not is_sevenscenes_folder(tum_dir)
    assert detect_reader(tum_dir) == "tum"


# ---------------------------------------------------------------- occupancy vs the C++ OctoMap

RES = 0.05
MAX_RANGE = 2.5  # below the sample's 3.6 m maximum, so cut rays (free space only) are exercised
# The first 60 of the 100 frames (the C++ OctoMap is run twice: ~12 s here instead of ~20 s on
# 2 busy cores; all 100 frames agree as well: 34,069 voxels, 100 %).
N_AGREE = 60


def expand_leaves(keys: np.ndarray, depth: np.ndarray, value: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Finest-voxel codes (sorted) and float32 log-odds of leaves given by their keys (any key
    inside the leaf), depths and values: a pruned leaf stands for its 8**k voxels."""
    codes, values = [np.zeros(0, np.int64)], [np.zeros(0, np.float32)]
    for d in np.unique(depth):
        sel = depth == d
        diff = TREE_DEPTH - int(d)
        corner = (keys[sel] >> diff) << diff
        r = np.arange(1 << diff)
        cube = np.stack(np.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)
        codes.append(pack((corner[:, None, :] + cube[None]).reshape(-1, 3)))
        values.append(np.repeat(value[sel].astype(np.float32), len(cube)))
    codes, values = np.concatenate(codes), np.concatenate(values)
    order = np.argsort(codes)
    return codes[order], values[order]


def octomap_voxels(tree) -> tuple[np.ndarray, np.ndarray]:
    keys, depth, value = [], [], []
    for leaf in tree.begin_leafs():
        key = leaf.getKey()
        keys.append((key[0], key[1], key[2]))
        depth.append(leaf.getDepth())
        value.append(leaf.getValue())
    return expand_leaves(np.array(keys, np.int64).reshape(-1, 3), np.array(depth, np.int64),
                         np.array(value, np.float32))


def file_voxels(path: Path) -> tuple[np.ndarray, np.ndarray]:
    tree = read_ot(path).tree
    leaf = tree.child_mask == 0
    return expand_leaves(unpack(tree.code[leaf]), tree.depth[leaf].astype(np.int64),
                         tree.value[leaf])


def compare(ours: tuple[np.ndarray, np.ndarray], theirs: tuple[np.ndarray, np.ndarray],
            threshold: float) -> dict[str, float]:
    """Classify every finest voxel known to either map (unknown / free / occupied) and compare
    the log-odds of the voxels both know."""
    union = np.union1d(ours[0], theirs[0])

    def classify(codes, values):
        pos = np.minimum(np.searchsorted(codes, union), max(len(codes) - 1, 0))
        known = codes[pos] == union if len(codes) else np.zeros(len(union), bool)
        state = np.full(len(union), UNKNOWN, dtype=np.int8)
        state[known] = np.where(values[pos[known]] >= threshold, OCCUPIED, FREE)
        return state, known, values[pos]

    a, a_known, a_val = classify(*ours)
    b, b_known, b_val = classify(*theirs)
    both = a_known & b_known
    return {"voxels": int(len(union)), "agreement": float(np.mean(a == b)),
            "value_agreement": float(np.mean(a_val[both] == b_val[both])),
            "occupied": int((b == OCCUPIED).sum()), "free": int((b == FREE).sum())}


@pytest.mark.slow
def test_evsmap_map_agrees_with_octomap_on_sevenscenes(sample, sevenscenes_dir, tmp_path,
                                                       capsys, record_property):
    """``evsmap map --frames 60`` with ``octomap-cpp`` and with ``orgb`` (written as .ot) against
    an ``octomap.OcTree`` fed the same clouds with ``insertPointCloud``: the same state
    (unknown / free / occupied) for every voxel and bit-identical log-odds."""
    octomap = require_module("octomap")
    from evsmap.mapping.raycast import frame_points

    tree = octomap.OcTree(RES)
    for i in range(N_AGREE):
        points, origin = frame_points(sample[i])
        tree.insertPointCloud(points, origin, MAX_RANGE, False, True)
    reference = octomap_voxels(tree)
    threshold = tree.getOccupancyThresLog()
    for updater in ("octomap-cpp", "orgb"):
        out = tmp_path / f"{updater}.ot"
        code, text, _ = run(capsys, "map", str(sevenscenes_dir), "--updater", updater,
                            "--resolution", str(RES), "--max-range", str(MAX_RANGE),
                            "--frames", str(N_AGREE), "--out", str(out), "--json")
        assert code == 0
        record = json.loads(text)
        assert record["frames"] == N_AGREE
        assert record["nodes"] == tree.size() and record["leaves"] == tree.getNumLeafNodes()
        stats = compare(file_voxels(out), reference, threshold)
        record_property(f"agreement_{updater}", stats)
        with capsys.disabled():
            print(f"\n7-Scenes {N_AGREE} frames, {RES} m, max range {MAX_RANGE} m, {updater}: "
                  f"{stats}")
        assert stats["voxels"] > 20_000 and stats["occupied"] > 2_000
        assert stats["agreement"] == 1.0, stats
        assert stats["value_agreement"] == 1.0, stats
