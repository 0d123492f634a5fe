"""The speed cells of a comparison as one figure: run A's FPS against each other run's.

One point per network and input size that both measured (Tables I and II's FPS cells), on log
axes, with error bars from each value's precision (the half-width of its median's 95 %
interval) and the diagonal (equal speed) drawn; the dotted lines beside it are the geometric
mean of the ratios, so a machine twice as fast puts its points on a line parallel to the
diagonal. Each run compared with A has its colour.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from evsmap.report.compare import Comparison
from evsmap.report.figure_base import new_figure, save_figure

_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")
_MARKERS = {"table1": "o", "table2": "s"}


def speed_points(comparison: Comparison, index: int) -> list[dict[str, Any]]:
    """The shared speed cells of column 0 and column ``index``: label, x, y and their
    half-widths (None without a precision)."""
    a, b = comparison.columns[0], comparison.columns[index]
    out = []
    for cid in comparison.shared:
        cell = comparison.cells[cid]
        if not cell.speed:
            continue
        va, vb = a.values[cid], b.values[cid]
        if va.value <= 0 or vb.value <= 0:
            continue
        first = cell.header.split(" ")[0]
        size = first if any(x in first for x in ("×", "x")) else ""
        out.append({"label": f"{cell.label} {size}", "table": cell.table,
                    "x": va.value, "y": vb.value,
                    "dx": None if va.rel is None else va.value * va.rel,
                    "dy": None if vb.rel is None else vb.value * vb.rel})
    return out


def speed_plot(comparison: Comparison, path: Path) -> bool:
    """Draw the figure into ``path``; False (nothing written) when no speed cell is shared."""
    series = [(i, speed_points(comparison, i)) for i in range(1, len(comparison.columns))]
    series = [(i, pts) for i, pts in series if pts]
    if not series:
        return False
    fig = new_figure(7.5, 8.2, layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    low = min(min(p["x"], p["y"]) for _, pts in series for p in pts) / 1.5
    high = max(max(p["x"], p["y"]) for _, pts in series for p in pts) * 1.5
    ax.plot([low, high], [low, high], color="0.3", lw=1, label="equal speed")
    for n, (i, pts) in enumerate(series):
        colour = _COLOURS[n % len(_COLOURS)]
        for table, marker in _MARKERS.items():
            mine = [p for p in pts if p["table"] == table]
            if not mine:
                continue
            ax.errorbar([p["x"] for p in mine], [p["y"] for p in mine],
                        xerr=[p["dx"] or 0.0 for p in mine], yerr=[p["dy"] or 0.0 for p in mine],
                        fmt=marker, color=colour, ms=5, capsize=2, lw=0.8,
                        label=f"{_name(comparison, i)}, Table {'I' if table == 'table1' else 'II'}")
        ratio = math.exp(sum(math.log(p["y"] / p["x"]) for p in pts) / len(pts))
        ax.plot([low, high], [low * ratio, high * ratio], color=colour, lw=0.8, ls=":",
                label=f"{_name(comparison, i)}: geometric mean {ratio:.2f}x")
        for p in pts:
            ax.annotate(p["label"], (p["x"], p["y"]), fontsize=6, xytext=(3, 3),
                        textcoords="offset points", color=colour)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlim(low, high)
    ax.set_ylim(low, high)
    ax.set_aspect("equal")
    ax.set_xlabel(f"A: {comparison.columns[0].name} - FPS ({comparison.columns[0].machine})",
                  fontsize=8)
    ax.set_ylabel("FPS of the run compared with A", fontsize=8)
    ax.set_title("Speed cells of both runs (error bars: each median's 95 % interval)",
                 fontsize=9)
    ax.grid(True, which="both", lw=0.3, alpha=0.5)
    # outside the axes: every corner of a log-log comparison can hold points
    fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncol=1, fontsize=7)
    save_figure(fig, path)
    return True


def _name(comparison: Comparison, index: int) -> str:
    col = comparison.columns[index]
    return f"{chr(ord('A') + index)}: {col.name}"

