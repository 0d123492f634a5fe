"""Render RGB, metric depth and labels of a :class:`~evsmap.synth.scene.Room` with Open3D's
``RaycastingScene`` (Embree).

One ray per pixel through the pixel centre, direction ``R @ [(u - cx)/fx, (v - cy)/fy, 1]`` so the
hit distance is the z-depth itself. Colour = per-instance albedo x procedural texture x shading
(ambient + Lambert from ceiling lights with distance fall-off, compiled in
:mod:`evsmap.synth.shading`) + sensor noise. Optional Kinect-v1
style depth noise and holes (see :func:`kinect_noise`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evsmap.data import Intrinsics
from evsmap.open3d_loader import load_open3d
from evsmap.readers.images import (  # noqa: F401  (re-exported: the renderer's depth encoding)
    DEPTH_SCALE,
    dequantize_depth,
    quantize_depth,
)
from evsmap.synth.scene import BOX_TRIANGLES, Room
from evsmap.synth.shading import linear_colour


@dataclass(frozen=True)
class RenderedView:
    depth: np.ndarray  # float32 metres, 0 where nothing was hit
    labels: np.ndarray  # uint8, 255 where nothing was hit
    rgb: np.ndarray  # uint8 HxWx3
    normals: np.ndarray  # float32 HxWx3 world normals facing the camera
    instance: np.ndarray  # int32 part index, -1 where nothing was hit
    dirs: np.ndarray  # float64 HxWx3 world ray directions (z-component 1 in the camera frame)


class RoomRenderer:
    """Ray-casts one room; build once, render many poses."""

    def __init__(self, room: Room) -> None:
        o3d = load_open3d()
        self._o3d = o3d
        self.room = room
        self.scene = o3d.t.geometry.RaycastingScene()
        self._geom_to_part = {}
        for i, part in enumerate(room.parts):
            gid = self.scene.add_triangles(
                o3d.core.Tensor(part.vertices().astype(np.float32)),
                o3d.core.Tensor(BOX_TRIANGLES),
            )
            self._geom_to_part[int(gid)] = i
        ids = np.full(max(self._geom_to_part) + 2, -1, dtype=np.int32)
        for gid, i in self._geom_to_part.items():
            ids[gid] = i
        self._lut = ids
        self._labels = np.append(room.labels, np.uint8(255))
        self._albedo = np.array([p.albedo for p in room.parts] + [(0, 0, 0)], dtype=np.float32)
        self._lights = np.asarray(room.lights, dtype=np.float32).reshape(-1, 3)
        self._rays: tuple[Intrinsics, np.ndarray] | None = None
        self.threads = 0
        """Embree threads of the ray casting (0: all cores, Open3D's default; the image does
        not depend on it)."""

    def _camera_rays(self, intrinsics: Intrinsics) -> np.ndarray:
        """Camera-frame direction of each pixel's ray, (H, W, 3), computed once per camera."""
        if self._rays is None or self._rays[0] != intrinsics:
            i = intrinsics
            u, v = np.meshgrid(np.arange(i.width, dtype=np.float64),
                               np.arange(i.height, dtype=np.float64))
            cam = np.stack([(u - i.cx) / i.fx, (v - i.cy) / i.fy, np.ones_like(u)], axis=-1)
            self._rays = (intrinsics, cam)
        return self._rays[1]

    def cast(self, intrinsics: Intrinsics, pose: np.ndarray) -> dict[str, np.ndarray]:
        """Raw ray-cast of one view: z-depth, part index, world normals, ray directions."""
        h, w = intrinsics.height, intrinsics.width
        cam = self._camera_rays(intrinsics)
        dirs = cam.reshape(-1, 3) @ pose[:3, :3].T
        origin = np.broadcast_to(pose[:3, 3], dirs.shape)
        rays = np.concatenate([origin, dirs], axis=1).astype(np.float32)
        ans = self.scene.cast_rays(self._o3d.core.Tensor(rays), nthreads=self.threads)
        t = ans["t_hit"].numpy()
        gid = ans["geometry_ids"].numpy().astype(np.int64)
        hit = np.isfinite(t)
        gid = np.where(hit & (gid < len(self._lut) - 1), gid, len(self._lut) - 1)
        part = self._lut[gid]
        normals = ans["primitive_normals"].numpy()
        flip = np.sum(normals * dirs, axis=1) > 0
        normals[flip] *= -1
        return {
            "depth": np.where(hit, t, 0.0).astype(np.float32).reshape(h, w),
            "part": part.reshape(h, w),
            "normals": normals.astype(np.float32).reshape(h, w, 3),
            "dirs": dirs.reshape(h, w, 3),
        }

    def render(self, intrinsics: Intrinsics, pose: np.ndarray, *, rng: np.random.Generator,
               rgb_noise: float = 2.0) -> RenderedView:
        """Depth (exact), labels, shaded RGB and normals of one view."""
        c = self.cast(intrinsics, pose)
        part = c["part"]
        labels = self._labels[part]
        depth = c["depth"]
        color = linear_colour(pose[:3, 3], c["dirs"], depth, c["normals"], part, self._albedo,
                              self._lights)
        color = np.clip(color, 0.0, 1.0) ** (1 / 2.2) * 255.0
        if rgb_noise > 0:
            color = color + rng.normal(0.0, rgb_noise, color.shape)
        rgb = np.clip(np.round(color), 0, 255).astype(np.uint8)
        rgb[part < 0] = 0
        return RenderedView(depth, labels, rgb, c["normals"], part, c["dirs"])


