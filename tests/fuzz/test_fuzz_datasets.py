"""Fuzz targets: the prepared segmentation datasets (manifests, id lists, label and depth PNGs) and
the official files ``evsmap datasets prepare`` reads (NYUv2's MATLAB files, SUN RGB-D's scene
folders and segmentation file, Cityscapes' camera JSON and label PNGs).

Every target opens its input the way ``evsmap eval`` / training does (the registered reader, frame
0) or the way ``prepare_*`` does, under the property of :mod:`tests.fuzz.harness`: it works, or
it stops with one line naming the file."""

from __future__ import annotations

import io
import json
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
import scipy.io
from hypothesis import given
from hypothesis import strategies as st
from PIL import Image

from evsmap.datasets import cityscapes as cs
from evsmap.datasets import nyuv2, sunrgbd
from evsmap.datasets import synthrooms as sr
from evsmap.datasets.common import MANIFEST, load_mat, make_manifest, read_label_png
from evsmap.datasets.lookup import open_dataset
from tests.datasets.datasets_fixtures import (
    h5_matlab,
    stamp_matlab_header,
    write_city_tree,
    write_nyu_source,
    write_sun_source,
)
from tests.fuzz.harness import check_cli, check_file, mutated_bytes, text_lines, write_variant


def _nyu_samples() -> Path:
    # the project's sample lookup: a skip that names the fetch command, a failure with CI=true
    from evsmap.testing import require_sample

    return require_sample("nyuv2-samples")


def _png(array: np.ndarray, mode: str | None = None) -> bytes:
    buf = io.BytesIO()
    img = Image.fromarray(array) if mode is None else Image.fromarray(array).convert(mode)
    img.save(buf, format="PNG", compress_level=1)
    return buf.getvalue()


