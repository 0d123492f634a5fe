"""A ScanNet scene's labelled mesh (``<scene>_vh_clean_2.labels.ply``) and its voxelisation,
the scene's 3D ground truth.

The file (ScanNet's README, "Data Organization") is the cleaned, decimated annotation mesh, a
binary PLY whose vertices carry ``x y z`` (metres, the frame the ``.sens`` poses are in),
``red green blue alpha`` and ``label``, the NYU40 id of the vertex's annotated object (0:
unannotated), and whose faces are vertex index triangles. It is read with ``plyfile``; ASCII
PLY and double coordinates are read too.

Voxelisation (:func:`voxelise`): every triangle is sampled on a barycentric lattice no coarser
than a third of the voxel edge, each sample carrying the triangle's area over its sample count
and the label of the triangle's vertex nearest to it (largest barycentric weight). A voxel the
surface passes through is occupied; its class is the label with most surface area in it, ties
to the lower id; a voxel whose surface is mostly unannotated is :data:`~evsmap.data.VOID` (it
counts for geometry, not for the semantic scores). Keys are OctoMap's without the 2^15 offset,
``floor(coordinate / resolution)``, as the synthetic rooms' ground truth.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evsmap.classes import NYU40_CLASSES
from evsmap.data import MAX_TRANSLATION_M, VOID, VoxelLabels
from evsmap.errors import DataFormatError, InvalidDataError

NYU40_UNANNOTATED = 0
"""The NYU40 id ScanNet writes for an unannotated vertex."""
MAX_ELEMENTS = 1 << 28
"""Most vertices or faces accepted (ScanNet's annotation meshes hold about 10^5)."""
MAX_SAMPLES = 2e8
"""Most surface samples one voxelisation makes (a ScanNet scene at 2 cm takes a few million)."""
SAMPLES_PER_EDGE = 3
"""Lattice points per voxel edge along a triangle's longest side (spacing <= resolution / 3)."""


@dataclass(frozen=True)
class LabelMesh:
    """A triangle mesh with a class per vertex.

    Attributes:
        vertices: ``float64`` (N, 3), metres.
        classes: ``uint8`` (N,), 0-based NYU40 class ids (NYU40 id - 1), :data:`VOID` for
            unannotated vertices.
        faces: ``int64`` (M, 3) vertex indices.
    """

    vertices: np.ndarray
    classes: np.ndarray
    faces: np.ndarray

    @property
    def area(self) -> float:
        """Total surface area, square metres."""
        return float(_areas(self.vertices, self.faces).sum())


def nyu40_classes(ids: np.ndarray, where: str) -> np.ndarray:
    """NYU40 ids (0 unannotated, 1..40) as 0-based class ids (``uint8``; 0 -> :data:`VOID`)."""
    ids = np.asarray(ids).astype(np.int64)
    bad = (ids < 0) | (ids > len(NYU40_CLASSES))
    if bad.any():
        raise DataFormatError(f"{where}: label {int(ids[bad][0])} is not an NYU40 id (0 "
                              f"unannotated, 1..{len(NYU40_CLASSES)})")
    return np.where(ids == NYU40_UNANNOTATED, VOID, ids - 1).astype(np.uint8)


def read_label_mesh(path: str | os.PathLike[str]) -> LabelMesh:
    """The mesh and vertex labels of a ``*_vh_clean_2.labels.ply``.

    Raises:
        DataFormatError: an unreadable or malformed PLY, no ``vertex``/``face`` element, no
            ``x y z``/``label`` property, a face that is not a triangle or names a vertex that
            is not there, a label that is not an NYU40 id, non-finite coordinates.
    """
    from plyfile import PlyData, PlyParseError

    path = Path(path)
    if not path.is_file():
        raise DataFormatError(f"{path}: file not found")
    try:
        with open(path, "rb") as f:
            ply = PlyData.read(f, known_list_len={"face": {"vertex_indices": 3}})
    except PlyParseError as exc:
        raise DataFormatError(f"{path}: not a readable PLY ({_one_line(exc)})") from None
    except (ValueError, TypeError, IndexError, KeyError, EOFError, MemoryError, OSError,
            UnicodeDecodeError, OverflowError) as exc:
        raise DataFormatError(f"{path}: not a readable PLY ({_one_line(exc)})") from None
    names = [e.name for e in ply.elements]
    for need in ("vertex", "face"):
        if need not in names:
            raise DataFormatError(f"{path}: no '{need}' element (it holds {', '.join(names)})")
    vertex, face = ply["vertex"], ply["face"]
    props = vertex.data.dtype.names or ()
    for need in ("x", "y", "z", "label"):
        if need not in props:
            raise DataFormatError(f"{path}: vertices have no '{need}' property (they have "
                                  f"{', '.join(props)}); the labelled mesh is "
                                  f"<scene>_vh_clean_2.labels.ply")
    if "vertex_indices" not in (face.data.dtype.names or ()):
        raise DataFormatError(f"{path}: faces have no 'vertex_indices' list")
    if len(vertex.data) > MAX_ELEMENTS or len(face.data) > MAX_ELEMENTS:
        raise DataFormatError(f"{path}: more than {MAX_ELEMENTS} vertices or faces")
    xyz = np.stack([np.asarray(vertex.data[k], dtype=np.float64) for k in "xyz"], axis=1)
    if not np.all(np.isfinite(xyz)):
        raise DataFormatError(f"{path}: non-finite vertex coordinates")
    if xyz.size and np.abs(xyz).max() > MAX_TRANSLATION_M:
        raise DataFormatError(f"{path}: a vertex lies beyond {MAX_TRANSLATION_M:.0e} m of the "
                              f"origin")
    faces = _triangles(face.data["vertex_indices"], len(xyz), path)
    return LabelMesh(xyz, nyu40_classes(vertex.data["label"], str(path)), faces)


def _triangles(lists: np.ndarray, vertices: int, path: Path) -> np.ndarray:
    """The face lists as an (M, 3) ``int64`` array, checked."""
    if lists.dtype != object and lists.ndim == 2:  # plyfile's fixed-length read
        faces = lists.astype(np.int64)
    else:
        sizes = np.fromiter((len(x) for x in lists), dtype=np.int64, count=len(lists))
        if np.any(sizes != 3):
            raise DataFormatError(f"{path}: face {int(np.flatnonzero(sizes != 3)[0])} has "
                                  f"{int(sizes[sizes != 3][0])} vertices (triangles only)")
        faces = (np.stack([np.asarray(x, dtype=np.int64) for x in lists]) if len(lists)
                 else np.zeros((0, 3), np.int64))
    faces = faces.reshape(-1, 3)
    if faces.size and (faces.min() < 0 or faces.max() >= vertices):
        bad = int(np.flatnonzero((faces < 0).any(axis=1) | (faces >= vertices).any(axis=1))[0])
        raise DataFormatError(f"{path}: face {bad} names vertex {faces[bad].tolist()}, the "
                              f"mesh has {vertices} vertices")
    return faces


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())[:200] or type(exc).__name__


