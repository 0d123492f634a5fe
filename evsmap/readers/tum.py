"""TUM RGB-D benchmark layout (Sturm et al., IROS 2012): reader and writer.

Layout: ``rgb.txt`` / ``depth.txt`` list ``timestamp path`` (``#`` comments), ``groundtruth.txt``
lists ``timestamp tx ty tz qx qy qz qw`` (camera-to-world), depth PNGs are ``uint16`` with
metres = value / 5000. evsmap's synthetic sequences add ``labels.txt`` + ``labels/`` (``uint8``,
255 void), ``intrinsics.txt`` and ``evsmap.json``.

Depth and RGB are associated one-to-one by timestamp within ``max_time_difference`` (0.02 s as
TUM's tools; see :func:`associate` for the matching and TUM's greedy variant), and the
ground-truth pose is interpolated to each depth timestamp (linear translation, slerp rotation).
"""

from __future__ import annotations

import bisect
import json
import math
import re
from pathlib import Path

import numpy as np

from evsmap.data import MAX_TRANSLATION_M, Frame, Intrinsics, Sequence
from evsmap.errors import DataFormatError, EvsmapError
from evsmap.geometry import interpolate_poses, matrix_to_quat
from evsmap.readers.images import (
    DEPTH_SCALE,
    check_rgbd_shapes,
    dequantize_depth,
    quantize_depth,
    read_rgb,
    read_uint8_labels,
    read_uint16,
    write_png,
)
from evsmap.registry import READERS, Takes

# Published intrinsics of the TUM RGB-D cameras (640x480), from the dataset's documentation.
TUM_CAMERAS: dict[str, Intrinsics] = {
    "fr1": Intrinsics(517.3, 516.5, 318.6, 255.3, 640, 480),
    "fr2": Intrinsics(520.9, 521.0, 325.1, 249.7, 640, 480),
    "fr3": Intrinsics(535.4, 539.2, 320.1, 247.6, 640, 480),
    "ros-default": Intrinsics(525.0, 525.0, 319.5, 239.5, 640, 480),
}
METADATA_FILE = "evsmap.json"
INTRINSICS_FILE = "intrinsics.txt"


def detect_camera(path: Path) -> str | None:
    """``fr1``/``fr2``/``fr3`` from a folder name such as ``rgbd_dataset_freiburg1_xyz``."""
    m = re.search(r"(?:freiburg|fr)([123])(?![0-9])", path.resolve().name.lower())
    return f"fr{m.group(1)}" if m else None


def read_list(path: Path, columns: int) -> list[list[str]]:
    """Non-comment lines of a TUM text file split on whitespace, each with ``columns`` fields
    and a finite time stamp first."""
    if not path.is_file():
        raise DataFormatError(f"{path}: file not found")
    rows = []
    try:
        text = path.read_text(encoding="utf-8-sig")  # a leading BOM is no field
    except (OSError, UnicodeDecodeError) as exc:
        raise DataFormatError(f"{path}: cannot read ({exc})") from None
    for lineno, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        fields = line.replace(",", " ").split()
        if len(fields) != columns:
            raise DataFormatError(
                f"{path}:{lineno}: expected {columns} fields, got {len(fields)}: {line[:80]!r}")
        try:
            stamp = float(fields[0])
        except ValueError:
            raise DataFormatError(f"{path}:{lineno}: bad timestamp {fields[0]!r}") from None
        if not math.isfinite(stamp):
            raise DataFormatError(f"{path}:{lineno}: timestamp {fields[0]!r} is not finite")
        rows.append(fields)
    return rows


def _pose_rows(path: Path, rows: list[list[str]]) -> np.ndarray:
    """``groundtruth.txt``'s rows as an N x 8 array (timestamp tx ty tz qx qy qz qw); a value
    that is not a finite number, or a quaternion of length zero, is an error naming the row."""
    out = np.empty((len(rows), 8))
    for n, row in enumerate(rows):
        try:
            out[n] = [float(v) for v in row[:8]]
        except ValueError:
            raise DataFormatError(f"{path}: pose row {n + 1} ({' '.join(row[:8])}) is not 8 "
                                  f"numbers") from None
    with np.errstate(over="ignore"):  # a norm that overflows is not zero: judged later
        bad = ~np.isfinite(out).all(axis=1) | (np.linalg.norm(out[:, 4:8], axis=1) < 1e-12)
    if bad.any():
        n = int(np.flatnonzero(bad)[0])
        raise DataFormatError(f"{path}: pose row {n + 1} ({' '.join(rows[n][:8])}) has a "
                              f"non-finite value or a zero quaternion")
    return out


