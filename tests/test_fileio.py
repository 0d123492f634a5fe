"""evsmap.fileio: a file written atomically is either the old one or the complete new one."""

from __future__ import annotations

import os
import stat

import pytest

from evsmap.fileio import atomic_path, atomic_write, atomic_write_bytes, atomic_write_text


def test_a_complete_write_replaces_the_file_with_the_umask_mode(tmp_path):
    target = tmp_path / "out.json"
    target.write_text("old")
    old_mask = os.umask(0o022)
    try:
        atomic_write_text(target, "new", durable=True)
    finally:
        os.umask(old_mask)
    assert target.read_text() == "new"
    assert stat.S_IMODE(target.stat().st_mode) == 0o644  # not mkstemp's 0600
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]


def test_an_error_mid_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "map.ot"
    target.write_bytes(b"complete old map")
    with pytest.raises(RuntimeError), atomic_write(target, "wb") as fh:
        fh.write(b"half a new m")
        raise RuntimeError("the writer failed")
    assert target.read_bytes() == b"complete old map"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.ot"]


def test_a_writer_that_writes_nothing_does_not_publish(tmp_path):
    target = tmp_path / "cloud.ply"
    with pytest.raises(OSError, match="nothing was written"), \
            atomic_path(target, suffix=".ply") as tmp:
        assert tmp.name.endswith(".ply") and tmp.parent == tmp_path
    assert not target.exists()


def test_bytes_and_text_modes(tmp_path):
    atomic_write_bytes(tmp_path / "a.bin", b"\x00\x01")
    assert (tmp_path / "a.bin").read_bytes() == b"\x00\x01"
    with pytest.raises(ValueError, match="mode"), atomic_write(tmp_path / "b", "a"):
        pass


def test_atomic_write_creates_the_missing_folders_above(tmp_path):
    """The output policy: a folder above an output that does not exist yet is made when the
    file is written (the commands checked beforehand that it can be)."""
    target = tmp_path / "new" / "deeper" / "map.json"
    atomic_write_text(target, "{}")
    assert target.read_text() == "{}"
    assert sorted(p.name for p in target.parent.iterdir()) == ["map.json"]
