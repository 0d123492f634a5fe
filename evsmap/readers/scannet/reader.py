"""ScanNet v2 scenes (Dai et al., CVPR 2017): the ``scannet`` reader.

What it opens (``path``):

* a scene folder of the official release, ``scans/scene0000_00/``, holding ``scene0000_00.sens``
  (the RGB-D stream, :mod:`~evsmap.readers.scannet.sens`), ``scene0000_00_vh_clean_2.labels.ply``
  (the labelled mesh, :mod:`~evsmap.readers.scannet.mesh`) and optionally
  ``scene0000_00_2d-label-filt.zip`` (ScanNet's filtered 2D label images, ``label-filt/N.png``);
  or the ``.sens`` file itself;
* the release's root (``scans/`` inside, ``scannetv2-labels.combined.tsv`` beside it), one scene
  read at a time (``scene=``, default the first by name);
* a folder written by ScanNet's SensReader (``reader.py --export_*``): ``color/N.jpg``,
  ``depth/N.png`` (16-bit, depth shift 1000), ``pose/N.txt`` (4x4 camera-to-world) and
  ``intrinsic/intrinsic_depth.txt`` (4x4), with ``label-filt/N.png`` if extracted; the labelled
  mesh is looked for in the folder and its parent.

Frames. Depth is metres = stored value / depth shift (1000), 0 = no measurement. The camera is
the depth camera: its intrinsics (``intrinsic_depth``) at the depth image's size. The colour
image (1296x968 in ScanNet) is resized to the depth image's size (bilinear) and used with the
depth camera's intrinsics, as the dataset's depth is registered to its colour camera and the
two share a field of view (ScanNet's colour fx = 1170 at 1296 px is the depth camera's 577.6 at
640 px); colours can be off by a pixel at depth edges. Poses are camera-to-world of that camera,
in the frame the mesh is in. A frame whose pose ScanNet marks invalid (-inf, tracking lost) is
a bad frame: a one-line error, which ``--skip-bad`` skips. Time stamps are the depth stamps
(microseconds) in seconds, or ``N / 30`` where the file has none (the exported layout).

Labels for the oracle (``labels=``): ``label-filt`` reads ScanNet's filtered 2D label images
(ScanNet label ids, mapped to NYU40 through ``scannetv2-labels.combined.tsv``, resized to the
depth image, nearest); ``mesh`` labels each pixel with the class of the labelled mesh's voxel
(2 cm, :data:`MESH_LABEL_RESOLUTION`) at its back-projected point, or the nearest one within
one voxel, void where there is none; ``none``; ``auto`` (default): ``label-filt`` where the
images and the table are there, else ``mesh`` where the mesh is, else none. Classes are NYU40,
0-based, as evsmap's networks are trained (255 void).

3D ground truth (:meth:`ScanNetSequence.ground_truth`): the labelled mesh voxelised at the
map's resolution (:func:`~evsmap.readers.scannet.mesh.voxelise`).
"""

from __future__ import annotations

import hashlib
import os
import zipfile
from pathlib import Path

import numpy as np

from evsmap.classes import NYU40_CLASSES
from evsmap.data import VOID, Frame, Intrinsics, Sequence, VoxelLabels
from evsmap.errors import DataFormatError, EvsmapError
from evsmap.readers.images import (
    decode_uint16,
    dequantize_depth,
    image_size,
    read_rgb,
    read_uint16,
)
from evsmap.readers.poses import checked_pose
from evsmap.readers.scannet.labelmap import LABELS_TSV, SCENE_ID, read_label_table
from evsmap.readers.scannet.mesh import LabelMesh, read_label_mesh, voxelise
from evsmap.readers.scannet.sens import SensFile
from evsmap.registry import READERS, Takes

LAYOUT = "scannet"
FRAME_RATE = 30.0
EXPORTED_DEPTH_SHIFT = 1000.0
"""SensReader's exported depth PNGs: value per metre (its README: "depth shift 1000")."""
MESH_SUFFIX = "_vh_clean_2.labels.ply"
LABEL_ZIP_SUFFIX = "_2d-label-filt.zip"
LABEL_DIR = "label-filt"
MESH_LABEL_RESOLUTION = 0.02
"""Voxel edge of the mesh ground truth that ``labels=mesh`` projects into the frames."""
ROTATION_TOLERANCE = 1e-3
"""Largest ``|R R^T - I|`` of a stored pose made orthonormal rather than refused (float32
matrices from BundleFusion are about 1e-7 off)."""
LABEL_SOURCES = ("auto", "label-filt", "mesh", "none")
_EXPORTED = ("color", "depth", "pose", "intrinsic")
TSV_SEARCH_DEPTH = 3
"""Folders above a scene searched for ``scannetv2-labels.combined.tsv``."""


