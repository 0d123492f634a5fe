"""The pipelined mapping loop: reading, segmentation and the map update of consecutive frames
overlap.

:func:`evsmap.measure.engine.run_mapping` runs its three stages one after the other per frame.
With ``pipeline=True`` it takes its frames from :func:`pipelined_frames` instead: a reader thread
reads frame ``i + 2`` while a segmentation thread segments frame ``i + 1`` and the calling thread
integrates frame ``i``. Each stage hands its frames on in order through a bounded queue (``depth``
frames), so the updater sees exactly the frames and observations of the sequential loop, in the
same order, and writes the same map (``tests/measure/test_pipelined.py`` compares the file bytes).

The overlap is real parallelism because the heavy parts of each stage release the GIL: ONNX
Runtime's ``run``, torch's operators, numba's compiled kernels (``nogil``), open3d's ray casting,
PIL's decoders and numpy's large array operations. What stays serialised is the Python glue
between them.

Each stage records its own per-frame times in its own :class:`StageTimes` (merged at the end):
under contention a stage's time is its wall time while sharing the cores, so the per-stage medians
of a pipelined run are larger than the sequential run's; the figure the pipeline improves is the
end-to-end rate, ``wall_hz``: frames / wall time of the whole loop, reading included
(``MappingPass.wall_s``); what a robot streaming the sequence gets. The sum of the stages'
medians (``segment_update_hz``, Table IV's Runtime) is another quantity: the segmentation +
update rate.

The threads of each stage are set for the loop (:class:`StageThreads`; :data:`PIPELINED` on 2
cores, :func:`evsmap.measure.thread_plan.thread_plan` for the cores and device at hand):
thread pools that busy-wait for a core are the enemy of overlap. numpy's OpenBLAS threads turned
the synthetic renderer's 307,200 x 3 by 3 x 3 ray product from 1 ms into 200 ms while the other
stages held the cores, and torch's two intra-op threads made the top-k's softmax denominator 3x
slower than one; both run on one thread in the pipeline (the same numbers: no reduction of
theirs is split across threads). A network on the CPU runs at the sequential loop's thread count
in both (:attr:`StageThreads.segment`): its logits depend on that count, so the pipeline keeps
it and the observations, thus the map, are the same bytes with the pipeline on and off
(``tests/cli/test_map_thread_independence.py``); on a GPU they do not depend on host threads.

A failure in a worker thread (a bad frame, a network error) is re-raised in the calling thread;
leaving the loop early (an exception, Ctrl-C) stops both workers within one queue timeout.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

from evsmap.data import Frame, SemanticObservation, Sequence
from evsmap.interfaces import Segmenter
from evsmap.readers.skipping import SkippedFrames

DEPTH = 2
"""Frames each queue holds: enough to keep every stage busy, little memory (a 640x480 frame
with its observation is about 4 MB)."""

_POLL_S = 0.05
"""How often a blocked worker looks at the stop flag."""


@dataclass(frozen=True)
class _End:
    """The last item of a queue: the stage finished, or failed with ``error``."""

    error: BaseException | None = None


class _Stage(threading.Thread):
    """A daemon thread running ``body(put)`` that always ends its output queue with
    :class:`_End` (carrying the exception when ``body`` raised)."""

    def __init__(self, name: str, body: Callable[[Callable[[Any], bool]], None],
                 out: queue.Queue[Any], stop: threading.Event) -> None:
        super().__init__(name=name, daemon=True)
        self._body, self._out, self._halt = body, out, stop

    def put(self, item: Any) -> bool:
        """Hand ``item`` on; False when the loop was stopped (the stage should return)."""
        while not self._halt.is_set():
            try:
                self._out.put(item, timeout=_POLL_S)
                return True
            except queue.Full:
                continue
        return False

    def run(self) -> None:
        end = _End()
        try:
            self._body(self.put)
        except BaseException as exc:  # noqa: BLE001 - re-raised in the consumer
            end = _End(exc)
        self.put(end)


def _get(q: queue.Queue[Any], stop: threading.Event) -> Any:
    while True:
        try:
            return q.get(timeout=_POLL_S)
        except queue.Empty:
            if stop.is_set():
                return _End()


def pipelined_frames(sequence: Sequence, order: list[int], *, segmenter: Segmenter | None,
                     read_times: Any, segment_times: Any,
                     timed_predict: Callable[[Segmenter, Frame, Any, Any], SemanticObservation],
                     timed_frames: Callable[..., Iterator[tuple[int, int, Frame]]],
                     skip_bad: bool, skipped: SkippedFrames,
                     progress: Callable[[Any], Any] | None = None, depth: int = DEPTH,
                     needed: Callable[[Frame], Any] | None = None
                     ) -> Iterator[tuple[int, int, Frame, SemanticObservation | None]]:
    """``(position, index, frame, observation)`` for each frame, in order, read and segmented
    ahead of the caller by two worker threads.

    Args:
        sequence, order: the frames to read, in order.
        segmenter: run on each frame in the segmentation thread (``None``: no segmentation,
            the observation is ``None``).
        read_times, segment_times: :class:`~evsmap.measure.engine.StageTimes` the reader
            (``read``) and the segmentation thread (``timed_predict``'s stages) add to; each is
            written by one thread only.
        timed_predict, timed_frames: the engine's timed prediction and timed reading (passed
            in: the engine imports this module).
        skip_bad, skipped: as for :func:`~evsmap.readers.skipping.read_frames` (``skipped`` is
            only written by the reader thread).
        progress: wraps the list of indices (it advances as frames are read).
        depth: frames each queue holds.
        needed: the pixels of a frame the caller reads the observation at (the updater's
            :meth:`~evsmap.interfaces.MapUpdater.semantic_pixels`, called in the segmentation
            thread; it must only read the frame and fixed settings), or None for all.
    """
    stop = threading.Event()
    read_q: queue.Queue[Any] = queue.Queue(maxsize=depth)
    seg_q: queue.Queue[Any] = queue.Queue(maxsize=depth)

    def read(put: Callable[[Any], bool]) -> None:
        for _, index, frame in timed_frames(sequence, order, read_times, skip_bad=skip_bad,
                                            skipped=skipped, progress=progress):
            if not put((index, frame)):
                return

    def segment(put: Callable[[Any], bool]) -> None:
        while True:
            item = _get(read_q, stop)
            if isinstance(item, _End):
                if item.error is not None:
                    raise item.error
                return
            index, frame = item
            observation = None if segmenter is None else \
                timed_predict(segmenter, frame, segment_times,
                              None if needed is None else needed(frame))
            if not put((index, frame, observation)):
                return

    workers = [_Stage("evsmap-read", read, read_q, stop),
               _Stage("evsmap-segment", segment, seg_q, stop)]
    for w in workers:
        w.start()
    try:
        position = 0
        while True:
            item = _get(seg_q, stop)
            if isinstance(item, _End):
                if item.error is not None:
                    raise item.error
                return
            index, frame, observation = item
            yield position, index, frame, observation
            position += 1
    finally:
        stop.set()
        for w in workers:
            w.join(timeout=5.0)


@dataclass(frozen=True)
class StageThreads:
    """The threads each stage of a mapping loop runs with (recorded beside its rates).

    Attributes:
        segment: a network segmenter's intra-op threads (ONNX Runtime's pool, or torch's
            during the forward pass; ``None``: torch's thread count before the loop, the
            sequential default). The only setting here the observations depend on: the
            network's logits change with it in the last float32 bits (docs/cli.md, "Thread
            independence").
        spinning: whether ONNX Runtime's idle workers busy-wait between operators (fast alone;
            in a pipeline they take the cores the reader and the update need).
        torch: torch's intra-op threads while the loop runs (a network's pre- and
            post-processing, which give the same bits whatever it is; ``None``: unchanged).
        update: the update kernels' threads (:mod:`evsmap.mapping.threads`; ``None``: its
            default, ``EVSMAP_UPDATE_THREADS`` or all).
        blas: numpy's BLAS threads while the loop runs (``None``: unchanged).
    """

    segment: int | None = None
    spinning: bool = True
    torch: int | None = None
    update: int | None = None
    blas: int | None = None

    def changed(self, changes: dict[str, int]) -> StageThreads:
        """These threads with ``changes`` (``{stage: threads}``, :func:`stage_thread_changes`)
        applied."""
        from dataclasses import replace

        return replace(self, segment=changes.get("segment", self.segment),
                       torch=changes.get("torch", self.torch),
                       update=changes.get("update", self.update),
                       blas=changes.get("blas", self.blas))

    @contextmanager
    def applied(self, segmenter: Segmenter | None) -> Iterator[dict[str, Any]]:
        """Set every stage's threads, yield what is in use (:meth:`record`), restore."""
        import torch

        from evsmap.mapping import threads as update_threads_mod

        old_torch = torch.get_num_threads()
        old_update = update_threads_mod.update_threads()
        blas = None
        try:
            if self.torch is not None:
                torch.set_num_threads(self.torch)
            if self.update is not None:
                update_threads_mod.set_update_threads(self.update)
            if self.blas is not None:
                from threadpoolctl import threadpool_limits

                blas = threadpool_limits(limits=self.blas, user_api="blas")
            # None: the thread count torch had before the loop (the sequential default)
            runtime = segmenter.set_threads(self.segment or old_torch, spinning=self.spinning) \
                if segmenter is not None else {}
            yield self._record(runtime)
        finally:
            if blas is not None:
                blas.restore_original_limits()
            torch.set_num_threads(old_torch)
            if self.update is not None:
                update_threads_mod.set_update_threads(old_update)

    def _record(self, runtime: dict[str, Any]) -> dict[str, Any]:
        import torch

        return {"read": 1, "segment": {"torch": torch.get_num_threads(), **runtime},
                "update": _update_record(), "blas": self.blas}


