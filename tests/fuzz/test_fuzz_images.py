"""Fuzz targets for the image files the readers decode (evsmap.readers.images: ``read_rgb``,
``read_uint16``, ``read_uint8_labels``; docs/robustness.md).

Byte mutations of the real samples (TUM RGB and depth PNGs, 7-Scenes ``.color.jpg`` and
``.depth.png``, NYUv2 40-class label PNGs), images generated with PIL in every mode, size, format
and frame count a user could hand over, headers edited to claim huge sizes (valid CRC), empty
and text files named ``.png``, and generated images put in a TUM folder where they must match
the intrinsics and each other in size. The property (tests/fuzz/harness.py): an array of the
documented dtype and shape, or one line naming the file; a lying header is refused before
anything is allocated.
"""

from __future__ import annotations

import io
import os
import shutil
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st
from PIL import Image

from evsmap.readers.images import read_rgb, read_uint8_labels, read_uint16
from evsmap.readers.tum import open_tum
from tests.fuzz.harness import check_file, mutated_bytes, write_variant

READERS = {"rgb": read_rgb, "uint16": read_uint16, "labels": read_uint8_labels}


def _checked(kind: str, path: Path):
    """Read ``path`` with reader ``kind`` and check what a success returns."""
    def call():
        arr = READERS[kind](path)
        assert isinstance(arr, np.ndarray) and arr.size > 0, arr
        if kind == "rgb":
            assert arr.dtype == np.uint8 and arr.ndim == 3 and arr.shape[2] == 3, arr.shape
        else:
            assert arr.dtype == (np.uint16 if kind == "uint16" else np.uint8), arr.dtype
            assert arr.ndim == 2, arr.shape
        return arr
    return call


def _samples(root: Path) -> dict[str, tuple[bytes, str]]:
    """Sample name -> (bytes, the reader meant for it)."""
    tum = root / "tum_fr1_xyz"
    seven = root / "sevenscenes_100"
    nyu = root / "nyuv2_samples"
    files = {
        "tum-rgb": (sorted((tum / "rgb").iterdir())[0], "rgb"),
        "tum-depth": (sorted((tum / "depth").iterdir())[0], "uint16"),
        "7scenes-color": (seven / "frame-000000.color.jpg", "rgb"),
        "7scenes-depth": (seven / "frame-000000.depth.png", "uint16"),
        "nyu-label40": (nyu / "label40" / "000433.png", "labels"),
        "nyu-depth": (nyu / "depth" / "000433.png", "uint16"),
    }
    return {name: (path.read_bytes(), kind) for name, (path, kind) in files.items()}


@pytest.fixture(scope="module")
def samples(tum_dir, sevenscenes_dir, nyuv2_samples_dir):
    return _samples(tum_dir.parent)


def _fuzz_bytes(folder: Path, samples: dict, names: tuple[str, ...], target: str) -> None:
    @given(st.sampled_from(names).flatmap(
        lambda n: st.tuples(st.just(n), mutated_bytes(samples[n][0]))))
    def inner(choice):
        name, data = choice
        suffix = ".jpg" if name == "7scenes-color" else ".png"
        path = write_variant(folder / f"{name}{suffix}", data)
        check_file(target, _checked(samples[name][1], path), path)

    inner()


def test_fuzz_depth_png_bytes(tmp_path, samples):
    _fuzz_bytes(tmp_path, samples, ("tum-depth", "7scenes-depth", "nyu-depth"),
                "images/depth-bytes")


def test_fuzz_rgb_bytes(tmp_path, samples):
    _fuzz_bytes(tmp_path, samples, ("tum-rgb", "7scenes-color"), "images/rgb-bytes")


def test_fuzz_label_png_bytes(tmp_path, samples):
    _fuzz_bytes(tmp_path, samples, ("nyu-label40",), "images/label-bytes")


# ----------------------------------------------------------------------------- generated
MODES = ("RGB", "RGBA", "L", "P", "I;16", "I;16B", "I;16L", "I", "F", "1", "LA", "PA", "CMYK",
         "RGBX", "YCbCr", "HSV", "LAB")
