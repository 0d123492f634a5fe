"""The cache shared across runs: where it is, what it holds, clearing it."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from evsmap import cache


def test_root_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("EVSMAP_CACHE_DIR", str(tmp_path / "c"))
    assert cache.cache_root() == tmp_path / "c"
    assert cache.cache_dir("onnx") == tmp_path / "c" / "onnx"
    with pytest.raises(ValueError, match="unknown cache kind"):
        cache.cache_dir("weights")
    monkeypatch.delenv("EVSMAP_CACHE_DIR")
    assert cache.cache_root().parts[-2:] == (".cache", "evsmap")


def test_info_and_clear(monkeypatch, tmp_path):
    monkeypatch.setenv("EVSMAP_CACHE_DIR", str(tmp_path))
    (tmp_path / "onnx").mkdir()
    (tmp_path / "onnx" / "a.onnx").write_bytes(b"x" * 1000)
    (tmp_path / "segmentation" / "obs-1").mkdir(parents=True)
    (tmp_path / "segmentation" / "obs-1" / "00000.npz").write_bytes(b"y" * 500)
    data = cache.info()
    assert data["kinds"]["onnx"] == {"path": str(tmp_path / "onnx"), "entries": 1, "files": 1,
                                     "bytes": 1000}
    assert data["kinds"]["segmentation"]["entries"] == 1 and data["bytes"] == 1500
    assert cache.clear(["onnx"]) == 1000
    assert not (tmp_path / "onnx").exists() and (tmp_path / "segmentation").exists()


def test_source_digest_changes_with_the_code():
    a = cache.source_digest("evsmap.synth")
    assert len(a) == 12 and a == cache.source_digest("evsmap.synth")
    assert a != cache.source_digest("evsmap.mapping")


def _evsmap(*args, env):
    return subprocess.run([sys.executable, "-m", "evsmap.cli.main", *args], capture_output=True,
                          text=True, env=env)


def test_cli(tmp_path):
    import os

    env = {**os.environ, "EVSMAP_CACHE_DIR": str(tmp_path)}
    (tmp_path / "sequences" / "s").mkdir(parents=True)
    (tmp_path / "sequences" / "s" / "f").write_bytes(b"z" * 2_000_000)
    r = _evsmap("cache", "info", "--json", env=env)
    assert r.returncode == 0 and json.loads(r.stdout)["kinds"]["sequences"]["bytes"] == 2_000_000
    r = _evsmap("cache", "clear", env=env)
    assert r.returncode == 2 and "--all" in r.stderr and "Traceback" not in r.stderr
    r = _evsmap("cache", "clear", "nope", env=env)
    assert r.returncode == 2 and "unknown cache kind 'nope'" in r.stderr
    r = _evsmap("cache", "clear", "sequences", env=env)
    assert r.returncode == 0 and "2.0 MB freed" in r.stdout
    assert not (tmp_path / "sequences").exists()


def test_folder_size_counts_files_and_file_links_but_does_not_enter_linked_folders(tmp_path):
    (tmp_path / "a" / "b").mkdir(parents=True)
    (tmp_path / "a" / "one").write_bytes(b"1" * 10)
    (tmp_path / "a" / "b" / "two").write_bytes(b"2" * 20)
    (tmp_path / "a" / "link").symlink_to(tmp_path / "a" / "one")  # counted: its target's size
    (tmp_path / "a" / "dir-link").symlink_to(tmp_path / "a" / "b")  # not entered
    (tmp_path / "a" / "dangling").symlink_to(tmp_path / "gone")  # skipped
    assert cache.folder_size(tmp_path / "a") == (3, 40)
    assert cache.folder_size(tmp_path / "a" / "one") == (0, 0)  # a file is not a folder
    assert cache.folder_size(tmp_path / "missing") == (0, 0)
