"""A small ScanNet scene in the official layout, and its independent voxelisation.

The scene is a box room whose six faces are axis-aligned rectangles with gaps between them
(each of one NYU40 id; the ceiling unannotated), seen from its middle by a camera turning on
the spot. Depth and labels are ray cast against the rectangles exactly; the ``.sens``, labelled
mesh, label table, 2D label archive and split files are written with
:mod:`evsmap.readers.scannet.write`.
:func:`box_truth` voxelises the room from the rectangles' areas (no sampling): what the reader's
mesh voxelisation must equal.
"""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np

from evsmap.classes import palette
from evsmap.data import VOID, VoxelLabels
from evsmap.readers.scannet.write import (
    SensFrame,
    write_label_ply,
    write_label_table,
    write_sens,
    write_split,
)

# (axis, plane, (lo, hi) on the next axis, (lo, hi) on the one after, NYU40 id): walls, floor
# and an unannotated ceiling, with gaps between them so that no voxel holds two faces, and no
# edge on a voxel boundary (at 2, 4 or 5 cm)
RECTANGLES = [
    (0, 0.013, (0.113, 1.513), (0.163, 1.063), 1),   # x = 0.013, wall
    (0, 2.013, (0.113, 1.513), (0.163, 1.063), 9),   # x = 2.013, window
    (1, 0.013, (0.163, 1.063), (0.113, 1.913), 1),   # y = 0.013, wall (z, then x)
    (1, 1.613, (0.163, 1.063), (0.113, 1.913), 8),   # y = 1.613, door
    (2, 0.013, (0.113, 1.913), (0.113, 1.513), 2),   # z = 0.013, floor (x, then y)
    (2, 1.213, (0.113, 1.913), (0.113, 1.513), 0),   # z = 1.213, ceiling, unannotated
]
DEPTH_K = (50.0, 50.0, 31.5, 23.5)
DEPTH_SIZE = (64, 48)
COLOR_SIZE = (128, 96)
CENTRE = np.array([1.013, 0.813, 0.613])
SCANNET_ID = {1: 1, 9: 5, 8: 28, 2: 2, 0: 0}
"""NYU40 id -> the ScanNet label id the 2D label images hold (the table maps it back)."""
FRAMES = 8
LOST = 3
"""The frame whose pose is -inf (tracking lost)."""


def pose(yaw: float) -> np.ndarray:
    forward = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    down = np.array([0.0, 0.0, -1.0])
    right = np.cross(down, forward)
    out = np.eye(4)
    out[:3, :3] = np.stack([right, down, forward], axis=1)
    out[:3, 3] = CENTRE
    return out


def cast(camera: np.ndarray, fx: float, fy: float, cx: float, cy: float, w: int, h: int
         ) -> tuple[np.ndarray, np.ndarray]:
    """(depth along the optical axis, NYU40 id) of each pixel, looking from inside the box."""
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    rays = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], axis=-1) @ camera[:3, :3].T
    o = camera[:3, 3]
    best = np.full((h, w), np.inf)
    ids = np.zeros((h, w), dtype=np.int64)
    for axis, plane, (b0, b1), (c0, c1), nyu in RECTANGLES:
        b, c = (axis + 1) % 3, (axis + 2) % 3
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (plane - o[axis]) / rays[..., axis]
        pb, pc = o[b] + t * rays[..., b], o[c] + t * rays[..., c]
        closer = (t > 0) & (t < best) & (pb >= b0) & (pb <= b1) & (pc >= c0) & (pc <= c1)
        best = np.where(closer, t, best)
        ids = np.where(closer, nyu, ids)
    best[~np.isfinite(best)] = 0.0  # through a gap: no measurement
    return best, ids


def rectangles() -> list[tuple[int, float, tuple[float, float], tuple[float, float], int]]:
    return list(RECTANGLES)


