"""ROS bags (ROS 1 ``.bag``, ROS 2 sqlite3 ``.db3`` and MCAP) as evsmap sequences.

A bag gives either RGB-D frames (colour ``Image``/``CompressedImage`` + registered depth + a
``CameraInfo``) or point-cloud frames (``PointCloud2``), each with a camera-to-world pose from

* a pose topic (``nav_msgs/Odometry``, ``geometry_msgs/TransformStamped``, ``PoseStamped`` or
  ``PoseWithCovarianceStamped``): the pose of the message's child frame in its header frame,
  followed by the static offset from that child frame to the sensor frame (``sensor_offset``, or
  the chain found in ``/tf_static`` + ``/tf``, or identity when neither has one - recorded in
  ``meta["sensor_offset"]``), or
* ``/tf`` + ``/tf_static``: the transform chain from ``world_frame`` to the sensor frame through
  any number of intermediate frames, dynamic links interpolated at the frame's stamp (linear
  translation, slerp rotation), static links constant.

Messages are read through :class:`rosbags.highlevel.AnyReader`. Opening a bag indexes it once
(header stamps, frame ids, image sizes: no image is decoded); :meth:`RosbagSequence.frame` reads
and decodes one frame's messages only (random access by bag time through the bag's own index;
reading frames in order continues one message stream instead of seeking). Problems with the
whole bag raise at open; problems with one frame (corrupt compressed image, wrong size, no pose
within ``max_pose_gap``) raise from ``frame(i)`` so a caller can skip that frame.

The sensor frame is the image's (or cloud's) ``header.frame_id`` unless ``sensor_frame`` is
given. Image poses use OpenCV camera axes (x right, y down, z forward), which is what a ROS
``*_optical_frame`` is (REP 103); if images are stamped in a body frame (x forward, y left,
z up), pass ``camera_axes="body"`` and the reader appends the fixed body-to-optical rotation.
Point clouds keep their own axes (the points are expressed in their header frame), so no axis
change applies to them. See ``docs/rosbags.md``.
"""

from __future__ import annotations

import io
import re
import warnings
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from evsmap.data import Frame, Intrinsics, Sequence
from evsmap.errors import DataFormatError, EvsmapError, InvalidDataError
from evsmap.geometry import interpolate_poses, pose_matrix
from evsmap.readers.tum import associate
from evsmap.registry import READERS

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
CLOUD = "sensor_msgs/msg/PointCloud2"
ODOMETRY = "nav_msgs/msg/Odometry"
POSE_TYPES = (ODOMETRY, "geometry_msgs/msg/TransformStamped", "geometry_msgs/msg/PoseStamped",
              "geometry_msgs/msg/PoseWithCovarianceStamped")
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")

COLOR_ENCODINGS = {"rgb8": (3, False), "bgr8": (3, True), "rgba8": (4, False),
                   "bgra8": (4, True), "mono8": (1, False)}
"""Supported colour ``Image`` encodings: channels and whether the order is BGR."""
DEPTH_ENCODINGS = {"16uc1": ("u2", 0.001), "mono16": ("u2", 0.001), "32fc1": ("f4", 1.0)}
"""Supported depth ``Image`` encodings (lower case): sample type and metres per unit."""
_COLOR_EXPECTED = "rgb8, bgr8, rgba8, bgra8 or mono8"
_DEPTH_EXPECTED = "16UC1 (millimetres) or 32FC1 (metres)"

BODY_TO_OPTICAL = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0],
                            [0.0, 0.0, 0.0, 1.0]])
"""Pose of a ROS optical frame (z forward, x right, y down) in its body frame (x forward, y left,
z up): appended to image poses with ``camera_axes="body"``."""

# Topic and frame defaults for known recordings. A tuple lists alternatives: the first topic the
# bag holds is used (raw vs image_transport names). Sources:
# * "asl": the ETH ASL "cow and lady" bag (voxblox dataset, projects.asl.ethz.ch/datasets/
#   doku.php?id=iros2017). voxblox's voxblox_ros/launch/cow_and_lady_dataset.launch remaps the
#   cloud to /camera/depth_registered/points and takes the Vicon pose from the TransformStamped
#   topic /kinect/vrpn_client/estimated_transform with use_tf_transforms=false; the Kinect-to-
#   Vicon-body calibration is not in the bag but in voxblox_ros/cfg/cow_and_lady.yaml (T_B_D,
#   "actually T_V_C", invert_T_B_D: true, so voxblox's T_G_C = T_G_V * that matrix), reproduced
#   here as sensor_offset.
# * "rtabmap": RTAB-Map's demo_mapping.bag. rtabmap_demos/launch/demo_robot_mapping.launch remaps
#   rgb/image, depth/image and rgb/camera_info to /data_throttled_image, /data_throttled_image_depth
#   and /data_throttled_camera_info with image_transport "compressed" and "compressedDepth" (so the
#   recorded topics are .../compressed and .../compressedDepth), and takes odometry from TF
#   (odom_frame_id "odom"; the /az3/base_controller/odom topic has no covariances).
# * "zed2i": the Stereolabs ZED ROS wrapper with camera name "zed2i" (zed-ros-wrapper
#   zed_wrapper_nodelet: rgb and depth images and camera_info in <name>_left_camera_optical_frame,
#   depth in metres (32FC1) unless openni_depth_mode, odometry "odom" -> "base_link"; base_link ->
#   camera frames come from the URDF through robot_state_publisher on /tf_static).
PRESETS: dict[str, dict[str, Any]] = {
    "asl": {
        "cloud_topic": ("/camera/depth_registered/points",),
        "odom_topic": ("/kinect/vrpn_client/estimated_transform",),
        "sensor_offset": [[0.971048, -0.120915, 0.206023, 0.00114049],
                          [0.15701, 0.973037, -0.168959, 0.0450936],
                          [-0.180038, 0.196415, 0.96385, 0.0430765],
                          [0.0, 0.0, 0.0, 1.0]],
    },
    "rtabmap": {
        "rgb_topic": ("/data_throttled_image/compressed", "/data_throttled_image"),
        "depth_topic": ("/data_throttled_image_depth/compressedDepth",
                        "/data_throttled_image_depth"),
        "camera_info_topic": ("/data_throttled_camera_info",),
        "world_frame": "odom",
    },
    "zed2i": {
        "rgb_topic": ("/zed2i/zed_node/rgb/image_rect_color",
                      "/zed2i/zed_node/rgb/image_rect_color/compressed"),
        "depth_topic": ("/zed2i/zed_node/depth/depth_registered",
                        "/zed2i/zed_node/depth/depth_registered/compressedDepth"),
        "camera_info_topic": ("/zed2i/zed_node/rgb/camera_info",),
        "odom_topic": ("/zed2i/zed_node/odom",),
    },
}

TIME_SOURCES = ("auto", "header", "bag", "order")


class _NoPose(Exception):
    """No pose at a frame's stamp (message without the stamp)."""


def _frame_name(frame: str) -> str:
    return frame.lstrip("/")


def _stamp_ns(msg: Any) -> int:
    stamp = msg.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _fmt(ns: int) -> str:
    return f"{ns / 1e9:.6f} s"


# --------------------------------------------------------------------------------------------
# Decoding
# --------------------------------------------------------------------------------------------

def _raw_rows(msg: Any, row_bytes: int, where: str) -> np.ndarray:
    """The image bytes as (height, row_bytes) uint8, honouring ``step`` (row padding)."""
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    if h == 0 or w == 0:
        raise DataFormatError(f"{where}: empty image ({w}x{h})")
    if step < row_bytes:
        raise DataFormatError(f"{where}: step {step} is less than a row of {w} pixels "
                              f"({row_bytes} bytes)")
    if data.size < step * (h - 1) + row_bytes:
        raise DataFormatError(f"{where}: {data.size} data bytes for a {w}x{h} image with step "
                              f"{step} (expected {step * h})")
    if data.size < step * h:  # last row without its padding
        data = np.concatenate([data, np.zeros(step * h - data.size, dtype=np.uint8)])
    return data[: step * h].reshape(h, step)[:, :row_bytes]


