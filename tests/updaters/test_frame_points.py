"""FramePoints: the compiled grouping kernel and the numpy path give the same voxels."""

from __future__ import annotations

import numpy as np
import pytest

import evsmap.mapping.front_end as front_end
from evsmap.data import Frame, Intrinsics
from evsmap.mapping.keys import pack
from evsmap.mapping.raycast import octomap_keys
from evsmap.registry import READERS
from evsmap.testing import missing


@pytest.fixture(scope="module")
def tum_frame(tum_dir):
    return READERS.create("tum", path=str(tum_dir)).frame(5)


def _both(frame, resolution, max_range=5.0, discretize=True):
    return [front_end.FramePoints(frame, resolution, max_range, discretize, kernels)
            for kernels in ("compiled", "reference")]


@pytest.mark.parametrize("resolution", [0.02, 0.05, 0.1])
def test_kernel_and_numpy_grouping_agree(tum_frame, resolution):
    if front_end.group_points is None:
        missing("numba cannot be imported: the compiled grouping is untested")
    a, b = _both(tum_frame, resolution)
    assert np.array_equal(a.voxel_codes, b.voxel_codes)
    assert np.array_equal(a.point_voxel, b.point_voxel)
    assert np.array_equal(a.endpoint, b.endpoint)
    assert np.array_equal(a.rays, b.rays)
    # each point's voxel is the OctoMap key of the point
    keys, ok = octomap_keys(a.points.astype(np.float32), resolution)
    assert ok.all()
    assert np.array_equal(a.voxel_codes[a.point_voxel], pack(keys))


def test_points_outside_the_key_range_are_left_out():
    # a 4x1 image whose last pixel lies beyond OctoMap's 16-bit key range at 1 mm
    intr = Intrinsics(1.0, 1.0, 1.5, 0.0, 4, 1)
    depth = np.array([[1.0, 2.0, 0.0, 40.0]], dtype=np.float32)
    frame = Frame(rgb=np.zeros((1, 4, 3), np.uint8), depth=depth, intrinsics=intr,
                  pose=np.eye(4), timestamp=0.0)
    for points in _both(frame, 0.001, max_range=-1.0, discretize=False):
        assert points.point_voxel.tolist()[:2] != [-1, -1] and points.point_voxel[2] == -1
        assert len(points.voxel_codes) == 2
        assert points.endpoint.tolist() == [True, True, False]


def test_a_huge_box_falls_back_to_sorting(monkeypatch, tum_frame):
    monkeypatch.setattr(front_end, "_DENSE_BOX", 10)
    a, b = _both(tum_frame, 0.05)
    assert np.array_equal(a.voxel_codes, b.voxel_codes)
    assert np.array_equal(a.point_voxel, b.point_voxel)


def test_the_kernels_switch_is_checked():
    from evsmap.errors import InvalidDataError
    from evsmap.updaters.orgb import ORGBMap

    assert ORGBMap().kernels == "compiled" and ORGBMap(kernels="reference").kernels == "reference"
    with pytest.raises(InvalidDataError, match="kernels must be one of compiled, reference"):
        ORGBMap(kernels="fast")
