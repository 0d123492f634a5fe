"""NYU Depth v2, labelled set (Silberman et al., ECCV 2012), with the 40-class labels of Gupta et
al. (CVPR 2013): reader of the prepared layout and :func:`prepare_nyuv2`.

Prepared layout (what :func:`prepare_nyuv2` writes; ``NNNNNN`` is the 1-based index of the frame
in the official ``.mat`` file, as in ``splits.mat``)::

    rgb/NNNNNN.png       640x480 8-bit RGB
    depth/NNNNNN.png     uint16, metres = value / 5000, 0 = invalid (the in-painted depth)
    label40/NNNNNN.png   uint8 0..39 (NYUv2-40 standard order), 255 = void
    train.txt test.txt   one 6-digit id per line (795 / 654 frames)
    evsmap-dataset.json  manifest

A folder with ``rgb/``, ``depth/`` and ``label40/`` but no split files (such as the shared
samples) can be read with ``split="all"``.

Source files (:func:`prepare_nyuv2`): ``nyu_depth_v2_labeled.mat`` (MATLAB v7.3 = HDF5: ``images``
N x 3 x 640 x 480 uint8, ``depths`` N x 640 x 480 float metres, ``labels`` N x 640 x 480 with
0 = void and 1..894; h5py shows MATLAB's column-major 480x640x3xN arrays transposed),
``splits.mat`` (``trainNdxs``, ``testNdxs``: 1-based indices) and ``classMapping40.mat``
(``mapClass``: 1 x 894, the 40-class id 1..40 of each of the 894 classes).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from evsmap.classes import NYU40_CLASSES, palette
from evsmap.data import VOID, Intrinsics
from evsmap.datasets.common import (
    H5_ERRORS,
    Progress,
    SegmentationSequence,
    apply_limit,
    check_limit,
    check_shape,
    is_hdf5,
    load_mat,
    make_manifest,
    open_prepared,
    read_id_list,
    read_label_png,
    read_manifest,
    require_dir,
    require_file,
    write_manifest,
)
from evsmap.errors import DataFormatError
from evsmap.fileio import atomic_write_text, staging_folder
from evsmap.readers.images import read_rgb, read_uint16, write_png
from evsmap.registry import READERS, Takes

NAME = "nyuv2"
NYUV2_INTRINSICS = Intrinsics(5.1885790117450188e02, 5.1946961112127485e02,
                              3.2558244941119034e02, 2.5373616633400465e02, 640, 480)
"""Kinect RGB camera of NYU Depth v2 (``fx_rgb``, ``fy_rgb``, ``cx_rgb``, ``cy_rgb`` of the NYU
toolbox's ``camera_params.m``), 640x480."""
WIDTH, HEIGHT = 640, 480
DEPTH_SCALE = 5000.0
"""Depth PNG value per metre in the prepared layout (as TUM RGB-D)."""
NUM_CLASSES = len(NYU40_CLASSES)
NUM_SOURCE_CLASSES = 894
SPLITS = ("train", "test")
OFFICIAL_COUNTS = {"train": 795, "test": 654}
LABELLED_MAT = "nyu_depth_v2_labeled.mat"
SPLITS_MAT = "splits.mat"
MAPPING_MAT = "classMapping40.mat"
RGB_DIR, DEPTH_DIR, LABEL_DIR = "rgb", "depth", "label40"


def _sort_ids(ids: list[str]) -> list[str]:
    return sorted(ids, key=lambda s: (len(s), s))


class NYUv2Sequence(SegmentationSequence):
    """A prepared NYUv2 folder (see the module docstring).

    Args:
        path: the folder holding ``rgb/``, ``depth/``, ``label40/``.
        split: ``train`` / ``test`` (from ``train.txt`` / ``test.txt``) or ``all`` (every image in
            ``rgb/``).
        limit: keep the first ``limit`` frames of the split (sorted by id).

    Every frame has the published NYUv2 Kinect RGB intrinsics (640x480), the identity pose and
    ``timestamp = index``; frames are named by their 6-digit id.
    """

    def __init__(self, *, path: str | Path, split: str = "all", limit: int | None = None) -> None:
        root = open_prepared(path, split, limit, SPLITS, NAME)
        for sub in (RGB_DIR, DEPTH_DIR, LABEL_DIR):
            require_dir(root / sub, f"NYUv2 {sub}")
        manifest = read_manifest(root)
        if manifest is not None and manifest.get("name") != NAME:
            raise DataFormatError(f"{root}: the manifest says dataset {manifest.get('name')!r}, "
                                  f"not {NAME!r}")
        if split == "all":
            ids = _sort_ids([p.stem for p in (root / RGB_DIR).glob("*.png")])
            if not ids:
                raise DataFormatError(f"{root / RGB_DIR}: no PNG images")
        else:
            split_file = root / f"{split}.txt"
            if not split_file.is_file():
                raise DataFormatError(
                    f"{split_file}: split file not found: this folder has no NYUv2 splits; read "
                    f"every frame with --split all (-r split=all where a command has no "
                    f"--split), or prepare the dataset with `evsmap datasets prepare nyuv2`")
            ids = _sort_ids(read_id_list(split_file))
            if not ids:
                raise DataFormatError(f"{split_file}: lists no frames")
        self.root = root
        self.folder = Path(root)
        super().__init__(
            root.resolve().name, NYUV2_INTRINSICS, layout=NAME, split=split,
            class_names=NYU40_CLASSES, class_colors=palette(NUM_CLASSES), path=root,
            names=apply_limit(ids, limit),
            meta={"intrinsics_source": "NYUv2 Kinect RGB, published calibration",
                  "depth_scale": DEPTH_SCALE, "dataset": manifest})

    def load(self, index: int):
        fid = self.names[index]
        rgb_path = self.root / RGB_DIR / f"{fid}.png"
        depth_path = self.root / DEPTH_DIR / f"{fid}.png"
        rgb = read_rgb(rgb_path)
        check_shape(rgb_path, rgb.shape, (HEIGHT, WIDTH), "image")
        raw = read_uint16(depth_path)
        check_shape(depth_path, raw.shape, (HEIGHT, WIDTH), "depth")
        labels = read_label_png(self.root / LABEL_DIR / f"{fid}.png", NUM_CLASSES, (HEIGHT, WIDTH))
        depth = raw.astype(np.float32) / np.float32(DEPTH_SCALE)
        return rgb, depth, NYUV2_INTRINSICS, labels


def is_nyuv2_folder(path: Path) -> bool:
    path = Path(path)
    return all((path / sub).is_dir() for sub in (RGB_DIR, DEPTH_DIR, LABEL_DIR))


@READERS.register(NAME, takes=Takes(path=True, split=True, limit=True),
                  detect=is_nyuv2_folder,
                  description="NYU Depth v2 labelled set, 40 classes (folder written by "
                              "`evsmap datasets prepare nyuv2`: rgb/, depth/, label40/)")
def open_nyuv2(*, path: str, split: str = "all", limit: int | None = None) -> NYUv2Sequence:
    """NYU Depth v2 labelled set, 40 classes (prepared folder: rgb/, depth/, label40/)."""
    return NYUv2Sequence(path=path, split=split, limit=limit)


# -- preparation --------------------------------------------------------------------------------
def _mapping_lut(path: Path) -> np.ndarray:
    """``uint8`` table: source label (0 void, 1..894) -> 0..39, void 255."""
    mapping = np.asarray(load_mat(path, ["mapClass"], "894->40 class mapping")["mapClass"])
    flat = mapping.ravel()
    if flat.size != NUM_SOURCE_CLASSES or flat.dtype.kind not in "uif":
        raise DataFormatError(f"{path}: mapClass must hold {NUM_SOURCE_CLASSES} class ids, got "
                              f"{flat.dtype} of shape {mapping.shape}")
    if not np.all(np.isfinite(flat)) or np.any(flat != np.round(flat)) \
            or flat.min() < 1 or flat.max() > NUM_CLASSES:
        raise DataFormatError(f"{path}: mapClass values must be integers in 1..{NUM_CLASSES}, "
                              f"got {flat.min()}..{flat.max()}")
    lut = np.empty(NUM_SOURCE_CLASSES + 1, dtype=np.uint8)
    lut[0] = VOID
    lut[1:] = flat.astype(np.int64) - 1
    return lut


def _split_indices(path: Path, count: int) -> dict[str, np.ndarray]:
    data = load_mat(path, ["trainNdxs", "testNdxs"], "NYUv2 train/test split")
    out: dict[str, np.ndarray] = {}
    for split, key in (("train", "trainNdxs"), ("test", "testNdxs")):
        v = np.asarray(data[key]).ravel()
        if v.size == 0 or v.dtype.kind not in "uif" or not np.all(np.isfinite(v)) \
                or np.any(v != np.round(v)) or np.any(np.abs(v) > 2**53):
            raise DataFormatError(f"{path}: {key} must be a list of 1-based frame indices")
        v = v.astype(np.int64)
        if v.min() < 1 or v.max() > count:
            raise DataFormatError(f"{path}: {key} has index {v.min() if v.min() < 1 else v.max()} "
                                  f"outside 1..{count} (the frames of {LABELLED_MAT})")
        if len(np.unique(v)) != len(v):
            raise DataFormatError(f"{path}: {key} lists a frame twice")
        out[split] = np.sort(v)
    both = np.intersect1d(out["train"], out["test"])
    if both.size:
        raise DataFormatError(f"{path}: frame {both[0]} is in both trainNdxs and testNdxs")
    return out


def _check_dataset(f, path: Path, key: str, shape: tuple) -> Any:  # an h5py Dataset
    import h5py

    try:
        ds = f[key] if key in f else None
    except H5_ERRORS as exc:
        raise DataFormatError(f"{path}: unreadable HDF5 file ({exc})") from None
    if ds is None:
        raise DataFormatError(f"{path}: has no dataset {key!r} (expected the labelled NYUv2 set)")
    if not isinstance(ds, h5py.Dataset) or ds.dtype.kind not in "uif" \
            or (key == "images" and ds.dtype != np.uint8):
        what = "a uint8 array" if key == "images" else "a numeric array"
        raise DataFormatError(f"{path}: {key!r} is not {what} (expected the labelled NYUv2 "
                              "set)")
    if ds.ndim != len(shape) or any(e is not None and e != s for e, s in zip(shape, ds.shape,
                                                                              strict=True)):
        want = " x ".join("N" if e is None else str(e) for e in shape)
        raise DataFormatError(f"{path}: dataset {key!r} has shape {ds.shape}, expected {want} "
                              "(MATLAB v7.3 arrays appear transposed in HDF5)")
    return ds


def _frame_labels(path: Path, index: int, labels: np.ndarray) -> np.ndarray:
    """Frame ``index``'s source labels as ``int64`` 0..894, checked."""
    if not labels.size:
        return labels.astype(np.int64)
    if not np.all(np.isfinite(labels)) or np.any(labels != np.round(labels)):
        raise DataFormatError(f"{path}: labels of frame {index} hold non-integer values "
                              f"(expected 0..{NUM_SOURCE_CLASSES})")
    if labels.min() < 0 or labels.max() > NUM_SOURCE_CLASSES:
        value = labels.min() if labels.min() < 0 else labels.max()
        raise DataFormatError(f"{path}: labels of frame {index} hold value {value} outside "
                              f"0..{NUM_SOURCE_CLASSES}")
    return labels.astype(np.int64)


def prepare_nyuv2(source_dir: str | Path, out_dir: str | Path, *, limit: int | None = None,
                  overwrite: bool = False, progress: Progress | None = None) -> dict:
    """Convert the official NYUv2 files in ``source_dir`` into the prepared layout in ``out_dir``.

    ``source_dir`` holds ``nyu_depth_v2_labeled.mat``, ``splits.mat`` and ``classMapping40.mat``.
    ``limit`` keeps the first ``limit`` frames of each split. ``out_dir`` is written atomically
    (refused when it exists and is not empty, unless ``overwrite``). ``progress`` wraps the list
    of frames to write. Returns the manifest.
    """
    import h5py

    src = Path(source_dir)
    require_dir(src, "NYUv2 source")
    check_limit(limit)
    labelled = require_file(src / LABELLED_MAT, "NYUv2 labelled data")
    require_file(src / SPLITS_MAT, "NYUv2 split file")
    require_file(src / MAPPING_MAT, "NYUv2 894->40 class mapping")
    lut = _mapping_lut(src / MAPPING_MAT)
    if not is_hdf5(labelled):
        raise DataFormatError(f"{labelled}: not a MATLAB v7.3 (HDF5) file; expected the official "
                              "NYU Depth v2 labelled data")
    out = Path(out_dir)
    try:
        f = h5py.File(labelled, "r")
    except H5_ERRORS as exc:
        raise DataFormatError(f"{labelled}: unreadable HDF5 file ({exc})") from None
    with f, staging_folder(out, source=src, overwrite=overwrite) as stage:
        images = _check_dataset(f, labelled, "images", (None, 3, WIDTH, HEIGHT))
        count = images.shape[0]
        depths = _check_dataset(f, labelled, "depths", (count, WIDTH, HEIGHT))
        labels = _check_dataset(f, labelled, "labels", (count, WIDTH, HEIGHT))
        splits = _split_indices(src / SPLITS_MAT, count)
        chosen = {s: apply_limit(list(splits[s]), limit) for s in SPLITS}
        tasks = [(s, int(i)) for s in SPLITS for i in chosen[s]]
        for sub in (RGB_DIR, DEPTH_DIR, LABEL_DIR):
            (stage / sub).mkdir()
        out_of_range = 0
        for _split, index in (progress(tasks) if progress else tasks):
            fid = f"{index:06d}"
            k = index - 1  # MATLAB indices are 1-based
            try:
                rgb = np.ascontiguousarray(np.asarray(images[k], dtype=np.uint8).transpose(2, 1, 0))
                metres = np.asarray(depths[k], dtype=np.float64).T
                source_labels = _frame_labels(labelled, index, np.asarray(labels[k]).T)
            except H5_ERRORS as exc:
                raise DataFormatError(f"{labelled}: cannot read frame {index} ({exc})") from None
            ok = np.isfinite(metres) & (metres > 0)
            q = np.where(ok, np.round(np.where(ok, metres, 0.0) * DEPTH_SCALE), 0.0)
            high = q > 65535
            out_of_range += int(high.sum())
            depth = np.where(high, 0, q).astype(np.uint16)
            write_png(stage / RGB_DIR / f"{fid}.png", rgb)
            write_png(stage / DEPTH_DIR / f"{fid}.png", depth)
            write_png(stage / LABEL_DIR / f"{fid}.png", lut[source_labels])
        for s in SPLITS:
            atomic_write_text(stage / f"{s}.txt", "".join(f"{i:06d}\n" for i in chosen[s]))
        manifest = make_manifest(
            NAME, source=src, splits={s: len(chosen[s]) for s in SPLITS},
            official_counts=OFFICIAL_COUNTS, limit=limit, num_classes=NUM_CLASSES,
            class_names=list(NYU40_CLASSES), depth_scale=DEPTH_SCALE, void_label=VOID,
            intrinsics=NYUV2_INTRINSICS.as_dict(), source_frames=count,
            depth_beyond_range_pixels=out_of_range,
            layout={"rgb": f"{RGB_DIR}/NNNNNN.png", "depth": f"{DEPTH_DIR}/NNNNNN.png",
                    "labels": f"{LABEL_DIR}/NNNNNN.png", "splits": "train.txt, test.txt"})
        write_manifest(stage, manifest)
    return manifest
