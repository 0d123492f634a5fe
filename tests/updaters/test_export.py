"""PLY export of octree maps: occupied voxel centres, colours and class colours through Open3D,
and ``evsmap map --ply``."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from evsmap.classes import palette
from evsmap.errors import DataFormatError, InvalidDataError
from evsmap.interfaces import OCCUPIED
from evsmap.open3d_loader import load_open3d
from evsmap.registry import READERS, SEGMENTERS, UPDATERS
from evsmap.testing import require_module
from evsmap.updaters.export import (
    check_color_by,
    class_colors,
    default_color_by,
    export_ply,
    occupied_points,
)

o3d = load_open3d()

RES = 0.1


@pytest.fixture(scope="module")
def frames():
    seq = READERS.create("synthetic", frames=2, width=160, height=120)
    oracle = SEGMENTERS.create("oracle")
    out = []
    for i in range(len(seq)):
        frame = seq.frame(i)
        out.append((frame, oracle.predict(frame)))
    return out


def mapped(name: str, frames, **options):
    updater = UPDATERS.create(name, resolution=RES, **options)
    for frame, observation in frames:
        updater.integrate(frame, observation if updater.uses_semantics else None)
    return updater


@pytest.fixture(scope="module")
def mcb(frames):  # the direct front end's node keeps no colour
    return mapped("multiclass-bayes", frames, front_end="direct")


@pytest.fixture(scope="module")
def orgb(frames):
    return mapped("orgb", frames)


def read_ply(path):
    cloud = o3d.io.read_point_cloud(str(path))
    rgb = np.round(np.asarray(cloud.colors) * 255.0).astype(np.uint8)
    return np.asarray(cloud.points), rgb


def occupied_count(updater) -> int:
    m = updater.map
    return int(np.count_nonzero(m.classify_logodds(m.logodds) == OCCUPIED))


# ---------------------------------------------------------------- occupied_points


def test_occupied_points_of_multiclass_bayes(mcb):
    centres, rgb, labels = occupied_points(mcb)
    n = occupied_count(mcb)
    assert n > 100
    assert centres.shape == (n, 3) and centres.dtype == np.float64
    assert rgb is None  # the EVSMaP map stores no colour
    assert labels.shape == (n,) and labels.dtype == np.int16
    # each centre is the centre of an occupied voxel, and its label the map's query label
    q = mcb.query(centres)
    assert np.all(q.state == OCCUPIED)
    assert np.array_equal(q.label, labels)
    frac = centres / RES - 0.5
    assert np.allclose(frac, np.round(frac), atol=1e-6)
    assert (labels >= 0).all() and labels.max() < 40


def test_occupied_points_of_orgb(orgb):
    centres, rgb, labels = occupied_points(orgb)
    n = occupied_count(orgb)
    assert centres.shape == (n, 3) and rgb.shape == (n, 3) and rgb.dtype == np.uint8
    assert labels is None
    m = orgb.map
    occupied = m.classify_logodds(m.logodds) == OCCUPIED
    assert np.array_equal(rgb, m.payload("rgb")[occupied])


def test_occupied_points_of_classic_semantic_has_both(frames):
    updater = mapped("classic-semantic", frames)
    centres, rgb, labels = occupied_points(updater)
    assert len(centres) == occupied_count(updater) > 0
    assert rgb is not None and labels is not None
    m = updater.map
    occupied = m.classify_logodds(m.logodds) == OCCUPIED
    assert np.array_equal(labels, m.payload("sem_classes")[occupied, 0])


def test_empty_map_has_no_points():
    centres, rgb, labels = occupied_points(UPDATERS.create("orgb", resolution=RES))
    assert centres.shape == (0, 3) and rgb.shape == (0, 3) and labels is None


# ---------------------------------------------------------------- export_ply


def test_export_class_colours_read_back(mcb, tmp_path):
    path = tmp_path / "mcb.ply"
    n = export_ply(mcb, path, color_by="class")
    centres, _, labels = occupied_points(mcb)
    assert n == len(centres) == occupied_count(mcb)
    assert path.read_bytes().startswith(b"ply\nformat binary_little_endian")
    points, rgb = read_ply(path)
    assert len(points) == n
    assert np.array_equal(points, centres)
    assert np.array_equal(rgb, palette(max(40, int(labels.max()) + 1))[labels])
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left


def test_export_default_colouring(mcb, orgb, tmp_path):
    assert default_color_by(mcb) == "class" and default_color_by(orgb) == "rgb"
    assert export_ply(mcb, tmp_path / "a.ply") == occupied_count(mcb)
    labels = occupied_points(mcb)[2]
    assert np.array_equal(read_ply(tmp_path / "a.ply")[1], class_colors(labels))
    n = export_ply(orgb, tmp_path / "b.ply")
    points, rgb = read_ply(tmp_path / "b.ply")
    centres, colours, _ = occupied_points(orgb)
    assert n == len(points) == occupied_count(orgb)
    assert np.array_equal(points, centres) and np.array_equal(rgb, colours)


def test_export_overwrites_and_ignores_suffix(orgb, tmp_path):
    path = tmp_path / "cloud.bin"
    path.write_bytes(b"old")
    n = export_ply(orgb, path, color_by="rgb")
    assert len(read_ply_any(path)) == n


def read_ply_any(path):
    """Open3D picks the reader by suffix: read a PLY saved under another name."""
    data = path.read_bytes()
    assert data.startswith(b"ply\n")
    copy = path.with_name(path.name + ".ply")
    copy.write_bytes(data)
    return read_ply(copy)[0]


def test_class_colors_unlabelled_is_black_and_large_ids_fit():
    out = class_colors(np.array([-1, 0, 45], dtype=np.int16))
    assert out[0].tolist() == [0, 0, 0]
    assert np.array_equal(out[1:], palette(46)[[0, 45]])
    assert class_colors(np.zeros(0, np.int16)).shape == (0, 3)


# ---------------------------------------------------------------- errors


def test_unknown_colouring(mcb, tmp_path):
    with pytest.raises(InvalidDataError, match="unknown PLY colouring 'depth'"):
        export_ply(mcb, tmp_path / "x.ply", color_by="depth")
    assert not (tmp_path / "x.ply").exists()


def test_rgb_without_colours_and_class_without_classes(mcb, orgb, tmp_path):
    with pytest.raises(InvalidDataError, match="'multiclass-bayes' stores no colours"):
        export_ply(mcb, tmp_path / "x.ply", color_by="rgb")
    with pytest.raises(InvalidDataError, match="'orgb' stores no classes"):
        export_ply(orgb, tmp_path / "x.ply", color_by="class")
    with pytest.raises(InvalidDataError, match="stores no colours"):
        check_color_by(UPDATERS.create("multiclass-bayes", front_end="direct"), "rgb")


def test_not_an_octree_updater(tmp_path):
    with pytest.raises(InvalidDataError, match="octree map updater"):
        occupied_points(object())
    require_module("octomap")
    with pytest.raises(InvalidDataError, match="octree map updater"):
        export_ply(UPDATERS.create("octomap-cpp"), tmp_path / "x.ply")


def test_empty_map_is_refused(tmp_path):
    with pytest.raises(InvalidDataError, match="no occupied voxels"):
        export_ply(UPDATERS.create("orgb", resolution=RES), tmp_path / "x.ply")


def test_unwritable_path_names_it(orgb, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")  # a file where the folder above the output should be
    under_file = blocker / "cloud.ply"
    with pytest.raises((DataFormatError, OSError), match=str(blocker)):
        export_ply(orgb, under_file)
    blocker.unlink()
    folder = tmp_path / "folder.ply"
    folder.mkdir()
    with pytest.raises(DataFormatError, match="folder.ply"):
        export_ply(orgb, folder)
    assert list(folder.iterdir()) == [] and [p.name for p in tmp_path.iterdir()] == ["folder.ply"]


# ---------------------------------------------------------------- evsmap map --ply


def evsmap(*args: str):
    return subprocess.run([sys.executable, "-m", "evsmap", *args], capture_output=True,
                          text=True, timeout=600)


def test_cli_map_writes_ply(tmp_path):
    path = tmp_path / "orgb.ply"
    r = evsmap("map", "synthetic", "--updater", "orgb", "--frames", "1", "--resolution", "0.1",
               "--ply", str(path), "--json")
    assert r.returncode == 0, r.stderr
    record = json.loads(r.stdout)
    assert path.is_file()
    points, rgb = read_ply(path)
    assert record["ply_points"] == len(points) > 0
    assert (rgb != 255).any()  # the stored colours, not white


def test_cli_map_ply_class_colours_text_output(tmp_path):
    path = tmp_path / "mcb.ply"
    r = evsmap("map", "synthetic", "--updater", "multiclass-bayes", "--frames", "1",
               "--resolution", "0.1", "--ply", str(path))
    assert r.returncode == 0, r.stderr
    assert "point cloud" in r.stdout and path.is_file()
    _, rgb = read_ply(path)
    assert {tuple(c) for c in rgb} <= {tuple(c) for c in palette(40)} | {(0, 0, 0)}


def test_cli_map_ply_errors_are_one_line_and_early(tmp_path):
    (tmp_path / "blocker").write_text("a file where a folder should be")
    cases = [
        (("--updater", "multiclass-bayes", "-o", "front_end=direct", "--ply",
          str(tmp_path / "a.ply"), "--ply-color", "rgb"), "stores no colours"),
        (("--updater", "orgb", "--ply", str(tmp_path / "blocker" / "b.ply")),
         "blocker is a file, not a folder"),
        (("--updater", "orgb", "--ply", str(tmp_path / "a.ply"), "--ply-color", "depth"),
         "invalid choice"),
    ]
    for args, message in cases:
        r = evsmap("map", "synthetic", "--frames", "1", "--resolution", "0.1", *args)
        assert r.returncode == 2, (args, r.stderr)
        assert message in r.stderr and "Traceback" not in r.stderr
        assert len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert not (tmp_path / "a.ply").exists()


def test_a_failed_write_prints_nothing_of_open3d(orgb, capfd):
    """Open3D reports a failed write on the process's own stderr; evsmap's one line is the
    only message (the issue's `--ply` into a read-only folder printed both)."""
    target = "/proc/self/cloud.ply"  # a folder no file can be created in
    with pytest.raises((DataFormatError, OSError)):
        export_ply(orgb, target)
    out, err = capfd.readouterr()
    assert out == "" and err == ""