def _sens_in(folder: Path) -> list[Path]:
    try:
        return sorted(p for p in folder.iterdir() if p.suffix == ".sens" and p.is_file())
    except OSError:
        return []


def _scene_dirs(root: Path) -> list[Path]:
    scans = root / "scans"
    try:
        return sorted(p for p in scans.iterdir() if SCENE_ID.match(p.name) and p.is_dir())
    except OSError:
        return []


def _is_exported(folder: Path) -> bool:
    return all((folder / d).is_dir() for d in _EXPORTED) and \
        (folder / "intrinsic" / "intrinsic_depth.txt").is_file()


def is_scannet(path: Path) -> bool:
    """A ``.sens`` file, a folder holding one, a SensReader export, or a release root with
    ``scans/sceneNNNN_NN/``."""
    path = Path(path)
    if path.is_file():
        return path.suffix == ".sens"
    if not path.is_dir():
        return False
    return bool(_sens_in(path)) or _is_exported(path) or bool(_scene_dirs(path))


class _SensFrames:
    """Frames from a ``.sens`` stream."""

    source = "sens"

    def __init__(self, path: Path) -> None:
        self.file = SensFile(path)
        self.path = path
        header = self.file.header
        self.numbers = np.arange(len(self.file), dtype=np.int64)
        w, h = header.depth_size
        self.intrinsics = _intrinsics(header.intrinsic_depth, w, h, f"{path}: depth camera")
        self.depth_shift = header.depth_shift
        stamps = np.array([e.timestamp_depth for e in self.file.frames], dtype=np.float64)
        self.stamped = bool(stamps.size and np.any(stamps != 0))
        self.timestamps = stamps / 1e6 if self.stamped else self.numbers / FRAME_RATE
        invalid = sum(not np.all(np.isfinite(e.pose)) for e in self.file.frames)
        self.meta = {"sensor": header.sensor_name, "frames_in_file": len(self.file),
                     "invalid_poses": int(invalid),
                     "color_size": list(header.color_size), "depth_size": list(header.depth_size),
                     "color_compression": header.color_compression,
                     "depth_compression": header.depth_compression,
                     "depth_shift": header.depth_shift,
                     "timestamps": "depth stamps" if self.stamped else "N / 30 s"}

    def where(self, i: int) -> str:
        return f"{self.path}: frame {int(self.numbers[i])}"

    def pose(self, i: int) -> np.ndarray:
        return self.file.frames[i].pose

    def depth(self, i: int) -> np.ndarray:
        return self.file.depth(i)

    def color(self, i: int) -> np.ndarray:
        return self.file.color(i)


class _ExportedFrames:
    """Frames from a SensReader export (``color/ depth/ pose/ intrinsic/``)."""

    source = "exported"

    def __init__(self, folder: Path) -> None:
        self.path = folder
        found: dict[str, dict[int, Path]] = {}
        for kind, ext in (("color", ".jpg"), ("depth", ".png"), ("pose", ".txt")):
            found[kind] = _numbered(folder / kind, ext)
        numbers = sorted(set().union(*(set(v) for v in found.values())))
        if not numbers:
            raise DataFormatError(f"{folder}: color/, depth/ and pose/ hold no numbered frames "
                                  f"(N.jpg, N.png, N.txt)")
        self.files = found
        self.numbers = np.array(numbers, dtype=np.int64)
        k_file = folder / "intrinsic" / "intrinsic_depth.txt"
        first_depth = found["depth"].get(numbers[0])
        size = image_size(first_depth) if first_depth is not None else None
        w, h = size if size is not None else (640, 480)
        from evsmap.readers.sevenscenes import read_matrix

        self.intrinsics = _intrinsics(read_matrix(k_file, 4, 4, "intrinsic matrix"), w, h,
                                      str(k_file))
        self.depth_shift = EXPORTED_DEPTH_SHIFT
        self.timestamps = self.numbers / FRAME_RATE
        incomplete = sum(any(n not in v for v in found.values()) for n in numbers)
        self.meta = {"frames_in_folder": len(numbers), "incomplete_frames": incomplete,
                     "depth_shift": EXPORTED_DEPTH_SHIFT, "timestamps": "N / 30 s"}

    def _file(self, kind: str, i: int, ext: str) -> Path:
        n = int(self.numbers[i])
        path = self.files[kind].get(n)
        if path is None:
            raise DataFormatError(f"{self.path / kind / f'{n}{ext}'}: file not found")
        return path

    def where(self, i: int) -> str:
        return str(self._file("pose", i, ".txt"))

    def pose(self, i: int) -> np.ndarray:
        from evsmap.readers.sevenscenes import read_matrix

        return read_matrix(self._file("pose", i, ".txt"), 4, 4, "camera-to-world pose")

    def depth(self, i: int) -> np.ndarray:
        return read_uint16(self._file("depth", i, ".png"))

    def color(self, i: int) -> np.ndarray:
        return read_rgb(self._file("color", i, ".jpg"))


