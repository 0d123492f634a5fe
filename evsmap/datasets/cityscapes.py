"""Cityscapes (Cordts et al., CVPR 2016), 19 train classes: reader of the official tree (or of a
folder written by :func:`prepare_cityscapes`) and :func:`prepare_cityscapes`.

Official tree (``leftImg8bit_trainvaltest.zip``, ``gtFine_trainvaltest.zip``,
``disparity_trainvaltest.zip``, ``camera_trainvaltest.zip`` unpacked into one folder)::

    leftImg8bit/<split>/<city>/<city>_<seq>_<frame>_leftImg8bit.png   2048x1024 8-bit RGB
    gtFine/<split>/<city>/<city>_<seq>_<frame>_gtFine_labelIds.png    uint8 label ids 0..33
    disparity/<split>/<city>/<city>_<seq>_<frame>_disparity.png       uint16: (v - 1) / 256 px
    camera/<split>/<city>/<city>_<seq>_<frame>_camera.json            baseline, fx fy u0 v0

Splits: train 2975, val 500, test 1525 frames. The test labels of the public release carry no
classes: they all map to void (255). Depth = baseline * fx / disparity (metres), 0 where the
disparity PNG is 0 (no measurement) or 1 (zero disparity).

:func:`prepare_cityscapes` checks the whole tree (every file present, images and disparity of the
right size and type, camera files complete) and writes, into its output folder, the label images
as train ids (``gtFine/<split>/<city>/<stem>_gtFine_labelTrainIds.png``, 255 void), the frame
lists ``<split>.txt`` (``<city>/<stem>`` per line) and ``evsmap-dataset.json`` whose ``source``
names the official tree; reading that folder takes images, disparity and cameras from there.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from evsmap.classes import CITYSCAPES19_CLASSES
from evsmap.data import VOID, Intrinsics
from evsmap.datasets.cityscapes_labels import CITYSCAPES19_COLORS, label_ids_to_train_ids
from evsmap.datasets.common import (
    MANIFEST,
    Progress,
    SegmentationSequence,
    apply_limit,
    check_limit,
    check_shape,
    make_manifest,
    manifest_name,
    open_prepared,
    read_id_list,
    read_json,
    read_label_png,
    read_manifest,
    require_dir,
    write_manifest,
)
from evsmap.errors import DataFormatError, EvsmapError
from evsmap.fileio import atomic_write_text, staging_folder
from evsmap.readers.images import read_rgb, read_uint8_labels, read_uint16, write_png
from evsmap.registry import READERS, Takes

NAME = "cityscapes"
SPLITS = ("train", "val", "test")
OFFICIAL_COUNTS = {"train": 2975, "val": 500, "test": 1525}
UNLABELLED_SPLITS = ("test",)
"""Splits whose public labels are all void."""
NATIVE_WIDTH, NATIVE_HEIGHT = 2048, 1024
RESOLUTIONS = {"2048x1024": (2048, 1024), "1024x512": (1024, 512)}
DEFAULT_RESOLUTION = "1024x512"
NUM_CLASSES = len(CITYSCAPES19_CLASSES)
NOMINAL_CAMERA = Intrinsics(2262.52, 2265.3017905988554, 1096.98, 513.137, 2048, 1024)
"""A typical Cityscapes camera (used only for the sequence's intrinsics when the first frame's
camera file cannot be read; every frame uses its own camera file)."""

RGB_DIR, LABEL_DIR, DISPARITY_DIR, CAMERA_DIR = "leftImg8bit", "gtFine", "disparity", "camera"
RGB_SUFFIX = "_leftImg8bit.png"
LABEL_IDS_SUFFIX = "_gtFine_labelIds.png"
TRAIN_IDS_SUFFIX = "_gtFine_labelTrainIds.png"
DISPARITY_SUFFIX = "_disparity.png"
CAMERA_SUFFIX = "_camera.json"


def disparity_to_depth(raw: np.ndarray, baseline: float, fx: float) -> np.ndarray:
    """``uint16`` Cityscapes disparity PNG -> ``float32`` depth in metres (0 = invalid)."""
    disparity = (raw.astype(np.float64) - 1.0) / 256.0
    valid = raw > 1
    depth = np.zeros(raw.shape, dtype=np.float64)
    depth[valid] = baseline * fx / disparity[valid]
    return depth.astype(np.float32)


def _camera_number(value: object) -> float:
    """``value`` as a float; NaN for what is not a number (a bool, a string, an integer beyond
    the float range)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return math.nan
    try:
        return float(value)
    except OverflowError:
        return math.nan


