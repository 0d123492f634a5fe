"""How each network expects its inputs; no torch here, so the registry can name the networks
without importing it."""

from __future__ import annotations

from dataclasses import dataclass

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


@dataclass(frozen=True)
class Normalization:
    """How a network expects its inputs.

    RGB is scaled to [0, 1], then ``(x - rgb_mean) / rgb_std`` per channel. Depth (metres) is
    standardised as ``(d - depth_mean) / depth_std``; invalid pixels (depth 0) are set to 0 after
    standardisation, i.e. to the mean depth, as ESANet's preprocessing does.
    """

    rgb_mean: tuple[float, float, float] = IMAGENET_MEAN
    rgb_std: tuple[float, float, float] = IMAGENET_STD
    depth_mean: float = 2.8419494
    depth_std: float = 1.4172594

    def as_dict(self) -> dict:
        return {"rgb_mean": list(self.rgb_mean), "rgb_std": list(self.rgb_std),
                "depth_mean": self.depth_mean, "depth_std": self.depth_std}


INDOOR = Normalization()
"""ImageNet RGB statistics; NYUv2 training-set depth statistics (ESANet's, converted to metres)."""
