"""Writing a test bag (ROS 1, ROS 2 sqlite3 or MCAP) from queued messages with rosbags' writers;
shared by the reader tests and the bag fuzz targets."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def write_queued(path: Path, fmt: str, typestore: Any, queue: list[tuple], *,
                 compression: str = "lz4") -> Path:
    """Write ``queue`` (``(log_ns, order, topic, msgtype, msg)`` tuples, written in log-time
    order) as a ``fmt`` bag (``ros1``, ``sqlite3`` or ``mcap``) at ``path``; ``compression``:
    ``none``, ``bz2`` or ``lz4`` (ROS 1 only)."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2

    if fmt == "ros1":
        writer = Writer1(path)
        if compression != "none":
            writer.set_compression(Writer1.CompressionFormat[compression.upper()])
    else:
        plugin = StoragePlugin.MCAP if fmt == "mcap" else StoragePlugin.SQLITE3
        writer = Writer2(path, version=9, storage_plugin=plugin)
    conns: dict[tuple[str, str], Any] = {}
    with writer:
        for log, _, topic, msgtype, msg in sorted(queue, key=lambda q: q[:2]):
            if (topic, msgtype) not in conns:
                conns[(topic, msgtype)] = writer.add_connection(topic, msgtype,
                                                                typestore=typestore)
            raw = typestore.serialize_ros1(msg, msgtype) if fmt == "ros1" else \
                typestore.serialize_cdr(msg, msgtype)
            writer.write(conns[(topic, msgtype)], log, raw)
    return path
