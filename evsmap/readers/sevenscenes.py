"""Microsoft 7-Scenes layout (Shotton et al., CVPR 2013): reader.

Layout of one sequence folder (e.g. ``chess/seq-01/``)::

    frame-NNNNNN.color.png   colour, 640x480 8-bit (``.color.jpg`` is accepted as well)
    frame-NNNNNN.depth.png   depth, uint16 millimetres; 0 and 65535 mean "no measurement"
    frame-NNNNNN.pose.txt    4x4 camera-to-world matrix (KinectFusion tracking), whitespace
                             separated
    camera-intrinsics.txt    optional 3x3 K; without it the dataset's documented depth camera
                             fx = fy = 585, cx = 320, cy = 240 (640x480)

A scene folder holding ``seq-01/``, ``seq-02/``, ... is read one sequence at a time
(``sequence=``, default the first). Frames are the union of the frame numbers seen in the three
kinds of files, in number order, so a frame missing one of its files is a bad frame (a one-line
:class:`~evsmap.errors.DataFormatError` naming the file from :meth:`SevenScenesSequence.frame`,
which ``--skip-bad`` leaves out) rather than silently absent. A pose file that holds nan/inf
(some 7-Scenes pose files do; MSVC-printed ``1.#QNAN`` / ``-1.#IND`` included), that
is not 4x4 or whose rotation block is not a rotation is such a bad frame too. The dataset has no
time stamps: frame ``N`` gets ``N / frame_rate`` seconds (the Kinect's 30 Hz). KinectFusion's
rotation blocks are slightly off orthonormal (about 1e-4); they are replaced by the nearest
rotation (see :func:`read_pose`), the translation is kept as written.

Registration caveat: the dataset's documentation states that the colour and depth cameras were
not calibrated against each other - the frames are the raw, unregistered Kinect images, and only
the depth camera's default intrinsics (585, 585, 320, 240) are given, which KinectFusion used to
compute the poses. This reader does what the dataset's own tools do: it uses the depth intrinsics
(and the depth camera's pose) for both images and pairs each depth pixel with the colour pixel at
the same row and column. Geometry (depth, poses, occupancy) does not depend on the colour;
colours (and anything a segmenter derives from them) can be shifted by a few pixels against the
depth, most visibly at depth discontinuities. Colour and depth must have the same size.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from evsmap.data import Frame, Intrinsics, Sequence
from evsmap.errors import DataFormatError, EvsmapError
from evsmap.readers.images import (
    check_rgbd_shapes,
    dequantize_depth,
    image_size,
    read_rgb,
    read_uint16,
)
from evsmap.readers.poses import checked_pose
from evsmap.registry import READERS, Takes

LAYOUT = "sevenscenes"
INTRINSICS_FILE = "camera-intrinsics.txt"
#: The dataset's documented depth camera (Kinect v1, 640x480), used when the folder has no
#: ``camera-intrinsics.txt``.
SEVENSCENES_INTRINSICS = Intrinsics(585.0, 585.0, 320.0, 240.0, 640, 480)
DEPTH_SCALE = 1000.0  # millimetres
INVALID_DEPTH = 65535
FRAME_RATE = 30.0
#: Largest ``|R R^T - I|`` of a pose file's rotation block that is made orthonormal rather than
#: refused (see :func:`read_pose`).
ROTATION_TOLERANCE = 1e-2
#: Largest frame number accepted in a file name (frame numbers become int64 and, divided by the
#: frame rate, exact float64 time stamps).
MAX_FRAME_NUMBER = 2**53

_FRAME_FILE = re.compile(r"^frame-(\d+)\.(color\.png|color\.jpg|depth\.png|pose\.txt)$")
_SEQ_DIR = re.compile(r"^seq-(\d+)$")
_SEQ_ZIP = re.compile(r"^seq-(\d+)\.zip$")
# MSVC prints non-finite doubles as 1.#QNAN, -1.#IND, 1.#INF (and with more digits, 1.#QNAN0)
_MSVC_NONFINITE = re.compile(r"^[-+]?\d\.#(QNAN|SNAN|IND|INF)\d*$", re.IGNORECASE)


def _scan(folder: Path) -> dict[int, dict[str, str]]:
    """Frame number -> {kind (``color.png``, ``depth.png``, ...): file name} of the files
    present."""
    frames: dict[int, dict[str, str]] = {}
    try:
        names = _names(folder)
    except OSError as exc:
        raise DataFormatError(f"{folder}: cannot list the folder ({exc})") from None
    for name in names:
        m = _FRAME_FILE.match(name)
        if m:
            number = int(m.group(1))  # a file name is at most 255 characters
            if number > MAX_FRAME_NUMBER:
                raise DataFormatError(f"{folder / name}: frame number out of range (at most "
                                      f"{MAX_FRAME_NUMBER})")
            frames.setdefault(number, {})[m.group(2)] = name
    return frames


def _names(folder: Path) -> list[str]:
    """The names in ``folder`` (the directory handle closed before returning)."""
    with os.scandir(folder) as entries:
        return [e.name for e in entries]


def _has_frames(folder: Path) -> bool:
    try:
        return any(_FRAME_FILE.match(name) for name in _names(folder))
    except OSError:
        return False


def _is_dir(entry: os.DirEntry) -> bool:
    """Whether ``entry`` is a folder (or a link to one); a link that loops or cannot be
    followed is not."""
    try:
        return entry.is_dir()
    except OSError:
        return False


def _sequence_dirs(folder: Path) -> list[Path]:
    """``seq-NN`` sub-folders in number order."""
    try:
        with os.scandir(folder) as it:
            names = [e.name for e in it if _SEQ_DIR.match(e.name) and _is_dir(e)]
    except OSError:
        return []
    names.sort(key=lambda n: (int(n.removeprefix("seq-")), n))  # the names match _SEQ_DIR
    return [folder / n for n in names]


def _zipped_sequences(folder: Path) -> list[str]:
    try:
        return sorted(n for n in _names(folder) if _SEQ_ZIP.match(n))
    except OSError:
        return []


def read_matrix(path: Path, rows: int, cols: int, what: str) -> np.ndarray:
    """A whitespace-separated ``rows`` x ``cols`` matrix of numbers as ``float64``; nan/inf
    (also MSVC's ``1.#QNAN``, ``-1.#INF``) are read as non-finite values for the caller to judge.

    Raises:
        DataFormatError: missing or unreadable file, wrong number of values, a non-number.
    """
    if not path.is_file():
        raise DataFormatError(f"{path}: file not found")
    try:
        tokens = path.read_text(encoding="utf-8-sig").split()  # BOM dropped
    except (OSError, UnicodeDecodeError) as exc:
        raise DataFormatError(f"{path}: cannot read ({exc})") from None
    if len(tokens) != rows * cols:
        raise DataFormatError(f"{path}: expected a {rows}x{cols} {what} ({rows * cols} numbers), "
                              f"got {len(tokens)} values")
    values = np.empty(len(tokens), dtype=np.float64)
    for k, tok in enumerate(tokens):
        try:
            values[k] = float(tok)
        except ValueError:
            if not _MSVC_NONFINITE.match(tok):
                raise DataFormatError(f"{path}: not a number: {tok[:40]!r}") from None
            values[k] = np.nan
    return values.reshape(rows, cols)


def read_intrinsics_file(path: Path, width: int, height: int) -> Intrinsics:
    """``camera-intrinsics.txt``: a 3x3 K ``[[fx 0 cx] [0 fy cy] [0 0 1]]`` (no image size in the
    file: ``width`` x ``height`` is the caller's)."""
    k = read_matrix(path, 3, 3, "intrinsics matrix K")
    if not np.all(np.isfinite(k)) or k[0, 1] != 0 or k[1, 0] != 0 or \
            not np.array_equal(k[2], [0.0, 0.0, 1.0]):
        raise DataFormatError(
            f"{path}: expected K = [[fx 0 cx] [0 fy cy] [0 0 1]], got {k.tolist()}")
    try:
        return Intrinsics(float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]),
                          width, height)
    except EvsmapError as exc:
        raise DataFormatError(f"{path}: bad intrinsics ({exc})") from None


