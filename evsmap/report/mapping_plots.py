"""The mapping figures: each system's rates and map size per sequence, and each map's growth
over the frames."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from evsmap.report.figure_base import MAP_ROWS, new_figure, save_figure
from evsmap.runner.records import CellRecord
from evsmap.tables.schema import PaperTable, mapping_table_id

# ------------------------------------------------------------------------------- mapping
MAPPING_QUANTITIES = ("update_hz", "segment_update_hz", "map_bytes")
"""The quantities :func:`mapping_plot` draws, one panel each (docs/measurement.md)."""


def mapping_entries(records: Iterable[CellRecord],
                    tables: Mapping[str, PaperTable] | None = None) -> list[dict[str, Any]]:
    """Measured mapping statistics per (sequence, voxel size, system): ``update_hz``,
    ``segment_update_hz``, ``map_bytes`` from the ``extra`` records, then from Table IV's records
    (map sizes on their column's sequence; a rate, and ``details``, only where the record says
    which sequence it measured in ``inputs["sequence"]``). The extra records win where both hold
    a value."""
    entries: dict[tuple[str, float | None, str], dict[str, Any]] = {}
    records = list(records)
    # the mapping runs only: the proxy maps (``extra/proxy-mapping/``, a trained network on a
    # synthrooms room) have their own table in table4.md and would read as a second system here
    extras = [r for r in records if r.status == "ok" and r.key.startswith("extra/mapping/")]
    table4 = [r for r in records if r.status == "ok" and r.table == mapping_table_id()
              and not r.key.startswith("extra/")]
    columns = {c.id: c for t in (tables or {}).values() if t.role == "mapping" for c in t.columns}

    def add(seq: Any, voxel: Any, rec: CellRecord, got: Mapping[str, Any]) -> None:
        if not seq:
            return
        voxel = float(voxel) if isinstance(voxel, (int, float)) else None
        entry = entries.setdefault((str(seq), voxel, rec.row), {
            "sequence": str(seq), "resolution": voxel, "row": rec.row,
            "label": rec.label or rec.row})
        for k, v in got.items():
            if (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                    and entry.get(k) is None):
                entry[k] = float(v)

    for rec in extras:
        add(rec.inputs.get("sequence"), rec.inputs.get("resolution"), rec,
            {k: rec.values.get(k) for k in MAPPING_QUANTITIES})
    for rec in table4:
        seq = rec.inputs.get("sequence")  # the sequence actually measured, when recorded
        for cid, v in rec.values.items():
            col = columns.get(cid)
            if col is None:
                continue
            voxel = rec.inputs.get("resolution", col.resolution)
            if col.quantity == "map_size" and (seq or col.datasets):
                add(seq or col.datasets[0], voxel, rec, {"map_bytes": v})
            elif col.quantity == "runtime_hz" and seq:
                add(seq, voxel, rec, {"segment_update_hz": v})
        if seq:
            add(seq, rec.inputs.get("resolution"), rec,
                {k: rec.details.get(k) for k in MAPPING_QUANTITIES})
    # systems that could not map a sequence here (a network without trained weights on a
    # sequence without labels): an entry without values, so the plot says n/a
    for rec in records:
        if rec.status == "na" and rec.key.startswith("extra/mapping/"):
            seq, voxel = rec.inputs.get("sequence"), rec.inputs.get("resolution")
            voxel = float(voxel) if isinstance(voxel, (int, float)) else None
            if seq:
                entries.setdefault((str(seq), voxel, rec.row), {
                    "sequence": str(seq), "resolution": voxel, "row": rec.row,
                    "label": rec.label or rec.row, "na": rec.reason})
    return [e for e in entries.values()
            if e.get("na") or any(e.get(k) is not None
                                  for k in MAPPING_QUANTITIES)]


def mapping_plot(records: Iterable[CellRecord], path: Path,
                 tables: Mapping[str, PaperTable] | None = None) -> bool:
    """Grouped bars, one panel per quantity (map update rate, segmentation + update rate in Hz,
    map size in MB), stacked: sequences are the groups, systems the bars, each bar labelled with
    its value; a system mapped on a sequence without that quantity reads "n/a", never a
    zero-height bar. ``False`` without any measured mapping record."""
    entries = mapping_entries(records, tables)
    if not entries:
        return False
    voxels = {e["resolution"] for e in entries}

    def group_name(e: dict[str, Any]) -> str:
        if len(voxels) > 1 and e["resolution"] is not None:
            return f"{e['sequence']} ({e['resolution'] * 100:g} cm)"
        return e["sequence"]

    groups = list(dict.fromkeys(group_name(e) for e in sorted(
        entries, key=lambda e: (e["sequence"], e["resolution"] or 0.0))))
    order = {r: i for i, r in enumerate(MAP_ROWS)}
    systems = sorted({(e["row"], e["label"]) for e in entries},
                     key=lambda s: (order.get(s[0], len(order)), s[0]))
    panels = (("update_hz", "Map update rate (Hz, median over frames)", 1.0, "{:.3g}"),
              ("segment_update_hz", "Segmentation + update rate (Hz)", 1.0, "{:.3g}"),
              ("map_bytes", "Map size (MB, the file each system writes)", 1e6, "{:.3g}"))
    fig = new_figure(max(9.0, 2.0 + 0.34 * len(groups) * len(systems)), 3.0 * len(panels) + 0.9)
    axes = fig.subplots(len(panels), 1)
    width = 0.84 / max(1, len(systems))
    x = np.arange(len(groups))
    by_key = {(group_name(e), e["row"]): e for e in entries}
    for ax, (key, title, div, fmt) in zip(axes, panels, strict=True):
        cells = [[None if (g, row) not in by_key else (by_key[g, row].get(key),)
                  for g in groups] for row, _ in systems]
        _draw_panel(ax, cells, [label for _, label in systems], div, fmt, x, width)
        ax.set_xticks(x, groups, fontsize=8)
        ax.set_xlim(-0.5, len(groups) - 0.5)
        ax.set_title(title, fontsize=9, loc="left")
    from matplotlib.patches import Patch

    handles = [Patch(color=f"C{i}", label=label) for i, (_, label) in enumerate(systems)]
    ncol = min(4, len(handles))
    fig.legend(handles=handles, loc="upper center", ncol=ncol, fontsize=8)
    rows = math.ceil(len(handles) / ncol)
    bottom = 0.0
    if any(e.get("na") for e in entries) or any(
            e.get(k) is None for e in entries for k, *_ in panels):
        fig.text(0.01, 0.005, "n/a: not measured for that system on that sequence here (a "
                 "network without trained weights cannot label a sequence without ground "
                 "truth; table4.md says why for each)", fontsize=7, color="0.35", va="bottom")
        bottom = 0.25 / fig.get_figheight()
    fig.tight_layout(rect=(0, bottom, 1, 1 - (0.12 + 0.22 * rows) / fig.get_figheight()))
    save_figure(fig, path)
    return True


def _draw_panel(ax: Any, cells: list[list[tuple[Any] | None]], labels: list[str], div: float,
                fmt: str, x: np.ndarray, width: float) -> None:
    """One panel of :func:`mapping_plot`: per system (``labels``) a bar per group, ``cells``
    holding each system's ``(value,)`` per group (``None``: no entry; a ``None`` value: "n/a"),
    then the y axis scaled to the bars (log where they span over 50x)."""
    drawn = []
    for i, (row_cells, label) in enumerate(zip(cells, labels, strict=True)):
        xs = x - 0.42 + width * (i + 0.5)
        heights, missing = [], []
        for xi, cell in zip(xs, row_cells, strict=True):
            v = None if cell is None else cell[0]
            heights.append(np.nan if v is None else v / div)
            if cell is not None and v is None:
                missing.append(xi)
        bars = ax.bar(xs, heights, width, label=label, color=f"C{i}")
        ax.bar_label(bars, [("" if np.isnan(h) else fmt.format(h)) for h in heights],
                     fontsize=6.5, rotation=90, padding=2)
        drawn += [h for h in heights if not np.isnan(h)]
        for xi in missing:
            ax.annotate("n/a", (xi, 0.0), xycoords=ax.get_xaxis_transform(), xytext=(0, 3),
                        textcoords="offset points",
                        ha="center", va="bottom", rotation=90, fontsize=6.5, color="0.45")
    ax.tick_params(axis="y", labelsize=7)
    ax.grid(True, axis="y", alpha=0.3)
    if drawn:
        positive = [h for h in drawn if h > 0]
        if positive and max(positive) / min(positive) > 50:
            from matplotlib.ticker import FuncFormatter

            ax.set_yscale("log")
            ax.set_ylim(min(positive) / 3, max(positive) * 12)
            ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        else:
            ax.set_ylim(0, max(drawn) * 1.3 or 1.0)
    else:
        ax.text(0.5, 0.5, "not measured", ha="center", va="center", transform=ax.transAxes)


# ------------------------------------------------------------------------------- growth
GROWTH_READINGS = (("nodes", "nodes", 1.0), ("memory_bytes", "C++ memory (MB, model)", 1e6),
                   ("colour_bytes", "colour-only file (MB)", 1e6))


def growth_plot(records: Iterable[CellRecord], path: Path) -> bool:
    """The map's growth with the frames integrated: one column per (sequence, voxel size), one
    row per reading (:data:`GROWTH_READINGS`), a line per system, from the mapping runs'
    ``details["growth"]`` snapshots. ``False`` without any."""
    series: dict[tuple[str, float], dict[str, tuple[str, list[dict[str, Any]]]]] = {}
    for rec in records:
        growth = (rec.details or {}).get("growth") if rec.status == "ok" else None
        if rec.key.startswith("extra/mapping/") and growth:
            where = (str(rec.inputs.get("sequence")), float(rec.inputs.get("resolution") or 0))
            series.setdefault(where, {})[rec.row] = (rec.label or rec.row, growth)
    if not series:
        return False
    places = sorted(series)
    order = {r: i for i, r in enumerate(MAP_ROWS)}
    fig = new_figure(max(6.0, 4.2 * len(places)), 2.6 * len(GROWTH_READINGS) + 0.8,
                  layout="constrained")
    axes = np.asarray(fig.subplots(len(GROWTH_READINGS), len(places), squeeze=False))
    for col, (seq, voxel) in enumerate(places):
        systems = sorted(series[(seq, voxel)].items(),
                         key=lambda kv: (order.get(kv[0], len(order)), kv[0]))
        for row, (key, title, div) in enumerate(GROWTH_READINGS):
            ax = axes[row, col]
            for i, (sys_row, (label, points)) in enumerate(systems):
                pts = [(p["frames"], p[key] / div) for p in points if p.get(key) is not None]
                if pts:
                    xs, ys = zip(*pts, strict=True)
                    style = "--" if sys_row.endswith("-direct") else "-"
                    ax.plot(xs, ys, style, marker="o", markersize=2.5, linewidth=1.2,
                            color=f"C{i % 10}", label=label)
            ax.set_title(f"{seq}, {voxel * 100:g} cm: {title}", fontsize=8)
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
            if row == len(GROWTH_READINGS) - 1:
                ax.set_xlabel("frames integrated", fontsize=8)
        axes[0, col].legend(fontsize=6, loc="best")
    save_figure(fig, path)
    return True
