"""The report's figures (matplotlib, drawn off-screen through the Agg canvas).

* :func:`networks_plot` - FPS against parameters and against FLOPs for the networks of Tables I
  and II whose speed and complexity were measured, the paper's values as hollow markers.
* :func:`mapping_plot` - map update rate, end-to-end rate and map size per sequence and system.
* :func:`qualitative_plot` - segmentation overlays beside the ground truth, and a top-down
  render of each system's semantic map.

Each returns ``False`` (and writes nothing) when it has no data to draw.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from evsmap.classes import NYU40_CLASSES, palette
from evsmap.errors import DataFormatError
from evsmap.runner.records import CellRecord
from evsmap.tables.schema import PaperTable

MAP_ROWS = ("orgbmap", "tesamap", "tfeagmap", "mesamap", "evsmap", "octomap-cpp")
"""Mapping systems in display order (Table IV rows, then the C++ OctoMap reference)."""

_DPI = 110


def _figure(width: float, height: float, layout: str | None = None):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=_DPI, layout=layout)
    FigureCanvasAgg(fig)
    return fig


def _save(fig, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png", dpi=_DPI)


# ------------------------------------------------------------------------------- networks
# (table, fps column, legend, marker)
_SPEED_SERIES = (
    ("table1", "fps", "Table I (640x480)", "o"),
    ("table2", "fps_1024", "Table II (1024x512)", "s"),
    ("table2", "fps_2048", "Table II (2048x1024)", "^"),
)


def _value(cells: Mapping[str, Mapping[str, Any]], col: str, which: str) -> float | None:
    line = cells.get(col)
    if line is None or pd.isna(line[which]):
        return None
    return float(line[which])


def network_points(frames: Mapping[str, pd.DataFrame]) -> list[dict[str, Any]]:
    """Rows of Tables I/II with a measured FPS: the measured and printed FPS, parameters (M) and
    FLOPs (G) for each speed column (``frames``: :func:`~evsmap.report.tables.table_frame` by
    table id)."""
    points = []
    for tid, fps_col, legend, marker in _SPEED_SERIES:
        frame = frames.get(tid)
        if frame is None or frame.empty:
            continue
        for row, group in frame.groupby("row", sort=False):
            cells = {r["column"]: r for r in group.to_dict("records")}
            fps = cells.get(fps_col)
            if fps is None or fps["status"] != "ok":
                continue

            points.append({
                "table": tid, "series": legend, "marker": marker, "row": row,
                "label": fps["label"],
                "fps": float(fps["measured"]), "params": _value(cells, "params", "measured"),
                "flops": _value(cells, "flops", "measured"),
                "paper_fps": _value(cells, fps_col, "paper"),
                "paper_params": _value(cells, "params", "paper"),
                "paper_flops": _value(cells, "flops", "paper")})
    return points


def networks_plot(frames: Mapping[str, pd.DataFrame], path: Path) -> bool:
    """FPS vs parameters and FPS vs FLOPs (two panels) of the networks with a measured speed
    and complexity; the paper's values for the same rows as hollow markers joined by a dotted
    line. ``False`` when no network has both."""
    points = network_points(frames)
    panels = (("params", "Parameters (M)"), ("flops", "FLOPs (G)"))
    if not any(p[x] is not None for p in points for x, _ in panels):
        return False
    fig = _figure(12, 5)
    axes = fig.subplots(1, 2)
    for ax, (x, xlabel) in zip(axes, panels, strict=True):
        shown = [p for p in points if p[x] is not None]
        xs: list[float] = []
        for i, series in enumerate(dict.fromkeys(p["series"] for p in points)):
            color = f"C{i}"
            pts = [p for p in shown if p["series"] == series]
            if not pts:
                continue
            marker = pts[0]["marker"]
            ax.scatter([p[x] for p in pts], [p["fps"] for p in pts], marker=marker, color=color,
                       s=45, label=f"{series}: measured", zorder=3)
            xs += [p[x] for p in pts]
            paper = [p for p in pts if p[f"paper_{x}"] is not None and p["paper_fps"] is not None]
            if paper:
                ax.scatter([p[f"paper_{x}"] for p in paper], [p["paper_fps"] for p in paper],
                           marker=marker, facecolors="none", edgecolors=color, s=45,
                           label=f"{series}: paper", zorder=3)
                xs += [p[f"paper_{x}"] for p in paper]
                for p in paper:
                    ax.plot([p[x], p[f"paper_{x}"]], [p["fps"], p["paper_fps"]], ":",
                            color=color, lw=0.8, zorder=2)
            for p in pts:
                ax.annotate(p["label"], (p[x], p["fps"]), textcoords="offset points",
                            xytext=(4, 4), fontsize=7)
        if not shown:
            ax.text(0.5, 0.5, f"no network with measured {xlabel.split(' ')[0]}", ha="center",
                    va="center", transform=ax.transAxes)
            ax.set_axis_off()
            continue
        positive = [v for v in xs if v > 0]
        if positive and max(positive) / min(positive) > 8:
            from matplotlib.ticker import LogLocator, NullFormatter, ScalarFormatter

            ax.set_xscale("log")
            ax.xaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
            ax.xaxis.set_major_formatter(ScalarFormatter())
            ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel(xlabel)
        ax.set_ylabel("FPS (batch 1)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    fig.suptitle("Speed against model size: measured (filled) and the paper (hollow)")
    fig.tight_layout()
    _save(fig, path)
    return True


# ------------------------------------------------------------------------------- mapping
def mapping_entries(records: Iterable[CellRecord],
                    tables: Mapping[str, PaperTable] | None = None) -> list[dict[str, Any]]:
    """Measured mapping statistics per (sequence, voxel size, system): ``update_hz``,
    ``end_to_end_hz``, ``map_bytes`` from the ``extra`` records, then from Table IV's records
    (map sizes on their column's sequence; a rate, and ``details``, only where the record says
    which sequence it measured in ``inputs["sequence"]``). The extra records win where both hold
    a value."""
    entries: dict[tuple[str, float | None, str], dict[str, Any]] = {}
    records = list(records)
    # the mapping runs only: the proxy maps (``extra/proxy-mapping/``, a trained network on a
    # synthrooms room) have their own table in table4.md and would read as a second system here
    extras = [r for r in records if r.status == "ok" and r.key.startswith("extra/mapping/")]
    table4 = [r for r in records if r.status == "ok" and r.table == "table4"
              and not r.key.startswith("extra/")]
    columns = {c.id: c for c in tables["table4"].columns} if tables and "table4" in tables else {}

    def add(seq: Any, voxel: Any, rec: CellRecord, got: Mapping[str, Any]) -> None:
        if not seq:
            return
        voxel = float(voxel) if isinstance(voxel, (int, float)) else None
        entry = entries.setdefault((str(seq), voxel, rec.row), {
            "sequence": str(seq), "voxel_size": voxel, "row": rec.row,
            "label": rec.label or rec.row})
        for k, v in got.items():
            if (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                    and entry.get(k) is None):
                entry[k] = float(v)

    for rec in extras:
        add(rec.inputs.get("sequence"), rec.inputs.get("voxel_size"), rec,
            {k: rec.values.get(k) for k in ("update_hz", "end_to_end_hz", "map_bytes")})
    for rec in table4:
        seq = rec.inputs.get("sequence")  # the sequence actually measured, when recorded
        for cid, v in rec.values.items():
            col = columns.get(cid)
            if col is None:
                continue
            voxel = rec.inputs.get("voxel_size", col.voxel_size)
            if col.quantity == "map_size" and (seq or col.datasets):
                add(seq or col.datasets[0], voxel, rec, {"map_bytes": v})
            elif col.quantity == "runtime_hz" and seq:
                add(seq, voxel, rec, {"end_to_end_hz": v})
        if seq:
            add(seq, rec.inputs.get("voxel_size"), rec,
                {k: rec.details.get(k) for k in ("update_hz", "end_to_end_hz", "map_bytes")})
    return [e for e in entries.values()
            if any(e.get(k) is not None for k in ("update_hz", "end_to_end_hz", "map_bytes"))]


def mapping_plot(records: Iterable[CellRecord], path: Path,
                 tables: Mapping[str, PaperTable] | None = None) -> bool:
    """Grouped bars: map update rate, end-to-end rate (Hz) and map size (MB) per sequence
    (groups) and system (bars). ``False`` without any measured mapping record."""
    entries = mapping_entries(records, tables)
    if not entries:
        return False
    voxels = {e["voxel_size"] for e in entries}

    def group_name(e: dict[str, Any]) -> str:
        if len(voxels) > 1 and e["voxel_size"] is not None:
            return f"{e['sequence']} ({e['voxel_size'] * 100:g} cm)"
        return e["sequence"]

    groups = list(dict.fromkeys(group_name(e) for e in sorted(
        entries, key=lambda e: (e["sequence"], e["voxel_size"] or 0.0))))
    order = {r: i for i, r in enumerate(MAP_ROWS)}
    systems = sorted({(e["row"], e["label"]) for e in entries},
                     key=lambda s: (order.get(s[0], len(order)), s[0]))
    panels = (("update_hz", "Map update (Hz)", 1.0), ("end_to_end_hz", "End-to-end (Hz)", 1.0),
              ("map_bytes", "Map size (MB)", 1e6))
    fig = _figure(max(8.0, 1.2 + 1.1 * len(groups) * max(1, len(systems)) * 0.45 * 3), 4.2)
    axes = fig.subplots(1, 3)
    width = 0.8 / max(1, len(systems))
    x = np.arange(len(groups))
    by_key = {(group_name(e), e["row"]): e for e in entries}
    for ax, (key, title, div) in zip(axes, panels, strict=True):
        drawn = False
        for i, (row, label) in enumerate(systems):
            heights = []
            for g in groups:
                e = by_key.get((g, row))
                v = None if e is None else e.get(key)
                heights.append(np.nan if v is None else v / div)
            if all(np.isnan(heights)):
                continue
            drawn = True
            ax.bar(x - 0.4 + width * (i + 0.5), heights, width, label=label, color=f"C{i}")
        ax.set_xticks(x, groups, rotation=20 if len(groups) > 3 else 0, fontsize=8)
        ax.set_xlim(-0.5, len(groups) - 0.5)
        ax.set_title(title, fontsize=10)
        ax.grid(True, axis="y", alpha=0.3)
        if not drawn:
            ax.text(0.5, 0.5, "not measured", ha="center", va="center", transform=ax.transAxes)
    handles, labels = [], []
    for ax in axes:
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    if handles:
        fig.legend(handles, labels, loc="upper center", ncol=min(6, len(labels)), fontsize=8)
    fig.tight_layout(rect=(0, 0, 1, 0.9))
    _save(fig, path)
    return True


# ------------------------------------------------------------------------------- qualitative
def _load_npz(path: Path) -> dict[str, np.ndarray]:
    try:
        with np.load(path, allow_pickle=False) as data:
            return {k: data[k] for k in data.files}
    except (OSError, ValueError, EOFError) as exc:
        raise DataFormatError(f"{path}: unreadable artifact ({exc})") from None


def _require(data: Mapping[str, np.ndarray], keys: Iterable[str], path: Path) -> None:
    missing = [k for k in keys if k not in data]
    if missing:
        raise DataFormatError(f"{path}: artifact lacks {', '.join(missing)}")


def split_map_name(path: Path, rows: Iterable[str] = MAP_ROWS) -> tuple[str, str]:
    """``map-<row>-<sequence>.npz`` -> (row, sequence); rows may hold dashes."""
    stem = path.name.removeprefix("map-").removesuffix(".npz")
    for row in sorted(rows, key=len, reverse=True):
        if stem.startswith(row + "-"):
            return row, stem[len(row) + 1:]
    row, _, seq = stem.rpartition("-")
    return (row, seq) if row else (stem, "")


def _class_colors(labels: np.ndarray) -> np.ndarray:
    """RGB floats per label; -1 (no class) is grey."""
    n = max(len(NYU40_CLASSES), int(labels.max()) + 1 if labels.size else 0)
    lut = np.vstack([palette(n).astype(np.float64) / 255.0, [[0.6, 0.6, 0.6]]])
    idx = np.where((labels >= 0) & (labels < n), labels, n).astype(np.int64)
    return lut[idx]


def _overlay(rgb: np.ndarray, labels: np.ndarray, alpha: float = 0.6) -> np.ndarray:
    """The label image's class colours blended over ``rgb``; void / no-class pixels stay RGB."""
    labels = labels.astype(np.int64)
    n = max(len(NYU40_CLASSES), int(labels[(labels >= 0) & (labels < 255)].max()) + 1
            if ((labels >= 0) & (labels < 255)).any() else 0)
    valid = (labels >= 0) & (labels < min(n, 255))
    colors = np.zeros(labels.shape + (3,), dtype=np.float64)
    colors[valid] = palette(n)[labels[valid]].astype(np.float64)
    base = rgb[..., :3].astype(np.float64)
    out = base.copy()
    out[valid] = (1 - alpha) * base[valid] + alpha * colors[valid]
    return np.clip(out, 0, 255).astype(np.uint8)


