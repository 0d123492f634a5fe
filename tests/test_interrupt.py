"""Ctrl-C and SIGTERM on real ``reproduce``, ``map`` and ``datasets prepare`` runs at random
moments: the command stops, no process of it is left, every file it wrote is whole, it says how
to resume, and the resumed (or repeated) result equals an uninterrupted one (timings aside).
Downloads: tests/datasets/test_fetch.py; training: tests/train/test_train_interrupt.py."""

from __future__ import annotations

import json
import shutil
import signal
from pathlib import Path

import pytest

from tests.interrupt_helpers import (
    LINUX_ONLY,
    RNG,
    SEED,
    START_S,
    assert_whole,
    interrupt,
    run_evsmap,
)

pytestmark = [pytest.mark.slow, LINUX_ONLY]

REPRODUCE_CELLS = ("table1/feagnet-v1/complexity*,table1/feagnet-v2/complexity*,"
                   "table1/feagnet-v1/speed*")


# ------------------------------------------------------------------------------------- reproduce
def _cells(run: Path) -> dict[str, dict]:
    return {r["key"]: r for r in (json.loads(p.read_text())
                                  for p in (run / "records").glob("*.json"))}


@pytest.fixture(scope="module")
def straight_run(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("straight")
    out = tmp / "run"
    run_evsmap(["reproduce", "--quick", "--tables", "I", "--cells", REPRODUCE_CELLS,
                "--workers", "2", "--out", str(out)], tmp)
    return out


@pytest.mark.parametrize(("sig", "group"), [(signal.SIGINT, True), (signal.SIGTERM, False)],
                         ids=["ctrl-c", "sigterm"])
def test_reproduce_interrupted_and_resumed_equals_a_straight_run(straight_run, tmp_path, sig,
                                                                 group):
    out = tmp_path / "run"
    after = RNG.uniform(START_S, 20.0)
    code, err = interrupt(["reproduce", "--quick", "--tables", "I", "--cells", REPRODUCE_CELLS,
                           "--workers", "2", "--out", str(out)], tmp_path, after_s=after,
                          sig=sig, group=group)
    if out.exists():
        assert_whole(out)
    if code == 128 + sig and (out / "run.json").exists():
        assert f"evsmap reproduce --resume --out {out}" in err, err
    if not (out / "run.json").exists():  # stopped before the run began: start it again
        shutil.rmtree(out, ignore_errors=True)
        run_evsmap(["reproduce", "--quick", "--tables", "I", "--cells", REPRODUCE_CELLS,
                    "--out", str(out)], tmp_path)
    else:  # the run's own settings come back from run.json
        run_evsmap(["reproduce", "--resume", "--out", str(out)], tmp_path)
    straight, resumed = _cells(straight_run), _cells(out)
    assert straight.keys() == resumed.keys(), f"seed {SEED}, signal at {after:.2f} s"
    for key, record in straight.items():
        assert resumed[key]["status"] == record["status"] == "ok", key
        if record["kind"] == "complexity":  # deterministic: equal; speed: measured again
            assert resumed[key]["values"] == record["values"], key
    run = json.loads((out / "run.json").read_text())
    assert run["finished"] and run["settings"]["quick"] is True
    assert run["settings"]["cells"] == REPRODUCE_CELLS.split(",")
    assert (out / "table1.md").is_file()


# ------------------------------------------------------------------------------------------ map
MAP = ["map", "synthetic", "--updater", "multiclass-bayes", "-r", "width=160", "-r",
       "height=120", "-r", "frames=40", "--resolution", "0.1"]


@pytest.fixture(scope="module")
def straight_map(tmp_path_factory) -> bytes:
    tmp = tmp_path_factory.mktemp("map")
    run_evsmap([*MAP, "--out", str(tmp / "map.ot")], tmp)
    return (tmp / "map.ot").read_bytes()


def test_map_interrupted_writes_nothing_and_a_rerun_equals_a_straight_one(straight_map,
                                                                         tmp_path):
    target = tmp_path / "maps" / "map.ot"
    target.parent.mkdir()
    target.write_bytes(b"an older map")  # what was there stays until a new map is whole
    after = RNG.uniform(START_S, 8.0)
    code, err = interrupt([*MAP, "--out", str(target), "--overwrite"], tmp_path, after_s=after,
                          sig=signal.SIGTERM)
    assert_whole(target.parent)
    # the old map, or the whole new one when the run finished before the signal took effect
    now = target.read_bytes()
    assert now in (b"an older map", straight_map), f"seed {SEED}"
    if code == 128 + signal.SIGTERM:
        assert ("run the same command again" in err) if now == b"an older map" else \
            (f"{target} is written" in err), err
    run_evsmap([*MAP, "--out", str(target), "--overwrite"], tmp_path)
    assert target.read_bytes() == straight_map


# ------------------------------------------------------------------------------------- prepare
def test_prepare_interrupted_leaves_nothing_and_a_rerun_completes(tmp_path):
    out = tmp_path / "data" / "synthrooms"
    argv = ["datasets", "prepare", "synthrooms", "--out", str(out), "--rooms", "6",
            "--frames-per-room", "3", "--size", "80x60"]
    code, err = interrupt(argv, tmp_path, after_s=RNG.uniform(START_S, 6.0), sig=signal.SIGINT,
                          group=True)
    assert_whole(tmp_path / "data") if (tmp_path / "data").exists() else None
    if code != 0 and not out.exists():
        assert "run the same command again" in err
    elif out.exists():  # finished before the signal took effect: then it is whole
        manifest = json.loads((out / "evsmap-dataset.json").read_text())
        assert manifest["frames"] == 18, f"seed {SEED}: a half-prepared dataset was left"
        if code == 128 + signal.SIGINT:  # (not when it had already exited, -SIGINT)
            assert f"{out} is ready" in err, err
        shutil.rmtree(out)
    run_evsmap(argv, tmp_path)
    manifest = json.loads((out / "evsmap-dataset.json").read_text())
    assert manifest["frames"] == 18
