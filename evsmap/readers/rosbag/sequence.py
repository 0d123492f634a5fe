"""The ROS bag reader: :class:`RosbagSequence`, which opens a bag, ties topic selection
(:mod:`.topics`), the index and frame plans (:mod:`.index`) and the frame poses
(:mod:`.framepose`) together at open and reads and decodes one frame's messages on demand
(:mod:`.messages`); bag detection; and :func:`open_rosbag`, registered as the ``rosbag`` reader.
"""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path
from typing import Any

from evsmap.data import Frame, Intrinsics, Sequence
from evsmap.errors import DataFormatError, EvsmapError, InvalidDataError
from evsmap.readers.rosbag.checks import check_bag_folder, check_storage_files
from evsmap.readers.rosbag.framepose import _FramePoseMixin
from evsmap.readers.rosbag.index import _Msg
from evsmap.readers.rosbag.messages import (
    _COLOR_EXPECTED,
    _DEPTH_EXPECTED,
    CAMERA_INFO,
    CLOUD,
    COMPRESSED,
    IMAGE,
    TF_TYPES,
    _fmt,
    _one_line,
    decode_cloud,
    decode_color_image,
    decode_compressed_color,
    decode_compressed_depth,
    decode_depth_image,
)
from evsmap.readers.rosbag.topics import PRESETS, TIME_SOURCES
from evsmap.registry import READERS, Takes


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


class RosbagSequence(_FramePoseMixin, Sequence):
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
        self.folder = bag
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

        if bag.is_dir() and (bag / "metadata.yaml").is_file():
            check_bag_folder(bag)
        check_storage_files(bag)
        try:
            from rosbags.typesys import Stores, get_typestore

            reader = AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
            reader.open()
        except MemoryError:  # a claimed size allocated: not the file's error
            raise
        except Exception as exc:  # rosbags raises its own errors, OSError, YAML errors, ...
            raise DataFormatError(f"{self.label}: not a readable ROS bag "
                                  f"({_one_line(exc)})") from None
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
                color_found, depth_found, _ = self._classify_images()
                wants_images = bool(color_found) and bool(depth_found)
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
        except MemoryError:
            raise
        except Exception as exc:
            self._cursor = (gen, keys, last, counts)
            self._drop_cursor()
            raise DataFormatError(f"{self.label}: cannot read messages at bag time "
                                  f"{_fmt(start)} ({_one_line(exc)})") from None
        if found < len(msgs):
            self._cursor = (gen, keys, last, counts)
            self._drop_cursor()
            missing = [m.topic for m, raw in zip(msgs, out, strict=True) if raw is None]
            raise DataFormatError(f"{self.label}: message on {', '.join(missing)} at bag time "
                                  f"{_fmt(start)} not found again (bag changed since opening?)")
        self._cursor = (gen, keys, last, counts)
        return [raw for raw in out if raw is not None]  # all of them: found == len(msgs)

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
            try:
                return Frame.from_points(points, plan.pose, plan.time / 1e9, colors=colors,
                                         name=stamp)
            except InvalidDataError as exc:
                raise DataFormatError(f"{where}: {_one_line(exc)}") from None
        intr = self.intrinsics
        assert intr is not None  # an rgbd bag's are set up with its topics
        size = (intr.width, intr.height)
        (m_rgb, w_rgb, rgb_msg), (m_depth, w_depth, depth_msg) = decoded
        rgb = decode_color_image(rgb_msg, w_rgb) if self._type_of(m_rgb.topic) == IMAGE else \
            decode_compressed_color(rgb_msg, w_rgb, size)
        depth = decode_depth_image(depth_msg, w_depth) if self._type_of(m_depth.topic) == IMAGE \
            else decode_compressed_depth(depth_msg, w_depth, size)
        if rgb.shape[:2] != intr.shape:
            raise DataFormatError(f"{w_rgb}: image is {rgb.shape[1]}x{rgb.shape[0]} but the "
                                  f"intrinsics ({self.meta['intrinsics_source']}) are for "
                                  f"{intr.width}x{intr.height}")
        if depth.shape != rgb.shape[:2]:
            raise DataFormatError(f"{w_depth}: depth is {depth.shape[1]}x{depth.shape[0]} but "
                                  f"the colour image on {m_rgb.topic} is "
                                  f"{rgb.shape[1]}x{rgb.shape[0]} (depth must be registered)")
        try:
            return Frame(rgb=rgb, depth=depth, intrinsics=intr, pose=plan.pose,
                         timestamp=plan.time / 1e9, name=stamp)
        except InvalidDataError as exc:
            raise DataFormatError(f"{w_rgb}: {_one_line(exc)}") from None

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


@READERS.register("rosbag", takes=Takes(path=True, limit=True), detect=is_rosbag,
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