def top_down(centres: np.ndarray, resolution: float) -> np.ndarray:
    """Indices of the topmost occupied voxel of each (x, y) column, ordered by height (so a
    scatter in that order shows the top)."""
    if len(centres) == 0:
        return np.zeros(0, dtype=np.int64)
    res = resolution if resolution > 0 else 0.05
    kx = np.floor(centres[:, 0] / res).astype(np.int64)
    ky = np.floor(centres[:, 1] / res).astype(np.int64)
    order = np.lexsort((centres[:, 2], ky, kx))
    last = np.ones(len(order), dtype=bool)
    last[:-1] = (kx[order][1:] != kx[order][:-1]) | (ky[order][1:] != ky[order][:-1])
    top = order[last]
    return top[np.argsort(centres[top, 2], kind="stable")]


def _draw_seg(axes, data: Mapping[str, np.ndarray], path: Path) -> None:
    rgb, gt, pred = data["rgb"], data["gt"], data["pred"]
    title = str(data["title"]) if "title" in data else path.stem.removeprefix("seg-")
    for ax, img, name in zip(axes, (rgb, _overlay(rgb, gt), _overlay(rgb, pred)),
                             (f"{title}: RGB", "ground truth", "prediction"), strict=True):
        ax.imshow(img)
        ax.set_title(textwrap.fill(name, 48), fontsize=8)
        ax.set_axis_off()


