"""Interruption: Ctrl-C (SIGINT) and SIGTERM stop a command promptly and leave nothing behind.

* :func:`handle_signals` (the command line wraps every command in it) turns SIGTERM into the
  same exception as Ctrl-C (:class:`Interrupted`, a :class:`KeyboardInterrupt`), so one code
  path unwinds both: ``with`` blocks close, process pools terminate their workers
  (:class:`evsmap.runner.executors.TerminatingPool`), temporary files go, finished files stay
  whole (they are all written by rename, :mod:`evsmap.fileio`).
* :func:`set_resume_hint`: a command says how to continue it; the command line prints that
  line when the command is interrupted.
* :func:`worker_init`: run first in every worker process evsmap spawns. The worker ignores
  SIGINT (a terminal's Ctrl-C reaches the whole process group; the parent decides and
  terminates its workers) and dies with its parent (``PR_SET_PDEATHSIG`` on Linux, and a
  watchdog thread elsewhere), so no worker outlives a parent killed outright.

This module imports nothing heavy: it is the first thing a spawned worker unpickles.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator

SIGNAL_NAMES: dict[int, str] = {signal.SIGINT: "SIGINT", signal.SIGTERM: "SIGTERM"}

_hint: str | Callable[[], str | None] | None = None


class Interrupted(KeyboardInterrupt):
    """A command stopped by a signal (SIGINT or SIGTERM).

    Attributes:
        signum: the signal's number.
    """

    def __init__(self, signum: int = signal.SIGINT) -> None:
        super().__init__(SIGNAL_NAMES.get(signum, f"signal {signum}"))
        self.signum = signum

    @property
    def exit_status(self) -> int:
        """128 + the signal's number, as a shell reports a process the signal ended."""
        return 128 + int(self.signum)


def set_resume_hint(hint: str | Callable[[], str | None] | None) -> None:
    """What the command line prints when this command is interrupted: a line, or a function
    that says it then (what is left to resume depends on when); ``None``: nothing."""
    global _hint
    _hint = hint


def resume_hint() -> str | None:
    """The line set by :func:`set_resume_hint`, as of now."""
    if callable(_hint):
        try:
            return _hint()
        except Exception:  # a hint must never hide the interruption
            return None
    return _hint


def file_state(path: str | os.PathLike[str] | None) -> tuple[int, int] | None:
    """(inode, modification time) of a file or folder, None when absent: what a command
    compares to tell whether its output was moved into place before a signal came."""
    if path is None:
        return None
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_ino, st.st_mtime_ns


def interruption_behind(exc: BaseException | None) -> KeyboardInterrupt | None:
    """The interruption an exception stands for, if any: itself, or one in its cause/context
    chain. A signal that lands while compiled code calls back into Python (numba loading a
    cached function, a torch op) comes out as ``SystemError(... returned a result with an
    exception set)`` with the :class:`Interrupted` as its cause; an import broken off by
    Ctrl-C can come out as an :class:`ImportError`."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, KeyboardInterrupt):
            return exc
        exc = exc.__cause__ or exc.__context__
    return None


def reraise_interruption(exc: BaseException) -> None:
    """Raise the interruption behind ``exc`` (:func:`interruption_behind`), if any: called
    first by every handler that records an error and goes on, so that a signal seen through
    compiled code still stops the command instead of becoming a failed cell."""
    interrupt = interruption_behind(exc)
    if interrupt is not None:
        raise interrupt


NATIVE_CALLBACK_PACKAGES = ("llvmlite",)
"""Packages whose Python code runs as ctypes callbacks from native code (llvmlite: LLVM's object
cache while numba compiles or loads a kernel). An exception raised there is swallowed
("Exception ignored on calling ctypes callback function") and the native caller goes on with a
broken result: the process crashed (SIGSEGV) where Ctrl-C came during numba's first compile."""
DEFER_S = 0.02
"""How soon a signal that landed in such a callback is delivered again."""


def _in_native_callback(frame: object) -> bool:
    """Whether the interrupted code runs inside one of :data:`NATIVE_CALLBACK_PACKAGES`."""
    parts = tuple(f"{os.sep}{name}{os.sep}" for name in NATIVE_CALLBACK_PACKAGES)
    current = frame
    while current is not None:
        code = getattr(current, "f_code", None)
        if code is not None and any(p in code.co_filename for p in parts):
            return True
        current = getattr(current, "f_back", None)
    return False


_held = 0
"""How many :func:`uninterrupted` blocks the main thread is in."""
_pending: int | None = None
"""A signal that came during such a block, raised at its end."""


@contextlib.contextmanager
def uninterrupted() -> Iterator[None]:
    """A block that SIGINT and SIGTERM do not break into (under :func:`handle_signals`): a
    signal that comes meanwhile is raised as :class:`Interrupted` when the block ends. For
    short steps that must not stop half-done, e.g. taking a trial from a shared study and
    marking it as this worker's (stopped between the two, nobody could tell it was
    abandoned)."""
    global _held, _pending
    _held += 1
    try:
        yield
    finally:
        _held -= 1
        if _held == 0 and _pending is not None:
            signum, _pending = _pending, None
            _raise_interrupted(signum, None)


def _raise_interrupted(signum: int, frame: object) -> None:
    global _pending
    if _held:  # inside an uninterrupted() block: raised at its end
        _pending = signum
        return
    if _in_native_callback(frame):  # not here: deliver it again once the callback returned
        timer = threading.Timer(DEFER_S, os.kill, (os.getpid(), signum))
        timer.daemon = True
        timer.start()
        return
    # the first signal unwinds the command; a second one (an impatient Ctrl-C) must not break
    # off that cleanup (terminating workers takes at most a second or two), so it is ignored
    for other in (signal.SIGINT, signal.SIGTERM):
        signal.signal(other, signal.SIG_IGN)
    raise Interrupted(signum)


@contextlib.contextmanager
def handle_signals() -> Iterator[None]:
    """SIGINT and SIGTERM raise :class:`Interrupted` in the main thread for the block (a no-op
    off the main thread, where Python cannot set handlers). Handlers that were there are
    restored after."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    saved = {}
    for signum in (signal.SIGINT, signal.SIGTERM):
        current = signal.getsignal(signum)
        if current is signal.SIG_IGN:  # e.g. started with nohup: keep ignoring it
            continue
        saved[signum] = current
        signal.signal(signum, _raise_interrupted)
    try:
        yield
    finally:
        for signum, handler in saved.items():
            signal.signal(signum, handler)
        set_resume_hint(None)


# ------------------------------------------------------------------------------------- workers
PR_SET_PDEATHSIG = 1


def _die_with_parent_linux() -> bool:
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def _watch_parent(parent: int, period_s: float = 0.5) -> None:
    import time

    while True:
        time.sleep(period_s)
        if os.getppid() != parent:
            os._exit(1)


def worker_init(parent: int | None = None) -> None:
    """The initializer of every worker process: ignore SIGINT, die with the parent.

    ``parent`` is the pid of the process that spawned this one (``initargs=(os.getpid(),)``):
    a parent already gone by now ends the worker at once. The watchdog thread runs everywhere,
    as a second line behind ``PR_SET_PDEATHSIG``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if parent is None:
        parent = os.getppid()
    if sys.platform.startswith("linux"):
        _die_with_parent_linux()
    if os.getppid() != parent:
        os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent,), name="evsmap-parent-watch",
                     daemon=True).start()
