"""HHA (baselines.hha): the encoding on ray-cast planes of known orientation and on the real NYUv2
samples, invalid depth, and HHASegmenter end to end (torch and ONNX Runtime)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch
from torch import nn

from baselines.hha import (
    encode_hha,
    gravity_direction,
    hha_channels,
    surface_normals,
)
from baselines.hha.encoding import ANGLE_OFFSET
from evsmap.data import Frame, Intrinsics
from evsmap.errors import InvalidDataError
from evsmap.registry import READERS
from evsmap.segmenters.normalization import Normalization

CAMERA = Intrinsics(525.0, 525.0, 319.5, 239.5, 640, 480)
FLOOR, WALL, CEILING = 38, 128, 218  # angle channel of 0, 90 and 180 degrees


def _rotation(pitch_deg: float, roll_deg: float) -> np.ndarray:
    """Camera-to-world rotation of a camera pitched down by ``pitch`` and rolled by ``roll``;
    world axes x right, y down (gravity), z forward."""
    p, r = np.deg2rad(pitch_deg), np.deg2rad(roll_deg)
    pitch = np.array([[1, 0, 0], [0, np.cos(p), np.sin(p)], [0, -np.sin(p), np.cos(p)]])
    roll = np.array([[np.cos(r), -np.sin(r), 0], [np.sin(r), np.cos(r), 0], [0, 0, 1]])
    return pitch @ roll


def _render(planes: list[tuple[tuple[float, float, float], float]], rotation: np.ndarray,
            camera: Intrinsics = CAMERA) -> tuple[np.ndarray, np.ndarray]:
    """Depth (metres) and the index of the plane hit per pixel, for a camera at the world
    origin looking through planes ``n . x = d`` (unit ``n`` pointing away from the camera)."""
    u, v = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
    rays = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy,
                     np.ones(u.shape)], axis=-1) @ rotation.T  # camera z = 1 -> t is depth
    best = np.full(u.shape, np.inf)
    index = np.full(u.shape, -1)
    for i, (normal, d) in enumerate(planes):
        along = rays @ np.asarray(normal, dtype=np.float64)
        with np.errstate(divide="ignore"):
            t = np.where(along > 1e-9, d / along, np.inf)
        closer = t < best
        best[closer], index[closer] = t[closer], i
    depth = np.where(np.isfinite(best) & (best < 20.0), best, 0.0).astype(np.float32)
    return depth, index


def _interior(index: np.ndarray, plane: int, margin: int = 12) -> np.ndarray:
    """Pixels of ``plane`` whose (2 margin + 1)^2 neighbourhood is all on that plane."""
    from scipy.ndimage import binary_erosion

    return binary_erosion(index == plane, structure=np.ones((2 * margin + 1,) * 2))


ROOM = [((0.0, 1.0, 0.0), 1.5),  # floor 1.5 m below the camera
        ((0.0, 0.0, 1.0), 6.0),  # wall 6 m ahead
        ((np.sin(np.deg2rad(30)), -np.cos(np.deg2rad(30)), 0.0),  # ceiling sloping 30 degrees
         1.0 * np.cos(np.deg2rad(30)))]


@pytest.fixture(scope="module")
def room():
    rotation = _rotation(6.0, 8.0)
    depth, index = _render(ROOM, rotation)
    return depth, index, rotation, hha_channels(depth, CAMERA)


def test_room_gravity_is_recovered(room) -> None:
    _, _, rotation, channels = room
    expected = rotation.T @ np.array([0.0, 1.0, 0.0])  # world down in the camera frame
    assert np.degrees(np.arccos(np.clip(channels.gravity @ expected, -1, 1))) < 0.5


def test_room_angles_match_each_plane_tilt(room) -> None:
    depth, index, _, channels = room
    hha = channels.to_uint8()
    for plane, degrees in ((0, 0.0), (1, 90.0), (2, 150.0)):
        inside = _interior(index, plane)
        assert inside.sum() > 2000
        np.testing.assert_allclose(channels.angle[inside], degrees, atol=0.5)
        assert abs(int(np.median(hha[..., 2][inside])) - (degrees + ANGLE_OFFSET)) <= 1
    assert np.median(hha[..., 2][_interior(index, 0)]) == FLOOR
    assert np.median(hha[..., 2][_interior(index, 1)]) == WALL


def test_room_height_and_disparity(room) -> None:
    depth, index, rotation, channels = room
    # gravity is estimated to ~0.2 degrees (the mixed normals along the creases): a few cm
    # over the 6 m room
    assert channels.floor_cm == pytest.approx(-150.0, abs=3.0)
    floor = _interior(index, 0)
    np.testing.assert_allclose(channels.height[floor], 0.0, atol=4.0)
    # wall height: 150 cm minus the world-down coordinate of the wall point
    u, v = np.meshgrid(np.arange(640), np.arange(480))
    cam = np.stack([(u - CAMERA.cx) / CAMERA.fx, (v - CAMERA.cy) / CAMERA.fy,
                    np.ones(u.shape)], axis=-1) * depth[..., None]
    world_down = (cam @ rotation.T)[..., 1] * 100.0
    wall = _interior(index, 1)
    np.testing.assert_allclose(channels.height[wall], 150.0 - world_down[wall], atol=4.0)
    valid = depth > 0
    np.testing.assert_allclose(channels.disparity[valid],
                               310.0 / np.maximum(depth[valid], 1.0), rtol=1e-5)
    hha = channels.to_uint8()
    near = valid & (depth <= 1.2)
    assert np.all(hha[..., 0][near] == 255)  # saturates below 1.216 m


def test_single_tilted_plane_gives_its_normal_as_gravity() -> None:
    # camera 0.6 m above a floor, pitched 35 and rolled 12 degrees: gravity is the floor's
    # normal; the floor is higher than -90 cm, so the release's 130 cm camera height applies
    rotation = _rotation(35.0, 12.0)
    depth, index = _render([((0.0, 1.0, 0.0), 0.6)], rotation)
    channels = hha_channels(depth, CAMERA)
    expected = rotation.T @ np.array([0.0, 1.0, 0.0])
    assert np.degrees(np.arccos(channels.gravity @ expected)) < 0.1
    assert channels.floor_cm == -130.0
    inside = _interior(index, 0)
    np.testing.assert_allclose(channels.height[inside], 70.0, atol=0.5)
    hha = channels.to_uint8()
    assert np.all(hha[..., 2][inside] == FLOOR)
    assert np.all(hha[..., 1][inside] == 70)


def test_a_vertical_plane_is_perpendicular_to_gravity() -> None:
    # normals of a wall tilted about the vertical axis by 40 degrees: angle 90 wherever gravity
    # (here the camera's y axis, nothing else in view) points
    yaw = np.deg2rad(40.0)
    depth, index = _render([((np.sin(yaw), 0.0, np.cos(yaw)), 2.0)], np.eye(3))
    normals = surface_normals(depth, CAMERA, radius=3)
    inside = _interior(index, 0)
    np.testing.assert_allclose(normals[inside], np.broadcast_to(
        [np.sin(yaw), 0.0, np.cos(yaw)], normals[inside].shape), atol=1e-4)  # float32 depth
    hha = encode_hha(depth, CAMERA)
    assert np.all(hha[..., 2][inside] == WALL)


def test_invalid_depth_is_zero_in_every_channel(room) -> None:
    depth = room[0].copy()
    depth[100:160, 200:300] = 0.0
    depth[:, :5] = 0.0
    hha = encode_hha(depth, CAMERA)
    assert hha.dtype == np.uint8 and hha.shape == (480, 640, 3)
    assert np.all(hha[depth == 0] == 0)
    assert np.all(hha[depth > 0][:, 0] > 0)
    # next to the hole the plane fits use the remaining pixels: the same angles as without it
    index = room[1]
    one_plane = np.zeros_like(depth, dtype=bool)
    for plane in range(3):
        one_plane |= _interior(index, plane, margin=4)
    ring = np.zeros_like(one_plane)
    ring[96:100, 200:300] = ring[160:164, 200:300] = True
    ring &= one_plane
    assert ring.sum() > 100
    complete = encode_hha(room[0], CAMERA)
    assert np.abs(hha[..., 2][ring].astype(int) - complete[..., 2][ring]).max() <= 1
    empty = encode_hha(np.zeros((48, 64), np.float32), CAMERA)
    assert empty.shape == (48, 64, 3) and not empty.any()


def test_isolated_pixels_get_the_release_angle_of_an_undefined_normal() -> None:
    depth = np.zeros((40, 40), np.float32)
    depth[20, 20] = 2.0  # one point: no plane
    channels = hha_channels(depth, CAMERA.scaled(40, 40))
    assert channels.angle[20, 20] == 180.0
    assert encode_hha(depth, CAMERA)[20, 20, 2] == CEILING


def test_bad_depth_is_refused() -> None:
    with pytest.raises(InvalidDataError, match=r"\(H, W\) depth"):
        encode_hha(np.zeros((4, 4, 1)), CAMERA)
    with pytest.raises(InvalidDataError, match="finite, non-negative"):
        encode_hha(np.full((4, 4), np.nan), CAMERA)
    with pytest.raises(InvalidDataError, match="finite, non-negative"):
        encode_hha(np.full((4, 4), -1.0), CAMERA)


def test_gravity_starts_from_the_camera_down_axis_without_normals() -> None:
    assert np.array_equal(gravity_direction(np.full((4, 4, 3), np.nan)), [0.0, 1.0, 0.0])


def test_importing_the_encoding_does_not_import_torch() -> None:
    code = ("import sys, baselines.hha; "
            "assert 'torch' not in sys.modules and 'baselines.hha.segmenter' not in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


# -- the real NYUv2 samples (floor-to-wall scenes) ------------------------------------------------

@pytest.fixture(scope="module")
def nyu_frames(nyuv2_samples_dir):
    frames = list(READERS.create("nyuv2", path=str(nyuv2_samples_dir)))
    return [(f, hha_channels(f.depth, f.intrinsics)) for f in frames]


def test_nyuv2_hha_is_finite_uint8_and_zero_where_depth_is_missing(nyu_frames) -> None:
    for frame, channels in nyu_frames:
        hha = channels.to_uint8()
        assert hha.dtype == np.uint8 and hha.shape == frame.depth.shape + (3,)
        valid = frame.depth > 0
        assert np.all(hha[~valid] == 0)
        for c in (channels.disparity, channels.height, channels.angle):
            assert np.all(np.isfinite(c[valid]))
        # depth under 10 m: disparity at least 31
        assert hha[..., 0][valid].min() >= 31
        assert np.array_equal(encode_hha(frame.depth, frame.intrinsics), hha)


def test_nyuv2_gravity_is_the_floor_normal(nyu_frames) -> None:
    for frame, channels in nyu_frames:
        floor = (frame.labels == 1) & (frame.depth > 0)
        normals = surface_normals(frame.depth, frame.intrinsics, radius=10)[floor]
        mean = np.nanmean(normals, axis=0)
        mean /= np.linalg.norm(mean)
        assert np.degrees(np.arccos(mean @ channels.gravity)) < 5.0
        assert channels.gravity[1] > 0.85  # roughly the camera's down axis


def test_nyuv2_floor_and_wall_angles(nyu_frames) -> None:
    for frame, channels in nyu_frames:
        hha = channels.to_uint8()
        valid = frame.depth > 0
        floor = hha[..., 2][(frame.labels == 1) & valid]
        wall = hha[..., 2][(frame.labels == 0) & valid]
        assert floor.size > 10_000 and wall.size > 10_000
        # per-pixel normals from 7x7 windows of Kinect depth scatter by ~10 degrees
        assert FLOOR <= np.median(floor) <= FLOOR + 15
        assert abs(np.median(wall) - WALL) <= 10
        assert np.mean(np.abs(floor.astype(int) - FLOOR) < 20) > 0.7


def test_nyuv2_height_increases_upwards(nyu_frames) -> None:
    for frame, channels in nyu_frames:
        valid = frame.depth > 0
        rows = np.nonzero(valid)[0]
        height = channels.height[valid]
        # Spearman rank correlation of image row and height: the lower in the image the lower
        rank_rows = np.argsort(np.argsort(rows)).astype(float)
        rank_height = np.argsort(np.argsort(height)).astype(float)
        assert np.corrcoef(rank_rows, rank_height)[0, 1] < -0.5
        floor = np.median(channels.height[(frame.labels == 1) & valid])
        wall = np.median(channels.height[(frame.labels == 0) & valid])
        assert 0 <= floor < 20 and wall > floor + 50
        assert channels.floor_cm < -90.0  # the floor is in view


# -- HHASegmenter --------------------------------------------------------------------------------

class TinyRGBHHA(nn.Module):
    """RGB and HHA concatenated, one 3x3 convolution to 3 classes at half resolution."""

    def __init__(self) -> None:
        super().__init__()
        torch.manual_seed(0)
        self.conv = nn.Conv2d(6, 3, 3, stride=2, padding=1)

    def forward(self, rgb: torch.Tensor, hha: torch.Tensor) -> torch.Tensor:
        return self.conv(torch.cat([rgb, hha], 1))


def _segmenter(backend: str = "torch"):
    from baselines.hha import HHASegmenter

    return HHASegmenter(name="tiny-hha", module=TinyRGBHHA(), num_classes=3,
                        class_names=("a", "b", "c"), uses_depth=True, default_size=(48, 64),
                        normalization=Normalization(), backend=backend,
                        config={"test": "hha"})


def test_hha_segmenter_inputs(nyu_frames) -> None:
    from baselines.hha.segmenter import HHA_MEAN, HHA_STD, hha_input

    seg = _segmenter()
    assert seg.input_names == ("rgb", "hha") and seg.uses_depth
    a, b = seg.example_inputs(32, 40), seg.example_inputs(32, 40)
    assert [tuple(t.shape) for t in a] == [(1, 3, 32, 40), (1, 3, 32, 40)]
    assert all(torch.equal(x, y) for x, y in zip(a, b, strict=True))
    assert not torch.equal(a[0], a[1])
    frame = nyu_frames[0][0]
    rgb, hha = seg.preprocess(frame)
    assert rgb.shape == (1, 3, 48, 64) and hha.shape == (1, 3, 48, 64)
    expected = hha_input(encode_hha(frame.depth, frame.intrinsics), (48, 64))
    torch.testing.assert_close(hha, expected)
    # standardisation: an HHA of zeros is -mean/std per channel; full resolution is not resized
    zeros = hha_input(np.zeros((8, 8, 3), np.uint8), (8, 8))
    torch.testing.assert_close(zeros[0, :, 0, 0],
                               -torch.tensor(HHA_MEAN) / torch.tensor(HHA_STD))
    full = hha_input(np.full((8, 8, 3), 255, np.uint8), (8, 8))
    torch.testing.assert_close(full[0, :, 3, 3],
                               (1 - torch.tensor(HHA_MEAN)) / torch.tensor(HHA_STD))


def test_hha_segmenter_predicts_with_torch_and_onnxruntime(nyu_frames) -> None:
    pytest.importorskip("onnxruntime")
    frame = nyu_frames[1][0]
    torch_seg, ort_seg = _segmenter(), _segmenter("onnxruntime")
    inputs = torch_seg.preprocess(frame)
    torch.testing.assert_close(ort_seg.logits(inputs), torch_seg.logits(inputs),
                               atol=1e-5, rtol=1e-5)
    obs = torch_seg.predict(frame, k=2)
    assert obs.classes.shape[:2] == frame.depth.shape and obs.num_classes == 3
    assert set(torch_seg.last_timings) == {"preprocess", "network", "postprocess"}
    assert np.array_equal(ort_seg.predict(frame, k=2).classes[..., 0], obs.classes[..., 0])


def test_hha_segmenter_onnx_inputs_are_named_rgb_and_hha(tmp_path) -> None:
    ort = pytest.importorskip("onnxruntime")
    from evsmap.models.onnx_export import export_onnx

    seg = _segmenter()
    inputs = seg.example_inputs(32, 48)
    path = export_onnx(seg.module, inputs, seg.input_names, tmp_path / "tiny.onnx")
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    assert [i.name for i in session.get_inputs()] == ["rgb", "hha"]
    out = session.run(None, {n: t.numpy() for n, t in zip(seg.input_names, inputs,
                                                            strict=True)})[0]
    with torch.no_grad():
        np.testing.assert_allclose(out, seg.module(*inputs).numpy(), atol=1e-5, rtol=1e-5)


def test_point_cloud_frames_are_refused() -> None:
    seg = _segmenter()
    cloud = Frame.from_points(np.zeros((4, 3), np.float32), np.eye(4), 0.0, name="cloud")
    with pytest.raises(InvalidDataError, match="needs RGB-D images"):
        seg.preprocess(cloud)


def test_the_network_factory_makes_an_hha_segmenter() -> None:
    from baselines.hha import HHASegmenter
    from baselines.networks.common import DatasetSetting, make_segmenter
    from baselines.networks.common import _card as card_of

    card = card_of("tiny-hha", "tiny", "none", "nyuv2", DatasetSetting(input_size=(48, 64)),
                   "hha", "")
    seg = make_segmenter(name="tiny-hha", module=TinyRGBHHA(), card=card, num_classes=40,
                         depth="hha", backend="torch", weights=None, input_size=None,
                         config={})
    assert isinstance(seg, HHASegmenter) and seg.input_names == ("rgb", "hha")
