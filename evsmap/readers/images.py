"""Checked image loading: every failure names the file and what was expected."""

from __future__ import annotations

import io
import re
import struct
import warnings
import zlib
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from evsmap.errors import DataFormatError

DEPTH_SCALE = 5000.0
"""TUM RGB-D depth PNG scale: metres = value / 5000."""


def quantize_depth(depth: np.ndarray, scale: float = DEPTH_SCALE) -> np.ndarray:
    """Metres -> ``uint16`` PNG values (0 stays invalid; beyond 65535/scale becomes invalid)."""
    q = np.round(np.asarray(depth, np.float64) * scale)
    q[(q > 65535) | ~np.isfinite(q)] = 0
    return q.astype(np.uint16)


def dequantize_depth(raw: np.ndarray, scale: float = DEPTH_SCALE) -> np.ndarray:
    """``uint16`` PNG values -> metres as ``float32`` (0 = invalid). The one conversion used by
    the renderer and every reader, so a write/read round trip is exact."""
    return raw.astype(np.float32) / np.float32(scale)


def check_rgbd_shapes(raw: np.ndarray, rgb: np.ndarray, intrinsics, *, depth_file: Path,
                      rgb_file: Path, intrinsics_source: str) -> None:
    """A depth image must match its colour image and the intrinsics in size.

    Raises:
        DataFormatError: naming the depth file and both sizes.
    """
    if raw.shape != rgb.shape[:2]:
        raise DataFormatError(
            f"{depth_file}: depth is {raw.shape[1]}x{raw.shape[0]} but "
            f"{rgb_file.name} is {rgb.shape[1]}x{rgb.shape[0]}")
    if raw.shape != intrinsics.shape:
        raise DataFormatError(
            f"{depth_file}: image is {raw.shape[1]}x{raw.shape[0]} but the intrinsics "
            f"({intrinsics_source}) are for {intrinsics.width}x{intrinsics.height}")


MAX_PIXELS = 1 << 26
"""Largest image (width x height) the readers decode, about 67 megapixels (8192 x 8192): far
above any RGB-D camera's, far below what a corrupt or hostile header can claim, so such a header
is refused before anything is allocated."""

# what a corrupt file makes PIL raise, besides OSError (UnidentifiedImageError, truncated data,
# decoder errors): parsers raise SyntaxError, ValueError, struct.error, EOFError, IndexError,
# KeyError or TypeError on malformed chunks, DecompressionBombError on a huge size
_PIL_ERRORS = (OSError, SyntaxError, ValueError, EOFError, IndexError, KeyError, TypeError,
               struct.error, zlib.error, Image.DecompressionBombError)


def _open(path: Path) -> Image.Image:
    """The decoded image at ``path``; a missing, corrupt or oversized file is a one-line
    :class:`DataFormatError` naming it. The file is closed on return, whatever happened (PIL
    leaves a file it opened itself open when its size check refuses the header)."""
    if not path.is_file():
        raise DataFormatError(f"{path}: file not found")
    try:
        with open(path, "rb") as fh:
            # from memory: PIL reads the rest of a PNG chunk whose length field claims up to
            # 4 GiB in one read(), which a file object allocates before reading, memory not
            return _decode(path, io.BytesIO(fh.read()))
    except OSError as exc:
        raise DataFormatError(f"{path}: cannot read ({_one_line(exc)})") from None


def _decode(path: Path | str, fh) -> Image.Image:
    try:
        with warnings.catch_warnings():  # sizes PIL only warns about are refused below
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            img = Image.open(fh)
    except Image.DecompressionBombError:
        raise DataFormatError(f"{path}: image header claims a size above {MAX_PIXELS} pixels "
                              f"(corrupt file?)") from None
    except _PIL_ERRORS as exc:
        raise DataFormatError(f"{path}: unreadable or corrupt image ({_one_line(exc)})") from None
    width, height = img.size
    if width <= 0 or height <= 0 or width * height > MAX_PIXELS:
        raise DataFormatError(f"{path}: image header claims {width}x{height} pixels (at most "
                              f"{MAX_PIXELS} read; corrupt file?)")
    try:
        img.load()
    except _PIL_ERRORS as exc:
        raise DataFormatError(f"{path}: unreadable or corrupt image ({_one_line(exc)})") from None
    return img