SEQUENTIAL = StageThreads()
"""The sequential loop: every library's defaults (each stage alone has all the cores)."""

PIPELINED = StageThreads(segment=None, spinning=False, torch=1, update=1, blas=1)
"""The pipelined loop's threads on 2 cores (docs/realtime.md), and the loop's default where no
plan is given: the network keeps the sequential loop's threads (ONNX Runtime without spinning),
so both loops segment every frame into the same bytes; torch's pre/post-processing, the update
and numpy's BLAS run on one thread each (their pools busy-wait for cores the other stages hold).
:func:`evsmap.measure.thread_plan.thread_plan` gives exactly this for 2 cores on the CPU, and
sizes the loop for other core counts and for a GPU."""

LOOP_THREADS = ("read", "segment", "update")
"""The pipelined loop's threads, in its order: the reader, the segmentation (pre-processing,
network, post-processing or the oracle, one after the other) and the update."""


def loop_balance(stage_ms: dict[str, float], wall_hz: float, *, pipelined: bool
                 ) -> dict[str, Any]:
    """How near the loop's ``wall_hz`` came to the rate its stages allow, and each stage's
    share of a frame's wall time; ``{}`` without frames.

    ``stage_ms``: each stage's median ms a frame (``MappingRecord.stage_medians``). The
    pipelined loop can at best run at its slowest thread's rate (the segmentation thread's
    stages add up); the sequential loop at the rate of all stages one after the other.

    Returns:
        ``threads_ms`` (the median ms a frame of each loop thread, :data:`LOOP_THREADS`),
        ``bound`` (the slowest thread's name, or ``"all stages"`` for the sequential loop),
        ``bound_ms``, ``reached`` (``wall_hz * bound_ms / 1000``: the share of the bound's rate
        the loop reached) and ``shares`` (each stage's median ms over the wall time a frame,
        ``1000 / wall_hz``; in the pipelined loop the stages overlap and their shares add up
        to more than 1).
    """
    if not stage_ms or not wall_hz > 0:
        return {}
    segment = [v for k, v in stage_ms.items() if k not in ("read", "update")]
    groups = {"read": [stage_ms["read"]] if "read" in stage_ms else [], "segment": segment,
              "update": [stage_ms["update"]] if "update" in stage_ms else []}
    threads_ms = {k: float(sum(v)) for k, v in groups.items() if v}
    if pipelined:
        bound = max(threads_ms, key=lambda k: threads_ms[k])
        bound_ms = threads_ms[bound]
    else:
        bound, bound_ms = "all stages", sum(stage_ms.values())
    frame_ms = 1000.0 / wall_hz
    return {"threads_ms": threads_ms, "bound": bound, "bound_ms": bound_ms,
            "reached": wall_hz * bound_ms / 1000.0,
            "shares": {k: v / frame_ms for k, v in stage_ms.items()}}


