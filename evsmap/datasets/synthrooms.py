"""Synthetic rooms: a labelled RGB-D segmentation dataset rendered from the built-in procedural
rooms (:mod:`evsmap.synth`), split into train/val/test by room - :func:`prepare_synthrooms` and
the reader of its folder.

Generation. Room ``i`` (0-based) is of type ``SCENE_TYPES[i % 4]`` (``bedroom``, ``living_room``,
``office``, ``kitchen``: round-robin) and has its own layout seed derived from ``seed`` and ``i``
(:func:`room_seed`; ``evsmap synth --scene TYPE --seed ROOM_SEED --noise`` renders the same
room). Each room is seen from ``frames_per_room`` views spread over one lap of the synth camera
path (:func:`evsmap.synth.trajectory.room_trajectory`), whose distance from the walls, height,
mean pitch and gaze sweep rate are drawn per room, so rooms are not all seen from the same lap.
Depth carries the Kinect-v1-like noise and holes of ``evsmap synth --noise``; labels and poses are
exact. The same options give the same bytes.

Splits (:func:`split_rooms`): the last ``max(h, round(0.15 N))`` rooms are ``test``, the same
number before them ``val`` and the rest ``train``, with ``h = 2`` from 8 rooms on (else 1). A room
is in exactly one split; consecutive rooms have different types, so from 8 rooms on every split
has at least two room types (from 24 rooms on, all four). At least 3 rooms are needed.

Prepared layout (``RRRR`` the room index, ``FFFF`` the view index in the room)::

    rgb/RRRR_FFFF.png      8-bit RGB
    depth/RRRR_FFFF.png    uint16, metres = value / 5000, 0 = invalid
    labels/RRRR_FFFF.png   uint8 0..39 (NYUv2-40 standard order), 255 = void
    poses.txt              "id room timestamp tx ty tz qx qy qz qw" per frame (camera-to-world,
                           OpenCV camera axes, full float precision)
    train.txt val.txt test.txt   one frame id per line
    evsmap-dataset.json    manifest: generator version, options, camera intrinsics, rooms
                           (type, seed, split, size, camera-path parameters), rooms and frames per
                           split, class names, pixel counts per class and split

(``labels/`` rather than NYUv2's ``label40/``, so the folder is not taken for a NYUv2 one.)

Reader (``synthrooms``; ``split`` = ``all`` / ``train`` / ``val`` / ``test``, ``limit``,
``room``): frames carry the renderer's intrinsics and camera-to-world poses. Frames of several
rooms do not share one world (every room has its origin in a corner), so such a sequence has
``meta["poses"] = False`` (``evsmap map`` refuses it) and timestamps ``0, 1, 2, ...``;
``room=N`` selects one room's frames in path order with their walk timestamps and
``meta["poses"] = True``, which ``evsmap map`` integrates with the true poses.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from evsmap.classes import NYU40_CLASSES, palette
from evsmap.data import VOID, Frame, Intrinsics, VoxelLabels
from evsmap.datasets.common import (
    Progress,
    SegmentationSequence,
    apply_limit,
    check_frame_id,
    check_limit,
    check_shape,
    check_split,
    make_manifest,
    read_id_list,
    read_label_png,
    read_manifest,
    require_dir,
    require_file,
    write_manifest,
)
from evsmap.errors import DataFormatError, EvsmapError
from evsmap.fileio import atomic_write_text, staging_folder
from evsmap.geometry import pose_matrix
from evsmap.readers.images import (
    DEPTH_SCALE,
    dequantize_depth,
    quantize_depth,
    read_rgb,
    read_uint16,
    write_png,
)
from evsmap.registry import READERS, Takes

NAME = "synthrooms"
GENERATOR_VERSION = 1
"""Bumped whenever a change alters the generated files for the same options (the synth renderer's
own version is recorded beside it)."""
SPLITS = ("train", "val", "test")
NUM_CLASSES = len(NYU40_CLASSES)
RGB_DIR, DEPTH_DIR, LABEL_DIR = "rgb", "depth", "labels"
POSES_FILE = "poses.txt"

DEFAULT_ROOMS = 24
DEFAULT_FRAMES_PER_ROOM = 20
DEFAULT_SIZE = (240, 320)
"""(height, width): half the NYUv2 / Kinect resolution, what the ``synth-proxy`` training uses."""
DEFAULT_SEED = 0
MIN_ROOMS = 3
MAX_ROOMS = 9999
MAX_FRAMES_PER_ROOM = 9999
MIN_SIDE, MAX_SIDE = 16, 4096

# per-room camera-path parameters, drawn uniformly (see room_trajectory)
PATH_RANGES = {
    "inset": (1.0, 1.6),  # metres from the walls (tall furniture stands within 0.8 m of them)
    "eye_height": (1.15, 1.6),  # above the low furniture in the middle (chair backs < 1 m)
    "pitch": (-0.45, -0.2),  # radians, mean of a +-0.18 swing
    "turns": (0.7, 1.5),  # gaze sweeps per lap / 2
}


# -- plan -----------------------------------------------------------------------------------------
def scene_types() -> tuple[str, ...]:
    """The synth package's room types, in its order (the round-robin order of the rooms)."""
    from evsmap.synth.scene import SCENES

    return tuple(SCENES)


