"""``evsmap explore`` on the command line: a study made, resumed to a new target and reported
(and linked from Table IV's section); bad input is one line, exit 2, and a stored study is left
as it was; two processes share one SQLite study; Ctrl-C keeps every finished trial."""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from evsmap.cli.main import main

TINY = ["-r", "frames=3", "-r", "width=64", "-r", "height=48", "-r", "noise=false"]


def _fails(capsys, argv: list[str], expected: str) -> str:
    assert main(["explore", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and expected in err, err
    return err


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.slow
def test_study_made_resumed_and_linked(tmp_path: Path, space_file: Path, capsys) -> None:
    out = tmp_path / "study"
    assert main(["explore", "--space", str(space_file), "--out", str(out), "--trials", "2",
                 *TINY]) == 0
    printed = capsys.readouterr().out
    assert "over 2 trials" in printed and (out / "index.md").is_file()
    # bad input against the stored study: one line, exit 2, the study's bytes unchanged
    before = _digest(out / "study.db")
    _fails(capsys, ["--space", str(space_file), "--out", str(out), *TINY],
           "holds a study already; pass --resume")
    other = tmp_path / "other.toml"
    other.write_text(space_file.read_text().replace("default = 0.6", "default = 0.5"))
    _fails(capsys, ["--space", str(other), "--out", str(out), "--resume"],
           "not the space study 'explore' was made with")
    _fails(capsys, ["--out", str(out), "--resume", "-s", "accuracy=0.5"],
           "-s: the study was made with {}")
    assert _digest(out / "study.db") == before
    # resumed to a new target: one more trial, the report rewritten
    assert main(["explore", "--out", str(out), "--resume", "--trials", "3"]) == 0
    assert "over 3 trials" in capsys.readouterr().out
    from evsmap.explore.latest import latest_study

    latest = latest_study()
    assert latest is not None and latest["index"] == str((out / "index.md").resolve())
    # Table IV's section links it; the gate's build does not read the cache's study
    import tarfile

    from evsmap.gate.workloads import REPORT_FIXTURE
    from evsmap.report.build import build_report

    run = tmp_path / "run"
    with tarfile.open(REPORT_FIXTURE) as tar:
        tar.extractall(run, filter="data")
    build_report(run)
    assert "../study/index.md" in (run / "table4.md").read_text()
    build_report(run, study=None)
    assert "design-space study" not in (run / "table4.md").read_text()


def test_bad_input_is_one_line(tmp_path: Path, space_file: Path, capsys) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(space_file.read_text().replace('name = "psi"', 'name = "psy"'))
    _fails(capsys, ["--space", str(bad), "--out", str(tmp_path / "a")],
           "multiclass-bayes has no option 'psy'")
    assert not (tmp_path / "a").exists()
    _fails(capsys, ["--space", str(space_file), "--out", str(tmp_path / "b"), "--storage",
                    "sqlite:////nonexistent-folder/x/study.db"], "cannot be opened")
    _fails(capsys, ["--space", str(space_file), "--out", str(tmp_path / "c"), "--storage",
                    "nosuchdialect://host/db"], "--storage nosuchdialect://host/db")
    _fails(capsys, ["--out", str(tmp_path / "d"), "--resume"], "no study to resume")
    _fails(capsys, ["--out", str(tmp_path / "e"), "--segmenter", "feagnet-v1"],
           "a network needs --weights FILE")
    _fails(capsys, ["--out", str(tmp_path / "f"), "--updater", "orgb"], "no shipped space")
    _fails(capsys, ["--out", str(tmp_path / "g"), "-s", "acc=1"], "oracle has no option 'acc'")
    (tmp_path / "h").mkdir()
    (tmp_path / "h" / "notes.txt").write_text("mine")
    _fails(capsys, ["--out", str(tmp_path / "h")], "exists and is not empty")
    assert (tmp_path / "h" / "notes.txt").read_text() == "mine"


def _env() -> dict[str, str]:
    root = str(Path(__file__).resolve().parents[2])
    return {**os.environ, "PYTHONPATH": os.pathsep.join([root, os.environ.get("PYTHONPATH",
                                                                               "")])}


def _study(out: Path):
    import optuna

    from evsmap.explore.study import open_storage

    # through evsmap's opening (its creation lock): polling a study file the explore process is
    # still making must not stamp its schema a second time
    return optuna.load_study(study_name="explore",
                             storage=open_storage(f"sqlite:///{out / 'study.db'}"))


@pytest.mark.slow
def test_two_processes_share_one_study(tmp_path: Path, space_file: Path) -> None:
    out, trials = tmp_path / "shared", 10
    argv = [sys.executable, "-m", "evsmap", "explore", "--out", str(out)]
    first = subprocess.Popen([*argv, "--space", str(space_file), "--trials", str(trials),
                              *TINY, "-r", "frames=6"], env=_env(),
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while not (out / "study.db").is_file() and time.monotonic() < deadline:
        time.sleep(0.2)
    time.sleep(1.0)  # the study's first trial is under way
    second = subprocess.Popen([*argv, "--resume"], env=_env(), stdout=subprocess.DEVNULL,
                              stderr=subprocess.PIPE)
    errors = [p.communicate(timeout=600)[1].decode() for p in (first, second)]
    assert first.returncode == 0 and second.returncode == 0, errors
    study = _study(out)
    done = [t for t in study.trials if t.state.name == "COMPLETE"]
    assert len(done) == trials
    pids = {t.user_attrs["worker"]["pid"] for t in done}
    assert pids <= {first.pid, second.pid}
    assert len({t.number for t in done}) == trials
    assert len({tuple(sorted(t.params.items())) for t in done}) == trials  # distinct trials
    assert len(pids) == 2, "both processes completed trials"


@pytest.mark.slow
def test_ctrl_c_keeps_finished_trials(tmp_path: Path, space_file: Path) -> None:
    out = tmp_path / "stopped"
    proc = subprocess.Popen([sys.executable, "-m", "evsmap", "explore", "--out", str(out),
                             "--space", str(space_file), "--trials", "50", *TINY],
                            env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            start_new_session=True)
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        time.sleep(0.5)
        if (out / "study.db").is_file():
            try:
                if sum(t.state.name == "COMPLETE" for t in _study(out).trials) >= 2:
                    break
            except Exception:  # noqa: BLE001 - the file is being made
                continue
    os.killpg(proc.pid, signal.SIGINT)
    err = proc.communicate(timeout=30)[1].decode()
    assert proc.returncode == 130, err
    assert "continue with `evsmap explore --out" in err
    kept = [t.params for t in _study(out).trials if t.state.name == "COMPLETE"]
    assert len(kept) >= 2
    # resumed to one trial more: every finished trial kept, none left running, none twice
    resumed = subprocess.run([sys.executable, "-m", "evsmap", "explore", "--out", str(out),
                              "--resume", "--trials", str(len(kept) + 1)], env=_env(),
                             capture_output=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr.decode()
    trials = _study(out).trials
    done = [t.params for t in trials if t.state.name == "COMPLETE"]
    assert done[:len(kept)] == kept and len(done) == len(kept) + 1
    assert "RUNNING" not in {t.state.name for t in trials}


def test_objectives_without_ground_truth_are_refused_first(tmp_path: Path, tum_dir: Path,
                                                          capsys) -> None:
    out = tmp_path / "tum"
    _fails(capsys, ["--out", str(out), "--sequence", str(tum_dir)],
           "objective scene_miou needs ground-truth voxels")
    assert not (out / "study.db").exists()  # checked before the study was made
