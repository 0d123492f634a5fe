"""SwiftNet-RN18 (single scale), the network: "In Defense of Pre-trained ImageNet Architectures
for Real-time Semantic Segmentation of Road-driving Images" (Orsic, Kreso, Bevandic, Segvic;
CVPR 2019), written from the official code (orsic/swiftnet, ``configs/rn18_single_scale.py``,
``models/resnet/resnet_single_scale.py``, ``models/util.py``, ``models/semseg.py``;
docs/baselines/swiftnet-rn18.md).

Layout: a ResNet-18 encoder (:mod:`baselines.backbones.resnet`, torchvision's parameter names
under ``backbone.``, so an ImageNet state dict loads into it) whose four stage outputs are the
skips (the official blocks return their sum "before" the ReLU too, but that ReLU is in place, so
the skips are the activated outputs, as here); a spatial pyramid
pooling on the 1/32 map (BN-ReLU-1x1 to 128, three levels that average-pool it to grids of 8, 4
and 2 rows, as many columns as the aspect ratio gives, each BN-ReLU-1x1 to 42 and upsampled
back, concatenated with it and fused by BN-ReLU-1x1 to 128); three upsampling modules
(1/32 -> 1/16 -> 1/8 -> 1/4): the skip through BN-ReLU-1x1 to 128, added to the bilinearly
upsampled features, BN-ReLU-3x3; a BN-ReLU-1x1 classifier (with bias) and a bilinear upsampling
to the input. 11,797,071 parameters for 19 classes (11,176,512 of them the encoder).

The official model standardises the image inside (buffers, no parameters: Cityscapes mean
(73.15, 82.90, 72.3) and std (47.67, 48.49, 47.73) on 0-255 RGB); here the card's normalisation
does it before the network (:mod:`baselines.networks.swiftnet`).

This module imports torch; :mod:`baselines.networks.swiftnet` registers the network without it.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from baselines.backbones.resnet import ResNet, resnet18

__all__ = ["BNReLUConv", "SpatialPyramidPooling", "SwiftNet", "UpsampleBlend", "swiftnet_rn18"]

_SPP_BN_MOMENTUM = 0.005  # the official pyramid's BatchNorm momentum (0.01 / 2)


def _up(x: torch.Tensor, size: tuple[int, int] | torch.Size) -> torch.Tensor:
    return F.interpolate(x, size=tuple(size), mode="bilinear", align_corners=False)


class BNReLUConv(nn.Sequential):
    """BatchNorm, ReLU, conv (``kernel``, same size).

    Args:
        in_channels, out_channels: channels in and out.
        kernel: kernel size (1 or 3).
        bias: the conv has a bias (the classifier's does).
        momentum: the BatchNorm momentum.
    """

    def __init__(self, *, in_channels: int, out_channels: int, kernel: int = 1,
                 bias: bool = False, momentum: float = 0.1) -> None:
        super().__init__()
        self.norm = nn.BatchNorm2d(in_channels, momentum=momentum)
        self.relu = nn.ReLU()
        self.conv = nn.Conv2d(in_channels, out_channels, kernel, padding=kernel // 2, bias=bias)


class SpatialPyramidPooling(nn.Module):
    """SwiftNet's pyramid pooling on the last encoder map.

    Args:
        in_channels: encoder channels.
        channels: width of the reduced map and of the output (128).
        level_channels: width of each pooled level (128 // 3 = 42).
        grids: rows of each level's pooling grid; its columns follow the map's aspect ratio.
    """

    def __init__(self, *, in_channels: int, channels: int = 128, level_channels: int = 42,
                 grids: tuple[int, ...] = (8, 4, 2)) -> None:
        super().__init__()
        self.grids = grids
        self.reduce = BNReLUConv(in_channels=in_channels, out_channels=channels,
                                 momentum=_SPP_BN_MOMENTUM)
        self.levels = nn.ModuleList(
            BNReLUConv(in_channels=channels, out_channels=level_channels,
                       momentum=_SPP_BN_MOMENTUM) for _ in grids)
        self.fuse = BNReLUConv(in_channels=channels + len(grids) * level_channels,
                               out_channels=channels, momentum=_SPP_BN_MOMENTUM)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        size = (int(x.shape[-2]), int(x.shape[-1]))  # plain ints, also when traced
        x = self.reduce(x)
        levels = [x]
        for rows, level in zip(self.grids, self.levels, strict=True):
            pooled = F.adaptive_avg_pool2d(x, (rows, max(1, round(size[1] / size[0] * rows))))
            levels.append(_up(level(pooled), size))
        return self.fuse(torch.cat(levels, dim=1))


class UpsampleBlend(nn.Module):
    """One decoder step: the skip through BN-ReLU-1x1, plus the upsampled features, then
    BN-ReLU-3x3.

    Args:
        skip_channels: the encoder skip's channels.
        channels: the decoder width (128).
    """

    def __init__(self, *, skip_channels: int, channels: int = 128) -> None:
        super().__init__()
        self.skip = BNReLUConv(in_channels=skip_channels, out_channels=channels)
        self.blend = BNReLUConv(in_channels=channels, out_channels=channels, kernel=3)

    def forward(self, x: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        skip = self.skip(skip)
        return self.blend(_up(x, skip.shape[-2:]) + skip)


class SwiftNet(nn.Module):
    """SwiftNet, single scale, on a torchvision-style ResNet.

    Args:
        num_classes: output classes.
        backbone: the encoder (BasicBlock ResNet; its ``channels`` give the skip widths).
        channels: decoder and pyramid width (128).
    """

    def __init__(self, *, num_classes: int = 19, backbone: ResNet | None = None,
                 channels: int = 128) -> None:
        super().__init__()
        self.num_classes = num_classes
        self.backbone = backbone if backbone is not None else resnet18()
        c2, c3, c4, c5 = self.backbone.channels
        self.spp = SpatialPyramidPooling(in_channels=c5, channels=channels,
                                         level_channels=channels // 3)
        self.up = nn.ModuleList(UpsampleBlend(skip_channels=c, channels=channels)
                                for c in (c4, c3, c2))
        self.classifier = BNReLUConv(in_channels=channels, out_channels=num_classes, bias=True)

    def forward(self, rgb: torch.Tensor) -> torch.Tensor:
        skips = self.backbone.forward_features(rgb)
        x = self.spp(skips[-1])
        for up, skip in zip(self.up, reversed(skips[:-1]), strict=True):
            x = up(x, skip)
        return _up(self.classifier(x), rgb.shape[-2:])


def swiftnet_rn18(*, num_classes: int = 19) -> SwiftNet:
    """SwiftNet-RN18 single scale as published (ResNet-18, 128 decoder channels)."""
    return SwiftNet(num_classes=num_classes, backbone=resnet18())