def decode_color_image(msg: Any, where: str) -> np.ndarray:
    """``sensor_msgs/Image`` (rgb8, bgr8, rgba8, bgra8, mono8) -> ``uint8`` HxWx3 RGB."""
    enc = str(msg.encoding).lower()
    if enc not in COLOR_ENCODINGS:
        raise DataFormatError(f"{where}: colour encoding {msg.encoding!r}; expected "
                              f"{_COLOR_EXPECTED}")
    channels, bgr = COLOR_ENCODINGS[enc]
    rows = _raw_rows(msg, int(msg.width) * channels, where)
    img = np.ascontiguousarray(rows).reshape(int(msg.height), int(msg.width), channels)
    if channels == 1:
        return np.repeat(img, 3, axis=2)
    img = img[..., :3]
    return np.ascontiguousarray(img[..., ::-1] if bgr else img)


def _clean_depth(depth: np.ndarray) -> np.ndarray:
    depth = depth.astype(np.float32, copy=False)
    bad = ~np.isfinite(depth) | (depth < 0)
    if bad.any():
        depth = np.where(bad, np.float32(0.0), depth)
    return np.ascontiguousarray(depth, dtype=np.float32)


def decode_depth_image(msg: Any, where: str) -> np.ndarray:
    """``sensor_msgs/Image`` 16UC1/mono16 (mm) or 32FC1 (m) -> ``float32`` metres, 0 invalid."""
    enc = str(msg.encoding).lower()
    if enc not in DEPTH_ENCODINGS:
        raise DataFormatError(f"{where}: depth encoding {msg.encoding!r}; expected "
                              f"{_DEPTH_EXPECTED}")
    kind, scale = DEPTH_ENCODINGS[enc]
    dtype = np.dtype(kind).newbyteorder(">" if msg.is_bigendian else "<")
    rows = _raw_rows(msg, int(msg.width) * dtype.itemsize, where)
    values = np.ascontiguousarray(rows).view(dtype).reshape(int(msg.height), int(msg.width))
    if kind == "u2":
        return _clean_depth(values.astype(np.float32) * np.float32(scale))
    return _clean_depth(values.astype(np.float32))


def _pil_open(data: bytes, where: str, what: str):
    from PIL import Image, UnidentifiedImageError

    try:
        img = Image.open(io.BytesIO(data))
        img.load()
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as exc:
        raise DataFormatError(f"{where}: cannot decode the {what} data ({exc})") from None
    return img


def decode_compressed_color(msg: Any, where: str) -> np.ndarray:
    """``sensor_msgs/CompressedImage`` (JPEG, PNG, anything Pillow reads) -> ``uint8`` RGB."""
    img = _pil_open(bytes(np.asarray(msg.data, dtype=np.uint8)), where,
                    f"compressed image ({msg.format!r})")
    if img.mode in ("I;16", "I;16B", "I;16L", "I", "F"):
        raise DataFormatError(f"{where}: compressed colour image is {img.mode} "
                              f"(16/32-bit); expected 8-bit colour or grey")
    return np.ascontiguousarray(np.asarray(img.convert("RGB"), dtype=np.uint8))


_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _png_uint16(data: bytes, where: str) -> np.ndarray:
    img = _pil_open(data, where, "compressedDepth PNG")
    arr = np.asarray(img)
    if arr.ndim != 2 or img.mode not in ("I;16", "I;16B", "I;16L", "I", "L"):
        raise DataFormatError(f"{where}: compressedDepth PNG is {img.mode} with shape "
                              f"{arr.shape}; expected one 16-bit channel")
    return arr.astype(np.uint16)


def decode_compressed_depth(msg: Any, where: str) -> np.ndarray:
    """Depth from ``sensor_msgs/CompressedImage``: image_transport's ``compressedDepth`` PNG
    (16UC1 millimetres, or 32FC1 as quantised inverse depth) or a plain 16-bit PNG in mm.

    ``compressedDepth`` data is a 12-byte header (int32 format, float32 depthQuantA,
    float32 depthQuantB; little-endian) followed by a PNG; a 32FC1 image's pixels hold
    ``v = A / depth + B`` and decode as ``A / (v - B)`` (0 for invalid), as
    compressed_depth_image_transport's codec does. Its RVL variant is not supported.
    """
    fmt = str(msg.format)
    data = bytes(np.asarray(msg.data, dtype=np.uint8))
    low = fmt.lower()
    encoding = low.split(";", 1)[0].strip()
    if "compresseddepth" in low:
        if "rvl" in low:
            raise DataFormatError(f"{where}: compressedDepth format {fmt!r} (RVL) is not "
                                  f"supported; expected compressedDepth PNG")
        if encoding not in DEPTH_ENCODINGS:
            raise DataFormatError(f"{where}: compressedDepth of encoding {encoding!r}; "
                                  f"expected {_DEPTH_EXPECTED}")
        if data[12:20] == _PNG_MAGIC:
            header, png = data[:12], data[12:]
        elif data[:8] == _PNG_MAGIC:  # no configuration header
            header, png = b"", data
        else:
            raise DataFormatError(f"{where}: compressedDepth data has no PNG at byte 0 or 12 "
                                  f"({len(data)} bytes)")
        raw = _png_uint16(png, where)
        if encoding == "32fc1":
            if len(header) != 12:
                raise DataFormatError(f"{where}: 32FC1 compressedDepth without its quantisation "
                                      f"header")
            quant = np.frombuffer(header, dtype="<f4", count=2, offset=4)
            a, b = np.float32(quant[0]), np.float32(quant[1])
            with np.errstate(divide="ignore", invalid="ignore"):
                depth = a / (raw.astype(np.float32) - b)
            return _clean_depth(np.where(raw == 0, np.float32(0.0), depth))
        return _clean_depth(raw.astype(np.float32) * np.float32(0.001))
    if encoding and encoding in ("32fc1",):
        raise DataFormatError(f"{where}: compressed depth format {fmt!r} is not supported; "
                              f"expected compressedDepth PNG or a 16-bit PNG in millimetres")
    img = _pil_open(data, where, f"compressed depth ({fmt!r})")
    if img.mode not in ("I;16", "I;16B", "I;16L", "I"):
        raise DataFormatError(f"{where}: compressed depth image is {img.mode}; expected a "
                              f"16-bit PNG in millimetres or compressedDepth")
    return _clean_depth(np.asarray(img).astype(np.float32) * np.float32(0.001))


_POINT_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def decode_cloud(msg: Any, where: str) -> tuple[np.ndarray, np.ndarray | None]:
    """``sensor_msgs/PointCloud2`` -> finite ``float32`` Nx3 points (NaN/inf dropped) and their
    ``uint8`` Nx3 colours (from a packed ``rgb``/``rgba`` float32/uint32 field or ``r``, ``g``,
    ``b`` uint8 fields) or None."""
    fields = {str(f.name): f for f in msg.fields}
    order = ">" if msg.is_bigendian else "<"
    for axis in "xyz":
        if axis not in fields:
            raise DataFormatError(f"{where}: PointCloud2 has no {axis!r} field (fields: "
                                  f"{', '.join(fields) or 'none'})")
        if fields[axis].datatype not in (7, 8):
            raise DataFormatError(f"{where}: PointCloud2 field {axis!r} has datatype "
                                  f"{fields[axis].datatype}; expected FLOAT32 (7) or FLOAT64 (8)")
    step = int(msg.point_step)
    names, formats, offsets = [], [], []

    def add(name: str, kind: str) -> None:
        f = fields[name]
        size = np.dtype(kind).itemsize
        if int(f.offset) + size > step:
            raise DataFormatError(f"{where}: PointCloud2 field {name!r} at offset {f.offset} "
                                  f"overruns point_step {step}")
        names.append(name)
        formats.append(order + kind)
        offsets.append(int(f.offset))

    for axis in "xyz":
        add(axis, _POINT_TYPES[fields[axis].datatype])
    color_field = next((n for n in ("rgb", "rgba") if n in fields), None)
    if color_field is not None and fields[color_field].datatype in (6, 7):
        add(color_field, "u4")  # packed 0x(AA)RRGGBB; a float32 field holds the same bits
    else:
        color_field = None
        if all(c in fields and fields[c].datatype == 2 for c in "rgb"):
            for c in "rgb":
                add(c, "u1")
            color_field = "r,g,b"
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": step})
    h, w = int(msg.height), int(msg.width)
    n = h * w
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    row = w * step
    row_step = int(msg.row_step) if int(msg.row_step) else row
    if row_step < row or data.size < row_step * (h - 1) + row:
        raise DataFormatError(f"{where}: PointCloud2 of {w}x{h} points with point_step {step} "
                              f"and row_step {msg.row_step} needs {row_step * h} bytes, has "
                              f"{data.size}")
    if n == 0:
        return np.zeros((0, 3), np.float32), None if color_field is None else \
            np.zeros((0, 3), np.uint8)
    if row_step != row or data.size != row * h:
        if data.size < row_step * h:
            data = np.concatenate([data, np.zeros(row_step * h - data.size, np.uint8)])
        data = np.ascontiguousarray(data[: row_step * h].reshape(h, row_step)[:, :row])
    rec = data.reshape(-1).view(dtype)
    pts = np.stack([rec["x"].astype(np.float32), rec["y"].astype(np.float32),
                    rec["z"].astype(np.float32)], axis=1)
    keep = np.all(np.isfinite(pts), axis=1)
    colors = None
    if color_field == "r,g,b":
        colors = np.stack([rec["r"], rec["g"], rec["b"]], axis=1).astype(np.uint8)
    elif color_field is not None:
        packed = rec[color_field].astype(np.uint32)
        colors = np.stack([(packed >> 16) & 255, (packed >> 8) & 255, packed & 255],
                          axis=1).astype(np.uint8)
    if not keep.all():
        pts = pts[keep]
        colors = colors[keep] if colors is not None else None
    return np.ascontiguousarray(pts), colors


