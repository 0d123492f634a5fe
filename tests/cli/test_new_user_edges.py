"""The edges a new user meets first (issue 35): outputs that never lose work, one weights policy,
warnings for results that are empty in practice, messages that name the culprit."""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path

import numpy as np
import pytest
import torch

from evsmap.cli import outputs as outputs_module
from evsmap.cli.main import main
from evsmap.cli.map_cmd import empty_result_warnings, range_warning
from evsmap.cli.outputs import Output, claim_outputs
from evsmap.data import Frame, Intrinsics
from evsmap.errors import EvsmapError
from evsmap.measure.range_survey import ray_lengths, survey_indices, survey_ranges


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def error_line(code: int, err: str) -> str:
    """The one error line of a refused command (notes and warnings aside)."""
    assert code == 2, err
    lines = [x for x in err.strip().splitlines() if ": error: " in x]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


# -- the output policy ------------------------------------------------------------------------
def test_claim_outputs_rules(tmp_path):
    existing = tmp_path / "map.ot"
    existing.write_text("precious")
    with pytest.raises(EvsmapError, match=r"^--out .*map\.ot: exists \(pass --overwrite"):
        claim_outputs([Output("--out", existing)], overwrite=False)
    claim_outputs([Output("--out", existing)], overwrite=True)  # allowed, nothing touched
    assert existing.read_text() == "precious"
    with pytest.raises(EvsmapError, match="must end in .ot or .bt"):
        claim_outputs([Output("--out", tmp_path / "map.txt", suffixes=(".ot", ".bt"))],
                      overwrite=False)
    with pytest.raises(EvsmapError, match="is a folder; give a file name"):
        claim_outputs([Output("--out", tmp_path)], overwrite=True)
    with pytest.raises(EvsmapError, match="exists and is a file, not a folder"):
        claim_outputs([Output("--out", existing, folder=True)], overwrite=True)
    full = tmp_path / "full"
    full.mkdir()
    (full / "x").write_text("x")
    with pytest.raises(EvsmapError, match="folder exists and is not empty"):
        claim_outputs([Output("--out", full, folder=True)], overwrite=False)
    (tmp_path / "empty").mkdir()
    claim_outputs([Output("--out", tmp_path / "empty", folder=True)], overwrite=False)
    with pytest.raises(EvsmapError, match="--out and --ply name the same path"):
        claim_outputs([Output("--out", tmp_path / "a"), Output("--ply", tmp_path / "a")],
                      overwrite=False)
    # a folder that does not exist yet is fine where the folder above it takes files
    claim_outputs([Output("--out", tmp_path / "new" / "deeper" / "m.ot")], overwrite=False)
    assert not (tmp_path / "new").exists()  # created only when written
    with pytest.raises(EvsmapError, match=r"map\.ot is a file, not a folder"):
        claim_outputs([Output("--out", existing / "m.ot")], overwrite=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty", "full", "map.ot"]


def test_claim_outputs_names_an_unwritable_folder_once(tmp_path, monkeypatch):
    real_open = os.open

    def refuse(path, *args, **kwargs):
        if ".evsmap-write-check" in str(path):
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return real_open(path, *args, **kwargs)

    monkeypatch.setattr(outputs_module.os, "open", refuse)
    with pytest.raises(EvsmapError) as info:
        claim_outputs([Output("--out", tmp_path / "m.ot")], overwrite=False)
    message = str(info.value)
    assert message == f"--out {tmp_path / 'm.ot'}: cannot write in {tmp_path} (Permission denied)"


def test_map_refuses_an_existing_map_and_overwrites_only_when_asked(tmp_path, capsys):
    out = tmp_path / "precious.ot"
    out.write_bytes(b"a 36-frame map")
    base = ("map", "synthetic", "--updater", "orgb", "--frames", "1", "--resolution", "0.2",
            "--out", out)
    line = error_line(*run(capsys, *base)[::2])
    assert line == f"evsmap map: error: --out {out}: exists (pass --overwrite to replace it)"
    assert out.read_bytes() == b"a 36-frame map"
    code, _, err = run(capsys, *base, "--overwrite")
    assert code == 0, err
    assert out.read_bytes().startswith(b"# Octomap OcTree file")


def test_map_checks_its_outputs_before_any_frame_is_mapped(tmp_path, capsys, monkeypatch):
    import evsmap.measure.mapping as mapping

    def never(*args, **kwargs):
        raise AssertionError("mapped before the outputs were checked")

    monkeypatch.setattr(mapping, "map_sequence", never)
    real_open = os.open

    def read_only(path, *args, **kwargs):
        if ".evsmap-write-check" in str(path) and Path(path).parent == tmp_path / "ro":
            raise OSError(errno.EROFS, "Read-only file system", str(path))
        return real_open(path, *args, **kwargs)

    monkeypatch.setattr(outputs_module.os, "open", read_only)
    (tmp_path / "ro").mkdir()
    code, _, err = run(capsys, "map", "synthetic", "--updater", "orgb", "--out",
                       tmp_path / "ok.ot", "--ply", tmp_path / "ro" / "cloud.ply")
    assert error_line(code, err) == (f"evsmap map: error: --ply {tmp_path / 'ro' / 'cloud.ply'}"
                                     f": cannot write in {tmp_path / 'ro'} (Read-only file "
                                     f"system)")
    assert err.count(str(tmp_path / "ro")) == 2  # the path once, and its folder once


def test_synth_and_predict_check_their_folder_up_front(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    line = error_line(*run(capsys, "synth", "--out", blocker / "seq", "--frames", "1")[::2])
    assert line.endswith(f"--out {blocker / 'seq'}: {blocker} is a file, not a folder")
    line = error_line(*run(capsys, "predict", "oracle", "synthetic", "--out",
                           blocker / "pred")[::2])
    assert line.endswith(f"--out {blocker / 'pred'}: {blocker} is a file, not a folder")


# -- warnings for results that are empty in practice ------------------------------------------
def test_ray_lengths_of_images_and_clouds():
    depth = np.zeros((3, 4), dtype=np.float32)
    depth[1, 2] = 2.0  # on the principal point: the ray length is the depth
    depth[0, 0] = 1.0
    intr = Intrinsics(fx=1.0, fy=1.0, cx=2.0, cy=1.0, width=4, height=3)
    frame = Frame(rgb=np.zeros((3, 4, 3), np.uint8), depth=depth, intrinsics=intr,
                  pose=np.eye(4), timestamp=0.0)
    lengths = sorted(ray_lengths(frame))
    assert lengths == pytest.approx([2.0, np.sqrt(1 + 4 + 1)])
    cloud = Frame.from_points(np.array([[3, 4, 0], [0, 0, 10]], np.float32), np.eye(4), 0.0)
    assert sorted(ray_lengths(cloud)) == pytest.approx([5.0, 10.0])
    survey = survey_ranges([(0, cloud), (4, cloud)], max_range=6.0)
    assert (survey.frames, survey.points, survey.beyond) == ((0, 4), 4, 2)
    assert survey.share_beyond == 0.5 and range_warning(survey) is None  # not most
    far = survey_ranges([(0, cloud)], max_range=4.0)
    assert "100 % of the points of frames 0 lie beyond --max-range 4 m" in range_warning(far)
    assert survey_indices(100) == [0, 50, 99] and survey_indices(1) == [0]


def test_lidar_bag_with_the_rgbd_range_warns_twice_and_says_the_fix(lidar_bag, capsys):
    code, out, err = run(capsys, "map", lidar_bag, "--updater", "orgb", "--frames", "3",
                         "--resolution", "0.2", "--json")
    assert code == 0, err
    warnings = [x for x in err.splitlines() if x.startswith("evsmap map: warning:")]
    assert len(warnings) == 2, err
    assert "100 % of the points of frames 0, 1, 2 lie beyond --max-range 5 m" in warnings[0]
    assert "Pass --max-range " in warnings[0] and "or -1 for no limit" in warnings[0]
    assert warnings[1] == ("evsmap map: warning: the map holds no occupied voxel, only free "
                           "space (most points lie beyond --max-range 5 m, see above)")
    record = json.loads(out)
    assert record["occupied_voxels"] == 0 and record["range_survey"]["share_beyond"] == 1.0
    code, out, err = run(capsys, "map", lidar_bag, "--updater", "orgb", "--frames", "1",
                         "--resolution", "0.5", "--max-range", "-1", "--json")
    assert code == 0 and "warning" not in err.replace("stamps do not overlap", ""), err
    assert json.loads(out)["occupied_voxels"] > 0


@pytest.fixture(scope="module")
def mostly_broken(tmp_path_factory):
    """A 5-frame synthetic sequence whose depth images 1, 2 and 3 are truncated."""
    out = tmp_path_factory.mktemp("broken") / "seq"
    assert main(["synth", "--out", str(out), "--frames", "5", "--width", "80",
                 "--height", "60"]) == 0
    depth = sorted((out / "depth").iterdir(), key=lambda p: float(p.stem))
    for path in depth[1:4]:
        path.write_bytes(path.read_bytes()[:40])
    return out


@pytest.mark.parametrize("argv", [
    ("map", "{seq}", "--updater", "orgb", "--resolution", "0.2"),
    ("eval", "oracle", "--dataset", "{seq}"),
    ("predict", "oracle", "{seq}", "--out", "{tmp}/pred"),
], ids=["map", "eval", "predict"])
def test_most_frames_skipped_is_a_warning(mostly_broken, tmp_path, capsys, argv):
    argv = [a.format(seq=mostly_broken, tmp=tmp_path) for a in argv]
    code, _, err = run(capsys, *argv, "--skip-bad")
    assert code == 0, err
    assert (f"evsmap {argv[0]}: warning: 3 of 5 frames were skipped as unreadable (--skip-bad); "
            f"the result stands on 2 (the reasons are in the record's 'skipped')") in err


def test_a_map_of_free_space_only_writes_no_ply():
    class Args:
        max_range = 5.0
        ply = Path("cloud.ply")

    record = {"frames": 4, "occupied_voxels": 0, "range_survey": {"share_beyond": 0.1}}
    assert empty_result_warnings(record, Args()) == [
        "the map holds no occupied voxel, only free space; no PLY was written"]


def test_ply_of_a_cpp_octomap_says_what_to_do_instead(capsys):
    line = error_line(*run(capsys, "map", "synthetic", "--updater", "octomap-cpp", "--ply",
                           "cloud.ply", "--frames", "1")[::2])
    assert line == ("evsmap map: error: --ply: updater 'octomap-cpp' keeps its map in C++ "
                    "OctoMap, which evsmap cannot list as points; write it with --out (.ot or "
                    ".bt, for octovis) or map with one of evsmap's updaters")
    assert "OctoMapAdapter" not in line


# -- one weights policy -----------------------------------------------------------------------
@pytest.mark.parametrize("command", ["map", "eval", "predict", "speed"])
def test_every_network_command_has_the_same_weights_options(command):
    from evsmap.cli.main import build_parser

    sub = build_parser()._subparsers._group_actions[0].choices[command]
    options = {s for a in sub._actions for s in a.option_strings}
    assert {"--weights", "--allow-random", "--seed"} <= options


def test_a_text_file_as_weights_names_the_file_and_what_it_is(tmp_path, capsys):
    text = tmp_path / "notes.txt"
    text.write_text("hello, these are not weights")
    line = error_line(*run(capsys, "eval", "feagnet-v1", "--dataset", "synthetic",
                           "--weights", text)[::2])
    assert line == (f"evsmap eval: error: {text}: not a PyTorch checkpoint (a torch.save file "
                    f"is a zip archive; this one starts with b'hello, t')")
    line = error_line(*run(capsys, "eval", "oracle", "--dataset", "synthetic", "--weights",
                           text)[::2])
    assert line.endswith(f"--weights {text}: oracle is not a network and takes no weights "
                         f"(drop --weights)")


def test_speed_takes_weights_and_states_them(tmp_path, capsys):
    from evsmap.segmenters.create import create_segmenter

    weights = tmp_path / "v1.pt"
    net = create_segmenter("feagnet-v1", init_seed=9)
    torch.save(net.module.state_dict(), weights)
    code, out, err = run(capsys, "speed", "feagnet-v1", "--weights", weights, "--height", "64",
                         "--width", "64", "--runs", "1", "--warmup", "0", "--json")
    assert code == 0 and err == "", err
    record = json.loads(out)
    assert (record["weights"], record["random_weights"], record["init_seed"]) == \
        (str(weights), False, None)


# -- messages that name the culprit -----------------------------------------------------------
def test_info_and_map_take_the_synthetic_reader_by_name(capsys):
    code, out, err = run(capsys, "info", "synthetic", "-r", "frames=2", "-r", "width=64",
                         "-r", "height=48")
    assert code == 0, err
    assert "reader: synthetic" in out and "frames      2" in out
    code, _, err = run(capsys, "map", "synthetic", "--reader", "synthetic", "--updater",
                       "orgb", "--frames", "1", "--resolution", "0.2")
    assert code == 0, err


def test_a_pathless_reader_with_a_path_says_what_to_do(tmp_path, capsys):
    line = error_line(*run(capsys, "map", tmp_path, "--reader", "synthetic", "--updater",
                           "orgb")[::2])
    assert line == (f"evsmap map: error: reader 'synthetic' takes no path: give 'synthetic' as "
                    f"the sequence (not '{tmp_path}'), or leave out --reader to read "
                    f"'{tmp_path}' with the reader its layout needs")


def test_eval_finds_a_sample_by_name_and_names_the_split_option(nyuv2_samples_dir, capsys,
                                                                monkeypatch):
    monkeypatch.setenv("EVSMAP_DATA_ROOT", str(nyuv2_samples_dir.parent))
    line = error_line(*run(capsys, "eval", "oracle", "--dataset", nyuv2_samples_dir.name)[::2])
    assert "split file not found" in line and "--split all" in line
    code, out, err = run(capsys, "eval", "oracle", "--dataset", nyuv2_samples_dir.name,
                         "--split", "all", "--limit", "1")
    assert code == 0, err
    line = error_line(*run(capsys, "eval", "oracle", "--dataset", "no_such_dataset")[::2])
    assert "no_such_dataset: no such file or folder, nor a dataset of that name" in line
