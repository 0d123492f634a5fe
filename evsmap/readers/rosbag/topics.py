"""Topic policy: the presets of known recordings, the accepted time sources, and the mixin of
:class:`~evsmap.readers.rosbag.sequence.RosbagSequence` that lists a bag's topics and picks the
one for each role (given, from the preset, or the only candidate of the right type; otherwise a
one-line error naming the candidates), sorts image topics into colour and depth, and chooses the
pose source (a pose topic or ``/tf``)."""

from __future__ import annotations

from collections.abc import Generator, Iterable
from typing import Any, Literal, overload

from evsmap.data import Intrinsics
from evsmap.errors import DataFormatError
from evsmap.readers.rosbag.messages import (
    COLOR_ENCODINGS,
    COMPRESSED,
    DEPTH_ENCODINGS,
    IMAGE,
    POSE_TYPES,
    TF_TYPES,
    _one_line,
)

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


class _TopicsMixin:
    """Topic lookup and selection for a sequence holding an open ``rosbags`` reader
    (``self._reader``), its ``label`` and ``meta``.

    The root of :class:`~evsmap.readers.rosbag.sequence.RosbagSequence`'s mixins: the attributes
    the sequence sets for all of them are declared here (annotations only)."""

    _reader: Any  # rosbags' AnyReader
    label: str
    meta: dict[str, Any]
    kind: str
    camera_axes: str
    max_time_difference: float
    max_pose_gap: float
    intrinsics: Intrinsics | None

    def _topics_of(self, types: Iterable[str]) -> list[str]:
        types = set(types)
        return sorted({c.topic for c in self._reader.connections if c.msgtype in types
                       and c.msgcount != 0})

    def _conns(self, topic: str) -> list[Any]:
        return [c for c in self._reader.connections if c.topic == topic]

    def _type_of(self, topic: str) -> str:
        types = {c.msgtype for c in self._conns(topic)}
        return types.pop() if len(types) == 1 else ""

    def _messages(self, where: str,
                  **selection: Any) -> Generator[tuple[Any, int, bytes], None, None]:
        """The reader's messages; a failure of the bag's storage (a corrupt chunk, index or
        record, a failed decompression: rosbags' errors, OSError, RuntimeError, ...) raises a
        one-line DataFormatError naming ``where``."""
        gen = self._reader.messages(**selection)
        try:
            while True:
                try:
                    item = next(gen)
                except StopIteration:
                    return
                except MemoryError:
                    raise
                except Exception as exc:
                    raise DataFormatError(f"{where}: cannot read the bag's messages "
                                          f"({_one_line(exc)})") from None
                yield item
        finally:
            gen.close()

    def _first(self, topic: str) -> Any:
        where = f"{self.label}: topic {topic}"
        gen = self._messages(where, connections=self._conns(topic))
        try:
            for conn, _, raw in gen:
                return self._deserialize(raw, conn, where)
        finally:
            gen.close()
        return None

    def _deserialize(self, raw: bytes, conn: Any, where: str) -> Any:
        try:
            return self._reader.deserialize(raw, conn.msgtype)
        except MemoryError:
            raise
        except Exception as exc:
            raise DataFormatError(f"{where}: cannot decode the {conn.msgtype} message "
                                  f"({_one_line(exc)})") from None

    @overload
    def _pick(self, role: str, option: str, given: Any, preset: dict, types: tuple[str, ...],
              candidates: list[str] | None = ..., required: Literal[True] = ...) -> str: ...
    @overload
    def _pick(self, role: str, option: str, given: Any, preset: dict, types: tuple[str, ...],
              candidates: list[str] | None = ..., required: bool = ...) -> str | None: ...

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