def read_camera(path: Path) -> tuple[float, Intrinsics]:
    """(baseline in metres, native 2048x1024 intrinsics) from a ``*_camera.json``."""
    if not path.is_file():
        raise DataFormatError(f"{path}: camera file not found")
    record = read_json(path)
    try:
        baseline = record["extrinsic"]["baseline"]
        values = [record["intrinsic"][k] for k in ("fx", "fy", "u0", "v0")]
    except (KeyError, TypeError):
        raise DataFormatError(f"{path}: expected extrinsic.baseline and intrinsic.fx/fy/u0/v0") \
            from None
    numbers = [_camera_number(v) for v in (baseline, *values)]
    if not all(math.isfinite(v) for v in numbers) or numbers[0] <= 0 \
            or not math.isfinite(numbers[0] * numbers[1]):
        shown = str([baseline, *values])
        raise DataFormatError(f"{path}: baseline and intrinsics must be finite numbers with a "
                              f"positive baseline, got {shown[:200]}"
                              + ("..." if len(shown) > 200 else ""))
    baseline, fx, fy, cx, cy = numbers
    try:
        return float(baseline), Intrinsics(fx, fy, cx, cy, NATIVE_WIDTH, NATIVE_HEIGHT)
    except EvsmapError as exc:
        raise DataFormatError(f"{path}: bad intrinsics ({exc})") from None


def check_resolution(resolution: str) -> tuple[int, int]:
    if resolution not in RESOLUTIONS:
        raise EvsmapError(f"unknown Cityscapes resolution {resolution!r} "
                          f"(known: {', '.join(RESOLUTIONS)})")
    return RESOLUTIONS[resolution]


def _downsample_rgb(rgb: np.ndarray) -> np.ndarray:
    """Halve an HxWx3 ``uint8`` image by averaging 2x2 blocks (area resampling)."""
    h, w = rgb.shape[0] // 2, rgb.shape[1] // 2
    a = rgb[:2 * h, :2 * w].astype(np.uint16)
    total = a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2] + 2
    return (total >> 2).astype(np.uint8)  # the mean, rounded half up


def list_frames(root: Path, split: str) -> list[tuple[str, str]]:
    """Sorted ``(city, stem)`` of ``leftImg8bit/<split>/<city>/<stem>_leftImg8bit.png``."""
    folder = require_dir(root / RGB_DIR / split, f"Cityscapes {RGB_DIR}/{split}")
    frames = sorted((p.parent.name, p.name[:-len(RGB_SUFFIX)])
                    for p in folder.glob(f"*/*{RGB_SUFFIX}") if p.is_file())
    if not frames:
        raise DataFormatError(f"{folder}: no */*{RGB_SUFFIX} images")
    return frames


def _official_splits(root: Path) -> list[str]:
    return [s for s in SPLITS if (root / RGB_DIR / s).is_dir()]


