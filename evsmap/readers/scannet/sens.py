"""ScanNet's ``.sens`` RGB-D stream (version 4): header, frame index, frame decoding.

Written from the format as ScanNet's SensReader defines it (``SensReader/c++/src/sensorData.h``,
``SensorData::loadFromFile``; ``SensReader/python/SensorData.py``), all little-endian:

header
    ``uint32`` version (4), ``uint64`` n and n bytes of sensor name; the colour camera's
    calibration then the depth camera's, each a 4x4 ``float32`` intrinsic and a 4x4 ``float32``
    extrinsic matrix (row-major); ``int32`` colour compression (-1 unknown, 0 raw, 1 png,
    2 jpeg); ``int32`` depth compression (-1 unknown, 0 raw ``uint16``, 1 zlib ``uint16``,
    2 occi); ``uint32`` colour width, height, depth width, height; ``float32`` depth shift
    (depth value per metre, 1000 in ScanNet); ``uint64`` frame count.
frame
    4x4 ``float32`` camera-to-world pose (all entries -inf where tracking was lost);
    ``uint64`` colour and depth time stamps (microseconds; the capture app multiplies seconds
    by 10^6); ``uint64`` colour and depth byte counts; the colour bytes; the depth bytes.
after the frames
    ``uint64`` IMU frame count and the IMU frames (not read here).

:class:`SensFile` reads the header and walks the frame headers once (seeking over the images),
so opening a 2 GB scan costs a few milliseconds a thousand frames; a frame's images are read
and decoded when asked for. Everything wrong with the bytes is a one-line
:class:`~evsmap.errors.DataFormatError` naming the file (and the frame).
"""

from __future__ import annotations

import io
import os
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from evsmap.errors import DataFormatError

VERSION = 4
COLOR_COMPRESSION = {-1: "unknown", 0: "raw", 1: "png", 2: "jpeg"}
DEPTH_COMPRESSION = {-1: "unknown", 0: "raw_ushort", 1: "zlib_ushort", 2: "occi_ushort"}
READ_COLOR = ("raw", "png", "jpeg")
READ_DEPTH = ("raw_ushort", "zlib_ushort")
MAX_NAME_BYTES = 1 << 16
"""Longest sensor name accepted (ScanNet's are a few dozen bytes)."""
MAX_IMAGE_SIDE = 1 << 15
DEPTH_SHIFT_RANGE = (1.0, 1e6)
"""Stored depth values per metre accepted (ScanNet 1000, TUM 5000): below 1 a 16-bit value
would stand for kilometres, above 10^6 for less than a micrometre."""
FRAME_HEADER = struct.Struct("<16f4Q")
"""A frame's fixed part: pose (16 ``float32``), colour and depth stamps, colour and depth sizes."""
_HEAD = struct.Struct("<I")
_CAMERAS = struct.Struct("<64f2i4If")


@dataclass(frozen=True)
class SensHeader:
    """The fixed part of a ``.sens`` file.

    Attributes:
        sensor_name: the capture device ScanNet names (e.g. ``StructureSensor``).
        intrinsic_color, extrinsic_color, intrinsic_depth, extrinsic_depth: 4x4 ``float64``.
        color_compression, depth_compression: names from :data:`COLOR_COMPRESSION` and
            :data:`DEPTH_COMPRESSION`.
        color_size, depth_size: (width, height) of the images.
        depth_shift: stored depth value per metre.
        frames: the frame count the header states.
    """

    sensor_name: str
    intrinsic_color: np.ndarray = field(repr=False)
    extrinsic_color: np.ndarray = field(repr=False)
    intrinsic_depth: np.ndarray = field(repr=False)
    extrinsic_depth: np.ndarray = field(repr=False)
    color_compression: str
    depth_compression: str
    color_size: tuple[int, int]
    depth_size: tuple[int, int]
    depth_shift: float
    frames: int


