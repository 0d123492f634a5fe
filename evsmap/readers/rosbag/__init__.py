"""ROS bags (ROS 1 ``.bag``, ROS 2 sqlite3 ``.db3`` and MCAP) as evsmap sequences: the reader
package. Importing it registers the ``rosbag`` reader."""

from evsmap.readers.rosbag.sequence import (
    BODY_TO_OPTICAL,
    PRESETS,
    RosbagSequence,
    decode_cloud,
    decode_color_image,
    decode_compressed_color,
    decode_compressed_depth,
    decode_depth_image,
    is_rosbag,
    open_rosbag,
)

__all__ = ["BODY_TO_OPTICAL", "PRESETS", "RosbagSequence", "decode_cloud", "decode_color_image",
           "decode_compressed_color", "decode_compressed_depth", "decode_depth_image",
           "is_rosbag", "open_rosbag"]