class CityscapesSequence(SegmentationSequence):
    """Cityscapes frames with depth from disparity and 19-class labels.

    Args:
        path: the official tree (``leftImg8bit/``, ``gtFine/``, ``disparity/``, ``camera/``) or a
            folder written by :func:`prepare_cityscapes`.
        split: ``train``, ``val``, ``test`` or ``all`` (the splits present, in that order).
        limit: keep the first ``limit`` frames (sorted by split, city and name).
        resolution: ``1024x512`` (RGB averaged over 2x2 blocks, labels and depth nearest, the
            intrinsics scaled) or ``2048x1024`` (native).

    Each frame has the intrinsics of its own camera file; the sequence's ``intrinsics`` are the
    first frame's. Frames are named ``<split>/<stem>``; test labels are all void.
    """

    def __init__(self, *, path: str | Path, split: str = "all", limit: int | None = None,
                 resolution: str = DEFAULT_RESOLUTION) -> None:
        root = open_prepared(path, split, limit, SPLITS, NAME)
        self.size = check_resolution(resolution)
        manifest = read_manifest(root)
        if manifest is not None and manifest.get("name") != NAME:
            raise DataFormatError(f"{root}: the manifest says dataset {manifest.get('name')!r}, "
                                  f"not {NAME!r}")
        self.prepared = root if manifest is not None else None
        if manifest is not None:
            raw = manifest.get("source")
            source = Path(raw) if isinstance(raw, str) and raw else Path("?")
            if not source.is_absolute() or not (source / RGB_DIR).is_dir():
                raise DataFormatError(f"{root / MANIFEST}: the Cityscapes tree it was prepared "
                                      f"from ({raw}) is not there; prepare it again")
            present = [s for s in SPLITS if (root / f"{s}.txt").is_file()]
        else:
            source = root
            require_dir(root / RGB_DIR, f"Cityscapes {RGB_DIR}")
            present = _official_splits(root)
        if split == "all":
            wanted = present
            if not wanted:
                raise DataFormatError(f"{root}: no Cityscapes split found")
        else:
            wanted = [split]
        self.source = source
        self.entries: list[tuple[str, str, str]] = []
        self.labels_missing: set[str] = set()
        for s in wanted:
            if self.prepared is not None:
                rows = read_id_list(root / f"{s}.txt", parts=2)
                frames = sorted((city, name) for city, name in (r.split("/", 1) for r in rows))
                require_dir(root / LABEL_DIR / s, f"prepared {LABEL_DIR}/{s}")
                require_dir(source / RGB_DIR / s, f"Cityscapes {RGB_DIR}/{s}")
            else:
                frames = list_frames(root, s)
                if not (root / LABEL_DIR / s).is_dir():
                    if s not in UNLABELLED_SPLITS:
                        require_dir(root / LABEL_DIR / s, f"Cityscapes {LABEL_DIR}/{s}")
                    self.labels_missing.add(s)
            require_dir(source / DISPARITY_DIR / s, f"Cityscapes {DISPARITY_DIR}/{s}")
            require_dir(source / CAMERA_DIR / s, f"Cityscapes {CAMERA_DIR}/{s}")
            self.entries.extend((s, city, stem) for city, stem in frames)
        self.entries = apply_limit(self.entries, limit)
        if not self.entries:
            raise DataFormatError(f"{root}: no frames in split {split!r}")
        if self.prepared is not None:
            for entry in self.entries:
                if not self._path(RGB_DIR, entry, RGB_SUFFIX).is_file():
                    raise DataFormatError(
                        f"{root / f'{entry[0]}.txt'}: frame {entry[1]}/{entry[2]} has no image "
                        f"{self._path(RGB_DIR, entry, RGB_SUFFIX)} in the Cityscapes tree")
        first = self.entries[0]
        try:
            _, camera = read_camera(self._path(CAMERA_DIR, first, CAMERA_SUFFIX))
            intr_source = "per frame (camera/*.json); first frame shown"
        except DataFormatError:
            camera = NOMINAL_CAMERA
            intr_source = "typical Cityscapes camera (first frame's camera file unreadable)"
        if self.size != (NATIVE_WIDTH, NATIVE_HEIGHT):
            camera = camera.scaled(*self.size)
        super().__init__(
            root.resolve().name, camera, layout=NAME, split=split,
            class_names=CITYSCAPES19_CLASSES, class_colors=CITYSCAPES19_COLORS, path=root,
            names=[f"{s}/{stem}" for s, _city, stem in self.entries],
            meta={"intrinsics_source": intr_source, "resolution": resolution,
                  "source": str(source), "prepared": manifest is not None,
                  "void_label_splits": [s for s in wanted if s in UNLABELLED_SPLITS],
                  "dataset": manifest})

    def _path(self, kind: str, entry: tuple[str, str, str], suffix: str) -> Path:
        split, city, stem = entry
        base = self.prepared if kind == LABEL_DIR and self.prepared is not None else self.source
        return base / kind / split / city / f"{stem}{suffix}"

    def disparity_scale(self, index: int) -> float:
        """Baseline x native fx from the frame's camera file: the disparity PNG is in native
        (2048-wide) pixels at any reading resolution."""
        baseline, camera = read_camera(self._path(CAMERA_DIR, self.entries[index],
                                                  CAMERA_SUFFIX))
        return baseline * camera.fx

    def load(self, index: int):
        entry = self.entries[index]
        native = (NATIVE_HEIGHT, NATIVE_WIDTH)
        rgb_path = self._path(RGB_DIR, entry, RGB_SUFFIX)
        rgb = read_rgb(rgb_path)
        check_shape(rgb_path, rgb.shape, native, "image")
        disp_path = self._path(DISPARITY_DIR, entry, DISPARITY_SUFFIX)
        raw = read_uint16(disp_path)
        check_shape(disp_path, raw.shape, native, "disparity")
        baseline, camera = read_camera(self._path(CAMERA_DIR, entry, CAMERA_SUFFIX))
        if self.prepared is not None:
            labels = read_label_png(self._path(LABEL_DIR, entry, TRAIN_IDS_SUFFIX), NUM_CLASSES,
                                    native)
        elif entry[0] in self.labels_missing:
            labels = np.full(native, VOID, dtype=np.uint8)
        else:
            label_path = self._path(LABEL_DIR, entry, LABEL_IDS_SUFFIX)
            ids = read_uint8_labels(label_path)
            check_shape(label_path, ids.shape, native, "labels")
            labels = label_ids_to_train_ids(ids, label_path)
        depth = disparity_to_depth(raw, baseline, camera.fx)
        if self.size != (NATIVE_WIDTH, NATIVE_HEIGHT):
            rgb = _downsample_rgb(rgb)
            depth = np.ascontiguousarray(depth[::2, ::2])
            labels = np.ascontiguousarray(labels[::2, ::2])
            camera = camera.scaled(*self.size)
        return rgb, depth, camera, labels