def room_seed(seed: int, index: int) -> int:
    """Layout seed of room ``index`` for the dataset seed ``seed`` (31-bit, hashed so it does not
    coincide with the small seeds of demos and tests)."""
    state = np.random.SeedSequence([int(seed), int(index), 0x5259]).generate_state(1, np.uint32)
    return int(state[0] & np.uint32(0x7FFFFFFF))


def room_path(seed: int, index: int) -> dict[str, float]:
    """Camera-path parameters of room ``index`` (keyword arguments of ``room_trajectory``)."""
    rng = np.random.default_rng([int(seed), int(index), 0x9A7])
    return {k: round(float(rng.uniform(lo, hi)), 4) for k, (lo, hi) in PATH_RANGES.items()}


def split_rooms(rooms: int) -> dict[str, list[int]]:
    """Room indices per split (see the module docstring); needs ``rooms >= 3``."""
    if rooms < MIN_ROOMS:
        raise EvsmapError(f"{NAME} needs at least {MIN_ROOMS} rooms (one each for train, val and "
                          f"test), got {rooms}")
    held = max(2 if rooms >= 8 else 1, math.floor(0.15 * rooms + 0.5))
    first_val, first_test = rooms - 2 * held, rooms - held
    return {"train": list(range(first_val)), "val": list(range(first_val, first_test)),
            "test": list(range(first_test, rooms))}


def frame_id(room: int, view: int) -> str:
    return f"{room:04d}_{view:04d}"


def _check_int(name: str, value: object, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) \
            or not lo <= value <= hi:
        raise EvsmapError(f"{NAME}: {name} must be an integer in {lo}..{hi}, got {value!r}")
    return int(value)


def parse_size(text: str) -> tuple[int, int]:
    """``"HxW"`` -> ``(height, width)``, each in 16..4096; else a one-line error."""
    parts = str(text).lower().split("x")
    try:
        if len(parts) != 2:
            raise ValueError
        h, w = (int(p) for p in parts)
    except ValueError:
        raise EvsmapError(f"size must be HEIGHTxWIDTH in pixels (e.g. 240x320), got {text!r}"
                          ) from None
    if not (MIN_SIDE <= h <= MAX_SIDE and MIN_SIDE <= w <= MAX_SIDE):
        raise EvsmapError(f"size {text!r}: height and width must be in {MIN_SIDE}..{MAX_SIDE}")
    return h, w


def _room_sequence(scene: str, seed: int, frames: int, height: int, width: int,
                   path: dict[str, Any]):
    """The synth sequence of one room with this room's camera path (noisy depth)."""
    from evsmap.synth.sequence import SyntheticSequence
    from evsmap.synth.trajectory import room_trajectory

    seq = SyntheticSequence(scene=scene, seed=seed, frames=frames, width=width, height=height,
                            noise=True)
    seq.timestamps, seq.translations, seq.quaternions = room_trajectory(
        seq.room.size, frames, seed=seed, **path)
    return seq


