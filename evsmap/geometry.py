"""Rigid-body helpers: quaternions (TUM order qx qy qz qw), slerp, pose interpolation,
back-projection. All functions are vectorised over leading dimensions.

Quaternion and rotation-matrix conversions and slerp go through
:class:`scipy.spatial.transform.Rotation` (imported on first use, so importing this module stays
light); this module fixes the conventions around it: TUM's scalar-last order, ``w >= 0`` for
quaternions made from matrices, slerp along the shortest arc on the first quaternion's side, and
invalid input (zero or non-finite quaternions, matrices that are not rotations) as
:class:`~evsmap.errors.InvalidDataError`.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from evsmap.errors import InvalidDataError


def _rotations(quats: np.ndarray) -> Any:
    """A :class:`~scipy.spatial.transform.Rotation` stack from (N, 4) quaternions (x, y, z, w),
    normalised; zero or non-finite quaternions raise :class:`InvalidDataError`."""
    from scipy.spatial.transform import Rotation

    if not np.all(np.isfinite(quats)):
        raise InvalidDataError("quaternion with a non-finite component")
    try:
        return Rotation.from_quat(quats)
    except ValueError as exc:  # zero norm
        raise InvalidDataError(f"invalid quaternion: {exc}") from None


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from quaternions (..., 4) in (x, y, z, w) order.

    The quaternions are normalised first; a zero or non-finite one raises
    :class:`InvalidDataError`.
    """
    q = np.asarray(q, dtype=np.float64)
    flat = q.reshape(-1, 4)
    if not len(flat):
        return np.zeros(q.shape[:-1] + (3, 3))
    return _rotations(flat).as_matrix().reshape(q.shape[:-1] + (3, 3))


def matrix_to_quat(r: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) in (x, y, z, w) order with w >= 0 from rotation matrices (..., 3, 3).

    Each matrix is taken to its nearest rotation first (rounded input is fine). Of the two
    quaternions of a rotation the one with ``w > 0`` is returned; for a half turn (``w = 0``) the
    one whose first non-zero component is positive. A matrix with a non-finite entry or a
    non-positive determinant (a reflection) raises :class:`InvalidDataError`.
    """
    from scipy.spatial.transform import Rotation

    r = np.asarray(r, dtype=np.float64)
    flat = r.reshape(-1, 3, 3)
    if not len(flat):
        return np.zeros(r.shape[:-2] + (4,))
    if not np.all(np.isfinite(flat)):
        raise InvalidDataError("rotation matrix with a non-finite entry")
    try:
        rot = Rotation.from_matrix(flat)
    except ValueError as exc:  # a reflection or a degenerate matrix
        raise InvalidDataError(f"not a rotation matrix: {exc}".splitlines()[0]) from None
    return rot.as_quat(canonical=True).reshape(r.shape[:-2] + (4,))


def slerp(q0: np.ndarray, q1: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation between quaternions (x, y, z, w), shortest arc.

    ``q0``, ``q1`` are (..., 4) (normalised here), ``t`` broadcasts against their leading
    dimensions. The result is unit length and on ``q0``'s side: t=0 gives ``q0`` (normalised),
    t=1 the one of ``q1`` and ``-q1`` nearer to ``q0``.
    """
    from scipy.spatial.transform import Rotation

    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    lead = np.broadcast_shapes(q0.shape[:-1], q1.shape[:-1], t.shape)
    a = np.broadcast_to(q0, lead + (4,)).reshape(-1, 4)
    b = np.broadcast_to(q1, lead + (4,)).reshape(-1, 4)
    if not len(a):
        return np.zeros(lead + (4,))
    start = _rotations(a)
    # the relative rotation's vector has angle <= pi: the shortest arc whatever b's sign
    step = (start.inv() * _rotations(b)).as_rotvec()
    frac = np.broadcast_to(t, lead).reshape(-1, 1)
    return (start * Rotation.from_rotvec(frac * step)).as_quat().reshape(lead + (4,))


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


class Pinhole(Protocol):
    """What :func:`backproject` reads of a camera, in pixels (:class:`evsmap.data.Intrinsics` is
    one; this module does not import the data model, which builds on it)."""

    @property
    def fx(self) -> float: ...
    @property
    def fy(self) -> float: ...
    @property
    def cx(self) -> float: ...
    @property
    def cy(self) -> float: ...


def backproject(depth: np.ndarray, intrinsics: Pinhole, pose: np.ndarray | None = None,
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


def look_at(eye: np.ndarray, target: np.ndarray,
            up: npt.ArrayLike = (0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera-to-world rotation (3x3) of an OpenCV camera at ``eye`` looking at ``target``
    (z forward, x right, y down), with ``up`` the world's up direction."""
    eye = np.asarray(eye, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.asarray(up, dtype=np.float64))
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    return np.stack([right, down, forward], axis=1)