FORMATS = ("PNG", "JPEG", "GIF", "TIFF", "BMP", "WEBP", "PPM", "TGA", "ICO")


@st.composite
def generated_images(draw) -> bytes:
    """An image PIL can write: any mode, a small or zero size, any format, one or several
    frames (animated PNG / GIF / TIFF / WebP); or an empty file, text, a bare header."""
    special = draw(st.sampled_from([None] * 8 + ["empty", "text", "header", "ppm-huge"]))
    if special == "empty":
        return b""
    if special == "text":
        return draw(st.text(max_size=80)).encode("utf-8", "surrogatepass")
    if special == "header":
        return b"\x89PNG\r\n\x1a\n"
    if special == "ppm-huge":
        w, h = draw(st.integers(0, 2**31)), draw(st.integers(0, 2**31))
        return f"P{draw(st.sampled_from('23456'))}\n{w} {h}\n65535\n".encode() + b"\0" * 64
    mode = draw(st.sampled_from(MODES))
    fmt = draw(st.sampled_from(FORMATS))
    w, h = draw(st.integers(1, 24)), draw(st.integers(1, 24))
    frames = draw(st.integers(1, 3))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    images = []
    for _ in range(frames):
        img = Image.new(mode, (w, h))
        raw = rng.integers(0, 256, len(img.tobytes()), dtype=np.uint8).tobytes()
        try:
            img.frombytes(raw)
        except (ValueError, OSError):
            pass
        images.append(img)
    buf = io.BytesIO()
    try:
        if frames > 1:
            images[0].save(buf, format=fmt, save_all=True, append_images=images[1:])
        else:
            images[0].save(buf, format=fmt)
    except (OSError, ValueError, KeyError, TypeError):
        assume(False)
    return buf.getvalue()


def test_fuzz_generated_images(tmp_path):
    @given(generated_images(), st.sampled_from([".png", ".jpg"]))
    def inner(data, suffix):
        path = write_variant(tmp_path / f"generated{suffix}", data)
        for kind in READERS:
            check_file("images/generated", _checked(kind, path), path)

    inner()


# ----------------------------------------------------------------------------- huge headers
def png_with_size(data: bytes, width: int, height: int) -> bytes:
    """``data`` (a PNG) with its IHDR width and height replaced and the chunk's CRC fixed."""
    assert data[12:16] == b"IHDR"
    ihdr = bytearray(data[16:29])
    ihdr[0:8] = struct.pack(">II", width, height)
    crc = struct.pack(">I", zlib.crc32(b"IHDR" + bytes(ihdr)) & 0xFFFFFFFF)
    return data[:16] + bytes(ihdr) + crc + data[33:]


def jpeg_with_size(data: bytes, width: int, height: int) -> bytes:
    """``data`` (a JPEG) with its first start-of-frame marker claiming ``width`` x ``height``."""
    i = 2
    while i + 4 <= len(data):
        marker, length = data[i + 1], struct.unpack(">H", data[i + 2:i + 4])[0]
        if marker in (0xC0, 0xC1, 0xC2):
            return data[:i + 5] + struct.pack(">HH", height, width) + data[i + 9:]
        i += 2 + length
    raise AssertionError("no start-of-frame marker")


_side = st.one_of(st.integers(0, 2**31 - 1), st.sampled_from(
    [0, 1, 100000, 65535, 2**31 - 1, 8193, 46341, 640, 480, 10**5]))


