"""Fuzz targets for the ROS bag reader (:mod:`evsmap.readers.rosbag`): ROS 1 ``.bag`` bytes (the
real LiDAR bag and small generated bags, with record-aware edits of headers, chunks, index and
connection records), bare ROS 2 ``.db3`` / ``.mcap`` bytes, messages with drawn fields written
into small ROS 1, ROS 2 sqlite3 and MCAP bags (``Image``, ``CompressedImage``, compressedDepth,
``CameraInfo``, ``PointCloud2``, ``TFMessage``, ``Odometry``), a ROS 2 folder's
``metadata.yaml`` (edited lines and bytes, and file paths leaving the folder), and ``evsmap info``
/ ``evsmap map`` on mutated bags. The property is the harness's (tests/fuzz/harness.py)."""

from __future__ import annotations

import functools
import io
import struct
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from evsmap.errors import EvsmapError
from evsmap.registry import READERS
from tests.fuzz.harness import check_cli, check_file, mutated_bytes, text_lines, write_variant
from tests.readers.bag_writing import write_queued

FORMATS = ("ros1", "sqlite3", "mcap")
SUFFIX = {"ros1": ".bag", "sqlite3": "", "mcap": ""}
T0 = 1_000 * 10**9  # first stamp of generated bags, ns
DT = 10**8  # 0.1 s between frames


def _budget(share: float) -> Callable:
    """Run a fraction of the profile's examples (targets that write whole bags are slower)."""
    return settings(max_examples=max(3, int(settings().max_examples * share)))


# --------------------------------------------------------------------------------------------
# Writing small bags (the ideas of tests/readers/test_rosbag.py, with every field drawable)
# --------------------------------------------------------------------------------------------


@functools.cache
def _typestore(fmt: str) -> Any:
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    if fmt == "ros1":
        ts = get_typestore(Stores.ROS1_NOETIC)
        ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms",
                                       "tf2_msgs/msg/TFMessage"))
        return ts
    return get_typestore(Stores.ROS2_HUMBLE)


class Bag:
    """Messages queued by topic and bag time, written in time order on :meth:`close`."""

    def __init__(self, path: Path, fmt: str, compression: str = "lz4") -> None:
        self.path, self.fmt, self.compression = Path(path), fmt, compression
        self.ts = _typestore(fmt)
        self.queue: list[tuple[int, int, str, str, Any]] = []

    def make(self, msgtype: str, **fields: Any) -> Any:
        names = {n.lower(): n for n, _ in self.ts.fielddefs[msgtype][1]}
        return self.ts.types[msgtype](**{names[k.lower()]: v for k, v in fields.items()})

    def header(self, stamp: int, frame: str) -> Any:
        sec, nsec = divmod(stamp, 10**9)
        time = self.make("builtin_interfaces/msg/Time", sec=sec, nanosec=nsec)
        if self.fmt == "ros1":
            return self.make("std_msgs/msg/Header", seq=0, stamp=time, frame_id=frame)
        return self.make("std_msgs/msg/Header", stamp=time, frame_id=frame)

    def add(self, topic: str, msgtype: str, msg: Any, log: int) -> None:
        self.queue.append((log, len(self.queue), topic, msgtype, msg))

    def vec(self, kind: str, v: Any) -> Any:
        names = ("x", "y", "z", "w")[: len(v)]
        return self.make(kind, **dict(zip(names, (float(x) for x in v), strict=True)))

    def transform(self, stamp: int, parent: str, child: str, t: Any, q: Any) -> Any:
        return self.make("geometry_msgs/msg/TransformStamped",
                         header=self.header(stamp, parent), child_frame_id=child,
                         transform=self.make("geometry_msgs/msg/Transform",
                                             translation=self.vec("geometry_msgs/msg/Vector3", t),
                                             rotation=self.vec("geometry_msgs/msg/Quaternion",
                                                               q)))

    def tf(self, topic: str, transforms: list[Any], log: int) -> None:
        self.add(topic, "tf2_msgs/msg/TFMessage",
                 self.make("tf2_msgs/msg/TFMessage", transforms=transforms), log)

    def odometry(self, topic: str, stamp: int, parent: str, child: str, t: Any, q: Any,
                 log: int | None = None) -> None:
        zero = self.vec("geometry_msgs/msg/Vector3", (0, 0, 0))
        msg = self.make(
            "nav_msgs/msg/Odometry", header=self.header(stamp, parent), child_frame_id=child,
            pose=self.make("geometry_msgs/msg/PoseWithCovariance",
                           pose=self.make("geometry_msgs/msg/Pose",
                                          position=self.vec("geometry_msgs/msg/Point", t),
                                          orientation=self.vec("geometry_msgs/msg/Quaternion",
                                                               q)),
                           covariance=np.zeros(36)),
            twist=self.make("geometry_msgs/msg/TwistWithCovariance",
                            twist=self.make("geometry_msgs/msg/Twist", linear=zero,
                                            angular=zero), covariance=np.zeros(36)))
        self.add(topic, "nav_msgs/msg/Odometry", msg, stamp + 300 if log is None else log)

    def image(self, topic: str, stamp: int, frame: str, *, width: int, height: int,
              encoding: str, step: int, data: bytes, big: int = 0) -> None:
        msg = self.make("sensor_msgs/msg/Image", header=self.header(stamp, frame), height=height,
                        width=width, encoding=encoding, is_bigendian=big, step=step,
                        data=np.frombuffer(data, np.uint8).copy())
        self.add(topic, "sensor_msgs/msg/Image", msg, stamp + 1000)

    def compressed(self, topic: str, stamp: int, frame: str, data: bytes, fmt: str) -> None:
        msg = self.make("sensor_msgs/msg/CompressedImage", header=self.header(stamp, frame),
                        format=fmt, data=np.frombuffer(data, np.uint8).copy())
        self.add(topic, "sensor_msgs/msg/CompressedImage", msg, stamp + 1000)

    def camera_info(self, topic: str, stamp: int, frame: str, *, width: int, height: int,
                    k: Any, d: Any = (), binning: tuple[int, int] = (0, 0),
                    roi: tuple[int, int] = (0, 0)) -> None:
        region = self.make("sensor_msgs/msg/RegionOfInterest", x_offset=0, y_offset=0,
                           height=roi[1], width=roi[0], do_rectify=False)
        msg = self.make("sensor_msgs/msg/CameraInfo", header=self.header(stamp, frame),
                        height=height, width=width, distortion_model="plumb_bob",
                        d=np.asarray(d, np.float64), k=np.asarray(k, np.float64),
                        r=np.eye(3).reshape(-1), p=np.zeros(12), binning_x=binning[0],
                        binning_y=binning[1], roi=region)
        self.add(topic, "sensor_msgs/msg/CameraInfo", msg, stamp + 500)

    def cloud(self, topic: str, stamp: int, frame: str, *, fields: list[tuple[str, int, int, int]],
              point_step: int, row_step: int, width: int, height: int, data: bytes,
              big: int = 0) -> None:
        pfs = [self.make("sensor_msgs/msg/PointField", name=n, offset=o, datatype=d, count=c)
               for n, o, d, c in fields]
        msg = self.make("sensor_msgs/msg/PointCloud2", header=self.header(stamp, frame),
                        height=height, width=width, fields=pfs, is_bigendian=bool(big),
                        point_step=point_step, row_step=row_step,
                        data=np.frombuffer(data, np.uint8).copy(), is_dense=False)
        self.add(topic, "sensor_msgs/msg/PointCloud2", msg, stamp + 1000)

    def close(self) -> Path:
        return write_queued(self.path, self.fmt, self.ts, self.queue,
                            compression=self.compression)


