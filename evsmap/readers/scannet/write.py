"""Writing ScanNet's formats: a ``.sens`` stream, a labelled-mesh PLY, the label table and a
split file, byte for byte as :mod:`~evsmap.readers.scannet.sens`,
:mod:`~evsmap.readers.scannet.mesh` and :mod:`~evsmap.readers.scannet.labelmap` describe them.
The tests build small scenes in the official layout with these; a user can write a recording
of their own as a ScanNet scene the same way."""

from __future__ import annotations

import io
import os
import struct
import zlib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evsmap.readers.scannet.sens import COLOR_COMPRESSION, DEPTH_COMPRESSION, FRAME_HEADER, VERSION


@dataclass(frozen=True)
class SensFrame:
    """One frame to write: colour (``uint8`` HxWx3), depth (``uint16`` HxW, depth-shift units),
    camera-to-world pose (4x4; -inf entries mark a lost frame) and time stamps (microseconds)."""

    color: np.ndarray
    depth: np.ndarray
    pose: np.ndarray
    timestamp_color: int = 0
    timestamp_depth: int = 0


def _code(table: dict[int, str], name: str) -> int:
    return next(k for k, v in table.items() if v == name)


def _encode_color(rgb: np.ndarray, kind: str) -> bytes:
    if kind == "raw":
        return np.ascontiguousarray(rgb, dtype=np.uint8).tobytes()
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb, dtype=np.uint8)).save(
        buf, format="JPEG" if kind == "jpeg" else "PNG", quality=95)
    return buf.getvalue()


def _encode_depth(depth: np.ndarray, kind: str) -> bytes:
    raw = np.ascontiguousarray(depth, dtype="<u2").tobytes()
    return zlib.compress(raw) if kind == "zlib_ushort" else raw


def write_sens(path: str | os.PathLike[str], frames: Iterable[SensFrame], *,
               intrinsic_color: np.ndarray, intrinsic_depth: np.ndarray,
               color_size: tuple[int, int], depth_size: tuple[int, int],
               depth_shift: float = 1000.0, sensor_name: str = "StructureSensor",
               color_compression: str = "jpeg", depth_compression: str = "zlib_ushort",
               extrinsic_color: np.ndarray | None = None,
               extrinsic_depth: np.ndarray | None = None) -> int:
    """Write a version-4 ``.sens`` file (no IMU frames); returns the number of frames.

    Args:
        intrinsic_color, intrinsic_depth: 4x4 (or 3x3, padded) camera matrices.
        color_size, depth_size: (width, height).
        color_compression: ``jpeg``, ``png`` or ``raw``; depth_compression ``zlib_ushort`` or
            ``raw_ushort``.
    """
    frames = list(frames)

    def mat(m: np.ndarray | None) -> list[float]:
        out = np.eye(4)
        if m is not None:
            m = np.asarray(m, dtype=np.float64)
            out[:m.shape[0], :m.shape[1]] = m
        return out.astype(np.float32).ravel().tolist()

    name = sensor_name.encode()
    with open(path, "wb") as f:
        f.write(struct.pack("<I", VERSION))
        f.write(struct.pack("<Q", len(name)) + name)
        f.write(struct.pack("<64f", *mat(intrinsic_color), *mat(extrinsic_color),
                            *mat(intrinsic_depth), *mat(extrinsic_depth)))
        f.write(struct.pack("<2i", _code(COLOR_COMPRESSION, color_compression),
                            _code(DEPTH_COMPRESSION, depth_compression)))
        f.write(struct.pack("<4I", *color_size, *depth_size))
        f.write(struct.pack("<f", depth_shift))
        f.write(struct.pack("<Q", len(frames)))
        for fr in frames:
            color = _encode_color(fr.color, color_compression)
            depth = _encode_depth(fr.depth, depth_compression)
            pose = np.asarray(fr.pose, dtype=np.float32).ravel().tolist()
            f.write(FRAME_HEADER.pack(*pose, int(fr.timestamp_color), int(fr.timestamp_depth),
                                      len(color), len(depth)))
            f.write(color)
            f.write(depth)
        f.write(struct.pack("<Q", 0))  # no IMU frames
    return len(frames)


def write_label_ply(path: str | os.PathLike[str], vertices: np.ndarray, nyu40_ids: np.ndarray,
                    faces: np.ndarray, *, binary: bool = True) -> None:
    """A ``*_vh_clean_2.labels.ply``: vertices ``x y z`` (float), ``red green blue alpha``
    (uchar), ``label`` (ushort NYU40 id); faces ``vertex_indices`` (uchar count, int)."""
    from plyfile import PlyData, PlyElement

    v = np.asarray(vertices, dtype=np.float32)
    ids = np.asarray(nyu40_ids, dtype=np.uint16)
    vdata = np.empty(len(v), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"),
                                     ("green", "u1"), ("blue", "u1"), ("alpha", "u1"),
                                     ("label", "u2")])
    for k, axis in enumerate("xyz"):
        vdata[axis] = v[:, k]
    from evsmap.classes import palette

    colours = palette(41)[np.minimum(ids, 40)]
    vdata["red"], vdata["green"], vdata["blue"] = colours[:, 0], colours[:, 1], colours[:, 2]
    vdata["alpha"] = 255
    vdata["label"] = ids
    fdata = np.empty(len(faces), dtype=[("vertex_indices", "i4", (3,))])
    fdata["vertex_indices"] = np.asarray(faces, dtype=np.int32).reshape(-1, 3)
    ply = PlyData([PlyElement.describe(vdata, "vertex"),
                   PlyElement.describe(fdata, "face", len_types={"vertex_indices": "u1"},
                                       val_types={"vertex_indices": "i4"})],
                  text=not binary, byte_order="<")
    ply.write(str(path))


def write_label_table(path: str | os.PathLike[str], rows: Sequence[tuple[int, str, int]]) -> None:
    """A ``scannetv2-labels.combined.tsv`` with ScanNet's first columns: ``id``,
    ``raw_category``, ``category``, ``count``, ``nyu40id``, ``eigen13id``, ``nyuClass``,
    ``nyu40class`` (rows: id, raw category, nyu40id)."""
    from evsmap.classes import NYU40_CLASSES

    header = ["id", "raw_category", "category", "count", "nyu40id", "eigen13id", "nyuClass",
              "nyu40class"]
    lines = ["\t".join(header)]
    for label_id, raw, nyu in rows:
        name = NYU40_CLASSES[nyu - 1] if 1 <= nyu <= 40 else ""
        lines.append("\t".join([str(label_id), raw, raw, "1", str(nyu), "0", name, name]))
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


def write_split(path: str | os.PathLike[str], scenes: Iterable[str]) -> None:
    """An official split file: one scene id a line."""
    Path(path).write_text("".join(f"{s}\n" for s in scenes), encoding="utf-8")


__all__ = ["SensFrame", "write_label_ply", "write_label_table", "write_sens", "write_split"]