# --------------------------------------------------------------------------------------------
# Poses
# --------------------------------------------------------------------------------------------

@dataclass
class _Samples:
    """Timestamped transforms parent <- child (pose of child in parent)."""

    parent: str
    child: str
    label: str
    times: list[int] = field(default_factory=list)  # ns
    bag_times: list[int] = field(default_factory=list)
    trans: list[tuple[float, float, float]] = field(default_factory=list)
    quats: list[tuple[float, float, float, float]] = field(default_factory=list)

    def add(self, stamp: int, log: int, t: Any, q: Any) -> None:
        self.times.append(stamp)
        self.bag_times.append(log)
        self.trans.append((float(t.x), float(t.y), float(t.z)))
        self.quats.append((float(q.x), float(q.y), float(q.z), float(q.w)))

    def track(self, source: str) -> _Track:
        return _Track(self, source)


class _Track:
    """A dynamic transform resampled at query times (lerp + slerp between samples)."""

    def __init__(self, samples: _Samples, source: str) -> None:
        ns = np.asarray(samples.bag_times if source == "bag" else samples.times, dtype=np.int64)
        trans = np.asarray(samples.trans, dtype=np.float64).reshape(-1, 3)
        quats = np.asarray(samples.quats, dtype=np.float64).reshape(-1, 4)
        order = np.argsort(ns, kind="stable")
        ns, trans, quats = ns[order], trans[order], quats[order]
        # several samples at one stamp: keep the last
        keep = np.ones(len(ns), dtype=bool)
        keep[:-1] = ns[1:] != ns[:-1]
        self.ns, self.trans, self.quats = ns[keep], trans[keep], quats[keep]
        self.times = self.ns.astype(np.float64) * 1e-9
        self.label = samples.label
        self.samples = samples

    def __len__(self) -> int:
        return len(self.ns)

    def covers(self, t_ns: int, max_gap: float) -> bool:
        try:
            self.check(t_ns, max_gap)
        except _NoPose:
            return False
        return True

    def check(self, t_ns: int, max_gap: float) -> None:
        ns = self.ns
        if not len(ns) or t_ns < ns[0] or t_ns > ns[-1]:
            span = f"{_fmt(int(ns[0]))} .. {_fmt(int(ns[-1]))}" if len(ns) else "no samples"
            raise _NoPose(f"outside the samples of {self.label} ({span})")
        i = int(np.searchsorted(ns, t_ns))
        gap = abs(int(ns[i]) - t_ns)
        if i > 0:
            gap = min(gap, t_ns - int(ns[i - 1]))
        if gap * 1e-9 > max_gap:
            raise _NoPose(f"the nearest sample of {self.label} is {gap * 1e-9:.3f} s away "
                          f"(max_pose_gap {max_gap} s)")

    def at(self, t_ns: int, max_gap: float) -> np.ndarray:
        self.check(t_ns, max_gap)
        return interpolate_poses(self.times, self.trans, self.quats,
                                 np.array([t_ns * 1e-9]))[0]


def _check_quat(q: Any, where: str) -> None:
    v = np.array([q.x, q.y, q.z, q.w], dtype=np.float64)
    if not np.all(np.isfinite(v)) or np.linalg.norm(v) < 1e-6:
        raise DataFormatError(f"{where}: invalid rotation quaternion {v.tolist()}")


class _TfTree:
    """``/tf`` + ``/tf_static``: a tree of frames; looks up world <- sensor at a time."""

    def __init__(self, label: str) -> None:
        self.label = label
        self.static: dict[str, tuple[str, np.ndarray]] = {}
        self.dynamic: dict[str, _Samples] = {}
        self.conflicts: set[str] = set()
        self.tracks: dict[str, _Track] = {}
        self.source = "header"

    def add(self, tf: Any, log: int, topic: str, static: bool) -> None:
        parent, child = _frame_name(tf.header.frame_id), _frame_name(tf.child_frame_id)
        where = f"{self.label}: topic {topic} transform {parent} -> {child}"
        _check_quat(tf.transform.rotation, where)
        t, q = tf.transform.translation, tf.transform.rotation
        if static:
            self.static[child] = (parent, pose_matrix(
                np.array([t.x, t.y, t.z], dtype=np.float64),
                np.array([q.x, q.y, q.z, q.w], dtype=np.float64)))
            return
        samples = self.dynamic.get(child)
        if samples is None:
            samples = self.dynamic[child] = _Samples(parent, child, f"{topic} {parent} -> {child}")
        elif samples.parent != parent:
            self.conflicts.add(child)
            return
        samples.add(_stamp_ns(tf), log, t, q)

    def set_source(self, source: str) -> None:
        self.source = source
        self.tracks = {c: s.track(source) for c, s in self.dynamic.items()}

    def parent(self, frame: str) -> str | None:
        if frame in self.static:
            return self.static[frame][0]
        if frame in self.dynamic:
            return self.dynamic[frame].parent
        return None

    def frames(self) -> set[str]:
        out = set(self.static) | set(self.dynamic)
        out |= {p for p, _ in self.static.values()} | {s.parent for s in self.dynamic.values()}
        return out

    def to_root(self, frame: str) -> list[str]:
        path, seen = [frame], {frame}
        while (p := self.parent(path[-1])) is not None and p not in seen:
            path.append(p)
            seen.add(p)
        return path

    def root(self, frame: str) -> str:
        return self.to_root(frame)[-1]

    def chain(self, target: str, source: str) -> tuple[list[str], list[str]] | None:
        """Frames from ``source`` up to the common ancestor and from ``target`` up to it."""
        up_s, up_t = self.to_root(source), self.to_root(target)
        common = next((f for f in up_s if f in set(up_t)), None)
        if common is None:
            return None
        return up_s[: up_s.index(common) + 1], up_t[: up_t.index(common) + 1]

    def _edge(self, child: str, t_ns: int, max_gap: float) -> np.ndarray:
        if child in self.static:
            return self.static[child][1]
        return self.tracks[child].at(t_ns, max_gap)

    def _up(self, path: list[str], t_ns: int, max_gap: float) -> np.ndarray:
        out = np.eye(4)
        for child in reversed(path[:-1]):  # ancestor-most link first
            out = out @ self._edge(child, t_ns, max_gap)
        return out

    def lookup(self, target: str, source: str, t_ns: int, max_gap: float) -> np.ndarray:
        """Pose of ``source`` in ``target`` at ``t_ns`` (raises _NoPose)."""
        links = self.chain(target, source)
        if links is None:
            raise _NoPose(f"no transform chain from {target} to {source}")
        up_s, up_t = links
        return np.linalg.inv(self._up(up_t, t_ns, max_gap)) @ self._up(up_s, t_ns, max_gap)

    def dynamic_links(self, target: str, source: str) -> list[str]:
        links = self.chain(target, source)
        if links is None:
            return []
        return [c for path in links for c in path[:-1] if c not in self.static]

    def describe(self, target: str, source: str) -> str:
        links = self.chain(target, source)
        if links is None:
            return "none"
        up_s, up_t = links
        path = up_t + up_s[::-1][1:]  # target up to the common ancestor, then down to source
        marks = []
        for a, b in zip(path, path[1:], strict=False):
            child = a if self.parent(a) == b else b
            marks.append(f"{a} -> {b} ({'static' if child in self.static else 'dynamic'})")
        return ", ".join(marks) if marks else "identity"