IDENTITY_Q = (0.0, 0.0, 0.0, 1.0)


def _cloud_data(n: int, rng: np.random.Generator) -> tuple[list, int, bytes]:
    rec = np.zeros(n, dtype=np.dtype({"names": ["x", "y", "z", "rgb"],
                                      "formats": ["<f4", "<f4", "<f4", "<u4"],
                                      "offsets": [0, 4, 8, 16], "itemsize": 20}))
    pts = rng.normal(size=(n, 3)).astype(np.float32)
    rec["x"], rec["y"], rec["z"] = pts.T
    rec["rgb"] = rng.integers(0, 2**24, n, dtype=np.uint32)
    return [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("rgb", 16, 7, 1)], 20, rec.tobytes()


def _cloud_bag(folder: Path, fmt: str, compression: str = "lz4", frames: int = 3) -> Path:
    """Point clouds + odometry + a static sensor link in /tf_static."""
    rng = np.random.default_rng(1)
    bag = Bag(folder / f"cloud_{fmt}_{compression}{SUFFIX[fmt]}", fmt, compression)
    fields, step, data = _cloud_data(30, rng)
    for k in range(frames):
        t = T0 + k * DT
        bag.cloud("/points", t, "lidar", fields=fields, point_step=step, row_step=step * 30,
                  width=30, height=1, data=data)
    bag.tf("/tf_static", [bag.transform(T0, "base", "lidar", (0, 0, 1), IDENTITY_Q)], T0 - 10)
    for k in range(-1, frames + 1):
        t = T0 + k * DT
        bag.odometry("/odom", t, "odom", "base", (k * 0.5, 0, 0), IDENTITY_Q)
    return bag.close()


# --------------------------------------------------------------------------------------------
# Reading a bag as evsmap does, and the property for every frame
# --------------------------------------------------------------------------------------------


def _well_formed(exc: EvsmapError, names: tuple[str, ...]) -> None:
    text = str(exc)
    if "\n" in text.strip() or not text.strip() or not any(n and n in text for n in names):
        raise AssertionError(f"frame error is not one line naming one of {names}: {text!r}")


def _read(path: Path, names: tuple[str, ...] = (), max_frames: int = 5, **options: Any) -> int:
    """Open ``path`` with the registered ``rosbag`` reader and read up to ``max_frames`` frames;
    a frame's own error (one line naming the bag) does not stop the others."""
    names = names + (Path(path).name,)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        seq = READERS.create("rosbag", path=str(path), **options)
        try:
            read = 0
            for i in range(min(len(seq), max_frames)):
                try:
                    seq.frame(i)
                    read += 1
                except EvsmapError as exc:
                    _well_formed(exc, names)
            return read
        finally:
            seq.close()


# --------------------------------------------------------------------------------------------
# 1. ROS 1 bag bytes
# --------------------------------------------------------------------------------------------


def _records(data: bytes, pos: int = 13, stop: int | None = None
             ) -> list[tuple[int, int, int, int]]:
    """(start, header length, data length, end) of each record of a ROS 1 bag (or of the
    records inside an uncompressed chunk's data, from ``pos`` to ``stop``)."""
    out = []
    stop = len(data) if stop is None else stop
    while pos + 8 <= stop:
        hlen = struct.unpack_from("<I", data, pos)[0]
        if pos + 8 + hlen > len(data):
            break
        dlen = struct.unpack_from("<I", data, pos + 4 + hlen)[0]
        end = min(pos + 8 + hlen + dlen, stop)
        out.append((pos, hlen, dlen, end))
        pos = end
    return out


def _fields(data: bytes, start: int, hlen: int) -> list[tuple[bytes, int, int]]:
    """(name, value offset, value length) of a record header's fields."""
    out, pos, end = [], start + 4, start + 4 + hlen
    while pos + 4 <= end:
        flen = struct.unpack_from("<I", data, pos)[0]
        field = data[pos + 4: pos + 4 + flen]
        eq = field.find(b"=")
        if eq > 0:  # (a corrupt length may claim more than the file has)
            out.append((field[:eq], pos + 4 + eq + 1, len(field) - eq - 1))
        pos += 4 + flen
    return out


class Blob(bytes):
    """A bag's bytes with a short repr (hypothesis prints a failing example: a whole bag's repr
    runs to tens of MB; reproduce it with the printed @reproduce_failure)."""

    def __repr__(self) -> str:
        import hashlib

        return f"<{len(self)} bytes, sha1 {hashlib.sha1(self).hexdigest()[:12]}>"


_SPECIAL = [0, 1, 2, 7, 255, 2**16, 2**31 - 1, 2**31, 2**32 - 1, 2**32, 2**63 - 1, 2**64 - 1]


