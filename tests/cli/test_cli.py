import json
import subprocess
import sys

import pytest

from evsmap.cli.main import main


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_list_json(capsys):
    code, out, _ = run(capsys, "list", "--json")
    assert code == 0
    data = json.loads(out)
    assert set(data) == {"segmenters", "updaters", "readers"}
    assert {"tum", "synthetic"} <= set(data["readers"])
    assert all(isinstance(n, str) for v in data.values() for n in v)


def test_list_text_has_descriptions(capsys):
    code, out, _ = run(capsys, "list")
    assert code == 0 and "tum" in out and "TUM RGB-D" in out


def test_synth_then_info(capsys, tmp_path):
    out_dir = tmp_path / "seq"
    code, out, _ = run(capsys, "synth", "--out", str(out_dir), "--frames", "3", "--seed", "2",
                       "--scene", "kitchen", "--width", "80", "--height", "60", "--noise")
    assert code == 0 and "wrote 3 frames" in out
    for name in ("rgb.txt", "depth.txt", "labels.txt", "groundtruth.txt", "intrinsics.txt",
                 "evsmap.json"):
        assert (out_dir / name).is_file()
    assert len(list((out_dir / "depth").glob("*.png"))) == 3
    meta = json.loads((out_dir / "evsmap.json").read_text())
    assert meta["scene"] == "kitchen" and meta["seed"] == 2 and meta["noise"] is True

    code, out, _ = run(capsys, "info", str(out_dir), "--json")
    assert code == 0
    info = json.loads(out)
    assert info["layout"] == "synthetic" and info["frames"] == 3
    assert (info["width"], info["height"]) == (80, 60)
    assert 0.3 < info["depth"]["min_m"] < info["depth"]["max_m"] < 10
    assert info["labels"]["classes_present"] >= 3
    assert info["poses"]["path_length_m"] > 0

    code, out, _ = run(capsys, "info", str(out_dir))
    assert code == 0 and "layout: synthetic" in out and "labels" in out


def test_synth_is_deterministic_on_disk(capsys, tmp_path):
    for name in ("a", "b"):
        assert run(capsys, "synth", "--out", str(tmp_path / name), "--frames", "2",
                   "--width", "48", "--height", "36", "--noise")[0] == 0
    for sub in ("rgb", "depth", "labels"):
        a = sorted((tmp_path / "a" / sub).iterdir())
        b = sorted((tmp_path / "b" / sub).iterdir())
        assert [p.read_bytes() for p in a] == [p.read_bytes() for p in b]
    assert (tmp_path / "a" / "groundtruth.txt").read_text() == \
        (tmp_path / "b" / "groundtruth.txt").read_text()


def test_synth_refuses_to_clobber(capsys, tmp_path):
    out_dir = tmp_path / "seq"
    out_dir.mkdir()
    keep = out_dir / "precious.txt"
    keep.write_text("mine")
    code, _, err = run(capsys, "synth", "--out", str(out_dir), "--frames", "1")
    assert code == 2 and "not empty" in err and "--overwrite" in err
    assert keep.read_text() == "mine"
    # a failing render (bad scene) with --overwrite leaves the folder as it was
    code, _, err = run(capsys, "synth", "--out", str(out_dir), "--frames", "1", "--scene",
                       "attic", "--overwrite")
    assert code == 2 and "unknown scene 'attic'" in err
    assert keep.read_text() == "mine"
    code, _, _ = run(capsys, "synth", "--out", str(out_dir), "--frames", "1", "--width", "32",
                     "--height", "24", "--overwrite")
    assert code == 0 and not keep.exists() and (out_dir / "rgb.txt").is_file()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".seq")]


