"""The semantic-detail section of Table IV's report (:mod:`evsmap.runner.detail`): per sequence,
Table IV's map updates fed by one network, with each map's 3D scores beside its size and rate,
the claim "EVSMap keeps TESAMap's semantic detail" checked on ScanNet, and how the synthetic
room's semantic figures move with the labels (the run's own, the oracle's other profiles, a
trained proxy network's)."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from evsmap.runner.detail import (
    DETAIL_ROWS,
    SEMANTIC_DETAIL_TOLERANCE,
    SENSITIVITY_SEQUENCE,
    detail_row,
    is_detail,
    is_sensitivity,
    sensitivity_system,
)
from evsmap.runner.records import CellRecord
from evsmap.runner.scannet import is_scannet_sequence

CLAIM = "EVSMap keeps TESAMap's semantic detail"
SENSITIVITY_TITLE = "How the semantic figures move with the labels"
OLDER_ORACLE = "per-pixel"
"""The oracle's model before it had profiles (2026-11-29): a record from then that names no
profile used it."""


def _records(extras: Iterable[CellRecord]) -> list[CellRecord]:
    """The section's own rows (not the label-source runs)."""
    return [r for r in extras if is_detail(r.row) and not is_sensitivity(r.row)]


def labels_of(r: CellRecord) -> dict[str, Any] | None:
    """The label source of a semantic mapping record: its ``details["labels"]`` (written since
    the sources were compared), else its run's ``inputs["labels"]``; for an older record that
    names only ``labels_from``, the oracle's profile from its note (``profile NAME;``), else the
    model the oracle had then (:data:`OLDER_ORACLE`), or the network it names. None for a
    record without labels (geometry only, not measured)."""
    stored = r.details.get("labels") if r.status == "ok" else None
    if isinstance(stored, Mapping):
        return dict(stored)
    if isinstance(r.inputs.get("labels"), Mapping):
        return dict(r.inputs["labels"])
    source = r.details.get("labels_from") if r.status == "ok" else None
    if not source:
        return None
    if source == "oracle":
        return {"kind": "oracle", "profile": _noted_profile(r) or OLDER_ORACLE}
    return {"kind": "network", "model": str(source)}


def _noted_profile(r: CellRecord) -> str | None:
    """The profile an oracle note of 2026-11-29 names (``(profile fitted; ...``)."""
    for note in r.notes:
        text = str(note)
        if "oracle segmenter (profile " in text:
            return text.split("oracle segmenter (profile ", 1)[1].split(";", 1)[0].strip()
    return None


def labels_text(labels: Mapping[str, Any] | None) -> str:
    """A label source in words: ``oracle, profile fitted`` or ``feagnet-v1, weights FILE
    (synthrooms)``."""
    if labels is None:
        return "-"
    if labels.get("kind") == "oracle":
        return f"oracle, profile {labels.get('profile') or OLDER_ORACLE}"
    if labels.get("kind") == "network":
        text = str(labels.get("model"))
        if labels.get("weights"):
            text += f", weights {labels['weights']}"
        return text + (f" ({labels['dataset']})" if labels.get("dataset") else "")
    return str(labels.get("model") or labels.get("kind"))


def _source_key(labels: Mapping[str, Any]) -> tuple[str, str]:
    """What identifies a label source across records: the oracle's profile, or the network."""
    if labels.get("kind") == "oracle":
        return ("oracle", str(labels.get("profile") or OLDER_ORACLE))
    return (str(labels.get("kind")), str(labels.get("model")))


def _by_sequence(records: list[CellRecord]) -> dict[str, dict[str, CellRecord]]:
    """Per sequence, its records by row, in :data:`DETAIL_ROWS` order (others after)."""
    order = {detail_row(row): i for i, row in enumerate(DETAIL_ROWS)}
    out: dict[str, dict[str, CellRecord]] = {}
    for r in sorted(records, key=lambda r: (order.get(r.row, len(order)), r.row)):
        out.setdefault(str(r.inputs.get("sequence")), {})[r.row] = r
    return out


def _value(r: CellRecord, name: str) -> float | None:
    v = r.values.get(name) if r.status == "ok" else None
    return None if v is None or (isinstance(v, float) and math.isnan(v)) else float(v)


