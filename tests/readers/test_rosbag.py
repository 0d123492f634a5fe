"""The ROS bag reader: the real LiDAR bag, bags written here from real TUM frames (ROS 1, ROS 2
sqlite3 and MCAP; raw and compressed images; poses from /tf chains and odometry), point clouds
and bad input."""

from __future__ import annotations

import io
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image

from evsmap.errors import DataFormatError
from evsmap.geometry import matrix_to_quat, pose_matrix, quat_to_matrix
from evsmap.readers.rosbag import (
    BODY_TO_OPTICAL,
    decode_cloud,
    decode_color_image,
    decode_compressed_depth,
    decode_depth_image,
    is_rosbag,
    open_rosbag,
)
from evsmap.readers.tum import read_list
from evsmap.registry import READERS
from tests.readers.bag_writing import write_queued

# --------------------------------------------------------------------------------------------
# A small bag writer on rosbags' writers (messages are buffered and written in time order)
# --------------------------------------------------------------------------------------------


class BagWriter:
    def __init__(self, path: Path, fmt: str) -> None:
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        self.path, self.fmt = Path(path), fmt
        if fmt == "ros1":
            self.ts = get_typestore(Stores.ROS1_NOETIC)
            self.ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms",
                                                "tf2_msgs/msg/TFMessage"))
        else:
            self.ts = get_typestore(Stores.ROS2_HUMBLE)
        self.queue: list[tuple[int, int, str, str, object]] = []

    def make(self, msgtype: str, **fields):
        cls = self.ts.types[msgtype]
        names = {n.lower(): n for n, _ in self.ts.fielddefs[msgtype][1]}
        return cls(**{names[k.lower()]: v for k, v in fields.items()})

    def header(self, stamp_ns: int, frame: str):
        time = self.make("builtin_interfaces/msg/Time", sec=stamp_ns // 10**9,
                         nanosec=stamp_ns % 10**9)
        if self.fmt == "ros1":
            return self.make("std_msgs/msg/Header", seq=0, stamp=time, frame_id=frame)
        return self.make("std_msgs/msg/Header", stamp=time, frame_id=frame)

    def add(self, topic: str, msgtype: str, msg, log_ns: int) -> None:
        self.queue.append((log_ns, len(self.queue), topic, msgtype, msg))

    # -- message helpers ----------------------------------------------------------------------
    def image(self, topic, stamp, frame, array, encoding, *, big=False, pad=0, log=None):
        h, w = array.shape[:2]
        arr = array.astype(array.dtype.newbyteorder(">" if big else "<"))
        rows = arr.reshape(h, -1).view(np.uint8).reshape(h, -1)
        step = rows.shape[1] + pad
        data = np.zeros((h, step), np.uint8)
        data[:, : rows.shape[1]] = rows
        msg = self.make("sensor_msgs/msg/Image", header=self.header(stamp, frame), height=h,
                        width=w, encoding=encoding, is_bigendian=int(big), step=step,
                        data=data.reshape(-1))
        self.add(topic, "sensor_msgs/msg/Image", msg, stamp + 1000 if log is None else log)

    def compressed(self, topic, stamp, frame, data: bytes, fmt: str):
        msg = self.make("sensor_msgs/msg/CompressedImage", header=self.header(stamp, frame),
                        format=fmt, data=np.frombuffer(data, np.uint8).copy())
        self.add(topic, "sensor_msgs/msg/CompressedImage", msg, stamp + 1000)

    def camera_info(self, topic, stamp, frame, intr):
        roi = self.make("sensor_msgs/msg/RegionOfInterest", x_offset=0, y_offset=0, height=0,
                        width=0, do_rectify=False)
        k = np.array([intr.fx, 0, intr.cx, 0, intr.fy, intr.cy, 0, 0, 1], dtype=np.float64)
        p = np.array([intr.fx, 0, intr.cx, 0, 0, intr.fy, intr.cy, 0, 0, 0, 1, 0], np.float64)
        msg = self.make("sensor_msgs/msg/CameraInfo", header=self.header(stamp, frame),
                        height=intr.height, width=intr.width, distortion_model="plumb_bob",
                        d=np.zeros(5), k=k, r=np.eye(3).reshape(-1), p=p, binning_x=0,
                        binning_y=0, roi=roi)
        self.add(topic, "sensor_msgs/msg/CameraInfo", msg, stamp + 500)

    def _transform(self, pose):
        q = matrix_to_quat(pose[:3, :3])
        t = pose[:3, 3]
        return (self.make("geometry_msgs/msg/Vector3", x=t[0], y=t[1], z=t[2]),
                self.make("geometry_msgs/msg/Quaternion", x=q[0], y=q[1], z=q[2], w=q[3]))

    def tf(self, topic, stamp, parent, child, pose, log=None):
        trans, rot = self._transform(pose)
        tf = self.make("geometry_msgs/msg/TransformStamped", header=self.header(stamp, parent),
                       child_frame_id=child,
                       transform=self.make("geometry_msgs/msg/Transform", translation=trans,
                                           rotation=rot))
        msg = self.make("tf2_msgs/msg/TFMessage", transforms=[tf])
        self.add(topic, "tf2_msgs/msg/TFMessage", msg, stamp + 200 if log is None else log)

    def odometry(self, topic, stamp, parent, child, pose):
        trans, rot = self._transform(pose)
        point = self.make("geometry_msgs/msg/Point", x=trans.x, y=trans.y, z=trans.z)
        zero = self.make("geometry_msgs/msg/Vector3", x=0.0, y=0.0, z=0.0)
        msg = self.make(
            "nav_msgs/msg/Odometry", header=self.header(stamp, parent), child_frame_id=child,
            pose=self.make("geometry_msgs/msg/PoseWithCovariance",
                           pose=self.make("geometry_msgs/msg/Pose", position=point,
                                          orientation=rot), covariance=np.zeros(36)),
            twist=self.make("geometry_msgs/msg/TwistWithCovariance",
                            twist=self.make("geometry_msgs/msg/Twist", linear=zero,
                                            angular=zero), covariance=np.zeros(36)))
        self.add(topic, "nav_msgs/msg/Odometry", msg, stamp + 300)

    def transform_stamped(self, topic, stamp, parent, child, pose):
        trans, rot = self._transform(pose)
        msg = self.make("geometry_msgs/msg/TransformStamped", header=self.header(stamp, parent),
                        child_frame_id=child,
                        transform=self.make("geometry_msgs/msg/Transform", translation=trans,
                                            rotation=rot))
        self.add(topic, "geometry_msgs/msg/TransformStamped", msg, stamp + 300)

    def cloud(self, topic, stamp, frame, fields, point_step, data, *, width, height=1,
              big=False, row_step=None):
        pfs = [self.make("sensor_msgs/msg/PointField", name=n, offset=o, datatype=d, count=1)
               for n, o, d in fields]
        msg = self.make("sensor_msgs/msg/PointCloud2", header=self.header(stamp, frame),
                        height=height, width=width, fields=pfs, is_bigendian=big,
                        point_step=point_step, row_step=row_step or point_step * width,
                        data=np.frombuffer(data, np.uint8).copy(), is_dense=False)
        self.add(topic, "sensor_msgs/msg/PointCloud2", msg, stamp + 1000)

    def close(self) -> Path:
        return write_queued(self.path, self.fmt, self.ts, self.queue)


