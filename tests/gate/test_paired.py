"""The paired gate (``evsmap gate --against REF``): verdicts from paired ratios, the choice
between the stored figures and a reference commit, the git facts it stands on, and a real run
on a copy of this tree that fails on a planted slowdown and a planted allocation."""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from evsmap.errors import EvsmapError
from evsmap.gate.compare import compare_paired, summary, table
from evsmap.paths import REPO_ROOT
from evsmap.testing import missing

MiB = 2**20
GIT_ENV = {"GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@example.org",
           "GIT_COMMITTER_NAME": "t", "GIT_COMMITTER_EMAIL": "t@example.org"}


def rec(time_ratio=10.0, peak=200 * MiB, calibration="compute", workload_ms=100.0, **counts):
    return {"name": "w", "time_ratio": time_ratio, "peak_rss_bytes": peak,
            "calibration": calibration, "workload_ms": workload_ms,
            "counts": counts or {"params": 7}}


def rows_of(rows, measure):
    return [r for r in rows if r.measure == measure]


# -- verdicts ---------------------------------------------------------------------------------


def test_the_verdict_is_the_median_of_the_paired_ratios():
    # the machine slowed during pair 2 (both sides 1.5x): paired ratios stay at 1.0, 1.3, 1.3
    pairs = {"w": [(rec(10.0), rec(10.0)), (rec(15.0), rec(19.5)), (rec(10.0), rec(13.0))]}
    (row,) = rows_of(compare_paired(pairs), "time_ratio")
    assert row.change == pytest.approx(0.30) and row.verdict == "FAIL"
    assert "above the reference" in row.why
    assert row.baseline == 10.0 and row.now == 13.0  # the medians of each side
    pairs = {"w": [(rec(10.0), rec(11.0)), (rec(15.0), rec(16.0)), (rec(10.0), rec(10.5))]}
    assert rows_of(compare_paired(pairs), "time_ratio")[0].verdict == "ok"
    pairs = {"w": [(rec(10.0), rec(8.0))]}
    assert rows_of(compare_paired(pairs), "time_ratio")[0].verdict == "better"


def test_a_peak_fails_above_10_percent_and_the_slack():
    grown = {"w": [(rec(peak=200 * MiB), rec(peak=240 * MiB))]}
    assert rows_of(compare_paired(grown), "peak_rss_bytes")[0].verdict == "FAIL"
    small = {"w": [(rec(peak=10 * MiB), rec(peak=11.5 * MiB))]}  # +15 % but 1.5 MiB
    assert rows_of(compare_paired(small), "peak_rss_bytes")[0].verdict == "ok"


def test_every_count_is_held_against_the_reference():
    pairs = {"w": [(rec(params=7, output_sha256="aa"), rec(params=7, output_sha256="bb"))]}
    (row,) = rows_of(compare_paired(pairs), "output_sha256")
    assert row.verdict == "FAIL" and "differs from the reference" in row.why


def test_other_calibrations_are_judged_on_raw_times():
    pairs = {"w": [(rec(10.0, workload_ms=100.0),
                    rec(5.0, calibration="memory", workload_ms=140.0))]}
    (row,) = rows_of(compare_paired(pairs), "time_ratio")
    assert row.change == pytest.approx(0.40) and row.verdict == "FAIL"
    assert "judged on raw times" in row.why


def test_workloads_on_one_side_and_errors():
    pairs = {"gone-wrong": [(rec(), {"name": "gone-wrong", "error": "boom"})],
             "old-fails": [({"name": "old-fails", "error": "no input"}, rec())],
             "no-data": [({"name": "no-data", "skipped": "needs x"},
                          {"name": "no-data", "skipped": "needs x"})]}
    rows = compare_paired(pairs, only_reference=["removed"], only_here={"added": rec()})
    verdict = {r.workload: r.verdict for r in rows if r.measure == "-"}
    assert verdict == {"removed": "FAIL", "gone-wrong": "FAIL", "old-fails": "not compared",
                       "no-data": "FAIL", "added": "new"}
    passed, text = summary(rows, paired=True)
    assert not passed and "gone-wrong" in text and "removed" in text
    assert "another kind" not in text and "better than or new to the reference" in text
    assert "| workload | measure | reference | now |" in table(rows, against="reference")


