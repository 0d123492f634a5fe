"""The semantic-detail section of Table IV's report (:mod:`evsmap.runner.detail`): per sequence,
Table IV's map updates fed by one network, with each map's 3D scores beside its size and rate,
and the claim "EVSMap keeps TESAMap's semantic detail" checked on ScanNet."""

from __future__ import annotations

import math
from collections.abc import Iterable

from evsmap.runner.detail import DETAIL_ROWS, SEMANTIC_DETAIL_TOLERANCE, detail_row, is_detail
from evsmap.runner.records import CellRecord
from evsmap.runner.scannet import is_scannet_sequence

CLAIM = "EVSMap keeps TESAMap's semantic detail"


def _records(extras: Iterable[CellRecord]) -> list[CellRecord]:
    return [r for r in extras if is_detail(r.row)]


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
    source = r.details.get("labels_from")
    if source == "oracle":
        return "oracle (ground truth, seeded noise)"
    return str(source) if source else "-"


def detail_markdown(extras: Iterable[CellRecord]) -> list[str]:
    """The section (empty when the run has no semantic-detail records)."""
    records = _records(extras)
    if not records:
        return []
    from evsmap.runner.mapping_cells import READINGS, TABLE4_READING

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
        voxel = first.inputs.get("voxel_size")
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
    return out


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
    without ScanNet (the synthetic room's difference given beside it)."""
    by_seq = _by_sequence(_records(extras))
    if not by_seq:
        return []
    tolerance = f"within {100 * SEMANTIC_DETAIL_TOLERANCE:g} point"
    out = []
    synthetic = difference(by_seq.get("synthetic", {}))
    aside = ("" if synthetic is None else
             f"; on the synthetic room {100 * synthetic:+.1f} points")
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


__all__ = ["CLAIM", "detail_markdown", "difference", "verdict_rows"]
