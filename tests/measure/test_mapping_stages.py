"""``map_sequence``'s time accounting: every stage that ran, nothing for stages that did not."""

from __future__ import annotations

import pytest
import torch

from evsmap.measure.mapping import map_sequence
from evsmap.registry import READERS, SEGMENTERS, UPDATERS


@pytest.fixture(scope="module")
def seq():
    return READERS.create("synthetic", frames=2, width=80, height=60)


def test_a_network_reports_its_three_stages(seq):
    torch.manual_seed(0)
    net = SEGMENTERS.create("feagnet-v1", input_size=(64, 96))
    rec = map_sequence(seq, UPDATERS.create("multiclass-bayes", resolution=0.2),
                       updater_name="multiclass-bayes", segmenter=net,
                       segmenter_name="feagnet-v1")
    assert set(rec.stages_ms) == {"read", "preprocess", "network", "postprocess", "update"}
    assert all(len(v) == 2 for v in rec.stages_ms.values())
    assert len(rec.segment_ms) == 2
    # the stages add up to the segmentation time measured around predict
    for i in range(2):
        parts = sum(rec.stages_ms[s][i] for s in ("preprocess", "network", "postprocess"))
        assert parts <= rec.segment_ms[i] + 1e-6
    assert set(rec.stage_medians()) == set(rec.stages_ms)


def test_the_oracle_is_not_counted_as_segmentation(seq):
    rec = map_sequence(seq, UPDATERS.create("multiclass-bayes", resolution=0.2),
                       updater_name="multiclass-bayes", segmenter=SEGMENTERS.create("oracle"),
                       segmenter_name="oracle")
    assert rec.segment_ms == [] and len(rec.stages_ms["oracle"]) == 2
    assert rec.segment_update_hz == rec.update_hz
    assert rec.wall_hz <= rec.update_hz  # frames / wall: reading and the oracle too


def test_an_updater_without_semantics_runs_no_segmenter(seq):
    rec = map_sequence(seq, UPDATERS.create("orgb", resolution=0.2), updater_name="orgb",
                       segmenter=SEGMENTERS.create("oracle"), segmenter_name="oracle")
    assert rec.segmenter is None and rec.segment_ms == []
    assert set(rec.stages_ms) == {"read", "update"}
    assert "uses no semantics" in rec.extra["segmenter_not_run"]


def test_the_record_names_each_rate_once_and_gives_the_runner_its_values(seq):
    """One record of a mapping run: ``map --json`` prints it, the runner stores its values
    (docs/measurement.md, "Quantities of a mapping run")."""
    torch.manual_seed(0)
    net = SEGMENTERS.create("feagnet-v1", input_size=(64, 96))
    rec = map_sequence(seq, UPDATERS.create("multiclass-bayes", resolution=0.2),
                       updater_name="multiclass-bayes", segmenter=net,
                       segmenter_name="feagnet-v1", pipeline=False)
    median = sorted(rec.update_ms)[0] / 2 + sorted(rec.update_ms)[1] / 2
    segment = sorted(rec.segment_ms)[0] / 2 + sorted(rec.segment_ms)[1] / 2
    assert rec.update_hz == pytest.approx(1000.0 / median)
    assert rec.segment_update_hz == pytest.approx(1000.0 / (median + segment))
    assert rec.wall_hz == pytest.approx(rec.frames / rec.wall_s)
    data = rec.as_dict()
    assert not {"hz_median", "hz_end_to_end", "hz_segment_update", "end_to_end_hz"} & set(data)
    values = rec.values()
    assert list(values)[:3] == ["frames", "update_hz", "segment_update_hz"]
    assert values["segment_update_hz"] == rec.segment_update_hz
    assert values["map_bytes"] == rec.map_bytes_published  # Table IV's Map Size
    assert values["rss_added_bytes"] == rec.peak_rss_bytes - rec.start_rss_bytes