def _draw_map(ax, data: Mapping[str, np.ndarray], row: str, title: str):
    """Draw one map; returns (scatter, span in metres, resolution) for sizing the markers once
    the layout is final, or ``None`` for an empty map."""
    centres = np.asarray(data["centres"], dtype=np.float64).reshape(-1, 3)
    labels = np.asarray(data["labels"]).reshape(-1) if "labels" in data else None
    resolution = float(data["resolution"]) if "resolution" in data else 0.05
    idx = top_down(centres, resolution)
    rgb = np.asarray(data["colors"]).reshape(-1, 3) if "colors" in data else None
    labelled = labels is not None and bool((labels >= 0).any())
    if rgb is not None and (row == "orgbmap" or not labelled) and rgb.any():
        colors = rgb[idx].astype(np.float64) / 255.0
        how = "RGB"
    elif labelled:
        colors = _class_colors(labels[idx])
        how = "class"
    else:  # occupancy only: colour by height
        import matplotlib

        z = centres[idx, 2]
        span_z = float(z.max() - z.min()) if len(z) else 0.0
        colors = matplotlib.colormaps["viridis"]((z - (z.min() if len(z) else 0.0))
                                                 / (span_z or 1.0))[:, :3]
        how = "height"
    title += f", {how}"
    ax.set_title(title, fontsize=8)
    ax.set_aspect("equal")
    if len(idx) == 0:
        ax.text(0.5, 0.5, "empty map", ha="center", va="center", transform=ax.transAxes)
        ax.set_xticks([])
        ax.set_yticks([])
        return None
    xy = centres[idx, :2]
    lo, hi = xy.min(0) - resolution, xy.max(0) + resolution
    span = max(float((hi - lo).max()), resolution)
    ax.set_xlim(lo[0], lo[0] + span)
    ax.set_ylim(lo[1], lo[1] + span)
    dots = ax.scatter(xy[:, 0], xy[:, 1], c=colors, s=1.0, marker="s", linewidths=0)
    ax.set_xlabel("x (m)", fontsize=7)
    ax.set_ylabel("y (m)", fontsize=7)
    ax.tick_params(labelsize=6)
    return dots, span, resolution


