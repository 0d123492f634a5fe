"""The bag's index and frame plans: the mixin of
:class:`~evsmap.readers.rosbag.sequence.RosbagSequence` that reads the needed topics once (header
facts of every frame message, every pose and transform sample, the first ``CameraInfo``), checks
the image topics and builds the intrinsics, and pairs colour with depth into per-frame plans
under header and bag time."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np

from evsmap.data import Intrinsics
from evsmap.errors import DataFormatError, EvsmapError, InvalidDataError
from evsmap.readers.rosbag.messages import (
    _COLOR_EXPECTED,
    _DEPTH_EXPECTED,
    COLOR_ENCODINGS,
    DEPTH_ENCODINGS,
    IMAGE,
    ODOMETRY,
    _fmt,
    _frame_name,
    _stamp_ns,
)
from evsmap.readers.rosbag.poses import _check_quat, _check_translation, _Samples, _TfTree
from evsmap.readers.rosbag.topics import _TopicsMixin
from evsmap.readers.tum import associate


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


class _IndexMixin(_TopicsMixin):
    """Indexing and frame planning for a sequence holding an open ``rosbags`` reader."""

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
        for conn, log, raw in self._messages(self.label, connections=conns):
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
        _check_translation(t, f"{self.label}: topic {topic} message at {_fmt(stamp)}")
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

    def _intrinsics_from(self, info: Any, topic: str | None,
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
