"""Helpers shared by the runner tests."""

from __future__ import annotations

from concurrent.futures import Future


class Inline:
    """An executor that runs each task at once in this process (stands in for the runner's
    process pools; takes and ignores their constructor arguments)."""

    def __init__(self, *args, **kwargs) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def submit(self, fn, *args):
        fut = Future()
        fut.set_result(fn(*args))
        return fut
