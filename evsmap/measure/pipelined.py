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
end-to-end rate, frames / wall time (``MappingPass.wall_s``).

BLAS (numpy's OpenBLAS) runs with one thread during the loop (``threadpoolctl``): its threads
busy-wait for cores the other stages hold, and a 307,200 x 3 by 3 x 3 product that takes 1 ms
alone took 200 ms that way (the synthetic renderer's ray directions). One thread gives the same
numbers (no reduction is split).

A failure in a worker thread (a bad frame, a network error) is re-raised in the calling thread;
leaving the loop early (an exception, Ctrl-C) stops both workers within one queue timeout.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from evsmap.data import Frame, SemanticObservation, Sequence
from evsmap.interfaces import Segmenter
from evsmap.readers.skipping import SkippedFrames, read_frames

DEPTH = 2
"""Frames each queue holds: enough to keep every stage busy, little memory (a 640x480 frame
with its observation is about 4 MB)."""

BLAS_THREADS = 1
"""numpy's BLAS threads while the stages overlap."""

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
                 out: queue.Queue, stop: threading.Event) -> None:
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


def _get(q: queue.Queue, stop: threading.Event) -> Any:
    while True:
        try:
            return q.get(timeout=_POLL_S)
        except queue.Empty:
            if stop.is_set():
                return _End()


def pipelined_frames(sequence: Sequence, order: list[int], *, segmenter: Segmenter | None,
                     read_times: Any, segment_times: Any,
                     timed_predict: Callable[[Segmenter, Frame, Any], SemanticObservation],
                     skip_bad: bool, skipped: SkippedFrames,
                     progress: Callable[[Any], Any] | None = None, depth: int = DEPTH
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
        timed_predict: the engine's timed prediction.
        skip_bad, skipped: as for :func:`~evsmap.readers.skipping.read_frames` (``skipped`` is
            only written by the reader thread).
        progress: wraps the list of indices (it advances as frames are read).
        depth: frames each queue holds.
    """
    stop = threading.Event()
    read_q: queue.Queue = queue.Queue(maxsize=depth)
    seg_q: queue.Queue = queue.Queue(maxsize=depth)

    def read(put) -> None:
        indices = order if progress is None else progress(order)
        frames = iter(read_frames(sequence, indices, skip_bad=skip_bad, skipped=skipped))
        while True:
            t0 = time.perf_counter()
            try:
                index, frame = next(frames)
            except StopIteration:
                return
            read_times.add("read", (time.perf_counter() - t0) * 1000.0)
            if not put((index, frame)):
                return

    def segment(put) -> None:
        while True:
            item = _get(read_q, stop)
            if isinstance(item, _End):
                if item.error is not None:
                    raise item.error
                return
            index, frame = item
            observation = None if segmenter is None else \
                timed_predict(segmenter, frame, segment_times)
            if not put((index, frame, observation)):
                return

    from threadpoolctl import threadpool_limits

    workers = [_Stage("evsmap-read", read, read_q, stop),
               _Stage("evsmap-segment", segment, seg_q, stop)]
    blas = threadpool_limits(limits=BLAS_THREADS, user_api="blas")
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
        blas.restore_original_limits()


def stage_threads(segmenter: Segmenter | None) -> dict[str, Any]:
    """The threads each stage runs with, as set now (recorded beside a rate): the reader's
    (one Python thread; a reader's library may add its own), the segmenter's (torch's intra-op
    threads, and ONNX Runtime's when that is its backend) and the update kernels' (numba)."""
    import torch

    segment: dict[str, Any] = {"torch": torch.get_num_threads()}
    if segmenter is not None and getattr(segmenter, "backend", None) == "onnxruntime":
        segment["onnxruntime"] = torch.get_num_threads()
    return {"read": 1, "segment": segment, "update": update_threads(),
            "blas_when_pipelined": BLAS_THREADS}


def update_threads() -> dict[str, Any]:
    """The update kernels' threads and numba threading layer
    (:func:`evsmap.mapping.threads.threading_info`)."""
    from evsmap.mapping.threads import threading_info

    info = dict(threading_info())
    info["numba"] = info.pop("threads")
    return info