# --------------------------------------------------------------------------------------------
# Index
# --------------------------------------------------------------------------------------------

@dataclass
class _Msg:
    """One indexed message: where to find it again and its header facts."""

    topic: str
    conn_key: tuple[str, int]
    log: int  # bag time, ns
    nth: int  # rank among messages of this connection with the same bag time
    stamp: int  # header stamp, ns
    frame_id: str
    width: int = 0
    height: int = 0
    encoding: str = ""


@dataclass
class _Plan:
    """What a frame needs: its messages, its time and its pose (or why it has none)."""

    msgs: tuple[_Msg, ...]
    time: int
    pose: np.ndarray | None = None
    no_pose: str = ""


def _bag_format(path: Path) -> str:
    if path.is_dir():
        return "ros2-mcap" if any(path.glob("*.mcap*")) else "ros2-sqlite3"
    return {".bag": "ros1", ".mcap": "ros2-mcap", ".db3": "ros2-sqlite3"}.get(path.suffix,
                                                                             "unknown")


_MAGIC = {".bag": b"#ROSBAG V2.0", ".mcap": b"\x89MCAP", ".db3": b"SQLite format 3"}


def is_rosbag(path: Path) -> bool:
    """A ROS 1 ``.bag``, a bare ``.mcap`` / ``.db3`` file or a ROS 2 bag folder."""
    path = Path(path)
    if path.is_file():
        magic = _MAGIC.get(path.suffix)
        if magic is None:
            return False
        try:
            with path.open("rb") as fh:
                return fh.read(len(magic)) == magic
        except OSError:
            return False
    if path.is_dir() and (path / "metadata.yaml").is_file():
        return any(path.glob("*.db3*")) or any(path.glob("*.mcap*"))
    return False