def _interpolate(path: Path, gt: np.ndarray, ts: np.ndarray) -> np.ndarray:
    """The ground-truth poses (sorted N x 8 rows of ``path``) at the times ``ts``; values so large
    that interpolating them overflows are an error naming ``path``."""
    if not len(ts):
        return np.zeros((0, 4, 4))
    with np.errstate(all="ignore"):
        try:
            poses = interpolate_poses(gt[:, 0], gt[:, 1:4], gt[:, 4:8], ts)
        except (EvsmapError, ValueError) as exc:
            raise DataFormatError(f"{path}: cannot interpolate the poses ({exc})") from None
    bad = ~np.isfinite(poses).all(axis=(1, 2))
    if bad.any():
        raise DataFormatError(f"{path}: the pose interpolated at time {ts[bad][0]!r} is not "
                              f"finite (values too large)")
    far = np.abs(poses[:, :3, 3]).max(axis=1) > MAX_TRANSLATION_M
    if far.any():
        raise DataFormatError(f"{path}: the pose at time {ts[far][0]!r} is beyond "
                              f"{MAX_TRANSLATION_M:.0e} m from the origin")
    return poses


def _read_metadata(path: Path) -> dict:
    """``evsmap.json`` as a dict; unreadable, not JSON or not an object is an error naming it."""
    try:
        info = json.loads(path.read_bytes())  # bytes: UTF-8/16/32, a BOM allowed
    except (OSError, ValueError) as exc:  # ValueError: JSONDecodeError, UnicodeDecodeError
        raise DataFormatError(f"{path}: not valid JSON ({_one_line(exc)})") from None
    except RecursionError:
        raise DataFormatError(f"{path}: not valid JSON (nested too deeply)") from None
    if not isinstance(info, dict):
        raise DataFormatError(f"{path}: expected a JSON object, got {type(info).__name__}")
    return info


def _class_names(path: Path, names: object) -> tuple[str, ...]:
    """``evsmap.json``'s ``classes``: a list of strings (or absent)."""
    if names is None:
        return ()
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise DataFormatError(f"{path}: 'classes' must be a list of class names")
    return tuple(names)


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())[:200]


def _candidates(a: np.ndarray, b: np.ndarray, max_difference: float):
    """For each a_i, the indices j of b (into the sorted order) with |a_i - b_j| < tolerance."""
    order_b = np.argsort(b, kind="stable")
    bs = b[order_b]
    lo = np.searchsorted(bs, a - max_difference, side="left")
    hi = np.searchsorted(bs, a + max_difference, side="right")
    cands = []
    for i, (first, last) in enumerate(zip(lo, hi, strict=True)):
        js = np.arange(first, last)
        with np.errstate(invalid="ignore"):  # inf - inf: nan, never within the tolerance
            d = np.abs(a[i] - bs[js])
        keep = d < max_difference
        cands.append(list(zip(js[keep].tolist(), d[keep].tolist(), strict=True)))
    return order_b, cands