def png_claiming(width: int, height: int, bits: int = 8, colour: int = 0) -> bytes:
    """A PNG whose (checksummed) header claims ``width`` x ``height`` over a tiny image."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + \
            struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    head = struct.pack(">IIBBBBB", width, height, bits, colour, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", head) + \
        chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b"")


def idat_claim(png: bytes, length: int = 0xFFFFFF00) -> bytes:
    """``png`` whose first IDAT chunk claims ``length`` bytes (PIL reads the unread rest of it in
    one call once the image is decoded)."""
    i = png.find(b"IDAT")
    return png[:i - 4] + length.to_bytes(4, "big") + png[i:]


HUGE_PNGS = [png_claiming(100_000, 100_000), png_claiming(20_000, 20_000, 16),
             png_claiming(2**31 - 1, 1), png_claiming(640, 480_000)]


def _read_frame(folder: Path, split: str, **options: object) -> None:
    """Open ``folder`` as ``evsmap eval`` does (detected reader, split) and read frame 0."""
    seq, _ = open_dataset(str(folder), split=split, options=list(options.items()))
    if len(seq):
        seq[0]


ODD_JSON = st.sampled_from([
    "[" * 100_000, '{"a":' * 50_000 + "1" + "}" * 50_000,
    '{"format": "evsmap-dataset", "name": "nyuv2", "version": ' + "9" * 5000 + "}",
    '{"extrinsic": {"baseline": ' + "1" * 4500 + "}}", "\ufeff{}", "null", "[]", '"x"'])
"""JSON texts no edit of a record gives: deep nesting, integers too long to convert, a BOM,
values that are not objects."""


def _json_edits(record: dict) -> st.SearchStrategy[str]:
    """A manifest with one of its values replaced by an odd one, or keys dropped."""
    odd = st.one_of(st.none(), st.booleans(), st.integers(-2**70, 2**70),
                    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=20),
                    st.lists(st.integers(), max_size=3), st.builds(dict), st.builds(list),
                    st.builds(lambda: {"fx": "x"}))

    @st.composite
    def edit(draw: st.DrawFn) -> str:
        out = json.loads(json.dumps(record))
        for _ in range(draw(st.integers(1, 3))):
            if not out:
                break
            # a value at depth 1..3 (inside objects and lists) replaced, or a key dropped
            holder, key = out, draw(st.sampled_from(sorted(out)))
            for _depth in range(draw(st.integers(0, 2))):
                inner = holder[key]
                if isinstance(inner, dict) and inner:
                    holder, key = inner, draw(st.sampled_from(sorted(inner)))
                elif isinstance(inner, list) and inner:
                    holder, key = inner, draw(st.integers(0, len(inner) - 1))
            if isinstance(holder, dict) and draw(st.booleans()):
                del holder[key]
            else:
                holder[key] = draw(odd)
        return json.dumps(out, allow_nan=True)

    return edit()


# -- prepared folders ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def prepared(tmp_path_factory) -> dict[str, Path]:
    """A prepared folder of each dataset: NYUv2 from the real samples (with split files and a
    manifest), SUN RGB-D and Cityscapes from the tiny official trees, synthrooms rendered small."""
    base = tmp_path_factory.mktemp("prepared")
    out: dict[str, Path] = {}
    nyu = base / "nyuv2"
    shutil.copytree(_nyu_samples(), nyu)
    (nyu / "train.txt").write_text("000433\n")
    (nyu / "test.txt").write_text("000464\n")
    nyuv2.write_manifest(nyu, make_manifest("nyuv2", source=nyu, splits={"train": 1, "test": 1},
                                            num_classes=40))
    out["nyuv2"] = nyu
    sun_src = base / "sun_source"
    write_sun_source(sun_src)
    sunrgbd.prepare_sunrgbd(sun_src, base / "sunrgbd")
    out["sunrgbd"] = base / "sunrgbd"
    city_src = base / "city_source"
    write_city_tree(city_src, {"val": [("lindau", "lindau_000000_000019")]})
    cs.prepare_cityscapes(city_src, base / "cityscapes")
    out["cityscapes"] = base / "cityscapes"
    sr.prepare_synthrooms(base / "synthrooms", rooms=3, frames_per_room=1, size=(16, 16))
    out["synthrooms"] = base / "synthrooms"
    return out


DEFAULT_SPLIT = {"nyuv2": "test", "sunrgbd": "test", "cityscapes": "val", "synthrooms": "test"}


@pytest.mark.parametrize("name", ["nyuv2", "sunrgbd", "cityscapes", "synthrooms"])
def test_fuzz_manifest(name, prepared, tmp_path_factory):
    folder = tmp_path_factory.mktemp(f"manifest_{name}") / name
    shutil.copytree(prepared[name], folder)
    manifest = folder / MANIFEST
    original = manifest.read_bytes()
    record = json.loads(original)

    @given(st.one_of(mutated_bytes(original), _json_edits(record), ODD_JSON,
                     text_lines(original.decode().splitlines())))
    def inner(data):
        write_variant(manifest, data)
        check_file("datasets/manifest", lambda: _read_frame(folder, DEFAULT_SPLIT[name]),
                   manifest, names=(folder.name, MANIFEST))

    inner()


# (dataset, list file relative to the folder, split that reads it)
ID_LISTS = [("nyuv2", "test.txt", "test"), ("sunrgbd", "test/frames.txt", "test"),
            ("cityscapes", "val.txt", "val"), ("synthrooms", "test.txt", "test"),
            ("synthrooms", "poses.txt", "test")]


@pytest.mark.parametrize("name,rel,split", ID_LISTS)
def test_fuzz_id_lists(name, rel, split, prepared, tmp_path_factory):
    folder = tmp_path_factory.mktemp(f"ids_{name}") / name
    shutil.copytree(prepared[name], folder)
    target = folder / rel
    original = target.read_bytes()

    lines = original.decode().splitlines()

    @st.composite
    def quaternion(draw: st.DrawFn) -> str:
        """poses.txt with a frame's quaternion zero, tiny or huge."""
        out = list(lines)
        i = draw(st.integers(1, len(out) - 1))
        fields = out[i].split()
        q = draw(st.sampled_from(["0", "1e-320", "1e308", "1e200", "-0"]))
        fields[6:10] = [q, q, q, q] if draw(st.booleans()) else [q, "0", "0", "0"]
        out[i] = " ".join(fields)
        return "\n".join(out) + "\n"

    strategies = [mutated_bytes(original), text_lines(lines), st.binary(max_size=64)]
    if rel == "poses.txt":
        strategies.append(quaternion())

    @given(st.one_of(*strategies))
    def inner(data):
        write_variant(target, data)
        check_file("datasets/id-list", lambda: _read_frame(folder, split), target,
                   names=(folder.name,))

    inner()


