"""The thread plan gives the update kernels as many threads as a big host has (14 of 16 cores
beside a GPU, evsmap.measure.thread_plan): the map is the same bytes at every count the plans
use, not only at the one and two threads this machine has. numba starts its pool at
``NUMBA_NUM_THREADS`` when it loads, so the maps are made in a process with 16 of them."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

pytestmark = pytest.mark.slow

COUNTS = (1, 2, 5, 14, 16)
"""The 1-, 2- and 16-core CPU plans' update threads, the 16-core GPU plan's, and all 16."""

SCRIPT = """
import hashlib, sys, tempfile
from pathlib import Path
from evsmap.mapping import threads
from evsmap.registry import READERS, SEGMENTERS, UPDATERS

seq = READERS.create("synthetic", frames=6, width=160, height=120)
oracle = SEGMENTERS.create("oracle", seed=2, accuracy=0.6)
frames = [seq.frame(i) for i in range(len(seq))]
observations = [oracle.predict(f) for f in frames]
out = Path(tempfile.mkdtemp()) / "map.ot"
for n in map(int, sys.argv[2:]):
    threads.set_update_threads(n)
    m = UPDATERS.create("multiclass-bayes", front_end=sys.argv[1], resolution=0.05,
                        max_range=4.0)
    for frame, observation in zip(frames, observations):
        m.integrate(frame, observation)
    m.write(out)
    print(threads.update_threads(), m.map.num_leaves,
          hashlib.sha256(out.read_bytes()).hexdigest())
"""


@pytest.mark.parametrize("front_end", ["direct", "generator"])
def test_the_map_is_the_same_bytes_at_every_planned_update_thread_count(front_end):
    env = {**os.environ, "NUMBA_NUM_THREADS": "16"}
    env.pop("EVSMAP_UPDATE_THREADS", None)
    done = subprocess.run([sys.executable, "-c", SCRIPT, front_end, *map(str, COUNTS)],
                          env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    rows = [line.split() for line in done.stdout.splitlines()]
    assert [int(r[0]) for r in rows] == list(COUNTS)  # each count ran, none capped
    assert int(rows[0][1]) > 1000
    assert len({(r[1], r[2]) for r in rows}) == 1, rows