def associate(a: np.ndarray, b: np.ndarray, max_difference: float,
              method: str = "optimal") -> list[tuple[int, int]]:
    """One-to-one matches (i, j) between timestamp arrays ``a`` and ``b`` with
    |a_i - b_j| < ``max_difference``, sorted by ``a``.

    ``greedy`` is TUM's ``associate.py``: take the globally closest pairs first. Between two
    30 Hz streams offset by about half a period (as in freiburg1) it strands frames: on the first
    37 frames of fr1_xyz it keeps 32. ``optimal`` (default) is an order-preserving matching that
    keeps the most pairs and, among those, the smallest total time difference (dynamic programming
    over each frame's at most few candidates); it keeps all 37 there.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if method not in ("optimal", "greedy"):
        raise EvsmapError(f"unknown association method {method!r} (known: optimal, greedy)")
    order_a = np.argsort(a, kind="stable")
    order_b, cands = _candidates(a[order_a], b, max_difference)
    if method == "greedy":
        flat = [(d, i, j) for i, cs in enumerate(cands) for j, d in cs]
        used_a, used_b, pairs = set(), set(), []
        for _, i, j in sorted(flat):
            if i not in used_a and j not in used_b:
                used_a.add(i)
                used_b.add(j)
                pairs.append((int(order_a[i]), int(order_b[j])))
        return sorted(pairs)
    floors = [min((j for j, _ in cs), default=len(b)) for cs in cands]
    for i in range(len(floors) - 2, -1, -1):  # the smallest j any frame from i on can take
        floors[i] = min(floors[i], floors[i + 1])
    return sorted((int(order_a[i]), int(order_b[j])) for i, j in _optimal_path(cands, floors))


def _optimal_path(cands: list[list[tuple[int, float]]], floors: list[int]) -> list[tuple[int, int]]:
    """The order-preserving matching of :func:`associate` (``optimal``) as (i, j) pairs.

    Dynamic programming over frames: a state is the last b index used (-1: none) with its score
    (pairs, -total difference) and its pairs as a linked list. States are kept only while no
    state with a smaller last index scores at least as much, so scores rise with the last index
    and the best state to extend with b index j is the one with the largest last index below j
    (a bisection). States whose last index is below every candidate of the frames still to come
    (``floors[i + 1]``) are all extended alike: only the best of them is kept. A frame costs its
    candidates' bisections plus the states within its time window, so a long sequence is
    linear in its length and duplicated stamps cost a window's square, not its cube.
    """
    lasts: list[int] = [-1]
    states: list[tuple[tuple[int, float], tuple | None]] = [((0, 0.0), None)]
    for i, cs in enumerate(cands):
        new = dict(zip(lasts, states, strict=True))  # a_i left unmatched
        for j, d in cs:
            k = bisect.bisect_left(lasts, j) - 1
            if k < 0:
                continue
            (pairs, total), node = states[k]
            score = (pairs + 1, total - d)
            if j not in new or score > new[j][0]:
                new[j] = (score, ((i, j), node))
        floor = floors[i + 1] if i + 1 < len(floors) else None
        lasts, states = [], []
        for last in sorted(new):
            if states and not new[last][0] > states[-1][0]:
                continue  # dominated by a state with a smaller last index
            if floor is not None and states and lasts[-1] < floor and last < floor:
                lasts.pop()  # both below what later frames can take: keep the better
                states.pop()
            lasts.append(last)
            states.append(new[last])
    path, node = [], states[-1][1]
    while node is not None:
        path.append(node[0])
        node = node[1]
    return path[::-1]


def read_intrinsics_file(path: Path) -> Intrinsics:
    """``intrinsics.txt``: one line ``fx fy cx cy width height`` (``#`` comments allowed)."""
    rows = read_list(path, 6)
    if len(rows) != 1:
        raise DataFormatError(f"{path}: expected one line 'fx fy cx cy width height'")
    try:
        fx, fy, cx, cy = (float(v) for v in rows[0][:4])
        width, height = int(rows[0][4]), int(rows[0][5])
        return Intrinsics(fx, fy, cx, cy, width, height)
    except (ValueError, EvsmapError) as exc:
        raise DataFormatError(f"{path}: bad intrinsics ({exc})") from None


class TumSequence(Sequence):
    """A TUM RGB-D sequence folder (or an ``evsmap synth`` output).

    Args:
        path: the sequence folder (holding ``rgb.txt``, ``depth.txt``, ``groundtruth.txt``).
        camera: ``fr1``, ``fr2``, ``fr3`` or ``ros-default``; detected from the folder name when
            omitted. Ignored when ``intrinsics`` is given or the folder has ``intrinsics.txt``.
        intrinsics: explicit camera parameters (override everything else).
        max_time_difference: association tolerance between depth and RGB stamps, seconds.
        association: ``optimal`` (most pairs) or ``greedy`` (TUM's associate.py).
        max_pose_gap: a frame is dropped when the ground-truth samples around its stamp are
            further apart than this (motion-capture dropouts), seconds.
        depth_scale: depth PNG value per metre.
    """

    def __init__(self, *, path: str | Path, camera: str | None = None,
                 intrinsics: Intrinsics | None = None, max_time_difference: float = 0.02,
                 max_pose_gap: float = 0.1, depth_scale: float = DEPTH_SCALE,
                 association: str = "optimal") -> None:
        root = Path(path)
        if not root.is_dir():
            raise DataFormatError(f"{root}: not a folder")
        if not (max_time_difference > 0):
            raise EvsmapError(f"max_time_difference must be positive, got {max_time_difference}")
        self.root = root
        self.folder = Path(root)
        self.depth_scale = float(depth_scale)
        meta: dict = {"layout": "tum", "path": str(root)}
        meta_file = root / METADATA_FILE
        classes: tuple[str, ...] = ()
        if meta_file.is_file():
            info = _read_metadata(meta_file)
            if info.get("format") == "evsmap-synthetic":
                meta.update(layout="synthetic", synthetic=info)
                classes = _class_names(meta_file, info.get("classes"))
        intr, source = self._intrinsics(root, camera, intrinsics)
        meta["intrinsics_source"] = source
        super().__init__(root.resolve().name, intr, meta)
        if classes:  # after __init__: an empty list reads meta, which __init__ sets
            self.class_names = classes
            self.num_classes = len(classes)

        rgb = read_list(root / "rgb.txt", 2)
        depth = read_list(root / "depth.txt", 2)
        if not depth:
            raise DataFormatError(f"{root / 'depth.txt'}: lists no depth images")
        gt_path = root / "groundtruth.txt"
        gt = read_list(gt_path, 8)
        if len(gt) < 1:
            raise DataFormatError(f"{gt_path}: no poses (camera-to-world poses are required)")
        gt_arr = _pose_rows(gt_path, gt)
        order = np.argsort(gt_arr[:, 0], kind="stable")
        gt_arr = gt_arr[order]
        dup = np.diff(gt_arr[:, 0]) <= 0
        if np.any(dup):
            gt_arr = gt_arr[np.concatenate([[True], ~dup])]
        t_rgb = np.array([float(r[0]) for r in rgb])
        t_depth = np.array([float(r[0]) for r in depth])
        pairs = associate(t_depth, t_rgb, max_time_difference, association)
        dropped = {"no_rgb_within_tolerance": len(depth) - len(pairs), "no_pose": 0}
        matched = np.array([i for i, _ in pairs], dtype=np.int64)
        ts = t_depth[matched] if len(matched) else np.zeros(0)
        gt_t = gt_arr[:, 0]
        inside = (ts >= gt_t[0]) & (ts <= gt_t[-1])
        hi = np.clip(np.searchsorted(gt_t, ts, side="left"), 0, len(gt_t) - 1)
        lo = np.clip(hi - 1, 0, len(gt_t) - 1)
        exact = gt_t[hi] == ts
        gap = np.where(exact, 0.0, gt_t[hi] - gt_t[lo])
        ok = inside & (gap <= max_pose_gap)
        dropped["no_pose"] = int((~ok).sum())
        pairs = [p for p, keep in zip(pairs, ok, strict=True) if keep]
        ts = ts[ok]
        self.poses = _interpolate(gt_path, gt_arr, ts)
        self.timestamps = ts
        self.depth_files = [root / depth[i][1] for i, _ in pairs]
        self.rgb_files = [root / rgb[j][1] for _, j in pairs]
        self.label_files: list[Path] | None = None
        labels_txt = root / "labels.txt"
        if labels_txt.is_file():
            lab = {row[0]: root / row[1] for row in read_list(labels_txt, 2)}
            missing = [depth[i][0] for i, _ in pairs if depth[i][0] not in lab]
            if missing:
                raise DataFormatError(
                    f"{labels_txt}: no label image for depth timestamp {missing[0]} "
                    f"({len(missing)} missing)")
            self.label_files = [lab[depth[i][0]] for i, _ in pairs]
        self.meta.update(
            listed_depth=len(depth), listed_rgb=len(rgb), groundtruth_poses=len(gt_arr),
            dropped=dropped, has_labels=self.label_files is not None,
        )
        if not len(self):
            raise DataFormatError(
                f"{root}: no usable frames ({dropped['no_rgb_within_tolerance']} depth images "
                f"without RGB within {max_time_difference} s, {dropped['no_pose']} without pose)")

    @staticmethod
    def _intrinsics(root: Path, camera: str | None,
                    intrinsics: Intrinsics | None) -> tuple[Intrinsics, str]:
        if intrinsics is not None:
            return intrinsics, "explicit"
        if (root / INTRINSICS_FILE).is_file() and camera is None:
            return read_intrinsics_file(root / INTRINSICS_FILE), INTRINSICS_FILE
        if camera is not None:
            if camera not in TUM_CAMERAS:
                raise EvsmapError(
                    f"unknown TUM camera {camera!r} (known: {', '.join(TUM_CAMERAS)})")
            return TUM_CAMERAS[camera], f"camera {camera}"
        detected = detect_camera(root)
        if detected is None:
            raise EvsmapError(
                f"{root}: cannot tell which TUM camera recorded this folder (its name has no "
                f"freiburg1/2/3); pass camera=fr1|fr2|fr3|ros-default (-r camera=NAME; "
                f"--camera with evsmap info) or add {INTRINSICS_FILE}")
        return TUM_CAMERAS[detected], f"camera {detected} (from folder name)"

    def __len__(self) -> int:
        return len(self.timestamps)

    def frame_stem(self, index: int) -> str:
        """Frame ``index``'s own file stem: its depth image's (the frame's timestamp, e.g.
        ``1305031102.160407``), the name ``evsmap predict`` writes its outputs under."""
        return self.depth_files[index].stem

    def frame(self, index: int) -> Frame:
        rgb = read_rgb(self.rgb_files[index])
        raw = read_uint16(self.depth_files[index])
        check_rgbd_shapes(raw, rgb, self.intrinsics, depth_file=self.depth_files[index],
                          rgb_file=self.rgb_files[index],
                          intrinsics_source=self.meta["intrinsics_source"])
        labels = None
        if self.label_files is not None:
            labels = read_uint8_labels(self.label_files[index])
            if labels.shape != raw.shape:
                raise DataFormatError(f"{self.label_files[index]}: label size {labels.shape} "
                                      f"differs from depth size {raw.shape}")
        return Frame(rgb=rgb, depth=dequantize_depth(raw, self.depth_scale),
                     intrinsics=self.intrinsics, pose=self.poses[index],
                     timestamp=float(self.timestamps[index]), labels=labels,
                     name=self.depth_files[index].name)


def is_tum_folder(path: Path) -> bool:
    path = Path(path)
    return (path / "rgb.txt").is_file() and (path / "depth.txt").is_file()


@READERS.register("tum", takes=Takes(path=True, camera=True), detect=is_tum_folder,
                  description="TUM RGB-D folder (rgb.txt, depth.txt, groundtruth.txt) or an "
                              "`evsmap synth` output")
def open_tum(*, path: str, camera: str | None = None, intrinsics: Intrinsics | None = None,
             max_time_difference: float = 0.02, max_pose_gap: float = 0.1,
             association: str = "optimal") -> TumSequence:
    """TUM RGB-D folder (rgb.txt, depth.txt, groundtruth.txt) or an `evsmap synth` output."""
    return TumSequence(path=path, camera=camera, intrinsics=intrinsics,
                       max_time_difference=max_time_difference, max_pose_gap=max_pose_gap,
                       association=association)


def write_tum(sequence: Sequence, out: Path, *, quaternions: np.ndarray | None = None,
              progress=None) -> None:
    """Write ``sequence`` to the folder ``out`` in the TUM layout (plus labels and intrinsics).

    RGB, depth and labels share each frame's timestamp; poses are written with full float
    precision (``repr``). ``quaternions`` (N x 4, x y z w), when the sequence was generated from
    them, are written as they are instead of being recovered from the matrices, so reading the
    folder back gives bit-identical pose matrices. ``progress`` wraps the frame iterator.
    """
    out = Path(out)
    for sub in ("rgb", "depth"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    intr = sequence.intrinsics
    assert intr is not None, "write_tum writes RGB-D sequences, which have intrinsics"
    (out / INTRINSICS_FILE).write_text(
        "# fx fy cx cy width height (pixels, pinhole, no distortion)\n"
        f"{intr.fx!r} {intr.fy!r} {intr.cx!r} {intr.cy!r} {intr.width} {intr.height}\n")
    header = "# {what}\n# file: '{name}'\n# timestamp filename\n"
    rgb_lines = [header.format(what="color images", name=sequence.name)]
    depth_lines = [header.format(what="depth maps", name=sequence.name)]
    label_lines = [header.format(what="semantic labels (uint8 class ids, 255 void)",
                                 name=sequence.name)]
    gt_lines = [f"# ground truth trajectory\n# file: '{sequence.name}'\n"
                "# timestamp tx ty tz qx qy qz qw\n"]
    has_labels = False
    frames = iter(sequence) if progress is None else progress(sequence)
    for frame in frames:
        stamp = f"{frame.timestamp:.6f}"
        assert frame.rgb is not None and frame.depth is not None  # an RGB-D frame
        write_png(out / "rgb" / f"{stamp}.png", frame.rgb)
        write_png(out / "depth" / f"{stamp}.png", quantize_depth(frame.depth))
        rgb_lines.append(f"{stamp} rgb/{stamp}.png\n")
        depth_lines.append(f"{stamp} depth/{stamp}.png\n")
        if frame.labels is not None:
            (out / "labels").mkdir(exist_ok=True)
            write_png(out / "labels" / f"{stamp}.png", frame.labels)
            label_lines.append(f"{stamp} labels/{stamp}.png\n")
            has_labels = True
        index = len(gt_lines) - 1
        t = frame.pose[:3, 3]
        quat = quaternions[index] if quaternions is not None else matrix_to_quat(frame.pose[:3, :3])
        gt_lines.append(" ".join([stamp] + [repr(float(v)) for v in (*t, *quat)]) + "\n")
    (out / "rgb.txt").write_text("".join(rgb_lines))
    (out / "depth.txt").write_text("".join(depth_lines))
    (out / "groundtruth.txt").write_text("".join(gt_lines))
    if has_labels:
        (out / "labels.txt").write_text("".join(label_lines))
