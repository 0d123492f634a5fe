"""``reproduce --synthetic-labels oracle|network`` and ``--oracle-profile NAME|FILE``: a bad value
is one line and exit 2; the values given are the run's (RunContext, run.json) and a resumed run
keeps them. The cells are faked (in-process, instant)."""

from __future__ import annotations

import json

import pytest
from runner_fixtures import Inline

import evsmap.runner.matrix as matrix
from evsmap.cli.main import main
from evsmap.runner.records import CellRecord
from evsmap.segmenters.oracle_profile import DEFAULT_PROFILE, load_profile

CELLS = "table1/feagnet-v1/complexity*"


@pytest.fixture
def fake_cells(monkeypatch):
    def execute_spec(spec, ctx):
        return CellRecord(key=spec.key, table=spec.table, row=spec.row, label=spec.label,
                          kind=spec.kind, metrics=list(spec.metrics), status="ok",
                          values={m: 1.0 for m in spec.metrics})

    monkeypatch.setattr(matrix, "execute_spec", execute_spec)
    monkeypatch.setattr(matrix, "_spawn_pool", Inline)
    monkeypatch.setattr(matrix, "_fresh_executor", Inline)


def _reproduce(tmp_path, *extra: str) -> int:
    return main(["reproduce", "--quick", "--tables", "I", "--cells", CELLS, "--workers", "1",
                 "--data-root", str(tmp_path), "--out", str(tmp_path / "run"), *extra])


@pytest.mark.parametrize("args, message", [
    (["--oracle-profile", "smooth"], "argument --oracle-profile: oracle: profile 'smooth' is "
                                     "neither one of fitted, per-pixel, noise-free nor a file"),
    (["--synthetic-labels", "proxy"], "argument --synthetic-labels: invalid choice: 'proxy'"),
])
def test_a_bad_value_is_one_line_and_exit_2(tmp_path, capsys, args, message):
    with pytest.raises(SystemExit) as exc:
        _reproduce(tmp_path, *args)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert message in err[-1]
    assert not (tmp_path / "run").exists()


def test_an_unreadable_profile_file_is_refused(tmp_path, capsys):
    bad = tmp_path / "mine.json"
    bad.write_text("{not json")
    with pytest.raises(SystemExit) as exc:
        _reproduce(tmp_path, "--oracle-profile", str(bad))
    assert exc.value.code == 2 and "cannot read profile" in capsys.readouterr().err


def test_the_values_are_the_runs_and_a_resume_keeps_them(tmp_path, fake_cells, capsys,
                                                       monkeypatch):
    profile = tmp_path / "profiles" / "mine.json"
    profile.parent.mkdir()
    profile.write_text(json.dumps(load_profile("per-pixel").to_json()))
    monkeypatch.chdir(profile.parent)  # a file named relative to here is stored absolute
    assert _reproduce(tmp_path, "--synthetic-labels", "network",
                      "--oracle-profile", "mine.json") == 0
    run = json.loads((tmp_path / "run" / "run.json").read_text())
    assert run["settings"]["synthetic_labels"] == "network"
    assert run["settings"]["oracle_profile"] == str(profile)
    assert run["context"]["synthetic_labels"] == "network"
    assert run["context"]["oracle_profile"] == str(profile)
    capsys.readouterr()
    # resuming with another profile would mix records made with two: refused
    code = main(["reproduce", "--resume", "--out", str(tmp_path / "run"),
                 "--oracle-profile", "noise-free"])
    assert code == 2
    assert "made with --oracle-profile" in capsys.readouterr().err
    assert main(["reproduce", "--resume", "--out", str(tmp_path / "run")]) == 0


def test_the_defaults(tmp_path, fake_cells):
    assert _reproduce(tmp_path) == 0
    run = json.loads((tmp_path / "run" / "run.json").read_text())
    assert run["context"]["synthetic_labels"] == "oracle"
    assert run["context"]["oracle_profile"] == DEFAULT_PROFILE
    assert run["sequences"]["synthetic"]["labels"] == \
        f"ground truth (oracle segmenter, profile {DEFAULT_PROFILE})"