@dataclass(frozen=True)
class SensFrameEntry:
    """Where one frame lies in the file, and its fixed fields."""

    pose: np.ndarray = field(repr=False)  # 4x4 float32 as stored
    timestamp_color: int
    timestamp_depth: int
    color_offset: int
    color_bytes: int
    depth_offset: int
    depth_bytes: int


def _read_exact(f: io.BufferedReader, n: int, path: Path, what: str) -> bytes:
    data = f.read(n)
    if len(data) != n:
        raise DataFormatError(f"{path}: file ends inside the {what} (truncated .sens)")
    return data


def read_header(f: io.BufferedReader, path: Path) -> SensHeader:
    """The header at the start of ``f`` (left positioned at the first frame)."""
    (version,) = _HEAD.unpack(_read_exact(f, 4, path, "header"))
    if version != VERSION:
        raise DataFormatError(f"{path}: not a ScanNet .sens file of version {VERSION} (the file "
                              f"starts with version {version})")
    (name_len,) = struct.unpack("<Q", _read_exact(f, 8, path, "header"))
    if name_len > MAX_NAME_BYTES:
        raise DataFormatError(f"{path}: sensor name of {name_len} bytes (at most "
                              f"{MAX_NAME_BYTES}): not a .sens header")
    name = _read_exact(f, name_len, path, "header").decode("utf-8", "replace")
    values = _CAMERAS.unpack(_read_exact(f, _CAMERAS.size, path, "header"))
    mats = np.array(values[:64], dtype=np.float64).reshape(4, 4, 4)
    color_c, depth_c, cw, ch, dw, dh, shift = values[64:]
    (count,) = struct.unpack("<Q", _read_exact(f, 8, path, "header"))
    for what, code, known in (("colour", color_c, COLOR_COMPRESSION),
                              ("depth", depth_c, DEPTH_COMPRESSION)):
        if code not in known:
            raise DataFormatError(f"{path}: unknown {what} compression code {code} (known: "
                                  + ", ".join(f"{k} {v}" for k, v in known.items()) + ")")
    for what, (w, h) in (("colour", (cw, ch)), ("depth", (dw, dh))):
        if not (0 < w <= MAX_IMAGE_SIDE and 0 < h <= MAX_IMAGE_SIDE):
            raise DataFormatError(f"{path}: {what} image size {w}x{h} in the header is not a "
                                  f"camera's")
    if not (np.isfinite(shift) and DEPTH_SHIFT_RANGE[0] <= shift <= DEPTH_SHIFT_RANGE[1]):
        raise DataFormatError(f"{path}: depth shift {shift!r} in the header must lie in "
                              f"{DEPTH_SHIFT_RANGE[0]:g}..{DEPTH_SHIFT_RANGE[1]:g} (1000: "
                              f"millimetres)")
    return SensHeader(name, mats[0], mats[1], mats[2], mats[3], COLOR_COMPRESSION[color_c],
                      DEPTH_COMPRESSION[depth_c], (int(cw), int(ch)), (int(dw), int(dh)),
                      float(shift), int(count))


