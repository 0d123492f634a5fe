"""A camera-to-world matrix read from a dataset, checked and made a rigid transform: the one
place the readers that take 4x4 matrices from files (7-Scenes, ScanNet) judge them."""

from __future__ import annotations

import numpy as np

from evsmap.data import MAX_TRANSLATION_M
from evsmap.errors import DataFormatError


def checked_pose(pose: np.ndarray, where: str, *, tolerance: float) -> np.ndarray:
    """``pose`` (4x4) as a ``float64`` camera-to-world matrix with its rotation block made
    orthonormal; every problem is a one-line :class:`DataFormatError` starting with ``where``.

    Trackers write matrices that are not quite rotations (KinectFusion's in 7-Scenes are
    1e-4 off, float32 matrices 1e-7): a rotation block within ``tolerance`` of a rotation
    (``|R R^T - I|``, ``det R > 0``) is replaced by the nearest rotation (polar decomposition,
    ``U V^T`` of its SVD) and the translation kept as written. Non-finite entries (ScanNet
    writes -inf for a frame its tracking lost), a last row other than ``0 0 0 1``, a
    translation beyond :data:`~evsmap.data.MAX_TRANSLATION_M` and a block further from a
    rotation are refused.
    """
    pose = np.array(pose, dtype=np.float64).reshape(4, 4)
    if not np.all(np.isfinite(pose)):
        bad = int((~np.isfinite(pose)).sum())
        raise DataFormatError(f"{where}: non-finite pose ({bad} of 16 entries are nan/inf)")
    if not np.allclose(pose[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise DataFormatError(f"{where}: pose last row must be [0 0 0 1], got {pose[3].tolist()}")
    if np.abs(pose[:3, 3]).max() > MAX_TRANSLATION_M:
        raise DataFormatError(f"{where}: pose translation {pose[:3, 3].tolist()} is beyond "
                              f"{MAX_TRANSLATION_M:.0e} m from the origin")
    rot = pose[:3, :3]
    with np.errstate(all="ignore"):  # huge entries overflow to inf: refused just below
        err = float(np.abs(rot @ rot.T - np.eye(3)).max())
        det = float(np.linalg.det(rot))
    if not err <= tolerance or not det > 0:
        raise DataFormatError(
            f"{where}: pose rotation block is not a rotation (|R R^T - I| = {err:.2e}, "
            f"det {det:.4f}; tolerance {tolerance:g})")
    u, _, vt = np.linalg.svd(rot)
    pose[:3, :3] = u @ vt  # det R > 0, so U V^T is a proper rotation
    pose[3] = (0.0, 0.0, 0.0, 1.0)
    return pose


__all__ = ["checked_pose"]