def _tracked(frames: _SensFrames | _ExportedFrames, i: int) -> bool:
    """Whether frame ``i``'s stored pose is not ScanNet's -inf mark (an unreadable pose file
    stays in, a bad frame for :meth:`ScanNetSequence.frame` to report)."""
    try:
        return not np.all(np.isneginf(np.asarray(frames.pose(i))))
    except DataFormatError:
        return True


def _numbered(folder: Path, ext: str) -> dict[int, Path]:
    try:
        names = os.listdir(folder)
    except OSError:
        return {}
    out = {}
    for name in names:
        stem, dot, suffix = name.partition(".")
        if dot and "." + suffix == ext and stem.isdigit() and len(stem) < 16:
            out[int(stem)] = folder / name
    return out


def _intrinsics(k: np.ndarray, width: int, height: int, where: str) -> Intrinsics:
    """The pinhole of a 4x4 (or 3x3) ScanNet intrinsic matrix at ``width`` x ``height``."""
    k = np.asarray(k, dtype=np.float64)
    if not np.all(np.isfinite(k[:3, :3])):
        raise DataFormatError(f"{where}: non-finite intrinsic matrix")
    try:
        return Intrinsics(float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]),
                          int(width), int(height))
    except EvsmapError as exc:
        raise DataFormatError(f"{where}: bad intrinsics ({exc})") from None


def _resize(image: np.ndarray, width: int, height: int, *, nearest: bool) -> np.ndarray:
    if image.shape[1] == width and image.shape[0] == height:
        return image
    from PIL import Image

    resample = Image.Resampling.NEAREST if nearest else Image.Resampling.BILINEAR
    return np.asarray(Image.fromarray(image).resize((width, height), resample))


