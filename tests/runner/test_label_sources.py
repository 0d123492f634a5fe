"""The synthetic room's label sources (evsmap/runner/detail.py, evsmap/runner/mapping_*.py):
TESAMap and EVSMap mapped again with each oracle profile and a proxy network's labels, planned
with and without proxy weights, each with its own record key, its source on the run (typed) and
in the record; the oracle's observations never shared between profiles; ``--synthetic-labels
network`` on Table IV's synthetic rows."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import torch

from evsmap.registry import SEGMENTERS
from evsmap.runner.context import RunContext
from evsmap.runner.detail import (
    SENSITIVITY_ROWS,
    is_sensitivity,
    sensitivity_row,
    sensitivity_system,
)
from evsmap.runner.mapping_labels import (
    lacks_labels,
    oracle_observations_key,
    unlabelled_record,
)
from evsmap.runner.mapping_plan import LabelSource
from evsmap.runner.mapping_record import mapping_record
from evsmap.runner.matrix import plan
from evsmap.segmenters.cards import make_card
from evsmap.segmenters.oracle_profile import PROFILE_NAMES


def _proxy_weights(folder: Path, model: str = "feagnet-v1") -> Path:
    """A weights file whose card is for ``model`` on synthrooms (the runner reads the card only
    when planning; these tensors fit no network)."""
    state = {"head.weight": torch.zeros(3, 3)}
    card = make_card(model=model, options={}, num_classes=40,
                     class_names=[f"c{i}" for i in range(40)], state_dict=state,
                     dataset="synthrooms", epochs=1, val_miou=0.1)
    path = folder / "proxy" / f"{model}@synthrooms" / "best.pt"
    path.parent.mkdir(parents=True)
    torch.save({"state_dict": state, "card": card}, path)
    return path


def _ctx(tmp_path: Path, weights: Path | None = None) -> RunContext:
    (tmp_path / "run").mkdir(exist_ok=True)
    return RunContext.create(tmp_path / "run", data_root=tmp_path, weights_dir=weights,
                             quick=True)


def _sensitivity(ctx: RunContext):
    return [r for r in plan(ctx, ["table4"]).runs if is_sensitivity(r.row)]


def test_without_proxy_weights_each_other_profile_twice_and_one_na_run(tmp_path):
    ctx = _ctx(tmp_path)
    runs = _sensitivity(ctx)
    others = [p for p in PROFILE_NAMES if p != ctx.oracle_profile]
    oracle = [r for r in runs if r.labels.kind == "oracle"]
    assert [(r.labels.profile, sensitivity_system(r.row)) for r in oracle] == [
        (p, row) for p in others for row in SENSITIVITY_ROWS]
    network = [r for r in runs if r.labels.kind == "network"]
    assert len(network) == 1 and sensitivity_system(network[0].row) is None
    assert all(r.sequence == "synthetic" and r.resolution == ctx.resolution and not r.views
               for r in runs)
    # every source has its own record key; the default rows' keys are untouched
    keys = [r.key for r in runs]
    assert len(set(keys)) == len(keys)
    assert "extra/mapping/detail-labels-per-pixel-evsmap/synthetic@0.02m" in keys
    # the n/a run says what is missing and how to get it, without being mapped
    missing = network[0]
    assert lacks_labels(ctx, missing)
    record = unlabelled_record(missing)
    assert record.status == "na" and record.needs == ["weights:feagnet-v1@synthrooms"]
    assert "evsmap reproduce --train" in record.reason and \
        "feagnet-v1@synthrooms.pt" in record.reason
    assert record.inputs["labels"] == {"kind": "network", "model": "feagnet-v1",
                                       "dataset": "synthrooms"}


def test_with_proxy_weights_the_network_maps_both_rows(tmp_path):
    weights = tmp_path / "weights"
    _proxy_weights(weights, "feagnet-v2")  # not the first model: the first found is taken
    ctx = _ctx(tmp_path, weights)
    network = [r for r in _sensitivity(ctx) if r.labels.kind == "network"]
    assert [r.row for r in network] == [sensitivity_row("network", row)
                                        for row in SENSITIVITY_ROWS]
    assert all(r.labels == LabelSource.network("feagnet-v2") for r in network)
    assert not any(lacks_labels(ctx, r) for r in network)


def test_the_runs_own_profile_is_not_mapped_twice(tmp_path):
    ctx = _ctx(tmp_path)
    ctx.oracle_profile = "per-pixel"
    profiles = {r.labels.profile for r in _sensitivity(ctx) if r.labels.kind == "oracle"}
    assert profiles == set(PROFILE_NAMES) - {"per-pixel"}
    # with the network as the run's labels, every profile is a source beside it
    ctx.synthetic_labels = "network"
    runs = _sensitivity(ctx)
    assert {r.labels.profile for r in runs} == set(PROFILE_NAMES)


def test_oracle_observations_are_keyed_by_profile(tmp_path):
    ctx = _ctx(tmp_path)
    seq = SimpleNamespace(name="synthetic")
    keys = [oracle_observations_key(SEGMENTERS.create("oracle", profile=p, **ctx.oracle), ctx,
                                    seq, "frames") for p in PROFILE_NAMES]
    assert len({repr(sorted(k.items())) for k in keys}) == len(PROFILE_NAMES)
    assert [k["profile"] for k in keys] == list(PROFILE_NAMES)


def test_a_label_source_run_records_its_source(tmp_path):
    ctx = _ctx(tmp_path)
    run = next(r for r in _sensitivity(ctx)
               if r.labels == LabelSource.oracle("noise-free") and r.row.endswith("-evsmap"))
    record = mapping_record(run, ctx)
    assert record.status == "ok", record.reason or record.error
    assert record.key == "extra/mapping/detail-labels-noise-free-evsmap/synthetic@0.02m"
    assert record.inputs["labels"] == {"kind": "oracle", "profile": "noise-free"}
    assert record.details["labels"]["profile"] == "noise-free"
    assert record.details["labels_from"] == "oracle (profile noise-free)"
    assert 0 < record.values["scene_miou"] <= 1
    # its map is a row's again: no views of its own
    assert not list((tmp_path / "run" / "artifacts").glob("map-detail-labels-*"))


def test_synthetic_labels_network_relabels_table4s_synthetic_rows(tmp_path):
    ctx = _ctx(tmp_path)
    ctx.synthetic_labels = "network"
    runs = plan(ctx, ["table4"]).runs
    semantic = [r for r in runs if r.sequence == "synthetic" and r.segmenter is not None
                and not is_sensitivity(r.row)]
    assert semantic and all(r.labels == LabelSource.network("feagnet-v1") for r in semantic)
    evsmap = next(r for r in semantic if r.row == "evsmap")
    assert evsmap.key == "extra/mapping/evsmap/synthetic@0.02m"  # Table IV reads it
    assert lacks_labels(ctx, evsmap)
    record = unlabelled_record(evsmap)
    assert record.needs == ["weights:feagnet-v1@synthrooms"]
    # geometry-only rows are untouched
    assert all(r.labels is None for r in runs if r.segmenter is None)
