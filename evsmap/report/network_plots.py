"""The networks' figure: measured FPS against FLOPs for the networks of Tables I and II, and
each network's speed over ESANet-R34's beside the paper's ratio."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from evsmap.report.figure_base import empty_panel, new_figure, save_figure
from evsmap.runner.records import CellRecord
from evsmap.tables.schema import PaperTable, load_tables

# ------------------------------------------------------------------------------- networks
_MARKERS = ("o", "s", "^", "D", "v", "P")


def speed_series(tables: Mapping[str, PaperTable] | None = None) -> list[tuple[str, str, str, str]]:
    """``(table, fps column, legend, marker)`` of every FPS column of the networks' tables
    (``role = "networks"``, default: the package's), in the tables' order."""
    chosen = load_tables() if tables is None else tables
    columns = [(tid, t.number, c) for tid, t in chosen.items() if t.role == "networks"
               for c in t.columns if c.quantity == "fps"]
    return [(tid, c.id, f"Table {number}" + (f" ({c.input_size[1]}x{c.input_size[0]})"
                                             if c.input_size else ""),
             _MARKERS[i % len(_MARKERS)]) for i, (tid, number, c) in enumerate(columns)]


def _value(cells: Mapping[str, Mapping[str, Any]], col: str, which: str) -> float | None:
    line = cells.get(col)
    if line is None or pd.isna(line[which]):
        return None
    return float(line[which])


def network_points(frames: Mapping[str, pd.DataFrame], records: Iterable[CellRecord] = (),
                   tables: Mapping[str, PaperTable] | None = None) -> list[dict[str, Any]]:
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
    for tid, fps_col, legend, marker in speed_series(tables):
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
        assert best is not None  # the first offset is always kept
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
    fig = new_figure(13, max(5.6, 0.36 * len(ratios) + 1.6))
    left, right = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.0, 1.1]})

    _cost_panel(left, points, series, colors)
    left.set_title("Speed against cost, this machine", fontsize=10)

    _ratio_panel(right, ratios, colors)
    right.set_title("Speed relative to the paper's baseline (carries across machines)",
                    fontsize=10)
    fig.tight_layout()
    save_figure(fig, path)
    return True


def _cost_panel(left: Any, points: list[dict[str, Any]], series: list[str],
                colors: dict[str, str]) -> None:
    """The left panel of :func:`networks_plot`: FPS against FLOPs, lines of constant G MAC/s."""
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
        empty_panel(left, "no network with measured FLOPs")


def _ratio_panel(right: Any, ratios: list[dict[str, Any]], colors: dict[str, str]) -> None:
    """The right panel of :func:`networks_plot`: each network's speed over the baseline's,
    measured here beside the paper's."""
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
        empty_panel(right, f"{SPEED_BASELINE} not timed in this run: no speed ratio")


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