class ScanNetSequence(Sequence):
    """One ScanNet scene (:mod:`module notes <evsmap.readers.scannet.reader>`).

    Args:
        path: a scene folder, its ``.sens`` file, a SensReader export, or the release root.
        scene: the scene of a release root (``scene0011_00``); default the first by name.
        labels: where the oracle's frame labels come from: ``auto``, ``label-filt``, ``mesh``
            or ``none``.
        step: read every ``step``-th frame (ScanNet records at 30 Hz).
        mesh: the labelled mesh (default ``<scene>_vh_clean_2.labels.ply`` beside the frames).
        label_table: ``scannetv2-labels.combined.tsv`` (default: looked for in the scene's
            folder and the three above it).
        drop_lost: leave out the frames whose pose is invalid (-inf, tracking lost) before
            taking every ``step``-th (what the runner maps); by default they are bad frames.
    """

    def __init__(self, *, path: str | Path, scene: str | None = None, labels: str = "auto",
                 step: int = 1, mesh: str | Path | None = None,
                 label_table: str | Path | None = None, drop_lost: bool = False) -> None:
        given = Path(path)
        if labels not in LABEL_SOURCES:
            raise EvsmapError(f"labels must be one of {', '.join(LABEL_SOURCES)}, got {labels!r}")
        if isinstance(step, bool) or not isinstance(step, int) or step < 1:
            raise EvsmapError(f"step must be a positive integer, got {step!r}")
        folder, scene_id, frames = self._open(given, scene)
        self.folder = folder
        self.scene_id = scene_id
        self.root = frames.path
        self.frames = frames
        self.step = step
        kept = np.arange(len(frames.numbers), dtype=np.int64)
        lost = 0
        if drop_lost:
            tracked = [i for i in range(len(kept)) if _tracked(frames, i)]
            kept, lost = kept[tracked], len(kept) - len(tracked)
        self.indices = kept[::step]
        if mesh is not None and not Path(mesh).is_file():
            raise DataFormatError(f"{mesh}: file not found (mesh=)")
        self.mesh_path = Path(mesh) if mesh is not None else self._find_mesh(folder, scene_id)
        self.table_path = (Path(label_table) if label_table is not None
                           else _find_upwards(folder, LABELS_TSV))
        self.label_images = self._find_label_images(folder, scene_id)
        self.labels_source = self._labels_source(labels)
        self._mesh: LabelMesh | None = None
        self._truth: dict[float, VoxelLabels] = {}
        self._label_lookup: np.ndarray | None = None
        self._lookup: VoxelLookup | None = None
        self._zip: zipfile.ZipFile | None = None
        meta = {"layout": LAYOUT, "source": frames.source, "path": str(frames.path),
                "scene": scene_id, "step": step, **frames.meta,
                **({"dropped": {"lost_tracking": lost}} if drop_lost else {}),
                "mesh": None if self.mesh_path is None else str(self.mesh_path),
                "label_table": None if self.table_path is None else str(self.table_path),
                "labels": self.labels_source,
                "ground_truth_source": None if self.mesh_path is None else
                f"labelled mesh {self.mesh_path.name}, voxelised at the map's resolution",
                "colour_registration": "colour resized to the depth image; depth camera "
                                       "intrinsics for both",
                "class_names": list(NYU40_CLASSES), "num_classes": len(NYU40_CLASSES)}
        super().__init__(scene_id, frames.intrinsics, meta)

    # ---- where the files are
    @staticmethod
    def _open(given: Path, scene: str | None) -> tuple[Path, str, _SensFrames | _ExportedFrames]:
        if given.is_file():
            if given.suffix != ".sens":
                raise DataFormatError(f"{given}: not a .sens file")
            if scene is not None:
                raise EvsmapError(f"{given}: scene= applies to a release root holding scans/")
            return given.parent, given.stem, _SensFrames(given)
        if not given.is_dir():
            raise DataFormatError(f"{given}: no such file or folder")
        scenes = _scene_dirs(given)
        if scenes and not _sens_in(given):
            names = [p.name for p in scenes]
            chosen = scenes[0] if scene is None else given / "scans" / str(scene)
            if scene is not None and chosen.name not in names:
                listed = ", ".join(names[:8]) + (" ..." if len(names) > 8 else "")
                raise EvsmapError(f"{given}: no scene {scene!r} under scans/ (it holds {listed})")
            given = chosen
        elif scene is not None:
            raise EvsmapError(f"{given}: scene= applies to a release root holding scans/")
        sens = _sens_in(given)
        if sens:
            own = [p for p in sens if p.stem == given.name]
            if len(sens) > 1 and not own:
                raise DataFormatError(f"{given}: holds {len(sens)} .sens files "
                                      f"({', '.join(p.name for p in sens[:4])}); give one")
            path = (own or sens)[0]
            return given, path.stem, _SensFrames(path)
        if _is_exported(given):
            scene_id = given.name if SCENE_ID.match(given.name) else given.resolve().name
            return given, scene_id, _ExportedFrames(given)
        raise DataFormatError(f"{given}: not a ScanNet scene (no .sens file, no color/ depth/ "
                              f"pose/ intrinsic/ export, no scans/ folder)")

    @staticmethod
    def _find_mesh(folder: Path, scene_id: str) -> Path | None:
        for place in (folder, folder.parent):
            exact = place / f"{scene_id}{MESH_SUFFIX}"
            if exact.is_file():
                return exact
            try:
                found = sorted(p for p in place.iterdir() if p.name.endswith(MESH_SUFFIX))
            except OSError:
                found = []
            if len(found) == 1:
                return found[0]
        return None

    @staticmethod
    def _find_label_images(folder: Path, scene_id: str) -> Path | None:
        archive = folder / f"{scene_id}{LABEL_ZIP_SUFFIX}"
        if archive.is_file():
            return archive
        extracted = folder / LABEL_DIR
        return extracted if extracted.is_dir() else None

    def _labels_source(self, wanted: str) -> str:
        if wanted == "label-filt":
            if self.label_images is None:
                raise DataFormatError(f"{self.folder}: labels=label-filt needs "
                                      f"{self.scene_id}{LABEL_ZIP_SUFFIX} or {LABEL_DIR}/")
            if self.table_path is None:
                raise DataFormatError(f"{self.folder}: labels=label-filt needs {LABELS_TSV} (the "
                                      f"ScanNet label ids' NYU40 classes): put it in the release "
                                      f"root or pass -r label_table=FILE")
        if wanted == "mesh" and self.mesh_path is None:
            raise DataFormatError(f"{self.folder}: labels=mesh needs the labelled mesh "
                                  f"(*{MESH_SUFFIX}); pass -r mesh=FILE")
        if wanted != "auto":
            return wanted
        if self.label_images is not None and self.table_path is not None:
            return "label-filt"
        return "mesh" if self.mesh_path is not None else "none"

    def frames_identity(self) -> str:
        """The stream's and the label files' paths, sizes and modification times, with the
        frames chosen (step, lost frames dropped) and the labels' source."""
        parts = [f"scannet:{self.scene_id}", f"step={self.step}",
                 "frames=" + hashlib.sha256(self.indices.tobytes()).hexdigest()[:16],
                 f"labels={self.labels_source}"]
        for path in (self.frames.path, self.mesh_path, self.table_path, self.label_images):
            if path is not None:
                try:
                    st = Path(path).stat()
                    parts.append(f"{Path(path).resolve()}:{st.st_mtime_ns}:{st.st_size}")
                except OSError:
                    parts.append(str(path))
        return "|".join(parts)

    # ---- ground truth
    @property
    def has_ground_truth(self) -> bool:
        return self.mesh_path is not None

    def label_mesh(self) -> LabelMesh:
        """The labelled mesh (read once)."""
        if self.mesh_path is None:
            raise DataFormatError(f"{self.folder}: no labelled mesh (*{MESH_SUFFIX})")
        if self._mesh is None:
            self._mesh = read_label_mesh(self.mesh_path)
        return self._mesh

    def ground_truth(self, resolution: float) -> VoxelLabels | None:
        """The labelled mesh voxelised at ``resolution`` (made once per resolution); None
        without a mesh."""
        if self.mesh_path is None:
            return None
        key = float(resolution)
        if key not in self._truth:
            self._truth[key] = voxelise(self.label_mesh(), key)
        return self._truth[key]

    # ---- frames
    def __len__(self) -> int:
        return len(self.indices)

    def frame_stem(self, index: int) -> str:
        """Frame ``index``'s ScanNet frame number, the name SensReader exports it under."""
        return str(int(self.frames.numbers[self.indices[index]]))

    def frame(self, index: int) -> Frame:
        i = int(self.indices[index])
        src = self.frames
        stored = np.asarray(src.pose(i))
        if np.all(np.isneginf(stored)):
            raise DataFormatError(f"{src.where(i)}: invalid camera pose (-inf, ScanNet's mark for "
                                  f"a frame its tracking lost); --skip-bad skips such frames")
        pose = checked_pose(stored, src.where(i), tolerance=ROTATION_TOLERANCE)
        raw = src.depth(i)
        intr = src.intrinsics
        if raw.shape != intr.shape:
            raise DataFormatError(f"{src.where(i)}: depth is {raw.shape[1]}x{raw.shape[0]} but "
                                  f"the depth camera's intrinsics are for "
                                  f"{intr.width}x{intr.height}")
        rgb = _resize(src.color(i), intr.width, intr.height, nearest=False)
        depth = dequantize_depth(raw, src.depth_shift)
        labels = self._labels(i, depth, pose)
        return Frame(rgb=rgb, depth=depth, intrinsics=intr, pose=pose,
                     timestamp=float(src.timestamps[i]), labels=labels,
                     name=self.frame_stem(index))

    def _labels(self, i: int, depth: np.ndarray, pose: np.ndarray) -> np.ndarray | None:
        if self.labels_source == "label-filt":
            return self._label_image(i)
        if self.labels_source == "mesh":
            if self._lookup is None:
                truth = self.ground_truth(MESH_LABEL_RESOLUTION)
                assert truth is not None
                self._lookup = VoxelLookup(truth)
            return self._lookup.project(depth, self.frames.intrinsics, pose)
        return None

    def _label_archive(self) -> zipfile.ZipFile:
        """The 2D label archive, opened once: its central directory lists thousands of images
        (parsing it took 13 ms a frame for 5 000 when the archive was opened per frame)."""
        if self._zip is None:
            assert self.label_images is not None
            self._zip = zipfile.ZipFile(self.label_images)
        return self._zip

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_zip"] = None  # an open file does not travel to another process
        return state

    def _label_image(self, i: int) -> np.ndarray:
        n = int(self.frames.numbers[i])
        assert self.label_images is not None and self.table_path is not None
        if self._label_lookup is None:
            self._label_lookup = read_label_table(self.table_path)
        if self.label_images.is_dir():
            raw = read_uint16(self.label_images / f"{n}.png")
        else:
            member = f"{LABEL_DIR}/{n}.png"
            where = f"{self.label_images}: {member}"
            try:
                data = self._label_archive().read(member)
            except KeyError:
                raise DataFormatError(f"{where}: not in the archive") from None
            # what zipfile raises on a damaged archive or member (NotImplementedError: a
            # compression method it does not have)
            except (OSError, zipfile.BadZipFile, EOFError, NotImplementedError) as exc:
                raise DataFormatError(f"{where}: cannot read ({exc})") from None
            raw = decode_uint16(data, where=where)
        intr = self.frames.intrinsics
        return _resize(self._label_lookup[raw], intr.width, intr.height, nearest=True)