def test_fuzz_huge_claimed_sizes(tmp_path, samples):
    """A header edited to claim a huge size (e.g. 100000 x 100000) is refused before the
    pixels are allocated: one line naming the file, within the harness's address-space bound."""
    png = ("tum-depth", "tum-rgb", "nyu-label40", "7scenes-depth")

    @given(st.sampled_from(png + ("7scenes-color",)), _side, _side,
           st.sampled_from(["whole", "truncated", "idat-length"]))
    def inner(name, width, height, cut):
        data, kind = samples[name]
        jpeg = name == "7scenes-color"
        if jpeg:
            edited = jpeg_with_size(data, min(width, 65535), min(height, 65535))
        elif cut == "idat-length":  # the size kept, the first IDAT chunk claiming ~4 GiB
            i = data.find(b"IDAT")
            edited = data[:i - 4] + (0xFFFFFF00 - width % 256).to_bytes(4, "big") + data[i:]
        else:
            edited = png_with_size(data, width, height)
        if cut == "truncated":
            edited = edited[:2048]
        path = write_variant(tmp_path / f"{name}-huge{'.jpg' if jpeg else '.png'}", edited)
        check_file("images/huge-header", _checked(kind, path), path)

    inner()
    # the documented case: 100000 x 100000 refused as a one-line error naming the file
    path = write_variant(tmp_path / "bomb.png",
                         png_with_size(samples["tum-depth"][0], 100000, 100000))
    from evsmap.errors import DataFormatError
    with pytest.raises(DataFormatError, match="bomb.png") as info:
        read_uint16(path)
    assert "\n" not in str(info.value)


# ----------------------------------------------------------------------------- in a frame
@st.composite
def frame_images(draw) -> tuple[str, bytes]:
    """Which of a TUM frame's images to replace (``rgb``, ``depth``, ``labels``) and a PNG
    for it: the right or a wrong mode, the right size, off by one, transposed or tiny."""
    which = draw(st.sampled_from(["rgb", "depth", "labels"]))
    w, h = draw(st.sampled_from([(640, 480), (480, 640), (639, 480), (640, 481), (1, 1),
                                 (320, 240)]))
    mode = draw(st.sampled_from({"rgb": ["RGB", "RGB", "RGBA", "P", "L", "I;16"],
                                 "depth": ["I;16", "I;16", "I", "L", "RGB", "F"],
                                 "labels": ["L", "L", "P", "I;16", "RGB", "1"]}[which]))
    img = Image.new(mode, (w, h), color=draw(st.integers(0, 255)))
    buf = io.BytesIO()
    img.save(buf, format="TIFF" if mode in ("F", "I") else "PNG")
    return which, buf.getvalue()


def test_fuzz_images_in_a_tum_frame(tmp_path, tum_dir, nyuv2_samples_dir):
    root = tmp_path / "rgbd_dataset_freiburg1_xyz"
    root.mkdir()
    stamps = {}
    for name in ("rgb", "depth"):
        rows = [r for r in (tum_dir / f"{name}.txt").read_text().splitlines()
                if not r.startswith("#")][:2]
        (root / f"{name}.txt").write_text("\n".join(rows) + "\n")
        (root / name).mkdir()
        for row in rows:
            stamp, rel = row.split()
            shutil.copyfile(tum_dir / rel, root / rel)
            stamps.setdefault(name, []).append((stamp, root / rel))
    (root / "labels").mkdir()
    label = nyuv2_samples_dir / "label40" / "000433.png"
    lines = []
    for stamp, _ in stamps["depth"]:
        shutil.copyfile(label, root / "labels" / f"{stamp}.png")
        lines.append(f"{stamp} labels/{stamp}.png")
    stamps["labels"] = [(s, root / "labels" / f"{s}.png") for s, _ in stamps["depth"]]
    (root / "labels.txt").write_text("\n".join(lines) + "\n")
    first = float(stamps["depth"][0][0])
    gt = [r for r in (tum_dir / "groundtruth.txt").read_text().splitlines()
          if not r.startswith("#") and abs(float(r.split()[0]) - first) < 0.2]
    (root / "groundtruth.txt").write_text("\n".join(gt) + "\n")
    seq = open_tum(path=str(root))
    assert seq.frame(0).labels is not None

    # the frame whose images are replaced: the one whose depth image comes first
    originals = {which: (files[0][1], files[0][1].read_bytes()) for which, files in stamps.items()}

    @given(frame_images())
    def inner(choice):
        which, data = choice
        path = originals[which][0]
        write_variant(path, data)
        try:
            index = [p.name for p in seq.depth_files].index(originals["depth"][0].name)
            check_file("images/tum-frame", lambda: open_tum(path=str(root)).frame(index), path)
        finally:
            path.write_bytes(originals[which][1])

    inner()
    assert os.path.exists(root / "labels.txt")