def kinect_noise(
    depth: np.ndarray, normals: np.ndarray, dirs: np.ndarray, labels: np.ndarray, *,
    rng: np.random.Generator, min_range: float = 0.5, max_range: float = 8.0,
    window_label: int | None = 8,
) -> np.ndarray:
    """Kinect-v1-like corruption of an exact depth image.

    * axial noise (Nguyen, Izadi and Lovell, 3DIMPVT 2012):
      ``sigma_z = 0.0012 + 0.0019 (z - 0.4)^2 + 0.0001 / sqrt(z) * theta^2 / (pi/2 - theta)^2``
      with ``theta`` the incidence angle;
    * holes: outside ``[min_range, max_range]``, at grazing incidence (theta > 80 deg), on
      glass (the ``window_label`` class, 70 % of pixels), at depth discontinuities (pixels next to
      a > 10 % jump, with probability 0.6 - the IR shadow), and a sparse speckle of dropouts.

    Lateral (in-plane) noise and the disparity quantisation steps are not modelled.
    """
    z = depth.astype(np.float64)
    valid = z > 0
    d = dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)
    cos = np.clip(-np.sum(d * normals, axis=-1), 1e-6, 1.0)
    theta = np.arccos(cos)
    zs = np.maximum(z, 1e-3)
    sigma = (0.0012 + 0.0019 * (zs - 0.4) ** 2
             + 0.0001 / np.sqrt(zs) * theta**2 / np.maximum(np.pi / 2 - theta, 1e-3) ** 2)
    noisy = z + rng.normal(0.0, 1.0, z.shape) * sigma
    holes = ~valid | (z < min_range) | (z > max_range) | (theta > np.deg2rad(80))
    if window_label is not None:
        holes |= (labels == window_label) & (rng.random(z.shape) < 0.7)
    jump = np.zeros_like(valid)
    rel = 0.1 * zs
    dv = np.abs(np.diff(z, axis=0)) > np.minimum(rel[1:], rel[:-1])
    dh = np.abs(np.diff(z, axis=1)) > np.minimum(rel[:, 1:], rel[:, :-1])
    jump[1:] |= dv
    jump[:-1] |= dv
    jump[:, 1:] |= dh
    jump[:, :-1] |= dh
    holes |= jump & (rng.random(z.shape) < 0.6)
    holes |= rng.random(z.shape) < 0.003
    noisy[holes] = 0.0
    return np.maximum(noisy, 0.0).astype(np.float32)