# -- preparation ----------------------------------------------------------------------------------
def prepare_synthrooms(out_dir: str | Path, *, rooms: int = DEFAULT_ROOMS,
                       frames_per_room: int = DEFAULT_FRAMES_PER_ROOM,
                       size: tuple[int, int] = DEFAULT_SIZE, seed: int = DEFAULT_SEED,
                       overwrite: bool = False, progress: Progress | None = None) -> dict:
    """Render ``rooms`` rooms x ``frames_per_room`` views at ``size`` = (height, width) into the
    prepared layout in ``out_dir`` (see the module docstring) and return the manifest.

    ``out_dir`` is written atomically (refused when it exists and is not empty, unless
    ``overwrite``). ``progress`` wraps the list of (room, view) pairs to render.
    """
    from evsmap.synth.sequence import GENERATOR_VERSION as SYNTH_VERSION
    from evsmap.synth.sequence import default_intrinsics

    rooms = _check_int("rooms", rooms, MIN_ROOMS, MAX_ROOMS)
    frames_per_room = _check_int("frames_per_room", frames_per_room, 1, MAX_FRAMES_PER_ROOM)
    seed = _check_int("seed", seed, 0, 2**63 - 1)
    if not (isinstance(size, (tuple, list)) and len(size) == 2):
        raise EvsmapError(f"{NAME}: size must be (height, width), got {size!r}")
    height, width = (_check_int(n, v, MIN_SIDE, MAX_SIDE)
                     for n, v in zip(("height", "width"), size, strict=True))
    types = scene_types()
    splits = split_rooms(rooms)
    split_of = {r: s for s, members in splits.items() for r in members}
    plan: list[dict[str, Any]] = [
        {"index": i, "scene": types[i % len(types)], "seed": room_seed(seed, i),
         "split": split_of[i], "frames": frames_per_room, "path": room_path(seed, i)}
        for i in range(rooms)]
    intrinsics = default_intrinsics(width, height)
    counts = {s: np.zeros(256, dtype=np.int64) for s in SPLITS}
    pose_lines = ["# id room timestamp tx ty tz qx qy qz qw  (camera-to-world, OpenCV camera "
                  "axes: x right, y down, z forward; room frame: floor corner at the origin, "
                  "z up)\n"]
    tasks = [(r, v) for r in range(rooms) for v in range(frames_per_room)]
    with staging_folder(Path(out_dir), overwrite=overwrite) as stage:
        for sub in (RGB_DIR, DEPTH_DIR, LABEL_DIR):
            (stage / sub).mkdir()
        current, seq = -1, None
        for r, v in (progress(tasks) if progress else tasks):
            room = plan[r]
            if r != current:
                seq = _room_sequence(room["scene"], room["seed"], frames_per_room, height,
                                     width, room["path"])
                room["size_m"] = [round(float(x), 6) for x in seq.room.size]
                current = r
            assert seq is not None  # made for the first task
            frame = seq.frame(v)
            fid = frame_id(r, v)
            write_png(stage / RGB_DIR / f"{fid}.png", frame.rgb)
            write_png(stage / DEPTH_DIR / f"{fid}.png", quantize_depth(frame.depth))
            write_png(stage / LABEL_DIR / f"{fid}.png", frame.labels)
            counts[room["split"]] += np.bincount(frame.labels.ravel(), minlength=256)
            values = [*seq.translations[v], *seq.quaternions[v]]
            pose_lines.append(f"{fid} {r} {seq.timestamps[v]:.6f} "
                              + " ".join(repr(float(x)) for x in values) + "\n")
        atomic_write_text(stage / POSES_FILE, "".join(pose_lines))
        for s in SPLITS:
            atomic_write_text(stage / f"{s}.txt", "".join(
                f"{frame_id(r, v)}\n" for r in splits[s] for v in range(frames_per_room)))
        manifest = make_manifest(
            NAME, source=stage, splits={s: len(splits[s]) * frames_per_room for s in SPLITS},
            generator={"module": __name__, "version": GENERATOR_VERSION,
                       "synth_version": SYNTH_VERSION},
            options={"rooms": rooms, "frames_per_room": frames_per_room, "height": height,
                     "width": width, "seed": seed, "noise": True},
            num_classes=NUM_CLASSES, class_names=list(NYU40_CLASSES), void_label=VOID,
            depth_scale=DEPTH_SCALE, intrinsics=intrinsics.as_dict(), scene_types=list(types),
            split_rooms=splits,
            split_scenes={s: {t: sum(plan[r]["scene"] == t for r in splits[s]) for t in types}
                          for s in SPLITS},
            pixel_counts={s: {"classes": [int(c) for c in counts[s][:NUM_CLASSES]],
                              "void": int(counts[s][VOID]), "total": int(counts[s].sum())}
                          for s in SPLITS},
            rooms=plan,
            layout={"rgb": f"{RGB_DIR}/RRRR_FFFF.png", "depth": f"{DEPTH_DIR}/RRRR_FFFF.png",
                    "labels": f"{LABEL_DIR}/RRRR_FFFF.png", "poses": POSES_FILE,
                    "splits": "train.txt, val.txt, test.txt"})
        manifest["source"] = f"evsmap.synth rooms, seed {seed}"
        write_manifest(stage, manifest)
    return manifest