class RosbagSequence(Sequence):
    """Frames of a ROS 1 or ROS 2 bag: RGB-D images or point clouds, with poses.

    Args: see :func:`open_rosbag`.
    """

    def __init__(self, *, path: str | Path, preset: str | None = None,
                 rgb_topic: str | None = None, depth_topic: str | None = None,
                 camera_info_topic: str | None = None, cloud_topic: str | None = None,
                 odom_topic: str | None = None, world_frame: str | None = None,
                 sensor_frame: str | None = None, max_time_difference: float = 0.02,
                 max_pose_gap: float = 0.1, limit: int | None = None,
                 time_source: str = "auto", sensor_offset: Any = None,
                 camera_axes: str = "optical", intrinsics: Intrinsics | None = None) -> None:
        from rosbags.highlevel import AnyReader

        bag = Path(path)
        self.path = bag
        self.label = str(path)
        if not bag.exists():
            raise DataFormatError(f"{self.label}: no such file or folder")
        if not (max_time_difference > 0):
            raise EvsmapError(f"max_time_difference must be positive, got {max_time_difference}")
        if not (max_pose_gap >= 0):
            raise EvsmapError(f"max_pose_gap must be non-negative, got {max_pose_gap}")
        if limit is not None and (isinstance(limit, bool) or int(limit) != limit or limit < 1):
            raise EvsmapError(f"limit must be a positive integer, got {limit!r}")
        if time_source not in TIME_SOURCES:
            raise EvsmapError(f"unknown time_source {time_source!r} (known: "
                              f"{', '.join(TIME_SOURCES)})")
        if camera_axes not in ("optical", "body"):
            raise EvsmapError(f"camera_axes must be 'optical' or 'body', got {camera_axes!r}")
        if preset is not None and preset not in PRESETS:
            raise EvsmapError(f"unknown rosbag preset {preset!r} (known: {', '.join(PRESETS)})")
        self.max_pose_gap = float(max_pose_gap)
        self.max_time_difference = float(max_time_difference)
        self.camera_axes = camera_axes
        self._closed = False
        name = bag.name if bag.is_dir() else bag.stem
        meta: dict[str, Any] = {"layout": "rosbag", "path": str(bag),
                                "bag_format": _bag_format(bag), "preset": preset}
        super().__init__(name or str(bag), None, meta)

        try:
            from rosbags.typesys import Stores, get_typestore

            reader = AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
            reader.open()
        except Exception as exc:  # rosbags raises its own errors, OSError, YAML errors, ...
            raise DataFormatError(f"{self.label}: not a readable ROS bag ({exc})") from None
        self._reader = reader
        self._cursor: tuple[Any, frozenset, int, Counter] | None = None
        try:
            self._setup(preset, rgb_topic, depth_topic, camera_info_topic, cloud_topic,
                        odom_topic, world_frame, sensor_frame, limit, time_source,
                        sensor_offset, intrinsics)
        except BaseException:
            self.close()
            raise

    # -- set-up -------------------------------------------------------------------------------
    def _topics_of(self, types: Iterable[str]) -> list[str]:
        types = set(types)
        return sorted({c.topic for c in self._reader.connections if c.msgtype in types
                       and c.msgcount != 0})

    def _conns(self, topic: str) -> list[Any]:
        return [c for c in self._reader.connections if c.topic == topic]

    def _type_of(self, topic: str) -> str:
        types = {c.msgtype for c in self._conns(topic)}
        return types.pop() if len(types) == 1 else ""

    def _first(self, topic: str) -> Any:
        gen = self._reader.messages(connections=self._conns(topic))
        try:
            for conn, _, raw in gen:
                return self._deserialize(raw, conn, f"{self.label}: topic {topic}")
        finally:
            gen.close()
        return None

    def _deserialize(self, raw: bytes, conn: Any, where: str) -> Any:
        try:
            return self._reader.deserialize(raw, conn.msgtype)
        except Exception as exc:
            raise DataFormatError(f"{where}: cannot decode the {conn.msgtype} message "
                                  f"({exc})") from None

    def _pick(self, role: str, option: str, given: Any, preset: dict, types: tuple[str, ...],
              candidates: list[str] | None = None, required: bool = True) -> str | None:
        """The topic for ``role``: given, from the preset (first present) or the only candidate."""
        if given is not None:
            if not self._conns(given):
                raise DataFormatError(
                    f"{self.label}: no topic {given} ({option}); the bag has "
                    f"{self._listing()}")
            if self._type_of(given) not in types:
                raise DataFormatError(
                    f"{self.label}: topic {given} ({option}) is {self._type_of(given) or 'mixed'}"
                    f"; expected {' or '.join(types)}")
            return given
        if option in preset:
            options = preset[option]
            for topic in options:
                if self._conns(topic):
                    return self._pick(role, option, topic, {}, types)
            if required:
                raise DataFormatError(
                    f"{self.label}: preset {self.meta['preset']!r} expects {role} on "
                    f"{' or '.join(options)}, which the bag lacks; pass {option}=TOPIC (the bag "
                    f"has {self._listing()})")
            return None
        cands = self._topics_of(types) if candidates is None else candidates
        if len(cands) == 1:
            return cands[0]
        if not cands:
            if required:
                raise DataFormatError(
                    f"{self.label}: no {role} topic ({' or '.join(types)}); the bag has "
                    f"{self._listing()}")
            return None
        raise DataFormatError(
            f"{self.label}: {len(cands)} candidate {role} topics ({', '.join(cands)}); choose "
            f"one with {option}=TOPIC")

    def _listing(self) -> str:
        topics = self._reader.topics
        if not topics:
            return "no topics"
        listed = [f"{t} ({info.msgtype}, {info.msgcount})" for t, info in sorted(topics.items())]
        more = f", ... ({len(listed) - 30} more)" if len(listed) > 30 else ""
        return ", ".join(listed[:30]) + more

    def _classify_images(self) -> tuple[list[str], list[str], dict[str, str]]:
        """Image/CompressedImage topics split into colour and depth by their first message."""
        color, depth, seen = [], [], {}
        for topic in self._topics_of((IMAGE, COMPRESSED)):
            msg = self._first(topic)
            if msg is None:
                continue
            if self._type_of(topic) == IMAGE:
                enc = str(msg.encoding).lower()
                seen[topic] = msg.encoding
                if enc in COLOR_ENCODINGS:
                    color.append(topic)
                elif enc in DEPTH_ENCODINGS:
                    depth.append(topic)
            else:
                fmt = str(msg.format).lower()
                seen[topic] = msg.format
                if "compresseddepth" in fmt or fmt.split(";")[0].strip() in DEPTH_ENCODINGS:
                    depth.append(topic)
                else:
                    color.append(topic)
        return color, depth, seen

    def _setup(self, preset_name, rgb_topic, depth_topic, camera_info_topic, cloud_topic,
               odom_topic, world_frame, sensor_frame, limit, time_source, sensor_offset,
               intrinsics) -> None:
        reader = self._reader
        preset = dict(PRESETS.get(preset_name or "", {}))
        if not reader.connections or reader.message_count == 0:
            raise DataFormatError(f"{self.label}: the bag holds no messages")
        if world_frame is None and "world_frame" in preset and odom_topic is None:
            world_frame = preset["world_frame"]
        if sensor_offset is None and "sensor_offset" in preset and odom_topic is None:
            sensor_offset = preset["sensor_offset"]

        image_given = rgb_topic is not None or depth_topic is not None
        wants_cloud = cloud_topic is not None or ("cloud_topic" in preset and not image_given)
        wants_images = image_given or "rgb_topic" in preset
        if not wants_cloud and not wants_images:
            has_images = bool(self._topics_of((IMAGE, COMPRESSED)))
            has_cloud = bool(self._topics_of((CLOUD,)))
            if not has_images and not has_cloud:
                raise DataFormatError(
                    f"{self.label}: the bag has no images (sensor_msgs/Image or CompressedImage) "
                    f"or point clouds (sensor_msgs/PointCloud2); it has {self._listing()}")
            if has_images and has_cloud:
                # images win when both colour and depth can be found; else the cloud
                color, depth, _ = self._classify_images()
                wants_images = bool(color) and bool(depth)
                wants_cloud = not wants_images
            else:
                wants_cloud = has_cloud
                wants_images = not has_cloud
        self.kind = "cloud" if wants_cloud and not wants_images else "rgbd"
        self.meta["kind"] = self.kind
        topics: dict[str, Any] = {}
        self.meta["topics"] = topics

        if self.kind == "cloud":
            cloud = self._pick("point cloud", "cloud_topic", cloud_topic, preset, (CLOUD,))
            topics["cloud"] = cloud
            frame_topics = [cloud]
        else:
            color_c, depth_c, seen = self._classify_images()
            if rgb_topic is None and "rgb_topic" not in preset and not color_c:
                raise DataFormatError(
                    f"{self.label}: no colour image topic (Image with encoding "
                    f"{_COLOR_EXPECTED}, or CompressedImage); image topics: "
                    f"{self._describe_images(seen)}; the bag has {self._listing()}")
            rgb = self._pick("colour image", "rgb_topic", rgb_topic, preset,
                             (IMAGE, COMPRESSED), color_c)
            if depth_topic is None and "depth_topic" not in preset and not depth_c:
                raise DataFormatError(
                    f"{self.label}: no depth image topic (Image with encoding {_DEPTH_EXPECTED},"
                    f" or compressedDepth); image topics: {self._describe_images(seen)}")
            depth = self._pick("depth image", "depth_topic", depth_topic, preset,
                               (IMAGE, COMPRESSED), depth_c)
            if rgb == depth:
                raise DataFormatError(f"{self.label}: rgb_topic and depth_topic are both {rgb}")
            topics.update(rgb=rgb, depth=depth)
            frame_topics = [rgb, depth]
            info_topic = None
            if intrinsics is None:
                info_c = self._topics_of((CAMERA_INFO,))
                ns = re.sub(r"/(compressed|compressedDepth|theora)$", "", rgb).rsplit("/", 1)[0]
                if camera_info_topic is None and "camera_info_topic" not in preset and \
                        f"{ns}/camera_info" in info_c:
                    camera_info_topic = f"{ns}/camera_info"
                info_topic = self._pick("camera info", "camera_info_topic", camera_info_topic,
                                        preset, (CAMERA_INFO,))
            topics["camera_info"] = info_topic

        pose_topic, use_tf = self._pose_source(odom_topic, world_frame, preset, frame_topics)
        topics["pose"] = pose_topic
        tf_topics = self._topics_of(TF_TYPES)
        topics["tf"] = tf_topics
        self._index(frame_topics, pose_topic, tf_topics)

        if self.kind == "rgbd":
            self._check_images(topics["rgb"], topics["depth"], info_topic, intrinsics)
        self._plan(limit)
        self._poses(pose_topic, use_tf, world_frame, sensor_frame, sensor_offset, time_source)

    def _describe_images(self, seen: dict[str, str]) -> str:
        return ", ".join(f"{t} ({v})" for t, v in seen.items()) or "none"

    def _pose_source(self, odom_topic, world_frame, preset, frame_topics):
        if odom_topic is not None or ("odom_topic" in preset and world_frame is None):
            topic = self._pick("pose", "odom_topic", odom_topic, preset, POSE_TYPES)
            return topic, False
        tf_dynamic = [t for t in self._topics_of(TF_TYPES) if not t.endswith("tf_static")]
        if world_frame is not None:
            if not self._topics_of(TF_TYPES):
                raise DataFormatError(
                    f"{self.label}: world_frame={world_frame!r} needs /tf or /tf_static, which "
                    f"the bag lacks; the bag has {self._listing()}")
            return None, True
        cands = self._topics_of(POSE_TYPES) + tf_dynamic
        if len(cands) == 1:
            return (None, True) if cands[0] in tf_dynamic else (cands[0], False)
        if not cands:
            raise DataFormatError(
                f"{self.label}: no pose source for {', '.join(frame_topics)}: no Odometry, "
                f"TransformStamped or PoseStamped topic and no /tf; the bag has "
                f"{self._listing()}")
        raise DataFormatError(
            f"{self.label}: {len(cands)} candidate pose sources ({', '.join(cands)}); choose "
            f"one with odom_topic=TOPIC or, for /tf, world_frame=FRAME")

    def _index(self, frame_topics: list[str], pose_topic: str | None,
               tf_topics: list[str]) -> None:
        """One pass over the needed topics: header facts of frame messages, all poses."""
        wanted = set(frame_topics) | set(tf_topics) | ({pose_topic} if pose_topic else set())
        info = self.meta["topics"].get("camera_info")
        if info:
            wanted.add(info)
        conns = [c for c in self._reader.connections if c.topic in wanted]
        self._msgs: dict[str, list[_Msg]] = {t: [] for t in frame_topics}
        self._tf = _TfTree(self.label)
        self._pose_samples: _Samples | None = None
        self._camera_info = None
        counts: Counter = Counter()
        for conn, log, raw in self._reader.messages(connections=conns):
            topic = conn.topic
            key = (topic, conn.id)
            nth = counts[(key, log)]
            counts[(key, log)] += 1
            where = f"{self.label}: topic {topic} message at bag time {_fmt(log)}"
            if topic in self._msgs:
                msg = self._deserialize(raw, conn, where)
                self._msgs[topic].append(_Msg(
                    topic, key, log, nth, _stamp_ns(msg), _frame_name(msg.header.frame_id),
                    int(getattr(msg, "width", 0)), int(getattr(msg, "height", 0)),
                    str(getattr(msg, "encoding", getattr(msg, "format", "")))))
            elif topic == info:
                if self._camera_info is None:
                    self._camera_info = self._deserialize(raw, conn, where)
            elif topic == pose_topic:
                self._add_pose(self._deserialize(raw, conn, where), conn.msgtype, log, topic)
            if topic in tf_topics:
                msg = self._deserialize(raw, conn, where)
                for tf in msg.transforms:
                    self._tf.add(tf, log, topic, static=topic.endswith("tf_static"))
        for topic, msgs in self._msgs.items():
            if not msgs:
                raise DataFormatError(f"{self.label}: topic {topic} has no messages")
        self.meta["messages"] = {t: len(m) for t, m in self._msgs.items()}
        if self._tf.conflicts:
            self.meta["tf_conflicts"] = sorted(self._tf.conflicts)

    def _add_pose(self, msg: Any, msgtype: str, log: int, topic: str) -> None:
        if msgtype == ODOMETRY:
            child, pose = msg.child_frame_id, msg.pose.pose
            t, q = pose.position, pose.orientation
        elif msgtype == "geometry_msgs/msg/TransformStamped":
            child = msg.child_frame_id
            t, q = msg.transform.translation, msg.transform.rotation
        elif msgtype == "geometry_msgs/msg/PoseStamped":
            child, t, q = "", msg.pose.position, msg.pose.orientation
        else:  # PoseWithCovarianceStamped
            child, t, q = "", msg.pose.pose.position, msg.pose.pose.orientation
        stamp = _stamp_ns(msg)
        _check_quat(q, f"{self.label}: topic {topic} message at {_fmt(stamp)}")
        if self._pose_samples is None:
            self._pose_samples = _Samples(_frame_name(msg.header.frame_id), _frame_name(child),
                                          f"{topic}")
        self._pose_samples.add(stamp, log, t, q)

    def _check_images(self, rgb: str, depth: str, info_topic: str | None,
                      intrinsics: Intrinsics | None) -> None:
        first_rgb, first_depth = self._msgs[rgb][0], self._msgs[depth][0]
        raw_rgb, raw_depth = self._type_of(rgb) == IMAGE, self._type_of(depth) == IMAGE
        if raw_rgb and first_rgb.encoding.lower() not in COLOR_ENCODINGS:
            raise DataFormatError(f"{self.label}: topic {rgb} has encoding "
                                  f"{first_rgb.encoding}; expected {_COLOR_EXPECTED}")
        if raw_depth and first_depth.encoding.lower() not in DEPTH_ENCODINGS:
            raise DataFormatError(f"{self.label}: topic {depth} has encoding "
                                  f"{first_depth.encoding}; expected {_DEPTH_EXPECTED}")
        if not raw_depth:
            fmt = first_depth.encoding.lower()
            if "rvl" in fmt:
                raise DataFormatError(f"{self.label}: topic {depth} has format "
                                      f"{first_depth.encoding!r} (compressedDepth RVL), which "
                                      f"is not supported; expected compressedDepth PNG")
        if raw_rgb and raw_depth and (first_rgb.width, first_rgb.height) != \
                (first_depth.width, first_depth.height):
            raise DataFormatError(
                f"{self.label}: depth on {depth} is {first_depth.width}x{first_depth.height} "
                f"but colour on {rgb} is {first_rgb.width}x{first_rgb.height}; depth must be "
                f"registered to the colour image (e.g. a depth_registered topic)")
        if intrinsics is not None:
            if not isinstance(intrinsics, Intrinsics):
                raise EvsmapError(f"intrinsics must be Intrinsics, got "
                                  f"{type(intrinsics).__name__}")
            self.intrinsics = intrinsics
            self.meta["intrinsics_source"] = "explicit"
        else:
            info = self._camera_info
            if info is None:
                raise DataFormatError(f"{self.label}: topic {info_topic} has no messages")
            size = (first_rgb.width, first_rgb.height) if raw_rgb else None
            self.intrinsics = self._intrinsics_from(info, info_topic, size)
            self.meta["intrinsics_source"] = f"CameraInfo {info_topic}"
        if raw_rgb and (first_rgb.width, first_rgb.height) != \
                (self.intrinsics.width, self.intrinsics.height):
            raise DataFormatError(
                f"{self.label}: {self.meta['intrinsics_source']} is for "
                f"{self.intrinsics.width}x{self.intrinsics.height} but colour images on {rgb} "
                f"are {first_rgb.width}x{first_rgb.height}")

    def _intrinsics_from(self, info: Any, topic: str,
                         image_size: tuple[int, int] | None) -> Intrinsics:
        k = np.asarray(getattr(info, "k", getattr(info, "K", None)), dtype=np.float64).reshape(-1)
        where = f"{self.label}: topic {topic}"
        if k.size != 9 or not np.all(np.isfinite(k)) or k[0] <= 0 or k[4] <= 0:
            raise DataFormatError(f"{where}: camera matrix K {k.tolist()} is not a valid "
                                  f"pinhole camera")
        bx, by = int(info.binning_x), int(info.binning_y)
        roi = info.roi
        if bx > 1 or by > 1 or (int(roi.width) and int(roi.height) and
                                (int(roi.width), int(roi.height)) !=
                                (int(info.width), int(info.height))):
            raise DataFormatError(f"{where}: binning ({bx}, {by}) or a region of interest "
                                  f"is not supported")
        d = np.asarray(getattr(info, "d", getattr(info, "D", [])), dtype=np.float64)
        if d.size and np.any(d != 0):
            self.meta["distortion_ignored"] = {"model": str(info.distortion_model),
                                               "coefficients": d.tolist()}
        width, height = int(info.width), int(info.height)
        if (width == 0 or height == 0) and image_size is not None:  # size left unset
            width, height = image_size
            self.meta["camera_info_size"] = "0x0 in CameraInfo; the colour image's size used"
        try:
            return Intrinsics(fx=float(k[0]), fy=float(k[4]), cx=float(k[2]), cy=float(k[5]),
                              width=width, height=height)
        except InvalidDataError as exc:
            raise DataFormatError(f"{where}: {exc}") from None

    def _plan(self, limit: int | None) -> None:
        self._plans_for: dict[str, list[_Plan]] = {}
        self._dropped_for: dict[str, dict[str, int]] = {}
        for source in ("header", "bag"):
            plans, dropped = self._plan_frames(source)
            self._plans_for[source] = plans
            self._dropped_for[source] = dropped
        self._limit = limit

    def _plan_frames(self, source: str) -> tuple[list[_Plan], dict[str, int]]:
        def t(m: _Msg) -> int:
            return m.log if source == "bag" else m.stamp

        topics = self.meta["topics"]
        if self.kind == "cloud":
            msgs = sorted(self._msgs[topics["cloud"]], key=lambda m: (t(m), m.log))
            return [_Plan((m,), t(m)) for m in msgs], {}
        rgb = sorted(self._msgs[topics["rgb"]], key=lambda m: (t(m), m.log))
        depth = sorted(self._msgs[topics["depth"]], key=lambda m: (t(m), m.log))
        t_rgb = np.array([t(m) for m in rgb], dtype=np.int64)
        t_depth = np.array([t(m) for m in depth], dtype=np.int64)
        ref = min(t_rgb.min(), t_depth.min())
        pairs = associate((t_depth - ref) * 1e-9, (t_rgb - ref) * 1e-9, self.max_time_difference)
        plans = [_Plan((rgb[j], depth[i]), t(depth[i])) for i, j in pairs]
        return plans, {"depth_without_rgb": len(depth) - len(pairs),
                       "rgb_without_depth": len(rgb) - len(pairs)}

    # -- poses --------------------------------------------------------------------------------
    def _poses(self, pose_topic, use_tf, world_frame, sensor_frame, sensor_offset,
               time_source) -> None:
        if not self._plans_for["header"] and not self._plans_for["bag"]:
            why = self._why_none(self._dropped_for["header"])
            raise DataFormatError(f"{self.label}: no frames ({why})")
        first = self._plans_for["header"][0].msgs[0] if self._plans_for["header"] else \
            self._plans_for["bag"][0].msgs[0]
        sensor = _frame_name(sensor_frame) if sensor_frame else (first.frame_id if first else "")
        self.meta["sensor_frame"] = sensor
        self._sensor_given = bool(sensor_frame)
        offset = None
        if sensor_offset is not None:
            offset = np.asarray(sensor_offset, dtype=np.float64)
            if offset.shape != (4, 4) or not np.all(np.isfinite(offset)):
                raise EvsmapError(f"sensor_offset must be a finite 4x4 matrix, got shape "
                                  f"{offset.shape}")
            u, _, vt = np.linalg.svd(offset[:3, :3])  # re-orthonormalise (rounded calibrations)
            offset = offset.copy()
            offset[:3, :3] = u @ vt
        if use_tf:
            self._setup_tf(world_frame, sensor, sensor_frame)
        else:
            self._setup_odom(pose_topic, sensor, sensor_frame, offset)
        if self.kind == "rgbd" and self.camera_axes == "body":
            self.meta["camera_axes"] = "body (body-to-optical rotation appended)"
        else:
            self.meta["camera_axes"] = "optical" if self.kind == "rgbd" else "sensor"

        chosen, reason = self._choose_time_source(time_source, use_tf)
        self.meta["time_source"] = chosen
        if reason:
            self.meta["time_source_reason"] = reason
            warnings.warn(f"{self.label}: {reason}", stacklevel=4)
        plans = self._plans_for["header" if chosen == "order" else chosen]
        dropped = dict(self._dropped_for["header" if chosen == "order" else chosen])
        if self._limit is not None and len(plans) > self._limit:
            dropped["beyond_limit"] = len(plans) - self._limit
            plans = plans[: self._limit]
        self._frames = plans
        self._resolve(plans, chosen)
        self.meta["dropped"] = dropped
        self.meta["frames_without_pose"] = sum(1 for p in plans if p.pose is None)
        if not plans:
            raise DataFormatError(f"{self.label}: no frames ({self._why_none(dropped)})")

    def _why_none(self, dropped: dict[str, int]) -> str:
        if self.kind == "rgbd":
            return (f"no colour and depth messages within {self.max_time_difference} s of each "
                    f"other: {dropped.get('depth_without_rgb', 0)} depth images unmatched")
        return "no clouds"

    def _setup_tf(self, world_frame, sensor, sensor_frame) -> None:
        tf = self._tf
        option = "sensor_frame" if sensor_frame else "the header frame_id"
        if sensor not in tf.frames():
            raise DataFormatError(
                f"{self.label}: sensor frame {sensor!r} ({option}) is not in /tf or /tf_static "
                f"(frames: {', '.join(sorted(tf.frames())) or 'none'})")
        world = _frame_name(world_frame) if world_frame else tf.root(sensor)
        if world not in tf.frames():
            raise DataFormatError(
                f"{self.label}: world frame {world!r} is not in /tf or /tf_static (frames: "
                f"{', '.join(sorted(tf.frames()))})")
        if tf.chain(world, sensor) is None:
            raise DataFormatError(
                f"{self.label}: no transform chain from {world} to {sensor} in /tf + "
                f"/tf_static ({sensor}'s root is {tf.root(sensor)})")
        self._world, self._sensor = world, sensor
        self.meta["world_frame"] = world
        self.meta["pose_source"] = f"tf {world} -> {sensor}: {tf.describe(world, sensor)}"
        self._pose_mode = "tf"

    def _setup_odom(self, pose_topic, sensor, sensor_frame, offset) -> None:
        samples = self._pose_samples
        if samples is None:
            raise DataFormatError(f"{self.label}: topic {pose_topic} has no messages")
        self._pose_mode = "odom"
        self.meta["world_frame"] = samples.parent
        child = samples.child
        desc = f"{self._type_of(pose_topic).split('/')[-1]} {pose_topic} " \
               f"({samples.parent or '?'} -> {child or '?'})"
        self._offset_static: np.ndarray | None = None
        self._offset_chain: tuple[str, str] | None = None
        if offset is not None:
            self._offset_static = offset
            note = "given (sensor_offset)"
        elif child and child == sensor:
            self._offset_static = np.eye(4)
            note = f"identity ({pose_topic} gives {sensor} itself)"
        elif child and sensor and self._tf.chain(child, sensor) is not None:
            self._offset_chain = (child, sensor)
            note = f"{child} -> {sensor} from /tf: {self._tf.describe(child, sensor)}"
        else:
            self._offset_static = np.eye(4)
            why = f"child_frame_id of {pose_topic} is empty" if not child else \
                f"no transform from {child} to {sensor} in /tf_static or /tf"
            note = f"identity ({why})"
            if child and sensor:
                warnings.warn(f"{self.label}: {note}; poses are those of {child}", stacklevel=5)
        self.meta["sensor_offset"] = note
        self.meta["pose_source"] = f"{desc}, sensor offset {note}"

    def _choose_time_source(self, requested: str, use_tf: bool) -> tuple[str, str]:
        if requested == "order" and use_tf:
            raise EvsmapError("time_source='order' needs a pose topic (odom_topic), not /tf")
        if requested != "auto":
            if requested == "order":
                self._check_order()
            return requested, ""
        header_plans = self._plans_for["header"]
        stamps_zero = all(m.stamp == 0 for p in header_plans for m in p.msgs)
        if not stamps_zero and self._covered(header_plans, "header"):
            return "header", ""
        spans = self._spans()
        if self._covered(self._plans_for["bag"], "bag"):
            why = "frame header stamps are all zero" if stamps_zero else \
                f"frame and pose header stamps do not overlap ({spans})"
            return "bag", f"{why}: frames and poses matched by bag (recording) time"
        if not use_tf and self._pose_samples is not None and \
                len(self._pose_samples.times) == len(header_plans):
            return "order", (f"frame and pose stamps do not overlap in header or bag time "
                             f"({spans}): the k-th frame takes the k-th pose message "
                             f"({len(header_plans)} of each)")
        raise DataFormatError(
            f"{self.label}: frame and pose times do not overlap ({spans}); pass "
            f"time_source='order' (k-th frame with the k-th pose message) or another pose "
            f"source")

    def _check_order(self) -> None:
        n_pose = len(self._pose_samples.times) if self._pose_samples else 0
        n_frames = len(self._plans_for["header"])
        if n_pose < min(n_frames, self._limit or n_frames):
            raise DataFormatError(f"{self.label}: time_source='order' needs a pose message per "
                                  f"frame: {n_frames} frames, {n_pose} pose messages")

    def _spans(self) -> str:
        def span(values: list[int]) -> str:
            return f"{_fmt(min(values))} .. {_fmt(max(values))}" if values else "none"

        frames = [p.time for p in self._plans_for["header"]]
        if self._pose_mode == "odom":
            poses = list(self._pose_samples.times)
        else:
            poses = [t for c in self._tf.dynamic_links(self._world, self._sensor)
                     for t in self._tf.dynamic[c].times]
        return f"frames {span(frames)}, poses {span(poses)}"

    def _covered(self, plans: list[_Plan], source: str) -> bool:
        """Whether some frame has a pose under ``source``."""
        self._set_source(source)
        for plan in plans:
            try:
                self._pose_at(plan)
            except _NoPose:
                continue
            return True
        return not plans

    def _set_source(self, source: str) -> None:
        self._tf.set_source("bag" if source == "bag" else "header")
        if self._pose_samples is not None:
            self._track = self._pose_samples.track("bag" if source == "bag" else "header")

    def _pose_at(self, plan: _Plan, index: int | None = None) -> np.ndarray:
        gap = self.max_pose_gap
        if self._pose_mode == "tf":
            sensor = self._sensor_of(plan)
            pose = self._tf.lookup(self._world, sensor, plan.time, gap)
        else:
            if index is not None:  # time_source "order"
                track = self._track
                pose = pose_matrix(track.trans[index], track.quats[index])
            else:
                pose = self._track.at(plan.time, gap)
            if self._offset_chain is not None:
                child, sensor = self._offset_chain
                pose = pose @ self._tf.lookup(child, sensor, plan.time, gap)
            else:
                pose = pose @ self._offset_static
        if self.kind == "rgbd" and self.camera_axes == "body":
            pose = pose @ BODY_TO_OPTICAL
        return pose

    def _sensor_of(self, plan: _Plan) -> str:
        """The frame's sensor frame: ``sensor_frame``, else its (colour or cloud) header's."""
        sensor = self.meta["sensor_frame"]
        frame = plan.msgs[0].frame_id
        if self._sensor_given or frame == sensor or not frame:
            return sensor
        if frame in self._tf.frames() and self._tf.chain(self._world, frame) is not None:
            return frame
        return sensor

    def _resolve(self, plans: list[_Plan], source: str) -> None:
        self._set_source(source)
        for k, plan in enumerate(plans):
            try:
                pose = self._pose_at(plan, k if source == "order" else None)
            except _NoPose as exc:
                plan.no_pose = str(exc)
                continue
            plan.pose = pose

    # -- access -------------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self._frames)

    def _fetch(self, msgs: tuple[_Msg, ...]) -> list[bytes]:
        """The raw bytes of ``msgs`` (random access by bag time; in-order reads stream)."""
        if self._closed:
            raise EvsmapError(f"{self.label}: the bag was closed")
        want = {(m.conn_key, m.log, m.nth): i for i, m in enumerate(msgs)}
        keys = frozenset(m.conn_key for m in msgs)
        start = min(m.log for m in msgs)
        cur = self._cursor
        if cur is None or cur[1] != keys or start <= cur[2]:
            self._drop_cursor()
            conns = [c for c in self._reader.connections if (c.topic, c.id) in keys]
            cur = (self._reader.messages(connections=conns, start=start), keys, start - 1,
                   Counter())
        gen, _, last, counts = cur
        out: list[bytes | None] = [None] * len(msgs)
        found = 0
        try:
            for conn, log, raw in gen:
                key = (conn.topic, conn.id)
                if log != last:
                    counts.clear()
                    last = log
                nth = counts[key]
                counts[key] += 1
                slot = want.get((key, log, nth))
                if slot is not None:
                    out[slot] = raw
                    found += 1
                    if found == len(msgs):
                        break
        except Exception as exc:
            self._cursor = (gen, keys, last, counts)
            self._drop_cursor()
            raise DataFormatError(f"{self.label}: cannot read messages at bag time "
                                  f"{_fmt(start)} ({exc})") from None
        if found < len(msgs):
            self._cursor = (gen, keys, last, counts)
            self._drop_cursor()
            missing = [m.topic for m, raw in zip(msgs, out, strict=True) if raw is None]
            raise DataFormatError(f"{self.label}: message on {', '.join(missing)} at bag time "
                                  f"{_fmt(start)} not found again (bag changed since opening?)")
        self._cursor = (gen, keys, last, counts)
        return out  # type: ignore[return-value]

    def _drop_cursor(self) -> None:
        cur, self._cursor = getattr(self, "_cursor", None), None
        if cur is not None:
            try:
                cur[0].close()
            except Exception:  # a generator that failed is already finished
                pass

    def frame(self, index: int) -> Frame:
        plan = self._frames[index]
        stamp = f"{plan.time / 1e9:.6f}"
        if plan.pose is None:
            topic = plan.msgs[-1].topic
            raise DataFormatError(f"{self.label}: no pose for the frame on {topic} at stamp "
                                  f"{stamp} s: {plan.no_pose}")
        raws = self._fetch(plan.msgs)
        conns = {(c.topic, c.id): c for c in self._reader.connections}
        decoded = []
        for m, raw in zip(plan.msgs, raws, strict=True):
            where = f"{self.label}: topic {m.topic} at stamp {_fmt(m.stamp)}"
            decoded.append((m, where, self._deserialize(raw, conns[m.conn_key], where)))
        if self.kind == "cloud":
            _, where, msg = decoded[0]
            points, colors = decode_cloud(msg, where)
            return Frame.from_points(points, plan.pose, plan.time / 1e9, colors=colors,
                                     name=stamp)
        (m_rgb, w_rgb, rgb_msg), (m_depth, w_depth, depth_msg) = decoded
        rgb = decode_color_image(rgb_msg, w_rgb) if self._type_of(m_rgb.topic) == IMAGE else \
            decode_compressed_color(rgb_msg, w_rgb)
        depth = decode_depth_image(depth_msg, w_depth) if self._type_of(m_depth.topic) == IMAGE \
            else decode_compressed_depth(depth_msg, w_depth)
        intr = self.intrinsics
        if rgb.shape[:2] != intr.shape:
            raise DataFormatError(f"{w_rgb}: image is {rgb.shape[1]}x{rgb.shape[0]} but the "
                                  f"intrinsics ({self.meta['intrinsics_source']}) are for "
                                  f"{intr.width}x{intr.height}")
        if depth.shape != rgb.shape[:2]:
            raise DataFormatError(f"{w_depth}: depth is {depth.shape[1]}x{depth.shape[0]} but "
                                  f"the colour image on {m_rgb.topic} is "
                                  f"{rgb.shape[1]}x{rgb.shape[0]} (depth must be registered)")
        return Frame(rgb=rgb, depth=depth, intrinsics=intr, pose=plan.pose,
                     timestamp=plan.time / 1e9, name=stamp)

    def close(self) -> None:
        """Close the bag (frames can no longer be read)."""
        if not getattr(self, "_closed", True) and getattr(self, "_reader", None) is not None:
            self._closed = True
            self._drop_cursor()
            try:
                self._reader.close()
            except Exception:  # already closed or half-open
                pass

    def __enter__(self) -> RosbagSequence:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        self.close()


