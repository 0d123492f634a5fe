"""A write that fails (a full disk: ENOSPC; a read-only folder: EACCES, EROFS) is one line on
stderr naming the file, exit 2, and nothing written before is damaged: the file that was there
keeps its bytes, a folder keeps its files, no temporary file is left.

The failures are simulated (the tests may run as root, where a read-only mode stops nothing):
``open`` for writing under a folder raises the error, or, for ENOSPC, the writes to such a file
fail once a few bytes went through, as on a disk that fills up in the middle of a file."""

from __future__ import annotations

import builtins
import errno
import io
import json
import os
from pathlib import Path

import pytest

from evsmap.cli.main import main
from evsmap.fileio import WriteError, atomic_write_text

CASES = [pytest.param(errno.ENOSPC, id="disk-full"), pytest.param(errno.EACCES, id="read-only"),
         pytest.param(errno.EROFS, id="read-only-fs")]


class _FillingFile:
    """A file whose writes fail with ENOSPC once ``room`` bytes are written."""

    def __init__(self, fh, path: str, room: int) -> None:
        self._fh, self._path, self._room = fh, path, room

    def write(self, data):
        self._room -= len(data)
        if self._room < 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), self._path)
        return self._fh.write(data)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._fh.close()
        return False

    def __iter__(self):
        return iter(self._fh)

    def __getattr__(self, name):
        return getattr(self._fh, name)


def fail_writes(monkeypatch, under: Path, code: int, *, room: int = 64,
                skip: int = 0) -> dict[str, int]:
    """From now on, files opened for writing under ``under`` fail with ``code`` (the first
    ``skip`` of them are written normally). Returns a counter of the files refused."""
    real_open = builtins.open
    under = str(under.resolve())
    seen = {"opened": 0, "failed": 0}

    def fake_open(file, mode="r", *args, **kwargs):
        writing = isinstance(file, (str, os.PathLike)) and any(c in mode for c in "wax+")
        if writing and os.path.abspath(os.fspath(file)).startswith(under):
            seen["opened"] += 1
            if seen["opened"] > skip:
                seen["failed"] += 1
                if code != errno.ENOSPC:
                    raise OSError(code, os.strerror(code), os.fspath(file))
                return _FillingFile(real_open(file, mode, *args, **kwargs), os.fspath(file),
                                    room)
        return real_open(file, mode, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", fake_open)
    monkeypatch.setattr(io, "open", fake_open)
    return seen


def one_line(err: str, path: Path) -> None:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert str(path) in lines[0] and "Traceback" not in err, err


def no_temporaries(folder: Path) -> None:
    left = [p.name for p in folder.rglob(".*") if p.name.endswith(".tmp")
            or ".partial-" in p.name]
    assert not left, left


# ----------------------------------------------------------------------------------- fileio
@pytest.mark.parametrize("code", CASES)
def test_atomic_write_names_the_file_and_keeps_the_old_one(monkeypatch, tmp_path, code):
    target = tmp_path / "record.json"
    target.write_text('{"old": true}')
    fail_writes(monkeypatch, tmp_path, code, room=4)
    with pytest.raises(WriteError) as info:
        atomic_write_text(target, json.dumps({"new": "x" * 100}))
    assert str(info.value).startswith(f"cannot write {target}: ")
    assert isinstance(info.value, OSError)  # callers catching OSError still see it
    assert target.read_text() == '{"old": true}'
    no_temporaries(tmp_path)


# -------------------------------------------------------------------------------------- map
@pytest.mark.parametrize("code", CASES)
def test_map_out_on_a_full_or_read_only_disk(monkeypatch, capsys, tmp_path, code):
    target = tmp_path / "maps" / "map.ot"
    target.parent.mkdir()
    target.write_bytes(b"the map of yesterday")
    fail_writes(monkeypatch, target.parent, code)
    status = main(["map", "synthetic", "--updater", "orgb", "-r", "width=80", "-r", "height=60",
                   "-r", "frames=3", "--out", str(target)])
    err = capsys.readouterr().err
    assert status == 2
    one_line(err, target)
    assert target.read_bytes() == b"the map of yesterday"
    no_temporaries(target.parent)


# -------------------------------------------------------------------------------------- synth
@pytest.mark.parametrize("code", CASES)
def test_synth_out_leaves_no_half_written_sequence(monkeypatch, capsys, tmp_path, code):
    out = tmp_path / "seqs" / "room"
    out.parent.mkdir()
    (out.parent / "keep.txt").write_text("mine")
    fail_writes(monkeypatch, out.parent, code, skip=2)  # a few frames go through first
    status = main(["synth", "--out", str(out), "--frames", "4", "--width", "80", "--height",
                   "60"])
    err = capsys.readouterr().err
    assert status == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and str(out.parent) in lines[0] and "Traceback" not in err, err
    assert not out.exists()
    assert sorted(p.name for p in out.parent.iterdir()) == ["keep.txt"]


# ------------------------------------------------------------------------------ report, runs
@pytest.fixture
def finished_run(tmp_path):
    from tests.report.conftest import make_run

    run = tmp_path / "run"
    make_run(run)
    assert main(["report", str(run)]) == 0
    return run


@pytest.mark.parametrize("code", CASES)
def test_report_keeps_the_previous_report_whole(monkeypatch, capsys, finished_run, code):
    before = {p.name: p.read_bytes() for p in finished_run.iterdir() if p.is_file()}
    capsys.readouterr()
    fail_writes(monkeypatch, finished_run, code, skip=1)
    status = main(["report", str(finished_run)])
    err = capsys.readouterr().err
    assert status == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and str(finished_run) in lines[0] and "Traceback" not in err, err
    after = {p.name: p.read_bytes() for p in finished_run.iterdir() if p.is_file()}
    assert after.keys() == before.keys()
    # each file is the old one or a whole new one (the same records give the same text)
    assert {n: b for n, b in after.items() if not n.endswith(".png")} == \
        {n: b for n, b in before.items() if not n.endswith(".png")}
    no_temporaries(finished_run)