# -- reader ---------------------------------------------------------------------------------------
def _read_poses(path: Path) -> dict[str, tuple[int, float, np.ndarray, np.ndarray]]:
    """``id -> (room, timestamp, translation, quaternion xyzw)`` from ``poses.txt``."""
    require_file(path, "synthrooms poses file")
    out: dict[str, tuple[int, float, np.ndarray, np.ndarray]] = {}
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise DataFormatError(f"{path}: cannot read ({exc})") from None
    for number, line in enumerate(text.splitlines(), 1):
        fields = line.split("#", 1)[0].split()
        if not fields:
            continue
        try:
            if len(fields) != 10:
                raise ValueError
            room = int(fields[1])
            values = np.array([float(x) for x in fields[2:]], dtype=np.float64)
            if not np.all(np.isfinite(values)):
                raise ValueError
            norm = float(np.linalg.norm(values[4:8]))
            if not (math.isfinite(norm) and 1e-6 < norm < 1e6):
                raise DataFormatError(f"{path}:{number}: quaternion qx qy qz qw has norm {norm:g} "
                                      "(expected a unit quaternion)")
        except ValueError:
            raise DataFormatError(f"{path}:{number}: expected 'id room timestamp tx ty tz qx qy "
                                  f"qz qw', got {line!r}") from None
        check_frame_id(fields[0], f"{path}:{number}")
        if fields[0] in out:
            raise DataFormatError(f"{path}:{number}: frame {fields[0]} listed twice")
        out[fields[0]] = (room, float(values[0]), values[1:4], values[4:8])
    return out


def is_synthrooms_folder(path: Path) -> bool:
    from evsmap.datasets.common import manifest_name

    path = Path(path)
    return path.is_dir() and manifest_name(path) == NAME