# -- git ----------------------------------------------------------------------------------------


def _git(root: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True,
                          check=True, env={**os.environ, **GIT_ENV}).stdout.strip()


@pytest.fixture
def repo(tmp_path):
    if shutil.which("git") is None:
        missing("needs git")
    root = tmp_path / "repo"
    root.mkdir()
    _git(root, "init", "-q")
    (root / "benchmarks").mkdir()
    (root / "benchmarks" / "baseline.json").write_text('{"format": 2, "kinds": {}}\n')
    (root / "a.txt").write_text("one\n")
    _git(root, "add", "-A")
    _git(root, "commit", "-qm", "first")
    (root / "a.txt").write_text("two\n")
    _git(root, "commit", "-qam", "second")
    return root


def test_git_facts(repo, tmp_path):
    from evsmap.gitinfo import export_tree, last_commit_of, resolve_commit, toplevel

    assert toplevel(repo / "benchmarks" / "baseline.json") == repo.resolve()
    assert toplevel(tmp_path / "elsewhere.json") is None
    first = _git(repo, "rev-parse", "HEAD~1")
    assert last_commit_of(repo / "benchmarks" / "baseline.json") == first
    assert last_commit_of(repo / "untracked.json") is None
    assert resolve_commit(repo, "HEAD~1") == first
    with pytest.raises(EvsmapError, match="--against nope: no such commit, branch or tag"):
        resolve_commit(repo, "nope")
    export_tree(repo, first, tmp_path / "out")
    assert (tmp_path / "out" / "a.txt").read_text() == "one\n"
    assert (repo / "a.txt").read_text() == "two\n"  # the checkout itself is untouched


def test_a_shallow_clone_is_named(repo, tmp_path):
    from evsmap.gitinfo import resolve_commit

    clone = tmp_path / "shallow"
    subprocess.run(["git", "clone", "-q", "--depth", "1", f"file://{repo}", str(clone)],
                   check=True, capture_output=True)
    with pytest.raises(EvsmapError, match="this clone is shallow"):
        resolve_commit(clone, "HEAD~1")


# -- which comparison ----------------------------------------------------------------------------


def _args(baseline, **kw):
    return argparse.Namespace(**{"baseline": Path(baseline), "against": None, "stored": False,
                                 "update": False, "only": None, **kw})


def _data(kind, commit="c0ffee"):
    return {"format": 2, "kinds": {kind: {"updated": "2026-01-01T00:00:00+00:00",
                                          "commit": commit, "workloads": {},
                                          "machine": {"cpu": "Some CPU",
                                                      "instruction_set": "avx2", "cpus": 2}}}}


HERE = {"kind": "thiskind", "cpu": "This CPU", "instruction_set": "avx512-vnni", "cpus": 2}


def test_the_stored_figures_of_this_kind_are_used_when_the_baseline_has_them(repo):
    from evsmap.cli.gate_cmd import choose_comparison

    c = choose_comparison(_args(repo / "benchmarks" / "baseline.json"), _data("thiskind"), HERE)
    assert c.mode == "stored" and "has figures of this machine kind" in c.why


def test_another_kind_pairs_with_the_commit_that_last_changed_the_baseline(repo):
    from evsmap.cli.gate_cmd import choose_comparison

    path = repo / "benchmarks" / "baseline.json"
    c = choose_comparison(_args(path), _data("otherkind"), HERE)
    assert c.mode == "paired" and c.commit == _git(repo, "rev-parse", "HEAD~1")
    assert "no figures of this machine kind (This CPU, avx512-vnni, 2 cores; it has: Some " \
           "CPU, avx2, 2 cores)" in c.why and "the last to change" in c.why
    c = choose_comparison(_args(path, stored=True), _data("otherkind"), HERE)
    assert c.mode == "counts" and c.entry is not None
    c = choose_comparison(_args(path, against="HEAD"), _data("thiskind"), HERE)
    assert c.mode == "paired" and c.commit == _git(repo, "rev-parse", "HEAD")


