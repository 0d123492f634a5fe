"""Decoding ROS messages into arrays: the message type names the reader knows, colour and depth
``Image`` and ``CompressedImage`` (including image_transport's ``compressedDepth``) into
``uint8`` RGB and ``float32`` metres, ``PointCloud2`` into points and colours, and the header
helpers (stamps in nanoseconds, frame names) the other modules share."""

from __future__ import annotations

import io
from typing import Any

import numpy as np

from evsmap.errors import DataFormatError

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
CLOUD = "sensor_msgs/msg/PointCloud2"
ODOMETRY = "nav_msgs/msg/Odometry"
POSE_TYPES = (ODOMETRY, "geometry_msgs/msg/TransformStamped", "geometry_msgs/msg/PoseStamped",
              "geometry_msgs/msg/PoseWithCovarianceStamped")
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")

COLOR_ENCODINGS = {"rgb8": (3, False), "bgr8": (3, True), "rgba8": (4, False),
                   "bgra8": (4, True), "mono8": (1, False)}
"""Supported colour ``Image`` encodings: channels and whether the order is BGR."""
DEPTH_ENCODINGS = {"16uc1": ("u2", 0.001), "mono16": ("u2", 0.001), "32fc1": ("f4", 1.0)}
"""Supported depth ``Image`` encodings (lower case): sample type and metres per unit."""
_COLOR_EXPECTED = "rgb8, bgr8, rgba8, bgra8 or mono8"
_DEPTH_EXPECTED = "16UC1 (millimetres) or 32FC1 (metres)"


def _frame_name(frame: str) -> str:
    return frame.lstrip("/")


def _stamp_ns(msg: Any) -> int:
    stamp = msg.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _fmt(ns: int) -> str:
    return f"{ns / 1e9:.6f} s"


def _one_line(exc: BaseException) -> str:
    """An exception's text on one line (a library's message may span several)."""
    return " ".join(str(exc).split()) or type(exc).__name__

def _raw_rows(msg: Any, row_bytes: int, where: str) -> np.ndarray:
    """The image bytes as (height, row_bytes) uint8, honouring ``step`` (row padding)."""
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    if h == 0 or w == 0:
        raise DataFormatError(f"{where}: empty image ({w}x{h})")
    if step < row_bytes:
        raise DataFormatError(f"{where}: step {step} is less than a row of {w} pixels "
                              f"({row_bytes} bytes)")
    if data.size < step * (h - 1) + row_bytes:
        raise DataFormatError(f"{where}: {data.size} data bytes for a {w}x{h} image with step "
                              f"{step} (expected {step * h})")
    return _rows(data, h, row_bytes, step)


def _rows(data: np.ndarray, count: int, row_bytes: int, stride: int) -> np.ndarray:
    """``count`` rows of ``row_bytes`` starting every ``stride`` bytes of ``data`` (which holds
    them, the last one possibly without its padding): no padding is allocated, however large
    the stride claims to be."""
    data = np.ascontiguousarray(data)
    if stride == row_bytes:
        return data[: count * row_bytes].reshape(count, row_bytes)
    view = np.lib.stride_tricks.as_strided(data, shape=(count, row_bytes), strides=(stride, 1),
                                           writeable=False)
    return np.ascontiguousarray(view)


def decode_color_image(msg: Any, where: str) -> np.ndarray:
    """``sensor_msgs/Image`` (rgb8, bgr8, rgba8, bgra8, mono8) -> ``uint8`` HxWx3 RGB."""
    enc = str(msg.encoding).lower()
    if enc not in COLOR_ENCODINGS:
        raise DataFormatError(f"{where}: colour encoding {msg.encoding!r}; expected "
                              f"{_COLOR_EXPECTED}")
    channels, bgr = COLOR_ENCODINGS[enc]
    rows = _raw_rows(msg, int(msg.width) * channels, where)
    img = np.ascontiguousarray(rows).reshape(int(msg.height), int(msg.width), channels)
    if channels == 1:
        return np.repeat(img, 3, axis=2)
    img = img[..., :3]
    return np.ascontiguousarray(img[..., ::-1] if bgr else img)


def _clean_depth(depth: np.ndarray) -> np.ndarray:
    depth = depth.astype(np.float32, copy=False)
    bad = ~np.isfinite(depth) | (depth < 0)
    if bad.any():
        depth = np.where(bad, np.float32(0.0), depth)
    return np.ascontiguousarray(depth, dtype=np.float32)