@st.composite
def ros1_variant(draw: st.DrawFn, data: bytes) -> bytes:
    """A ROS 1 bag with 1..3 edits aware of its records: a header field's value (sizes,
    positions, counts, connection ids, times, the compression name) replaced, a record's
    length fields overwritten, a record's first bytes mutated, a record dropped or duplicated, or
    plain byte mutations."""
    out = bytearray(data)
    for _ in range(draw(st.integers(1, 3))):
        recs = _records(bytes(out))
        op = draw(st.sampled_from(["field", "length", "record", "drop", "dup", "bytes",
                                   "message"]))
        if not recs or op == "bytes":
            out = bytearray(draw(mutated_bytes(bytes(out), max_ops=2)))
            continue
        start, hlen, dlen, end = draw(st.sampled_from(recs))
        if op == "message":  # a message's first bytes, inside an uncompressed chunk
            inner = [r for c in recs if _is_plain_chunk(bytes(out), c)
                     for r in _records(bytes(out), c[0] + 8 + c[1], c[3])]
            if not inner:
                continue
            start, hlen, dlen, end = draw(st.sampled_from(inner))
            body = start + 8 + hlen
            head = min(end, body + 256)
            out[body:head] = draw(mutated_bytes(bytes(out[body:head]), max_ops=2)).ljust(
                head - body, b"\0")[: head - body]
        elif op == "field":
            fields = _fields(bytes(out), start, hlen)
            if not fields:
                continue
            name, off, size = draw(st.sampled_from(fields))
            if size in (1, 4, 8):
                value = draw(st.one_of(st.sampled_from(_SPECIAL),
                                       st.integers(0, 2 ** (8 * size) - 1),
                                       st.just(len(out))))
                out[off: off + size] = (value % 2 ** (8 * size)).to_bytes(size, "little")
            else:  # a string (compression, topic, type, md5sum, definition): same length
                text = draw(st.sampled_from(["none", "bz2", "lz4", "zstd", "", "x" * size]))
                out[off: off + size] = text.encode().ljust(size, b"\0")[:size]
        elif op == "length":
            where = draw(st.sampled_from([start, start + 4 + hlen]))
            value = draw(st.one_of(st.sampled_from(_SPECIAL[:9]), st.integers(0, len(out))))
            out[where: where + 4] = (value % 2**32).to_bytes(4, "little")
        elif op == "record":
            head = min(end, start + 8 + hlen + 512)
            out[start:head] = draw(mutated_bytes(bytes(out[start:head]), max_ops=2))
        elif op == "drop":
            del out[start:end]
        else:
            out[end:end] = out[start:end]
    return Blob(out)


def _is_plain_chunk(data: bytes, record: tuple[int, int, int, int]) -> bool:
    fields = {n: data[o: o + k] for n, o, k in _fields(data, record[0], record[1])}
    return fields.get(b"op") == b"\x05" and fields.get(b"compression") == b"none"


@functools.cache
def _real_bag_uncompressed() -> bytes:
    """The real bag's messages rewritten in uncompressed chunks (so message edits survive)."""
    import tempfile

    from rosbags.rosbag1 import Reader, Writer

    with tempfile.TemporaryDirectory() as tmp:
        dst = Path(tmp) / "plain.bag"
        with Reader(_real_bag_path()) as reader, \
                Writer(dst) as writer:
            conns = {c.id: writer.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data,
                                                 md5sum=c.digest, callerid=c.ext.callerid,
                                                 latching=c.ext.latching)
                     for c in reader.connections}
            for conn, stamp, raw in reader.messages():
                writer.write(conns[conn.id], stamp, raw)
        return dst.read_bytes()


def _real_bag_path() -> Path:
    from evsmap.testing import require_sample

    return require_sample("lidar-odometry-bag")


@functools.cache
def _real_bag() -> bytes:
    return _real_bag_path().read_bytes()


def test_fuzz_ros1_real_bag(tmp_path_factory):
    """The real bag as recorded (LZ4 chunks) and rewritten uncompressed (message edits)."""
    variants = [ros1_variant(_real_bag()), ros1_variant(_real_bag_uncompressed())]
    folder = tmp_path_factory.mktemp("ros1_real")

    @given(st.one_of(variants))
    def inner(variant):
        path = write_variant(folder / "lidar_odometry.bag", variant)
        check_file("rosbag/ros1-real-bytes", lambda: _read(path), path)

    inner()


@functools.cache
def _small_bag_bytes(compression: str) -> bytes:
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        return _cloud_bag(Path(tmp), "ros1", compression).read_bytes()


def test_fuzz_ros1_small_bags(tmp_path_factory):
    folder = tmp_path_factory.mktemp("ros1_small")
    variants = {c: ros1_variant(_small_bag_bytes(c)) for c in ("none", "bz2", "lz4")}

    @given(st.sampled_from(sorted(variants)).flatmap(lambda c: variants[c]))
    def inner(variant):
        path = write_variant(folder / "small.bag", variant)
        check_file("rosbag/ros1-small-bytes", lambda: _read(path), path)

    inner()


@functools.cache
def _ros2_file_bytes(fmt: str) -> bytes:
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        folder = _cloud_bag(Path(tmp), fmt)
        return next(folder.glob("*.mcap" if fmt == "mcap" else "*.db3")).read_bytes()


def test_fuzz_ros2_storage_files(tmp_path_factory):
    """Bare ``.db3`` and ``.mcap`` files (the readers also open them without a folder)."""
    folder = tmp_path_factory.mktemp("ros2_files")
    variants = {f: mutated_bytes(_ros2_file_bytes(f)) for f in ("sqlite3", "mcap")}

    @given(st.sampled_from(sorted(variants)).flatmap(
        lambda f: st.tuples(st.just(f), variants[f])))
    def inner(case):
        fmt, variant = case
        path = write_variant(folder / ("bag.mcap" if fmt == "mcap" else "bag.db3"), variant)
        check_file("rosbag/ros2-storage-bytes", lambda: _read(path), path)

    inner()


# --------------------------------------------------------------------------------------------
# 2. Messages with drawn fields
# --------------------------------------------------------------------------------------------

