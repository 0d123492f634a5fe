"""A study's trials as plain records, its Pareto fronts and the answer it gives: where the
explored map is smaller than the baseline's at no more than :data:`MIOU_LOSS_POINTS` of 3D mIoU
lost, the best size ratio found there and its parameters, and whether the paper's "up to 2.6
times" (:data:`PAPER_SIZE_RATIO`) is reached. Only the report layer formats them."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import optuna

PAPER_SIZE_RATIO = 2.6
"""EVSMaP's abstract: "reducing memory size of the map by up to 2.6 times"."""
MIOU_LOSS_POINTS = 1.0
"""The 3D mIoU (over the observed scene) a smaller map may lose against the baseline's and
still count, in points."""

RECORD_FIELDS = ("map_size", "map_bytes", "map_bytes_colour", "octomap_memory_bytes",
                 "scene_miou", "map_miou", "semantic_accuracy", "precision", "recall", "update_hz",
                 "rate_ratio", "size_ratio", "miou_loss", "pruned_share", "leaves", "nodes",
                 "wall_s")
"""A trial record's fields that go into a row as they are (docs/explore.md, "Trials")."""


def trial_rows(study: optuna.Study) -> list[dict[str, Any]]:
    """Every trial of ``study`` as a flat row: number, slot, state, role, the parameters
    (``param:<name>``), the record's fields, the reference's and the baseline's."""
    rows = []
    for t in study.get_trials(deepcopy=False):
        record = t.user_attrs.get("record") or {}
        row: dict[str, Any] = {"number": t.number, "slot": t.user_attrs.get("slot"),
                               "state": t.state.name, "role": t.user_attrs.get("role", ""),
                               "error": t.user_attrs.get("error", "")}
        row.update({f"param:{k}": v for k, v in sorted(t.params.items())})
        row.update({k: record.get(k) for k in RECORD_FIELDS})
        reference = record.get("reference") or {}
        row["reference_update_hz"] = reference.get("update_hz")
        baseline = record.get("baseline") or {}
        for k in ("map_size", "scene_miou", "map_miou", "semantic_accuracy", "rate_ratio",
                  "update_hz"):
            row[f"baseline_{k}"] = baseline.get(k)
        worker = t.user_attrs.get("worker") or {}
        row["host"], row["pid"] = worker.get("host"), worker.get("pid")
        row["started"] = t.datetime_start.isoformat() if t.datetime_start else None
        row["finished"] = t.datetime_complete.isoformat() if t.datetime_complete else None
        rows.append(row)
    return rows


def complete(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [r for r in rows if r["state"] == "COMPLETE"]


def _finite(value: Any) -> bool:
    return isinstance(value, (int, float)) and math.isfinite(value)


def pareto_front(rows: list[dict[str, Any]], x: str, y: str, *, x_lower: bool,
                 y_lower: bool) -> list[dict[str, Any]]:
    """The rows no other row beats on both ``x`` and ``y`` (``*_lower``: lower is better),
    sorted by ``x``; rows lacking either value are left out."""
    points = [r for r in rows if _finite(r.get(x)) and _finite(r.get(y))]

    def better(a: float, b: float, lower: bool) -> bool:
        return a < b if lower else a > b

    def dominated(r: dict[str, Any]) -> bool:
        for o in points:
            no_worse = (not better(r[x], o[x], x_lower)) and (not better(r[y], o[y], y_lower))
            strictly = better(o[x], r[x], x_lower) or better(o[y], r[y], y_lower)
            if no_worse and strictly:
                return True
        return False

    return sorted((r for r in points if not dominated(r)), key=lambda r: r[x])


FRONTS: dict[str, tuple[str, str, bool, bool]] = {
    "size": ("map_size", "scene_miou", True, False),
    "rate": ("rate_ratio", "scene_miou", False, False),
}
"""The fronts a study reports: (x, y, x lower is better, y lower is better)."""


@dataclass(frozen=True)
class Answer:
    """What a study says about the paper's map-size claim.

    Attributes:
        trials: complete trials.
        paired: trials with a baseline map beside them (a size ratio).
        within: the trials whose map is smaller than the baseline's (``size_ratio`` > 1) at
            no more than :data:`MIOU_LOSS_POINTS` of 3D mIoU lost.
        best: of ``within``, the one with the largest size ratio (``None``: none).
        best_any: the largest size ratio of any trial, whatever its mIoU.
        default: the paper's point (the first trial), if it finished.
        region: per parameter, the (min, max) over ``within``.
        reaches_paper: the best ratio within the mIoU bound reaches :data:`PAPER_SIZE_RATIO`.
    """

    trials: int
    paired: int
    within: list[dict[str, Any]] = field(default_factory=list)
    best: dict[str, Any] | None = None
    best_any: dict[str, Any] | None = None
    default: dict[str, Any] | None = None
    region: dict[str, tuple[Any, Any]] = field(default_factory=dict)
    reaches_paper: bool = False


def answer(rows: list[dict[str, Any]]) -> Answer:
    """:class:`Answer` over the complete trials of ``rows``."""
    done = complete(rows)
    paired = [r for r in done if _finite(r.get("size_ratio"))]
    within = [r for r in paired if r["size_ratio"] > 1.0 and _finite(r.get("miou_loss"))
              and r["miou_loss"] <= MIOU_LOSS_POINTS]
    best = max(within, key=lambda r: r["size_ratio"], default=None)
    best_any = max(paired, key=lambda r: r["size_ratio"], default=None)
    default = next((r for r in done if r.get("role")), None)
    region: dict[str, tuple[Any, Any]] = {}
    for key in sorted({k for r in within for k in r if k.startswith("param:")}):
        values = [r[key] for r in within if r.get(key) is not None]
        region[key.split(":", 1)[1]] = (min(values), max(values))
    return Answer(trials=len(done), paired=len(paired), within=within, best=best,
                  best_any=best_any, default=default, region=region,
                  reaches_paper=best is not None and best["size_ratio"] >= PAPER_SIZE_RATIO)