class VoxelLookup:
    """A :class:`~evsmap.data.VoxelLabels` made searchable once: its voxels' codes sorted, so
    that labelling a frame's pixels (:meth:`project`) costs the search alone; a sequence keeps one.

    Args:
        truth: the voxels and their classes.
    """

    def __init__(self, truth: VoxelLabels) -> None:
        from evsmap.mapping.keys import KEY_MAX, KEY_OFFSET, pack

        gt = truth.keys.astype(np.int64) + KEY_OFFSET
        inside = np.all((gt >= 0) & (gt <= KEY_MAX), axis=1)
        codes = pack(gt[inside])
        order = np.argsort(codes)
        self.resolution = truth.resolution
        self.codes = codes[order]
        self.labels = truth.labels[inside][order]

    def project(self, depth: np.ndarray, intrinsics: Intrinsics,
                pose: np.ndarray) -> np.ndarray:
        """Each pixel's class: the voxel at its back-projected point, else the nearest within
        one voxel (:func:`~evsmap.metrics.mapping.nearest_within`); :data:`VOID` where the
        depth is missing or no voxel is near."""
        from evsmap.geometry import backproject
        from evsmap.mapping.keys import KEY_OFFSET
        from evsmap.metrics.mapping import nearest_within

        out = np.full(depth.shape, VOID, dtype=np.uint8)
        valid = depth > 0
        if not valid.any() or not self.codes.size:
            return out
        points = backproject(depth, intrinsics, pose)
        keys = np.floor(points / self.resolution).astype(np.int64) + KEY_OFFSET
        found = nearest_within(keys, self.codes, 1)
        cls = np.full(len(keys), VOID, dtype=np.uint8)
        hit = found >= 0
        cls[hit] = self.labels[found[hit]]
        out[valid] = cls
        return out


