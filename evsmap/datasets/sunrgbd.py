"""SUN RGB-D (Song et al., CVPR 2015), 37 classes: reader of the prepared layout and
:func:`prepare_sunrgbd`.

Source (:func:`prepare_sunrgbd` reads the official release as unzipped)::

    SUNRGBD/<sensor>/<dataset>/.../<scene>/image/<name>.jpg
                                          /depth_bfx/<name>.png   refined depth (depth/: raw)
                                          /intrinsics.txt          3x3 K, row-major
    SUNRGBDtoolbox/Metadata/SUNRGBDMeta.mat         SUNRGBDMeta(i).rgbpath/.rgbname/.depthname
    SUNRGBDtoolbox/Metadata/SUNRGBD2Dseg.mat        v7.3: SUNRGBD2Dseg(i).seglabel, 0 void, 1..37
    SUNRGBDtoolbox/traintestSUNRGBD/allsplit.mat    alltrain / alltest: scene folders

Frame ``i`` of ``SUNRGBDMeta`` has the labels ``SUNRGBD2Dseg(i).seglabel``; it is a training
frame when its scene folder is in ``alltrain`` (5285 frames), else a test frame (5050; frames in
neither list go to test as in the usual preparation scripts and are counted in the manifest).
Depth PNGs store millimetres rotated by 3 bits: ``mm = (v >> 3) | (v << 13)`` on 16 bits (the
toolbox's ``read3dPoints.m``; the toolbox also clamps to 8 m for its point clouds, evsmap does
not).

Prepared layout (``NNNNN`` numbers the frames of a split from 1 in ``SUNRGBDMeta`` order)::

    <split>/rgb/NNNNN.png      8-bit RGB (sizes differ between sensors)
    <split>/depth/NNNNN.png    uint16 millimetres (decoded), 0 = invalid
    <split>/label37/NNNNN.png  uint8 0..36 (seg37list order), 255 = void
    <split>/frames.txt         "id fx fy cx cy width height scene" per frame
    evsmap-dataset.json
"""

from __future__ import annotations

from pathlib import Path, PurePosixPath

import numpy as np

from evsmap.classes import SUNRGBD37_CLASSES, palette
from evsmap.data import VOID, Intrinsics
from evsmap.datasets.common import (
    H5_ERRORS,
    Progress,
    SegmentationSequence,
    apply_limit,
    check_frame_id,
    check_limit,
    check_shape,
    is_hdf5,
    load_mat,
    loadmat_checked,
    make_manifest,
    mat_strings,
    open_prepared,
    read_h5_array,
    read_label_png,
    read_manifest,
    require_dir,
    require_file,
    write_manifest,
)
from evsmap.errors import DataFormatError, EvsmapError
from evsmap.fileio import atomic_write_text, staging_folder
from evsmap.readers.images import read_rgb, read_uint16, write_png
from evsmap.registry import READERS, Takes

NAME = "sunrgbd"
SPLITS = ("train", "test")
OFFICIAL_COUNTS = {"train": 5285, "test": 5050}
NUM_CLASSES = len(SUNRGBD37_CLASSES)
DEPTH_SCALE = 1000.0
"""Depth PNG value per metre in the prepared layout (millimetres)."""
DATA_DIR = "SUNRGBD"
META_MAT = Path("SUNRGBDtoolbox", "Metadata", "SUNRGBDMeta.mat")
SEG_MAT = Path("SUNRGBDtoolbox", "Metadata", "SUNRGBD2Dseg.mat")
SPLIT_MAT = Path("SUNRGBDtoolbox", "traintestSUNRGBD", "allsplit.mat")
RGB_DIR, DEPTH_DIR, LABEL_DIR = "rgb", "depth", "label37"
FRAMES_FILE = "frames.txt"


def decode_depth(raw: np.ndarray) -> np.ndarray:
    """SUN RGB-D depth PNG values -> ``uint16`` millimetres (the 3-bit rotation undone)."""
    v = raw.astype(np.uint32)
    return (((v >> 3) | (v << 13)) & 0xFFFF).astype(np.uint16)