def mesh() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices, NYU40 ids and triangles of the six rectangles (two triangles each, own
    vertices so each face keeps its label)."""
    verts, ids, faces = [], [], []
    for axis, plane, (b0, b1), (c0, c1), nyu in rectangles():
        b, c = (axis + 1) % 3, (axis + 2) % 3
        base = len(verts)
        for pb, pc in ((b0, c0), (b1, c0), (b1, c1), (b0, c1)):
            p = np.zeros(3)
            p[axis], p[b], p[c] = plane, pb, pc
            verts.append(p)
            ids.append(nyu)
        faces += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    return np.array(verts), np.array(ids), np.array(faces)


def box_truth(resolution: float) -> VoxelLabels:
    """The room's voxels at ``resolution``, each labelled by the face with most area in it
    (ties: lower class; unannotated = void, ranked last), from the rectangles' overlaps."""
    area: dict[tuple[int, int, int], dict[int, float]] = {}
    for axis, plane, (b0, b1), (c0, c1), nyu in rectangles():
        b, c = (axis + 1) % 3, (axis + 2) % 3
        ka = int(np.floor(plane / resolution))
        cls = VOID if nyu == 0 else nyu - 1
        for kb in range(int(np.floor(b0 / resolution)), int(np.floor(b1 / resolution)) + 1):
            lb = min(b1, (kb + 1) * resolution) - max(b0, kb * resolution)
            for kc in range(int(np.floor(c0 / resolution)), int(np.floor(c1 / resolution)) + 1):
                lc = min(c1, (kc + 1) * resolution) - max(c0, kc * resolution)
                if lb <= 0 or lc <= 0:
                    continue
                key = [0, 0, 0]
                key[axis], key[b], key[c] = ka, kb, kc
                cell = area.setdefault(tuple(key), {})
                cell[cls] = cell.get(cls, 0.0) + lb * lc
    keys = sorted(area)
    labels = [min(area[k], key=lambda cls: (-round(area[k][cls], 12), cls)) for k in keys]
    return VoxelLabels(np.array(keys, dtype=np.int32), np.array(labels, dtype=np.uint8),
                       resolution)


def write_scene(root: Path, name: str = "scene0000_00", *, label_images: bool = False,
                frames: int = FRAMES, lost: int | None = LOST) -> Path:
    """The release layout under ``root``: ``scans/<name>/`` with the ``.sens`` and labelled mesh
    (and the 2D label archive), the label table and the split files; returns the scene
    folder."""
    folder = root / "scans" / name
    folder.mkdir(parents=True, exist_ok=True)
    fx, fy, cx, cy = DEPTH_K
    w, h = DEPTH_SIZE
    cw, ch = COLOR_SIZE
    k_depth = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
    k_color = np.array([[2 * fx, 0, 2 * cx + 0.5], [0, 2 * fy, 2 * cy + 0.5], [0, 0, 1]])
    colours = palette(41)
    records, label_pngs = [], {}
    for i in range(frames):
        cam = pose(2 * np.pi * i / frames + 0.1)
        depth, ids = cast(cam, fx, fy, cx, cy, w, h)
        raw = np.round(depth * 1000).astype(np.uint16)
        rgb = np.repeat(np.repeat(colours[ids], 2, axis=0), 2, axis=1)
        stored = cam.copy()
        if i == lost:
            stored[:] = -np.inf
        records.append(SensFrame(rgb, raw, stored, 1_000_000 + 33_333 * i,
                                 1_000_000 + 33_333 * i))
        lookup = np.zeros(41, dtype=np.uint16)
        for nyu, sid in SCANNET_ID.items():
            lookup[nyu] = sid
        scannet_ids = lookup[ids]
        label_pngs[i] = np.repeat(np.repeat(scannet_ids, 2, axis=0), 2, axis=1)
    write_sens(folder / f"{name}.sens", records, intrinsic_color=k_color,
               intrinsic_depth=k_depth, color_size=(cw, ch), depth_size=(w, h))
    v, ids, faces = mesh()
    write_label_ply(folder / f"{name}_vh_clean_2.labels.ply", v, ids, faces)
    write_label_table(root / "scannetv2-labels.combined.tsv",
                      [(sid, f"raw{nyu}", nyu) for nyu, sid in SCANNET_ID.items() if sid]
                      + [(40, "ignored", 0)])
    if label_images:
        from PIL import Image

        with zipfile.ZipFile(folder / f"{name}_2d-label-filt.zip", "w") as archive:
            for i, image in label_pngs.items():
                buf = io.BytesIO()
                Image.fromarray(image).save(buf, format="PNG")
                archive.writestr(f"label-filt/{i}.png", buf.getvalue())
    write_split(root / "scannetv2_val.txt", [name])
    write_split(root / "scannetv2_train.txt", [])
    return folder
