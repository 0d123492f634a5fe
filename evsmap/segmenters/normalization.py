"""How each network expects its inputs; no torch here, so the registry can name the networks
without importing it.

Depth reaches every network from a :class:`~evsmap.data.Frame` in metres. A network trained on a
dataset's own depth files expects that file's units, so a :class:`Normalization` names a depth
encoding that turns metres back into them before the standardisation:

* ``metres`` - metres as they are (FEAGNet; ESANet's NYUv2 statistics converted to metres: the
  NYUv2 files ESANet reads hold millimetres, a linear factor).
* ``sunrgbd-png`` - the value of SUN RGB-D's ``depth_bfx`` PNG, which ESANet reads without
  decoding: millimetres rotated left by 3 bits in 16 bits (``(mm << 3 | mm >> 13) & 0xFFFF``,
  i.e. 8 x mm below 8.192 m and wrapped above, as the file holds it).
* ``cityscapes-disparity`` - the value of Cityscapes' disparity PNG, which ESANet reads raw:
  ``256 * B f / depth + 1`` with the frame's stereo baseline times focal length
  (:attr:`Frame.disparity_scale`), 0 where depth is invalid.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from evsmap.errors import InvalidDataError

if TYPE_CHECKING:
    from evsmap.data import Frame

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
DEPTH_ENCODINGS = ("metres", "sunrgbd-png", "cityscapes-disparity")


@dataclass(frozen=True)
class Normalization:
    """How a network expects its inputs.

    RGB is scaled to [0, 1], then ``(x - rgb_mean) / rgb_std`` per channel. Depth is encoded
    (:meth:`encode_depth`) into the units of ``depth_encoding`` and standardised as
    ``(d - depth_mean) / depth_std`` in those units; invalid pixels (depth 0) are set to 0 after
    standardisation, i.e. to the mean depth, as ESANet's preprocessing does.
    """

    rgb_mean: tuple[float, float, float] = IMAGENET_MEAN
    rgb_std: tuple[float, float, float] = IMAGENET_STD
    depth_mean: float = 2.84194941272766
    depth_std: float = 1.4172594281672277
    depth_encoding: str = "metres"

    def __post_init__(self) -> None:
        if self.depth_encoding not in DEPTH_ENCODINGS:
            raise ValueError(f"depth_encoding must be one of {DEPTH_ENCODINGS}, got "
                             f"{self.depth_encoding!r}")

    def as_dict(self) -> dict:
        return {"rgb_mean": list(self.rgb_mean), "rgb_std": list(self.rgb_std),
                "depth_mean": self.depth_mean, "depth_std": self.depth_std,
                "depth_encoding": self.depth_encoding}

    def encode_depth(self, depth: np.ndarray, frame: Frame | None = None) -> np.ndarray:
        """``depth`` (metres, 0 invalid) in this encoding's units, ``float32``, 0 still
        invalid. ``frame`` supplies what an encoding needs beyond the depth (the disparity
        scale of a Cityscapes frame)."""
        depth = np.asarray(depth, dtype=np.float32)
        if self.depth_encoding == "metres":
            return depth
        valid = depth > 0
        out = np.zeros(depth.shape, dtype=np.float32)
        if self.depth_encoding == "sunrgbd-png":
            mm = np.rint(depth.astype(np.float64) * 1000.0).astype(np.int64)
            png = ((mm << 3) | (mm >> 13)) & 0xFFFF
            out[valid] = png[valid]
            return out
        scale = None if frame is None else frame.disparity_scale
        if scale is None:
            name = f"frame {frame.name!r}" if frame is not None and frame.name else "this frame"
            raise InvalidDataError(
                f"{name} has no stereo disparity scale (baseline x focal length): a network "
                f"trained on Cityscapes disparity needs frames from the Cityscapes reader")
        png = np.rint(256.0 * float(scale) / depth[valid].astype(np.float64) + 1.0)
        out[valid] = png
        return out


INDOOR = Normalization()
"""ImageNet RGB statistics; NYUv2 training-set depth statistics (ESANet's
``2841.94941272766 +- 1417.2594281672277`` mm, in metres)."""

SUNRGBD_ESANET = Normalization(depth_mean=19025.14930492213, depth_std=9880.916071806689,
                               depth_encoding="sunrgbd-png")
"""ESANet's SUN RGB-D statistics, over the ``depth_bfx`` PNG values it reads."""

CITYSCAPES_ESANET = Normalization(depth_mean=9069.706336834102, depth_std=7178.335960071306,
                                  depth_encoding="cityscapes-disparity")
"""ESANet's Cityscapes statistics, over the raw disparity PNG values it reads."""
