"""The measurements beyond the paper's tables: the mapping runs on every sequence (``extra/...``
records), as a frame (:func:`extra_frame`, ``extra.csv``) and as Table IV's "Measured beyond the
paper" section (:func:`extra_markdown`), with the map-size claim per sequence and the sections of
``reproduce --train``'s proxy networks.

Every number shown as measured comes from a record's ``values``; nothing is derived or filled in.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import pandas as pd

from evsmap.report.cells import Footnotes, format_number, md_escape, number, record_note
from evsmap.runner.records import CellRecord

EXTRA_VALUES = ("update_hz", "segment_update_hz", "map_bytes", "map_bytes_full",
                "map_bytes_colour", "map_bytes_message", "octomap_memory_bytes", "map_nbytes",
                "rss_added_bytes",
                "peak_rss_bytes", "nodes", "leaves", "pruned_share", "precision", "recall",
                "semantic_accuracy", "semantic_accuracy_all", "map_miou", "frames", "miou")
"""Value keys of the ``extra`` records (docs/measurement.md, "Quantities";
``miou``: the synthrooms proxy networks')."""

PROXY_SECTION = "Synthetic proxy (evsmap's synthrooms, not the paper's datasets)"
"""Title of the ``reproduce --train`` sections (``extra/proxy...`` records)."""

EXTRA_COUNTS = frozenset({"map_bytes", "map_bytes_full", "map_bytes_colour", "map_bytes_message",
                          "octomap_memory_bytes", "map_nbytes",
                          "rss_added_bytes", "peak_rss_bytes", "nodes", "leaves", "frames"})
"""Value keys that are counts (bytes, nodes, frames): integers in :func:`extra_frame`."""

EXTRA_COLUMNS = ("key", "row", "label", "sequence", "resolution", "status", *EXTRA_VALUES,
                 "labels_from", "note")
"""Columns of :func:`extra_frame` (values in base units: Hz, bytes, fractions; ``labels_from``:
the labels a semantic map was made with, :func:`evsmap.report.detail.labels_text`)."""

# (value key, header, divisor to printed unit, decimals)
EXTRA_PRINT = (
    ("update_hz", "Update (Hz)", 1.0, 1),
    ("segment_update_hz", "Segmentation + update (Hz)", 1.0, 1),
    ("map_bytes", "Map size (MB)", 1e6, 2),
    ("map_bytes_full", "Full state (MB)", 1e6, 2),
    ("octomap_memory_bytes", "OctoMap memoryUsage() formula (MB)", 1e6, 2),
    ("map_nbytes", "Map arrays, measured (MB)", 1e6, 2),
    ("rss_added_bytes", "Peak RSS added by mapping, measured (MB)", 1e6, 1),
    ("nodes", "Nodes", 1.0, 0),
    ("leaves", "Leaves", 1.0, 0),
    ("pruned_share", "Pruned (%)", 0.01, 1),
    ("precision", "Occupancy precision (%)", 0.01, 1),
    ("recall", "Occupancy recall (%)", 0.01, 1),
    ("semantic_accuracy", "Semantic accuracy (%)", 0.01, 1),
    ("semantic_accuracy_all", "Semantic accuracy, no class = wrong (%)", 0.01, 1),
    ("map_miou", "Map mIoU (%)", 0.01, 1),
)


def extra_records(records: Iterable[CellRecord]) -> list[CellRecord]:
    """The ``extra/...`` records, ordered by sequence, voxel size, Table IV row order, key."""
    order = {r: i for i, r in enumerate(("orgbmap", "tesamap", "tfeagmap", "mesamap", "evsmap",
                                          "octomap-cpp"))}
    extras = [r for r in records if r.table == "extra" or r.key.startswith("extra/")]
    return sorted(extras, key=lambda r: (str(r.inputs.get("sequence", "")),
                                         number(r.inputs.get("resolution")) or 0.0,
                                         order.get(r.row, len(order)), r.key))


def extra_frame(records: Iterable[CellRecord]) -> pd.DataFrame:
    """The ``extra`` records, one line each, values in base units (:data:`EXTRA_COLUMNS`)."""
    lines = []
    for rec in extra_records(records):
        line: dict[str, Any] = {
            "key": rec.key, "row": rec.row, "label": rec.label,
            "sequence": str(rec.inputs.get("sequence", "")),
            "resolution": number(rec.inputs.get("resolution")),
            "status": {"na": "n/a"}.get(rec.status, rec.status),
            "labels_from": _labels_column(rec),
            "note": record_note(rec, sequence=False)}
        for key in EXTRA_VALUES:
            line[key] = number(rec.values.get(key)) if rec.status == "ok" else None
        lines.append(line)
    frame = pd.DataFrame(lines, columns=list(EXTRA_COLUMNS))
    for name in ("resolution", *EXTRA_VALUES):
        # counts stay integers in the CSV (nullable: a cell without a value stays empty)
        kind = "Int64" if name in EXTRA_COUNTS else "float64"
        frame[name] = pd.to_numeric(frame[name]).astype(kind)
    return frame


def _labels_column(rec: CellRecord) -> str | None:
    """The labels a semantic map record was made with, in words; None for the others."""
    from evsmap.report.detail import labels_of, labels_text

    labels = labels_of(rec) if rec.inputs.get("segmenter") else None
    return None if labels is None else labels_text(labels)


_SEMANTIC_VALUES = ("semantic_accuracy", "semantic_accuracy_all", "map_miou")
"""The extra table's semantic columns."""


def labels_lines(recs: Iterable[CellRecord]) -> list[str]:
    """Which labels the semantic columns of one extra table used: each source with its rows
    (none where no row has a semantic figure)."""
    sources: dict[str, list[str]] = {}
    for rec in recs:
        text = _labels_column(rec) if rec.status == "ok" else None
        if text is not None and any(number(rec.values.get(k)) is not None
                                    for k in _SEMANTIC_VALUES):
            sources.setdefault(text, []).append(rec.label or rec.row)
    if not sources:
        return []
    parts = [f"{md_escape(text)} ({', '.join(md_escape(r) for r in rows)})"
             for text, rows in sources.items()]
    return ["Labels of the semantic columns: " + "; ".join(parts) + ".", ""]


def extra_markdown(records: Iterable[CellRecord]) -> list[str]:
    """The "Measured beyond the paper" section: one table per sequence (and voxel size)."""
    extras = [r for r in extra_records(records) if not _is_proxy(r)]
    proxy = [r for r in extra_records(records) if r.key.startswith("extra/proxy-mapping/")]
    out = ["## Measured beyond the paper", ""]
    if not extras and not proxy:
        return out + ["No measurements beyond the paper in this run.", ""]
    if not extras:
        return out + proxy_mapping_markdown(proxy)
    out += ["Every mapping system on the sequences this run had, with the map update rate alone "
            "and with segmentation (segmentation + update), the size of the map file each system "
            "itself writes (Table IV's \"Map Size\"; classic-semantic: semantic_slam's "
            "ColorOcTree) and of evsmap's full resumable state, the memory the map would take "
            "by OctoMap's memoryUsage() formula in the original C++ node types (OctoMap 16 B "
            "a node, semantic_slam 48 B a Bayesian and 32 B a max node, EVSMap 32 B, plus 64 B "
            "per inner node's child array; a model, not a measurement), the bytes of the "
            "arrays evsmap holds it in and the peak resident memory mapping added to the "
            "process (both measured), its nodes, leaves and the share of the finest leaves "
            "pruned, and the map's quality against "
            "the ground truth (occupancy precision and recall, semantic accuracy and mIoU of "
            "the occupied voxels), so a smaller map is never bought unseen with a worse one.",
            ""]
    groups: dict[tuple[str, float | None], list[CellRecord]] = {}
    for rec in extras:
        key = (str(rec.inputs.get("sequence", "") or "unknown"),
               number(rec.inputs.get("resolution")))
        groups.setdefault(key, []).append(rec)
    for (seq, voxel), recs in groups.items():
        title = f"### Sequence `{seq}`"
        if voxel is not None:
            title += f", voxel size {voxel:g} m"
        out += [title, ""]
        notes = Footnotes()
        frames = {n for n in (number(r.values.get("frames")) for r in recs if r.status == "ok")
                  if n is not None}
        if len(frames) == 1:
            out += [f"{int(frames.pop())} frames.", ""]
        headers = ["System"] + [h for _, h, _, _ in EXTRA_PRINT]
        out.append("| " + " | ".join(headers) + " |")
        out.append("|---|" + "|".join("---:" for _ in EXTRA_PRINT) + "|")
        for rec in recs:
            note = record_note(rec, sequence=False)
            label = md_escape(rec.label or rec.row)
            if note:
                label += f" {notes.ref(note)}"
            cells = [label]
            for value_key, _, div, dec in EXTRA_PRINT:
                value = number(rec.values.get(value_key)) if rec.status == "ok" else None
                if rec.status == "na":
                    cells.append("n/a")
                elif rec.status == "error":
                    cells.append("error")
                elif value is None:
                    cells.append("-")
                else:
                    cells.append(format_number(value / div, dec))
            out.append("| " + " | ".join(cells) + " |")
        out.append("")
        out += labels_lines(recs)
        out += size_claim_lines(recs)
        if notes.texts:
            out += notes.markdown() + [""]
    return out + (proxy_mapping_markdown(proxy) if proxy else [])


SIZE_CLAIM = ("tfeagmap", "evsmap", 2.6)
"""Table IV's map-size claim as this report checks it: (compared row, EVSMap's row, the paper's
"up to" factor by which EVSMap's map is smaller)."""


def size_claim_lines(recs: Iterable[CellRecord]) -> list[str]:
    """One paragraph on the paper's map-size claim for one sequence: the ratio of the two
    saved files and what makes it (bytes a node, nodes), when both rows were measured."""
    by_row = {r.row: r for r in recs if r.status == "ok"}
    other, ours, factor = SIZE_CLAIM
    if other not in by_row or ours not in by_row:
        return []
    a, b = by_row[other].values, by_row[ours].values
    size_a, size_b = number(a.get("map_bytes")), number(b.get("map_bytes"))
    nodes_a, nodes_b = number(a.get("nodes")), number(b.get("nodes"))
    if not (size_a and size_b and nodes_a and nodes_b):
        return []
    ratio = size_a / size_b
    verdict = ("reproduces" if ratio >= factor else
               "does not reproduce" + (" (EVSMap's map is smaller, by less)" if ratio > 1 else
                                       ": EVSMap's map is the larger one"))
    label_a, label_b = by_row[other].label or other, by_row[ours].label or ours
    return [f"Map size, {label_a} / {label_b} (each the file the system itself saves): "
            f"{ratio:.2f}x. The paper reports EVSMap's map up to {factor:g}x smaller; here "
            f"that {verdict}. Bytes a node in the file: {size_a / nodes_a:.1f} against "
            f"{size_b / nodes_b:.1f}; nodes: {int(nodes_a):,} against {int(nodes_b):,} "
            f"({nodes_b / nodes_a:.2f}x).", ""]


def _is_proxy(record: CellRecord) -> bool:
    return record.key.startswith(("extra/proxy/", "extra/proxy-mapping/"))


def _pct_text(value: Any) -> str:
    value = number(value)
    return "-" if value is None else format_number(100 * value, 1)


def _status_text(rec: CellRecord) -> str | None:
    return {"na": "n/a", "error": "error"}.get(rec.status)


def proxy_accuracy_markdown(records: Iterable[CellRecord]) -> list[str]:
    """The "Synthetic proxy" section of Tables I and III: each network trained by
    ``reproduce --train`` on synthrooms (``extra/proxy/...`` records), never the paper's
    columns."""
    recs = [r for r in extra_records(records) if r.key.startswith("extra/proxy/")]
    if not recs:
        return []
    out = [f"## {PROXY_SECTION}", "",
           "Networks trained by `evsmap reproduce --train` on evsmap's synthetic rooms "
           "(`synthrooms`, NYUv2's 40 classes), NOT on the paper's datasets: these values are "
           "no measurement of the paper's columns above. Test mIoU: measured on the synthrooms "
           "test split as the accuracy cells measure; val mIoU, epochs and recipe: from the "
           "weights card.", "",
           "| Network | Test mIoU (%) | Val mIoU (%) | Epochs | Recipe | Weights card |",
           "|---|---:|---:|---:|---|---|"]
    for rec in recs:
        d = rec.details
        status = _status_text(rec)
        test = status or _pct_text(rec.values.get("miou"))
        card = (rec.notes[-1] if rec.status == "ok" and rec.notes else
                rec.reason or rec.error or "")
        out.append("| " + " | ".join(md_escape(str(x)) for x in (
            rec.row, test, _pct_text(d.get("val_miou")), d.get("epochs") or "-",
            d.get("recipe") or "-", card)) + " |")
    return out + [""]


_PROXY_SCORES = ("semantic_accuracy", "map_miou", "precision", "recall")


def proxy_mapping_markdown(records: Iterable[CellRecord]) -> list[str]:
    """Table IV's part of the "Synthetic proxy" section: TFEAGMap's and EVSMap's maps of one
    synthrooms test room with a trained network's labels, scored against the room's ground
    truth."""
    recs = list(records)
    out = [f"### {PROXY_SECTION}", "",
           "TFEAGMap's (classic-semantic) and EVSMap's (multiclass-bayes) updaters on one "
           "synthrooms test room with the labels of a network trained by `evsmap reproduce "
           "--train` (real network errors, not the oracle's), each map's occupied voxels scored "
           "against the room's ground truth.", ""]
    notes = Footnotes()
    headers = {k: h for k, h, _, _ in EXTRA_PRINT}  # the extra tables' words for each value
    out += ["| System | Sequence | Frames | " + " | ".join(headers[k] for k in (
        *_PROXY_SCORES, "update_hz")) + " |", "|---|---|---:|---:|---:|---:|---:|---:|"]
    for rec in recs:
        label = md_escape(rec.label or rec.row)
        note = record_note(rec, sequence=False)
        if note:
            label += f" {notes.ref(note)}"
        status = _status_text(rec)
        v = rec.values
        frames = number(v.get("frames"))
        hz = number(v.get("update_hz"))
        cells = [status or (str(int(frames)) if frames is not None else "-")] + [
            status or _pct_text(v.get(k))
            for k in _PROXY_SCORES] + [
            status or ("-" if hz is None else format_number(hz, 1))]
        out.append("| " + " | ".join([label, md_escape(str(rec.inputs.get("sequence", ""))),
                                      *cells]) + " |")
    out.append("")
    if notes.texts:
        out += notes.markdown() + [""]
    return out