def _size_markers(ax, drawn) -> None:
    """One voxel per marker: its side in points from the axes' final width."""
    dots, span, resolution = drawn
    width_pt = ax.get_window_extent().width / _DPI * 72.0
    dots.set_sizes([max(0.3, (width_pt / span * resolution) ** 2)])


def qualitative_plot(artifacts: Path, path: Path,
                     labels: Mapping[str, str] | None = None) -> bool:
    """Segmentation overlays (``seg-*.npz``: RGB / ground truth / prediction, one row per file)
    above a top-down render of each system's map (``map-*.npz``: the topmost occupied voxel of
    each column, coloured by class, ORGBMap by its RGB). ``labels``: display names of the map
    rows. ``False`` when there is no artifact."""
    segs = sorted(artifacts.glob("seg-*.npz")) if artifacts.is_dir() else []
    maps = sorted(artifacts.glob("map-*.npz")) if artifacts.is_dir() else []
    if not segs and not maps:
        return False
    seg_data = []
    for p in segs:
        d = _load_npz(p)
        _require(d, ("rgb", "gt", "pred"), p)
        seg_data.append((p, d))
    order = {r: i for i, r in enumerate(MAP_ROWS)}
    map_data = []
    for p in maps:
        d = _load_npz(p)
        _require(d, ("centres",), p)
        row, seq = split_map_name(p, set(MAP_ROWS) | set(labels or {}))
        map_data.append((row, seq, d))
    map_data.sort(key=lambda m: (m[1], order.get(m[0], len(order)), m[0]))
    map_cols = min(4, max(1, len(map_data)))
    map_rows = math.ceil(len(map_data) / map_cols) if map_data else 0
    seg_h, map_h = 2.6 * len(seg_data), 3.4 * map_rows
    fig = _figure(max(9.0, 3.2 * map_cols), seg_h + map_h + 0.6, layout="constrained")
    if seg_data and map_data:
        top, bottom = fig.subfigures(2, 1, height_ratios=[seg_h, map_h])
    else:
        top = bottom = fig
    if seg_data:
        axes = top.subplots(len(seg_data), 3, squeeze=False)
        for ax_row, (p, d) in zip(axes, seg_data, strict=True):
            _draw_seg(ax_row, d, p)
    if map_data:
        axes = bottom.subplots(map_rows, map_cols, squeeze=False).ravel()
        for ax in axes[len(map_data):]:
            ax.set_axis_off()
        sized = []
        for ax, (row, seq, d) in zip(axes, map_data, strict=False):
            name = (labels or {}).get(row, row)
            drawn = _draw_map(ax, d, row, f"{name} ({seq})" if seq else name)
            if drawn is not None:
                sized.append((ax, drawn))
        bottom.suptitle("Maps seen from above (topmost voxel of each column), coloured by "
                        "class, RGB or height", fontsize=9)
        fig.draw_without_rendering()  # settle the layout, then size the voxels
        for ax, drawn in sized:
            _size_markers(ax, drawn)
    _save(fig, path)
    return True
