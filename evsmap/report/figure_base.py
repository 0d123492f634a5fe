"""What every figure of the report shares: the systems' display order, an off-screen figure
(matplotlib's Agg canvas), its atomic save, an empty panel's text."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

MAP_ROWS = ("orgbmap", "tesamap", "tfeagmap", "mesamap", "evsmap", "octomap-cpp")
"""Mapping systems in display order (Table IV rows, then the C++ OctoMap reference)."""

DPI = 110
"""The figures' resolution, dots per inch."""


def new_figure(width: float, height: float,
               layout: Literal["constrained", "compressed", "tight"] | None = None) -> Any:
    """A matplotlib figure on the off-screen Agg canvas."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=DPI, layout=layout)
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Any, path: Path) -> None:
    """``fig`` written to ``path`` as PNG, atomically."""
    from evsmap.fileio import atomic_path

    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path, suffix=".png") as tmp:  # an earlier figure stays until this is whole
        fig.savefig(tmp, format="png", dpi=DPI)


def empty_panel(ax: Any, text: str) -> None:
    """``text`` in the middle of an axes without axes."""
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, fontsize=9)
    ax.set_axis_off()