def image_size(path: Path) -> tuple[int, int] | None:
    """``(width, height)`` from the image header at ``path`` (nothing decoded), or None when the
    file is missing or not an image PIL can identify (the caller reads and reports it later)."""
    try:
        with open(path, "rb") as fh, warnings.catch_warnings():  # closed even on a bomb error
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            return Image.open(fh).size
    except _PIL_ERRORS:
        return None


def _one_line(exc: BaseException) -> str:
    """``exc``'s message on one line, short, without PIL's repr of the in-memory buffer."""
    if isinstance(exc, UnidentifiedImageError):
        return "not a recognised image format"
    text = _BUFFER_REPR.sub("the file", " ".join(str(exc).split()))
    return text[:200] or type(exc).__name__


_BUFFER_REPR = re.compile(r"<_io\.\w+ object at 0x[0-9a-fA-F]+>")


def read_rgb(path: Path) -> np.ndarray:
    """8-bit colour image as ``uint8`` HxWx3 (RGBA and palette images are converted; grey and
    16-bit images are refused)."""
    return _as_rgb(_open(path), path)


def decode_rgb(data: bytes, *, where: str) -> np.ndarray:
    """:func:`read_rgb` of an encoded image held in memory (a JPEG inside a ScanNet ``.sens``);
    errors start with ``where``."""
    return _as_rgb(_decode(where, io.BytesIO(data)), where)


def _as_rgb(image: Image.Image, where: Path | str) -> np.ndarray:
    with image as img:
        if img.mode not in ("RGB", "RGBA", "P"):
            raise DataFormatError(f"{where}: expected an 8-bit colour image, got mode {img.mode}")
        return np.asarray(img.convert("RGB"), dtype=np.uint8)


def read_uint16(path: Path) -> np.ndarray:
    """16-bit single-channel image (depth) as ``uint16`` HxW."""
    return _as_uint16(_open(path), path)


def decode_uint16(data: bytes, *, where: str) -> np.ndarray:
    """:func:`read_uint16` of an encoded image held in memory (a 16-bit label PNG inside a
    zip); errors start with ``where``."""
    return _as_uint16(_decode(where, io.BytesIO(data)), where)


def _as_uint16(image: Image.Image, where: Path | str) -> np.ndarray:
    with image as img:
        if img.mode not in ("I;16", "I;16B", "I;16L", "I"):
            raise DataFormatError(f"{where}: expected a 16-bit single-channel image, "
                                  f"got mode {img.mode}")
        arr = np.asarray(img)
    if arr.ndim != 2:
        raise DataFormatError(f"{where}: expected a single-channel image, got shape {arr.shape}")
    if arr.dtype != np.uint16:
        if arr.min() < 0 or arr.max() > 65535:
            raise DataFormatError(f"{where}: values outside the 16-bit range")
        arr = arr.astype(np.uint16)
    return arr


def read_uint8_labels(path: Path) -> np.ndarray:
    """8-bit single-channel label image as ``uint8`` HxW."""
    with _open(path) as img:
        if img.mode not in ("L", "P"):
            raise DataFormatError(f"{path}: expected an 8-bit single-channel label image, "
                                  f"got mode {img.mode}")
        return np.asarray(img, dtype=np.uint8)


def write_png(path: Path, array: np.ndarray) -> None:
    """Write ``uint8`` HxW / HxWx3 or ``uint16`` HxW as PNG (deterministic bytes)."""
    if array.dtype == np.uint16:
        img = Image.fromarray(array)
    elif array.dtype == np.uint8 and array.ndim in (2, 3):
        img = Image.fromarray(array)
    else:
        raise ValueError(f"cannot write {array.dtype} {array.shape} as PNG")
    img.save(path, format="PNG", compress_level=1)