def is_cityscapes_folder(path: Path) -> bool:
    path = Path(path)
    if (path / MANIFEST).is_file():
        return manifest_name(path) == NAME
    return (path / RGB_DIR).is_dir() and ((path / DISPARITY_DIR).is_dir()
                                          or (path / LABEL_DIR).is_dir())


@READERS.register(NAME, takes=Takes(path=True, split=True, limit=True, resolution=True),
                  detect=is_cityscapes_folder,
                  description="Cityscapes, 19 classes, depth from disparity (official tree or a "
                              "folder written by `evsmap datasets prepare cityscapes`)")
def open_cityscapes(*, path: str, split: str = "all", limit: int | None = None,
                    resolution: str = DEFAULT_RESOLUTION) -> CityscapesSequence:
    """Cityscapes, 19 classes, depth from disparity (official tree or prepared folder)."""
    return CityscapesSequence(path=path, split=split, limit=limit, resolution=resolution)


# -- preparation --------------------------------------------------------------------------------
def _probe(path: Path, modes: tuple[str, ...], what: str) -> None:
    """Check an image's header: it opens, has one of ``modes`` and the native size."""
    if not path.is_file():
        raise DataFormatError(f"{path}: file not found")
    try:
        with Image.open(path) as img:
            mode, size = img.mode, img.size
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError, EOFError,
            Image.DecompressionBombError) as exc:
        raise DataFormatError(f"{path}: unreadable or corrupt image ({exc})") from None
    if mode not in modes:
        raise DataFormatError(f"{path}: expected {what}, got mode {mode}")
    if size != (NATIVE_WIDTH, NATIVE_HEIGHT):
        raise DataFormatError(f"{path}: image is {size[0]}x{size[1]}, expected "
                              f"{NATIVE_WIDTH}x{NATIVE_HEIGHT}")


