"""The data model shared by every reader, segmenter and updater.

* :class:`Intrinsics` - pinhole camera (fx, fy, cx, cy, width, height), no distortion.
* :class:`Frame` - one RGB-D observation: RGB ``uint8`` HxWx3, metric depth ``float32`` HxW with 0
  for invalid, the camera's intrinsics, camera-to-world pose ``float64`` 4x4 (OpenCV camera axes:
  x right, y down, z forward), a timestamp in seconds and optional ``uint8`` labels (255 = void).
  Its point-cloud form (:meth:`Frame.from_points`: a LiDAR or PointCloud2 scan) holds ``float32``
  Nx3 points in the sensor frame, optional ``uint8`` Nx3 colours, the sensor-to-world pose and no
  images.
* :class:`SemanticObservation` - a segmenter's per-pixel top-k class ids and probabilities.
* :class:`Sequence` - a named, sized, iterable series of frames with one set of intrinsics.
* :class:`VoxelLabels` - a scene's 3D ground truth: its occupied voxels and their classes, what
  :meth:`Sequence.ground_truth` gives where a sequence has one.

Constructors validate shapes, dtypes and finiteness and say exactly what is wrong.
"""

from __future__ import annotations

import abc
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evsmap.errors import InvalidDataError
from evsmap.geometry import backproject

VOID = 255
"""Label value of pixels without a class."""


