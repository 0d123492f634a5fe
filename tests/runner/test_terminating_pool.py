"""``TerminatingPool``: leaving its block by an exception ends the workers at once instead of
waiting for their tasks; workers ignore SIGINT and die with their parent, even one killed
outright (SIGKILL), so no cell worker outlives a run."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from evsmap.runner.executors import TerminatingPool

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="checks processes through /proc")


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _wait_gone(pids: list[int], within_s: float) -> list[int]:
    deadline = time.monotonic() + within_s
    while (left := [p for p in pids if _alive(p)]) and time.monotonic() < deadline:
        time.sleep(0.05)
    return left


def test_an_exception_in_the_block_terminates_busy_workers():
    with pytest.raises(KeyboardInterrupt):
        with TerminatingPool(2) as pool:
            futures = [pool.submit(time.sleep, 120) for _ in range(2)]
            deadline = time.monotonic() + 30
            while not all(f.running() for f in futures) and time.monotonic() < deadline:
                time.sleep(0.05)
            pids = list(pool._processes)
            raise KeyboardInterrupt
    # the block did not wait 120 s, and nothing is left
    assert _wait_gone(pids, 5.0) == []


def test_workers_ignore_sigint_and_the_pool_still_works():
    with TerminatingPool(1) as pool:
        pid = pool.submit(os.getpid).result()
        os.kill(pid, signal.SIGINT)
        time.sleep(0.2)
        assert pool.submit(os.getpid).result() == pid  # the same worker, still serving


def test_workers_die_with_a_parent_killed_outright(tmp_path):
    script = textwrap.dedent("""
        import os, sys, time
        from evsmap.runner.executors import TerminatingPool
        if __name__ == "__main__":
            pool = TerminatingPool(2)
            futures = [pool.submit(time.sleep, 120) for _ in range(2)]
            time.sleep(1.0)
            print(" ".join(str(p) for p in pool._processes), flush=True)
            time.sleep(120)
    """)
    path = tmp_path / "parent.py"
    path.write_text(script)
    proc = subprocess.Popen([sys.executable, str(path)], stdout=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": os.pathsep.join(
                                [str(Path(__file__).resolve().parents[2]),
                                 os.environ.get("PYTHONPATH", "")])})
    workers = [int(p) for p in proc.stdout.readline().split()]
    assert len(workers) == 2 and all(_alive(p) for p in workers)
    proc.kill()  # SIGKILL: no handler runs in the parent
    proc.wait()
    left = _wait_gone(workers, 5.0)
    for pid in left:
        os.kill(pid, signal.SIGKILL)
    assert left == []