def _find_upwards(folder: Path, name: str) -> Path | None:
    place = folder.resolve()
    for _ in range(TSV_SEARCH_DEPTH + 1):
        candidate = place / name
        if candidate.is_file():
            return candidate
        if place.parent == place:
            break
        place = place.parent
    return None


@READERS.register("scannet", takes=Takes(path=True), detect=is_scannet,
                  description="ScanNet v2 scene: scans/sceneNNNN_NN/ with its .sens and "
                              "labelled mesh, the .sens file, a SensReader export, or the "
                              "release root (-r scene=scene0011_00)")
def open_scannet(*, path: str, scene: str | None = None, labels: str = "auto", step: int = 1,
                 mesh: str | None = None, label_table: str | None = None,
                 drop_lost: bool = False) -> ScanNetSequence:
    """ScanNet v2 scene (``.sens`` stream or SensReader export, labelled mesh as 3D truth).

    Args:
        path: a scene folder, its ``.sens`` file, a SensReader export, or the release root.
        scene: the scene of a release root (``scene0011_00``); default the first by name.
        labels: the oracle's frame labels: ``auto`` (ScanNet's label-filt images where they
            and the label table are there, else projected from the labelled mesh), ``label-filt``,
            ``mesh`` or ``none``.
        step: read every step-th frame (ScanNet records at 30 Hz).
        mesh: the labelled mesh (default ``<scene>_vh_clean_2.labels.ply`` beside the frames).
        label_table: ``scannetv2-labels.combined.tsv`` (default: found in the scene's folder or
            up to three folders above).
        drop_lost: leave out the frames with invalid (-inf) poses before taking every
            step-th (by default each is a bad frame that --skip-bad skips).
    """
    return ScanNetSequence(path=path, scene=scene, labels=labels, step=step, mesh=mesh,
                           label_table=label_table, drop_lost=drop_lost)


__all__ = ["LABEL_SOURCES", "MESH_LABEL_RESOLUTION", "ScanNetSequence", "is_scannet",
           "open_scannet", "VoxelLookup"]
