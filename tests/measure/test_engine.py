"""The measurement engine: one timed loop for segmentation and one for mapping, with evaluators
(``evsmap.measure.engine``, ``evsmap.measure.evaluators``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from evsmap.data import FrameList, SemanticObservation
from evsmap.errors import EvsmapError, InvalidDataError
from evsmap.interfaces import Segmenter
from evsmap.measure.engine import in_memory, rates, run_mapping, run_segmentation
from evsmap.measure.evaluators import (
    ConfusionEvaluator,
    KeepObservations,
    MapFiles,
    MapStatistics,
    SegmentationEvaluator,
    write_map,
)
from evsmap.registry import READERS, SEGMENTERS, UPDATERS


@pytest.fixture(scope="module")
def seq():
    return READERS.create("synthetic", frames=3, width=80, height=60)


class Counting(Segmenter):
    """The ground truth as a one-hot observation; counts its calls."""

    num_classes = 40
    class_names = ()

    def __init__(self) -> None:
        self.calls = 0

    @property
    def module(self):
        return None

    def predict(self, frame, *, k=3):
        self.calls += 1
        labels = np.where(frame.labels == 255, 0, frame.labels).astype(np.int64)
        probs = np.zeros((*labels.shape, self.num_classes), dtype=np.float32)
        np.put_along_axis(probs, labels[..., None], 1.0, axis=2)
        return SemanticObservation.from_probabilities(probs, k=3)


class Order(SegmentationEvaluator):
    name = "order"

    def __init__(self, log: list[str]) -> None:
        self.log = log

    def check(self, index, frame):
        self.log.append(f"check {index}")

    def process(self, index, frame, observation):
        self.log.append(f"process {index}")

    def evaluate(self):
        return list(self.log)


def test_segmentation_times_each_stage_and_runs_warmup_untimed(seq):
    net = Counting()
    log: list[str] = []
    run = run_segmentation(seq, net, indices=[2, 0], warmup=2, evaluators=[Order(log)])
    assert net.calls == 4  # 2 warm-up + 2 timed
    assert run.indices == [2, 0] and run.frames == 2
    assert set(run.times.stages) == {"read", "predict"}
    assert len(run.predict_ms) == 2 and all(ms >= 0 for ms in run.predict_ms)
    # each frame is checked before it is segmented, processed after
    assert run.results["order"] == ["check 2", "process 2", "check 0", "process 0"]


def test_perfect_predictions_score_one(seq):
    run = run_segmentation(seq, Counting(), evaluators=[ConfusionEvaluator(num_classes=40)])
    assert run.frames == 3
    assert run.results["confusion"].miou == pytest.approx(1.0)


def test_an_unlabelled_frame_is_refused_before_the_segmenter_runs(seq):
    net = Counting()
    frames = [seq.frame(0)]
    unlabelled = FrameList("plain", frames[0].intrinsics,
                           [dataclasses.replace(frames[0], labels=None)])
    with pytest.raises(EvsmapError, match="'plain' has no ground-truth labels"):
        run_segmentation(unlabelled, net, evaluators=[
            ConfusionEvaluator(num_classes=40, source="plain")])
    assert net.calls == 0


def test_kept_observations_reach_the_sink_in_order(seq):
    seen = []
    run = run_segmentation(seq, Counting(), evaluators=[
        KeepObservations(sink=lambda n, o: seen.append(n))])
    assert seen == [0, 1, 2] and len(run.results["observations"]) == 3


def test_two_evaluators_with_one_name_are_refused(seq):
    with pytest.raises(InvalidDataError, match="two evaluators named confusion"):
        run_segmentation(seq, Counting(), evaluators=[ConfusionEvaluator(num_classes=40),
                                                      ConfusionEvaluator(num_classes=40)])


def test_mapping_makes_the_map_inside_its_memory_scope_and_evaluates_it(seq):
    made = []

    def factory():
        made.append(1)
        return UPDATERS.create("multiclass-bayes", resolution=0.2)

    run = run_mapping(seq, factory, segmenter=Counting(),
                      evaluators=[MapStatistics(), MapFiles()])
    assert made == [1] and run.frames == 3
    assert set(run.times.stages) == {"read", "predict", "update"}
    assert len(run.update_ms) == len(run.segment_ms) == 3
    assert run.memory is not None and run.memory.peak_rss_bytes >= run.memory.start_rss_bytes
    stats, files = run.results["stats"], run.results["files"]
    assert stats.nodes == run.updater.stats().nodes and stats.leaves > 0
    assert set(files.sizes) == {"full", "published", "colour", "message"} and files.file is None


def test_the_engine_builds_the_map_a_plain_loop_builds(seq, tmp_path):
    observations = [Counting().predict(seq.frame(i)) for i in range(len(seq))]
    plain = UPDATERS.create("multiclass-bayes", resolution=0.2)
    for i in range(len(seq)):
        plain.integrate(seq.frame(i), observations[i])
    run = run_mapping(seq, UPDATERS.create("multiclass-bayes", resolution=0.2),
                      observations=observations, measure_memory=False,
                      evaluators=[MapFiles(out=tmp_path / "engine.ot")])
    write_map(plain, tmp_path / "plain.ot")
    assert run.memory is None and run.segment_ms == []
    assert (tmp_path / "engine.ot").read_bytes() == (tmp_path / "plain.ot").read_bytes()


def test_observations_go_only_to_an_updater_that_uses_semantics(seq):
    run = run_mapping(seq, UPDATERS.create("orgb", resolution=0.2), segmenter=Counting())
    assert run.segmenter_not_run is not None and "predict" not in run.times.stages


def test_mapping_refuses_bad_combinations(seq):
    updater = UPDATERS.create("multiclass-bayes", resolution=0.2)
    obs = [Counting().predict(seq.frame(0))]
    with pytest.raises(InvalidDataError, match="not both"):
        run_mapping(seq, updater, segmenter=Counting(), observations=obs)
    with pytest.raises(InvalidDataError, match="1 observations for 3 frames"):
        run_mapping(seq, updater, observations=obs)
    still = FrameList("still", seq.intrinsics, [seq.frame(0)], meta={"poses": False})
    with pytest.raises(EvsmapError, match="no camera poses"):
        run_mapping(still, updater)


def test_the_oracle_is_its_own_stage(seq):
    run = run_mapping(seq, UPDATERS.create("multiclass-bayes", resolution=0.2),
                      segmenter=SEGMENTERS.create("oracle"), measure_memory=False)
    assert run.segment_ms == [] and len(run.times.get("oracle")) == 3


def test_rates():
    assert rates([10.0, 20.0, 30.0]) == (50.0, 50.0)
    assert rates([10.0, 10.0], [30.0, 30.0]) == (100.0, 25.0)
    assert all(np.isnan(rates([])))
    # the median segmentation time (any number of frames) + the median update time
    assert rates([10.0, 30.0, 20.0], [40.0, 30.0]) == (50.0, pytest.approx(1000.0 / 55.0))


def test_in_memory_wraps_frames(seq):
    frames = [seq.frame(0), seq.frame(1)]
    wrapped = in_memory(frames, "two")
    assert len(wrapped) == 2 and wrapped.frame(1) is frames[1]
    with pytest.raises(InvalidDataError, match="no frames"):
        in_memory([], "none")