class SynthRoomsSequence(SegmentationSequence):
    """A folder written by :func:`prepare_synthrooms` (see the module docstring).

    Args:
        path: the folder holding ``evsmap-dataset.json``, ``rgb/``, ``depth/``, ``labels/``.
        split: ``train`` / ``val`` / ``test`` or ``all`` (every frame).
        limit: keep the first ``limit`` frames (in room, then view order).
        room: only the frames of this room (its index in the manifest), in camera-path order,
            with their walk timestamps; the sequence then has poses for mapping.
    """

    def __init__(self, *, path: str | Path, split: str = "all", limit: int | None = None,
                 room: int | None = None) -> None:
        root = Path(path)
        if not root.is_dir():
            raise DataFormatError(f"{root}: synthrooms folder not found")
        check_split(split, SPLITS, NAME)
        check_limit(limit)
        manifest = read_manifest(root)
        if manifest is None:
            raise DataFormatError(f"{root}: no evsmap-dataset.json (write the folder with "
                                  "`evsmap datasets prepare synthrooms`)")
        if manifest.get("name") != NAME:
            raise DataFormatError(f"{root}: the manifest says dataset {manifest.get('name')!r}, "
                                  f"not {NAME!r}")
        try:
            intrinsics = Intrinsics(**manifest["intrinsics"])
            rooms = {int(r["index"]): r for r in manifest["rooms"]}
        except (KeyError, TypeError, ValueError, OverflowError) as exc:
            raise DataFormatError(f"{root / 'evsmap-dataset.json'}: bad intrinsics or rooms "
                                  f"({exc})") from None
        for sub in (RGB_DIR, DEPTH_DIR, LABEL_DIR):
            require_dir(root / sub, f"synthrooms {sub}")
        poses = _read_poses(root / POSES_FILE)
        if split == "all":
            ids = sorted(poses)
        else:
            ids = sorted(read_id_list(root / f"{split}.txt"))
            if not ids:
                raise DataFormatError(f"{root / f'{split}.txt'}: lists no frames")
            missing = [i for i in ids if i not in poses]
            if missing:
                raise DataFormatError(f"{root / f'{split}.txt'}: frame {missing[0]} has no pose "
                                      f"in {POSES_FILE}")
        extra: dict = {}
        if room is not None:
            if isinstance(room, bool) or not isinstance(room, (int, np.integer)) \
                    or int(room) not in rooms:
                raise EvsmapError(f"{NAME}: room must be a room index 0..{len(rooms) - 1}, "
                                  f"got {room!r}")
            room = int(room)
            ids = [i for i in ids if poses[i][0] == room]
            if not ids:
                raise EvsmapError(f"{NAME}: room {room} is in split {rooms[room].get('split')!r}, "
                                  f"not {split!r} (leave out split, or pick a room of it)")
            info = rooms[room]
            extra = {"poses": True, "room": room, "scene": info.get("scene"),
                     "seed": info.get("seed"), "room_size_m": info.get("size_m")}
        seq_rooms = sorted({poses[i][0] for i in ids})
        if room is None:
            extra = {"no_poses_hint": f"{NAME} frames of several rooms do not share one world: "
                                      f"pick one room with -r room=N (rooms {_ranges(seq_rooms)} "
                                      f"here)"}
        self.root = root
        self.folder = Path(root)
        self._poses = poses
        self._by_room = room is not None
        name = root.resolve().name + (f"-room{room}" if room is not None else "")
        super().__init__(
            name, intrinsics, layout=NAME, split=split, class_names=NYU40_CLASSES,
            class_colors=palette(NUM_CLASSES), path=root, names=apply_limit(ids, limit),
            meta={"intrinsics_source": "synth renderer (Kinect-v1-like, scaled)",
                  "depth_scale": DEPTH_SCALE, "rooms": seq_rooms, "dataset": manifest,
                  **extra})

    def load(self, index: int):
        fid = self.names[index]
        assert self.intrinsics is not None  # the prepared layout's
        shape = self.intrinsics.shape
        rgb_path = self.root / RGB_DIR / f"{fid}.png"
        depth_path = self.root / DEPTH_DIR / f"{fid}.png"
        rgb = read_rgb(rgb_path)
        check_shape(rgb_path, rgb.shape, shape, "image")
        raw = read_uint16(depth_path)
        check_shape(depth_path, raw.shape, shape, "depth")
        labels = read_label_png(self.root / LABEL_DIR / f"{fid}.png", NUM_CLASSES, shape)
        return rgb, dequantize_depth(raw), self.intrinsics, labels

    @property
    def has_ground_truth(self) -> bool:
        """One room (``-r room=N``) has the room's ground truth; a split of several has none."""
        return bool(self._by_room)

    def ground_truth(self, resolution: float) -> VoxelLabels:
        """The room's ground-truth voxels (:class:`~evsmap.data.VoxelLabels`) at
        ``resolution``, rebuilt from the manifest's scene and seed; only for one room
        (``-r room=N``), where the frames share its world."""
        from evsmap.synth.sequence import SyntheticSequence

        if not self._by_room:
            raise EvsmapError(f"{NAME}: ground truth is per room: pick one with -r room=N")
        meta = self.meta
        return SyntheticSequence(scene=meta["scene"], seed=int(meta["seed"])).ground_truth(
            resolution)

    def pose(self, index: int) -> np.ndarray:
        """Camera-to-world pose of frame ``index`` in its room's frame."""
        _, _, t, q = self._poses[self.names[index]]
        return pose_matrix(t, q)

    def frame(self, index: int) -> Frame:
        rgb, depth, intrinsics, labels = self.load(index)
        fid = self.names[index]
        stamp = self._poses[fid][1] if self._by_room else float(index)
        return Frame(rgb=rgb, depth=depth, intrinsics=intrinsics, pose=self.pose(index),
                     timestamp=stamp, labels=labels, name=fid)


def _ranges(values: list[int]) -> str:
    """``[0, 1, 2, 5]`` -> ``"0-2, 5"``."""
    out, start = [], None
    for i, v in enumerate(values):
        if start is None:
            start = v
        if i + 1 == len(values) or values[i + 1] != v + 1:
            out.append(str(start) if start == v else f"{start}-{v}")
            start = None
    return ", ".join(out)


@READERS.register(NAME, takes=Takes(path=True, split=True, limit=True),
                  detect=is_synthrooms_folder,
                  description="synthetic rooms, NYUv2 40 classes, with poses per room (folder "
                              "written by `evsmap datasets prepare synthrooms`)")
def open_synthrooms(*, path: str, split: str = "all", limit: int | None = None,
                    room: int | None = None) -> SynthRoomsSequence:
    """Synthetic rooms, NYUv2 40 classes, split by room (prepared folder; -r room=N for one room
    with poses)."""
    return SynthRoomsSequence(path=path, split=split, limit=limit, room=room)