# -- prepared label and depth PNGs --------------------------------------------------------------
def _label_variants(labels: np.ndarray) -> st.SearchStrategy[bytes]:
    """Format-aware label PNGs: wrong mode, size, values beyond the classes, 16 bits, palette."""
    h, w = labels.shape

    @st.composite
    def variant(draw: st.DrawFn) -> bytes:
        kind = draw(st.sampled_from(["rgb", "size", "values", "16bit", "palette", "tiny",
                                     "la", "float", "onebit"]))
        if kind == "rgb":
            return _png(np.stack([labels] * 3, axis=2))
        if kind == "size":
            return _png(labels[:draw(st.integers(1, h)), :draw(st.integers(1, w))])
        if kind == "values":
            out = labels.copy()
            out[draw(st.integers(0, h - 1)), :] = draw(st.integers(40, 254))
            return _png(out)
        if kind == "16bit":
            return _png(labels.astype(np.uint16) * draw(st.sampled_from([1, 257, 300])))
        if kind == "palette":
            return _png(labels, "P")
        if kind == "tiny":
            return _png(np.zeros((1, 1), np.uint8))
        if kind == "la":
            return _png(labels, "LA")
        if kind == "float":
            buf = io.BytesIO()
            Image.fromarray(labels.astype(np.float32)).save(buf, format="TIFF")
            return buf.getvalue()
        return _png(labels, "1")

    return variant()


def test_fuzz_label_png(prepared, tmp_path_factory):
    folder = tmp_path_factory.mktemp("labels") / "nyuv2"
    shutil.copytree(prepared["nyuv2"], folder)
    target = folder / "label40" / "000464.png"
    original = target.read_bytes()
    labels = np.asarray(Image.open(io.BytesIO(original)))

    huge = st.sampled_from([*HUGE_PNGS, idat_claim(original)])

    @given(st.one_of(mutated_bytes(original), _label_variants(labels), huge), st.booleans())
    def inner(data, direct):
        write_variant(target, data)
        if direct:
            check_file("datasets/label-png", lambda: read_label_png(target, 40, (480, 640)),
                       target)
        else:
            check_file("datasets/label-png", lambda: _read_frame(folder, "test"), target)

    inner()


def test_fuzz_depth_png(prepared, tmp_path_factory):
    folder = tmp_path_factory.mktemp("depth") / "nyuv2"
    shutil.copytree(prepared["nyuv2"], folder)
    target = folder / "depth" / "000464.png"
    original = target.read_bytes()
    depth = np.asarray(Image.open(io.BytesIO(original)))
    variants = st.sampled_from([
        _png(depth.astype(np.uint8)), _png(np.stack([depth.astype(np.uint8)] * 3, axis=2)),
        _png(depth[:100]), _png(depth.astype(np.uint8), "P"), b"", b"\x89PNG\r\n\x1a\n",
        *HUGE_PNGS, idat_claim(original)])

    @given(st.one_of(mutated_bytes(original), variants))
    def inner(data):
        write_variant(target, data)
        check_file("datasets/depth-png", lambda: _read_frame(folder, "test"), target)

    inner()


# -- NYUv2's MATLAB files -----------------------------------------------------------------------
@pytest.fixture(scope="module")
def nyu_source(tmp_path_factory) -> Path:
    """The official NYUv2 files with two frames (the labelled .mat as small as the layout
    allows)."""
    from tests.datasets.datasets_fixtures import nyu_arrays

    root = tmp_path_factory.mktemp("nyu_source")
    arrays = {k: v[:2] for k, v in nyu_arrays(2).items()}
    write_nyu_source(root, arrays)
    scipy.io.savemat(root / nyuv2.SPLITS_MAT, {"trainNdxs": np.array([[1.0]]),
                                               "testNdxs": np.array([[2.0]])})
    return root


def _mat_variant(value: object, key: str) -> bytes:
    buf = io.BytesIO()
    scipy.io.savemat(buf, {key: value})
    return buf.getvalue()


@pytest.mark.parametrize("name,key", [(nyuv2.SPLITS_MAT, "trainNdxs"),
                                      (nyuv2.MAPPING_MAT, "mapClass")])