def _pct(v: float | None) -> str:
    return "-" if v is None else f"{100 * v:.1f} %"


def _num(v: float | None, fmt: str) -> str:
    return "-" if v is None else format(v, fmt)


def _labels_from(r: CellRecord) -> str:
    if r.status != "ok":
        return "-"
    if r.inputs.get("segmenter") is None:
        return "none (geometry)"
    return labels_text(labels_of(r)).replace("|", "\\|")


def detail_markdown(extras: Iterable[CellRecord]) -> list[str]:
    """The section (empty when the run has no semantic-detail records)."""
    extras = list(extras)
    records = _records(extras)
    if not records:
        return []
    from evsmap.runner.table4_reading import READINGS, TABLE4_READING

    reading = READINGS[TABLE4_READING]
    out = ["## Semantic detail in 3D: Table IV's updates, one network (beyond the paper)", "",
           "The paper says EVSMap keeps the semantic detail of the map while shrinking it, and "
           "shows it in pictures (Fig. 7). Here each update maps the same frames with the same "
           "labels, so the maps differ by the update alone, and each map is scored against the "
           "scene's ground-truth voxels: the synthetic room's, and a ScanNet scene's labelled "
           "mesh voxelised at the map's resolution (the class with most surface area in each "
           "voxel; unannotated surface counts for geometry only). 3D accuracy: the occupied "
           "leaves matched to a ground-truth voxel whose class is right; map mIoU over those "
           "leaves; scene mIoU over every observed ground-truth voxel (one the map dropped is a "
           "miss): docs/measurement.md. Map size: " + TABLE4_READING + ", Table IV's reading. "
           "Rate: the update's median, and segmentation + update (Table IV's runtime).", ""]
    for seq, rows in sorted(_by_sequence(records).items(), key=lambda kv: (
            is_scannet_sequence(kv[0]), kv[0])):
        first = next(iter(rows.values()))
        voxel = first.inputs.get("resolution")
        if all(r.status != "ok" for r in rows.values()):
            out += [f"### {seq}", "", f"Not measured: {first.reason or first.status}", ""]
            continue
        out += [f"### {seq} at {float(voxel) * 100:g} cm" if voxel else f"### {seq}", "",
                "| System | labels from | 3D accuracy | map mIoU | scene mIoU | recall | nodes "
                "| map size (MB) | update (Hz) | seg + update (Hz) |",
                "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for r in rows.values():
            if r.status != "ok":
                out.append(f"| {r.label} | {r.status}: {r.reason or ''} |" + " - |" * 8)
                continue
            size = _value(r, reading)
            out.append(
                f"| {r.label} | {_labels_from(r)} | {_pct(_value(r, 'semantic_accuracy'))} | "
                f"{_pct(_value(r, 'map_miou'))} | {_pct(_value(r, 'scene_miou'))} | "
                f"{_pct(_value(r, 'recall'))} | {_num(_value(r, 'nodes'), ',.0f')} | "
                f"{_num(None if size is None else size / 1e6, '.2f')} | "
                f"{_num(_value(r, 'update_hz'), '.2f')} | "
                f"{_num(_value(r, 'segment_update_hz'), '.2f')} |")
        diff = difference(rows)
        if diff is not None:
            out.append("")
            out.append(f"EVSMap's scene mIoU minus TESAMap's: {100 * diff:+.1f} points "
                       f"(the claim allows -{100 * SEMANTIC_DETAIL_TOLERANCE:g}).")
        out.append("")
        if seq == SENSITIVITY_SEQUENCE:
            out += sensitivity_markdown(extras)
    return out


@dataclass
class SourceResult:
    """TESAMap's and EVSMap's maps of the synthetic room with one label source."""

    labels: dict[str, Any]
    own: bool
    """The run's own labels (the section's rows), not a label-source run."""
    rows: dict[str, CellRecord] = field(default_factory=dict)
    """``detail-tesamap`` / ``detail-evsmap`` -> record."""
    missing: CellRecord | None = None
    """The source's n/a record (a network without weights)."""

    @property
    def difference(self) -> float | None:
        return difference(self.rows)

    @property
    def holds(self) -> bool | None:
        diff = self.difference
        return None if diff is None else diff >= -SEMANTIC_DETAIL_TOLERANCE

    def describe(self) -> str:
        return labels_text(self.labels) + (" (this run's labels)" if self.own else "")


def _source_order(result: SourceResult) -> tuple[int, int, str]:
    from evsmap.runner.mapping_plan import PROXY_LABEL_MODELS
    from evsmap.segmenters.oracle_profile import PROFILE_NAMES

    kind, name = _source_key(result.labels)
    if kind == "oracle":
        return (0 if result.own else 1, PROFILE_NAMES.index(name)
                if name in PROFILE_NAMES else len(PROFILE_NAMES), name)
    return (0 if result.own else 2, PROXY_LABEL_MODELS.index(name)
            if name in PROXY_LABEL_MODELS else len(PROXY_LABEL_MODELS), name)


def sensitivity(extras: Iterable[CellRecord]) -> list[SourceResult]:
    """The synthetic room's label sources (:mod:`evsmap.runner.detail`), the run's own first:
    each with its TESAMap and EVSMap records, or its n/a record."""
    records = [r for r in extras if is_detail(r.row)
               and r.inputs.get("sequence") == SENSITIVITY_SEQUENCE]
    results: dict[tuple[str, str], SourceResult] = {}
    own_rows = {r.row: r for r in records if r.row in (detail_row("tesamap"),
                                                        detail_row("evsmap"))}
    own_labels = next((labels_of(r) for r in own_rows.values() if labels_of(r)), None)
    if own_labels is not None:
        results[_source_key(own_labels)] = SourceResult(own_labels, True, own_rows)
    for r in records:
        labels = labels_of(r) if is_sensitivity(r.row) else None
        if labels is None:
            continue
        result = results.setdefault(_source_key(labels), SourceResult(labels, False))
        if result.own:
            continue  # the run's own rows already show this source
        system = sensitivity_system(r.row)
        if system is None:
            result.missing = r
        else:
            result.rows[detail_row(system)] = r
            if r.status == "ok":
                result.labels = labels  # with the weights file the run used
    return sorted(results.values(), key=_source_order)


def _cells(rec: CellRecord | None) -> list[str]:
    if rec is None:
        return ["-", "-"]
    if rec.status != "ok":
        return [rec.status, "-"]
    return [_pct(_value(rec, "semantic_accuracy")), _pct(_value(rec, "scene_miou"))]


def sensitivity_markdown(extras: Iterable[CellRecord]) -> list[str]:
    """The synthetic room's "How the semantic figures move with the labels" table and whether
    the claim's conclusion depends on the labels (empty without label-source runs)."""
    results = sensitivity(extras)
    if not any(not r.own for r in results):
        return []
    tolerance = 100 * SEMANTIC_DETAIL_TOLERANCE
    out = [f"#### {SENSITIVITY_TITLE} ({SENSITIVITY_SEQUENCE} room)", "",
           "TESAMap and EVSMap map the same frames at the same voxel size again with each "
           "label source: the oracle under each of its profiles (per-pixel: every pixel's error "
           "independent; fitted: errors fitted to a trained network's; noise-free: exact labels) "
           "and a trained proxy network's own labels (docs/oracle.md). The claim's criterion: "
           f"EVSMap's scene mIoU at most {tolerance:g} point below TESAMap's.", "",
           "| Labels | TESAMap 3D accuracy | TESAMap scene mIoU | EVSMap 3D accuracy | "
           "EVSMap scene mIoU | EVSMap - TESAMap (points) | criterion |",
           "|---|---:|---:|---:|---:|---:|---|"]
    for result in results:
        name = result.describe().replace("|", "\\|")
        if not result.rows and result.missing is not None:
            why = str(result.missing.reason or result.missing.status).replace("|", "\\|")
            out.append(f"| {name} | n/a: {why} |" + " - |" * 5)
            continue
        diff, holds = result.difference, result.holds
        cells = (_cells(result.rows.get(detail_row("tesamap")))
                 + _cells(result.rows.get(detail_row("evsmap"))))
        out.append(f"| {name} | " + " | ".join(cells) + " | "
                   + ("-" if diff is None else f"{100 * diff:+.1f}") + " | "
                   + ("-" if holds is None else "holds" if holds else "does not hold") + " |")
    out += ["", depends_sentence(results), ""]
    return out


def depends_sentence(results: list[SourceResult]) -> str:
    """Whether the conclusion depends on the labels: it does where the criterion holds with
    some sources and not with others."""
    measured = [r for r in results if r.holds is not None]
    if len(measured) < 2:
        return ("Fewer than two label sources were measured here: whether the conclusion "
                "depends on the labels cannot be said.")
    holding = [r.describe() for r in measured if r.holds]
    failing = [r.describe() for r in measured if not r.holds]
    if holding and failing:
        return (f"The conclusion depends on the labels: the criterion holds with "
                f"{'; '.join(holding)} and does not with {'; '.join(failing)}.")
    return (f"The conclusion does not depend on the labels here: the criterion "
            f"{'holds' if holding else 'does not hold'} with each of the {len(measured)} "
            f"label sources measured.")


def spread_text(extras: Iterable[CellRecord]) -> str | None:
    """The synthetic room's difference with the run's own labels and its range over the label
    sources, for the claims table (None without a measured difference)."""
    results = [r for r in sensitivity(extras) if r.difference is not None]
    own = next((r for r in results if r.own), None)
    if not results:
        return None
    text = "on the synthetic room " + (
        f"{100 * own.difference:+.1f} points with this run's labels "
        f"({labels_text(own.labels)})" if own is not None and own.difference is not None
        else "not measured with this run's labels")
    if len(results) > 1:
        diffs = [100 * r.difference for r in results if r.difference is not None]
        holding = sum(bool(r.holds) for r in results)
        text += (f", from {min(diffs):+.1f} to {max(diffs):+.1f} over {len(results)} label "
                 f"sources (the criterion holds with {holding} of {len(results)})")
    return text


def difference(rows: dict[str, CellRecord]) -> float | None:
    """EVSMap's 3D scene mIoU minus TESAMap's on one sequence, or None where either is
    missing."""
    a, b = rows.get(detail_row("evsmap")), rows.get(detail_row("tesamap"))
    if a is None or b is None:
        return None
    va, vb = _value(a, "scene_miou"), _value(b, "scene_miou")
    return None if va is None or vb is None else va - vb


def verdict_rows(extras: Iterable[CellRecord]) -> list[str]:
    """The claim-table row(s): the claim on each ScanNet scene, or "cannot be checked here"
    without ScanNet (the synthetic room's difference given beside it, with its range over the
    label sources: :func:`spread_text`)."""
    extras = list(extras)
    by_seq = _by_sequence(_records(extras))
    if not by_seq:
        return []
    tolerance = f"within {100 * SEMANTIC_DETAIL_TOLERANCE:g} point"
    out = []
    spread = spread_text(extras)
    aside = "" if spread is None else "; " + spread.replace("|", "\\|")
    scenes = {s: rows for s, rows in by_seq.items() if is_scannet_sequence(s)}
    checked = False
    for seq, rows in sorted(scenes.items()):
        diff = difference(rows)
        if diff is None:
            continue
        checked = True
        holds = diff >= -SEMANTIC_DETAIL_TOLERANCE
        out.append(f"| {CLAIM} (3D scene mIoU {tolerance}, same network), {seq} | "
                   f"{100 * diff:+.1f} pt | exact | - | "
                   f"{'holds' if holds else 'does not hold'} |")
    if not checked:
        why = _why_not(scenes)
        out.append(f"| {CLAIM} (3D scene mIoU {tolerance}, same network), ScanNet | - | - | - | "
                   f"cannot be checked here ({why}{aside}) |")
    return out


def _why_not(scenes: dict[str, dict[str, CellRecord]]) -> str:
    for rows in scenes.values():
        for r in rows.values():
            if r.status != "ok":
                return str(r.reason or r.status).removeprefix("n/a - ").replace("|", "\\|")
    return "needs the ScanNet dataset under the data root as scannet/"


__all__ = ["CLAIM", "SENSITIVITY_TITLE", "SourceResult", "depends_sentence", "detail_markdown",
           "difference", "labels_of", "labels_text", "sensitivity", "sensitivity_markdown",
           "spread_text", "verdict_rows"]
