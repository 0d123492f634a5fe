"""Where the matrix's cells run: the interface the scheduler (:mod:`evsmap.runner.matrix`) uses,
and :class:`LocalExecutor`, the default, which runs them in process pools on this machine.

An executor gives the scheduler two kinds of workers:

* a *pool* for the cells that are not timed (complexity, accuracy), run side by side;
* *timing slots*: places where one timed cell (speed, the mapping runs) runs at a time, alone,
  each in a fresh interpreter. This machine is one slot; a Ray cluster
  (:mod:`evsmap.runner.ray_executor`) has one per node that times.

Both are handed out as :class:`concurrent.futures.Executor` objects, so the scheduler submits a
cell and reads its record (a plain dict) from a future, whichever executor runs it.
"""

from __future__ import annotations

import abc
import multiprocessing
import os
from collections.abc import Callable
from concurrent.futures import Executor, ProcessPoolExecutor
from dataclasses import dataclass
from multiprocessing.process import BaseProcess
from types import TracebackType
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from evsmap.runner.context import RunContext

EXECUTORS = ("local", "ray")
"""The executors ``evsmap reproduce --executor`` takes."""


@dataclass(frozen=True)
class TimingSlot:
    """A place where timed cells run, one at a time.

    Attributes:
        name: what the run's messages call it (``this machine``, a node's host name).
        cpus: the threads a timed cell uses there (all the node's CPUs); None keeps the run's
            own ``threads``.
        node_id: the Ray node, None on this machine.
    """

    name: str
    cpus: int | None = None
    node_id: str | None = None


class TerminatingPool(ProcessPoolExecutor):
    """A spawned process pool that never outlives an error or an interruption.

    Leaving its ``with`` block normally waits for the tasks, as any pool does. Leaving it by an
    exception (Ctrl-C, SIGTERM, a failed cell) cancels what has not started and terminates the
    workers at once (SIGTERM, then SIGKILL for one that is still there after ``grace_s``),
    instead of waiting for the running tasks to finish. Its workers ignore SIGINT and die with
    this process (:func:`evsmap.interrupt.worker_init`).

    Args:
        max_workers: processes.
        max_tasks_per_child: tasks a worker runs before it is replaced (1: a fresh interpreter
            per task).
        grace_s: how long a terminated worker has to go before it is killed.
    """

    def __init__(self, max_workers: int, *, max_tasks_per_child: int | None = None,
                 grace_s: float = 1.0, context: Any = None) -> None:
        from evsmap.interrupt import worker_init

        context = context or multiprocessing.get_context("spawn")
        # a forkserver's children are the server's: they watch it, and it ends with this process
        parent = None if context.get_start_method() == "forkserver" else os.getpid()
        super().__init__(max_workers=max(1, max_workers), mp_context=context,
                         initializer=worker_init, initargs=(parent,),
                         max_tasks_per_child=max_tasks_per_child)
        self.grace_s = grace_s

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> bool | None:
        if exc_type is None:
            return super().__exit__(exc_type, exc, tb)
        self.terminate_workers()
        return False

    def terminate_workers(self) -> None:
        """Cancel the queued tasks and end every worker now."""
        processes = list((getattr(self, "_processes", None) or {}).values())
        self.shutdown(wait=False, cancel_futures=True)
        terminate_processes(processes, self.grace_s)


def terminate_processes(processes: list[BaseProcess], grace_s: float = 1.0) -> None:
    """SIGTERM to every live process of ``processes``, SIGKILL to those still alive after
    ``grace_s`` seconds in all; each is reaped."""
    import time

    for proc in processes:
        if proc.is_alive():
            proc.terminate()
    deadline = time.monotonic() + grace_s
    for proc in processes:
        proc.join(max(0.0, deadline - time.monotonic()))
        if proc.is_alive():
            proc.kill()
            proc.join(1.0)


def spawn_pool(workers: int) -> Executor:
    """``workers`` spawned processes, each running any number of cells."""
    return TerminatingPool(workers)


FRESH_PRELOAD = ("evsmap.runner.matrix",)
"""What the timed cells' fork server imports once (torch, numpy and the runner: 1.1-1.9 s of
every fresh interpreter's start on the 2-core VM this was measured on)."""


def fresh_context() -> Any:
    """Where a timed cell's fresh process comes from: a fork server (POSIX) that imported
    :data:`FRESH_PRELOAD` once and has run nothing, so each cell still starts in a process no
    cell ran in (no warm caches, threads or memory of another cell), without paying the
    interpreter's start and the imports again; its children end with ``os._exit`` once their
    record is sent, not through the interpreter's teardown (0.9 s a cell with ``spawn``).
    Elsewhere, ``spawn``."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(list(FRESH_PRELOAD))
    return context


def fresh_process() -> Executor:
    """One task per fresh interpreter (:func:`fresh_context`), one at a time."""
    return TerminatingPool(1, max_tasks_per_child=1, context=fresh_context())


class CellExecutor(abc.ABC):
    """What runs the cells of one ``reproduce`` run; entered once around the run
    (``with executor: ...``), which starts and stops whatever it needs."""

    name = "executor"

    def __enter__(self) -> CellExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:  # noqa: B027 (optional hook: nothing to release by default)
        """Release what :meth:`__enter__` or :meth:`prepare` started."""

    def prepare(self, ctx: RunContext) -> None:  # noqa: B027 (optional hook)
        """Check that the cells of ``ctx``'s run can run here (before any is scheduled)."""

    @abc.abstractmethod
    def pool(self, workers: int, threads: int) -> Executor:
        """An executor for the cells that are not timed; ``workers`` is the ``--workers``
        setting, ``threads`` the threads a cell uses (:meth:`pool_threads`)."""

    def pool_threads(self, threads: int) -> int:
        """The threads a pooled cell gets when the run asks for ``threads``."""
        return threads

    @abc.abstractmethod
    def timing_slots(self) -> list[TimingSlot]:
        """Where timed cells run; as many run at once as there are slots, one per slot."""

    @abc.abstractmethod
    def fresh(self, slot: TimingSlot) -> Executor:
        """An executor that runs each task submitted to it alone in ``slot``, in a fresh
        interpreter."""

    def placement(self) -> dict[str, Any]:
        """Said in a record's ``environment["executor"]`` when the cell's own worker did not
        say more."""
        return {"name": self.name}

    def describe(self) -> dict[str, Any]:
        """The executor and its workers, for ``run.json``."""
        return {"name": self.name}

    def summary(self) -> str:
        """One line for the run's output: where the cells run."""
        return f"{self.name} executor"


class LocalExecutor(CellExecutor):
    """This machine: the pooled cells in ``workers`` spawned processes, the timed cells one at
    a time, each in a fresh spawned interpreter, after the pool has finished (so nothing of the
    run shares the cores with them).

    Args:
        pool: makes the pool from ``workers`` (default: :func:`spawn_pool`).
        fresh: makes the executor of one timed cell (default: :func:`fresh_process`).
    """

    name = "local"

    def __init__(self, *, pool: Callable[[int], Executor] | None = None,
                 fresh: Callable[[], Executor] | None = None) -> None:
        self._pool = pool or spawn_pool
        self._fresh = fresh or fresh_process

    def pool(self, workers: int, threads: int) -> Executor:
        return self._pool(workers)

    def timing_slots(self) -> list[TimingSlot]:
        return [TimingSlot(name="this machine")]

    def fresh(self, slot: TimingSlot) -> Executor:
        return self._fresh()

    def summary(self) -> str:
        return "local: the cells that are not timed in a process pool, timed cells one at a time"
