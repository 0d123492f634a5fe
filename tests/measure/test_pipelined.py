"""The pipelined mapping loop: the same map as the sequential loop, errors surfaced, workers
stopped."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import torch

from evsmap.data import FrameList
from evsmap.errors import EvsmapError
from evsmap.measure.engine import StageTimes, run_mapping
from evsmap.measure.evaluators import MapFiles
from evsmap.measure.mapping import map_sequence
from evsmap.registry import READERS, SEGMENTERS, UPDATERS


@pytest.fixture(scope="module")
def seq():
    return READERS.create("synthetic", frames=5, width=80, height=60)


def _map_bytes(tmp_path, name, seq, segmenter, pipeline, **kwargs):
    out = tmp_path / f"{name}.ot"
    run = run_mapping(seq, UPDATERS.create("multiclass-bayes", resolution=0.1),
                      segmenter=segmenter, pipeline=pipeline, measure_memory=False,
                      evaluators=[MapFiles(out=out)], **kwargs)
    return run, out.read_bytes()


@pytest.mark.parametrize("segmenter", ["oracle", "feagnet-v1"])
def test_the_pipelined_map_is_the_sequential_map(tmp_path, seq, segmenter):
    torch.manual_seed(0)
    seg = SEGMENTERS.create(segmenter, **({"input_size": (64, 96)}
                                          if segmenter != "oracle" else {}))
    seq_run, seq_bytes = _map_bytes(tmp_path, "seq", seq, seg, False)
    pipe_run, pipe_bytes = _map_bytes(tmp_path, "pipe", seq, seg, True)
    assert pipe_bytes == seq_bytes
    assert pipe_run.indices == seq_run.indices == list(range(5))
    assert pipe_run.pipelined and not seq_run.pipelined
    # every stage timed once per frame, in both loops
    assert {k: len(v) for k, v in pipe_run.times.stages.items()} == \
        {k: len(v) for k, v in seq_run.times.stages.items()}
    assert pipe_run.wall_s > 0 and pipe_run.hz_wall == pytest.approx(5 / pipe_run.wall_s)


def test_observations_given_beforehand_are_used_in_order(tmp_path, seq):
    oracle = SEGMENTERS.create("oracle")
    observations = [oracle.predict(seq.frame(i)) for i in range(len(seq))]
    _, seq_bytes = _map_bytes(tmp_path, "seq", seq, None, False, observations=observations)
    _, pipe_bytes = _map_bytes(tmp_path, "pipe", seq, None, True, observations=observations)
    assert pipe_bytes == seq_bytes


class _Failing(FrameList):
    """Frame 2 cannot be read."""

    def frame(self, index):
        if index == 2:
            raise EvsmapError("frame 2: corrupt depth image")
        return super().frame(index)


def _failing(seq):
    frames = [seq.frame(i) for i in range(len(seq))]
    return _Failing("failing", frames[0].intrinsics, frames)


def test_a_reader_error_reaches_the_caller_and_stops_the_workers(seq):
    before = threading.active_count()
    with pytest.raises(EvsmapError, match="frame 2: corrupt"):
        run_mapping(_failing(seq), UPDATERS.create("multiclass-bayes", resolution=0.1),
                    segmenter=SEGMENTERS.create("oracle"), pipeline=True,
                    measure_memory=False)
    assert threading.active_count() == before


def test_skip_bad_leaves_the_frame_out_in_both_loops(tmp_path, seq):
    runs = {}
    for pipeline in (False, True):
        out = tmp_path / f"{pipeline}.ot"
        runs[pipeline] = run_mapping(
            _failing(seq), UPDATERS.create("multiclass-bayes", resolution=0.1),
            segmenter=SEGMENTERS.create("oracle"), pipeline=pipeline, skip_bad=True,
            measure_memory=False, evaluators=[MapFiles(out=out)])
        runs[pipeline].bytes = out.read_bytes()
    assert runs[True].indices == runs[False].indices == [0, 1, 3, 4]
    assert runs[True].skipped.frames == runs[False].skipped.frames
    assert runs[True].bytes == runs[False].bytes


class _Boom:
    """A segmenter that fails on its third frame."""

    uses_semantics = True
    last_timings: dict = {}

    def __init__(self):
        self.oracle = SEGMENTERS.create("oracle")
        self.calls = 0

    def predict(self, frame, *, k=3):
        self.calls += 1
        if self.calls == 3:
            raise RuntimeError("network exploded")
        return self.oracle.predict(frame, k=k)


def test_a_segmenter_error_reaches_the_caller(seq):
    before = threading.active_count()
    with pytest.raises(RuntimeError, match="network exploded"):
        run_mapping(seq, UPDATERS.create("multiclass-bayes", resolution=0.1),
                    segmenter=_Boom(), pipeline=True, measure_memory=False)
    assert threading.active_count() == before


def test_leaving_the_loop_early_stops_the_workers(seq):
    from evsmap.measure.engine import timed_predict
    from evsmap.measure.pipelined import pipelined_frames
    from evsmap.readers.skipping import SkippedFrames

    before = threading.active_count()
    frames = pipelined_frames(seq, list(range(len(seq))), segmenter=SEGMENTERS.create("oracle"),
                              read_times=StageTimes(), segment_times=StageTimes(),
                              timed_predict=timed_predict, skip_bad=False,
                              skipped=SkippedFrames())
    position, index, frame, observation = next(frames)
    assert (position, index) == (0, 0) and observation is not None
    frames.close()
    assert threading.active_count() == before


def test_map_sequence_records_the_wall_rate_and_the_stage_threads(seq):
    from evsmap.measure.pipelined import stage_threads

    rec = map_sequence(seq, UPDATERS.create("multiclass-bayes", resolution=0.2),
                       updater_name="multiclass-bayes", segmenter=SEGMENTERS.create("oracle"),
                       segmenter_name="oracle", pipeline=True, threads=stage_threads(None))
    assert rec.pipeline["enabled"] is True and rec.pipeline["update"]["numba"] >= 1
    assert rec.hz_end_to_end == pytest.approx(rec.frames / rec.wall_s)
    assert np.isfinite(rec.hz_segment_update)
