"""The compiled per-pixel colour of the synthetic renderer is the numpy reference, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from evsmap.synth import shading
from evsmap.synth.sequence import SyntheticSequence


@pytest.mark.parametrize("scene", ["living_room", "bedroom", "office", "kitchen"])
def test_compiled_colour_is_the_numpy_reference(scene):
    seq = SyntheticSequence(scene=scene, seed=2, frames=12, width=160, height=120)
    renderer = seq.renderer
    for index in (0, 5, 11):
        pose = seq.pose(index)
        c = renderer.cast(seq.intrinsics, pose)
        args = (pose[:3, 3], c["dirs"], c["depth"], c["normals"], c["part"], renderer._albedo,
                renderer._lights)
        compiled = shading.linear_colour(*args)
        reference = shading.linear_colour_numpy(*args)
        assert compiled.dtype == reference.dtype == np.float64
        assert np.array_equal(compiled, reference)


def test_pixels_without_a_hit_take_the_last_albedo_row():
    origin = np.zeros(3)
    dirs = np.ones((2, 2, 3))
    depth = np.ones((2, 2), np.float32)
    normals = np.tile(np.float32([0, 0, -1]), (2, 2, 1))
    part = np.array([[-1, 0], [1, -1]], np.int32)
    albedo = np.float32([[1, 0, 0], [0, 1, 0], [0, 0, 0]])
    lights = np.float32([[0, 0, 3]])
    out = shading.linear_colour(origin, dirs, depth, normals, part, albedo, lights)
    assert np.array_equal(out, shading.linear_colour_numpy(origin, dirs, depth, normals, part,
                                                           albedo, lights))
    assert np.all(out[0, 0] == 0) and np.all(out[1, 1] == 0)
    assert out[0, 1, 0] > 0 and out[0, 1, 1] == 0 and out[1, 0, 1] > 0


def test_hash_values_lie_in_the_unit_interval():
    k = np.arange(-5, 5, dtype=np.int64) + (1 << 20)
    v = shading.hash01(k, k[::-1], k, np.zeros_like(k))
    assert v.min() >= 0.0 and v.max() < 1.0 and len(np.unique(v)) == len(v)