def test_a_shallow_clone_does_not_pair_with_its_cut_and_says_so(repo, tmp_path):
    from evsmap.cli.gate_cmd import choose_comparison

    clone = tmp_path / "shallow"
    subprocess.run(["git", "clone", "-q", "--depth", "1", f"file://{repo}", str(clone)],
                   check=True, capture_output=True)
    path = clone / "benchmarks" / "baseline.json"
    c = choose_comparison(_args(path), _data("otherkind"), HERE)
    assert c.mode == "counts" and "this clone is shallow" in c.why


def test_an_uncommitted_baseline_of_another_kind_compares_counts_and_says_why(tmp_path):
    from evsmap.cli.gate_cmd import choose_comparison

    c = choose_comparison(_args(tmp_path / "b.json"), _data("otherkind"), HERE)
    assert c.mode == "counts" and "is not committed in a git checkout" in c.why


def test_update_only_on_a_new_kind_is_refused(repo):
    from evsmap.cli.gate_cmd import choose_comparison

    path = repo / "benchmarks" / "baseline.json"
    with pytest.raises(EvsmapError, match="record every workload the first time"):
        choose_comparison(_args(path, update=True, only=["read/*"]), _data("otherkind"), HERE)
    assert choose_comparison(_args(path, update=True), _data("otherkind"), HERE).mode == "record"


def test_the_cli_refuses_against_with_update_or_stored(capsys):
    from evsmap.cli.main import main

    for extra in (["--update"], ["--stored"]):
        assert main(["gate", "--against", "HEAD", *extra]) == 2
        assert "exclude each other" in capsys.readouterr().err


# -- the reference's side ----------------------------------------------------------------------


def test_the_dependency_digest_follows_the_lock_and_dependencies_only(tmp_path):
    from evsmap.gate.paired import dependency_digest

    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "constraints.txt").write_text("numpy==2.4.6\n")
        (tmp_path / name / "pyproject.toml").write_text(
            '[project]\nname = "x"\ndependencies = ["numpy"]\n[tool.ruff]\nline-length = 1\n')
    (tmp_path / "b" / "pyproject.toml").write_text(
        '[project]\nname = "x"\ndependencies = ["numpy"]\n[tool.ruff]\nline-length = 2\n')
    assert dependency_digest(tmp_path / "a") == dependency_digest(tmp_path / "b")
    (tmp_path / "b" / "constraints.txt").write_text("numpy==2.4.7\n")
    assert dependency_digest(tmp_path / "a") != dependency_digest(tmp_path / "b")


def test_a_reference_without_the_paired_gate_is_named(tmp_path):
    from evsmap.gate.paired import prepare_reference
    from evsmap.gate.run import Checkout

    old = tmp_path / "old"
    (old / "evsmap" / "gate").mkdir(parents=True)
    (old / "evsmap" / "__init__.py").write_text("")
    (old / "evsmap" / "gate" / "__init__.py").write_text("")
    checkout = Checkout(python=sys.executable, cwd=old, env={"PYTHONPATH": str(old)})
    with pytest.raises(EvsmapError, match="predates the paired gate"):
        prepare_reference(checkout, tmp_path / "w", threads=1, cpu=0, patterns=None,
                          commit="0123456789abcdef")


# -- end to end ---------------------------------------------------------------------------------

SLOWDOWN = '''
            self.frames = [seq[i] for i in range(len(seq))]
            if self.reader != "tum":  # planted: the bag read takes several times as long
                import time as _t
                _start = _t.perf_counter()
                [seq[i] for i in range(len(seq))]
                _t.sleep(3 * (_t.perf_counter() - _start))
            else:  # planted: 40 MiB more held while the TUM frames are read
                self._ballast = np.ones(5 * 2**20)
'''


def _copy_of_this_tree(dest: Path) -> None:
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for name in ("evsmap", "baselines"):
        shutil.copytree(REPO_ROOT / name, dest / name, ignore=ignore)
    for name in ("pyproject.toml", "constraints.txt"):
        shutil.copy2(REPO_ROOT / name, dest / name)
    (dest / "benchmarks").mkdir()
    shutil.copy2(REPO_ROOT / "benchmarks" / "baseline.json", dest / "benchmarks")


