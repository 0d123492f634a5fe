"""How many threads the compiled map-update kernels use, and numba's threading layer for them.

The update kernels (:mod:`evsmap.mapping.kernels`, :mod:`evsmap.mapping.mcb_kernel`) split their
loops over threads with numba ``prange``; each thread writes its own slices, so the results are
the same at any thread count. This module holds the one setting they share:

* :func:`set_update_threads` / :func:`update_threads`: the number of threads (1 to numba's
  ``NUMBA_NUM_THREADS``); the environment variable :data:`ENV` (``EVSMAP_UPDATE_THREADS``) sets
  the default, otherwise all of numba's threads.
* :func:`kernel_threads`: the context an updater runs its kernels in. numba's
  ``set_num_threads`` is per calling thread, so the setting is applied there, in the thread that
  launches the kernels (a pipeline runs the update in its own Python thread); with the
  ``workqueue`` layer, which does not allow two threads to launch parallel kernels at once, it
  also holds a lock.
* :func:`threading_info`: ``{"layer": ..., "threads": ...}`` for reports.

The threading layer is chosen here, at import, before any parallel kernel runs: ``omp`` when
numba has it (safe to launch from any thread while other threads run numba code), else
``workqueue`` (launches serialised by :func:`kernel_threads`'s lock). A layer already chosen
through ``NUMBA_THREADING_LAYER`` is kept. With ``omp``, ``OMP_WAIT_POLICY`` defaults to
``PASSIVE`` (unless set): GNU OpenMP's threads otherwise spin between the kernels' short
parallel loops, and on a machine whose cores are busy (another process, or the segmenter in the
pipeline's other thread) the spinning slowed the update about 5x in our measurements.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import threading
from collections.abc import Iterator
from types import ModuleType

numba: ModuleType | None
try:
    import numba
except ImportError:  # pragma: no cover - numba is a dependency; the numpy paths need no threads
    numba = None

ENV = "EVSMAP_UPDATE_THREADS"
"""Environment variable: the default number of update threads."""

_LOCK = threading.Lock()
_threads: int | None = None  # None: the default (ENV, else all)


def _has_omp() -> bool:
    try:
        importlib.import_module("numba.np.ufunc.omppool")  # loads libgomp when numba has it
    except ImportError:
        return False
    return True


def _choose_layer() -> str | None:
    if numba is None:
        return None
    chosen = str(numba.config.THREADING_LAYER)
    if os.environ.get("NUMBA_THREADING_LAYER") or chosen not in ("default", "safe", "threadsafe"):
        return chosen  # chosen by the user (an explicit layer name)
    # libgomp reads its wait policy when it loads, which importing numba's omp pool does
    had_policy = "OMP_WAIT_POLICY" in os.environ
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    layer = "omp" if _has_omp() else "workqueue"
    if layer != "omp" and not had_policy:
        del os.environ["OMP_WAIT_POLICY"]
    numba.config.THREADING_LAYER = layer
    return layer


_LAYER = _choose_layer()


def max_threads() -> int:
    """The most threads the kernels can use (numba's ``NUMBA_NUM_THREADS``; 1 without numba)."""
    return int(numba.config.NUMBA_NUM_THREADS) if numba is not None else 1


def _checked(n: object, source: str) -> int:
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"{source}: the number of update threads must be a positive integer, "
                         f"got {n!r}")
    return min(n, max_threads())


def _default() -> int:
    value = os.environ.get(ENV, "").strip()
    if not value:
        return max_threads()
    try:
        n = int(value)
    except ValueError:
        raise ValueError(f"{ENV}={value!r}: the number of update threads must be a positive "
                         f"integer") from None
    return _checked(n, ENV)


def set_update_threads(n: int | None) -> int:
    """Use ``n`` threads in the update kernels (capped at :func:`max_threads`); ``None``: the
    default again (:data:`ENV`, else all). Returns the number now in use.

    Raises:
        ValueError: ``n`` is not a positive integer.
    """
    global _threads
    _threads = None if n is None else _checked(n, "set_update_threads")
    return update_threads()


def update_threads() -> int:
    """The number of threads the update kernels use."""
    return _threads if _threads is not None else _default()


def threading_layer() -> str | None:
    """numba's threading layer: the one running once a parallel kernel has run, else the one
    configured (None without numba)."""
    if numba is None:
        return None
    try:
        return str(numba.threading_layer())
    except ValueError:  # no parallel kernel has run yet
        return _LAYER


def threading_info() -> dict[str, object]:
    """``{"layer": threading_layer(), "threads": update_threads()}`` for reports (with
    ``omp``, also ``"omp_wait_policy"``)."""
    info: dict[str, object] = {"layer": threading_layer(), "threads": update_threads()}
    if info["layer"] == "omp":
        info["omp_wait_policy"] = os.environ.get("OMP_WAIT_POLICY", "")
    return info


@contextlib.contextmanager
def kernel_threads() -> Iterator[int]:
    """Run the update kernels inside: applies :func:`update_threads` to the calling thread
    (numba's setting is per thread) and, with the ``workqueue`` layer, serialises launches.
    Yields the number of threads."""
    n = update_threads()
    if numba is None:
        yield n
        return
    lock = _LOCK if _LAYER == "workqueue" else contextlib.nullcontext()
    with lock:
        if numba.get_num_threads() != n:
            numba.set_num_threads(n)
        yield n
