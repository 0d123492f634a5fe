"""The qualitative figure: segmentation overlays beside the ground truth, and a top-down render
of each system's semantic map."""

from __future__ import annotations

import math
import textwrap
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np

from evsmap.classes import NYU40_CLASSES, palette
from evsmap.errors import DataFormatError
from evsmap.report.figure_base import DPI, MAP_ROWS, new_figure, save_figure


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
    elif labels is not None and labelled:
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
    width_pt = ax.get_window_extent().width / DPI * 72.0
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
    fig = new_figure(max(9.0, 3.2 * map_cols), seg_h + map_h + 0.6 + legend_h,
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
    save_figure(fig, path)
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
