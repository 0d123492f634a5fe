"""The report's figures (matplotlib, drawn off-screen through the Agg canvas).

* :func:`networks_plot` - measured FPS against FLOPs for the networks of Tables I and II, and
  each network's speed over ESANet-R34's beside the paper's ratio.
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
from evsmap.tables.schema import PaperTable, mapping_table_id

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
    from evsmap.fileio import atomic_path

    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path, suffix=".png") as tmp:  # an earlier figure stays until this is whole
        fig.savefig(tmp, format="png", dpi=_DPI)


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


def network_points(frames: Mapping[str, pd.DataFrame],
                   records: Iterable[CellRecord] = ()) -> list[dict[str, Any]]:
    """Rows of Tables I/II with a measured FPS: the measured and printed FPS, the timing's
    calibration and the FLOPs (G) for each speed column (``frames``:
    :func:`~evsmap.report.tables.table_frame` by table id). ``flops`` is the speed record's
    own count at the resolution it timed (fvcore, ``details["macs"]``, from ``records``), else
    the table's FLOPs column."""
    timed_macs = {}
    for rec in records:
        macs = (rec.details or {}).get("macs") if rec.status == "ok" else None
        if rec.kind == "speed" and isinstance(macs, (int, float)) and macs > 0:
            for col in rec.metrics:
                timed_macs[(rec.table, rec.row, col)] = float(macs) / 1e9
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
                "fps": float(fps["measured"]),
                "calibration": _value(cells, fps_col, "calibration_gmacs"),
                "flops": timed_macs.get((tid, row, fps_col), _value(cells, "flops", "measured")),
                "paper_fps": _value(cells, fps_col, "paper")})
    return points


def _log_axis(ax, which: str, values: Iterable[float]) -> None:
    """Log scale with plain-number ticks on ``ax``'s ``which`` ("x" or "y") axis when the
    positive ``values`` span more than a factor of 8."""
    positive = [v for v in values if v is not None and v > 0]
    if not positive or max(positive) / min(positive) <= 8:
        return
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    (ax.set_xscale if which == "x" else ax.set_yscale)("log")
    axis = ax.xaxis if which == "x" else ax.yaxis
    axis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    axis.set_minor_formatter(NullFormatter())


# candidate label offsets (points) around a marker, tried in this order
_OFFSETS = ((5, 5), (5, -11), (-5, 5), (-5, -11), (8, -3), (-8, -3), (0, 9), (0, -15),
            (12, 12), (-12, 12), (12, -18), (-12, -18))


def place_labels(ax, xs: list[float], ys: list[float], texts: list[str],
                 fontsize: float = 7) -> list:
    """Annotate each point with its text at the first offset of :data:`_OFFSETS` whose box
    overlaps no label placed before it, no marker and stays inside the axes (else the offset
    that overlaps least). Returns the annotations."""
    fig = ax.figure
    renderer = fig.canvas.get_renderer()
    fig.draw_without_rendering()
    frame = ax.get_window_extent(renderer)
    points = ax.transData.transform(np.column_stack([xs, ys])) if xs else np.zeros((0, 2))
    scale = fig.dpi / 72.0
    placed: list = []
    out = []
    for i in sorted(range(len(xs)), key=lambda k: (-points[k][1], points[k][0])):
        best, best_cost = None, math.inf
        for dx, dy in _OFFSETS:
            ann = ax.annotate(texts[i], (xs[i], ys[i]), textcoords="offset points",
                              xytext=(dx, dy), fontsize=fontsize,
                              ha="left" if dx >= 0 else "right")
            box = ann.get_window_extent(renderer)
            cost = sum(_overlap(box, b) for b in placed)
            cost += sum(_overlap(box, _marker_box(p, 4 * scale)) for j, p in enumerate(points)
                        if j != i)
            cost += _outside(box, frame)
            if cost < best_cost:
                if best is not None:
                    best[0].remove()
                best, best_cost = (ann, box), cost
            else:
                ann.remove()
            if cost == 0:
                break
        placed.append(best[1])
        out.append(best[0])
    return out


def _marker_box(p, r):
    from matplotlib.transforms import Bbox

    return Bbox.from_extents(p[0] - r, p[1] - r, p[0] + r, p[1] + r)


def _overlap(a, b) -> float:
    w = min(a.x1, b.x1) - max(a.x0, b.x0)
    h = min(a.y1, b.y1) - max(a.y0, b.y0)
    return w * h if w > 0 and h > 0 else 0.0