def test_fuzz_nyuv2_mat_v5(name, key, nyu_source, tmp_path_factory):
    """The small MATLAB v5 files (split indices, class mapping): bytes mutated, variables of the
    wrong type, shape or values, as ``prepare_nyuv2`` reads them."""
    folder = tmp_path_factory.mktemp("nyu_v5")
    target = folder / name
    original = (nyu_source / name).read_bytes()
    odd = st.sampled_from([
        _mat_variant(np.array([[np.nan, 1.0]]), key), _mat_variant(np.array([["abc"]]), key),
        _mat_variant(np.zeros((0, 0)), key), _mat_variant(np.array([[1e300]]), key),
        _mat_variant(np.array([[-5]], dtype=np.int8), key),
        _mat_variant(np.array([[1.5, 2.0]]), key), _mat_variant({"a": 1}, key),
        _mat_variant(np.array([[1 + 2j]]), key), _mat_variant(np.ones((894, 2)), key),
        _mat_variant(np.array([[True, False]]), key), _mat_variant(np.array([[1.0]]), "other"),
        _mat_variant(np.array([[2**62]], dtype=np.uint64), key)])
    read = nyuv2._split_indices if name == nyuv2.SPLITS_MAT else \
        (lambda path, count=None: nyuv2._mapping_lut(path))

    @given(st.one_of(mutated_bytes(original), odd))
    def inner(data):
        write_variant(target, data)
        check_file("datasets/nyuv2-mat-v5", lambda: read(target, 2), target)

    inner()


def _h5_mat(path: Path, datasets: dict[str, np.ndarray | tuple]) -> None:
    """A MATLAB v7.3 file: arrays, or (shape, dtype) for a chunked dataset with nothing
    written (a huge claimed size costs nothing on disk)."""
    with h5_matlab(path) as f:
        for key, value in datasets.items():
            if isinstance(value, tuple):
                shape, dtype = value
                f.create_dataset(key, shape=shape, dtype=dtype,
                                 chunks=tuple(min(s, 64) or 1 for s in shape))
            else:
                f.create_dataset(key, data=value)
    stamp_matlab_header(path)


H5_VARIANTS = {
    "huge mapClass": {"mapClass": ((10**6, 10**6), "f8")},
    "string mapClass": {"mapClass": np.array([b"abc"])},
    "mapClass 3-D": {"mapClass": np.ones((2, 447, 1))},
    "mapClass NaN": {"mapClass": np.full((1, 894), np.nan)},
    "compound": {"mapClass": np.zeros(894, dtype=[("a", "f8"), ("b", "i4")])},
    "group": {},
    "scalar": {"mapClass": np.float64(3.0)},
    "empty": {"mapClass": np.zeros((0,))},
}


@pytest.mark.parametrize("variant", sorted(H5_VARIANTS))
def test_nyuv2_mat_hdf5_variants(variant, tmp_path):
    """Format-aware v7.3 class mappings (HDF5): wrong dtypes and shapes, a 10^12-element claim."""
    target = tmp_path / nyuv2.MAPPING_MAT
    _h5_mat(target, H5_VARIANTS[variant])
    if variant == "group":
        with h5py.File(target, "a") as f:
            f.create_group("mapClass")
    check_file("datasets/nyuv2-mat-hdf5", lambda: nyuv2._mapping_lut(target), target)
    check_file("datasets/nyuv2-mat-hdf5", lambda: load_mat(target, ["mapClass"], "mapping"),
               target)


LABELLED_VARIANTS = {
    "images huge N": {"images": ((10**9, 3, 640, 480), "u1")},
    "images wrong dtype": {"images": ((1, 3, 640, 480), "f8"), "depths": ((1, 640, 480), "f4"),
                           "labels": ((1, 640, 480), "u2")},
    "labels float": {"images": ((1, 3, 640, 480), "u1"), "depths": ((1, 640, 480), "f4"),
                     "labels": np.full((1, 640, 480), 3.7, np.float32)},
    "labels negative": {"images": ((1, 3, 640, 480), "u1"), "depths": ((1, 640, 480), "f4"),
                        "labels": np.full((1, 640, 480), -3, np.int16)},
    "labels NaN": {"images": ((1, 3, 640, 480), "u1"), "depths": ((1, 640, 480), "f4"),
                   "labels": np.full((1, 640, 480), np.nan, np.float32)},
    "depths string": {"images": ((1, 3, 640, 480), "u1"), "depths": np.array([b"x"]),
                      "labels": ((1, 640, 480), "u2")},
    "images 3-D": {"images": ((3, 640, 480), "u1")},
    "depths complex": {"images": ((1, 3, 640, 480), "u1"), "depths": ((1, 640, 480), "c8"),
                       "labels": ((1, 640, 480), "u2")},
}