def read_pose(path: Path) -> np.ndarray:
    """A ``frame-NNNNNN.pose.txt``: the ``float64`` 4x4 camera-to-world matrix, checked and with
    its rotation block made orthonormal; every problem is a one-line error naming the file.

    KinectFusion's matrices are not quite rotations (on the 100-frame sample ``|R R^T - I|`` is
    1.1e-4 .. 1.4e-4 and ``det R`` 0.99982, beyond :class:`~evsmap.data.Frame`'s 1e-5 check), so a
    rotation block within :data:`ROTATION_TOLERANCE` of a rotation is replaced by the nearest
    rotation (polar decomposition, ``U V^T`` of its SVD; on the sample that moves a point by at
    most 0.07 mm per metre of range) and the translation is kept as written. Non-finite entries,
    a last row other than ``0 0 0 1`` and a block further from a rotation are refused.
    """
    return checked_pose(read_matrix(path, 4, 4, "camera-to-world pose"), str(path),
                        tolerance=ROTATION_TOLERANCE)


def _normalise_sequence(sequence: str | int) -> str:
    """``2``, ``"2"``, ``"02"``, ``"seq-2"``, ``"seq-02"`` -> ``"seq-02"`` (other names are
    kept)."""
    if isinstance(sequence, bool):
        raise EvsmapError(f"sequence must be a name such as seq-01 or a number, got {sequence!r}")
    text = str(sequence).strip()
    m = re.fullmatch(r"(?:seq-)?(\d+)", text)
    if m:
        return f"seq-{int(m.group(1)):02d}"
    return text


