"""The ScanNet reader on small scenes written in the official layout
(tests/readers/scannet_scene.py): the ``.sens`` stream and SensReader's export, the labelled
mesh's voxelisation against an independent one, the label table and the 2D label images, and
``evsmap info`` / ``evsmap map``."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest

from evsmap.cli.main import main
from evsmap.errors import DataFormatError, EvsmapError
from evsmap.readers.detect import detect_reader, open_sequence
from evsmap.readers.scannet.labelmap import read_label_table, read_split
from evsmap.readers.scannet.mesh import LabelMesh, read_label_mesh, voxelise
from evsmap.readers.scannet.sens import SensFile
from evsmap.readers.scannet.write import write_label_ply, write_label_table
from evsmap.registry import READERS, SEGMENTERS, UPDATERS
from tests.readers import scannet_scene as scene

NAME = "scene0000_00"


@pytest.fixture(scope="module")
def release(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("scannet")
    scene.write_scene(root, NAME, label_images=True)
    return root


@pytest.fixture(scope="module")
def folder(release) -> Path:
    return release / "scans" / NAME


def _sorted(truth):
    order = np.lexsort(truth.keys.T[::-1])
    return truth.keys[order], truth.labels[order]


def test_sens_header_and_frames(folder):
    sens = SensFile(folder / f"{NAME}.sens")
    h = sens.header
    assert (h.color_size, h.depth_size, h.depth_shift) == (scene.COLOR_SIZE, scene.DEPTH_SIZE,
                                                           1000.0)
    assert (h.color_compression, h.depth_compression) == ("jpeg", "zlib_ushort")
    assert len(sens) == scene.FRAMES and h.intrinsic_depth[0, 0] == scene.DEPTH_K[0]
    seq = READERS.create("scannet", path=str(folder))
    assert len(seq) == scene.FRAMES and seq.meta["invalid_poses"] == 1
    fx, fy, cx, cy = scene.DEPTH_K
    assert (seq.intrinsics.fx, seq.intrinsics.cx, seq.intrinsics.width) == (fx, cx, 64)
    frame = seq.frame(1)
    cam = scene.pose(2 * np.pi / scene.FRAMES + 0.1)
    depth, ids = scene.cast(cam, fx, fy, cx, cy, *scene.DEPTH_SIZE)
    np.testing.assert_array_equal(frame.depth, np.round(depth * 1000).astype(np.uint16)
                                  .astype(np.float32) / np.float32(1000))
    np.testing.assert_allclose(frame.pose, cam, atol=1e-6)
    assert frame.rgb.shape == (48, 64, 3)  # the 128x96 colour resized to the depth camera's
    assert frame.timestamp == pytest.approx(1.0 + 0.033333)
    # labels from ScanNet's label-filt images through the label table: the cast classes
    want = np.where(ids == 0, 255, ids - 1)
    np.testing.assert_array_equal(frame.labels, want.astype(np.uint8))


def test_lost_pose_is_a_bad_frame(folder, capsys):
    seq = READERS.create("scannet", path=str(folder))
    with pytest.raises(DataFormatError, match="frame 3: invalid camera pose .-inf"):
        seq.frame(scene.LOST)
    assert main(["info", str(folder)]) == 2
    assert "frame 3" in capsys.readouterr().err
    assert main(["info", str(folder), "--skip-bad", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["frames"] == scene.FRAMES - 1 and info["skipped"]["count"] == 1


def test_detected_from_the_scene_the_sens_and_the_root(release, folder):
    for path in (folder, folder / f"{NAME}.sens", release):
        assert detect_reader(path) == "scannet"
    assert open_sequence(str(release)).name == NAME
    with pytest.raises(EvsmapError, match="no scene 'scene0999_00'"):
        READERS.create("scannet", path=str(release), scene="scene0999_00")


@pytest.mark.parametrize("resolution", [0.02, 0.04, 0.05])
def test_mesh_voxelisation_equals_an_independent_one(folder, resolution):
    seq = READERS.create("scannet", path=str(folder))
    got, want = seq.ground_truth(resolution), scene.box_truth(resolution)
    assert got is not None and len(got) == len(want) > 0
    for a, b in zip(_sorted(got), _sorted(want), strict=True):
        np.testing.assert_array_equal(a, b)
    assert 255 in want.labels  # the unannotated ceiling: void, scored for geometry only


def test_voxel_takes_the_class_of_most_area(tmp_path):
    # one 5 cm voxel: 70 % of a square is class 3 (NYU40 id 4), 30 % class 0 (id 1)
    v = np.array([[0.001, 0.001, 0.02], [0.036, 0.001, 0.02], [0.036, 0.049, 0.02],
                  [0.001, 0.049, 0.02], [0.036, 0.001, 0.02], [0.049, 0.001, 0.02],
                  [0.049, 0.049, 0.02], [0.036, 0.049, 0.02]])
    ids = np.array([4, 4, 4, 4, 1, 1, 1, 1])
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    write_label_ply(tmp_path / "m.ply", v, ids, faces)
    mesh = read_label_mesh(tmp_path / "m.ply")
    truth = voxelise(mesh, 0.05)
    assert truth.keys.tolist() == [[0, 0, 0]] and truth.labels.tolist() == [3]
    assert mesh.area == pytest.approx(0.048 * 0.048, rel=1e-5)
    ascii_path = tmp_path / "a.ply"
    write_label_ply(ascii_path, v, ids, faces, binary=False)
    assert voxelise(read_label_mesh(ascii_path), 0.05).labels.tolist() == [3]


def test_label_archive_is_opened_once_and_not_pickled(folder, monkeypatch):
    import pickle
    import zipfile

    opened = []
    real = zipfile.ZipFile

    def counting(*args, **kwargs):
        opened.append(args[0])
        return real(*args, **kwargs)

    seq = READERS.create("scannet", path=str(folder), labels="label-filt")
    monkeypatch.setattr(zipfile, "ZipFile", counting)
    for i in (0, 1, 2):
        seq.frame(i)
    assert len(opened) == 1
    monkeypatch.undo()
    again = pickle.loads(pickle.dumps(seq))  # the open archive stays behind
    np.testing.assert_array_equal(again.frame(0).labels, seq.frame(0).labels)


def test_mesh_labels_equal_the_label_images(folder):
    images = READERS.create("scannet", path=str(folder), labels="label-filt")
    projected = READERS.create("scannet", path=str(folder), labels="mesh")
    for i in (0, 5):
        a, b = images.frame(i), projected.frame(i)
        seen = a.depth > 0
        assert np.mean(a.labels[seen] == b.labels[seen]) > 0.97
        assert np.all(b.labels[~seen] == 255)


def test_exported_layout_reads_the_same_frames(tmp_path, folder):
    """A SensReader export (color/N.jpg, depth/N.png, pose/N.txt, intrinsic/) of the scene."""
    from PIL import Image

    sens = SensFile(folder / f"{NAME}.sens")
    out = tmp_path / NAME
    for d in ("color", "depth", "pose", "intrinsic"):
        (out / d).mkdir(parents=True)
    for i in range(len(sens)):
        Image.fromarray(sens.color(i)).save(out / "color" / f"{i}.jpg")
        Image.fromarray(sens.depth(i)).save(out / "depth" / f"{i}.png")
        np.savetxt(out / "pose" / f"{i}.txt", sens.frames[i].pose, fmt="%f")
    np.savetxt(out / "intrinsic" / "intrinsic_depth.txt", sens.header.intrinsic_depth, fmt="%f")
    (tmp_path / f"{NAME}_vh_clean_2.labels.ply").write_bytes(
        (folder / f"{NAME}_vh_clean_2.labels.ply").read_bytes())
    assert detect_reader(out) == "scannet"
    exported = READERS.create("scannet", path=str(out))
    original = READERS.create("scannet", path=str(folder), labels="mesh")
    assert exported.meta["source"] == "exported" and exported.labels_source == "mesh"
    for i in (0, 6):
        a, b = exported.frame(i), original.frame(i)
        np.testing.assert_array_equal(a.depth, b.depth)
        np.testing.assert_allclose(a.pose, b.pose, atol=1e-5)
        np.testing.assert_array_equal(a.labels, b.labels)
    with pytest.raises(DataFormatError, match="pose/3.txt: invalid camera pose"):
        exported.frame(scene.LOST)


def test_step_reads_every_nth_frame(folder):
    seq = READERS.create("scannet", path=str(folder), step=3)
    assert len(seq) == 3 and [seq.frame_stem(i) for i in range(3)] == ["0", "3", "6"]
    with pytest.raises(EvsmapError, match="step must be a positive integer"):
        READERS.create("scannet", path=str(folder), step=0)


def test_map_json_scores_the_map_against_the_mesh(folder, capsys):
    """`evsmap map` on the scene: its 3D scores are the map's against the independent
    voxelisation of the room (the same oracle, seed and frames rebuilt here)."""
    from evsmap.metrics import evaluate_map

    argv = ["map", str(folder), "--updater", "multiclass-bayes", "--segmenter", "oracle",
            "--resolution", "0.05", "--skip-bad", "--json"]
    assert main(argv) == 0
    record = json.loads(capsys.readouterr().out)
    quality = record["quality"]
    seq = READERS.create("scannet", path=str(folder))
    updater = UPDATERS.create("multiclass-bayes", resolution=0.05)
    oracle = SEGMENTERS.create("oracle")
    for i in range(len(seq)):
        if i != scene.LOST:
            frame = seq.frame(i)
            updater.integrate(frame, oracle.predict(frame))
    want = evaluate_map(updater, scene.box_truth(0.05)).as_dict()
    for key in ("occupied", "ground_truth", "observed", "matched", "unlabelled",
                "semantic_accuracy", "map_miou", "scene_miou", "precision", "recall"):
        assert quality[key] == pytest.approx(want[key]), key
    assert quality["semantic_accuracy"] > 0.5 and quality["observed"] > 100


def test_label_table_and_splits(tmp_path):
    path = tmp_path / "t.tsv"
    write_label_table(path, [(1, "wall", 1), (5, "window", 9), (40, "misc", 0)])
    table = read_label_table(path)
    assert (table[1], table[5], table[40], table[7]) == (0, 8, 255, 255)
    path.write_text("id\tnyu40id\n3\tfour\n")
    with pytest.raises(DataFormatError, match="line 2: nyu40id 'four' is not an integer"):
        read_label_table(path)
    path.write_text("id\tnyu40id\n3\t41\n")
    with pytest.raises(DataFormatError, match="not an NYU40 id"):
        read_label_table(path)
    split = tmp_path / "scannetv2_val.txt"
    split.write_text("scene0011_00\nscene0011_01\n\n")
    assert read_split(split) == ["scene0011_00", "scene0011_01"]
    split.write_text("scene0011_00\nbad line\n")
    with pytest.raises(DataFormatError, match="line 2"):
        read_split(split)


def test_bad_files_are_one_line_errors(tmp_path, folder):
    sens = (folder / f"{NAME}.sens").read_bytes()
    bad = tmp_path / "x.sens"
    bad.write_bytes(sens[: len(sens) // 2])
    with pytest.raises(DataFormatError, match="truncated"):
        SensFile(bad)
    bad.write_bytes(struct.pack("<I", 3) + sens[4:])
    with pytest.raises(DataFormatError, match="version 4"):
        SensFile(bad)
    ply = tmp_path / "m.ply"
    from plyfile import PlyData, PlyElement

    v = np.zeros(3, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    f = np.zeros(1, dtype=[("vertex_indices", "i4", (3,))])
    PlyData([PlyElement.describe(v, "vertex"), PlyElement.describe(f, "face")]).write(str(ply))
    with pytest.raises(DataFormatError, match="no 'label' property"):
        read_label_mesh(ply)
    write_label_ply(ply, np.zeros((3, 3)), np.array([1, 1, 1]), np.array([[0, 1, 5]]))
    with pytest.raises(DataFormatError, match="face 0 names vertex"):
        read_label_mesh(ply)
    ply.write_bytes(b"ply\nformat nonsense\n")
    with pytest.raises(DataFormatError, match="m.ply: not a readable PLY"):
        read_label_mesh(ply)


def test_empty_mesh_has_no_voxels():
    mesh = LabelMesh(np.zeros((0, 3)), np.zeros(0, np.uint8), np.zeros((0, 3), np.int64))
    assert len(voxelise(mesh, 0.05)) == 0


def test_frames_identity_follows_the_frames_chosen(folder):
    """The runner's segmentation cache keys a sequence's observations by what its frames are:
    another step, dropping the lost frames or another label source is another key."""
    ids = {READERS.create("scannet", path=str(folder), **options).frames_identity()
           for options in ({}, {"step": 2}, {"drop_lost": True}, {"labels": "mesh"})}
    assert len(ids) == 4
    same = READERS.create("scannet", path=str(folder)).frames_identity()
    assert same in ids


def test_datasets_check_scannet(tmp_path, capsys, monkeypatch):
    """`evsmap datasets check scannet`: how to obtain it without a copy (exit 2), the counts of a
    good copy (exit 0), one line per problem of a damaged one (exit 1)."""
    monkeypatch.setenv("EVSMAP_DATA_ROOT", str(tmp_path / "empty"))
    monkeypatch.chdir(tmp_path)
    assert main(["datasets", "check", "scannet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "scan-net.org" in err and "scannet/" in err
    root = tmp_path / "release"
    scene.write_scene(root, NAME)
    scene.write_scene(root, "scene0001_00")
    assert main(["datasets", "check", "scannet", "--root", str(root)]) == 0
    out = capsys.readouterr().out
    assert "2 scenes, 16 frames" in out and "val   split: 1 of its 1 scenes present" in out
    assert "2 frames with invalid (-inf) poses" in out and "no problems found" in out
    sens = root / "scans" / "scene0001_00" / "scene0001_00.sens"
    sens.write_bytes(sens.read_bytes()[:5000])
    (root / "scans" / NAME / f"{NAME}_vh_clean_2.labels.ply").unlink()
    assert main(["datasets", "check", "scannet", "--root", str(root)]) == 1
    problems = [line for line in capsys.readouterr().out.splitlines()
                if line.startswith("problem: ")]
    assert len(problems) == 2
    assert "scene0001_00.sens" in problems[1] or "scene0001_00.sens" in problems[0]
    assert any("labels.ply: missing" in p for p in problems)


def test_reproduce_refuses_a_scene_that_is_not_an_id(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["reproduce", "--scannet-scenes", "scene11", "--out", "unused"])
    assert stop.value.code == 2 and "--scannet-scenes" in capsys.readouterr().err


def test_depth_shift_comes_from_the_header(tmp_path):
    """A stream stored at 4000 values a metre reads as the same metres as ScanNet's 1000."""
    from evsmap.readers.scannet.write import SensFrame, write_sens

    depth_m = np.full((4, 6), 1.25)
    depth_m[0, 0] = 0.0  # no measurement
    folder = tmp_path / "scene0002_00"
    folder.mkdir()
    frame = SensFrame(np.zeros((4, 6, 3), np.uint8), np.round(depth_m * 4000).astype(np.uint16),
                      np.eye(4))
    write_sens(folder / "scene0002_00.sens", [frame], intrinsic_color=np.eye(3) * 5,
               intrinsic_depth=np.array([[5.0, 0, 3], [0, 5.0, 2], [0, 0, 1]]),
               color_size=(6, 4), depth_size=(6, 4), depth_shift=4000.0,
               color_compression="raw", depth_compression="raw_ushort")
    seq = READERS.create("scannet", path=str(folder))
    assert seq.meta["depth_shift"] == 4000.0 and seq.labels_source == "none"
    got = seq.frame(0)
    assert got.depth[0, 0] == 0 and np.allclose(got.depth[1:], 1.25)
    assert got.timestamp == 0.0 and not seq.has_ground_truth and seq.ground_truth(0.05) is None
