"""HHA, the three-channel depth encoding of Gupta et al. (numpy only).

Paper: S. Gupta, R. Girshick, P. Arbelaez and J. Malik, "Learning Rich Features from RGB-D Images
for Object Detection and Segmentation", ECCV 2014. Each pixel of a depth map becomes

* **H**orizontal disparity: ``31000 / max(z_cm, 100)`` (z in centimetres: 310 / z in metres,
  saturating at 255 for z <= 1.216 m);
* **H**eight above the ground: ``-(g . p) - y_min`` in centimetres, ``p`` the pixel's 3D point
  (cm), ``g`` the estimated gravity direction (pointing down), ``y_min`` the lowest height of
  the frame, or -130 cm when that is higher than -90 cm (no floor in view: assume the camera is
  1.3 m above it);
* **A**ngle: the angle in degrees between the pixel's surface normal (3 px radius plane fit,
  oriented away from the camera) and gravity, plus 38 (``128 - 90``: a floor is 38, a wall 128,
  a ceiling 218);

each rounded to the nearest integer and saturated to 0..255 (MATLAB's ``uint8``). Gravity is
estimated from coarser normals (10 px radius): starting from the camera's down axis, twice (with
angle thresholds 45 and then 15 degrees, 5 iterations each) collect the normals within the
threshold of the current estimate ("floor", parallel) and those within the threshold of its
perpendicular plane ("wall"), and take the direction minimising ``sum_wall (g.n)^2 -
sum_floor (g.n)^2`` (the eigenvector of the least eigenvalue).

The constants and steps follow the authors' release (``s-gupta/rcnn-depth``:
``rcnn/saveHHA.m``, ``mcg/depth_features/processDepthImage.m``) and its Python port
(``charlesCXK/Depth2HHA-python``); ``docs/baselines/hha.md`` lists each choice and where it
comes from. Differences: pixels of invalid depth (0) are 0 in all three channels (the release
reads the dataset's in-painted depth for the point cloud and the raw one only to mask the
normal fits); pixel coordinates are 0-based like every evsmap camera (the MATLAB code counts
from 1). Channel order: 0 disparity, 1 height, 2 angle (the release's ``I(:,:,1..3)``, the
PNG's R, G, B).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from evsmap.errors import InvalidDataError

if TYPE_CHECKING:
    from evsmap.data import Intrinsics

__all__ = ["HHA", "encode_hha", "gravity_direction", "hha_channels", "surface_normals"]

#: Disparity channel: ``DISPARITY_SCALE / max(z_cm, MIN_DEPTH_CM)``.
DISPARITY_SCALE = 31000.0
MIN_DEPTH_CM = 100.0
#: Angle channel: degrees + ``ANGLE_OFFSET`` (0 deg -> 38, 90 -> 128, 180 -> 218).
ANGLE_OFFSET = 128.0 - 90.0
#: Height channel: when the lowest point lies above ``FLOOR_SEARCH_CM`` (cm, relative to the
#: camera), the floor is assumed at ``FLOOR_DEFAULT_CM``.
FLOOR_SEARCH_CM = -90.0
FLOOR_DEFAULT_CM = -130.0
#: Radii (pixels) of the square plane fits: normals of the angle channel, normals for gravity.
NORMAL_RADIUS = 3
GRAVITY_NORMAL_RADIUS = 10
#: Gravity estimation: (threshold in degrees, iterations) per round.
GRAVITY_ROUNDS = ((45.0, 5), (15.0, 5))
#: Initial gravity: the camera's y axis (down in an OpenCV camera).
GRAVITY_START = (0.0, 1.0, 0.0)
#: Below this angle (degrees) between gravity and the camera's y axis the release keeps the
#: camera frame for the height (its ``getRMatrix`` returns the identity).
MIN_ROTATION_DEG = 0.1


@dataclass(frozen=True)
class HHA:
    """The HHA channels before quantisation (float64, NaN where depth is invalid).

    Attributes:
        disparity: ``31000 / max(z_cm, 100)``.
        height: height above the estimated floor, centimetres.
        angle: angle between normal and gravity, degrees (180 where no normal could be fitted,
            as the release's clamped ``acosd`` of NaN).
        gravity: the estimated gravity direction in the camera frame (unit, pointing down).
        floor_cm: the floor's height relative to the camera (``y_min``), centimetres.
    """

    disparity: np.ndarray
    height: np.ndarray
    angle: np.ndarray
    gravity: np.ndarray
    floor_cm: float

    def to_uint8(self) -> np.ndarray:
        """``(H, W, 3)`` uint8: disparity, height, angle + 38, rounded half away from zero and
        saturated to 0..255 like MATLAB's ``uint8``; 0 where depth is invalid."""
        stacked = np.stack([self.disparity, self.height, self.angle + ANGLE_OFFSET], axis=-1)
        valid = np.isfinite(stacked)
        rounded = np.floor(np.clip(np.where(valid, stacked, 0.0), 0.0, 255.0) + 0.5)
        return np.clip(rounded, 0, 255).astype(np.uint8)


def _box_sum(values: np.ndarray, radius: int) -> np.ndarray:
    """Sum over the ``(2r+1) x (2r+1)`` window around each pixel of ``values`` (H, W, C), zero
    outside the image (MATLAB's ``filter2`` with a box of ones), via an integral image."""
    k = 2 * radius + 1
    padded = np.pad(values, ((radius + 1, radius), (radius + 1, radius), (0, 0)))
    s = padded.cumsum(axis=0).cumsum(axis=1)
    return s[k:, k:] - s[:-k, k:] - s[k:, :-k] + s[:-k, :-k]


def _camera(depth_m: np.ndarray, intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Normalised image coordinates ``(x/z, y/z)`` of every pixel (0-based)."""
    h, w = depth_m.shape
    if (intrinsics.height, intrinsics.width) != (h, w):
        intrinsics = intrinsics.scaled(w, h)
    u = (np.arange(w, dtype=np.float64) - intrinsics.cx) / intrinsics.fx
    v = (np.arange(h, dtype=np.float64) - intrinsics.cy) / intrinsics.fy
    return np.broadcast_to(u[None, :], (h, w)), np.broadcast_to(v[:, None], (h, w))


def _check_depth(depth_m: np.ndarray) -> np.ndarray:
    depth = np.asarray(depth_m, dtype=np.float64)
    if depth.ndim != 2:
        raise InvalidDataError(f"HHA needs an (H, W) depth map, got shape {depth.shape}")
    if not np.all(np.isfinite(depth)) or np.any(depth < 0):
        raise InvalidDataError("HHA needs finite, non-negative depth (0 = invalid)")
    return depth


def surface_normals(depth_m: np.ndarray, intrinsics: Intrinsics, *, radius: int) -> np.ndarray:
    """Unit surface normals ``(H, W, 3)`` from a least-squares plane over each pixel's
    ``(2r+1)^2`` window of valid depth, oriented away from the camera (``n . p >= 0``); NaN where
    the window's points do not determine a plane.

    The plane ``a x + b y + c z = 1`` is fitted as ``a (x/z) + b (y/z) + c = 1/z`` (the release's
    ``computeNormalsSquareSupport``): normal equations summed over the window, solved with the
    adjugate of the symmetric 3x3 matrix, normalised.
    """
    depth = _check_depth(depth_m)
    qx, qy = _camera(depth, intrinsics)
    valid = depth > 0
    m = valid.astype(np.float64)
    inv_z = np.divide(1.0, depth, out=np.zeros_like(depth), where=valid)
    qxm, qym = qx * m, qy * m
    terms = np.stack([qxm * qx, qxm * qy, qxm, qym * qy, qym, m,
                      qxm * inv_z, qym * inv_z, inv_z], axis=-1)
    s = _box_sum(terms, radius)
    a11, a12, a13, a22, a23, a33 = (s[..., i] for i in range(6))
    b = s[..., 6:9]
    # adjugate of [[a11 a12 a13] [a12 a22 a23] [a13 a23 a33]] (= det * inverse)
    c11 = a22 * a33 - a23 * a23
    c12 = a13 * a23 - a12 * a33
    c13 = a12 * a23 - a13 * a22
    c22 = a11 * a33 - a13 * a13
    c23 = a12 * a13 - a11 * a23
    c33 = a11 * a22 - a12 * a12
    n = np.stack([c11 * b[..., 0] + c12 * b[..., 1] + c13 * b[..., 2],
                  c12 * b[..., 0] + c22 * b[..., 1] + c23 * b[..., 2],
                  c13 * b[..., 0] + c23 * b[..., 1] + c33 * b[..., 2]], axis=-1)
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        n = np.where(norm > 0, n / norm, np.nan)
    # orient: first z >= 0, then away from the camera (n . p >= 0) where p is known
    n = n * np.where(n[..., 2:3] < 0, -1.0, 1.0)
    facing = n[..., 0] * qx + n[..., 1] * qy + n[..., 2]  # n . p / z
    n = n * np.where((facing < 0) & valid, -1.0, 1.0)[..., None]
    return n


def gravity_direction(normals: np.ndarray) -> np.ndarray:
    """The gravity direction (unit 3-vector in the camera frame, pointing down) most parallel
    to the floor-like and most perpendicular to the wall-like ``normals`` (H, W, 3; NaN
    ignored), by the release's ``getYDir`` rounds (:data:`GRAVITY_ROUNDS`)."""
    flat = normals.reshape(-1, 3)
    n = np.ascontiguousarray(flat[np.isfinite(flat).all(axis=1)].T)  # (3, N)
    g = np.asarray(GRAVITY_START, dtype=np.float64)
    if n.shape[1] == 0:
        return g
    for threshold_deg, iterations in GRAVITY_ROUNDS:
        t = np.deg2rad(threshold_deg)
        for _ in range(iterations):
            sim = np.abs(g @ n)
            # +1 for a wall normal, -1 for a floor normal: sum_wall n n^T - sum_floor n n^T
            weight = (sim < np.sin(t)).astype(np.float64) - (sim > np.cos(t))
            a = (n * weight) @ n.T
            _, vectors = np.linalg.eigh(a)
            new = vectors[:, 0]  # eigh sorts eigenvalues ascending
            g = new * (1.0 if float(new @ g) >= 0 else -1.0)
    return g / np.linalg.norm(g)


def hha_channels(depth_m: np.ndarray, intrinsics: Intrinsics) -> HHA:
    """The HHA channels of ``depth_m`` (metres, 0 = invalid) before quantisation."""
    depth = _check_depth(depth_m)
    valid = depth > 0
    z_cm = depth * 100.0
    qx, qy = _camera(depth, intrinsics)
    normals = surface_normals(depth, intrinsics, radius=NORMAL_RADIUS)
    gravity = gravity_direction(surface_normals(depth, intrinsics,
                                                radius=GRAVITY_NORMAL_RADIUS))
    nan = np.full(depth.shape, np.nan)
    # angle: the release clamps the cosine with MATLAB's min/max, which drop NaN: no normal
    # -> cos = -1 -> 180 degrees
    cos = np.clip(np.nan_to_num(normals @ gravity, nan=-1.0), -1.0, 1.0)
    angle = np.where(valid, np.degrees(np.arccos(cos)), nan)
    # height: -(R^T p)_y with R rotating the camera's y axis onto gravity, i.e. -(g . p)
    start = np.asarray(GRAVITY_START)
    tilt = np.degrees(np.arccos(np.clip(float(start @ gravity), -1.0, 1.0)))
    up_axis = gravity if tilt > MIN_ROTATION_DEG else start
    height = -(up_axis[0] * qx + up_axis[1] * qy + up_axis[2]) * z_cm
    floor_cm = float(height[valid].min()) if valid.any() else FLOOR_DEFAULT_CM
    if floor_cm > FLOOR_SEARCH_CM:
        floor_cm = FLOOR_DEFAULT_CM
    height = np.where(valid, height - floor_cm, nan)
    with np.errstate(divide="ignore"):
        disparity = np.where(valid, DISPARITY_SCALE / np.maximum(z_cm, MIN_DEPTH_CM), nan)
    return HHA(disparity=disparity, height=height, angle=angle, gravity=gravity,
               floor_cm=floor_cm)


def encode_hha(depth_m: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """HHA of a depth map: ``(H, W, 3)`` uint8 (disparity, height above ground, angle with
    gravity), 0 where depth is invalid (see the module notes).

    Args:
        depth_m: ``(H, W)`` depth in metres, 0 = invalid.
        intrinsics: the camera (scaled to the depth map's size when it differs).

    Raises:
        InvalidDataError: depth that is not a finite, non-negative (H, W) map.
    """
    return hha_channels(depth_m, intrinsics).to_uint8()

