"""The synthrooms dataset: generation, split by room, reader, CLI (prepare, info, eval, map)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from evsmap.cli.main import main
from evsmap.datasets import synthrooms as sr
from evsmap.datasets.common import read_manifest
from evsmap.errors import EvsmapError
from evsmap.readers.detect import detect_reader
from evsmap.readers.images import read_uint8_labels
from evsmap.registry import get_reader

ROOMS, VIEWS, SIZE = 8, 2, (48, 64)


def run(capsys, *argv):
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse errors
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="session")
def rooms_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("synthrooms") / "synthrooms"
    sr.prepare_synthrooms(out, rooms=ROOMS, frames_per_room=VIEWS, size=SIZE, seed=0)
    return out


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


def test_split_rule_is_disjoint_and_mixes_types():
    types = sr.scene_types()
    assert set(types) == {"bedroom", "living_room", "office", "kitchen"}
    for n in range(3, 80):
        splits = sr.split_rooms(n)
        members = [r for s in sr.SPLITS for r in splits[s]]
        assert sorted(members) == list(range(n))  # every room in exactly one split
        assert all(splits[s] for s in sr.SPLITS)
        if n >= 8:
            for s in sr.SPLITS:
                assert len({types[r % len(types)] for r in splits[s]}) >= 2, (n, s)
        if n >= 24:
            assert all(len({r % 4 for r in splits[s]}) == 4 for s in sr.SPLITS)
    assert {k: len(v) for k, v in sr.split_rooms(24).items()} == \
        {"train": 16, "val": 4, "test": 4}
    with pytest.raises(EvsmapError, match="at least 3 rooms"):
        sr.split_rooms(2)
    assert len({sr.room_seed(0, i) for i in range(1000)}) == 1000
    assert sr.room_seed(0, 3) != sr.room_seed(1, 3)


def test_layout_manifest_and_no_room_in_two_splits(rooms_dir):
    m = read_manifest(rooms_dir)
    assert m["name"] == "synthrooms" and m["generator"]["version"] == sr.GENERATOR_VERSION
    assert m["options"] == {"rooms": ROOMS, "frames_per_room": VIEWS, "height": SIZE[0],
                            "width": SIZE[1], "seed": 0, "noise": True}
    assert m["splits"] == {"train": 8, "val": 4, "test": 4} and m["frames"] == ROOMS * VIEWS
    assert m["class_names"][0] == "wall" and m["num_classes"] == 40 and m["void_label"] == 255
    poses = {line.split()[0]: int(line.split()[1])
             for line in (rooms_dir / "poses.txt").read_text().splitlines()
             if not line.startswith("#")}
    assert len(poses) == ROOMS * VIEWS
    seen: dict[int, str] = {}
    for split in sr.SPLITS:
        ids = (rooms_dir / f"{split}.txt").read_text().split()
        rooms = {poses[i] for i in ids}
        assert sorted(rooms) == m["split_rooms"][split]
        assert len(ids) == len(rooms) * VIEWS == m["splits"][split]
        for r in rooms:
            assert seen.setdefault(r, split) == split
            assert m["rooms"][r]["split"] == split
        assert sum(v > 0 for v in m["split_scenes"][split].values()) >= 2
    assert sorted(seen) == list(range(ROOMS))
    assert {r["scene"] for r in m["rooms"]} == set(sr.scene_types())
    assert [r["scene"] for r in m["rooms"][:4]] == list(sr.scene_types())  # round-robin
    assert len({r["seed"] for r in m["rooms"]}) == ROOMS
    assert len({tuple(r["path"].values()) for r in m["rooms"]}) == ROOMS  # varied paths
    for sub in ("rgb", "depth", "labels"):
        assert len(list((rooms_dir / sub).glob("*.png"))) == ROOMS * VIEWS
    assert not (rooms_dir / "label40").exists()  # not taken for a NYUv2 folder
    assert detect_reader(rooms_dir) == "synthrooms"


def test_same_options_same_bytes(rooms_dir, tmp_path):
    again = tmp_path / "again"
    sr.prepare_synthrooms(again, rooms=ROOMS, frames_per_room=VIEWS, size=SIZE, seed=0)
    assert _files(again) == _files(rooms_dir)
    other = tmp_path / "other"
    sr.prepare_synthrooms(other, rooms=3, frames_per_room=1, size=(16, 16), seed=1)
    first = tmp_path / "first"
    sr.prepare_synthrooms(first, rooms=3, frames_per_room=1, size=(16, 16), seed=0)
    assert _files(other)["rgb/0000_0000.png"] != _files(first)["rgb/0000_0000.png"]


def test_reader_gives_labelled_frames_of_the_size(rooms_dir):
    m = read_manifest(rooms_dir)
    for split in sr.SPLITS:
        seq = get_reader("synthrooms", path=str(rooms_dir), split=split)
        assert len(seq) == m["splits"][split]
        assert seq.meta["poses"] is False and seq.meta["rooms"] == m["split_rooms"][split]
        assert seq.num_classes == 40 and seq.meta["split"] == split
        for frame in seq:
            assert frame.rgb.shape == (*SIZE, 3) and frame.depth.shape == SIZE
            assert frame.labels.dtype == np.uint8 and frame.labels.shape == SIZE
            values = np.unique(frame.labels)
            assert np.all((values < 40) | (values == 255))
            assert frame.intrinsics.as_dict() == m["intrinsics"]
            assert frame.intrinsics.width == SIZE[1] and frame.intrinsics.height == SIZE[0]
            r = frame.pose[:3, :3]
            assert np.allclose(r @ r.T, np.eye(3)) and np.isfinite(frame.pose).all()
            assert 0.0 < (frame.depth > 0).mean() <= 1.0
    seq = get_reader("synthrooms", path=str(rooms_dir), split="train", limit=3)
    assert len(seq) == 3 and seq.names == ["0000_0000", "0000_0001", "0001_0000"]
    assert len(get_reader("synthrooms", path=str(rooms_dir))) == ROOMS * VIEWS


def test_manifest_pixel_counts_equal_a_recount(rooms_dir):
    m = read_manifest(rooms_dir)
    for split in sr.SPLITS:
        counts = np.zeros(256, dtype=np.int64)
        for fid in (rooms_dir / f"{split}.txt").read_text().split():
            counts += np.bincount(read_uint8_labels(rooms_dir / "labels" / f"{fid}.png").ravel(),
                                  minlength=256)
        got = m["pixel_counts"][split]
        assert got["classes"] == counts[:40].tolist()
        assert got["void"] == int(counts[255]) and got["total"] == int(counts.sum())
        assert got["total"] == m["splits"][split] * SIZE[0] * SIZE[1]


def test_room_option_gives_the_renderer_poses(rooms_dir):
    from evsmap.synth.render import RoomRenderer
    from evsmap.synth.scene import build_room

    m = read_manifest(rooms_dir)
    seq = get_reader("synthrooms", path=str(rooms_dir), room=5)
    info = m["rooms"][5]
    assert len(seq) == VIEWS and seq.meta["poses"] is True
    assert seq.meta["scene"] == info["scene"] and seq.meta["seed"] == info["seed"]
    assert [f.name for f in seq] == ["0005_0000", "0005_0001"]
    room = build_room(info["scene"], seed=info["seed"])
    renderer = RoomRenderer(room)
    stamps = []
    for frame in seq:
        cast = renderer.cast(frame.intrinsics, frame.pose)
        labels = np.append(room.labels, np.uint8(255))[cast["part"]]
        assert np.array_equal(labels, frame.labels)  # exact: pose and intrinsics as rendered
        valid = frame.depth > 0
        assert np.median(np.abs(cast["depth"][valid] - frame.depth[valid])) < 0.05  # noisy
        stamps.append(frame.timestamp)
    assert stamps[0] == 1.0 and stamps[1] > stamps[0]
    with pytest.raises(EvsmapError, match="room 5 is in split 'val', not 'train'"):
        get_reader("synthrooms", path=str(rooms_dir), split="train", room=5)
    assert len(get_reader("synthrooms", path=str(rooms_dir), split="val", room=5)) == VIEWS
    with pytest.raises(EvsmapError, match=r"room index 0\.\.7, got 8"):
        get_reader("synthrooms", path=str(rooms_dir), room=8)
    with pytest.raises(EvsmapError, match="unknown synthrooms split 'dev'"):
        get_reader("synthrooms", path=str(rooms_dir), split="dev")


def test_cli_info_eval_map_and_list(capsys, rooms_dir):
    code, out, err = run(capsys, "info", rooms_dir, "-r", "split=train")
    assert code == 0, err
    assert "reader: synthrooms" in out and "frames      8" in out and "resolution  64x48" in out
    assert "poses       none" in out

    code, out, err = run(capsys, "eval", "oracle", "--dataset", rooms_dir, "--split", "test",
                         "-o", "accuracy=1.0", "-o", "boundary_accuracy=1.0", "--json")
    assert code == 0, err
    record = json.loads(out)
    assert record["reader"] == "synthrooms" and record["split"] == "test"
    assert record["frames"] == 4 and record["miou"] == 1.0
    assert record["pixels"] == read_manifest(rooms_dir)["pixel_counts"]["test"]["total"] - \
        read_manifest(rooms_dir)["pixel_counts"]["test"]["void"]

    code, out, err = run(capsys, "map", rooms_dir, "-r", "room=3", "--updater",
                         "multiclass-bayes", "--json")
    assert code == 0, err
    record = json.loads(out)
    assert record["frames"] == 2 and record["leaves"] > 1000 and record["segmenter"] == "oracle"

    # frames of several rooms do not share a world: one line, exit 2 (the reader's hint names
    # -r room=N; map prints it where it reads meta["no_poses_hint"])
    code, out, err = run(capsys, "map", rooms_dir, "--updater", "multiclass-bayes")
    assert code == 2 and out == "" and err.count("\n") == 1
    assert "room=" in err or "no camera poses" in err
    hint = get_reader("synthrooms", path=str(rooms_dir), split="val").meta["no_poses_hint"]
    assert "pick one room with -r room=N (rooms 4-5 here)" in hint

    code, out, err = run(capsys, "datasets", "list", "--root", rooms_dir.parent)
    assert code == 0, err
    assert out.split()[:8] == ["synthrooms", str(rooms_dir), "train", "8,", "val", "4,", "test",
                               "4"]


def test_cli_prepare_and_bad_options(capsys, tmp_path):
    out = tmp_path / "rooms"
    code, stdout, err = run(capsys, "datasets", "prepare", "synthrooms", "--out", out,
                            "--rooms", 3, "--frames-per-room", 1, "--size", "16x24",
                            "--seed", 4)
    assert code == 0, err
    lines = stdout.splitlines()
    assert lines[0].startswith(f"prepared synthrooms in {out} (3 frames: 3 rooms x 1 views, "
                               "16x24, seed 4, ")
    assert lines[1].split()[:5] == ["train", "1", "frames,", "1", "rooms"]
    m = read_manifest(out)
    assert m["options"]["seed"] == 4 and m["intrinsics"]["width"] == 24
    before = _files(out)

    code, stdout, err = run(capsys, "datasets", "prepare", "synthrooms", "--out", out,
                            "--rooms", 3, "--frames-per-room", 1, "--size", "16x24")
    assert code == 2 and stdout == ""
    assert err == (f"evsmap datasets: error: --out {out}: folder exists and is not empty "
                   "(pass --overwrite to replace it once the new one is complete)\n")
    assert _files(out) == before
    code, _, err = run(capsys, "datasets", "prepare", "synthrooms", "--out", out,
                       "--rooms", 3, "--frames-per-room", 1, "--size", "16x24", "--overwrite")
    assert code == 0, err
    assert read_manifest(out)["options"]["seed"] == 0

    bad = [
        (["--size", "10"], "--size 10: must be HEIGHTxWIDTH in pixels, e.g. 240x320"),
        (["--size", "10x640"], "height and width must each be in 16..4096"),
        (["--rooms", "0"], "argument --rooms: expected a positive integer, got '0'"),
        (["--rooms", "2"], "needs at least 3 rooms"),
        (["--frames-per-room", "-1"], "argument --frames-per-room"),
        (["--from", str(tmp_path)], "--from does not apply to synthrooms"),
        (["--limit", "2"], "--limit does not apply to synthrooms"),
    ]
    for extra, message in bad:
        code, stdout, err = run(capsys, "datasets", "prepare", "synthrooms", "--out",
                                tmp_path / "never", *extra)
        assert code == 2 and stdout == "", extra
        assert err.count("\n") == 1 and message in err, (extra, err)
    assert not (tmp_path / "never").exists()
    code, _, err = run(capsys, "datasets", "prepare", "nyuv2", "--out", tmp_path / "never")
    assert code == 2 and "nyuv2 needs --from DIR" in err
    code, _, err = run(capsys, "datasets", "prepare", "nyuv2", "--from", tmp_path, "--rooms", 3)
    assert code == 2 and "--rooms applies to synthrooms only" in err


def test_trajectory_hook_defaults_unchanged():
    from evsmap.synth.trajectory import room_trajectory

    plain = room_trajectory((5.0, 4.2, 2.6), 9, seed=3)
    explicit = room_trajectory((5.0, 4.2, 2.6), 9, seed=3, inset=1.3, eye_height=1.45,
                               pitch=-0.32)
    for a, b in zip(plain, explicit, strict=True):
        assert np.array_equal(a, b)
