"""HHA (Gupta et al., ECCV 2014): the depth encoding of the RGB-D networks that read horizontal
disparity, height above ground and angle with gravity instead of depth, and their segmenter.

* :mod:`baselines.hha.encoding` (numpy): :func:`encode_hha`, ``(H, W)`` metres and the camera to
  ``(H, W, 3)`` uint8, and its steps (:func:`hha_channels`, :func:`surface_normals`,
  :func:`gravity_direction`); ``docs/baselines/hha.md`` documents each choice.
* :mod:`baselines.hha.segmenter` (torch): :class:`HHASegmenter`, an evsmap network segmenter
  whose inputs are ``rgb`` and ``hha``; loaded on first use, so importing this package imports
  no torch.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from baselines.hha.encoding import (
    HHA,
    encode_hha,
    gravity_direction,
    hha_channels,
    surface_normals,
)

if TYPE_CHECKING:
    from baselines.hha.segmenter import HHASegmenter

__all__ = ["HHA", "HHASegmenter", "encode_hha", "gravity_direction", "hha_channels",
           "surface_normals"]


def __getattr__(name: str) -> Any:
    # HHASegmenter imports torch: load it only when asked for
    if name == "HHASegmenter":
        from baselines.hha.segmenter import HHASegmenter

        return HHASegmenter
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