def _array(name: str, value: object, dtype: np.dtype | type, ndim: int) -> np.ndarray:
    if not isinstance(value, np.ndarray):
        raise InvalidDataError(f"{name} must be a numpy array, got {type(value).__name__}")
    if value.dtype != np.dtype(dtype):
        raise InvalidDataError(f"{name} must have dtype {np.dtype(dtype)}, got {value.dtype}")
    if value.ndim != ndim:
        raise InvalidDataError(f"{name} must have {ndim} dimensions, got shape {value.shape}")
    return value


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels for an image of ``width`` x ``height``."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "cx", "cy"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)):
                raise InvalidDataError(f"intrinsics {name} must be a number, got {v!r}")
            if not np.isfinite(v):
                raise InvalidDataError(f"intrinsics {name} must be finite, got {v!r}")
            object.__setattr__(self, name, float(v))
        for name in ("width", "height"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
                raise InvalidDataError(f"intrinsics {name} must be a positive integer, got {v!r}")
            object.__setattr__(self, name, int(v))
        if self.fx <= 0 or self.fy <= 0:
            raise InvalidDataError(
                f"intrinsics focal lengths must be positive, got fx={self.fx} fy={self.fy}"
            )

    @property
    def matrix(self) -> np.ndarray:
        """The 3x3 camera matrix K (float64)."""
        return np.array(
            [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]], dtype=np.float64
        )

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width), the shape of the images these intrinsics describe."""
        return (self.height, self.width)

    def scaled(self, width: int, height: int) -> Intrinsics:
        """The same camera resampled to ``width`` x ``height`` (pixel-centre convention)."""
        sx, sy = width / self.width, height / self.height
        return Intrinsics(
            fx=self.fx * sx, fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5, cy=(self.cy + 0.5) * sy - 0.5,
            width=width, height=height,
        )

    def as_dict(self) -> dict[str, float | int]:
        return {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy,
                "width": self.width, "height": self.height}


MAX_TRANSLATION_M = 1e9
"""A pose further from the origin than this (a million kilometres) is refused: no robot's map
spans it, geodetic (UTM, ECEF) coordinates are under 1e8 m, and beyond it the points of a
frame overflow the ``float32`` the updaters work in."""


def _check_pose(name: str, pose: object) -> np.ndarray:
    pose = _array(name, pose, np.float64, 2)
    if pose.shape != (4, 4):
        raise InvalidDataError(f"{name} must be 4x4, got shape {pose.shape}")
    if not np.all(np.isfinite(pose)):
        raise InvalidDataError(f"{name} has non-finite entries")
    if not np.allclose(pose[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise InvalidDataError(f"{name} last row must be [0 0 0 1], got {pose[3].tolist()}")
    rot = pose[:3, :3]
    with np.errstate(all="ignore"):  # huge entries: inf or nan, refused below (nan included)
        err = np.abs(rot @ rot.T - np.eye(3)).max()
        det = np.linalg.det(rot)
    if not err <= 1e-5 or not det >= 0:
        raise InvalidDataError(
            f"{name} rotation block is not a proper rotation (|R R^T - I| = {err:.2e})"
        )
    if np.abs(pose[:3, 3]).max() > MAX_TRANSLATION_M:
        raise InvalidDataError(f"{name} translation {pose[:3, 3].tolist()} is beyond "
                               f"{MAX_TRANSLATION_M:.0e} m from the origin")
    return pose


@dataclass(frozen=True, eq=False)
class Frame:
    """One RGB-D observation with its camera-to-world pose.

    A frame is either an image frame (``rgb``, ``depth`` and ``intrinsics`` given, ``points``
    None) or a point-cloud frame (``points`` given, the three image fields None; build it with
    :meth:`from_points`). Updaters take either; segmenters need images.

    Args (fields):
        rgb: ``uint8`` array HxWx3 (None for a point-cloud frame).
        depth: ``float32`` array HxW in metres, 0 where invalid; no NaN, no inf, no negatives
            (None for a point-cloud frame).
        intrinsics: the camera that took the frame; its size must match the images (None for a
            point-cloud frame).
        pose: ``float64`` 4x4 camera-to-world (or sensor-to-world) transform (OpenCV camera axes
            for cameras; a point cloud's own sensor axes otherwise).
        timestamp: seconds (any epoch), finite.
        labels: optional ``uint8`` HxW class ids, 255 for void (image frames only).
        name: optional identifier for messages (a file name, an index).
        points: ``float32`` Nx3 points in the sensor frame, finite (point-cloud frames only).
        point_colors: optional ``uint8`` Nx3 colours of ``points``.
        disparity_scale: for depth computed from a rectified stereo pair, baseline x focal
            length (metres x pixels of the disparity image), so that ``disparity = scale /
            depth``; None otherwise. Networks trained on a dataset's disparity files use it
            (:mod:`evsmap.segmenters.normalization`).
    """

    rgb: np.ndarray | None
    depth: np.ndarray | None
    intrinsics: Intrinsics | None
    pose: np.ndarray
    timestamp: float
    labels: np.ndarray | None = None
    name: str = ""
    points: np.ndarray | None = None
    point_colors: np.ndarray | None = None
    disparity_scale: float | None = None

    @classmethod
    def from_points(cls, points: np.ndarray, pose: np.ndarray, timestamp: float, *,
                    colors: np.ndarray | None = None, name: str = "") -> Frame:
        """A point-cloud frame: ``points`` (Nx3, sensor frame) seen from ``pose``."""
        if isinstance(points, np.ndarray) and points.dtype != np.float32 and \
                np.issubdtype(points.dtype, np.floating):
            points = points.astype(np.float32)
        return cls(rgb=None, depth=None, intrinsics=None, pose=pose, timestamp=timestamp,
                   name=name, points=points, point_colors=colors)

    def _check_points(self) -> None:
        for field in ("rgb", "depth", "intrinsics", "labels"):
            if getattr(self, field) is not None:
                raise InvalidDataError(f"a point-cloud frame has no {field} (got one)")
        pts = _array("points", self.points, np.float32, 2)
        if pts.shape[1] != 3:
            raise InvalidDataError(f"points must be Nx3, got shape {pts.shape}")
        if not np.all(np.isfinite(pts)):
            raise InvalidDataError("points have NaN or inf values (drop them)")
        if self.point_colors is not None:
            col = _array("point_colors", self.point_colors, np.uint8, 2)
            if col.shape != pts.shape:
                raise InvalidDataError(
                    f"point_colors shape {col.shape} does not match points shape {pts.shape}")

    def __post_init__(self) -> None:
        where = f"frame {self.name!r}: " if self.name else "frame: "
        try:
            if self.points is not None:
                self._check_points()
                self._check_pose_and_time()
                return
            if self.point_colors is not None:
                raise InvalidDataError("point_colors given without points")
            if self.rgb is None or self.depth is None or self.intrinsics is None:
                raise InvalidDataError(
                    "an image frame needs rgb, depth and intrinsics (or give points)")
            rgb = _array("rgb", self.rgb, np.uint8, 3)
            if rgb.shape[2] != 3:
                raise InvalidDataError(f"rgb must be HxWx3, got shape {rgb.shape}")
            depth = _array("depth", self.depth, np.float32, 2)
            if depth.shape != rgb.shape[:2]:
                raise InvalidDataError(
                    f"depth shape {depth.shape} does not match rgb shape {rgb.shape[:2]}"
                )
            if not np.all(np.isfinite(depth)):
                raise InvalidDataError("depth has NaN or inf values (use 0 for invalid)")
            if depth.size and depth.min() < 0:
                raise InvalidDataError(f"depth has negative values (min {depth.min()})")
            if not isinstance(self.intrinsics, Intrinsics):
                raise InvalidDataError(
                    f"intrinsics must be Intrinsics, got {type(self.intrinsics).__name__}"
                )
            if self.intrinsics.shape != rgb.shape[:2]:
                raise InvalidDataError(
                    f"intrinsics are for {self.intrinsics.width}x{self.intrinsics.height} but the "
                    f"images are {rgb.shape[1]}x{rgb.shape[0]}"
                )
            self._check_pose_and_time()
            if self.disparity_scale is not None and not (
                    isinstance(self.disparity_scale, (int, float, np.floating))
                    and not isinstance(self.disparity_scale, bool)
                    and np.isfinite(self.disparity_scale) and self.disparity_scale > 0):
                raise InvalidDataError(f"disparity_scale must be a positive number, got "
                                       f"{self.disparity_scale!r}")
            if self.labels is not None:
                labels = _array("labels", self.labels, np.uint8, 2)
                if labels.shape != rgb.shape[:2]:
                    raise InvalidDataError(
                        f"labels shape {labels.shape} does not match rgb shape {rgb.shape[:2]}"
                    )
        except InvalidDataError as exc:
            raise InvalidDataError(where + str(exc)) from None

    def _check_pose_and_time(self) -> None:
        _check_pose("pose", self.pose)
        ts = self.timestamp
        if isinstance(ts, bool) or not isinstance(ts, (int, float, np.floating, np.integer)):
            raise InvalidDataError(f"timestamp must be a number, got {ts!r}")
        if not np.isfinite(ts):
            raise InvalidDataError(f"timestamp must be finite, got {ts!r}")
        object.__setattr__(self, "timestamp", float(ts))

    @property
    def is_cloud(self) -> bool:
        """True for a point-cloud frame (no images)."""
        return self.points is not None

    def require_images(self, user: str) -> None:
        """Raise a clear error when ``user`` (a segmenter, a command) needs images and this is a
        point-cloud frame."""
        if self.points is not None:  # is_cloud
            raise InvalidDataError(
                f"frame {self.name!r} is a point cloud ({len(self.points)} points): {user} needs "
                f"RGB-D images")

    def sensor_points(self) -> np.ndarray:
        """(N, 3) float64 points in the sensor frame: the valid depth pixels back-projected in
        row-major order, or the cloud's points."""
        if self.points is not None:  # is_cloud
            return self.points.astype(np.float64)
        assert self.depth is not None and self.intrinsics is not None  # an image frame
        return backproject(self.depth, self.intrinsics)

    def colors(self) -> np.ndarray | None:
        """Colours indexed as the updaters index a frame's points (``FramePoints.pixels``): the
        image's pixels flattened (HW, 3), or the cloud's point colours (N, 3); None for a cloud
        without colours."""
        if self.is_cloud:
            return self.point_colors
        assert self.rgb is not None  # an image frame
        return self.rgb.reshape(-1, 3)

    @property
    def height(self) -> int:
        assert self.rgb is not None, "a point-cloud frame has no image size"
        return int(self.rgb.shape[0])

    @property
    def width(self) -> int:
        assert self.rgb is not None, "a point-cloud frame has no image size"
        return int(self.rgb.shape[1])

    @property
    def valid(self) -> np.ndarray:
        """Boolean HxW mask of pixels with a depth measurement."""
        assert self.depth is not None, "a point-cloud frame has no depth image"
        return self.depth > 0


@dataclass(frozen=True, eq=False)
class SemanticObservation:
    """Per-pixel top-k classes and probabilities from a segmenter.

    Args (fields):
        classes: integer array HxWxk (stored as ``int16``), most likely class first.
        probs: ``float32`` array HxWxk, probabilities in [0, 1], non-increasing along k, summing
            to at most 1 (the rest is the mass of the classes not kept).
        num_classes: size of the segmenter's label set; every class id is below it.
    """

    classes: np.ndarray
    probs: np.ndarray
    num_classes: int

    def __post_init__(self) -> None:
        c, p = self.classes, self.probs
        if not isinstance(c, np.ndarray) or not np.issubdtype(c.dtype, np.integer):
            raise InvalidDataError(
                f"observation classes must be an integer array, got "
                f"{getattr(c, 'dtype', type(c).__name__)}"
            )
        _array("observation probs", p, np.float32, 3)
        if c.ndim != 3 or c.shape != p.shape:
            raise InvalidDataError(
                f"observation classes {c.shape} and probs {p.shape} must both be HxWxk"
            )
        n = self.num_classes
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise InvalidDataError(f"num_classes must be a positive integer, got {n!r}")
        if not np.all(np.isfinite(p)):
            raise InvalidDataError("observation probs have NaN or inf values")
        if p.size:
            if p.min() < 0 or p.max() > 1:
                raise InvalidDataError(
                    f"observation probs must lie in [0, 1], got [{p.min()}, {p.max()}]"
                )
            if np.any(p.sum(axis=2) > 1 + 1e-4):
                raise InvalidDataError("observation probs sum to more than 1 at some pixels")
            if np.any(np.diff(p, axis=2) > 1e-6):
                raise InvalidDataError("observation probs must be sorted, most likely first")
            if c.min() < 0 or c.max() >= n:
                raise InvalidDataError(
                    f"observation class ids must lie in [0, {n - 1}], got [{c.min()}, {c.max()}]"
                )
        object.__setattr__(self, "classes", c.astype(np.int16, copy=False))
        object.__setattr__(self, "num_classes", int(n))

    @property
    def k(self) -> int:
        return int(self.classes.shape[2])

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.classes.shape[0]), int(self.classes.shape[1]))

    @property
    def argmax(self) -> np.ndarray:
        """HxW most likely class."""
        return self.classes[..., 0]

    @property
    def others(self) -> np.ndarray:
        """HxW probability mass not held by the k kept classes."""
        return np.clip(1.0 - self.probs.sum(axis=2), 0.0, 1.0)

    @classmethod
    def of_kernel(cls, classes: np.ndarray, probs: np.ndarray, num_classes: int
                  ) -> SemanticObservation:
        """An observation from evsmap's own top-k kernels (:mod:`evsmap.segmenters.topk`),
        without the whole-image checks of the constructor (7 ms a 640x480 frame): those kernels
        return ``int16`` classes below ``num_classes`` and sorted float32 probabilities in
        [0, 1] summing to at most 1 by construction (``tests/segmenters/test_topk.py``). Only
        the shapes and types are checked here; a plug-in's observation goes through the
        constructor."""
        if classes.dtype != np.int16 or probs.dtype != np.float32 or classes.ndim != 3 \
                or classes.shape != probs.shape:
            raise InvalidDataError(f"of_kernel needs int16 classes and float32 probs of one "
                                   f"HxWxk shape, got {classes.dtype} {classes.shape} and "
                                   f"{probs.dtype} {probs.shape}")
        observation = object.__new__(cls)
        object.__setattr__(observation, "classes", classes)
        object.__setattr__(observation, "probs", probs)
        object.__setattr__(observation, "num_classes", int(num_classes))
        return observation

    @classmethod
    def from_probabilities(cls, probs: np.ndarray, *, k: int = 3) -> SemanticObservation:
        """Keep the top ``k`` classes of a full HxWxC softmax."""
        probs = np.asarray(probs, dtype=np.float32)
        if probs.ndim != 3:
            raise InvalidDataError(f"probabilities must be HxWxC, got shape {probs.shape}")
        num_classes = probs.shape[2]
        k = min(k, num_classes)
        idx = np.argpartition(-probs, k - 1, axis=2)[..., :k]
        top = np.take_along_axis(probs, idx, axis=2)
        order = np.argsort(-top, axis=2, kind="stable")
        return cls(
            classes=np.take_along_axis(idx, order, axis=2).astype(np.int16),
            probs=np.take_along_axis(top, order, axis=2),
            num_classes=num_classes,
        )