def _read_frames_file(path: Path) -> list[tuple[str, Intrinsics, str]]:
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise DataFormatError(f"{path}: frame list not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DataFormatError(f"{path}: cannot read ({exc})") from None
    rows = []
    for number, line in enumerate(text.splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        parts = line.split(maxsplit=7)
        if len(parts) < 7:
            raise DataFormatError(f"{path}:{number}: expected 'id fx fy cx cy width height "
                                  f"scene', got {line!r}")
        try:
            fx, fy, cx, cy = (float(v) for v in parts[1:5])
            intr = Intrinsics(fx, fy, cx, cy, int(parts[5]), int(parts[6]))
        except (ValueError, EvsmapError) as exc:
            raise DataFormatError(f"{path}:{number}: bad intrinsics ({exc})") from None
        check_frame_id(parts[0], f"{path}:{number}")
        rows.append((parts[0], intr, parts[7] if len(parts) > 7 else ""))
    return rows


class SUNRGBDSequence(SegmentationSequence):
    """A prepared SUN RGB-D folder (see the module docstring).

    Args:
        path: the folder holding ``train/`` and ``test/``.
        split: ``train``, ``test`` or ``all`` (train then test).
        limit: keep the first ``limit`` frames.

    SUN RGB-D mixes four sensors and image sizes: every frame carries its own intrinsics (from
    ``frames.txt``), and the sequence's ``intrinsics`` are those of its first frame. Frames are
    named ``<split>/<id>``; poses are absent (identity, ``timestamp = index``).
    """

    def __init__(self, *, path: str | Path, split: str = "all", limit: int | None = None) -> None:
        root = open_prepared(path, split, limit, SPLITS, NAME)
        manifest = read_manifest(root)
        if manifest is not None and manifest.get("name") != NAME:
            raise DataFormatError(f"{root}: the manifest says dataset {manifest.get('name')!r}, "
                                  f"not {NAME!r}")
        wanted: tuple[str, ...] = SPLITS if split == "all" else (split,)
        if split == "all":
            wanted = tuple(s for s in SPLITS if (root / s).is_dir()) or SPLITS
        self.root = root
        self.folder = Path(root)
        self.entries: list[tuple[str, str, Intrinsics]] = []
        for s in wanted:
            require_dir(root / s, f"SUN RGB-D {s} split")
            for sub in (RGB_DIR, DEPTH_DIR, LABEL_DIR):
                require_dir(root / s / sub, f"SUN RGB-D {s}/{sub}")
            rows = _read_frames_file(root / s / FRAMES_FILE)
            rows.sort(key=lambda r: (len(r[0]), r[0]))
            self.entries.extend((s, fid, intr) for fid, intr, _scene in rows)
        self.entries = apply_limit(self.entries, limit)
        if not self.entries:
            raise DataFormatError(f"{root}: no frames in split {split!r}")
        sizes = sorted({f"{e[2].width}x{e[2].height}" for e in self.entries})
        super().__init__(
            root.resolve().name, self.entries[0][2], layout=NAME, split=split,
            class_names=SUNRGBD37_CLASSES, class_colors=palette(NUM_CLASSES), path=root,
            names=[f"{s}/{fid}" for s, fid, _ in self.entries],
            meta={"intrinsics_source": "per frame (frames.txt); first frame shown",
                  "depth_scale": DEPTH_SCALE, "sizes": sizes, "dataset": manifest})

    def load(self, index: int):
        split, fid, intr = self.entries[index]
        base = self.root / split
        rgb_path = base / RGB_DIR / f"{fid}.png"
        depth_path = base / DEPTH_DIR / f"{fid}.png"
        rgb = read_rgb(rgb_path)
        check_shape(rgb_path, rgb.shape, intr.shape, f"image (per {FRAMES_FILE})")
        raw = read_uint16(depth_path)
        check_shape(depth_path, raw.shape, intr.shape, "depth")
        labels = read_label_png(base / LABEL_DIR / f"{fid}.png", NUM_CLASSES, intr.shape)
        return rgb, raw.astype(np.float32) / np.float32(DEPTH_SCALE), intr, labels


def is_sunrgbd_folder(path: Path) -> bool:
    path = Path(path)
    return any((path / s / FRAMES_FILE).is_file() and (path / s / LABEL_DIR).is_dir()
               for s in SPLITS)


@READERS.register(NAME, takes=Takes(path=True, split=True, limit=True),
                  detect=is_sunrgbd_folder,
                  description="SUN RGB-D, 37 classes, mixed sensors (folder written by "
                              "`evsmap datasets prepare sunrgbd`)")
def open_sunrgbd(*, path: str, split: str = "all", limit: int | None = None) -> SUNRGBDSequence:
    """SUN RGB-D, 37 classes, mixed sensors (prepared folder: train/, test/)."""
    return SUNRGBDSequence(path=path, split=split, limit=limit)


# -- preparation --------------------------------------------------------------------------------
def scene_key(path: str) -> str | None:
    """``kv1/NYUdata/NYU0001`` from ``/n/fs/sun3d/data/SUNRGBD/kv1/NYUdata/NYU0001[/...]``: the
    part after the ``SUNRGBD`` folder (``None`` when there is none)."""
    parts = PurePosixPath(path.replace("\\", "/").strip()).parts
    if DATA_DIR not in parts:
        return None
    rest = parts[parts.index(DATA_DIR) + 1:]
    return "/".join(rest) if rest else None


class _MetaEntry:
    __slots__ = ("index", "scene", "rgbname", "depthname", "K")

    def __init__(self, index: int, scene: str, rgbname: str, depthname: str, K: object) -> None:
        self.index, self.scene, self.rgbname, self.depthname, self.K = \
            index, scene, rgbname, depthname, K


def _load_meta(path: Path) -> list[_MetaEntry]:
    require_file(path, "SUN RGB-D frame metadata")
    data = loadmat_checked(path, variable_names=["SUNRGBDMeta"], squeeze_me=True,
                           struct_as_record=False)
    if "SUNRGBDMeta" not in data:
        raise DataFormatError(f"{path}: has no variable 'SUNRGBDMeta'")
    entries = []
    for i, item in enumerate(np.atleast_1d(data["SUNRGBDMeta"]).ravel()):
        fields = {}
        for field in ("rgbpath", "rgbname", "depthname"):
            value = getattr(item, field, None)
            if not isinstance(value, str) or not value:
                raise DataFormatError(f"{path}: SUNRGBDMeta({i + 1}) has no {field}")
            fields[field] = value
        for field in ("rgbname", "depthname"):
            name = fields[field]
            if name in (".", "..") or any(c in name for c in "/\\\0"):
                raise DataFormatError(f"{path}: SUNRGBDMeta({i + 1}).{field} {name!r} is not a "
                                      "file name")
        rgb = PurePosixPath(fields["rgbpath"].replace("\\", "/"))
        key = scene_key(str(rgb.parent.parent)) if rgb.parent.name == "image" else None
        if key is None or ".." in key.split("/") or "\0" in key:
            raise DataFormatError(f"{path}: SUNRGBDMeta({i + 1}).rgbpath "
                                  f"{fields['rgbpath']!r} is not .../SUNRGBD/<scene>/image/<file>")
        entries.append(_MetaEntry(i, key, fields["rgbname"], fields["depthname"],
                                  getattr(item, "K", None)))
    if not entries:
        raise DataFormatError(f"{path}: SUNRGBDMeta is empty")
    return entries


def _split_keys(path: Path) -> dict[str, set[str]]:
    data = load_mat(path, ["alltrain", "alltest"], "SUN RGB-D train/test split")
    out: dict[str, set[str]] = {}
    for split, key in (("train", "alltrain"), ("test", "alltest")):
        try:
            names = mat_strings(data[key])
        except DataFormatError as exc:
            raise DataFormatError(f"{path}: {key}: {exc}") from None
        keys = {k for n in names if (k := scene_key(n.rstrip("/"))) is not None}
        if not keys:
            raise DataFormatError(f"{path}: {key} lists no .../SUNRGBD/<scene> folders")
        out[split] = keys
    return out


def _read_intrinsics(scene: Path, entry: _MetaEntry, width: int, height: int) -> Intrinsics:
    path = scene / "intrinsics.txt"
    if path.is_file():
        try:
            values = [float(v) for v in path.read_text().split()]
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise DataFormatError(f"{path}: expected 9 numbers (3x3 camera matrix) ({exc})") \
                from None
        if len(values) != 9:
            raise DataFormatError(f"{path}: expected 9 numbers (3x3 camera matrix), "
                                  f"got {len(values)}")
        K = np.array(values).reshape(3, 3)  # row-major, as the toolbox reads it
    elif entry.K is not None and np.asarray(entry.K).shape == (3, 3):
        K = np.asarray(entry.K)
        if K.dtype.kind not in "uif":
            raise DataFormatError(f"{path}: not found, and SUNRGBDMeta({entry.index + 1}).K is "
                                  f"not a numeric 3x3 matrix ({K.dtype})")
        K = K.astype(np.float64)
    else:
        raise DataFormatError(f"{path}: camera intrinsics not found")
    try:
        return Intrinsics(K[0, 0], K[1, 1], K[0, 2], K[1, 2], width, height)
    except EvsmapError as exc:
        raise DataFormatError(f"{path}: bad camera matrix ({exc})") from None


def _read_seglabel(f, refs: np.ndarray, entry: _MetaEntry, seg_path: Path) -> np.ndarray:
    import h5py

    ref = refs[entry.index]
    where = f"SUNRGBD2Dseg({entry.index + 1}).seglabel"
    try:
        obj = f[ref]
    except H5_ERRORS as exc:
        raise DataFormatError(f"{seg_path}: {where}: broken reference ({exc})") from None
    if not isinstance(obj, h5py.Dataset) or obj.ndim != 2:
        raise DataFormatError(f"{seg_path}: {where}: expected a 2-D label image")
    arr = read_h5_array(seg_path, obj, where).T  # MATLAB H x W stored column-major
    if arr.dtype.kind not in "uif":
        raise DataFormatError(f"{seg_path}: {where}: expected numeric labels, got {arr.dtype}")
    if arr.size and (not np.all(np.isfinite(arr)) or np.any(arr != np.round(arr))
                     or arr.min() < 0 or arr.max() > NUM_CLASSES):
        raise DataFormatError(f"{seg_path}: {where}: labels must be integers in "
                              f"0..{NUM_CLASSES} (0 void), got {arr.min()}..{arr.max()}")
    lut = np.concatenate([[VOID], np.arange(NUM_CLASSES)]).astype(np.uint8)
    return lut[arr.astype(np.int64)]


def _seglabel_refs(f, seg_path: Path, frames: int) -> np.ndarray:
    """The object references of ``SUNRGBD2Dseg.seglabel``, one per frame of the metadata."""
    import h5py

    try:
        if "SUNRGBD2Dseg" not in f or not isinstance(f["SUNRGBD2Dseg"], h5py.Group) \
                or "seglabel" not in f["SUNRGBD2Dseg"]:
            raise DataFormatError(f"{seg_path}: has no SUNRGBD2Dseg.seglabel")
        refs = read_h5_array(seg_path, f["SUNRGBD2Dseg"]["seglabel"],
                             "SUNRGBD2Dseg.seglabel").ravel()
    except H5_ERRORS as exc:
        raise DataFormatError(f"{seg_path}: unreadable HDF5 file ({exc})") from None
    if refs.dtype != h5py.ref_dtype and refs.dtype != object:
        raise DataFormatError(f"{seg_path}: SUNRGBD2Dseg.seglabel must hold object "
                              f"references, got {refs.dtype}")
    if len(refs) != frames:
        raise DataFormatError(f"{seg_path}: {len(refs)} label images but "
                              f"{META_MAT.name} lists {frames} frames")
    return refs


def prepare_sunrgbd(source_dir: str | Path, out_dir: str | Path, *, limit: int | None = None,
                    overwrite: bool = False, raw_depth: bool = False,
                    progress: Progress | None = None) -> dict:
    """Convert the official SUN RGB-D release in ``source_dir`` into the prepared layout.

    ``source_dir`` holds ``SUNRGBD/`` and ``SUNRGBDtoolbox/`` (see the module docstring).
    ``raw_depth`` reads ``depth/`` instead of the refined ``depth_bfx/``. ``limit`` keeps the
    first ``limit`` frames of each split; ``out_dir`` is written atomically (a non-empty one is
    refused unless ``overwrite``); ``progress`` wraps the list of frames. Returns the manifest.
    """
    import h5py

    src = Path(source_dir)
    require_dir(src, "SUN RGB-D source")
    check_limit(limit)
    data_dir = require_dir(src / DATA_DIR, "SUN RGB-D data (SUNRGBD.zip unpacked)")
    seg_path = require_file(src / SEG_MAT, "SUN RGB-D 2D segmentation")
    require_file(src / SPLIT_MAT, "SUN RGB-D split")
    meta = _load_meta(src / META_MAT)
    split_keys = _split_keys(src / SPLIT_MAT)
    assigned: dict[str, list[_MetaEntry]] = {s: [] for s in SPLITS}
    unlisted = 0
    for entry in meta:
        if entry.scene in split_keys["train"]:
            assigned["train"].append(entry)
        else:
            unlisted += entry.scene not in split_keys["test"]
            assigned["test"].append(entry)
    chosen = {s: apply_limit(assigned[s], limit) for s in SPLITS}
    tasks = [(s, n, e) for s in SPLITS for n, e in enumerate(chosen[s], 1)]
    if not is_hdf5(seg_path):
        raise DataFormatError(f"{seg_path}: not a MATLAB v7.3 (HDF5) file")
    depth_dir = "depth" if raw_depth else "depth_bfx"
    try:
        f = h5py.File(seg_path, "r")
    except H5_ERRORS as exc:
        raise DataFormatError(f"{seg_path}: unreadable HDF5 file ({exc})") from None
    with f, staging_folder(Path(out_dir), source=src, overwrite=overwrite) as stage:
        refs = _seglabel_refs(f, seg_path, len(meta))
        rows: dict[str, list[str]] = {s: [] for s in SPLITS}
        for s in SPLITS:
            for sub in (RGB_DIR, DEPTH_DIR, LABEL_DIR):
                (stage / s / sub).mkdir(parents=True)
        for split, number, entry in (progress(tasks) if progress else tasks):
            scene = data_dir / entry.scene
            rgb_path = scene / "image" / entry.rgbname
            depth_path = scene / depth_dir / entry.depthname
            for listed, what in ((rgb_path, "image"), (depth_path, "depth image")):
                if not listed.is_file():
                    raise DataFormatError(f"{listed}: {what} not found (listed by "
                                          f"SUNRGBDMeta({entry.index + 1}) in {META_MAT.name})")
            rgb = read_rgb(rgb_path)
            height, width = rgb.shape[:2]
            raw = read_uint16(depth_path)
            check_shape(depth_path, raw.shape, rgb.shape, "depth")
            labels = _read_seglabel(f, refs, entry, seg_path)
            if labels.shape != rgb.shape[:2]:
                raise DataFormatError(
                    f"{seg_path}: SUNRGBD2Dseg({entry.index + 1}).seglabel is "
                    f"{labels.shape[1]}x{labels.shape[0]} but {rgb_path} is {width}x{height}")
            intr = _read_intrinsics(scene, entry, width, height)
            fid = f"{number:05d}"
            write_png(stage / split / RGB_DIR / f"{fid}.png", rgb)
            write_png(stage / split / DEPTH_DIR / f"{fid}.png", decode_depth(raw))
            write_png(stage / split / LABEL_DIR / f"{fid}.png", labels)
            rows[split].append(f"{fid} {intr.fx!r} {intr.fy!r} {intr.cx!r} {intr.cy!r} "
                               f"{width} {height} {entry.scene}\n")
        for s in SPLITS:
            atomic_write_text(stage / s / FRAMES_FILE,
                              "# id fx fy cx cy width height scene (SUNRGBD/<scene>)\n"
                              + "".join(rows[s]))
        manifest = make_manifest(
            NAME, source=src, splits={s: len(chosen[s]) for s in SPLITS},
            official_counts=OFFICIAL_COUNTS, limit=limit, num_classes=NUM_CLASSES,
            class_names=list(SUNRGBD37_CLASSES), depth_scale=DEPTH_SCALE, void_label=VOID,
            depth_source=depth_dir, source_frames=len(meta), unlisted_in_allsplit=int(unlisted),
            layout={"rgb": f"<split>/{RGB_DIR}/NNNNN.png",
                    "depth": f"<split>/{DEPTH_DIR}/NNNNN.png",
                    "labels": f"<split>/{LABEL_DIR}/NNNNN.png",
                    "intrinsics": f"<split>/{FRAMES_FILE}"})
        write_manifest(stage, manifest)
    return manifest
