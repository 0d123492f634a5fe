"""The report's "How the semantic figures move with the labels" (evsmap/report/detail.py) from
hand-made records: per label source TESAMap's and EVSMap's scores, the difference and the
criterion, whether the conclusion depends on the labels, the claim row's spread, the labels of
the extra table's semantic columns, and records stored before the sources were compared."""

from __future__ import annotations

import pandas as pd

from evsmap.report.claims import claims_markdown
from evsmap.report.detail import (
    depends_sentence,
    detail_markdown,
    labels_of,
    sensitivity,
    verdict_rows,
)
from evsmap.report.tables import extra_frame, extra_markdown
from evsmap.runner.records import CellRecord

KEY = "extra/mapping/{row}/synthetic@0.02m"


def _rec(row: str, miou: float | None, *, labels: dict | None = None,
         inputs_labels: dict | None = None, labels_from: str | None = None,
         status: str = "ok", reason: str | None = None, notes=()) -> CellRecord:
    inputs = {"segmenter": "feagnet-v2", "updater": "x", "sequence": "synthetic",
              "resolution": 0.02}
    if inputs_labels is not None:
        inputs["labels"] = inputs_labels
    details = {}
    if labels is not None:
        details["labels"] = labels
    if labels_from is not None:
        details["labels_from"] = labels_from
    values = {} if miou is None else {"scene_miou": miou, "semantic_accuracy": miou + 0.1}
    return CellRecord(key=KEY.format(row=row), table="extra", row=row, label=row,
                      kind="mapping", metrics=[], status=status, values=values,
                      details=details, inputs=inputs, notes=list(notes), reason=reason)


FITTED = {"kind": "oracle", "profile": "fitted", "settings": "abc"}
PER_PIXEL = {"kind": "oracle", "profile": "per-pixel"}
NOISE_FREE = {"kind": "oracle", "profile": "noise-free"}
NETWORK = {"kind": "network", "model": "feagnet-v1", "dataset": "synthrooms"}


def _records(per_pixel_evsmap: float = 0.05) -> list[CellRecord]:
    return [
        _rec("detail-tesamap", 0.40, labels=FITTED, labels_from="oracle (profile fitted)"),
        _rec("detail-evsmap", 0.42, labels=FITTED, labels_from="oracle (profile fitted)"),
        _rec("detail-labels-per-pixel-tesamap", 0.17, labels=PER_PIXEL,
             inputs_labels=PER_PIXEL),
        _rec("detail-labels-per-pixel-evsmap", per_pixel_evsmap, labels=PER_PIXEL,
             inputs_labels=PER_PIXEL),
        _rec("detail-labels-noise-free-tesamap", 0.80, labels=NOISE_FREE,
             inputs_labels=NOISE_FREE),
        _rec("detail-labels-noise-free-evsmap", 0.85, labels=NOISE_FREE,
             inputs_labels=NOISE_FREE),
        _rec("detail-labels-network", None, inputs_labels=NETWORK, status="na",
             reason="n/a - needs trained weights (feagnet-v1@synthrooms): use --train"),
    ]


def _line(text: str, start: str) -> str:
    return next(x for x in text.splitlines() if x.startswith(start))


def test_the_table_per_label_source():
    text = "\n".join(detail_markdown(_records()))
    assert "#### How the semantic figures move with the labels (synthetic room)" in text
    assert _line(text, "| oracle, profile fitted (this run's labels) |") == (
        "| oracle, profile fitted (this run's labels) | 50.0 % | 40.0 % | 52.0 % | 42.0 % "
        "| +2.0 | holds |")
    assert _line(text, "| oracle, profile per-pixel |") == (
        "| oracle, profile per-pixel | 27.0 % | 17.0 % | 15.0 % | 5.0 % | -12.0 "
        "| does not hold |")
    assert _line(text, "| oracle, profile noise-free |").endswith("| +5.0 | holds |")
    assert "| feagnet-v1 (synthrooms) | n/a: n/a - needs trained weights " \
           "(feagnet-v1@synthrooms): use --train |" in text
    assert ("The conclusion depends on the labels: the criterion holds with oracle, profile "
            "fitted (this run's labels); oracle, profile noise-free and does not with oracle, "
            "profile per-pixel.") in text
    # the section's own table shows the run's rows only, naming their labels
    own = text.split("####", 1)[0]
    assert "detail-labels" not in own and "| oracle, profile fitted |" in own


def test_the_conclusion_does_not_depend_when_every_source_agrees():
    results = sensitivity(_records(per_pixel_evsmap=0.20))
    assert [r.holds for r in results] == [True, True, True, None]
    assert depends_sentence(results) == (
        "The conclusion does not depend on the labels here: the criterion holds with each of "
        "the 3 label sources measured.")


def test_the_claim_row_gives_the_spread():
    row = verdict_rows(_records())[0]
    assert "cannot be checked here" in row  # no ScanNet
    assert ("on the synthetic room +2.0 points with this run's labels (oracle, profile "
            "fitted), from -12.0 to +5.0 over 3 label sources (the criterion holds with 2 of "
            "3)") in row
    assert row in claims_markdown({}, [], _records())


def test_older_records_still_report():
    # before the label sources: labels_from "oracle" only, no details["labels"]; with a note
    # of the day the oracle had profiles, else its model then (per-pixel)
    old = _rec("detail-tesamap", 0.3, labels_from="oracle")
    noted = _rec("detail-evsmap", 0.3, labels_from="oracle", notes=[
        "labels from the oracle segmenter (profile fitted; seed=0: ground truth with seeded "
        "noise), no trained weights"])
    assert labels_of(old) == {"kind": "oracle", "profile": "per-pixel"}
    assert labels_of(noted) == {"kind": "oracle", "profile": "fitted"}
    text = "\n".join(detail_markdown([old, noted]))
    assert "| oracle, profile per-pixel |" in text and "####" not in text
    assert "on the synthetic room +0.0 points with this run's labels" in \
        verdict_rows([old, noted])[0]


def test_the_extra_table_names_the_labels_of_its_semantic_columns():
    recs = [_rec("tesamap", 0.4, labels=FITTED), _rec("evsmap", 0.5, labels=NETWORK | {
        "weights": "proxy/best.pt"}), _rec("orgbmap", None)]
    recs[2].inputs["segmenter"] = None
    text = "\n".join(extra_markdown(recs))
    assert ("Labels of the semantic columns: oracle, profile fitted (tesamap); feagnet-v1, "
            "weights proxy/best.pt (synthrooms) (evsmap).") in text
    frame = extra_frame(recs).set_index("row")
    assert frame.loc["tesamap", "labels_from"] == "oracle, profile fitted"
    assert pd.isna(frame.loc["orgbmap", "labels_from"])  # geometry only