@dataclass(frozen=True)
class VoxelLabels:
    """A scene's occupied voxels at one edge length: integer keys (N x 3, ``int32``,
    ``floor(coordinate / resolution)``, OctoMap's convention without its 2^15 offset), class ids
    (N,, ``uint8``; :data:`VOID` for a surface voxel without a class, which the 3D scores count
    for geometry only) and the edge length in metres."""

    keys: np.ndarray
    labels: np.ndarray
    resolution: float

    @property
    def centers(self) -> np.ndarray:
        return (self.keys.astype(np.float64) + 0.5) * self.resolution

    def __len__(self) -> int:
        return int(self.labels.shape[0])

    @classmethod
    def by_vote(cls, points: np.ndarray, labels: np.ndarray, resolution: float,
                weights: np.ndarray | None = None) -> VoxelLabels:
        """The voxels holding ``points`` (N x 3, metres), each with the label of most weight
        among its points (``weights``, default 1 each: the most points), ties to the lower
        label (so :data:`VOID` loses every tie).

        Raises:
            InvalidDataError: the points span more voxels than an int64 code can number.
        """
        if not len(points):
            return cls(np.zeros((0, 3), np.int32), np.zeros(0, np.uint8), float(resolution))
        keys = np.floor(np.asarray(points, dtype=np.float64) / resolution).astype(np.int64)
        off = keys.min(axis=0)
        span = keys.max(axis=0) - off + 1
        if float(np.prod(span.astype(np.float64))) * 256 > 2.0 ** 62:
            raise InvalidDataError(f"the surface spans {(span * resolution).tolist()} m: too "
                                   f"large to voxelise at {resolution:g} m")
        rel = keys - off
        code = (rel[:, 0] * span[1] + rel[:, 1]) * span[2] + rel[:, 2]
        pair, inverse = np.unique(code * 256 + np.asarray(labels, dtype=np.int64),
                                  return_inverse=True)
        weight = np.bincount(inverse.ravel(), weights=weights, minlength=len(pair))
        vox, lab = pair // 256, pair % 256
        order = np.lexsort((lab, -weight, vox))  # per voxel: most weight, then the lower label
        vox, lab = vox[order], lab[order]
        first = np.ones(len(vox), dtype=bool)
        first[1:] = vox[1:] != vox[:-1]
        vox, lab = vox[first], lab[first]
        kz = vox % span[2]
        ky = (vox // span[2]) % span[1]
        kx = vox // (span[2] * span[1])
        out = np.stack([kx, ky, kz], axis=1) + off
        return cls(out.astype(np.int32), lab.astype(np.uint8), float(resolution))


class Sequence(abc.ABC):
    """A named series of frames seen by one camera.

    Subclasses implement :meth:`__len__` and :meth:`frame`; iteration and (negative) indexing come
    from them. ``meta`` holds reader-specific facts (layout, source, dropped frames).
    ``intrinsics`` is the camera of the frames (the first frame's where a dataset mixes cameras,
    each frame then carrying its own), or None for a sequence of point clouds.

    Attributes:
        class_names: the label set of the frames' ``labels``, one name per class id; () where
            the reader does not say (or the frames have no labels). A reader sets the attribute
            or passes ``meta["class_names"]`` (and ``meta["num_classes"]``).
        num_classes: the size of that label set where known, else None.
        folder: the folder (or file: a bag) the frames are read from, set by the reader; None
            for frames not read from one place on disk (held in memory, generated).
    """

    folder: Path | None = None
    _class_names: tuple[str, ...] = ()
    _num_classes: int | None = None

    def __init__(self, name: str, intrinsics: Intrinsics | None, meta: dict | None = None
                 ) -> None:
        if intrinsics is not None and not isinstance(intrinsics, Intrinsics):
            raise InvalidDataError(
                f"sequence {name!r}: intrinsics must be Intrinsics, got {type(intrinsics).__name__}"
            )
        self.name = name
        self.intrinsics = intrinsics
        self.meta = dict(meta or {})

    @abc.abstractmethod
    def __len__(self) -> int:
        """Number of frames."""

    @abc.abstractmethod
    def frame(self, index: int) -> Frame:
        """Frame ``index`` (0 <= index < len)."""

    @property
    def class_names(self) -> tuple[str, ...]:
        own = self._class_names
        if own:
            return own
        return tuple(str(n) for n in (self.meta.get("class_names") or ()))

    @class_names.setter
    def class_names(self, names) -> None:
        self._class_names = tuple(str(n) for n in (names or ()))

    @property
    def num_classes(self) -> int | None:
        own = self._num_classes or self.meta.get("num_classes")
        if own:
            return int(own)
        return len(self.class_names) or None

    @num_classes.setter
    def num_classes(self, count: int | None) -> None:
        self._num_classes = int(count) if count else None

    def frame_stem(self, index: int) -> str | None:
        """Frame ``index``'s own name where the reader has one (its files' shared stem, e.g.
        TUM's timestamp), the name ``evsmap predict`` writes its outputs under; None (the
        default) where the frames have no names of their own."""
        return None

    def frames_identity(self) -> str | None:
        """What the frames (and their labels) are, for caches of what is computed from them
        (the runner's segmentation cache): a string that changes whenever a frame could, or
        None to let the caller use the sequence's :attr:`folder` and its modification time
        (the default)."""
        return None

    @property
    def has_ground_truth(self) -> bool:
        """Whether :meth:`ground_truth` gives voxels for this sequence as opened (False by
        default)."""
        return False

    def ground_truth(self, resolution: float) -> VoxelLabels | None:
        """The scene's occupied voxels and their classes at ``resolution`` metres, in the frames'
        world, for scoring a map (the synthetic rooms, a ScanNet scene's labelled mesh); None
        for a sequence without 3D ground truth (the default).

        Raises:
            EvsmapError: the sequence has ground truth but cannot give it as opened (e.g. a
                synthrooms split holding several rooms).
        """
        return None

    @property
    def has_poses(self) -> bool:
        """Whether the frames carry camera poses: False for a segmentation dataset, whose frames
        get the identity pose (its reader sets ``meta["poses"] = False``); mapping refuses it."""
        return self.meta.get("poses") is not False

    def __getitem__(self, index: int) -> Frame:
        n = len(self)
        if not -n <= index < n:
            raise IndexError(f"frame index {index} out of range for {n} frames of {self.name!r}")
        return self.frame(index % n)

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self.frame(i)


class FrameList(Sequence):
    """A sequence held in memory (tests, generated data)."""

    def __init__(self, name: str, intrinsics: Intrinsics | None, frames: list[Frame],
                 meta: dict | None = None) -> None:
        super().__init__(name, intrinsics, meta)
        for f in frames:
            if f.intrinsics != intrinsics:
                raise InvalidDataError(
                    f"frame {f.name!r} has intrinsics {f.intrinsics} but the sequence {name!r} "
                    f"has {intrinsics}"
                )
        self._frames = list(frames)

    def __len__(self) -> int:
        return len(self._frames)

    def frame(self, index: int) -> Frame:
        return self._frames[index]
