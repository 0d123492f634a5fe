"""Rigid-body helpers: quaternions (TUM order qx qy qz qw), slerp, pose interpolation,
back-projection. All functions are vectorised over leading dimensions."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # the data model builds on this module, not the other way round
    from evsmap.data import Intrinsics


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from quaternions (..., 4) in (x, y, z, w) order.

    The quaternions are normalised first.
    """
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = np.moveaxis(q, -1, 0)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    m = np.stack(
        [
            1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy),
            2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx),
            2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy),
        ],
        axis=-1,
    )
    return m.reshape(q.shape[:-1] + (3, 3))


def matrix_to_quat(r: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) in (x, y, z, w) order with w >= 0 from rotation matrices (..., 3, 3).

    Uses the largest-diagonal branch per matrix for numerical stability (Shepperd's method).
    """
    r = np.asarray(r, dtype=np.float64)
    flat = r.reshape(-1, 3, 3)
    m00, m11, m22 = flat[:, 0, 0], flat[:, 1, 1], flat[:, 2, 2]
    trace = m00 + m11 + m22
    cand = np.stack([trace, m00, m11, m22], axis=1)
    branch = np.argmax(cand, axis=1)
    q = np.empty((flat.shape[0], 4))
    # branch 0: w largest
    s = np.sqrt(np.maximum(1.0 + trace, 1e-300)) * 2
    q0 = np.stack([(flat[:, 2, 1] - flat[:, 1, 2]) / s, (flat[:, 0, 2] - flat[:, 2, 0]) / s,
                   (flat[:, 1, 0] - flat[:, 0, 1]) / s, 0.25 * s], axis=1)
    s = np.sqrt(np.maximum(1.0 + m00 - m11 - m22, 1e-300)) * 2
    q1 = np.stack([0.25 * s, (flat[:, 0, 1] + flat[:, 1, 0]) / s,
                   (flat[:, 0, 2] + flat[:, 2, 0]) / s,
                   (flat[:, 2, 1] - flat[:, 1, 2]) / s], axis=1)
    s = np.sqrt(np.maximum(1.0 + m11 - m00 - m22, 1e-300)) * 2
    q2 = np.stack([(flat[:, 0, 1] + flat[:, 1, 0]) / s, 0.25 * s,
                   (flat[:, 1, 2] + flat[:, 2, 1]) / s,
                   (flat[:, 0, 2] - flat[:, 2, 0]) / s], axis=1)
    s = np.sqrt(np.maximum(1.0 + m22 - m00 - m11, 1e-300)) * 2
    q3 = np.stack([(flat[:, 0, 2] + flat[:, 2, 0]) / s, (flat[:, 1, 2] + flat[:, 2, 1]) / s,
                   0.25 * s, (flat[:, 1, 0] - flat[:, 0, 1]) / s], axis=1)
    allq = np.stack([q0, q1, q2, q3], axis=1)
    q = allq[np.arange(flat.shape[0]), branch]
    q *= np.where(q[:, 3:4] < 0, -1.0, 1.0)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return q.reshape(r.shape[:-2] + (4,))


def slerp(q0: np.ndarray, q1: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation between unit quaternions (x, y, z, w), shortest arc.

    ``q0``, ``q1`` are (..., 4), ``t`` broadcasts against their leading dimensions; t=0 gives q0.
    """
    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    q0 = q0 / np.linalg.norm(q0, axis=-1, keepdims=True)
    q1 = q1 / np.linalg.norm(q1, axis=-1, keepdims=True)
    t = np.asarray(t, dtype=np.float64)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin = np.sin(theta)
    near = sin < 1e-9
    safe = np.where(near, 1.0, sin)
    w0 = np.where(near, 1.0 - t, np.sin((1.0 - t) * theta) / safe)
    w1 = np.where(near, t, np.sin(t * theta) / safe)
    out = w0 * q0 + w1 * q1
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def pose_matrix(translation: np.ndarray, quat: np.ndarray) -> np.ndarray:
    """4x4 (or ...x4x4) transforms from translations (..., 3) and quaternions (..., 4)."""
    translation = np.asarray(translation, dtype=np.float64)
    rot = quat_to_matrix(quat)
    out = np.zeros(rot.shape[:-2] + (4, 4))
    out[..., :3, :3] = rot
    out[..., :3, 3] = translation
    out[..., 3, 3] = 1.0
    return out


def interpolate_poses(
    times: np.ndarray, translations: np.ndarray, quats: np.ndarray, query: np.ndarray
) -> np.ndarray:
    """Poses at ``query`` times: linear in translation, slerp in rotation.

    ``times`` must be strictly increasing and every query inside ``[times[0], times[-1]]``. A query
    equal to a sample time returns that sample's pose exactly.

    Returns:
        float64 array (len(query), 4, 4).
    """
    times = np.asarray(times, dtype=np.float64)
    query = np.asarray(query, dtype=np.float64)
    hi = np.clip(np.searchsorted(times, query, side="left"), 1, len(times) - 1) if len(times) > 1 \
        else np.zeros(len(query), dtype=np.int64)
    lo = np.maximum(hi - 1, 0)
    exact = times[hi] == query
    lo = np.where(exact, hi, lo)
    span = times[hi] - times[lo]
    alpha = np.where(span > 0, (query - times[lo]) / np.where(span > 0, span, 1.0), 0.0)
    trans = translations[lo] + alpha[:, None] * (translations[hi] - translations[lo])
    quat = slerp(quats[lo], quats[hi], alpha)
    # keep sample poses bit-exact (no arithmetic on them)
    trans = np.where(exact[:, None], translations[hi], trans)
    quat = np.where(exact[:, None], quats[hi], quat)
    return pose_matrix(trans, quat)


def backproject(depth: np.ndarray, intrinsics: Intrinsics, pose: np.ndarray | None = None,
                mask: np.ndarray | None = None) -> np.ndarray:
    """3D points (N x 3, float64) of the valid depth pixels, in the camera frame or, with
    ``pose`` (camera-to-world), in the world frame. Row-major pixel order."""
    valid = depth > 0 if mask is None else mask & (depth > 0)
    v, u = np.nonzero(valid)
    z = depth[v, u].astype(np.float64)
    x = (u - intrinsics.cx) / intrinsics.fx * z
    y = (v - intrinsics.cy) / intrinsics.fy * z
    if pose is None:
        return np.stack([x, y, z], axis=1)
    return _rigid(pose, x, y, z)


def _rigid(pose: np.ndarray, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    # rotate axis by axis: an (N, 3) @ (3, 3) product goes through BLAS, whose thread start-up
    # dominates (and stalls under load) for such a thin matrix
    r, t = pose[:3, :3], pose[:3, 3]
    return np.stack([r[i, 0] * x + r[i, 1] * y + r[i, 2] * z + t[i] for i in range(3)], axis=1)


def transform_points(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """``pose`` (4x4) applied to (N, 3) points, as float64."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return _rigid(np.asarray(pose, dtype=np.float64), p[:, 0], p[:, 1], p[:, 2])


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera-to-world rotation (3x3) of an OpenCV camera at ``eye`` looking at ``target``
    (z forward, x right, y down), with ``up`` the world's up direction."""
    eye = np.asarray(eye, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.asarray(up, dtype=np.float64))
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    return np.stack([right, down, forward], axis=1)