def test_a_paired_run_fails_on_a_planted_slowdown_and_allocation(tmp_path):
    """This tree copied into a new repository and committed (the reference); the bag reader's
    workload slowed 2x and the TUM reader's given 40 MiB more in the working tree; both sides
    measured in pairs: the two planted regressions fail, named, and the counts agree."""
    from evsmap.testing import require_sample

    require_sample("lidar-odometry-bag")
    require_sample("tum-fr1-xyz")
    if shutil.which("git") is None:
        missing("needs git")
    root = tmp_path / "repo"
    root.mkdir()
    _copy_of_this_tree(root)
    _git(root, "init", "-q")
    _git(root, "add", "-A")
    _git(root, "commit", "-qm", "reference")
    code = root / "evsmap" / "gate" / "workloads.py"
    text = code.read_text()
    anchor = "\n            self.frames = [seq[i] for i in range(len(seq))]\n"
    assert anchor in text
    code.write_text(text.replace(anchor, SLOWDOWN, 1))
    from evsmap.paths import DATA_ROOT_ENV, default_data_root

    env = {**os.environ, "PYTHONPATH": str(root), DATA_ROOT_ENV: str(default_data_root())}
    r = subprocess.run([sys.executable, "-m", "evsmap", "gate", "--only", "read/rosbag",
                        "read/tum", "--against", "HEAD", "--budget", "0.5", "--confirm", "1",
                        "--json", "--baseline", str(root / "benchmarks" / "baseline.json")],
                       cwd=root, env=env, capture_output=True, text=True, timeout=900)
    assert r.returncode == 1, r.stderr[-2000:]
    out = json.loads(r.stdout)
    assert out["comparison"]["mode"] == "paired"
    assert "this interpreter and libraries" in out["reference_environment"]
    verdict = {(row["workload"], row["measure"]): row["verdict"] for row in out["rows"]}
    assert verdict[("read/rosbag", "time_ratio")] == "FAIL"
    assert verdict[("read/tum", "peak_rss_bytes")] == "FAIL"
    assert not [row for row in out["rows"] if row["measure"] in ("frames", "frames_sha256")]
    assert set(out["reference"]) == {"read/rosbag", "read/tum"}


def test_a_reference_with_another_lock_gets_its_own_environment(tmp_path, monkeypatch):
    """The commands that build it (venv, torch pinned alone, the source through its own lock),
    made once per lock digest; a failed step is one line with pip's last words."""
    from evsmap.gate import paired

    monkeypatch.setenv("EVSMAP_CACHE_DIR", str(tmp_path / "cache"))
    source = tmp_path / "ref"
    source.mkdir()
    (source / "constraints.txt").write_text("numpy==2.4.6\ntorch==2.13.0\n")
    calls = []

    def fake_run(cmd, **kw):
        calls.append(cmd)
        if cmd[1:3] == ["-m", "venv"]:
            Path(cmd[-1]).mkdir(parents=True)
        return subprocess.CompletedProcess(cmd, 0, "", "")

    monkeypatch.setattr(paired.subprocess, "run", fake_run)
    python = paired.own_environment(source, "d1", lambda _: None)
    assert python.endswith("gate/envs/d1/bin/python")
    assert calls[0][1:3] == ["-m", "venv"]
    assert calls[1][-1] == "torch==2.13.0" and str(source / "constraints.txt") in calls[1]
    assert calls[2][-1] == str(source) and "-c" in calls[2]
    calls.clear()
    assert paired.own_environment(source, "d1", lambda _: None) == python and calls == []

    def failing(cmd, **kw):
        return subprocess.CompletedProcess(cmd, 1, "", "ERROR: No matching distribution\n")

    monkeypatch.setattr(paired.subprocess, "run", failing)
    with pytest.raises(EvsmapError, match="cannot build the reference's environment.*No "
                                          "matching distribution"):
        paired.own_environment(source, "d2", lambda _: None)