def prepare_cityscapes(source_dir: str | Path, out_dir: str | Path, *, limit: int | None = None,
                       overwrite: bool = False, progress: Progress | None = None) -> dict:
    """Check the official Cityscapes tree in ``source_dir`` and write train-id labels, frame lists
    and the manifest into ``out_dir`` (see the module docstring).

    Every split present in ``leftImg8bit/`` is prepared; ``limit`` keeps the first ``limit``
    frames of each. Image and disparity files are checked from their headers (pixels are decoded
    when read); label files are decoded and mapped with the official id -> train id table.
    ``out_dir`` is written atomically (a non-empty one is refused unless ``overwrite``).
    Returns the manifest.
    """
    src = Path(source_dir)
    require_dir(src, "Cityscapes source")
    check_limit(limit)
    require_dir(src / RGB_DIR, f"Cityscapes {RGB_DIR} (leftImg8bit_trainvaltest.zip unpacked)")
    splits = _official_splits(src)
    if not splits:
        raise DataFormatError(f"{src / RGB_DIR}: no train/val/test folder")
    chosen: dict[str, list[tuple[str, str]]] = {}
    void_splits = []
    for s in splits:
        require_dir(src / DISPARITY_DIR / s, f"Cityscapes {DISPARITY_DIR}/{s} "
                                             "(disparity_trainvaltest.zip)")
        require_dir(src / CAMERA_DIR / s, f"Cityscapes {CAMERA_DIR}/{s} (camera_trainvaltest.zip)")
        if not (src / LABEL_DIR / s).is_dir():
            if s not in UNLABELLED_SPLITS:
                require_dir(src / LABEL_DIR / s, f"Cityscapes {LABEL_DIR}/{s} "
                                                 "(gtFine_trainvaltest.zip)")
            void_splits.append(s)
        chosen[s] = apply_limit(list_frames(src, s), limit)
    tasks = [(s, city, stem) for s in splits for city, stem in chosen[s]]
    with staging_folder(Path(out_dir), source=src, overwrite=overwrite) as stage:
        for split, city, stem in (progress(tasks) if progress else tasks):
            rel = Path(split, city)
            _probe(src / RGB_DIR / rel / f"{stem}{RGB_SUFFIX}", ("RGB", "RGBA"), "8-bit RGB")
            _probe(src / DISPARITY_DIR / rel / f"{stem}{DISPARITY_SUFFIX}",
                   ("I;16", "I;16B", "I;16L", "I"), "a 16-bit disparity image")
            read_camera(src / CAMERA_DIR / rel / f"{stem}{CAMERA_SUFFIX}")
            if split in void_splits:
                train_ids = np.full((NATIVE_HEIGHT, NATIVE_WIDTH), VOID, dtype=np.uint8)
            else:
                label_path = src / LABEL_DIR / rel / f"{stem}{LABEL_IDS_SUFFIX}"
                ids = read_uint8_labels(label_path)
                check_shape(label_path, ids.shape, (NATIVE_HEIGHT, NATIVE_WIDTH), "labels")
                train_ids = label_ids_to_train_ids(ids, label_path)
            (stage / LABEL_DIR / rel).mkdir(parents=True, exist_ok=True)
            write_png(stage / LABEL_DIR / rel / f"{stem}{TRAIN_IDS_SUFFIX}", train_ids)
        for s in splits:
            (stage / LABEL_DIR / s).mkdir(parents=True, exist_ok=True)
            atomic_write_text(stage / f"{s}.txt",
                              "".join(f"{city}/{stem}\n" for city, stem in chosen[s]))
        manifest = make_manifest(
            NAME, source=src, splits={s: len(chosen[s]) for s in splits},
            official_counts=OFFICIAL_COUNTS, limit=limit, num_classes=NUM_CLASSES,
            class_names=list(CITYSCAPES19_CLASSES), void_label=VOID,
            void_label_splits=[s for s in splits if s in UNLABELLED_SPLITS],
            native_size=[NATIVE_WIDTH, NATIVE_HEIGHT],
            layout={"labels": f"{LABEL_DIR}/<split>/<city>/<stem>{TRAIN_IDS_SUFFIX}",
                    "frames": "<split>.txt (<city>/<stem>)",
                    "images, disparity, cameras": "read from the source tree"})
        write_manifest(stage, manifest)
    return manifest
