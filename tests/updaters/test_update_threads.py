"""A map updated with the kernels on two threads is the one updated on one thread: the same
arrays and the same file bytes, also when the update runs in a thread of its own beside another
thread calling compiled code."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from evsmap.mapping import kernels, threads
from evsmap.registry import READERS, SEGMENTERS, UPDATERS
from evsmap.testing import missing


@pytest.fixture(autouse=True)
def _restore_threads():
    if kernels.trace is None:
        missing("numba cannot be imported: the parallel kernels are untested")
    yield
    threads.set_update_threads(None)


@pytest.fixture(scope="module")
def observed():
    seq = READERS.create("synthetic", frames=6, width=160, height=120)
    oracle = SEGMENTERS.create("oracle", seed=2, accuracy=0.6)
    frames = [seq.frame(i) for i in range(len(seq))]
    return frames, [oracle.predict(f) for f in frames]


def _map(observed, n, **options):
    threads.set_update_threads(n)
    frames, observations = observed
    m = UPDATERS.create("multiclass-bayes", front_end="direct", resolution=0.05, max_range=4.0,
                        **options)
    for frame, obs in zip(frames, observations, strict=True):
        m.integrate(frame, obs)
    return m


def _assert_same(a, b, tmp_path):
    assert np.array_equal(a.map.codes, b.map.codes)
    assert np.array_equal(a.map.logodds, b.map.logodds)
    for name in ("classes", "class_logodds", "others"):
        assert np.array_equal(a.map.payload(name), b.map.payload(name)), name
    a.write(tmp_path / "a.ot")
    b.write(tmp_path / "b.ot")
    assert (tmp_path / "a.ot").read_bytes() == (tmp_path / "b.ot").read_bytes()


@pytest.mark.parametrize("options", [{}, {"leaf_update": "average"}], ids=["paper", "average"])
def test_one_and_two_threads_write_the_same_map(observed, tmp_path, options):
    one = _map(observed, 1, **options)
    two = _map(observed, 2, **options)
    assert one.map.num_leaves > 1000
    _assert_same(one, two, tmp_path)


def test_the_update_in_its_own_thread_beside_other_compiled_code(observed, tmp_path):
    reference = _map(observed, 2)
    result, stop = [], threading.Event()

    def update():
        result.append(_map(observed, 2))

    def other():  # serial compiled code in another thread meanwhile
        counts = np.arange(1000, dtype=np.int64)
        while not stop.is_set():
            kernels._prefix(counts)

    side = threading.Thread(target=other)
    side.start()
    worker = threading.Thread(target=update)
    worker.start()
    worker.join()
    stop.set()
    side.join()
    _assert_same(reference, result[0], tmp_path)