@pytest.mark.parametrize("variant", sorted(LABELLED_VARIANTS))
def test_nyuv2_labelled_variants(variant, nyu_source, tmp_path, capsys):
    """``evsmap datasets prepare nyuv2`` on labelled files with wrong shapes, dtypes and values."""
    src = tmp_path / "src"
    shutil.copytree(nyu_source, src, ignore=shutil.ignore_patterns(nyuv2.LABELLED_MAT))
    _h5_mat(src / nyuv2.LABELLED_MAT, LABELLED_VARIANTS[variant])
    check_cli("datasets/prepare-cli", ["datasets", "prepare", "nyuv2", "--from", str(src),
                                       "--out", str(tmp_path / "out")],
              (nyuv2.LABELLED_MAT, nyuv2.SPLITS_MAT), capsys)
    check_file("datasets/nyuv2-mat-hdf5",
               lambda: nyuv2.prepare_nyuv2(src, tmp_path / "out2"), src / nyuv2.LABELLED_MAT,
               names=(nyuv2.SPLITS_MAT,))


def test_fuzz_nyuv2_labelled_bytes(nyu_source, tmp_path_factory):
    """Byte mutations of the (two-frame) labelled v7.3 file, through ``prepare_nyuv2``."""
    src = tmp_path_factory.mktemp("nyu_bytes")
    for name in (nyuv2.SPLITS_MAT, nyuv2.MAPPING_MAT):
        shutil.copyfile(nyu_source / name, src / name)
    original = (nyu_source / nyuv2.LABELLED_MAT).read_bytes()
    out_root = tmp_path_factory.mktemp("nyu_bytes_out")
    counter = iter(range(10**9))

    @given(mutated_bytes(original))
    def inner(data):
        target = write_variant(src / nyuv2.LABELLED_MAT, data)
        out = out_root / f"out{next(counter)}"
        check_file("datasets/nyuv2-mat-hdf5", lambda: nyuv2.prepare_nyuv2(src, out), target,
                   names=(nyuv2.SPLITS_MAT,))
        shutil.rmtree(out, ignore_errors=True)

    inner()