def _outside(box, frame) -> float:
    inside = _overlap(box, frame)
    return (box.width * box.height - inside) * 4.0


SPEED_BASELINE = "esanet-r34"
"""The row every network's speed is divided by in :func:`speed_ratios` (the paper's baseline
for its speed claims)."""


def speed_ratios(points: list[dict[str, Any]],
                 base: str = SPEED_BASELINE) -> list[dict[str, Any]]:
    """Per speed series of :func:`network_points`, each network's FPS over ``base``'s FPS in
    the same series: ``measured`` (both timed in this run, drift-corrected by their
    calibrations: :func:`~evsmap.measure.speed.calibrated_ratio`) and ``paper`` (both
    printed, else ``None``). Empty for a series without a measured ``base``."""
    out = []
    for series in dict.fromkeys(p["series"] for p in points):
        pts = [p for p in points if p["series"] == series]
        ref = next((p for p in pts if p["row"] == base), None)
        if ref is None or not ref["fps"]:
            continue
        from evsmap.measure.speed import calibrated_ratio

        for p in pts:
            if p is ref:
                continue
            paper = (p["paper_fps"] / ref["paper_fps"]
                     if p["paper_fps"] is not None and ref["paper_fps"] else None)
            out.append({"series": series, "marker": p["marker"], "row": p["row"],
                        "label": p["label"], "base_label": ref["label"],
                        "measured": calibrated_ratio(p["fps"], p.get("calibration"),
                                                     ref["fps"], ref.get("calibration")),
                        "paper": paper})
    return out


def networks_plot(frames: Mapping[str, pd.DataFrame], path: Path,
                  records: Iterable[CellRecord] = ()) -> bool:
    """Two panels. Left: measured FPS against measured FLOPs (log axes where the values span
    decades), with lines of constant throughput (G MAC/s). Right: each network's speed over
    ESANet-R34's at the same resolution, measured here beside the paper's ratio - the
    comparison that carries across machines (the paper's absolute FPS are a Jetson's).
    ``False`` when no network has a measured speed."""
    points = network_points(frames, records)
    if not points:
        return False
    series = list(dict.fromkeys(p["series"] for p in points))
    colors = {s: f"C{i}" for i, s in enumerate(series)}
    ratios = speed_ratios(points)
    # the ratio panel's two-line labels need about a third of an inch a network
    fig = _figure(13, max(5.6, 0.36 * len(ratios) + 1.6))
    left, right = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.0, 1.1]})

    shown = [p for p in points if p["flops"] is not None]
    if shown:
        for s in series:
            pts = [p for p in shown if p["series"] == s]
            if pts:
                left.scatter([p["flops"] for p in pts], [p["fps"] for p in pts],
                             marker=pts[0]["marker"], color=colors[s], s=40, zorder=3,
                             label=s)
        flops = [p["flops"] for p in shown]
        fps = [p["fps"] for p in shown]
        _log_axis(left, "x", flops)
        _log_axis(left, "y", fps)
        lo, hi = min(flops) / 1.5, max(flops) * 1.5
        y_lo = min(fps) / 1.6
        left.set_xlim(lo, hi)
        left.set_ylim(y_lo, max(fps) * 1.6)
        grid = np.geomspace(lo, hi, 50)
        for k, rate in enumerate(_iso_rates(flops, fps)):
            left.plot(grid, rate / grid, "--", color="0.75", lw=0.7, zorder=1,
                      label="constant G MAC/s (value at the line)" if k == 0 else None)
            # the value where the line leaves the plot at the bottom (the lines are a factor 2
            # or more apart there, so the short labels do not meet)
            x_at = rate / (y_lo * 1.15)
            if lo < x_at < hi:
                left.text(x_at, y_lo * 1.15, f"{rate:g}", fontsize=7, color="0.45",
                          ha="right", va="bottom")
        left.set_xlabel("FLOPs (G, fvcore; one multiply-add = one flop)")
        left.set_ylabel("FPS measured here (batch 1)")
        left.grid(True, which="major", alpha=0.3)
        left.legend(fontsize=7, loc="lower left")
        place_labels(left, [p["flops"] for p in shown], [p["fps"] for p in shown],
                     [p["label"] for p in shown])
    else:
        _empty(left, "no network with measured FLOPs")
    left.set_title("Speed against cost, this machine", fontsize=10)

    if ratios:
        y = np.arange(len(ratios))[::-1].astype(float)
        h = 0.38
        for yi, r in zip(y, ratios, strict=True):
            c = colors[r["series"]]
            left_bar = right.barh(yi + h / 2, r["measured"], h, color=c)
            right.bar_label(left_bar, [f"{r['measured']:.2f}x here"], fontsize=7, padding=2)
            if r["paper"] is not None:
                bar = right.barh(yi - h / 2, r["paper"], h, facecolor="white", edgecolor=c,
                                 hatch="///")
                right.bar_label(bar, [f"{r['paper']:.2f}x paper"], fontsize=7, padding=2,
                                color="0.35")
        right.set_yticks(y, [f"{r['label']}\n{r['series']}" for r in ratios], fontsize=7)
        right.axvline(1.0, color="0.3", lw=0.8)
        values = [r["measured"] for r in ratios] + [r["paper"] for r in ratios if r["paper"]]
        _log_axis(right, "x", values + [1.0])
        from matplotlib.ticker import FuncFormatter

        right.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}x"))
        right.set_xlim(min(values + [1.0]) / 1.5, max(values) * 2.2)
        right.set_xlabel(f"FPS / {ratios[0]['base_label']} FPS at the same resolution")
        right.grid(True, axis="x", which="major", alpha=0.3)
        from matplotlib.patches import Patch

        right.legend(handles=[Patch(color="0.4", label="measured here (same run, drift-corrected)"),
                              Patch(facecolor="white", edgecolor="0.4", hatch="///",
                                    label="the paper (its printed FPS)")],
                     fontsize=7, loc="lower right")
    else:
        _empty(right, f"{SPEED_BASELINE} not timed in this run: no speed ratio")
    right.set_title("Speed relative to the paper's baseline (carries across machines)",
                    fontsize=10)
    fig.tight_layout()
    _save(fig, path)
    return True


