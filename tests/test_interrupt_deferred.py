"""A signal that lands inside a ctypes callback from native code (llvmlite's object cache while
numba compiles) is delivered again a moment later instead of raising there: raised there, the
exception was swallowed and the process crashed (SIGSEGV) in CI's explore Ctrl-C test."""

from __future__ import annotations

import os
import signal
import sys
import time

import pytest

from evsmap import interrupt


def _frame_in(filename: str):
    """A live frame whose code says it comes from ``filename``."""
    namespace: dict = {"sys": sys}
    exec(compile("def where():\n    return sys._getframe()\n", filename, "exec"), namespace)
    return namespace["where"]()


def test_a_signal_inside_llvmlite_is_delivered_again(monkeypatch):
    sent: list[tuple[int, int]] = []
    monkeypatch.setattr(interrupt.os, "kill", lambda pid, signum: sent.append((pid, signum)))
    before = signal.getsignal(signal.SIGINT)
    frame = _frame_in(os.path.join(os.sep, "venv", "llvmlite", "binding", "executionengine.py"))
    interrupt._raise_interrupted(signal.SIGINT, frame)  # returns: nothing raised in the callback
    deadline = time.monotonic() + 5
    while not sent and time.monotonic() < deadline:
        time.sleep(0.01)
    assert sent == [(os.getpid(), signal.SIGINT)]
    assert signal.getsignal(signal.SIGINT) is before  # still armed for the redelivery


def test_a_signal_elsewhere_raises_at_once():
    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        with pytest.raises(interrupt.Interrupted):
            interrupt._raise_interrupted(signal.SIGTERM, _frame_in(__file__))
    finally:
        for s, handler in saved.items():
            signal.signal(s, handler)


def test_a_signal_in_an_uninterrupted_block_is_raised_at_its_end():
    """`uninterrupted()`: Ctrl-C inside the block lets it finish, then raises."""
    done = []
    with pytest.raises(interrupt.Interrupted), interrupt.handle_signals():
        with interrupt.uninterrupted():
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)  # the handler has run by now, and raised nothing
            done.append("finished")
    assert done == ["finished"]