COLOR = "/cam/color/image_raw"
DEPTH = "/cam/depth/image_raw"
INFO = "/cam/color/camera_info"
CAM = "cam_optical"
ENCODINGS = ["16UC1", "32FC1", "mono16", "rgb8", "bgr8", "rgba8", "bgra8", "mono8", "yuv422",
             "RGB8", "", "8UC3", "bayer_rggb8", "32FC1 ", "64FC1"]
COLOR_ENCODINGS = ["rgb8", "bgr8", "rgba8", "bgra8", "mono8"]
DEPTH_ENCODINGS = ["16UC1", "32FC1", "mono16"]
BPP = {"16uc1": 2, "mono16": 2, "32fc1": 4, "rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4,
       "mono8": 1, "yuv422": 2}


@st.composite
def image_fields(draw: st.DrawFn, encodings: list[str]) -> dict[str, Any]:
    """An ``Image``'s fields: mostly consistent small images, sometimes a wrong step, data
    length or endianness, an odd encoding, or a huge claimed size with little data."""
    enc = draw(st.sampled_from(encodings))
    bpp = BPP.get(enc.lower(), draw(st.integers(1, 4)))
    w, h = draw(st.sampled_from([(6, 5), (6, 5), (0, 5), (1, 1)])) if draw(st.booleans()) \
        else (draw(st.integers(0, 6)), draw(st.integers(0, 5)))
    if draw(st.integers(0, 5)) == 0:
        w, h = draw(st.sampled_from([(10**5, 10**5), (2**32 - 1, 2), (1, 2**32 - 1),
                                     (70_000, 70_000), (2**31, 2**31)]))
    step = w * bpp + draw(st.sampled_from([0, 0, 0, 1, 3, -1, -w * bpp, 2**32]))
    step = max(0, min(step, 2**32 - 1))
    size = min(step * h, 4096) + draw(st.sampled_from([0, 0, 0, 1, -1, -7, 64]))
    size = max(0, size)
    payload = draw(st.sampled_from(["random", "nan", "zeros"]))
    if payload == "nan":
        data = (np.full(size // 4 + 1, np.nan, "<f4").tobytes())[:size]
    elif payload == "zeros":
        data = bytes(size)
    else:
        data = draw(st.binary(min_size=min(size, 64), max_size=min(size, 64)))
        data = (data * (size // max(len(data), 1) + 1))[:size] if data else bytes(size)
    return {"width": w, "height": h, "encoding": enc, "step": step, "data": data,
            "big": draw(st.sampled_from([0, 1, 0, 255]))}


def _rgbd_bag(path: Path, fmt: str, color: Callable[[Bag, int], None],
              depth: Callable[[Bag, int], None], *, size: tuple[int, int],
              info: Callable[[Bag], None] | None = None, poses: str = "odom",
              frames: int = 2) -> Path:
    bag = Bag(path, fmt)
    for k in range(frames):
        color(bag, T0 + k * DT)
        depth(bag, T0 + k * DT)
    if info is None:
        w, h = size
        bag.camera_info(INFO, T0, CAM, width=w, height=h,
                        k=[500.0, 0, w / 2, 0, 500.0, h / 2, 0, 0, 1])
    else:
        info(bag)
    for k in range(-1, frames + 1):
        t = T0 + k * DT
        if poses == "odom":
            bag.odometry("/odom", t, "world", CAM, (k * 0.1, 0, 0), IDENTITY_Q)
        else:
            bag.tf("/tf", [bag.transform(t, "world", CAM, (k * 0.1, 0, 0), IDENTITY_Q)], t + 200)
    return bag.close()


def _fmt_strategy() -> st.SearchStrategy[str]:
    return st.sampled_from(FORMATS)


def test_fuzz_image_messages(tmp_path_factory):
    folder = tmp_path_factory.mktemp("images")
    counter = iter(range(10**9))

    @given(_fmt_strategy(), image_fields(COLOR_ENCODINGS * 3 + ENCODINGS),
           image_fields(DEPTH_ENCODINGS * 3 + ENCODINGS), st.booleans())
    def inner(fmt, rgb, dep, explicit):
        path = folder / f"img{next(counter)}{SUFFIX[fmt]}"
        _rgbd_bag(path, fmt, lambda b, t: b.image(COLOR, t, CAM, **rgb),
                  lambda b, t: b.image(DEPTH, t, CAM, **dep),
                  size=(rgb["width"], rgb["height"]))
        options = {"rgb_topic": COLOR, "depth_topic": DEPTH} if explicit else {}
        check_file("rosbag/image", lambda: _read(path, (COLOR, DEPTH), **options), path)

    inner()


def _png(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(array).save(buf, format="PNG")
    return buf.getvalue()


def _jpeg(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(array).save(buf, format="JPEG")
    return buf.getvalue()


def _png_header_claiming(width: int, height: int, mode: int = 2, depth: int = 8) -> bytes:
    """A PNG whose IHDR claims ``width`` x ``height`` with one tiny IDAT (a decompression bomb's
    header without its body)."""
    import zlib

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + \
            struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", width, height, depth, mode, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + \
        chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b"")


_RNG = np.random.default_rng(7)
_RGB = _RNG.integers(0, 256, (5, 6, 3), dtype=np.uint8)
_DEPTH16 = _RNG.integers(0, 5000, (5, 6), dtype=np.uint16)
PAYLOADS = {
    "png": _png(_RGB), "jpeg": _jpeg(_RGB), "png16": _png(_DEPTH16),
    "png8grey": _png(_RGB[..., 0]), "png-rgba": _png(np.dstack([_RGB, _RGB[..., :1]])),
    "png-other-size": _png(_RGB[:3, :4]), "empty": b"",
    "png-huge": _png_header_claiming(100_000, 100_000),
    "png-huge16": _png_header_claiming(30_000, 30_000, mode=0, depth=16),
    "png-big": _png_header_claiming(5_000, 4_000),
    "gif": b"GIF89a" + bytes(20),
}


@st.composite
def payload(draw: st.DrawFn) -> bytes:
    data = PAYLOADS[draw(st.sampled_from(sorted(PAYLOADS)))]
    edit = draw(st.sampled_from(["as-is", "as-is", "truncate", "mutate", "random"]))
    if edit == "truncate" and data:
        return data[: draw(st.integers(0, len(data) - 1))]
    if edit == "mutate":
        return draw(mutated_bytes(data, max_ops=2))
    if edit == "random":
        return draw(st.binary(max_size=200))
    return data


COLOR_FORMATS = ["rgb8; jpeg compressed bgr8", "png", "jpeg", "", "bgr8; png compressed bgr8",
                 "16UC1; compressedDepth", "rvl", "32FC1", "x" * 300]


def test_fuzz_compressed_color(tmp_path_factory):
    folder = tmp_path_factory.mktemp("compressed")
    counter = iter(range(10**9))

    @given(_fmt_strategy(), st.sampled_from(COLOR_FORMATS), payload(), payload())
    def inner(fmt, fmt_str, first, second):
        path = folder / f"cc{next(counter)}{SUFFIX[fmt]}"
        frames = iter([first, second])
        depth_png = bytes(12) + _png(_DEPTH16)
        _rgbd_bag(path, fmt, lambda b, t: b.compressed(COLOR + "/compressed", t, CAM,
                                                       next(frames), fmt_str),
                  lambda b, t: b.compressed(DEPTH + "/compressedDepth", t, CAM, depth_png,
                                            "16UC1; compressedDepth"), size=(6, 5))
        check_file("rosbag/compressed-image", lambda: _read(
            path, (COLOR, DEPTH), rgb_topic=COLOR + "/compressed",
            depth_topic=DEPTH + "/compressedDepth"), path)

    inner()


DEPTH_FORMATS = ["16UC1; compressedDepth", "32FC1; compressedDepth", "32FC1; compressedDepth png",
                 "16UC1; compressedDepth rvl", "mono16; compressedDepth", "8UC1; compressedDepth",
                 "compressedDepth", "16UC1", "png", "32FC1", ""]
QUANT = [100.0 * 101.0, 1.0 - 10100.0 / 10.0, 0.0, -1.0, float("nan"), float("inf"),
         float("-inf"), 1e-45, 3.4e38]


@st.composite
def depth_payload(draw: st.DrawFn) -> bytes:
    kind = draw(st.sampled_from(["header+png", "png", "short-header", "bad-header"]))
    png = draw(payload()) if draw(st.booleans()) else PAYLOADS["png16"]
    if kind == "png":
        return png
    a, b = draw(st.sampled_from(QUANT)), draw(st.sampled_from(QUANT))
    header = struct.pack("<iff", draw(st.sampled_from([0, 1, -1, 2**31 - 1])), a, b)
    if kind == "short-header":
        header = header[: draw(st.integers(0, 11))]
    elif kind == "bad-header":
        header = draw(st.binary(min_size=12, max_size=12))
    return header + png


def test_fuzz_compressed_depth(tmp_path_factory):
    folder = tmp_path_factory.mktemp("compressed_depth")
    counter = iter(range(10**9))

    @given(_fmt_strategy(), st.sampled_from(DEPTH_FORMATS), depth_payload(), depth_payload())
    def inner(fmt, fmt_str, first, second):
        path = folder / f"cd{next(counter)}{SUFFIX[fmt]}"
        frames = iter([first, second])
        _rgbd_bag(path, fmt, lambda b, t: b.compressed(COLOR + "/compressed", t, CAM,
                                                       PAYLOADS["png"], "png"),
                  lambda b, t: b.compressed(DEPTH + "/compressedDepth", t, CAM, next(frames),
                                            fmt_str), size=(6, 5))
        check_file("rosbag/compressed-depth", lambda: _read(
            path, (COLOR, DEPTH), rgb_topic=COLOR + "/compressed",
            depth_topic=DEPTH + "/compressedDepth"), path)

    inner()


FLOATS = st.one_of(st.sampled_from([0.0, -0.0, 1.0, -1.0, float("nan"), float("inf"),
                                    float("-inf"), 1e-300, 1e300, 500.0, 3.0]),
                   st.floats(-1e4, 1e4))


def test_fuzz_camera_info(tmp_path_factory):
    folder = tmp_path_factory.mktemp("camera_info")
    counter = iter(range(10**9))

    @given(_fmt_strategy(), st.one_of(
        st.just([500.0, 0, 3, 0, 500.0, 2.5, 0, 0, 1]),
        st.tuples(st.integers(0, 8), FLOATS).map(
            lambda e: [500.0, 0, 3, 0, 500.0, 2.5, 0, 0, 1][: e[0]] + [e[1]] +
            [500.0, 0, 3, 0, 500.0, 2.5, 0, 0, 1][e[0] + 1:]),
        st.lists(FLOATS, min_size=9, max_size=9)),
           st.sampled_from([(6, 5), (0, 0), (0, 5), (5, 6), (2**32 - 1, 2**32 - 1), (1, 1)]),
           st.lists(FLOATS, max_size=14),
           st.sampled_from([(0, 0), (0, 0), (1, 1), (2, 2), (0, 3)]),
           st.sampled_from([(0, 0), (0, 0), (6, 5), (3, 2), (0, 5)]))
    def inner(fmt, k, size, d, binning, roi):
        path = folder / f"ci{next(counter)}{SUFFIX[fmt]}"
        _rgbd_bag(path, fmt,
                  lambda b, t: b.image(COLOR, t, CAM, width=6, height=5, encoding="rgb8",
                                       step=18, data=_RGB.tobytes()),
                  lambda b, t: b.image(DEPTH, t, CAM, width=6, height=5, encoding="16UC1",
                                       step=12, data=_DEPTH16.tobytes()),
                  size=(6, 5),
                  info=lambda b: b.camera_info(INFO, T0, CAM, width=size[0], height=size[1],
                                               k=k, d=d, binning=binning, roi=roi),
                  poses="tf")
        check_file("rosbag/camera-info", lambda: _read(path, (COLOR, DEPTH, INFO)), path)

    inner()


FIELD_NAMES = ["x", "y", "z", "rgb", "rgba", "r", "g", "b", "intensity", ""]


@st.composite
def cloud_fields(draw: st.DrawFn) -> dict[str, Any]:
    """A ``PointCloud2``'s layout and data: fields with drawn offsets, datatypes and counts,
    point_step/row_step consistent or not, data shorter or longer than claimed, and sometimes a
    header claiming 10^9 points."""
    good = [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("rgb", 16, 7, 1)]
    if draw(st.booleans()):
        fields = good
    else:
        fields = draw(st.lists(st.tuples(st.sampled_from(FIELD_NAMES), st.integers(0, 40),
                                         st.sampled_from([0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 255]),
                                         st.sampled_from([0, 1, 1, 3])),
                               max_size=7))
        if draw(st.booleans()):
            fields = good[:3] + fields
    step = draw(st.sampled_from([20, 20, 0, 1, 4, 11, 12, 16, 24, 32, 2**32 - 1]))
    w, h = draw(st.integers(0, 12)), draw(st.integers(0, 3))
    if draw(st.integers(0, 5)) == 0:
        w, h = draw(st.sampled_from([(10**9, 1), (10**5, 10**4), (2**32 - 1, 2**32 - 1),
                                     (1, 10**9)]))
    row_step = draw(st.sampled_from([w * step, w * step, 0, w * step + 3, max(0, w * step - 1),
                                     2**32 - 1]))
    row_step = min(row_step, 2**32 - 1)
    size = min(row_step * h, 4096) + draw(st.sampled_from([0, 0, -1, -20, 8]))
    fill = draw(st.sampled_from(["normal", "nan", "inf", "random"]))
    n = max(0, size) // 4 + 1
    if fill == "random":
        raw = draw(st.binary(min_size=8, max_size=8)) * (n // 2 + 1)
    else:
        vals = {"normal": np.linspace(-3, 3, n), "nan": np.full(n, np.nan),
                "inf": np.full(n, np.inf)}[fill]
        raw = vals.astype("<f4").tobytes()
    return {"fields": fields, "point_step": step, "row_step": row_step, "width": w,
            "height": h, "data": raw[: max(0, size)],
            "big": draw(st.sampled_from([0, 0, 1]))}


def test_fuzz_pointcloud2(tmp_path_factory):
    folder = tmp_path_factory.mktemp("clouds")
    counter = iter(range(10**9))

    @given(_fmt_strategy(), cloud_fields(), cloud_fields())
    def inner(fmt, first, second):
        path = folder / f"pc{next(counter)}{SUFFIX[fmt]}"
        bag = Bag(path, fmt)
        for k, cloud in enumerate((first, second)):
            bag.cloud("/points", T0 + k * DT, "lidar", **cloud)
        for k in range(-1, 3):
            bag.odometry("/odom", T0 + k * DT, "odom", "lidar", (k, 0, 0), IDENTITY_Q)
        bag.close()
        check_file("rosbag/pointcloud2", lambda: _read(path, ("/points",)), path)

    inner()


FRAMES = ["world", "odom", "base", "lidar", "/base", "", "cam"]
QUATS = st.one_of(st.just(IDENTITY_Q), st.just((0.0, 0.0, 0.3827, 0.9239)),
                  st.sampled_from([IDENTITY_Q, (0.0, 0.0, 0.0, 0.0), (float("nan"), 0, 0, 1),
                                   (0, 0, 0, float("inf")), (1e-300, 0, 0, 0),
                                   (1e300, 1e300, 0, 0), (0, 0, 0.7071, 0.7071)]),
                  st.tuples(FLOATS, FLOATS, FLOATS, FLOATS))
VECS = st.one_of(st.just((0.0, 0.0, 0.0)), st.just((1.0, -2.0, 0.5)),
                 st.tuples(FLOATS, FLOATS, FLOATS))
STAMPS = st.one_of(st.integers(-3, 3).map(lambda k: T0 + k * DT),
                   st.sampled_from([0, 1, T0 + DT // 2, (2**31 - 1) * 10**9, T0 + 10**9]))


@st.composite
def transforms(draw: st.DrawFn) -> list[tuple[str, int, str, str, Any, Any]]:
    """(topic, stamp, parent, child, translation, rotation) links: chains, loops, frames that
    never connect, NaN and zero quaternions, far stamps."""
    out = []
    clean = draw(st.booleans())  # only the graph and the stamps are odd
    for _ in range(draw(st.integers(0, 8))):
        out.append((draw(st.sampled_from(["/tf", "/tf", "/tf_static"])), draw(STAMPS),
                    draw(st.sampled_from(FRAMES)), draw(st.sampled_from(FRAMES)),
                    (0.5, 0.0, 0.0) if clean else draw(VECS),
                    IDENTITY_Q if clean else draw(QUATS)))
    return out


def _cloud_frames(bag: Bag, frame: str, n: int = 2) -> None:
    fields, step, data = _cloud_data(10, np.random.default_rng(2))
    for k in range(n):
        bag.cloud("/points", T0 + k * DT, frame, fields=fields, point_step=step,
                  row_step=step * 10, width=10, height=1, data=data)


def test_fuzz_tf(tmp_path_factory):
    folder = tmp_path_factory.mktemp("tf")
    counter = iter(range(10**9))

    @given(_fmt_strategy(), transforms(), st.one_of(st.just("lidar"), st.sampled_from(FRAMES)),
           st.sampled_from([None, None, "world", "odom", "nowhere"]), st.booleans())
    def inner(fmt, links, sensor, world, chain):
        path = folder / f"tf{next(counter)}{SUFFIX[fmt]}"
        bag = Bag(path, fmt)
        _cloud_frames(bag, sensor)
        if chain:  # a sane chain for the drawn links to break
            for k in range(-1, 3):
                t = T0 + k * DT
                bag.tf("/tf", [bag.transform(t, "world", "base", (k, 0, 0), IDENTITY_Q)], t)
            bag.tf("/tf_static", [bag.transform(T0, "base", "lidar", (0, 0, 1), IDENTITY_Q)],
                   T0 - 5)
        for k, (topic, stamp, parent, child, t, q) in enumerate(links):
            bag.tf(topic, [bag.transform(stamp, parent, child, t, q)], T0 - 7 + k)
        if not chain and not any(topic == "/tf" for topic, *_ in links):
            bag.tf("/tf", [], T0)
        bag.close()
        options = {"world_frame": world} if world else {}
        check_file("rosbag/tf", lambda: _read(path, ("/points", "/tf"), **options), path)

    inner()


@st.composite
def odometry_samples(draw: st.DrawFn) -> list[tuple[int, int, str, str, Any, Any]]:
    out = []
    clean = draw(st.booleans())  # only the frames and the stamps are odd
    for k in range(draw(st.integers(0, 6))):
        stamp = draw(st.one_of(st.just(T0 + (k - 1) * DT), STAMPS))
        log = draw(st.one_of(st.just(stamp + 300), st.integers(0, 2 * T0)))
        out.append((stamp, log, draw(st.sampled_from(FRAMES)), draw(st.sampled_from(FRAMES)),
                    (k * 0.5, 0.0, 0.0) if clean else draw(VECS),
                    IDENTITY_Q if clean else draw(QUATS)))
    return out


def test_fuzz_odometry(tmp_path_factory):
    folder = tmp_path_factory.mktemp("odometry")
    counter = iter(range(10**9))

    @given(_fmt_strategy(), odometry_samples(),
           st.sampled_from(["auto", "header", "bag", "order"]),
           st.sampled_from([0.1, 0.0, 1e9]))
    def inner(fmt, samples, time_source, gap):
        path = folder / f"od{next(counter)}{SUFFIX[fmt]}"
        bag = Bag(path, fmt)
        _cloud_frames(bag, "lidar", 3)
        for stamp, log, parent, child, t, q in samples:
            bag.odometry("/odom", stamp, parent, child, t, q, log=log)
        bag.close()
        check_file("rosbag/odometry", lambda: _read(
            path, ("/points", "/odom"), time_source=time_source, max_pose_gap=gap), path)

    inner()


# --------------------------------------------------------------------------------------------
# 3. A ROS 2 folder's metadata.yaml
# --------------------------------------------------------------------------------------------


@functools.cache
def _ros2_folder(fmt: str) -> dict[str, bytes]:
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        folder = _cloud_bag(Path(tmp), fmt)
        return {p.name: p.read_bytes() for p in folder.iterdir()}


def _write_folder(folder: Path, files: dict[str, bytes], metadata: bytes | str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for old in folder.iterdir():
        old.unlink()
    for name, data in files.items():
        if name != "metadata.yaml":
            (folder / name).write_bytes(data)
    write_variant(folder / "metadata.yaml", metadata)
    return folder


def test_fuzz_metadata_yaml_lines(tmp_path_factory):
    root = tmp_path_factory.mktemp("metadata_lines")
    cases = {f: text_lines(_ros2_folder(f)["metadata.yaml"].decode().splitlines())
             for f in ("sqlite3", "mcap")}

    @given(st.sampled_from(sorted(cases)).flatmap(lambda f: st.tuples(st.just(f), cases[f])))
    def inner(case):
        fmt, text = case
        folder = _write_folder(root / f"bag_{fmt}", _ros2_folder(fmt), text)
        check_file("rosbag/metadata-lines", lambda: _read(folder), folder,
                   names=("metadata.yaml",))

    inner()


def test_fuzz_metadata_yaml_bytes(tmp_path_factory):
    root = tmp_path_factory.mktemp("metadata_bytes")
    cases = {f: mutated_bytes(_ros2_folder(f)["metadata.yaml"]) for f in ("sqlite3", "mcap")}

    @given(st.sampled_from(sorted(cases)).flatmap(lambda f: st.tuples(st.just(f), cases[f])))
    def inner(case):
        fmt, data = case
        folder = _write_folder(root / f"bag_{fmt}", _ros2_folder(fmt), data)
        check_file("rosbag/metadata-bytes", lambda: _read(folder), folder,
                   names=("metadata.yaml",))

    inner()


ESCAPES = ["/etc/passwd", "/tmp/{name}", "../{name}", "../../{name}", "sub/../../{name}",
           "./../{name}", "..", "/", "{outside}", "..\\{name}", "C:/{name}", "a/../../b.db3"]


def test_fuzz_metadata_paths_outside_folder(tmp_path_factory):
    """``relative_file_paths`` holding an absolute path or a ``..`` component is refused with
    an error naming metadata.yaml, whether or not the file exists there."""
    root = tmp_path_factory.mktemp("metadata_paths")

    @_budget(0.6)
    @given(st.sampled_from(["sqlite3", "mcap"]), st.sampled_from(ESCAPES),
           st.sampled_from(["block", "flow"]), st.booleans())
    def inner(fmt, escape, style, keep_original):
        files = _ros2_folder(fmt)
        name = next(n for n in files if n != "metadata.yaml")
        folder = root / f"bag_{fmt}"
        (root / name).write_bytes(files[name])  # the same file, outside the bag's folder
        bad = escape.format(name=name, outside=str(root / name))
        text = files["metadata.yaml"].decode()
        lines = text.splitlines()
        i = next(k for k, line in enumerate(lines) if "relative_file_paths" in line)
        entries = [bad] + ([name] if keep_original else [])
        if style == "flow":
            lines[i + 1] = "    " + "[" + ", ".join(repr(e) for e in entries) + "]"
            lines[i] = lines[i].rstrip()
        else:
            indent = lines[i + 1][: len(lines[i + 1]) - len(lines[i + 1].lstrip())]
            lines[i + 1: i + 2] = [f"{indent}- {e!r}" for e in entries]
        meta = "\n".join(lines) + "\n"
        if style == "flow":
            meta = meta.replace("relative_file_paths:\n    [", "relative_file_paths: [")
        _write_folder(folder, files, meta)

        def call():
            _read(folder)
            raise AssertionError(f"metadata.yaml naming {bad!r} was accepted")

        check_file("rosbag/metadata-paths", call, folder / "metadata.yaml")

    inner()


# --------------------------------------------------------------------------------------------
# 4. The command line
# --------------------------------------------------------------------------------------------


def test_fuzz_cli_on_mutated_bags(tmp_path_factory, capsys):
    folder = tmp_path_factory.mktemp("cli")
    small = ros1_variant(_small_bag_bytes("lz4"))

    @given(small, st.sampled_from(["info", "map"]))
    def inner(variant, command):
        path = write_variant(folder / "cli.bag", variant)
        argv = ["info", str(path)] if command == "info" else \
            ["map", str(path), "--updater", "orgb", "--frames", "2", "--resolution", "0.2",
             "--no-pipeline"]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            check_cli(f"rosbag/cli-{command}", argv, (path.name,), capsys)

    inner()


def test_fuzz_cli_on_real_bag(tmp_path_factory, capsys):
    folder = tmp_path_factory.mktemp("cli_real")
    real = ros1_variant(_real_bag())

    @_budget(0.4)
    @given(real, st.sampled_from(["info", "map"]))
    def inner(variant, command):
        path = write_variant(folder / "lidar_odometry.bag", variant)
        argv = ["info", str(path)] if command == "info" else \
            ["map", str(path), "--updater", "orgb", "--frames", "2", "--resolution", "0.5",
             "--no-pipeline"]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            check_cli(f"rosbag/cli-{command}", argv, (path.name,), capsys)

    inner()


@pytest.mark.parametrize("fmt", FORMATS)
def test_generated_bags_read(tmp_path, fmt):
    """The generators above make bags the reader accepts (so the fuzz starts from valid input)."""
    assert _read(_cloud_bag(tmp_path, fmt)) == 3
    path = _rgbd_bag(tmp_path / f"rgbd{SUFFIX[fmt]}", fmt,
                     lambda b, t: b.image(COLOR, t, CAM, width=6, height=5, encoding="rgb8",
                                          step=18, data=_RGB.tobytes()),
                     lambda b, t: b.image(DEPTH, t, CAM, width=6, height=5, encoding="16UC1",
                                          step=12, data=_DEPTH16.tobytes()), size=(6, 5))
    assert _read(path) == 2


# --------------------------------------------------------------------------------------------
# Regressions: one example of each bug the targets found
# --------------------------------------------------------------------------------------------


def _refused(path: Path, match: str, **options: Any) -> None:
    with pytest.raises(EvsmapError, match=match) as err:
        _read(path, **options)
    assert "\n" not in str(err.value) and path.name in str(err.value)


def test_regression_claimed_record_lengths(tmp_path):
    """A ROS 1 record or an MCAP chunk index claiming 4 GB is refused before rosbags reads it."""
    data = bytearray(_small_bag_bytes("lz4"))
    chunk = next(r for r in _records(bytes(data))
                 if dict((n, data[o: o + k]) for n, o, k in _fields(bytes(data), r[0], r[1]))
                 .get(b"op") == b"\x05")
    data[chunk[0]: chunk[0] + 4] = (2**32 - 1).to_bytes(4, "little")  # its header's length
    _refused(write_variant(tmp_path / "long.bag", bytes(data)), "not a complete record")
    mcap = bytearray(_ros2_file_bytes("mcap"))
    pos = 8
    while mcap[pos] != 0x08:  # the first chunk index
        pos += 9 + int.from_bytes(mcap[pos + 1: pos + 9], "little")
    offsets = int.from_bytes(mcap[pos + 9 + 32: pos + 9 + 36], "little")
    name = pos + 9 + 36 + offsets + 8
    size = name + 4 + int.from_bytes(mcap[name: name + 4], "little")
    mcap[size: size + 8] = (2**40).to_bytes(8, "little")
    _refused(write_variant(tmp_path / "long.mcap", bytes(mcap)), "claims 1099511627776 compressed")


def test_regression_strides_and_sizes(tmp_path):
    """A cloud's row_step or an image's step of 4 GB is not padded out; a PNG header claiming
    10^10 pixels or another size than the camera's is refused before decoding; a point_step
    beyond numpy's itemsize on an empty cloud is fine."""
    fields, step, data = _cloud_data(4, np.random.default_rng(0))
    bag = Bag(tmp_path / "stride.bag", "ros1")
    bag.cloud("/points", T0, "lidar", fields=fields, point_step=step, row_step=2**32 - 1,
              width=4, height=1, data=data)
    bag.cloud("/points", T0 + DT, "lidar", fields=fields, point_step=2**32 - 1, row_step=0,
              width=0, height=0, data=b"")
    bag.odometry("/odom", T0, "odom", "lidar", (0, 0, 0), IDENTITY_Q)
    bag.odometry("/odom", T0 + DT, "odom", "lidar", (1, 0, 0), IDENTITY_Q)
    assert check_file("rosbag/regressions", lambda: _read(bag.close()), None) == 2
    path = _rgbd_bag(tmp_path / "step.bag", "ros1",
                     lambda b, t: b.image(COLOR, t, CAM, width=6, height=1, encoding="rgb8",
                                          step=2**32 - 1, data=bytes(18)),
                     lambda b, t: b.image(DEPTH, t, CAM, width=6, height=1, encoding="16UC1",
                                          step=12, data=bytes(12)), size=(6, 1))
    assert check_file("rosbag/regressions", lambda: _read(path), None) == 2
    for name in ("png-huge", "png-big"):
        path = _rgbd_bag(tmp_path / f"{name}.bag", "ros1",
                         lambda b, t, n=name: b.compressed(COLOR + "/compressed", t, CAM,
                                                           PAYLOADS[n], "png"),
                         lambda b, t: b.compressed(DEPTH + "/compressedDepth", t, CAM,
                                                   bytes(12) + PAYLOADS["png16"],
                                                   "16UC1; compressedDepth"), size=(6, 5))
        assert check_file("rosbag/regressions", lambda p=path: _read(p), None) == 0


def test_regression_order_with_shared_pose_stamps(tmp_path):
    """time_source='order' with two pose messages sharing a stamp: the k-th message, no
    IndexError."""
    bag = Bag(tmp_path / "order.bag", "ros1")
    _cloud_frames(bag, "lidar", 3)
    for k, stamp in enumerate((T0 - DT, T0 + DT, T0 + DT)):
        bag.odometry("/odom", stamp, "world", "lidar", (k, 0, 0), IDENTITY_Q)
    path = bag.close()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        seq = READERS.create("rosbag", path=str(path), time_source="order")
        assert [seq[k].pose[0, 3] for k in range(3)] == [0.0, 1.0, 2.0]
        seq.close()


def test_regression_non_finite_translation(tmp_path):
    bag = Bag(tmp_path / "nan.bag", "ros1")
    _cloud_frames(bag, "lidar", 1)
    bag.odometry("/odom", T0, "world", "lidar", (float("nan"), 0, 0), IDENTITY_Q)
    _refused(bag.close(), "/odom .*non-finite translation")
