"""Depth encodings of :mod:`evsmap.segmenters.normalization`: metres back into the units of the
depth files each network was trained on."""

from __future__ import annotations

import numpy as np
import pytest

from baselines.segmenters import _ESANET_DEPTH
from evsmap.data import Frame, Intrinsics
from evsmap.errors import InvalidDataError
from evsmap.segmenters.normalization import INDOOR, Normalization


def _frame(depth, **extra) -> Frame:
    h, w = depth.shape
    return Frame(rgb=np.zeros((h, w, 3), np.uint8), depth=np.asarray(depth, np.float32),
                 intrinsics=Intrinsics(100.0, 100.0, w / 2, h / 2, w, h), pose=np.eye(4),
                 timestamp=0.0, name="f7", **extra)


def test_nyuv2_statistics_are_esanets_in_metres():
    assert INDOOR.depth_encoding == "metres"
    assert INDOOR.depth_mean * 1000 == pytest.approx(2841.94941272766, rel=1e-15)
    assert INDOOR.depth_std * 1000 == pytest.approx(1417.2594281672277, rel=1e-15)
    assert _ESANET_DEPTH["nyuv2"] is INDOOR
    depth = np.array([[0.0, 1.5]], np.float32)
    assert np.array_equal(INDOOR.encode_depth(depth), depth)


def test_sunrgbd_png_is_the_rotated_millimetres_esanet_reads():
    enc = _ESANET_DEPTH["sunrgbd"]
    assert (enc.depth_mean, enc.depth_std) == (19025.14930492213, 9880.916071806689)
    depth = np.array([[0.0, 1.234, 8.191, 8.192, 9.0]], np.float32)
    png = enc.encode_depth(depth)
    # below 8.192 m the rotation is a shift (x 8); from there the top bits wrap to the bottom,
    # as in the toolbox's depth_bfx files
    assert png[0].tolist() == [0, 9872, 65528, 1, (9000 << 3 & 0xFFFF) | (9000 >> 13)]


def test_cityscapes_disparity_needs_the_frame_scale():
    enc = _ESANET_DEPTH["cityscapes"]
    depth = np.array([[0.0, 10.0, 473.6]], np.float32)
    png = enc.encode_depth(depth, _frame(depth, disparity_scale=473.6))
    assert png[0].tolist() == [0.0, 12125.0, 257.0]  # rint(256 * 47.36 + 1): PNG integers
    with pytest.raises(InvalidDataError, match="frame 'f7' has no stereo disparity scale"):
        enc.encode_depth(depth, _frame(depth))


def test_bad_values_are_refused():
    with pytest.raises(ValueError, match="depth_encoding must be one of"):
        Normalization(depth_encoding="millimetres")
    depth = np.ones((2, 2), np.float32)
    for bad in (0.0, -1.0, float("nan"), True):
        with pytest.raises(InvalidDataError, match="disparity_scale must be a positive number"):
            _frame(depth, disparity_scale=bad)