def decode_depth_image(msg: Any, where: str) -> np.ndarray:
    """``sensor_msgs/Image`` 16UC1/mono16 (mm) or 32FC1 (m) -> ``float32`` metres, 0 invalid."""
    enc = str(msg.encoding).lower()
    if enc not in DEPTH_ENCODINGS:
        raise DataFormatError(f"{where}: depth encoding {msg.encoding!r}; expected "
                              f"{_DEPTH_EXPECTED}")
    kind, scale = DEPTH_ENCODINGS[enc]
    dtype = np.dtype(kind).newbyteorder(">" if msg.is_bigendian else "<")
    rows = _raw_rows(msg, int(msg.width) * dtype.itemsize, where)
    values = np.ascontiguousarray(rows).view(dtype).reshape(int(msg.height), int(msg.width))
    if kind == "u2":
        return _clean_depth(values.astype(np.float32) * np.float32(scale))
    return _clean_depth(values.astype(np.float32))


def _pil_open(data: bytes, where: str, what: str, size: tuple[int, int] | None = None):
    """The decoded image; with ``size`` (width, height), an image of another size is refused
    from its header, before its pixels are allocated."""
    import warnings

    from PIL import Image, UnidentifiedImageError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            img = Image.open(io.BytesIO(data))
            if size is not None and img.size != tuple(size):
                raise DataFormatError(f"{where}: {what} is {img.size[0]}x{img.size[1]}; "
                                      f"expected {size[0]}x{size[1]}")
            img.load()
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError, EOFError,
            Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
        raise DataFormatError(f"{where}: cannot decode the {what} data "
                              f"({_one_line(exc)})") from None
    return img


def decode_compressed_color(msg: Any, where: str,
                            size: tuple[int, int] | None = None) -> np.ndarray:
    """``sensor_msgs/CompressedImage`` (JPEG, PNG, anything Pillow reads) -> ``uint8`` RGB;
    with ``size`` (width, height), an image of another size is refused before decoding."""
    img = _pil_open(bytes(np.asarray(msg.data, dtype=np.uint8)), where,
                    f"compressed image ({msg.format!r})", size)
    if img.mode in ("I;16", "I;16B", "I;16L", "I", "F"):
        raise DataFormatError(f"{where}: compressed colour image is {img.mode} "
                              f"(16/32-bit); expected 8-bit colour or grey")
    return np.ascontiguousarray(np.asarray(img.convert("RGB"), dtype=np.uint8))


_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _png_uint16(data: bytes, where: str, size: tuple[int, int] | None) -> np.ndarray:
    img = _pil_open(data, where, "compressedDepth PNG", size)
    arr = np.asarray(img)
    if arr.ndim != 2 or img.mode not in ("I;16", "I;16B", "I;16L", "I", "L"):
        raise DataFormatError(f"{where}: compressedDepth PNG is {img.mode} with shape "
                              f"{arr.shape}; expected one 16-bit channel")
    return arr.astype(np.uint16)


def decode_compressed_depth(msg: Any, where: str,
                            size: tuple[int, int] | None = None) -> np.ndarray:
    """Depth from ``sensor_msgs/CompressedImage``: image_transport's ``compressedDepth`` PNG
    (16UC1 millimetres, or 32FC1 as quantised inverse depth) or a plain 16-bit PNG in mm; with
    ``size`` (width, height), an image of another size is refused before decoding.

    ``compressedDepth`` data is a 12-byte header (int32 format, float32 depthQuantA,
    float32 depthQuantB; little-endian) followed by a PNG; a 32FC1 image's pixels hold
    ``v = A / depth + B`` and decode as ``A / (v - B)`` (0 for invalid), as
    compressed_depth_image_transport's codec does. Its RVL variant is not supported.
    """
    fmt = str(msg.format)
    data = bytes(np.asarray(msg.data, dtype=np.uint8))
    low = fmt.lower()
    encoding = low.split(";", 1)[0].strip()
    if "compresseddepth" in low:
        if "rvl" in low:
            raise DataFormatError(f"{where}: compressedDepth format {fmt!r} (RVL) is not "
                                  f"supported; expected compressedDepth PNG")
        if encoding not in DEPTH_ENCODINGS:
            raise DataFormatError(f"{where}: compressedDepth of encoding {encoding!r}; "
                                  f"expected {_DEPTH_EXPECTED}")
        if data[12:20] == _PNG_MAGIC:
            header, png = data[:12], data[12:]
        elif data[:8] == _PNG_MAGIC:  # no configuration header
            header, png = b"", data
        else:
            raise DataFormatError(f"{where}: compressedDepth data has no PNG at byte 0 or 12 "
                                  f"({len(data)} bytes)")
        raw = _png_uint16(png, where, size)
        if encoding == "32fc1":
            if len(header) != 12:
                raise DataFormatError(f"{where}: 32FC1 compressedDepth without its quantisation "
                                      f"header")
            quant = np.frombuffer(header, dtype="<f4", count=2, offset=4)
            a, b = np.float32(quant[0]), np.float32(quant[1])
            with np.errstate(divide="ignore", invalid="ignore"):
                depth = a / (raw.astype(np.float32) - b)
            return _clean_depth(np.where(raw == 0, np.float32(0.0), depth))
        return _clean_depth(raw.astype(np.float32) * np.float32(0.001))
    if encoding and encoding in ("32fc1",):
        raise DataFormatError(f"{where}: compressed depth format {fmt!r} is not supported; "
                              f"expected compressedDepth PNG or a 16-bit PNG in millimetres")
    img = _pil_open(data, where, f"compressed depth ({fmt!r})", size)
    if img.mode not in ("I;16", "I;16B", "I;16L", "I"):
        raise DataFormatError(f"{where}: compressed depth image is {img.mode}; expected a "
                              f"16-bit PNG in millimetres or compressedDepth")
    return _clean_depth(np.asarray(img).astype(np.float32) * np.float32(0.001))


