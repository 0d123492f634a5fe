"""The pipelined mapping loop: the same map as the sequential loop, errors surfaced, workers
stopped."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import torch

from evsmap.data import FrameList
from evsmap.errors import EvsmapError
from evsmap.interfaces import Segmenter
from evsmap.measure.engine import StageTimes, run_mapping
from evsmap.measure.evaluators import MapFiles
from evsmap.measure.mapping import map_sequence
from evsmap.measure.pipelined import PIPELINED, StageThreads
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
    assert pipe_run.wall_s > 0 and pipe_run.wall_hz == pytest.approx(5 / pipe_run.wall_s)


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


class _Boom(Segmenter):
    """A segmenter that fails on its third frame."""

    name = "boom"
    module = None

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
    from evsmap.measure.engine import _timed_frames, timed_predict
    from evsmap.measure.pipelined import pipelined_frames
    from evsmap.readers.skipping import SkippedFrames

    before = threading.active_count()
    frames = pipelined_frames(seq, list(range(len(seq))), segmenter=SEGMENTERS.create("oracle"),
                              read_times=StageTimes(), segment_times=StageTimes(),
                              timed_predict=timed_predict, timed_frames=_timed_frames,
                              skip_bad=False,
                              skipped=SkippedFrames())
    position, index, frame, observation = next(frames)
    assert (position, index) == (0, 0) and observation is not None
    frames.close()
    assert threading.active_count() == before


def test_map_sequence_records_the_wall_rate_and_the_stage_threads(seq):
    rec = map_sequence(seq, UPDATERS.create("multiclass-bayes", resolution=0.2),
                       updater_name="multiclass-bayes", segmenter=SEGMENTERS.create("oracle"),
                       segmenter_name="oracle", pipeline=True)
    assert rec.pipeline["enabled"] is True and rec.pipeline["update"]["numba"] >= 1
    assert rec.pipeline["segment"]["torch"] == PIPELINED.torch and rec.pipeline["blas"] == 1
    assert rec.wall_hz == pytest.approx(rec.frames / rec.wall_s)
    assert np.isfinite(rec.segment_update_hz)


def test_stage_threads_are_set_for_the_loop_and_restored(seq):
    from evsmap.mapping.threads import update_threads

    torch_before, update_before = torch.get_num_threads(), update_threads()
    torch.manual_seed(0)
    net = SEGMENTERS.create("feagnet-v1", input_size=(64, 96), backend="onnxruntime")
    run = run_mapping(seq, UPDATERS.create("multiclass-bayes", resolution=0.2), segmenter=net,
                      pipeline=True, measure_memory=False, frames=2,
                      threads=StageThreads(segment=1, spinning=False, torch=1, update=1, blas=1))
    assert run.threads["segment"] == {"torch": 1, "onnxruntime": 1, "spinning": False}
    assert run.threads["update"]["numba"] == 1 and run.threads["blas"] == 1
    assert torch.get_num_threads() == torch_before and update_threads() == update_before
    # the session was built with them
    assert net._session.get_session_options().intra_op_num_threads == 1


@pytest.mark.parametrize("pairs, message", [
    ([("gpu", 2)], "unknown stage"), ([("update", 0)], "positive integer"),
    ([("torch", "two")], "positive integer"), ([("segment", True)], "positive integer")])
def test_bad_stage_threads_are_one_clear_error(pairs, message):
    from evsmap.errors import InvalidDataError
    from evsmap.measure.pipelined import stage_threads_option

    with pytest.raises(InvalidDataError, match=message):
        stage_threads_option(pairs, pipeline=True)


def test_stage_threads_option_starts_from_the_loop_default():
    from evsmap.measure.pipelined import SEQUENTIAL, stage_threads_option

    assert stage_threads_option([], pipeline=True) == PIPELINED
    assert stage_threads_option([("update", 1)], pipeline=False) == \
        StageThreads(update=1) and SEQUENTIAL.update is None