def stage_thread_changes(pairs: list[tuple[str, Any]]) -> dict[str, int]:
    """``KEY=N`` pairs from the command line (``--stage-threads``) as ``{stage: threads}``
    (``segment``, ``torch``, ``update``, ``blas``).

    Raises:
        InvalidDataError: an unknown key or a value that is not a positive integer.
    """
    from evsmap.errors import InvalidDataError

    keys = ("segment", "torch", "update", "blas")
    changes: dict[str, int] = {}
    for key, value in pairs:
        if key not in keys:
            raise InvalidDataError(f"--stage-threads {key}: unknown stage (known: "
                                   f"{', '.join(keys)})")
        try:
            n = int(str(value))
        except ValueError:
            n = 0
        if n < 1 or str(n) != str(value).strip():
            raise InvalidDataError(f"--stage-threads {key}={value}: a positive integer, please")
        changes[key] = n
    return changes


def stage_threads_option(pairs: list[tuple[str, Any]], *, pipeline: bool,
                         base: StageThreads | None = None) -> StageThreads:
    """``base`` (default: the loop's, :data:`PIPELINED` or :data:`SEQUENTIAL`; ``evsmap map``
    passes the plan for its cores, :mod:`evsmap.measure.thread_plan`) with ``KEY=N`` pairs
    from the command line applied (:func:`stage_thread_changes`).

    Raises:
        InvalidDataError: an unknown key or a value that is not a positive integer.
    """
    if base is None:
        base = PIPELINED if pipeline else SEQUENTIAL
    return base.changed(stage_thread_changes(pairs))


def _update_record() -> dict[str, Any]:
    """The update kernels' threads and numba threading layer
    (:func:`evsmap.mapping.threads.threading_info`)."""
    from evsmap.mapping.threads import threading_info

    info = dict(threading_info())
    info["numba"] = info.pop("threads")
    return info
