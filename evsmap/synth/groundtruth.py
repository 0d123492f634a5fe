"""Ground truth of a synthetic room for 3D evaluation: the occupied voxels and their labels.

Every visible box face inside the room is sampled densely (spacing <= resolution / 3); samples that
lie on or inside another part are hidden (a picture covers the wall behind it, a bed covers the
floor under it) and dropped. Each voxel that receives samples is occupied and takes the class with
the most samples in it. Voxel keys follow OctoMap's convention without the 2^15 offset:
``key = floor(coordinate / resolution)``, centre ``(key + 0.5) * resolution``.
"""

from __future__ import annotations

import numpy as np

from evsmap.data import VoxelLabels
from evsmap.synth.scene import Part, Room


def _face_samples(part: Part, spacing: float) -> list[np.ndarray]:
    """World points on each of the 6 faces of ``part`` on a grid no coarser than ``spacing``."""
    half = np.asarray(part.size) / 2.0
    rot = part.rotation()
    faces = []
    for axis in range(3):
        a, b = [i for i in range(3) if i != axis]
        na = int(np.ceil(2 * half[a] / spacing)) + 1
        nb = int(np.ceil(2 * half[b] / spacing)) + 1
        ga, gb = np.meshgrid(np.linspace(-half[a], half[a], na), np.linspace(-half[b], half[b], nb),
                             indexing="ij")
        for sign in (-1.0, 1.0):
            local = np.empty((ga.size, 3))
            local[:, axis] = sign * half[axis]
            local[:, a] = ga.ravel()
            local[:, b] = gb.ravel()
            faces.append(local @ rot.T + np.asarray(part.center))
    return faces


def _aabb(points_or_part) -> tuple[np.ndarray, np.ndarray]:
    pts = points_or_part.vertices() if isinstance(points_or_part, Part) else points_or_part
    return pts.min(axis=0), pts.max(axis=0)


def ground_truth_voxels(room: Room, resolution: float, *, hidden_tol: float = 1e-4) -> VoxelLabels:
    """Occupied voxels of the room's visible surfaces at ``resolution`` metres, with labels."""
    if not resolution > 0:
        raise ValueError(f"resolution must be positive, got {resolution}")
    spacing = resolution / 3.0
    L, W, H = room.size
    lo_room, hi_room = np.array([0.0, 0.0, 0.0]) - 1e-6, np.array([L, W, H]) + 1e-6
    boxes = [_aabb(p) for p in room.parts]
    all_points, all_labels = [], []
    for i, part in enumerate(room.parts):
        for pts in _face_samples(part, spacing):
            pts = pts[np.all((pts >= lo_room) & (pts <= hi_room), axis=1)]
            if not len(pts):
                continue
            lo, hi = pts.min(axis=0), pts.max(axis=0)
            keep = np.ones(len(pts), dtype=bool)
            for j, other in enumerate(room.parts):
                if j == i:
                    continue
                olo, ohi = boxes[j]
                if np.any(olo > hi + hidden_tol) or np.any(ohi < lo - hidden_tol):
                    continue
                keep &= ~other.contains(pts, tol=hidden_tol)
            pts = pts[keep]
            if len(pts):
                all_points.append(pts)
                all_labels.append(np.full(len(pts), part.label, dtype=np.int64))
    if not all_points:
        return VoxelLabels(np.zeros((0, 3), np.int32), np.zeros(0, np.uint8), resolution)
    # each voxel keeps the label with most samples (ties: lower class id)
    return VoxelLabels.by_vote(np.concatenate(all_points), np.concatenate(all_labels),
                               resolution)


__all__ = ["VoxelLabels", "ground_truth_voxels"]