@READERS.register("rosbag", detect=is_rosbag,
                  description="ROS 1 .bag or ROS 2 bag (sqlite3 / MCAP): RGB-D images or "
                              "PointCloud2 with poses from odometry or /tf")
def open_rosbag(*, path: str, preset: str | None = None, rgb_topic: str | None = None,
                depth_topic: str | None = None, camera_info_topic: str | None = None,
                cloud_topic: str | None = None, odom_topic: str | None = None,
                world_frame: str | None = None, sensor_frame: str | None = None,
                max_time_difference: float = 0.02, max_pose_gap: float = 0.1,
                limit: int | None = None, time_source: str = "auto",
                sensor_offset: Any = None, camera_axes: str = "optical",
                intrinsics: Intrinsics | None = None) -> RosbagSequence:
    """ROS 1 .bag or ROS 2 bag (sqlite3 / MCAP): RGB-D images or PointCloud2 with poses.

    Args:
        path: a ``.bag`` file, a ROS 2 bag folder (``metadata.yaml`` + ``.db3``/``.mcap``) or a
            bare ``.db3``/``.mcap`` file.
        preset: topic and frame defaults of a known recording: ``asl`` (voxblox cow and lady),
            ``rtabmap`` (RTAB-Map demo_mapping.bag), ``zed2i`` (ZED ROS wrapper); explicit
            options override it.
        rgb_topic, depth_topic, camera_info_topic: RGB-D input (``Image`` or
            ``CompressedImage``; ``CameraInfo``). Found by message type when omitted.
        cloud_topic: point-cloud input (``PointCloud2``).
        odom_topic: pose topic (``Odometry``, ``TransformStamped``, ``PoseStamped``,
            ``PoseWithCovarianceStamped``).
        world_frame: use ``/tf`` + ``/tf_static`` from this frame to the sensor frame.
        sensor_frame: the frame whose pose a frame takes (default: the message header's).
        max_time_difference: colour-depth association tolerance, seconds.
        max_pose_gap: a frame further than this from the nearest pose sample (of each dynamic
            link) has no pose, seconds.
        limit: keep the first ``limit`` frames.
        time_source: ``header`` stamps, ``bag`` (recording) times, ``order`` (k-th frame with the
            k-th pose message) or ``auto`` (header; bag or order only where header stamps are
            zero or frame and pose clocks do not overlap - recorded in ``meta``).
        sensor_offset: 4x4 pose of the sensor in the pose topic's child frame (overrides /tf).
        camera_axes: ``optical`` (image header frame has OpenCV axes, as ROS optical frames) or
            ``body`` (x forward, y left, z up; the body-to-optical rotation is appended).
        intrinsics: explicit camera parameters instead of the ``CameraInfo``.
    """
    return RosbagSequence(path=path, preset=preset, rgb_topic=rgb_topic, depth_topic=depth_topic,
                          camera_info_topic=camera_info_topic, cloud_topic=cloud_topic,
                          odom_topic=odom_topic, world_frame=world_frame,
                          sensor_frame=sensor_frame, max_time_difference=max_time_difference,
                          max_pose_gap=max_pose_gap, limit=limit, time_source=time_source,
                          sensor_offset=sensor_offset, camera_axes=camera_axes,
                          intrinsics=intrinsics)
