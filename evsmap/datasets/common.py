"""What the segmentation dataset readers and their ``prepare_*`` functions share.

* split names and ``limit`` checks, deterministic (sorted) frame order;
* the prepared-layout manifest ``evsmap-dataset.json`` (dataset name, layout version, frames per
  split, source path, evsmap version);
* writing a prepared folder atomically (a hidden partial folder renamed into place at the end);
* checked reads of label images and MATLAB files (v5 through scipy, v7.3/HDF5 through h5py);
* :class:`SegmentationSequence`, the base of the readers: frames without poses (identity pose,
  timestamp = index, ``meta["poses"] = False``), each with its own intrinsics.

Every problem with the user's files raises :class:`~evsmap.errors.DataFormatError` or
:class:`~evsmap.errors.InvalidDataError` with one line naming the file and what was expected.
"""

from __future__ import annotations

import abc
import json
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from evsmap.data import VOID, Frame, Intrinsics, Sequence
from evsmap.errors import DataFormatError, EvsmapError, InvalidDataError
from evsmap.fileio import atomic_write_text
from evsmap.readers.images import read_uint8_labels
from evsmap.version import evsmap_version

T = TypeVar("T")

MANIFEST = "evsmap-dataset.json"
"""File name of the manifest in every prepared dataset folder."""
MANIFEST_FORMAT = "evsmap-dataset"
LAYOUT_VERSION = 1
"""Version of the prepared layouts written by this evsmap (bumped when a layout changes)."""

Progress = Callable[[Iterable[Any]], Iterable[Any]]

_IDENTITY = np.eye(4, dtype=np.float64)
_IDENTITY.setflags(write=False)


# -- options ----------------------------------------------------------------------------------
def check_split(split: str, known: Iterable[str], dataset: str) -> str:
    """``split`` if it is one of ``known`` (or ``all``), else a one-line error."""
    names = [*known, "all"]
    if split not in names:
        raise EvsmapError(f"unknown {dataset} split {split!r} (known: {', '.join(names)})")
    return split


def check_limit(limit: int | None) -> int | None:
    """``None`` (every frame) or a positive integer."""
    if limit is None:
        return None
    if isinstance(limit, bool) or not isinstance(limit, (int, np.integer)) or limit < 1:
        raise EvsmapError(f"limit must be a positive integer or None, got {limit!r}")
    return int(limit)


def open_prepared(path: str | Path, split: str, limit: int | None, splits: Iterable[str],
                  dataset: str) -> Path:
    """A prepared dataset's folder, with its reader's ``split`` and ``limit`` checked; one-line
    errors."""
    root = Path(path)
    if not root.is_dir():
        raise DataFormatError(f"{root}: not a folder")
    check_split(split, splits, dataset)
    check_limit(limit)
    return root


def apply_limit(items: list[T], limit: int | None) -> list[T]:
    """The first ``limit`` items (all of them for ``None``)."""
    limit = check_limit(limit)
    return list(items) if limit is None else list(items)[:limit]


def class_colors_list(colors: np.ndarray) -> list[list[int]]:
    """``uint8`` (C, 3) colours as plain lists (for ``meta`` and JSON)."""
    return [[int(v) for v in row] for row in np.asarray(colors, dtype=np.uint8)]


# -- files ------------------------------------------------------------------------------------
def require_file(path: Path, what: str) -> Path:
    if not path.is_file():
        raise DataFormatError(f"{path}: {what} not found")
    return path


def require_dir(path: Path, what: str) -> Path:
    if not path.is_dir():
        raise DataFormatError(f"{path}: {what} folder not found")
    return path


MAX_ID_PART = 200
"""The longest part of a frame id (UTF-8 bytes): file names hold a suffix besides it, within
the usual 255-byte limit."""


def _utf8_len(text: str) -> int:
    return len(text.encode("utf-8", "replace"))