def is_sevenscenes_folder(path: Path) -> bool:
    """A folder with ``frame-NNNNNN.{color,depth,pose}`` files, or a scene folder holding
    ``seq-NN/`` sequence folders (or the official ``seq-NN.zip`` archives)."""
    path = Path(path)
    if not path.is_dir():
        return False
    if _has_frames(path):
        return True
    return any(_has_frames(d) for d in _sequence_dirs(path)) or bool(_zipped_sequences(path))


class SevenScenesSequence(Sequence):
    """One Microsoft 7-Scenes sequence (``seq-NN`` folder), or one sequence of a scene folder.

    Args:
        path: a sequence folder (``frame-NNNNNN.*`` files) or a scene folder holding ``seq-NN/``.
        sequence: which sequence of a scene folder (``seq-02``, ``02`` or ``2``); default the
            first. Refused for a sequence folder other than its own name.
        intrinsics: explicit camera parameters (override ``camera-intrinsics.txt`` and the
            documented 585/585/320/240).
        depth_scale: depth PNG value per metre (1000: millimetres).
        frame_rate: frames per second used to turn frame numbers into time stamps.
    """

    def __init__(self, *, path: str | Path, sequence: str | int | None = None,
                 intrinsics: Intrinsics | None = None, depth_scale: float = DEPTH_SCALE,
                 frame_rate: float = FRAME_RATE) -> None:
        given = Path(path)
        if not given.is_dir():
            raise DataFormatError(f"{given}: not a folder")
        if not (depth_scale > 0 and np.isfinite(depth_scale)):
            raise EvsmapError(f"depth_scale must be a positive number, got {depth_scale!r}")
        if not (frame_rate > 0 and np.isfinite(frame_rate)):
            raise EvsmapError(f"frame_rate must be a positive number, got {frame_rate!r}")
        root, sequences, note = self._choose(given, sequence)
        self.root = root
        self.folder = Path(root)
        self.depth_scale = float(depth_scale)
        self.frame_rate = float(frame_rate)
        listing = _scan(root)
        if not listing:
            raise DataFormatError(f"{root}: no frame-NNNNNN.color/.depth/.pose files{note}")
        self.numbers = np.array(sorted(listing), dtype=np.int64)

        def file(n: int, kind: str) -> Path:  # the name on disk, or the expected one if absent
            return root / listing[n].get(kind, f"frame-{n:06d}.{kind}")

        self.depth_files = [file(n, "depth.png") for n in self.numbers]
        self.pose_files = [file(n, "pose.txt") for n in self.numbers]
        # colour: the official PNG, else a JPEG; when neither exists frame() names both
        self.color_files = [file(n, "color.jpg" if "color.png" not in listing[n]
                                 and "color.jpg" in listing[n] else "color.png")
                            for n in self.numbers]
        self._color_missing = [not listing[n].keys() & {"color.png", "color.jpg"}
                               for n in self.numbers]
        self.timestamps = self.numbers.astype(np.float64) / self.frame_rate
        intr, source = self._intrinsics(root, intrinsics, note)
        full = root.resolve()
        name = f"{full.parent.name}/{full.name}" if _SEQ_DIR.match(full.name) else full.name
        incomplete = sum(not ({"depth.png", "pose.txt"} <= kinds.keys()
                              and kinds.keys() & {"color.png", "color.jpg"})
                         for kinds in listing.values())
        meta = {"layout": LAYOUT, "path": str(root), "intrinsics_source": source,
                "sequence": full.name,
                "frame_numbers": [int(self.numbers[0]), int(self.numbers[-1])],
                "incomplete_frames": incomplete,
                "colour_registration": "none (raw Kinect images; depth intrinsics used for both)"}
        if sequences:
            meta["sequences"] = sequences
        super().__init__(name, intr, meta)

    @staticmethod
    def _choose(given: Path, sequence: str | int | None) -> tuple[Path, list[str], str]:
        """The sequence folder to read, the scene's sequence names (empty for a sequence folder)
        and a note for error messages when the choice was not the user's."""
        if _has_frames(given):
            if sequence is not None and _normalise_sequence(sequence) != given.resolve().name:
                raise EvsmapError(
                    f"{given}: is one sequence ({given.resolve().name}) with its frames; "
                    f"sequence={sequence!r} applies to a scene folder holding seq-NN/ folders")
            return given, [], ""
        dirs = _sequence_dirs(given)
        names = [d.name for d in dirs]
        if not dirs:
            zips = _zipped_sequences(given)
            if zips:
                raise DataFormatError(
                    f"{given}: holds zipped sequences ({', '.join(zips)}); unzip them first "
                    f"(each gives a seq-NN/ folder)")
            raise DataFormatError(
                f"{given}: not a 7-Scenes folder (no frame-NNNNNN.* files, no seq-NN/ folders)")
        if sequence is None:
            chosen = dirs[0]
            note = ""
            if len(dirs) > 1:
                note = (f" (scene folder {given} holds {len(dirs)} sequences: {', '.join(names)};"
                        f" read the first, {chosen.name}; choose one with -r sequence=NAME)")
            return chosen, names, note
        want = _normalise_sequence(sequence)
        if want not in names:
            raise EvsmapError(f"{given}: no sequence {want!r} (sequence={sequence!r}); the scene "
                              f"holds {', '.join(names)}")
        return given / want, names, ""

    def _intrinsics(self, root: Path, intrinsics: Intrinsics | None,
                    note: str) -> tuple[Intrinsics, str]:
        if intrinsics is not None:
            if not isinstance(intrinsics, Intrinsics):
                raise EvsmapError(
                    f"intrinsics must be Intrinsics, got {type(intrinsics).__name__}")
            return intrinsics, "explicit"
        k_file = root / INTRINSICS_FILE
        if not k_file.is_file():
            return SEVENSCENES_INTRINSICS, "7-Scenes default depth camera"
        # K has no image size: take it from the first depth image's header (cheap, no decoding)
        width, height = SEVENSCENES_INTRINSICS.width, SEVENSCENES_INTRINSICS.height
        size = image_size(self.depth_files[0]) if self.depth_files else None
        if size is not None:  # else frame() reports the bad image itself
            width, height = size
        try:
            return read_intrinsics_file(k_file, width, height), INTRINSICS_FILE
        except DataFormatError as exc:
            raise DataFormatError(f"{exc}{note}") from None

    def __len__(self) -> int:
        return len(self.numbers)

    def frame_stem(self, index: int) -> str:
        """Frame ``index``'s own file stem, the part its colour, depth and pose files share
        (``frame-000042``): the name ``evsmap predict`` writes its outputs under."""
        return f"frame-{int(self.numbers[index]):06d}"

    def frame(self, index: int) -> Frame:
        if self._color_missing[index]:
            raise DataFormatError(
                f"{self.color_files[index]}: file not found (nor "
                f"{self.color_files[index].with_suffix('.jpg').name})")
        pose = read_pose(self.pose_files[index])
        rgb = read_rgb(self.color_files[index])
        raw = read_uint16(self.depth_files[index])
        check_rgbd_shapes(raw, rgb, self.intrinsics, depth_file=self.depth_files[index],
                          rgb_file=self.color_files[index],
                          intrinsics_source=self.meta["intrinsics_source"])
        depth = dequantize_depth(raw, self.depth_scale)
        depth[raw == INVALID_DEPTH] = 0.0
        return Frame(rgb=rgb, depth=depth, intrinsics=self.intrinsics, pose=pose,
                     timestamp=float(self.timestamps[index]), labels=None,
                     name=self.depth_files[index].name)


