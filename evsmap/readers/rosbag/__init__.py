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

The package, by concern: :mod:`.messages` decodes messages into arrays, :mod:`.poses` holds pose
tracks and the TF tree, :mod:`.topics` the presets and topic policy, :mod:`.index` the one-pass
index and frame plans, :mod:`.framepose` the pose and time source of each frame, and
:mod:`.sequence` the :class:`RosbagSequence` that ties them together and the ``rosbag`` reader's
registration (importing this package registers it).
"""

from evsmap.readers.rosbag.messages import (
    CAMERA_INFO,
    CLOUD,
    COLOR_ENCODINGS,
    COMPRESSED,
    DEPTH_ENCODINGS,
    IMAGE,
    ODOMETRY,
    POSE_TYPES,
    TF_TYPES,
    decode_cloud,
    decode_color_image,
    decode_compressed_color,
    decode_compressed_depth,
    decode_depth_image,
)
from evsmap.readers.rosbag.poses import BODY_TO_OPTICAL
from evsmap.readers.rosbag.sequence import RosbagSequence, is_rosbag, open_rosbag
from evsmap.readers.rosbag.topics import PRESETS, TIME_SOURCES

__all__ = [
    "BODY_TO_OPTICAL", "CAMERA_INFO", "CLOUD", "COLOR_ENCODINGS", "COMPRESSED", "DEPTH_ENCODINGS",
    "IMAGE", "ODOMETRY", "POSE_TYPES", "PRESETS", "TF_TYPES", "TIME_SOURCES", "RosbagSequence",
    "decode_cloud", "decode_color_image", "decode_compressed_color", "decode_compressed_depth",
    "decode_depth_image", "is_rosbag", "open_rosbag",
]