_POINT_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def decode_cloud(msg: Any, where: str) -> tuple[np.ndarray, np.ndarray | None]:
    """``sensor_msgs/PointCloud2`` -> finite ``float32`` Nx3 points (NaN/inf dropped) and their
    ``uint8`` Nx3 colours (from a packed ``rgb``/``rgba`` float32/uint32 field or ``r``, ``g``,
    ``b`` uint8 fields) or None."""
    fields = {str(f.name): f for f in msg.fields}
    order = ">" if msg.is_bigendian else "<"
    for axis in "xyz":
        if axis not in fields:
            raise DataFormatError(f"{where}: PointCloud2 has no {axis!r} field (fields: "
                                  f"{', '.join(fields) or 'none'})")
        if fields[axis].datatype not in (7, 8):
            raise DataFormatError(f"{where}: PointCloud2 field {axis!r} has datatype "
                                  f"{fields[axis].datatype}; expected FLOAT32 (7) or FLOAT64 (8)")
    step = int(msg.point_step)
    names, formats, offsets = [], [], []

    def add(name: str, kind: str) -> None:
        f = fields[name]
        size = np.dtype(kind).itemsize
        if int(f.offset) + size > step:
            raise DataFormatError(f"{where}: PointCloud2 field {name!r} at offset {f.offset} "
                                  f"overruns point_step {step}")
        names.append(name)
        formats.append(order + kind)
        offsets.append(int(f.offset))

    for axis in "xyz":
        add(axis, _POINT_TYPES[fields[axis].datatype])
    color_field = next((n for n in ("rgb", "rgba") if n in fields), None)
    if color_field is not None and fields[color_field].datatype in (6, 7):
        add(color_field, "u4")  # packed 0x(AA)RRGGBB; a float32 field holds the same bits
    else:
        color_field = None
        if all(c in fields and fields[c].datatype == 2 for c in "rgb"):
            for c in "rgb":
                add(c, "u1")
            color_field = "r,g,b"
    h, w = int(msg.height), int(msg.width)
    n = h * w
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    row = w * step
    row_step = int(msg.row_step) if int(msg.row_step) else row
    if row_step < row or data.size < row_step * (h - 1) + row:
        raise DataFormatError(f"{where}: PointCloud2 of {w}x{h} points with point_step {step} "
                              f"and row_step {msg.row_step} needs {row_step * h} bytes, has "
                              f"{data.size}")
    if n == 0:
        return np.zeros((0, 3), np.float32), None if color_field is None else \
            np.zeros((0, 3), np.uint8)
    # a point is at most the data (checked above), so point_step fits numpy's itemsize here
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": step})
    data = np.ascontiguousarray(_rows(data, h, row, row_step))
    rec = data.reshape(-1).view(dtype)
    pts = np.stack([rec["x"].astype(np.float32), rec["y"].astype(np.float32),
                    rec["z"].astype(np.float32)], axis=1)
    keep = np.all(np.isfinite(pts), axis=1)
    colors = None
    if color_field == "r,g,b":
        colors = np.stack([rec["r"], rec["g"], rec["b"]], axis=1).astype(np.uint8)
    elif color_field is not None:
        packed = rec[color_field].astype(np.uint32)
        colors = np.stack([(packed >> 16) & 255, (packed >> 8) & 255, packed & 255],
                          axis=1).astype(np.uint8)
    if not keep.all():
        pts = pts[keep]
        colors = colors[keep] if colors is not None else None
    return np.ascontiguousarray(pts), colors
