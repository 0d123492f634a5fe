"""Signals sent to real ``evsmap`` runs at random moments (tests/test_interrupt.py,
tests/train/test_train_interrupt.py).

Each run is a real ``evsmap`` process with a marker in its environment, so every process it
spawned can be found afterwards in ``/proc``. The moments are drawn from a seeded generator whose
seed is in every failure message (``EVSMAP_INTERRUPT_SEED`` replays one). How long a stop takes
is measured by ``benchmarks/interrupt_latency.py``; here a stop must only come within a hang
guard.
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

LINUX_ONLY = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="finds leftover processes through /proc")

EVSMAP = [sys.executable, "-m", "evsmap"]
HANG_S = 30.0
"""A stop that takes longer than this is a hang (the measured stop takes well under 2 s)."""

START_S = 1.0
"""Signals come no earlier than this into a run: before it, Python may still be starting, before
evsmap has set its handlers (a SIGINT then ends in Python's own KeyboardInterrupt; nothing has
been written; docs/robustness.md, "Limits")."""

SEED = int(os.environ.get("EVSMAP_INTERRUPT_SEED") or random.SystemRandom().randrange(10**6))
RNG = random.Random(SEED)

def marked_processes(mark: str) -> list[int]:
    """Live processes whose environment holds ``mark``."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            environ = (entry / "environ").read_bytes()
            state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if mark.encode() in environ and state != "Z":
            found.append(int(entry.name))
    return found


def evsmap_env(tmp_path: Path, mark: str) -> dict[str, str]:
    empty = tmp_path / "no-data"
    empty.mkdir(exist_ok=True)
    return {**os.environ, "EVSMAP_TEST_MARK": mark, "EVSMAP_DATA_ROOT": str(empty),
            "PYTHONPATH": os.pathsep.join([str(Path(__file__).resolve().parents[1]),
                                           os.environ.get("PYTHONPATH", "")])}


def interrupt(argv: list[str], tmp_path: Path, *, after_s: float, sig: int,
              group: bool = False) -> tuple[int, str]:
    """Run ``evsmap ARGV``, send ``sig`` after ``after_s`` seconds (to the whole process group,
    as a terminal's Ctrl-C does, when ``group``), and check that it stops and leaves no process.
    Returns the exit status and stderr."""
    mark = uuid.uuid4().hex
    err_path = tmp_path / f"stderr-{mark}.txt"
    with open(err_path, "w") as err:
        proc = subprocess.Popen([*EVSMAP, *argv], env=evsmap_env(tmp_path, mark),
                                stdout=subprocess.DEVNULL, stderr=err, start_new_session=True)
        time.sleep(after_s)
        if proc.poll() is None:
            if group:
                os.killpg(proc.pid, sig)
            else:
                proc.send_signal(sig)
        try:
            code = proc.wait(timeout=HANG_S)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            pytest.fail(f"seed {SEED}: evsmap {' '.join(argv)} still running {HANG_S:.0f} s "
                        f"after {signal.Signals(sig).name} at {after_s:.2f} s")
    deadline = time.monotonic() + 5.0
    while (left := marked_processes(mark)) and time.monotonic() < deadline:
        time.sleep(0.1)
    for pid in left:
        os.kill(pid, signal.SIGKILL)
    stderr = err_path.read_text()
    assert not left, (f"seed {SEED}: processes left behind after {signal.Signals(sig).name} at "
                      f"{after_s:.2f} s: {left}\n{stderr}")
    assert "Traceback" not in stderr, f"seed {SEED}:\n{stderr}"
    # -sig: the signal came while Python itself was starting, before evsmap set its handlers
    assert code in (0, 128 + sig, -sig), \
        f"seed {SEED}: exit {code} after {after_s:.2f} s\n{stderr}"
    return code, stderr


def run_evsmap(argv: list[str], tmp_path: Path) -> str:
    proc = subprocess.run([*EVSMAP, *argv], env=evsmap_env(tmp_path, uuid.uuid4().hex),
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return proc.stdout


def assert_whole(folder: Path) -> None:
    """No temporary or staging file is left and every JSON file parses."""
    for path in folder.rglob("*"):
        assert not (path.name.startswith(".") and (".partial-" in path.name
                                                   or path.name.endswith(".tmp"))), path
        if path.suffix == ".json":
            json.loads(path.read_text())