def test_info_on_real_tum(capsys, tum_dir):
    code, out, _ = run(capsys, "info", str(tum_dir), "--json")
    info = json.loads(out)
    assert code == 0 and info["layout"] == "tum" and info["frames"] == 36
    assert info["labels"] is None
    assert 0.5 < info["depth"]["min_m"] and info["depth"]["max_m"] < 5


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["synth", "--out", "x", "--frames", "0"], "--frames: expected a positive integer"),
        (["synth", "--frames", "2"], "--out"),
        (["info", "/no/such/folder"], "/no/such/folder: no such file or folder"),
        (["info", "."], ".: the folder is empty"),
        (["info", "/proc/self"], "layout not recognised (readers tried"),
        (["frobnicate"], "invalid choice"),
    ],
)
def test_user_errors_exit_2_with_one_line(argv, fragment, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    proc = subprocess.run([sys.executable, "-m", "evsmap", *argv], capture_output=True, text=True)
    assert proc.returncode == 2
    assert fragment in proc.stderr
    assert "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_every_command_has_help():
    for cmd in ("list", "synth", "info", "reproduce"):
        proc = subprocess.run([sys.executable, "-m", "evsmap", cmd, "--help"],
                              capture_output=True, text=True)
        assert proc.returncode == 0 and "usage: evsmap " + cmd in proc.stdout


def test_reproduce_quick_table_iv_then_resume_and_report(capsys, tmp_path, data_root, tum_dir):
    out_dir = tmp_path / "report"
    code, out, err = run(capsys, "reproduce", "--quick", "--tables", "IV", "--out",
                         str(out_dir), "--data-root", str(data_root))
    assert code == 0, err
    assert "0 failed" in out
    run_file = json.loads((out_dir / "run.json").read_text())
    assert run_file["finished"] and run_file["tables"] == ["table4"]
    assert set(run_file["sequences"]) == {"synthetic", "tum"}
    md = (out_dir / "table4.md").read_text()
    assert "| ORGBMap" in md and "/ 3.54 (" in md  # ORGBMap's TUM map measured beside the paper
    assert "n/a / 24.96" in md  # Seq.2 needs the RTAB-Map bag
    assert "## Measured beyond the paper" in md
    records = list((out_dir / "records").glob("*.json"))
    assert len(records) == len(run_file["cells"])
    for name in ("index.md", "table4.csv", "mapping.png", "qualitative.png"):
        assert (out_dir / name).stat().st_size > 100
    # a second run into the same folder is refused; --resume reruns nothing that finished
    code, _, err = run(capsys, "reproduce", "--quick", "--tables", "IV", "--out", str(out_dir))
    assert code == 2 and "--resume" in err
    before = {p.name: p.stat().st_mtime_ns for p in (out_dir / "records").glob("*.json")}
    ok = [p.name for p in (out_dir / "records").glob("*.json")
          if json.loads(p.read_text())["status"] == "ok"]
    code, out, _ = run(capsys, "reproduce", "--quick", "--tables", "IV", "--out", str(out_dir),
                       "--data-root", str(data_root), "--resume")
    assert code == 0
    after = {p.name: p.stat().st_mtime_ns for p in (out_dir / "records").glob("*.json")}
    assert all(before[n] == after[n] for n in ok)
    # resuming with other settings would mix records: refused
    code, _, err = run(capsys, "reproduce", "--no-quick", "--out", str(out_dir), "--resume")
    assert code == 2 and "was made with --quick" in err
    code, _, err = run(capsys, "reproduce", "--quick", "--tables", "I", "--out", str(out_dir),
                       "--resume")
    assert code == 2 and "covers tables table4" in err
    # the report is rebuilt from the records alone
    (out_dir / "table4.md").unlink()
    code, out, _ = run(capsys, "report", str(out_dir))
    assert code == 0 and (out_dir / "table4.md").read_text() == md


@pytest.mark.parametrize("wrapped", [True, False], ids=["inside-compiled-code", "plain"])
def test_a_signal_seen_through_compiled_code_is_still_an_interruption(capsys, monkeypatch,
                                                                      wrapped):
    # numba (loading a cached function) and torch turn an exception raised by a signal handler
    # in their callbacks into SystemError("... returned a result with an exception set")
    import signal

    from evsmap.cli import cache_cmd
    from evsmap.interrupt import Interrupted

    def interrupted_run(args):
        try:
            raise Interrupted(signal.SIGTERM)
        except Interrupted as exc:
            if not wrapped:
                raise
            raise SystemError("CPUDispatcher returned a result with an exception set") from exc

    monkeypatch.setattr(cache_cmd, "run_info", interrupted_run)
    code, _, err = run(capsys, "cache", "info")
    assert code == 128 + signal.SIGTERM
    assert "Traceback" not in err and "SystemError" not in err
    assert "interrupted" in err.lower()


def test_an_unrelated_system_error_is_not_called_an_interruption(capsys, monkeypatch):
    from evsmap.cli import cache_cmd

    def broken_run(args):
        raise SystemError("a real bug")

    monkeypatch.setattr(cache_cmd, "run_info", broken_run)
    with pytest.raises(SystemError, match="a real bug"):
        main(["cache", "info"])