def ns(t: float) -> int:
    return int(round(t * 1e9))


def png_bytes(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(array).save(buf, format="PNG")
    return buf.getvalue()


def jpeg_bytes(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(array).save(buf, format="JPEG", quality=95)
    return buf.getvalue()


# A camera mounted on a robot base: a pure rotation (base x forward -> optical z forward), so
# interpolating world->base and appending it reproduces interpolating world->camera exactly.
BASE_TO_CAMERA = BODY_TO_OPTICAL.copy()
DEPTH_Z0, DEPTH_MAX = 100.0, 10.0  # compressed_depth_image_transport's default quantisation


def compressed_depth_32f(depth: np.ndarray) -> bytes:
    a = np.float32(DEPTH_Z0 * (DEPTH_Z0 + 1.0))
    b = np.float32(1.0 - a / np.float32(DEPTH_MAX))
    with np.errstate(divide="ignore"):
        inv = np.where(depth > 0, a / depth.astype(np.float32) + b, 0).astype(np.uint16)
    header = np.array([0], "<i4").tobytes() + np.array([a, b], "<f4").tobytes()
    return header + png_bytes(inv)


# --------------------------------------------------------------------------------------------
# Fixtures: five real TUM frames and the ground truth around them
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tum(tum_dir):
    seq = READERS.create("tum", path=str(tum_dir))
    frames = [seq[i] for i in range(5)]
    gt = np.array([[float(v) for v in row] for row in read_list(tum_dir / "groundtruth.txt", 8)])
    lo, hi = frames[0].timestamp - 0.05, frames[-1].timestamp + 0.05
    gt = gt[(gt[:, 0] >= lo) & (gt[:, 0] <= hi)]
    return SimpleNamespace(seq=seq, frames=frames, intrinsics=seq.intrinsics, gt=gt)


def write_tum_bag(path, tum, fmt, *, rgb="rgb8", depth="32FC1", poses="tf", pad=0,
                  big=False, corrupt=None, pose_until=None, depth_size=None):
    """A bag of the five TUM frames; returns its path."""
    w = BagWriter(path, fmt)
    cam = "kinect_rgb_optical_frame"
    rgb_topic = "/camera/rgb/image_color" + ("/compressed" if rgb in ("png", "jpeg") else "")
    depth_topic = "/camera/depth_registered/image" + (
        "/compressedDepth" if depth.startswith("cd") else "")
    for k, f in enumerate(tum.frames):
        t = ns(f.timestamp)
        if k == 0:
            w.camera_info("/camera/rgb/camera_info", t, cam, tum.intrinsics)
        if rgb == "rgb8":
            w.image(rgb_topic, t, cam, f.rgb, "rgb8", pad=pad)
        elif rgb == "bgr8":
            w.image(rgb_topic, t, cam, np.ascontiguousarray(f.rgb[..., ::-1]), "bgr8", pad=pad)
        else:
            data = png_bytes(f.rgb) if rgb == "png" else jpeg_bytes(f.rgb)
            if corrupt == k:
                data = data[:40] + b"\x00garbage" * 20
            w.compressed(rgb_topic, t, cam, data, f"rgb8; {rgb} compressed bgr8")
        d = f.depth
        if depth_size is not None:
            d = d[: depth_size[1], : depth_size[0]]
        if depth == "32FC1":
            w.image(depth_topic, t, cam, np.where(d > 0, d, np.nan).astype(np.float32), "32FC1",
                    big=big)
        elif depth == "16UC1":
            w.image(depth_topic, t, cam, np.round(d * 1000).astype(np.uint16), "16UC1", big=big)
        elif depth == "cd16":
            data = bytes(12) + png_bytes(np.round(d * 1000).astype(np.uint16))
            w.compressed(depth_topic, t, cam, data, "16UC1; compressedDepth png")
        elif depth == "cd32":
            w.compressed(depth_topic, t, cam, compressed_depth_32f(d), "32FC1; compressedDepth")
    t0 = ns(tum.frames[0].timestamp)
    w.tf("/tf_static", t0, "base_link", cam, BASE_TO_CAMERA, log=t0 - 10**6)
    for row in tum.gt:
        t = ns(row[0])
        if pose_until is not None and row[0] > pose_until:
            break
        world_base = pose_matrix(row[1:4], row[4:8]) @ np.linalg.inv(BASE_TO_CAMERA)
        if poses == "tf":
            w.tf("/tf", t, "world", "base_link", world_base)
        else:
            w.odometry("/odom", t, "world", "base_link", world_base)
    return w.close()


def assert_matches_tum(seq, tum, *, rgb_exact=True, depth_tol=0.0):
    assert len(seq) == 5
    assert seq.intrinsics == tum.intrinsics
    for got, want in zip(seq, tum.frames, strict=True):
        assert got.timestamp == pytest.approx(want.timestamp, abs=1e-6)
        if rgb_exact:
            np.testing.assert_array_equal(got.rgb, want.rgb)
        else:  # JPEG (quality 95, chroma subsampled): close, and channels in RGB order
            diff = got.rgb.astype(int) - want.rgb.astype(int)
            assert np.abs(diff).mean() < 5.0
            assert np.all(np.abs(diff.mean(axis=(0, 1))) < 2.0)
        if depth_tol == 0.0:
            np.testing.assert_array_equal(got.depth, want.depth)
        else:
            np.testing.assert_array_equal(got.depth > 0, want.depth > 0)
            assert np.abs(got.depth - want.depth).max() <= depth_tol
        np.testing.assert_allclose(got.pose, want.pose, atol=1e-6, rtol=0)


# --------------------------------------------------------------------------------------------
# The real LiDAR bag
# --------------------------------------------------------------------------------------------


def test_real_lidar_bag(lidar_bag):
    from rosbags.highlevel import AnyReader

    bag = lidar_bag
    assert is_rosbag(bag)
    # the clouds are stamped in 2020 wall time and the odometry in simulated time (60.2 s ..),
    # also 7 s apart in bag time: the reader pairs them in order and says so
    with pytest.warns(UserWarning, match="k-th frame takes the k-th pose"):
        seq = open_rosbag(path=str(bag))
    assert seq.meta["bag_format"] == "ros1" and seq.meta["kind"] == "cloud"
    assert seq.meta["topics"]["cloud"] == "/luminar_pointcloud"
    assert seq.meta["topics"]["pose"] == "/base_pose_ground_truth"
    assert seq.meta["time_source"] == "order"
    assert seq.meta["sensor_offset"].startswith("identity")
    assert seq.intrinsics is None and len(seq) == 5

    clouds, odom = [], []
    with AnyReader([bag]) as reader:
        for conn, _, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic == "/luminar_pointcloud":
                clouds.append(msg)
            elif conn.topic == "/base_pose_ground_truth":
                p = msg.pose.pose
                odom.append(pose_matrix([p.position.x, p.position.y, p.position.z],
                                        [p.orientation.x, p.orientation.y, p.orientation.z,
                                         p.orientation.w]))
    xyz = np.dtype({"names": list("xyz"), "formats": ["<f4"] * 3, "offsets": [0, 4, 8],
                    "itemsize": 32})
    for frame, msg, pose in zip(seq, clouds, odom, strict=True):
        assert frame.is_cloud and frame.point_colors is None
        rec = np.frombuffer(bytes(msg.data), dtype=xyz)
        want = np.stack([rec["x"], rec["y"], rec["z"]], axis=1)
        want = want[np.all(np.isfinite(want), axis=1)]
        assert 35_000 < len(frame.points) == len(want) == msg.width * msg.height < 37_000
        np.testing.assert_array_equal(frame.points, want)
        assert np.all(np.isfinite(frame.points))
        np.testing.assert_array_equal(frame.pose, pose)
        assert frame.timestamp == pytest.approx(msg.header.stamp.sec +
                                                msg.header.stamp.nanosec * 1e-9)
    # header stamps asked for explicitly: no pose for any frame, raised per frame
    strict = open_rosbag(path=str(bag), time_source="header", limit=2)
    assert len(strict) == 2 and strict.meta["dropped"]["beyond_limit"] == 3
    with pytest.raises(DataFormatError, match=r"lidar_odometry\.bag: no pose .*"
                                              r"/luminar_pointcloud at stamp 1583971570\.0153"):
        strict.frame(0)


# --------------------------------------------------------------------------------------------
# RGB-D bags written from real TUM frames
# --------------------------------------------------------------------------------------------


def test_ros1_raw_images_tf_chain_exact(tmp_path, tum):
    bag = write_tum_bag(tmp_path / "tum.bag", tum, "ros1", rgb="rgb8", depth="32FC1")
    assert is_rosbag(bag) and READERS.names().count("rosbag") == 1
    seq = READERS.create("rosbag", path=str(bag))
    assert seq.meta["bag_format"] == "ros1" and seq.meta["time_source"] == "header"
    assert seq.meta["world_frame"] == "world"  # the root of the camera frame's tf tree
    assert seq.meta["topics"]["camera_info"] == "/camera/rgb/camera_info"
    assert "base_link -> kinect_rgb_optical_frame (static)" in seq.meta["pose_source"]
    assert "world -> base_link (dynamic)" in seq.meta["pose_source"]
    assert_matches_tum(seq, tum)
    # random access and reverse order read the same frames
    np.testing.assert_array_equal(seq[3].rgb, tum.frames[3].rgb)
    np.testing.assert_array_equal(seq[1].depth, tum.frames[1].depth)
    seq.close()


def test_ros2_sqlite_bgr_padded_16uc1_bigendian_odometry(tmp_path, tum):
    bag = write_tum_bag(tmp_path / "tum_sqlite", tum, "sqlite3", rgb="bgr8", depth="16UC1",
                        poses="odom", pad=7, big=True)
    seq = open_rosbag(path=str(bag))
    assert seq.meta["bag_format"] == "ros2-sqlite3"
    assert seq.meta["topics"]["pose"] == "/odom"
    assert "base_link -> kinect_rgb_optical_frame" in seq.meta["sensor_offset"]
    assert_matches_tum(seq, tum, depth_tol=0.0005 + 1e-6)
    # the bare .db3 file reads the same
    bare = open_rosbag(path=str(next(bag.glob("*.db3"))))
    np.testing.assert_allclose(bare[2].pose, tum.frames[2].pose, atol=1e-6, rtol=0)


def test_ros2_mcap_png_and_compressed_depth(tmp_path, tum):
    bag = write_tum_bag(tmp_path / "tum_mcap", tum, "mcap", rgb="png", depth="cd16")
    seq = open_rosbag(path=str(bag))
    assert seq.meta["bag_format"] == "ros2-mcap"
    assert_matches_tum(seq, tum, depth_tol=0.0005 + 1e-6)
    mcap = next(bag.glob("*.mcap"))
    assert is_rosbag(mcap) and is_rosbag(bag)
    assert len(open_rosbag(path=str(mcap))) == 5


def test_ros1_jpeg_and_compressed_inverse_depth(tmp_path, tum):
    bag = write_tum_bag(tmp_path / "jpeg.bag", tum, "ros1", rgb="jpeg", depth="cd32",
                        poses="odom")
    seq = open_rosbag(path=str(bag))
    # inverse-depth quantisation: a step of z^2 / A at depth z (A = z0 (z0 + 1))
    zmax = max(float(f.depth.max()) for f in tum.frames)
    assert_matches_tum(seq, tum, rgb_exact=False,
                       depth_tol=zmax**2 / (DEPTH_Z0 * (DEPTH_Z0 + 1)) + 1e-4)


def test_cli_info_and_map_on_bags(tmp_path, tum, lidar_bag, capsys):
    from evsmap.cli.main import main

    bag = write_tum_bag(tmp_path / "cli.bag", tum, "ros1")
    assert main(["info", str(bag)]) == 0
    out = capsys.readouterr().out
    assert "layout: rosbag, reader: rosbag" in out and "frames      5" in out
    assert "fx 517.30" in out
    assert main(["map", str(bag), "--updater", "orgb", "--frames", "2",
                 "--resolution", "0.1"]) == 0
    assert "2 frames of cli" in capsys.readouterr().out
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["info", str(lidar_bag)]) == 0
        assert "clouds      35,707 .. 36,457 points" in capsys.readouterr().out
        assert main(["map", str(lidar_bag), "--updater", "orgb", "--resolution", "0.2"]) == 0
        assert "5 frames of lidar_odometry" in capsys.readouterr().out


# --------------------------------------------------------------------------------------------
# Point clouds
# --------------------------------------------------------------------------------------------


def _cloud_bytes(points, colors, *, big=False, float64=False):
    """Points with padding between fields: x y z [pad] rgb(packed float32) [pad]."""
    order = ">" if big else "<"
    kind = "f8" if float64 else "f4"
    size = 8 if float64 else 4
    off = {"x": 0, "y": size, "z": 2 * size, "rgb": 3 * size + 4}
    step = 3 * size + 12
    rec = np.zeros(len(points), dtype=np.dtype({
        "names": ["x", "y", "z", "rgb"], "formats": [order + kind] * 3 + [order + "u4"],
        "offsets": [off["x"], off["y"], off["z"], off["rgb"]], "itemsize": step}))
    rec["x"], rec["y"], rec["z"] = points[:, 0], points[:, 1], points[:, 2]
    packed = (colors[:, 0].astype(np.uint32) << 16) | (colors[:, 1].astype(np.uint32) << 8) | \
        colors[:, 2].astype(np.uint32)
    rec["rgb"] = packed
    dt = 8 if float64 else 7
    fields = [("x", off["x"], dt), ("y", off["y"], dt), ("z", off["z"], dt),
              ("rgb", off["rgb"], 7)]
    return fields, step, rec.tobytes()


def test_pointcloud2_with_padding_and_rgb_via_tf(tmp_path):
    rng = np.random.default_rng(3)
    w = BagWriter(tmp_path / "cloud", "mcap")
    stamps = [10**9 * 100 + k * 10**8 for k in range(3)]
    want = []
    for k, t in enumerate(stamps):
        pts = rng.normal(size=(40, 3)).astype(np.float32)
        cols = rng.integers(0, 256, size=(40, 3), dtype=np.uint8)
        pts[5] = np.nan
        pts[17, 2] = np.inf
        fields, step, data = _cloud_bytes(pts, cols, big=k == 1, float64=k == 2)
        w.cloud("/velodyne_points", t, "velodyne", fields, step, data, width=40,
                big=k == 1)
        keep = np.all(np.isfinite(pts), axis=1)
        want.append((pts[keep], cols[keep]))
    # map -> odom (static) -> base (dynamic) -> velodyne (static)
    w.tf("/tf_static", stamps[0], "map", "odom", pose_matrix([1, 2, 3], [0, 0, 0, 1]))
    w.tf("/tf_static", stamps[0], "base", "velodyne", pose_matrix([0, 0, 1], [0, 0, 0, 1]))
    for k in range(4):
        t = stamps[0] - 5 * 10**7 + k * 10**8
        w.tf("/tf", t, "odom", "base", pose_matrix([k * 1.0, 0, 0], [0, 0, 0, 1]))
    seq = open_rosbag(path=str(w.close()), world_frame="map")
    assert seq.meta["kind"] == "cloud" and seq.meta["world_frame"] == "map"
    assert len(seq) == 3
    for k, (frame, (pts, cols)) in enumerate(zip(seq, want, strict=True)):
        np.testing.assert_array_equal(frame.points, pts)
        np.testing.assert_array_equal(frame.point_colors, cols)
        # base at x = k + 0.5 (halfway between samples), then the static links
        np.testing.assert_allclose(frame.pose[:3, 3], [1 + k + 0.5, 2, 4], atol=1e-9)


def test_decode_images_unit():
    def img(arr, enc, *, big=False, pad=0):
        h, w = arr.shape[:2]
        a = arr.astype(arr.dtype.newbyteorder(">" if big else "<"))
        rows = a.reshape(h, -1).view(np.uint8).reshape(h, -1)
        data = np.zeros((h, rows.shape[1] + pad), np.uint8)
        data[:, : rows.shape[1]] = rows
        return SimpleNamespace(height=h, width=w, encoding=enc, is_bigendian=int(big),
                               step=data.shape[1], data=data.reshape(-1))

    rgb = np.arange(4 * 5 * 3, dtype=np.uint8).reshape(4, 5, 3)
    alpha = np.full((4, 5, 1), 9, np.uint8)
    np.testing.assert_array_equal(decode_color_image(img(rgb, "rgb8", pad=3), "t"), rgb)
    np.testing.assert_array_equal(decode_color_image(img(rgb[..., ::-1], "bgr8"), "t"), rgb)
    np.testing.assert_array_equal(
        decode_color_image(img(np.concatenate([rgb, alpha], 2), "rgba8"), "t"), rgb)
    np.testing.assert_array_equal(
        decode_color_image(img(np.concatenate([rgb[..., ::-1], alpha], 2), "bgra8"), "t"), rgb)
    grey = rgb[..., 0]
    np.testing.assert_array_equal(decode_color_image(img(grey, "mono8"), "t"),
                                  np.repeat(grey[..., None], 3, axis=2))
    mm = np.array([[0, 1000, 65535], [1, 2, 3]], np.uint16)
    for big in (False, True):
        got = decode_depth_image(img(mm, "16UC1", big=big, pad=2), "t")
        np.testing.assert_allclose(got, mm * 0.001, rtol=1e-6)
    metres = np.array([[np.nan, 1.5, np.inf], [-1.0, 0.25, 2.0]], np.float32)
    got = decode_depth_image(img(metres, "32FC1", big=True), "t")
    np.testing.assert_array_equal(got, [[0, 1.5, 0], [0, 0.25, 2.0]])
    with pytest.raises(DataFormatError, match=r"where: depth encoding '8UC3'; expected 16UC1"):
        decode_depth_image(img(rgb, "8UC3"), "where")
    with pytest.raises(DataFormatError, match="step 4 is less than a row"):
        decode_color_image(SimpleNamespace(height=2, width=2, encoding="rgb8", is_bigendian=0,
                                           step=4, data=np.zeros(12, np.uint8)), "t")
    # compressedDepth: RVL is refused clearly, a 16-bit PNG without header is read
    raw = png_bytes(mm)
    msg = SimpleNamespace(format="16UC1; compressedDepth", data=np.frombuffer(raw, np.uint8))
    np.testing.assert_allclose(decode_compressed_depth(msg, "t"), mm * 0.001, rtol=1e-6)
    msg = SimpleNamespace(format="16UC1; compressedDepth rvl", data=np.zeros(20, np.uint8))
    with pytest.raises(DataFormatError, match="RVL.*not supported"):
        decode_compressed_depth(msg, "t")


def test_decode_cloud_row_padding_and_rgb_fields():
    pts = np.arange(12, dtype=np.float32).reshape(4, 3)
    rec = np.zeros(4, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("r", "u1"),
                             ("g", "u1"), ("b", "u1"), ("pad", "u1")])
    rec["x"], rec["y"], rec["z"] = pts.T
    rec["r"], rec["g"], rec["b"] = 1, 2, 3
    rows = rec.tobytes()
    data = rows[:32] + b"\xff" * 5 + rows[32:] + b"\xff" * 5  # 2x2 points, 5 bytes row padding
    fields = [SimpleNamespace(name=n, offset=o, datatype=d, count=1) for n, o, d in
              [("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("r", 12, 2), ("g", 13, 2), ("b", 14, 2)]]
    msg = SimpleNamespace(fields=fields, is_bigendian=False, point_step=16, row_step=37,
                          height=2, width=2, data=np.frombuffer(data, np.uint8))
    got, cols = decode_cloud(msg, "t")
    np.testing.assert_array_equal(got, pts)
    np.testing.assert_array_equal(cols, np.tile([1, 2, 3], (4, 1)))
    msg.fields = fields[:2]
    with pytest.raises(DataFormatError, match="t: PointCloud2 has no 'z' field"):
        decode_cloud(msg, "t")


# --------------------------------------------------------------------------------------------
# Bad input: each error names the file and the topic
# --------------------------------------------------------------------------------------------

SMALL = SimpleNamespace(fx=10.0, fy=10.0, cx=3.5, cy=2.5, width=8, height=6)


def small_bag(path, fmt="ros1", *, colors=("/cam/rgb",), depth="/cam/depth", depth_enc="32FC1",
              depth_shape=(6, 8), info=True, tf_until=None, frames=4, info_size=(8, 6)):
    w = BagWriter(path, fmt)
    rgb = np.full((6, 8, 3), 100, np.uint8)
    for k in range(frames):
        t = 5 * 10**9 + k * 10**8
        for topic in colors:
            w.image(topic, t, "cam", rgb, "rgb8")
        if depth:
            d = np.ones(depth_shape, np.float32) if depth_enc == "32FC1" else \
                np.ones(depth_shape + (3,), np.uint8)
            w.image(depth, t, "cam", d, depth_enc)
        if info and k == 0:
            from evsmap.data import Intrinsics

            size = dict(width=info_size[0], height=info_size[1])
            w.camera_info("/cam/camera_info", t, "cam", Intrinsics(**{**vars(SMALL), **size}))
        if tf_until is None or k <= tf_until:
            w.tf("/tf", t, "world", "cam", pose_matrix([k, 0, 0], [0, 0, 0, 1]))
    return w.close()


def test_missing_file_and_empty_bag(tmp_path):
    with pytest.raises(DataFormatError, match=r"nope\.bag: no such file"):
        open_rosbag(path=str(tmp_path / "nope.bag"))
    empty = BagWriter(tmp_path / "empty.bag", "ros1").close()
    with pytest.raises(DataFormatError, match=r"empty\.bag: the bag holds no messages"):
        open_rosbag(path=str(empty))
    bad = tmp_path / "bad.bag"
    bad.write_bytes(b"#ROSBAG V2.0\n" + b"\x00" * 50)
    with pytest.raises(DataFormatError, match=r"bad\.bag: not a readable ROS bag"):
        open_rosbag(path=str(bad))


@pytest.mark.parametrize("entry", ["/etc/passwd", "../outside.db3", "sub/../../outside.db3",
                                   "..", "C:\\bags\\outside.db3", "..\\outside.db3"])
def test_metadata_paths_outside_the_bag_folder_refused(tmp_path, entry):
    """A ROS 2 bag's metadata.yaml must not make evsmap open files outside its folder."""
    w = BagWriter(tmp_path / "bag", "sqlite3")
    w.tf("/tf", 10**9, "world", "cam", np.eye(4))
    folder = w.close()
    meta = folder / "metadata.yaml"
    db3 = next(folder.glob("*.db3"))
    text = meta.read_text()
    assert f"- {db3.name}" in text
    meta.write_text(text.replace(f"- {db3.name}", f"- {entry!r}"))
    with pytest.raises(DataFormatError, match=r"bag/metadata\.yaml: relative_file_paths names "
                                              r".*leaves the bag folder") as err:
        open_rosbag(path=str(folder))
    assert "\n" not in str(err.value)
    # the same file name inside the folder is fine
    meta.write_text(text)
    with pytest.raises(DataFormatError, match="no images"):
        open_rosbag(path=str(folder))


def test_missing_topics(tmp_path):
    only_tf = small_bag(tmp_path / "only_tf.bag", colors=(), depth=None, info=False)
    with pytest.raises(DataFormatError, match=r"only_tf\.bag: .*no images .*or point clouds"):
        open_rosbag(path=str(only_tf))
    no_info = small_bag(tmp_path / "no_info.bag", info=False)
    with pytest.raises(DataFormatError, match=r"no_info\.bag: no camera info topic"):
        open_rosbag(path=str(no_info))
    bag = small_bag(tmp_path / "ok.bag")
    with pytest.raises(DataFormatError, match=r"ok\.bag: no topic /odom \(odom_topic\)"):
        open_rosbag(path=str(bag), odom_topic="/odom")
    with pytest.raises(DataFormatError, match=r"ok\.bag: preset 'zed2i' expects colour image "
                                              r"on /zed2i/zed_node/rgb/image_rect_color"):
        open_rosbag(path=str(bag), preset="zed2i")


def test_two_candidate_topics(tmp_path):
    bag = small_bag(tmp_path / "two.bag", colors=("/cam/rgb", "/cam/rgb_raw"))
    with pytest.raises(DataFormatError, match=r"two\.bag: 2 candidate colour image topics "
                                              r"\(/cam/rgb, /cam/rgb_raw\); choose one with "
                                              r"rgb_topic=TOPIC"):
        open_rosbag(path=str(bag))
    seq = open_rosbag(path=str(bag), rgb_topic="/cam/rgb_raw")
    assert len(seq) == 4 and seq.meta["topics"]["rgb"] == "/cam/rgb_raw"
    np.testing.assert_array_equal(seq[2].pose[:3, 3], [2, 0, 0])


def test_unknown_encoding_and_size_mismatch(tmp_path):
    bag = small_bag(tmp_path / "enc.bag", depth_enc="8UC3")
    with pytest.raises(DataFormatError, match=r"enc\.bag: topic /cam/depth has encoding 8UC3; "
                                              r"expected 16UC1 \(millimetres\) or 32FC1"):
        open_rosbag(path=str(bag), depth_topic="/cam/depth")
    bag = small_bag(tmp_path / "size.bag", depth_shape=(3, 4))
    with pytest.raises(DataFormatError, match=r"size\.bag: depth on /cam/depth is 4x3 but "
                                              r"colour on /cam/rgb is 8x6; depth must be "
                                              r"registered"):
        open_rosbag(path=str(bag))
    bag = small_bag(tmp_path / "info.bag", info_size=(16, 12))
    with pytest.raises(DataFormatError, match=r"info\.bag: CameraInfo /cam/camera_info is for "
                                              r"16x12 but colour images on /cam/rgb are 8x6"):
        open_rosbag(path=str(bag))


def test_frame_without_pose_raises_from_frame(tmp_path):
    bag = small_bag(tmp_path / "gap.bag", tf_until=1)
    seq = open_rosbag(path=str(bag))
    assert len(seq) == 4 and seq.meta["frames_without_pose"] == 2
    assert seq[1].pose[0, 3] == 1.0
    with pytest.raises(DataFormatError, match=r"gap\.bag: no pose for the frame on /cam/depth "
                                              r"at stamp 5\.200000 s: outside the samples"):
        seq.frame(2)
    # a gap inside the samples, beyond max_pose_gap
    w = BagWriter(tmp_path / "gap2.bag", "ros1")
    for k, t in enumerate([0, 10**8, 2 * 10**8]):
        w.image("/cam/rgb", 10**9 + t, "cam", np.zeros((6, 8, 3), np.uint8), "rgb8")
        w.image("/cam/depth", 10**9 + t, "cam", np.ones((6, 8), np.float32), "32FC1")
        if k == 0:
            from evsmap.data import Intrinsics

            w.camera_info("/cam/camera_info", 10**9, "cam", Intrinsics(**vars(SMALL)))
    for t in (0, 3 * 10**8):
        w.tf("/tf", 10**9 + t, "world", "cam", np.eye(4))
    seq = open_rosbag(path=str(w.close()), max_pose_gap=0.05)
    assert seq[0].pose[0, 0] == 1.0
    with pytest.raises(DataFormatError, match=r"stamp 1\.100000 s: the nearest sample of /tf "
                                              r"world -> cam is 0\.100 s away"):
        seq.frame(1)
    with pytest.raises(DataFormatError, match=r"stamp 1\.200000 s"):
        seq.frame(2)


def test_corrupt_compressed_image_raises_from_frame(tmp_path, tum):
    bag = write_tum_bag(tmp_path / "corrupt.bag", tum, "ros1", rgb="jpeg", corrupt=2)
    seq = open_rosbag(path=str(bag))
    assert seq[1].rgb.shape == (480, 640, 3)
    with pytest.raises(DataFormatError, match=r"corrupt\.bag: topic "
                                              r"/camera/rgb/image_color/compressed at stamp "
                                              r"\d+\.\d{6} s: cannot decode"):
        seq.frame(2)
    assert seq[3].rgb.shape == (480, 640, 3)  # the next frame still reads


def test_presets_and_quaternion_helpers():
    from evsmap.readers.rosbag import PRESETS

    offset = np.array(PRESETS["asl"]["sensor_offset"])
    # the voxblox calibration is a rotation to the printed precision
    assert np.abs(offset[:3, :3] @ offset[:3, :3].T - np.eye(3)).max() < 1e-4
    assert {"rgb_topic", "depth_topic", "camera_info_topic"} <= set(PRESETS["rtabmap"])
    r = quat_to_matrix(matrix_to_quat(BODY_TO_OPTICAL[:3, :3]))
    np.testing.assert_allclose(r, BODY_TO_OPTICAL[:3, :3], atol=1e-12)


# --------------------------------------------------------------------------------------------
# Presets, time sources, camera axes
# --------------------------------------------------------------------------------------------


def _rot_z(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return pose_matrix([0, 0, 0], [0, 0, np.sin(a / 2), np.cos(a / 2)])


def test_zed2i_preset_odometry_with_static_camera_chain(tmp_path):
    from evsmap.data import Intrinsics

    w = BagWriter(tmp_path / "zed", "sqlite3")
    cam = "zed2i_left_camera_optical_frame"
    intr = Intrinsics(**vars(SMALL))
    center = pose_matrix([0.1, 0, 0.2], [0, 0, 0, 1])
    left = pose_matrix([0, 0.06, 0], [0, 0, 0, 1])
    t0 = 7 * 10**9
    w.tf("/tf_static", t0, "base_link", "zed2i_camera_center", center)
    w.tf("/tf_static", t0, "zed2i_camera_center", "zed2i_left_camera_frame", left)
    w.tf("/tf_static", t0, "zed2i_left_camera_frame", cam, BODY_TO_OPTICAL)
    odom = [pose_matrix([k, 2.0, 0], [0, 0, 0, 1]) @ _rot_z(10 * k) for k in range(3)]
    for k in range(3):
        t = t0 + k * 10**8
        w.camera_info("/zed2i/zed_node/rgb/camera_info", t, cam, intr)
        w.image("/zed2i/zed_node/rgb/image_rect_color", t, cam,
                np.full((6, 8, 4), 7, np.uint8), "bgra8")
        w.image("/zed2i/zed_node/depth/depth_registered", t, cam, np.ones((6, 8), np.float32),
                "32FC1")
        w.odometry("/zed2i/zed_node/odom", t, "odom", "base_link", odom[k])
        w.add("/zed2i/zed_node/pose", "geometry_msgs/msg/PoseStamped",
              w.make("geometry_msgs/msg/PoseStamped", header=w.header(t, "map"),
                     pose=w.make("geometry_msgs/msg/Pose",
                                 position=w.make("geometry_msgs/msg/Point", x=0.0, y=0.0,
                                                 z=0.0),
                                 orientation=w.make("geometry_msgs/msg/Quaternion", x=0.0,
                                                    y=0.0, z=0.0, w=1.0))), t + 400)
    bag = w.close()
    with pytest.raises(DataFormatError, match=r"zed: 2 candidate pose sources "
                                              r"\(/zed2i/zed_node/odom, /zed2i/zed_node/pose\); "
                                              r"choose one with odom_topic=TOPIC"):
        open_rosbag(path=str(bag))
    seq = open_rosbag(path=str(bag), preset="zed2i")
    assert seq.meta["topics"]["pose"] == "/zed2i/zed_node/odom"
    chain = center @ left @ BODY_TO_OPTICAL
    for k, frame in enumerate(seq):
        np.testing.assert_allclose(frame.pose, odom[k] @ chain, atol=1e-12)
        assert frame.rgb[0, 0].tolist() == [7, 7, 7]


def test_rtabmap_preset_compressed_topics_and_tf(tmp_path):
    from evsmap.data import Intrinsics

    w = BagWriter(tmp_path / "demo.bag", "ros1")
    intr = Intrinsics(**vars(SMALL))
    cam = "camera_rgb_optical_frame"
    t0 = 3 * 10**9
    w.tf("/tf", t0, "base_footprint", cam, BODY_TO_OPTICAL)  # a fixed link sent on /tf
    depth = np.full((6, 8), 1234, np.uint16)
    for k in range(3):
        t = t0 + k * 10**8
        w.camera_info("/data_throttled_camera_info", t, cam, intr)
        w.compressed("/data_throttled_image/compressed", t, cam,
                     jpeg_bytes(np.full((6, 8, 3), 90, np.uint8)), "rgb8; jpeg compressed bgr8")
        w.compressed("/data_throttled_image_depth/compressedDepth", t, cam,
                     bytes(12) + png_bytes(depth), "16UC1; compressedDepth")
        w.tf("/tf", t, "odom", "base_footprint", pose_matrix([0.5 * k, 0, 0], [0, 0, 0, 1]))
        w.tf("/tf", t + 10**7, "base_footprint", cam, BODY_TO_OPTICAL)
        w.odometry("/az3/base_controller/odom", t, "odom", "base_footprint", np.eye(4))
    seq = open_rosbag(path=str(w.close()), preset="rtabmap")
    assert seq.meta["world_frame"] == "odom" and seq.meta["topics"]["pose"] is None
    for k, frame in enumerate(seq):
        np.testing.assert_allclose(frame.pose, pose_matrix([0.5 * k, 0, 0], [0, 0, 0, 1])
                                   @ BODY_TO_OPTICAL, atol=1e-12)
        np.testing.assert_allclose(frame.depth, 1.234, rtol=1e-6)


def test_asl_preset_transform_topic_with_calibration(tmp_path):
    from evsmap.readers.rosbag import PRESETS

    w = BagWriter(tmp_path / "cow.bag", "ros1")
    t0 = 2 * 10**9
    vicon = [pose_matrix([k, 0, 1], [0, 0, 0, 1]) @ _rot_z(5 * k) for k in range(3)]
    pts = np.array([[0, 0, 1], [1, 2, 3]], np.float32)
    for k in range(3):
        t = t0 + k * 10**8
        fields, step, data = _cloud_bytes(pts, np.zeros((2, 3), np.uint8))
        w.cloud("/camera/depth_registered/points", t, "camera_rgb_optical_frame", fields, step,
                data, width=2)
        w.transform_stamped("/kinect/vrpn_client/estimated_transform", t, "world", "kinect",
                            vicon[k])
    seq = open_rosbag(path=str(w.close()), preset="asl")
    assert seq.meta["sensor_offset"] == "given (sensor_offset)"
    calib = np.array(PRESETS["asl"]["sensor_offset"])
    for k, frame in enumerate(seq):
        np.testing.assert_allclose(frame.pose, vicon[k] @ calib, atol=1e-4)
        np.testing.assert_array_equal(frame.points, pts)


def test_zero_header_stamps_use_bag_time_and_body_axes(tmp_path):
    from evsmap.data import Intrinsics

    w = BagWriter(tmp_path / "zero.bag", "ros1")
    intr = Intrinsics(**vars(SMALL))
    for k in range(3):
        log = 9 * 10**9 + k * 10**8
        w.camera_info("/cam/camera_info", 0, "cam_link", intr)
        w.image("/cam/rgb", 0, "cam_link", np.zeros((6, 8, 3), np.uint8), "rgb8", log=log)
        w.image("/cam/depth", 0, "cam_link", np.ones((6, 8), np.float32), "32FC1", log=log)
        w.tf("/tf", log, "world", "cam_link", pose_matrix([k, 0, 0], [0, 0, 0, 1]), log=log)
    bag = w.close()
    with pytest.warns(UserWarning, match="header stamps are all zero"):
        seq = open_rosbag(path=str(bag), camera_axes="body")
    assert seq.meta["time_source"] == "bag" and len(seq) == 3
    for k, frame in enumerate(seq):
        assert frame.timestamp == pytest.approx(9 + 0.1 * k)
        np.testing.assert_allclose(frame.pose, pose_matrix([k, 0, 0], [0, 0, 0, 1])
                                   @ BODY_TO_OPTICAL, atol=1e-12)
        # the optical z axis (viewing direction) is the body's x axis
        np.testing.assert_allclose(frame.pose[:3, 2], [1, 0, 0], atol=1e-12)
