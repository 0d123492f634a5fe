"""How a study's answer moves with the labels: one record per key point and label source, the
study's own labels taken from its trials, noise-free labels scoring at least per-pixel's, the
sizes measured under each labelling, the records stored in the study and read
back on a re-report, a trained network as one more source, the report's section and the options'
one-line errors."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from evsmap.explore.bench import Bench
from evsmap.explore.sensitivity import (
    ATTR,
    BEST_POINT,
    PAPER_POINT,
    Network,
    key_points,
    label_sources,
    measure_point,
    run_sensitivity,
)
from evsmap.explore.study import StudyConfig, create_study, load_study, open_storage
from evsmap.explore.workers import Worker, work
from tests.explore.conftest import SMALL_INPUTS

TRIALS = 3
PROFILES = {"oracle per-pixel", "oracle fitted", "oracle noise-free"}
FIGURES = ("map_size", "baseline_map_size", "size_ratio", "scene_miou", "baseline_scene_miou")


def _study(tmp_path: Path, space: Any) -> tuple[Any, Any, Bench]:
    storage = open_storage(f"sqlite:///{tmp_path / 'study'}.db")
    config = StudyConfig(space.text, space.path, SMALL_INPUTS.as_dict(), TRIALS)
    study = create_study(storage, "explore", space, config)
    bench = Bench(space, SMALL_INPUTS)
    work(study, storage, bench, trials=TRIALS, worker=Worker.here())
    return storage, study, bench


class _NoMapping(Bench):
    """A bench that must not map (a re-report reads the stored records)."""

    def labelled_map(self, *args: Any, **kwargs: Any) -> dict[str, Any]:
        raise AssertionError("a stored record was mapped again")


def _key(r: dict[str, Any]) -> tuple[int, str]:
    return r["trial"], r["source"]


@pytest.mark.slow
def test_records_per_point_and_source_stored_and_reused(tmp_path: Path, small_space) -> None:
    from evsmap.explore.results import answer, trial_rows

    storage, study, bench = _study(tmp_path, small_space)
    records = run_sensitivity(study, bench)
    points = key_points(answer(trial_rows(study)))
    assert points and points[0].roles[0] == PAPER_POINT
    # one record per key point and label source; the default study's labels are the fitted
    # profile's, marked as the study's and taken from its trial as stored
    assert len(records) == len(points) * len(PROFILES)
    assert {_key(r) for r in records} == {(p.trial, s) for p in points for s in PROFILES}
    trials = {t.number: t.user_attrs["record"] for t in study.trials}
    for r in records:
        assert r["study_labels"] == (r["source"] == "oracle fitted")
        if r["study_labels"]:
            trial = trials[r["trial"]]
            assert trial["labels"] == bench.labels_id()  # the trial recorded its labels
            assert r["from"] == "the study's trial" and r["profile"] == "fitted"
            assert r["size_ratio"] == trial["size_ratio"]
            assert r["miou_loss"] == pytest.approx(trial["miou_loss"])
        else:
            assert r["from"] == "mapped"
        assert r["meets"] == (r["size_ratio"] > 1 and r["miou_loss"] <= 1.0)
    by = {_key(r): r for r in records}
    for p in points:
        clean, noisy = by[(p.trial, "oracle noise-free")], by[(p.trial, "oracle per-pixel")]
        # exact labels score at least what per-pixel noise does, for both maps of the pair
        assert clean["scene_miou"] >= noisy["scene_miou"]
        assert clean["baseline_scene_miou"] >= noisy["baseline_scene_miou"]
        # the sizes are measured under each labelling, not copied from the study's trial
        for s in PROFILES:
            r = by[(p.trial, s)]
            assert r["size_ratio"] == pytest.approx(r["baseline_map_size"] / r["map_size"])
    # mapped again with the study's own labels, a key point gives the study's own figures
    own = next(s for s in label_sources(bench) if s.study)
    for p in points:
        again = measure_point(bench, own, trials[p.trial])
        fresh = by[(p.trial, "oracle fitted")]
        assert {k: again[k] for k in FIGURES} == {k: fresh[k] for k in FIGURES}
    # stored in the study: a re-report in a new process maps nothing and reads the same
    assert len(study.user_attrs[ATTR]["records"]) == len(records)
    again = run_sensitivity(load_study(storage, "explore"), _NoMapping(small_space, SMALL_INPUTS))
    assert again == records


@pytest.mark.slow
def test_a_trained_network_is_one_more_source(tmp_path: Path, small_space) -> None:
    import torch

    from evsmap.segmenters.cards import make_card
    from evsmap.segmenters.create import create_segmenter

    module = create_segmenter("feagnet-v1", init_seed=1).module
    state = module.state_dict()
    weights = tmp_path / "tiny.pt"
    card = make_card(model="feagnet-v1", options={}, num_classes=40,
                     class_names=[f"c{i}" for i in range(40)], state_dict=state)
    torch.save({"state_dict": state, "card": card}, weights)
    storage, study, bench = _study(tmp_path, small_space)
    records = run_sensitivity(study, bench, network=Network("feagnet-v1", str(weights)))
    network = [r for r in records if r["source"] == "feagnet-v1 (tiny.pt)"]
    assert len(network) == len(records) // 4 and all(not r["study_labels"] for r in network)
    assert all(r["weights"] == str(weights) and r["from"] == "mapped" for r in network)
    # the network is kept with the study: a re-report without it still has its records
    again = run_sensitivity(load_study(storage, "explore"), _NoMapping(small_space, SMALL_INPUTS))
    assert again == records


def test_the_study_s_labels_are_those_its_trial_recorded() -> None:
    from evsmap.explore.sensitivity import Source, point_sources

    sources = [Source("oracle per-pixel", "oracle", {"profile": "per-pixel"}),
               Source("oracle fitted", "oracle", {"profile": "fitted"}, study=True)]
    ids = {"oracle per-pixel": "a", "oracle fitted": "b"}
    # the trial's labels are today's fitted profile's: that source is the study's
    same = point_sources(sources, ids, "b")
    assert [(s.name, s.study, i) for s, i in same] == [("oracle per-pixel", False, "a"),
                                                       ("oracle fitted", True, "b")]
    # the fitted profile changed since the trials ran: today's is mapped like any other
    # source, and the study's own labels are one more row, read from the trial
    changed = point_sources(sources, ids, "c")
    assert [(s.name, s.study, i) for s, i in changed] == [
        ("the study's labels (oracle fitted, when its trials ran)", True, "c"),
        ("oracle per-pixel", False, "a"), ("oracle fitted", False, "b")]
    # a study made before trials recorded their labels: today's match
    assert [s.study for s, _ in point_sources(sources, ids, None)] == [False, True]


def _record(trial: int, point: str, source: str, ratio: float, loss: float,
            own: bool = False) -> dict[str, Any]:
    return {"trial": trial, "point": point, "source": source, "study_labels": own,
            "segmenter": "oracle", "weights": None, "size_ratio": ratio,
            "map_size": 2e6, "baseline_map_size": 2e6 * ratio, "scene_miou": 0.3,
            "baseline_scene_miou": 0.3 + loss / 100, "miou_loss": loss,
            "smaller": ratio > 1, "within": loss <= 1.0, "meets": ratio > 1 and loss <= 1.0}


def test_report_section_says_what_holds_and_what_depends(small_space) -> None:
    from evsmap.report.explore import sensitivity_section

    records = [{**_record(0, PAPER_POINT, "oracle fitted", 0.6, 4.0, own=True),
                "profile": "fitted"},
               _record(0, PAPER_POINT, "oracle noise-free", 0.6, 2.0),
               _record(0, PAPER_POINT, "feagnet-v1 (best.pt)", 0.6, 5.0),
               _record(7, BEST_POINT, "oracle fitted", 1.2, 0.5, own=True),
               _record(7, BEST_POINT, "oracle noise-free", 1.2, 3.0),
               _record(7, BEST_POINT, "feagnet-v1 (best.pt)", 1.2, 0.8)]
    text = "\n".join(sensitivity_section(records, small_space))
    assert text.startswith("## How the answer moves with the labels")
    assert "labelled by **oracle fitted** (segmenter `oracle`, profile `fitted`)" in text
    assert text.count("\n| trial ") == 6
    assert "| trial 7 (the best within 1 pt) | oracle fitted (the study's) | 1.20x |" in text
    verdict = next(line for line in text.splitlines() if line.startswith("Under every"))
    assert "at trial 0 (the paper's point) the map is not smaller than tesamap's" in verdict
    assert "at trial 0 (the paper's point) it loses more than 1 pt of scene mIoU" in verdict
    assert "at trial 7 (the best within 1 pt) the map is smaller than tesamap's" in verdict
    assert ("depends on the labels at trial 7 (the best within 1 pt) whether it loses no more "
            "than 1 pt of scene mIoU (yes with oracle fitted (the study's), feagnet-v1 "
            "(best.pt); no with oracle noise-free)") in verdict
    assert "The map sizes are the same under every labelling" in text
    moved = [*records[:3], {**records[3], "map_size": 1e6, "size_ratio": 2.4}, *records[4:]]
    said = "\n".join(sensitivity_section(moved, small_space))
    assert "move with the labels at trial 7 (the best within 1 pt) (its size ratio by 100 %)" \
        in said
    assert sensitivity_section([], small_space) == []


def _fails(capsys, argv: list[str], expected: str) -> None:
    from evsmap.cli.main import main

    assert main(["explore", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and expected in err, err


def test_bad_sensitivity_options_are_one_line(tmp_path: Path, capsys) -> None:
    out = ["--out", str(tmp_path / "s")]
    _fails(capsys, [*out, "--no-sensitivity", "--sensitivity-weights", "x.pt"],
           "--sensitivity-weights: not with --no-sensitivity")
    _fails(capsys, [*out, "--sensitivity-segmenter", "feagnet-v1"],
           "--sensitivity-segmenter: only with --sensitivity-weights FILE")
    _fails(capsys, [*out, "--sensitivity-weights", str(tmp_path / "none.pt")], "no such file")
    bare = tmp_path / "bare.pt"
    import torch

    torch.save({"head.weight": torch.zeros(2, 2)}, bare)
    _fails(capsys, [*out, "--sensitivity-weights", str(bare)],
           "no card names its model; give --sensitivity-segmenter NAME")
    _fails(capsys, [*out, "--sensitivity-weights", str(bare), "--sensitivity-segmenter",
                    "oracle"], "--sensitivity-segmenter oracle: not a network")
    _fails(capsys, [*out, "--sensitivity-weights", str(bare), "--sensitivity-segmenter",
                    "nosuch"], "--sensitivity-segmenter nosuch: not a registered segmenter")
    assert not (tmp_path / "s").exists()
