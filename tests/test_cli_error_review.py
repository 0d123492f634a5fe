"""The user errors of ``datasets``, ``weights``, ``cache``, ``gate``, ``report``, ``train`` and
``complexity`` as a new user meets them: one line on stderr, exit status 2, the culprit named,
the fix said; and the output policy (:mod:`evsmap.cli.outputs`) of the commands that write: an
existing output refused without ``--overwrite``, every output checked before any work.

A place that cannot be written is made with a file where a folder is expected (``chmod`` does not
stop root).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from evsmap.cli.main import main


def _fails(capsys, *argv) -> str:
    """Run ``evsmap ARGV``; it must fail as a user error: exit 2, one stderr line, no stdout
    traceback. Returns the line."""
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert code == 2, (code, out, err)
    assert err.count("\n") == 1 and err.endswith("\n"), err
    assert "Traceback" not in err and "Error:" not in err.split(": error: ", 1)[-1], err
    return err


def _named_once(line: str, culprit: object) -> None:
    assert line.count(str(culprit)) == 1, (str(culprit), line)


@pytest.fixture
def blocker(tmp_path) -> Path:
    """A file; a path under it cannot be written."""
    path = tmp_path / "blocker"
    path.write_text("a file, not a folder\n")
    return path


@pytest.fixture
def text_file(tmp_path) -> Path:
    path = tmp_path / "notes.pt"
    path.write_text("not a checkpoint\n")
    return path


# ----------------------------------------------------------------------------- weights
def test_weights_show_a_folder(capsys, tmp_path):
    err = _fails(capsys, "weights", "show", tmp_path)
    assert err.startswith("evsmap weights: error: ") and "is a folder, not a weights file" in err
    assert "evsmap weights list" in err
    _named_once(err, tmp_path)


def test_weights_convert_a_folder_as_src(capsys, tmp_path):
    src = tmp_path / "runs"
    src.mkdir()
    err = _fails(capsys, "weights", "convert", src, "--out", tmp_path / "out.pt")
    assert f"SRC {src}: is a folder" in err
    _named_once(err, src)


def test_weights_convert_refuses_an_existing_out_without_overwrite(capsys, tmp_path, text_file):
    dst = tmp_path / "old.pt"
    dst.write_bytes(b"kept")
    err = _fails(capsys, "weights", "convert", text_file, "--out", dst)
    assert f"--out {dst}: exists (pass --overwrite to replace it)" in err
    _named_once(err, dst)
    assert dst.read_bytes() == b"kept"


def test_weights_convert_force_is_an_alias_of_overwrite(capsys, tmp_path, text_file):
    dst = tmp_path / "old.pt"
    dst.write_bytes(b"kept")
    for flag in ("--overwrite", "--force"):
        err = _fails(capsys, "weights", "convert", text_file, "--out", dst, flag)
        # past the claim of --out: the source is what is wrong now, and the old file stays
        assert str(text_file) in err and "--out" not in err
        assert dst.read_bytes() == b"kept"


def test_weights_convert_checks_out_before_reading_src(capsys, blocker, text_file):
    dst = blocker / "out.pt"
    err = _fails(capsys, "weights", "convert", text_file, "--out", dst)
    assert f"--out {dst}:" in err and "is a file, not a folder" in err
    assert str(text_file) not in err  # the source was not read


def test_weights_convert_out_is_a_folder(capsys, tmp_path, text_file):
    err = _fails(capsys, "weights", "convert", text_file, "--out", tmp_path, "--overwrite")
    assert f"--out {tmp_path}: is a folder; give a file name" in err


# ----------------------------------------------------------------------------- gate
def test_gate_refuses_an_existing_results_file(capsys, tmp_path):
    results = tmp_path / "results.json"
    results.write_text("{}")
    err = _fails(capsys, "gate", "--results", results, "--only", "report/build")
    assert f"--results {results}: exists (pass --overwrite to replace it)" in err
    _named_once(err, results)
    assert results.read_text() == "{}"


def test_gate_checks_results_before_measuring(capsys, blocker, monkeypatch):
    import evsmap.gate.prepare as gate_prepare

    monkeypatch.setattr(gate_prepare, "discover", lambda **kw: pytest.fail("measured"))
    results = blocker / "results.json"
    err = _fails(capsys, "gate", "--results", results)
    assert f"--results {results}:" in err and "is a file, not a folder" in err


def test_gate_results_may_not_be_the_baseline(capsys, tmp_path):
    baseline = tmp_path / "baseline.json"
    baseline.write_text(json.dumps({"workloads": {}}))
    err = _fails(capsys, "gate", "--baseline", baseline, "--results", baseline, "--overwrite")
    assert "is the baseline file" in err
    _named_once(err, baseline)
    assert json.loads(baseline.read_text()) == {"workloads": {}}


def test_gate_overwrite_without_results(capsys):
    err = _fails(capsys, "gate", "--overwrite")
    assert "--overwrite applies to --results FILE only" in err


def test_gate_baseline_is_a_folder(capsys, tmp_path):
    err = _fails(capsys, "gate", "--baseline", tmp_path)
    assert f"--baseline {tmp_path}: is a folder, not a baseline file" in err
    _named_once(err, tmp_path)


def test_gate_update_checks_the_baseline_is_writable(capsys, blocker):
    baseline = blocker / "baseline.json"
    err = _fails(capsys, "gate", "--update", "--baseline", baseline)
    assert f"--baseline {baseline}:" in err and "is a file, not a folder" in err


def test_gate_thread_mismatch_says_the_fix(capsys, tmp_path):
    baseline = tmp_path / "baseline.json"
    from evsmap.gate.baseline import machine_info

    kind = machine_info(2)["kind"]
    baseline.write_text(json.dumps({"machine": {"kind": kind}, "settings": {"threads": 1},
                                    "workloads": {}}))
    err = _fails(capsys, "gate", "--baseline", baseline, "--threads", "2")
    assert "(pass --threads 1)" in err
    _named_once(err, baseline)


def test_gate_negative_confirm_is_refused(capsys):
    with pytest.raises(SystemExit) as exit_:  # an option's value: argparse's one line
        main(["gate", "--confirm", "-1"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1
    assert "argument --confirm: expected an integer >= 0, got '-1'" in err


# ----------------------------------------------------------------------------- cache
def test_cache_clear_all_and_kinds_conflict(capsys, monkeypatch, tmp_path):
    monkeypatch.setenv("EVSMAP_CACHE_DIR", str(tmp_path))
    err = _fails(capsys, "cache", "clear", "--all", "onnx")
    assert "--all clears every kind: leave out onnx" in err


def test_cache_root_is_a_file(capsys, monkeypatch, blocker):
    monkeypatch.setenv("EVSMAP_CACHE_DIR", str(blocker))
    for argv in (["info"], ["clear", "--all"]):
        err = _fails(capsys, "cache", *argv)
        assert "is a file, not a cache folder" in err and "$EVSMAP_CACHE_DIR" in err
        _named_once(err, blocker)


def test_cache_clear_says_what_it_could_not_remove(capsys, monkeypatch, tmp_path):
    from evsmap.cli import cache_cmd

    monkeypatch.setenv("EVSMAP_CACHE_DIR", str(tmp_path))
    (tmp_path / "onnx").mkdir()
    (tmp_path / "onnx" / "model.onnx").write_bytes(b"x" * 10)
    monkeypatch.setattr(cache_cmd, "clear", lambda kinds: 0)  # as if removal were refused
    err = _fails(capsys, "cache", "clear", "onnx")
    assert "1 files" in err and "could not be removed" in err
    _named_once(err, tmp_path / "onnx")


def test_cache_clear_names_a_kind_once(capsys, monkeypatch, tmp_path):
    monkeypatch.setenv("EVSMAP_CACHE_DIR", str(tmp_path))
    assert main(["cache", "clear", "onnx", "onnx"]) == 0
    assert capsys.readouterr().out.startswith("cleared onnx: ")


# ----------------------------------------------------------------------------- report
def test_report_dir_is_a_file(capsys, blocker):
    err = _fails(capsys, "report", blocker)
    assert f"{blocker}: is a file, not a run folder" in err
    _named_once(err, blocker)


def test_report_file_taken_by_a_folder(capsys, tmp_path, monkeypatch):
    import evsmap.report.build as build
    from evsmap.fileio import atomic_write_text

    run = tmp_path / "run"
    (run / "index.md").mkdir(parents=True)

    def fake_build(run_dir):
        atomic_write_text(Path(run_dir) / "table1.md", "kept\n")
        atomic_write_text(Path(run_dir) / "index.md", "index\n")
        return []

    monkeypatch.setattr(build, "build_report", fake_build)
    err = _fails(capsys, "report", run)
    assert f"{run / 'index.md'}: cannot write the report file there" in err
    assert (run / "table1.md").read_text() == "kept\n"  # what was written stays


# ----------------------------------------------------------------------------- complexity
def test_complexity_classes_and_num_classes_disagree(capsys):
    err = _fails(capsys, "complexity", "feagnet-v2", "--classes", "7", "-o", "num_classes=5")
    assert "--classes 7 and -o num_classes=5 disagree" in err


def test_complexity_input_size_option_points_to_height_width(capsys):
    err = _fails(capsys, "complexity", "feagnet-v2", "-o", "input_size=100x100")
    assert "-o input_size=100x100" in err and "--height H --width W" in err


# ----------------------------------------------------------------------------- datasets
def test_datasets_list_root_is_a_file(capsys, blocker):
    err = _fails(capsys, "datasets", "list", "--root", blocker)
    assert f"--root {blocker}: is a file, not a folder" in err


def test_datasets_list_given_root_missing(capsys, tmp_path):
    err = _fails(capsys, "datasets", "list", "--root", tmp_path / "nope")
    assert f"--root {tmp_path / 'nope'}: no such folder" in err and "pass --root" not in err


def test_datasets_list_default_root_missing_is_an_answer(capsys, tmp_path, monkeypatch):
    """A fresh machine: no datasets/ folder yet. The question has an answer (exit 0): nothing
    prepared, where it looked, what evsmap reads and how to prepare it."""
    monkeypatch.chdir(tmp_path)
    code = main(["datasets", "list"])
    out, err = capsys.readouterr()
    assert code == 0 and err == ""
    first, *rest = out.splitlines()
    assert first == (f"no prepared datasets under datasets ({tmp_path.resolve() / 'datasets'}: "
                     "no such folder yet)")
    listed = [line.split()[0] for line in rest[1:5]]
    assert listed == ["nyuv2", "sunrgbd", "cityscapes", "synthrooms"]
    assert "nyu_depth_v2_labeled.mat" in out and "evsmap datasets check scannet" in out
    assert main(["datasets", "list", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == []
    assert not (tmp_path / "datasets").exists()


@pytest.mark.parametrize("kind", ["file", "missing"])
def test_datasets_prepare_from_is_not_a_folder(capsys, tmp_path, blocker, kind):
    source = blocker if kind == "file" else tmp_path / "missing"
    err = _fails(capsys, "datasets", "prepare", "nyuv2", "--from", source,
                 "--out", tmp_path / "out")
    assert f"--from {source}: " in err and "nyu_depth_v2_labeled.mat" in err
    _named_once(err, source)


def test_datasets_prepare_claims_out_before_reading_from(capsys, tmp_path, blocker):
    source = tmp_path / "official"  # empty: reading it would fail
    source.mkdir()
    err = _fails(capsys, "datasets", "prepare", "nyuv2", "--from", source, "--out", blocker)
    assert f"--out {blocker}: exists and is a file, not a folder" in err
    unwritable = blocker / "nyuv2"
    err = _fails(capsys, "datasets", "prepare", "nyuv2", "--from", source, "--out", unwritable)
    assert f"--out {unwritable}:" in err and "is a file, not a folder" in err


def test_datasets_prepare_refuses_a_full_out_without_overwrite(capsys, tmp_path):
    source, out = tmp_path / "official", tmp_path / "out"
    source.mkdir()
    out.mkdir()
    (out / "keep.txt").write_text("kept")
    err = _fails(capsys, "datasets", "prepare", "nyuv2", "--from", source, "--out", out)
    assert f"--out {out}: folder exists and is not empty (pass --overwrite" in err
    assert (out / "keep.txt").read_text() == "kept"


def test_datasets_prepare_out_may_not_replace_from(capsys, tmp_path):
    err = _fails(capsys, "datasets", "prepare", "nyuv2", "--from", tmp_path, "--out", tmp_path)
    assert "would replace the --from folder" in err


def test_datasets_prepare_default_out_is_checked(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    Path("datasets").write_text("a file")
    err = _fails(capsys, "datasets", "prepare", "synthrooms", "--rooms", "3",
                 "--frames-per-room", "1", "--size", "24x32")
    assert err.startswith("evsmap datasets: error: the output folder datasets/synthrooms:")


def test_datasets_prepare_synthrooms_options_named(capsys, tmp_path):
    err = _fails(capsys, "datasets", "prepare", "synthrooms", "--out", tmp_path / "s",
                 "--rooms", "1")
    assert "--rooms 1:" in err and "pass --rooms 3 or more" in err
    err = _fails(capsys, "datasets", "prepare", "synthrooms", "--out", tmp_path / "s",
                 "--size", "24")
    assert "--size 24: must be HEIGHTxWIDTH" in err


@pytest.fixture
def no_download(monkeypatch):
    """A fetch that got past its checks would download: fail instead."""
    import evsmap.fetch

    monkeypatch.setattr(evsmap.fetch, "fetch_sample",
                        lambda *a, **k: pytest.fail("downloaded despite a bad output"))


def test_datasets_fetch_out_is_a_file(capsys, blocker, no_download):
    err = _fails(capsys, "datasets", "fetch", "tum-fr1-xyz", "--out", blocker)
    assert f"--out {blocker}: is a file, not a folder" in err


def test_datasets_fetch_checks_out_before_downloading(capsys, blocker, tmp_path, no_download):
    root = tmp_path / "data"
    (root / "tum_fr1_xyz").mkdir(parents=True)
    (root / "tum_fr1_xyz" / "rgb.txt").write_text("kept")
    err = _fails(capsys, "datasets", "fetch", "tum-fr1-xyz", "--out", root)
    assert "folder exists and is not empty (pass --overwrite" in err
    err = _fails(capsys, "datasets", "fetch", "tum-fr1-xyz", "--out", blocker / "data")
    assert f"--out {blocker / 'data'}" in err and "is a file, not a folder" in err
    err = _fails(capsys, "datasets", "fetch", "tum-fr1-xyz", "--out", tmp_path / "new",
                 "--cache-dir", blocker)
    assert f"--cache-dir {blocker}: is a file, not a folder" in err


def test_datasets_fetch_into_the_shared_folder_says_it_is_there(capsys, tmp_path, monkeypatch,
                                                                no_download):
    import evsmap.paths

    shared = tmp_path / "shared"
    (shared / "tum_fr1_xyz").mkdir(parents=True)
    monkeypatch.setattr(evsmap.paths, "shared_data_dir", lambda: shared)
    monkeypatch.setenv("EVSMAP_DATA_ROOT", str(shared))
    for extra in ([], ["--overwrite"]):  # neither sends the user to the other
        err = _fails(capsys, "datasets", "fetch", "tum-fr1-xyz", *extra)
        assert "already in the shared data folder" in err and "--out DIR" in err


# ----------------------------------------------------------------------------- train
def test_train_out_is_a_file(capsys, blocker):
    err = _fails(capsys, "train", "feagnet-v2", "--dataset", "synthetic", "--out", blocker)
    assert f"--out {blocker}: exists and is a file, not a folder" in err  # the output policy's line
    _named_once(err, blocker)


def test_train_out_cannot_be_written(capsys, blocker):
    out = blocker / "run"
    err = _fails(capsys, "train", "feagnet-v2", "--dataset", "synthetic", "--out", out)
    assert f"--out {out}:" in err and "is a file, not a folder" in err


def test_train_checks_an_existing_folder_is_writable_in_place(tmp_path):
    from evsmap.cli.train_cmd import check_out
    from evsmap.errors import EvsmapError

    run = tmp_path / "run"
    run.mkdir()
    (run / "checkpoint.pt").write_bytes(b"a run to resume")
    check_out(run)  # a resumed run's folder is not refused
    assert sorted(p.name for p in run.iterdir()) == ["checkpoint.pt"]  # the probe is gone
    if Path("/proc/self").is_dir():  # a folder nothing can be created in, even by root
        with pytest.raises(EvsmapError, match=r"--out /proc/self: cannot write in /proc/self"):
            check_out(Path("/proc/self"))