# -- SUN RGB-D's official tree ------------------------------------------------------------------
@pytest.fixture(scope="module")
def sun_source(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("sun") / "src"
    write_sun_source(root)
    return root


def _sun_prepare(src: Path, out: Path) -> None:
    try:
        sunrgbd.prepare_sunrgbd(src, out)
    finally:
        shutil.rmtree(out, ignore_errors=True)


SUN_SCENE = "kv1/NYUdata/NYU0001"


@pytest.mark.parametrize("rel", ["intrinsics.txt", "depth_bfx/img_0000.png",
                                 "image/img_0000.jpg"])
def test_fuzz_sunrgbd_scene_files(rel, sun_source, tmp_path_factory):
    """A scene's ``intrinsics.txt`` (lines and bytes), refined depth PNG and colour JPEG."""
    src = tmp_path_factory.mktemp("sun_scene") / "src"
    shutil.copytree(sun_source, src)
    target = src / "SUNRGBD" / SUN_SCENE / rel
    original = target.read_bytes()
    out = src.parent / "out"
    strategies = [mutated_bytes(original)]
    if rel.endswith((".png", ".jpg")):
        strategies.append(st.sampled_from(HUGE_PNGS))
    if rel.endswith(".txt"):
        strategies.append(text_lines(original.decode().splitlines()))

    @given(st.one_of(*strategies))
    def inner(data):
        write_variant(target, data)
        check_file("datasets/sunrgbd-raw", lambda: _sun_prepare(src, out), target)

    inner()


@pytest.mark.parametrize("name", ["SUNRGBD2Dseg.mat", "SUNRGBDMeta.mat"])
def test_fuzz_sunrgbd_mat(name, sun_source, tmp_path_factory):
    """The segmentation (v7.3, object references) and metadata (v5 structs) files."""
    src = tmp_path_factory.mktemp("sun_mat") / "src"
    shutil.copytree(sun_source, src)
    target = src / "SUNRGBDtoolbox" / "Metadata" / name
    original = target.read_bytes()
    out = src.parent / "out"
    strategies = [mutated_bytes(original)]
    if name == "SUNRGBDMeta.mat":  # the compressed form too (what MATLAB writes)
        buf = io.BytesIO()
        scipy.io.savemat(buf, {"SUNRGBDMeta": scipy.io.loadmat(target)["SUNRGBDMeta"]},
                         do_compression=True)
        strategies.append(mutated_bytes(buf.getvalue()))

    @given(st.one_of(*strategies))
    def inner(data):
        write_variant(target, data)
        check_file("datasets/sunrgbd-raw", lambda: _sun_prepare(src, out), target)

    inner()


SEG_VARIANTS = {
    "labels huge": ((10**6, 10**6), "f8"),
    "labels string": np.array([b"abc", b"d"]),
    "labels 3-D": np.ones((2, 12, 16)),
    "labels negative": np.full((16, 12), -1.0),
    "labels NaN": np.full((16, 12), np.nan),
    "labels too big": np.full((16, 12), 40.0),
    "labels complex": np.ones((16, 12), np.complex64),
    "labels wrong size": np.ones((5, 5)),
}


@pytest.mark.parametrize("variant", sorted(SEG_VARIANTS))
def test_sunrgbd_seg_variants(variant, sun_source, tmp_path):
    """``SUNRGBD2Dseg.mat`` whose first label image is of the wrong kind."""
    src = tmp_path / "src"
    shutil.copytree(sun_source, src)
    seg = src / "SUNRGBDtoolbox" / "Metadata" / "SUNRGBD2Dseg.mat"
    with h5py.File(seg, "a") as f:
        del f["#refs#"]["r0"]
        value = SEG_VARIANTS[variant]
        if isinstance(value, tuple):
            ds = f["#refs#"].create_dataset("r0", shape=value[0], dtype=value[1], chunks=(64, 64))
        else:
            ds = f["#refs#"].create_dataset("r0", data=value)
        refs = f["SUNRGBD2Dseg"]["seglabel"][()]
        refs[0, 0] = ds.ref
        f["SUNRGBD2Dseg"]["seglabel"][...] = refs
    check_file("datasets/sunrgbd-raw", lambda: _sun_prepare(src, tmp_path / "out"), seg)


# -- Cityscapes' camera files and label PNGs ----------------------------------------------------
@pytest.fixture(scope="module")
def city_source(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("city") / "src"
    write_city_tree(root, {"val": [("lindau", "lindau_000000_000019")]})
    return root


CITY_STEM = "val/lindau/lindau_000000_000019"


def test_fuzz_cityscapes_camera(city_source):
    target = city_source / "camera" / f"{CITY_STEM}_camera.json"
    original = target.read_bytes()
    record = json.loads(original)
    lines = json.dumps(record, indent=1).splitlines()
    folder = target.parent

    @st.composite
    def nested(draw: st.DrawFn) -> str:
        out = json.loads(original)
        part = draw(st.sampled_from(["extrinsic", "intrinsic"]))
        key = draw(st.sampled_from(sorted(out[part])))
        out[part][key] = draw(st.one_of(
            st.none(), st.booleans(), st.text(max_size=5), st.integers(-2**80, 2**80),
            st.sampled_from([10**400, -10**400, 10**308 * 10, 1e308]),
            st.floats(allow_nan=True, allow_infinity=True), st.just([1.0])))
        return json.dumps(out, allow_nan=True)

    @given(st.one_of(mutated_bytes(original), text_lines(lines), nested(), ODD_JSON))
    def inner(data):
        write_variant(folder / "fuzz_camera.json", data)
        check_file("datasets/cityscapes-camera",
                   lambda: cs.read_camera(folder / "fuzz_camera.json"),
                   folder / "fuzz_camera.json")

    inner()
    (folder / "fuzz_camera.json").unlink()


def test_fuzz_cityscapes_label_png(city_source, tmp_path_factory, capsys):
    src = tmp_path_factory.mktemp("city_labels") / "src"
    shutil.copytree(city_source, src)
    target = src / "gtFine" / f"{CITY_STEM}_gtFine_labelIds.png"
    original = target.read_bytes()
    ids = np.asarray(Image.open(io.BytesIO(original)))
    out = src.parent / "out"
    variants = st.sampled_from([
        _png(ids[:512]), _png(np.stack([ids] * 3, axis=2)), _png(ids.astype(np.uint16) * 300),
        _png(np.full_like(ids, 200)), _png(ids, "P"), _png(ids, "LA"), *HUGE_PNGS])

    @given(st.one_of(mutated_bytes(original), variants), st.booleans())
    def inner(data, cli):
        write_variant(target, data)
        shutil.rmtree(out, ignore_errors=True)
        if cli:
            check_cli("datasets/prepare-cli",
                      ["datasets", "prepare", "cityscapes", "--from", str(src), "--out",
                       str(out)], (target.name,), capsys)
        else:
            check_file("datasets/cityscapes-label",
                       lambda: cs.prepare_cityscapes(src, out), target)

    inner()


def test_fuzz_cityscapes_camera_cli(city_source, tmp_path_factory, capsys):
    """``evsmap datasets prepare cityscapes`` with a mutated camera file."""
    src = tmp_path_factory.mktemp("city_cam") / "src"
    shutil.copytree(city_source, src)
    target = src / "camera" / f"{CITY_STEM}_camera.json"
    original = target.read_bytes()
    out = src.parent / "out"

    @given(mutated_bytes(original))
    def inner(data):
        write_variant(target, data)
        shutil.rmtree(out, ignore_errors=True)
        check_cli("datasets/prepare-cli", ["datasets", "prepare", "cityscapes", "--from",
                                           str(src), "--out", str(out)], (target.name,), capsys)

    inner()


def test_fuzz_datasets_list_cli(prepared, tmp_path_factory, capsys):
    """``evsmap datasets list`` over a root whose prepared folders' manifests are damaged."""
    root = tmp_path_factory.mktemp("list_root")
    for name in ("nyuv2", "synthrooms"):
        shutil.copytree(prepared[name], root / name)
    manifest = root / "nyuv2" / MANIFEST
    original = manifest.read_bytes()
    record = json.loads(original)
    listed = {k: record[k] for k in ("format", "name", "splits", "version", "source")}

    @given(st.one_of(mutated_bytes(original), _json_edits(record), _json_edits(listed), ODD_JSON),
           st.booleans())
    def inner(data, as_json):
        write_variant(manifest, data)
        check_cli("datasets/list-cli", ["datasets", "list", "--root", str(root)]
                  + (["--json"] if as_json else []), (MANIFEST, "nyuv2"), capsys)

    inner()


@pytest.mark.parametrize("record", [{"name": "nyuv2", "splits": [1, 2]},
                                    {"name": 5, "splits": {"train": 1}},
                                    {"name": "nyuv2", "splits": "train"}])
def test_datasets_list_with_odd_manifest_fields(tmp_path, capsys, record):
    from evsmap.cli.main import main

    (tmp_path / "a").mkdir()
    (tmp_path / "a" / MANIFEST).write_text(json.dumps({"format": "evsmap-dataset", **record}))
    assert main(["datasets", "list", "--root", str(tmp_path)]) == 0
    assert capsys.readouterr().out.split("  ")[-1].strip() == (
        f"{tmp_path / 'a' / MANIFEST}: \"name\" must be a string and \"splits\" an object "
        "(frames per split)")


META_VARIANTS = {
    "rgbname climbs": ("rgbname", "../../../../evil.jpg"),
    "depthname path": ("depthname", "sub/x.png"),
    "rgbpath climbs": ("rgbpath", "/n/SUNRGBD/../../../etc/image/img_0000.jpg"),
    "rgbpath number": ("rgbpath", 5.0),
    "rgbname empty": ("rgbname", np.zeros((0, 0))),
    "K strings": ("K", np.array([["a", "b", "c"]] * 3)),
    "K complex": ("K", np.eye(3) * (1 + 1j)),
    "K NaN": ("K", np.full((3, 3), np.nan)),
    "K shape": ("K", np.ones((2, 5))),
    "K struct": ("K", {"a": 1.0}),
}


@pytest.mark.parametrize("variant", sorted(META_VARIANTS))
def test_sunrgbd_meta_variants(variant, sun_source, tmp_path, capsys):
    """``SUNRGBDMeta.mat`` whose first frame has a field of the wrong kind (the camera matrix
    counts when the scene has no intrinsics.txt), through ``evsmap datasets prepare sunrgbd``."""
    src = tmp_path / "src"
    shutil.copytree(sun_source, src)
    meta_path = src / "SUNRGBDtoolbox" / "Metadata" / "SUNRGBDMeta.mat"
    meta = scipy.io.loadmat(meta_path)["SUNRGBDMeta"]
    field, value = META_VARIANTS[variant]
    meta[0, 0][field] = value
    scipy.io.savemat(meta_path, {"SUNRGBDMeta": meta})
    (src / "SUNRGBD" / SUN_SCENE / "intrinsics.txt").unlink()
    check_cli("datasets/prepare-cli", ["datasets", "prepare", "sunrgbd", "--from", str(src),
                                       "--out", str(tmp_path / "out")],
              ("SUNRGBDMeta.mat", "intrinsics.txt"), capsys)
    assert not list(tmp_path.rglob("evil*"))


@pytest.mark.parametrize("rel", [f"leftImg8bit/{CITY_STEM}_leftImg8bit.png",
                                 f"disparity/{CITY_STEM}_disparity.png"])
def test_fuzz_cityscapes_images(rel, city_source, tmp_path_factory):
    """The colour and disparity PNGs: header-checked by ``prepare_cityscapes`` (the prepared
    folder is then read, frame 0), and decoded by the reader of the official tree."""
    src = tmp_path_factory.mktemp("city_images") / "src"
    shutil.copytree(city_source, src)
    target = src / rel
    original = target.read_bytes()
    out = src.parent / "out"

    def prepare_and_read() -> None:
        shutil.rmtree(out, ignore_errors=True)
        cs.prepare_cityscapes(src, out)
        _read_frame(out, "val", resolution="2048x1024")

    huge = st.sampled_from([*HUGE_PNGS, idat_claim(original)])

    @given(st.one_of(mutated_bytes(original), huge), st.booleans())
    def inner(data, prepare):
        write_variant(target, data)
        if prepare:
            check_file("datasets/cityscapes-images", prepare_and_read, target)
        else:
            check_file("datasets/cityscapes-images", lambda: _read_frame(src, "val"), target)

    inner()


def _mat_with_tag_type(mdtype: int) -> bytes:
    """A MATLAB v5 file (a cell holding a string, as SUNRGBDMeta's sequenceName) whose string
    data element claims type ``mdtype``."""
    buf = io.BytesIO()
    cell = np.empty((1, 1), dtype=object)
    cell[0, 0] = "kv1/NYUdata/NYU0001"
    scipy.io.savemat(buf, {"SUNRGBDMeta": cell})
    data = bytearray(buf.getvalue())
    text = "kv1/NYUdata/NYU0001".encode("utf-16-le")
    i = data.find(text)
    if i < 0:
        i = data.find(b"kv1/")
    data[i - 8:i - 4] = mdtype.to_bytes(4, "little")
    return bytes(data)


@pytest.mark.parametrize("mdtype", [0x6410, 0, 8, 10, 11, 19, 255])
def test_mat5_unknown_element_type_is_refused_before_scipy(mdtype, tmp_path):
    """scipy's compiled reader crashes the interpreter (SIGSEGV) on some unknown element types:
    the structure check refuses them first. Run in a child process, so a regression fails this
    test instead of killing the run."""
    import subprocess
    import sys

    path = tmp_path / "SUNRGBDMeta.mat"
    path.write_bytes(_mat_with_tag_type(mdtype))
    code = ("import sys; from pathlib import Path; from evsmap.datasets.common import "
            "loadmat_checked; from evsmap.errors import DataFormatError\n"
            "try:\n    loadmat_checked(Path(sys.argv[1]), squeeze_me=True, "
            "struct_as_record=False)\nexcept DataFormatError as exc:\n    print(exc)\n")
    done = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout == f"{path}: not a readable MATLAB file (unknown data type {mdtype})\n"