def _iso_rates(flops: list[float], fps: list[float]) -> list[float]:
    """Round throughputs (G MAC/s, 1-2-5 steps) spanning the measured points' FLOPs x FPS."""
    got = [f * s for f, s in zip(flops, fps, strict=True) if f > 0 and s > 0]
    if not got:
        return []
    lo, hi = min(got) / 1.2, max(got) * 1.2
    rates = []
    for exp in range(math.floor(math.log10(lo)) - 1, math.ceil(math.log10(hi)) + 1):
        for m in (1, 2, 5):
            v = m * 10.0 ** exp
            if lo <= v <= hi:
                rates.append(v)
    return rates[:: max(1, len(rates) // 4)]


def _empty(ax, text: str) -> None:
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, fontsize=9)
    ax.set_axis_off()


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
    table4 = [r for r in records if r.status == "ok" and r.table == mapping_table_id()
              and not r.key.startswith("extra/")]
    columns = {c.id: c for t in (tables or {}).values() if t.role == "mapping" for c in t.columns}

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
    # systems that could not map a sequence here (a network without trained weights on a
    # sequence without labels): an entry without values, so the plot says n/a
    for rec in records:
        if rec.status == "na" and rec.key.startswith("extra/mapping/"):
            seq, voxel = rec.inputs.get("sequence"), rec.inputs.get("voxel_size")
            voxel = float(voxel) if isinstance(voxel, (int, float)) else None
            if seq:
                entries.setdefault((str(seq), voxel, rec.row), {
                    "sequence": str(seq), "voxel_size": voxel, "row": rec.row,
                    "label": rec.label or rec.row, "na": rec.reason})
    return [e for e in entries.values()
            if e.get("na") or any(e.get(k) is not None
                                  for k in ("update_hz", "end_to_end_hz", "map_bytes"))]


def mapping_plot(records: Iterable[CellRecord], path: Path,
                 tables: Mapping[str, PaperTable] | None = None) -> bool:
    """Grouped bars, one panel per quantity (map update rate, end-to-end rate in Hz, map size in
    MB), stacked: sequences are the groups, systems the bars, each bar labelled with its value;
    a system mapped on a sequence without that quantity reads "n/a", never a zero-height bar.
    ``False`` without any measured mapping record."""
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
    panels = (("update_hz", "Map update rate (Hz, median over frames)", 1.0, "{:.3g}"),
              ("end_to_end_hz", "End-to-end rate (Hz: segmentation + update)", 1.0, "{:.3g}"),
              ("map_bytes", "Map size (MB, the file each system writes)", 1e6, "{:.3g}"))
    fig = _figure(max(9.0, 2.0 + 0.34 * len(groups) * len(systems)), 3.0 * len(panels) + 0.9)
    axes = fig.subplots(len(panels), 1)
    width = 0.84 / max(1, len(systems))
    x = np.arange(len(groups))
    by_key = {(group_name(e), e["row"]): e for e in entries}
    for ax, (key, title, div, fmt) in zip(axes, panels, strict=True):
        drawn = []
        for i, (row, label) in enumerate(systems):
            xs = x - 0.42 + width * (i + 0.5)
            heights, missing = [], []
            for xi, g in zip(xs, groups, strict=True):
                e = by_key.get((g, row))
                v = None if e is None else e.get(key)
                heights.append(np.nan if v is None else v / div)
                if e is not None and v is None:
                    missing.append(xi)
            bars = ax.bar(xs, heights, width, label=label, color=f"C{i}")
            ax.bar_label(bars, [("" if np.isnan(h) else fmt.format(h)) for h in heights],
                         fontsize=6.5, rotation=90, padding=2)
            drawn += [h for h in heights if not np.isnan(h)]
            for xi in missing:
                ax.annotate("n/a", (xi, 0.0), xycoords=ax.get_xaxis_transform(), xytext=(0, 3),
                            textcoords="offset points",
                            ha="center", va="bottom", rotation=90, fontsize=6.5, color="0.45")
        ax.set_xticks(x, groups, fontsize=8)
        ax.set_xlim(-0.5, len(groups) - 0.5)
        ax.set_title(title, fontsize=9, loc="left")
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
    present = _classes_present([d["gt"] for _, d in seg_data],
                               [d["pred"] for _, d in seg_data]
                               + [d["labels"] for _, _, d in map_data if "labels" in d])
    legend_h = 0.35 + 0.2 * math.ceil(len(present) / 8) if present else 0.0
    fig = _figure(max(9.0, 3.2 * map_cols), seg_h + map_h + 0.6 + legend_h,
                  layout="constrained")
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
    if present:
        _class_legend(fig, present)
    if map_data:
        fig.draw_without_rendering()  # settle the layout, then size the voxels
        for ax, drawn in sized:
            _size_markers(ax, drawn)
    _save(fig, path)
    return True


def _classes_present(truth: Iterable[np.ndarray], other: Iterable[np.ndarray],
                     min_share: float = 0.01) -> list[int]:
    """Sorted class ids (0..254) in any ``truth`` array, or covering at least ``min_share`` of
    one of the ``other`` arrays (predictions, maps: the scattered noise of a few pixels would
    fill the legend); void (255) and "no class" (negative) left out."""
    ids: set[int] = set()
    for a in truth:
        a = np.asarray(a).reshape(-1)
        ids.update(int(v) for v in np.unique(a[(a >= 0) & (a < 255)]))
    for a in other:
        a = np.asarray(a).reshape(-1)
        a = a[(a >= 0) & (a < 255)]
        if a.size:
            values, counts = np.unique(a, return_counts=True)
            ids.update(int(v) for v, c in zip(values, counts, strict=True)
                       if c >= min_share * a.size)
    return sorted(ids)


def _class_legend(fig, ids: list[int]) -> None:
    """A legend of the classes drawn (their names, NYUv2-40 order; ids past it by number),
    below the panels."""
    from matplotlib.patches import Patch

    n = max(len(NYU40_CLASSES), ids[-1] + 1)
    colors = palette(n).astype(np.float64) / 255.0
    handles = [Patch(color=colors[i], label=NYU40_CLASSES[i] if i < len(NYU40_CLASSES)
                     else f"class {i}") for i in ids]
    ncol = min(8, len(handles))
    fig.legend(handles=handles, loc="outside lower center", ncol=ncol, fontsize=7,
               title="classes (in the ground truth, or on at least 1 % of a prediction or "
                     "map; grey in a map: no class)", title_fontsize=7, frameon=False)


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
            where = (str(rec.inputs.get("sequence")), float(rec.inputs.get("voxel_size") or 0))
            series.setdefault(where, {})[rec.row] = (rec.label or rec.row, growth)
    if not series:
        return False
    places = sorted(series)
    order = {r: i for i, r in enumerate(MAP_ROWS)}
    fig = _figure(max(6.0, 4.2 * len(places)), 2.6 * len(GROWTH_READINGS) + 0.8,
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
    _save(fig, path)
    return True