def _areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


def _lattice(n: int) -> np.ndarray:
    """Barycentric weights (P, 3) of the lattice ``(i/n, j/n, 1 - i/n - j/n)``, i + j <= n."""
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    keep = i + j <= n
    u, v = i[keep] / n, j[keep] / n
    return np.stack([u, v, 1.0 - u - v], axis=1)


def surface_samples(mesh: LabelMesh, spacing: float
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points on every triangle no further apart than ``spacing`` along its sides, with each
    point's area weight and class (:mod:`module notes <evsmap.readers.scannet.mesh>`); yields
    groups of triangles with the same lattice so that no Python loop runs per triangle."""
    v, f = mesh.vertices, mesh.faces
    if not len(f):
        return np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.uint8)
    corners = v[f]  # (M, 3, 3)
    longest = np.max(np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2), axis=1)
    steps = np.maximum(np.ceil(np.minimum(longest / spacing, 1e9)).astype(np.int64), 1)
    total = float(np.sum((steps + 1.0) * (steps + 2.0) / 2.0))
    if total > MAX_SAMPLES:
        raise DataFormatError(f"the mesh needs {total:.3g} surface samples at {spacing:g} m "
                              f"spacing (at most {MAX_SAMPLES:.0e}): its triangles are too "
                              f"large for this voxel size")
    areas = _areas(v, f)
    points, weights, classes = [], [], []
    for n in np.unique(steps):
        group = np.flatnonzero(steps == n)
        bary = _lattice(int(n))  # (P, 3)
        pts = np.einsum("pk,mkd->mpd", bary, corners[group]).reshape(-1, 3)
        nearest = np.argmax(bary, axis=1)  # the vertex each lattice point is closest to
        cls = mesh.classes[f[group][:, nearest]].reshape(-1)
        points.append(pts)
        weights.append(np.repeat(areas[group] / len(bary), len(bary)))
        classes.append(cls)
    return np.concatenate(points), np.concatenate(weights), np.concatenate(classes)


def voxelise(mesh: LabelMesh, resolution: float) -> VoxelLabels:
    """The voxels at ``resolution`` metres the mesh's surface passes through, each with the
    class holding most of its surface area (:mod:`module notes <evsmap.readers.scannet.mesh>`)."""
    if not (np.isfinite(resolution) and resolution > 0):
        raise DataFormatError(f"voxel size must be a positive number of metres, got "
                              f"{resolution!r}")
    points, weights, classes = surface_samples(mesh, resolution / SAMPLES_PER_EDGE)
    try:  # per voxel the class of most area (ties: the lower id; void ranks last at 255)
        return VoxelLabels.by_vote(points, classes, float(resolution), weights)
    except InvalidDataError as exc:
        raise DataFormatError(f"mesh: {exc}") from None


__all__ = ["LabelMesh", "NYU40_UNANNOTATED", "nyu40_classes", "read_label_mesh",
           "surface_samples", "voxelise"]