def check_frame_id(item: str, where: str, parts: int = 1) -> str:
    """``item`` if it can name a frame's files: ``parts`` non-empty ``/``-separated parts, none of
    them ``.`` or ``..``, no backslash or control character; else a one-line error."""
    pieces = item.split("/")
    bad_piece = any(p in ("", ".", "..") or _utf8_len(p) > MAX_ID_PART for p in pieces)
    if len(pieces) != parts or bad_piece or "\\" in item \
            or any(ord(c) < 32 or ord(c) == 127 for c in item):
        shape = "one name" if parts == 1 else f"{parts} names joined by '/'"
        raise DataFormatError(f"{where}: id {item!r} cannot name a frame's files (expected "
                              f"{shape}, none empty, '.', '..' or over {MAX_ID_PART} "
                              "bytes, without '\\' or control characters)")
    return item


def read_id_list(path: Path, parts: int = 1) -> list[str]:
    """One id per line (blank lines and ``#`` comments skipped), in file order, no duplicates;
    each id names files: ``parts`` parts separated by ``/`` (:func:`check_frame_id`)."""
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise DataFormatError(f"{path}: split file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DataFormatError(f"{path}: cannot read split file ({exc})") from None
    ids: list[str] = []
    seen: set[str] = set()
    for number, line in enumerate(text.splitlines(), 1):
        item = line.split("#", 1)[0].strip()
        if not item:
            continue
        if len(item.split()) != 1:
            raise DataFormatError(f"{path}:{number}: expected one id per line, got {line!r}")
        check_frame_id(item, f"{path}:{number}", parts)
        if item in seen:
            raise DataFormatError(f"{path}:{number}: id {item} listed twice")
        seen.add(item)
        ids.append(item)
    return ids


def read_json(path: Path) -> Any:
    """The JSON value in ``path``; unreadable, not UTF-8, not JSON, nested too deeply or holding
    an integer too long to convert: a one-line error naming the file."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as exc:  # ValueError: JSON, UTF-8, integer digits
        raise DataFormatError(f"{path}: not valid JSON ({_one_line(exc)})") from None
    except RecursionError:
        raise DataFormatError(f"{path}: not valid JSON (nested too deeply)") from None


def read_manifest(folder: Path) -> dict | None:
    """The manifest of a prepared folder, ``None`` when there is none."""
    path = Path(folder) / MANIFEST
    if not path.is_file():
        return None
    record = read_json(path)
    if not isinstance(record, dict) or record.get("format") != MANIFEST_FORMAT:
        raise DataFormatError(f"{path}: not an evsmap dataset manifest "
                              f"(expected \"format\": \"{MANIFEST_FORMAT}\")")
    return record


def manifest_name(folder: Path) -> str | None:
    """The dataset name in ``folder``'s manifest, ``None`` without a (valid) manifest."""
    try:
        record = read_manifest(folder)
    except DataFormatError:
        return None
    return None if record is None else record.get("name")


def make_manifest(name: str, *, source: Path, splits: dict[str, int], **extra: Any) -> dict:
    return {
        "format": MANIFEST_FORMAT, "name": name, "version": LAYOUT_VERSION,
        "evsmap_version": evsmap_version(), "source": str(Path(source).resolve()),
        "splits": dict(splits), "frames": int(sum(splits.values())), **extra,
    }


def write_manifest(folder: Path, record: dict) -> None:
    atomic_write_text(Path(folder) / MANIFEST, json.dumps(record, indent=2) + "\n")



# -- MATLAB files -------------------------------------------------------------------------------
def is_hdf5(path: Path) -> bool:
    """Whether ``path`` is an HDF5 file (MATLAB v7.3 files are HDF5 with a 512-byte user block)."""
    try:
        import h5py

        return bool(h5py.is_hdf5(str(path)))
    except OSError:
        return False


MAX_MAT_BYTES = 256 * 1024**2
"""The largest HDF5 (MATLAB v7.3) variable read whole, in bytes: far more than any variable of
the official releases evsmap reads whole (split lists, class mappings, one label image; the
NYUv2 images are read frame by frame), far less than what a damaged header can claim, with room
for the checks' temporary copies."""

H5_ERRORS: tuple[type[Exception], ...] = (OSError, RuntimeError, KeyError, ValueError,
                                          TypeError, AttributeError)
"""What h5py raises on a damaged or unexpected HDF5 file (broken addresses, links, types)."""

MAT_ERRORS: tuple[type[Exception], ...] = (ValueError, TypeError, OSError, NotImplementedError,
                                           IndexError, KeyError, AttributeError, OverflowError,
                                           EOFError, UnboundLocalError, MemoryError)
"""What scipy.io.loadmat raises on a damaged MATLAB v5 file (besides its MatReadError).
MemoryError: scipy allocates what an element's tag claims (up to 4 GiB) or what a cell array's
dimensions claim before reading it; a damaged tag's claim fails the allocation (a real file's
variables are far smaller), and that is the file's fault, not a bug."""


def loadmat_checked(path: Path, **options: Any) -> dict:
    """``scipy.io.loadmat(path, **options)``; a damaged file is a one-line error naming it
    (its structure checked first: scipy crashes on some damaged element tags,
    :mod:`evsmap.datasets.matv5`)."""
    import zlib

    import scipy.io
    from scipy.io.matlab import MatReadError

    from evsmap.datasets.matv5 import check_mat5

    check_mat5(path)
    try:
        return scipy.io.loadmat(str(path), **options)
    except (MatReadError, zlib.error, *MAT_ERRORS) as exc:
        raise DataFormatError(f"{path}: not a readable MATLAB file ({_one_line(exc)})") from None


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def check_h5_size(path: Path, obj: object, what: str) -> None:
    """``obj`` (an HDF5 dataset) holds at most :data:`MAX_MAT_BYTES`; else a one-line error."""
    shape = getattr(obj, "shape", None) or ()
    itemsize = getattr(getattr(obj, "dtype", None), "itemsize", 1) or 1
    total = itemsize
    for n in shape:
        total *= int(n)
    if total > MAX_MAT_BYTES:
        raise DataFormatError(f"{path}: {what} claims shape {tuple(shape)} "
                              f"({total / 1024**3:.3g} GiB): not a variable of this dataset")


def read_h5_array(path: Path, obj: object, what: str) -> np.ndarray:
    """The whole of an HDF5 dataset ``obj`` as an array (size checked first)."""
    import h5py

    if not isinstance(obj, h5py.Dataset):
        raise DataFormatError(f"{path}: {what} is not an array (an HDF5 {type(obj).__name__})")
    check_h5_size(path, obj, what)
    try:
        return np.asarray(obj[()])
    except H5_ERRORS as exc:
        raise DataFormatError(f"{path}: cannot read {what} ({_one_line(exc)})") from None


def load_mat(path: Path, keys: Iterable[str], what: str) -> dict[str, np.ndarray]:
    """``keys`` of a MATLAB file, v5/v7 (scipy) or v7.3 (HDF5; arrays transposed back to MATLAB's
    row/column order). Missing file, unreadable file and missing keys are one-line errors."""
    require_file(path, what)
    keys = list(keys)
    if is_hdf5(path):
        import h5py

        try:
            with h5py.File(path, "r") as f:
                out = {}
                for key in keys:
                    if key not in f:
                        raise DataFormatError(f"{path}: has no variable {key!r} ({what})")
                    out[key] = read_h5_array(path, f[key], f"variable {key!r}").T
                return out
        except H5_ERRORS as exc:
            raise DataFormatError(f"{path}: unreadable MATLAB v7.3 file ({_one_line(exc)})") \
                from None
    data = loadmat_checked(path, variable_names=keys)
    for key in keys:
        if key not in data:
            raise DataFormatError(f"{path}: has no variable {key!r} ({what})")
    return {key: data[key] for key in keys}


def mat_strings(value: object) -> list[str]:
    """The strings in a MATLAB cell array / char array as loaded by scipy, flattened in order."""
    if isinstance(value, str):
        return [value]
    if isinstance(value, bytes):
        return [value.decode()]
    arr = np.asarray(value)
    if arr.dtype.kind in "US":
        # scipy gives a string per row of a char array (chars_as_strings)
        return [str(v) for v in arr.ravel()]
    if arr.dtype == object:
        out: list[str] = []
        for item in arr.ravel(order="F"):
            out.extend(mat_strings(item))
        return out
    raise DataFormatError(f"expected MATLAB strings, got {arr.dtype} {arr.shape}")


# -- labels -----------------------------------------------------------------------------------
def check_label_values(labels: np.ndarray, num_classes: int, where: Path | str,
                       what: str = "label") -> np.ndarray:
    """``labels`` if every value is a class id below ``num_classes`` or 255 (void)."""
    bad = (labels >= num_classes) & (labels != VOID)
    if bad.any():
        value = int(labels[bad].max())
        raise InvalidDataError(f"{where}: {what} {value} outside 0..{num_classes - 1} "
                               f"({VOID} void) at {int(bad.sum())} pixels")
    return labels


def read_label_png(path: Path, num_classes: int, shape: tuple[int, int] | None = None
                   ) -> np.ndarray:
    """A ``uint8`` label PNG with ids ``0..num_classes-1`` and 255 void, of size ``shape``."""
    labels = read_uint8_labels(path)
    if shape is not None and labels.shape != tuple(shape):
        raise DataFormatError(f"{path}: labels are {labels.shape[1]}x{labels.shape[0]}, expected "
                              f"{shape[1]}x{shape[0]} like the image")
    return check_label_values(labels, num_classes, path)


def check_shape(path: Path, shape: tuple[int, ...], expected: tuple[int, ...], what: str) -> None:
    if tuple(shape[:2]) != tuple(expected[:2]):
        raise DataFormatError(f"{path}: {what} is {shape[1]}x{shape[0]}, expected "
                              f"{expected[1]}x{expected[0]}")


# -- sequences --------------------------------------------------------------------------------
class SegmentationSequence(Sequence):
    """Base of the segmentation-dataset readers: frames with labels but without poses.

    Frames get the identity pose and ``timestamp = index``; ``meta`` holds ``poses: False``,
    ``layout``, ``split``, ``class_names``, ``class_colors`` (``uint8`` RGB lists),
    ``num_classes`` and ``path``. ``class_names`` is also an attribute (what
    :func:`evsmap.summary.summarize_sequence` looks for). Subclasses fill ``self.names`` (one
    identifier per frame, in order) and implement :meth:`load` (rgb, depth, intrinsics, labels).
    """

    def __init__(self, name: str, intrinsics: Intrinsics, *, layout: str, split: str,
                 class_names: tuple[str, ...], class_colors: np.ndarray, path: Path,
                 names: list[str], meta: dict | None = None) -> None:
        super().__init__(name, intrinsics, {
            "layout": layout, "poses": False, "split": split,
            "class_names": list(class_names), "class_colors": class_colors_list(class_colors),
            "num_classes": len(class_names), "void_label": VOID, "path": str(path),
            **(meta or {}),
        })
        self.class_names = tuple(class_names)
        self.num_classes = len(class_names)
        self.names = list(names)

    def __len__(self) -> int:
        return len(self.names)

    def frame_stem(self, index: int) -> str:
        """Frame ``index``'s own file stem, the part its image, depth and label files share
        (``000433``; a name's last part where it holds a split or city): the name ``evsmap
        predict`` writes its outputs under."""
        return self.names[index].rpartition("/")[2]

    @abc.abstractmethod
    def load(self, index: int) -> tuple[np.ndarray, np.ndarray, Intrinsics, np.ndarray | None]:
        """(rgb uint8 HxWx3, depth float32 metres HxW, intrinsics, labels uint8 HxW or None)."""

    def disparity_scale(self, index: int) -> float | None:
        """Frame ``index``'s stereo baseline x focal length (:attr:`Frame.disparity_scale`)
        where its depth came from disparity; None here."""
        return None

    def frame(self, index: int) -> Frame:
        rgb, depth, intrinsics, labels = self.load(index)
        return Frame(rgb=rgb, depth=depth, intrinsics=intrinsics, pose=_IDENTITY.copy(),
                     timestamp=float(index), labels=labels, name=self.names[index],
                     disparity_scale=self.disparity_scale(index))