@READERS.register("sevenscenes", takes=Takes(path=True), detect=is_sevenscenes_folder,
                  description="Microsoft 7-Scenes sequence folder (frame-NNNNNN.color/.depth/"
                              ".pose files) or a scene folder of seq-NN/ (-r sequence=seq-02)")
def open_sevenscenes(*, path: str, sequence: str | int | None = None,
                     intrinsics: Intrinsics | None = None, depth_scale: float = DEPTH_SCALE,
                     frame_rate: float = FRAME_RATE) -> SevenScenesSequence:
    """Microsoft 7-Scenes sequence folder or scene folder (frame-NNNNNN.color/.depth/.pose).

    Args:
        path: a sequence folder (``frame-NNNNNN.*``) or a scene folder holding ``seq-NN/``.
        sequence: the sequence of a scene folder (``seq-02``, ``02`` or ``2``); default the first.
        intrinsics: explicit camera parameters (default: ``camera-intrinsics.txt``, else the
            dataset's fx = fy = 585, cx = 320, cy = 240 at 640x480).
        depth_scale: depth PNG value per metre (1000: millimetres).
        frame_rate: frames per second for the time stamps (frame N at N / frame_rate s).
    """
    return SevenScenesSequence(path=path, sequence=sequence, intrinsics=intrinsics,
                               depth_scale=depth_scale, frame_rate=frame_rate)