class SensFile:
    """A ``.sens`` file's header and frame index (the module notes).

    Args:
        path: the ``.sens`` file.

    Raises:
        DataFormatError: not a version-4 ``.sens``, a header that no camera writes, a frame
            count the file cannot hold, a frame running past the end of the file.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        try:
            size = self.path.stat().st_size
            with open(self.path, "rb") as f:
                self.header = read_header(f, self.path)
                self.frames = self._index(f, size)
        except OSError as exc:
            raise DataFormatError(f"{self.path}: cannot read ({exc.strerror or exc})") from None

    def _index(self, f: io.BufferedReader, size: int) -> list[SensFrameEntry]:
        count = self.header.frames
        start = f.tell()
        if count > (size - start) // FRAME_HEADER.size:
            raise DataFormatError(f"{self.path}: the header states {count} frames but the file "
                                  f"holds at most {(size - start) // FRAME_HEADER.size} "
                                  f"(truncated, or not a .sens file)")
        entries = []
        pos = start
        for i in range(count):
            f.seek(pos)
            raw = f.read(FRAME_HEADER.size)
            if len(raw) != FRAME_HEADER.size:
                raise DataFormatError(f"{self.path}: file ends inside frame {i} of {count} "
                                      f"(truncated .sens)")
            values = FRAME_HEADER.unpack(raw)
            color_n, depth_n = values[18], values[19]
            color_at = pos + FRAME_HEADER.size
            end = color_at + color_n + depth_n
            if end > size:
                raise DataFormatError(f"{self.path}: frame {i} of {count} ends at byte {end}, "
                                      f"beyond the file's {size} bytes (truncated .sens)")
            pose = np.array(values[:16], dtype=np.float32).reshape(4, 4)
            entries.append(SensFrameEntry(pose, values[16], values[17], color_at, color_n,
                                          color_at + color_n, depth_n))
            pos = end
        return entries

    def __len__(self) -> int:
        return len(self.frames)

    def _bytes(self, offset: int, n: int) -> bytes:
        try:
            with open(self.path, "rb") as f:
                f.seek(offset)
                data = f.read(n)
        except OSError as exc:
            raise DataFormatError(f"{self.path}: cannot read ({exc.strerror or exc})") from None
        if len(data) != n:
            raise DataFormatError(f"{self.path}: file shrank while being read")
        return data

    def depth(self, index: int) -> np.ndarray:
        """Frame ``index``'s depth as stored (``uint16`` HxW, depth shift units, 0 = none)."""
        entry = self.frames[index]
        where = f"{self.path}: frame {index}"
        w, h = self.header.depth_size
        kind = self.header.depth_compression
        if kind not in READ_DEPTH:
            raise DataFormatError(f"{where}: depth compression {kind!r} is not read (evsmap reads "
                                  f"{', '.join(READ_DEPTH)}, what ScanNet's files hold)")
        data = self._bytes(entry.depth_offset, entry.depth_bytes)
        if kind == "zlib_ushort":
            try:
                data = zlib.decompress(data, bufsize=2 * w * h)
            except zlib.error as exc:
                raise DataFormatError(f"{where}: corrupt zlib depth ({exc})") from None
        if len(data) != 2 * w * h:
            raise DataFormatError(f"{where}: depth holds {len(data)} bytes, {2 * w * h} expected "
                                  f"for {w}x{h} uint16")
        return np.frombuffer(data, dtype="<u2").reshape(h, w).astype(np.uint16)

    def color(self, index: int) -> np.ndarray:
        """Frame ``index``'s colour image (``uint8`` HxWx3 RGB at the colour camera's size)."""
        entry = self.frames[index]
        where = f"{self.path}: frame {index}"
        w, h = self.header.color_size
        kind = self.header.color_compression
        if kind not in READ_COLOR:
            raise DataFormatError(f"{where}: colour compression {kind!r} is not read")
        data = self._bytes(entry.color_offset, entry.color_bytes)
        if kind == "raw":
            if len(data) != 3 * w * h:
                raise DataFormatError(f"{where}: raw colour holds {len(data)} bytes, "
                                      f"{3 * w * h} expected for {w}x{h} RGB")
            return np.frombuffer(data, dtype=np.uint8).reshape(h, w, 3).copy()
        from evsmap.readers.images import decode_rgb

        rgb = decode_rgb(data, where=f"{where} ({kind} colour)")
        if rgb.shape[:2] != (h, w):
            raise DataFormatError(f"{where}: colour image is {rgb.shape[1]}x{rgb.shape[0]}, the "
                                  f"header says {w}x{h}")
        return rgb


__all__ = ["COLOR_COMPRESSION", "DEPTH_COMPRESSION", "FRAME_HEADER", "SensFile",
           "SensFrameEntry", "SensHeader", "VERSION", "read_header"]
