"""DABNet, the network: "DABNet: Depth-wise Asymmetric Bottleneck for Real-time Semantic
Segmentation" (Li, Yun, Kim, Kim; BMVC 2019), written from the official code
(Reagan1311/DABNet, ``model/DABNet.py``; docs/baselines/dabnet.md).

Layout: a three-conv stem to 1/2 (32 channels), concatenated with the image average-pooled to
the same size; a downsampling block to 1/4 and three DAB modules (dilation 2); the same
concatenation with the image at 1/4; a downsampling block to 1/8 and six DAB modules
(dilations 4, 4, 8, 8, 16, 16); the concatenation with the image at 1/8; a 1x1 classifier and a
bilinear upsampling to the input. Every BatchNorm has ``eps=1e-3`` and is followed by a
per-channel PReLU. 756,643 parameters for 19 classes. The input height and width must
be multiples of 8 (as in the official code, a widening downsampling block concatenates a
stride-2 conv, which rounds up, with a 2x2 max-pool, which rounds down).

A DAB module (depth-wise asymmetric bottleneck): BN-PReLU, a 3x3 conv halving the channels,
two depth-wise branches of a 3x1 and a 1x3 conv (one plain, one dilated), their sum, BN-PReLU,
a 1x1 conv back to the input width and the residual.

This module imports torch; :mod:`baselines.networks.dabnet` registers the network without it.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["BNPReLU", "ConvBNPReLU", "DABModule", "DABNet", "DownsamplingBlock", "dabnet"]

_BN_EPS = 1e-3


class BNPReLU(nn.Sequential):
    """BatchNorm (``eps=1e-3``) then a per-channel PReLU.

    Args:
        channels: the feature channels.
    """

    def __init__(self, *, channels: int) -> None:
        super().__init__(nn.BatchNorm2d(channels, eps=_BN_EPS), nn.PReLU(channels))


class ConvBNPReLU(nn.Sequential):
    """A bias-free convolution, then :class:`BNPReLU` (``activate=True``) or nothing.

    Args:
        in_channels, out_channels: channels in and out.
        kernel: kernel size ``(kh, kw)``.
        stride: stride.
        dilation: dilation ``(dh, dw)``; the padding keeps the size (``dilation * (k // 2)``).
        groups: convolution groups (``in_channels`` for a depth-wise conv).
        activate: add the BN-PReLU.
    """

    def __init__(self, *, in_channels: int, out_channels: int, kernel: tuple[int, int],
                 stride: int = 1, dilation: tuple[int, int] = (1, 1), groups: int = 1,
                 activate: bool = True) -> None:
        padding = (dilation[0] * (kernel[0] // 2), dilation[1] * (kernel[1] // 2))
        layers: list[nn.Module] = [nn.Conv2d(in_channels, out_channels, kernel, stride=stride,
                                             padding=padding, dilation=dilation, groups=groups,
                                             bias=False)]
        if activate:
            layers.append(BNPReLU(channels=out_channels))
        super().__init__(*layers)


class DABModule(nn.Module):
    """Depth-wise asymmetric bottleneck with a residual connection.

    Args:
        channels: input and output channels (the bottleneck has half).
        dilation: the dilation of the second depth-wise branch.
    """

    def __init__(self, *, channels: int, dilation: int) -> None:
        super().__init__()
        mid = channels // 2
        self.pre = BNPReLU(channels=channels)
        self.reduce = ConvBNPReLU(in_channels=channels, out_channels=mid, kernel=(3, 3))

        def depthwise(kernel: tuple[int, int], dil: tuple[int, int]) -> ConvBNPReLU:
            return ConvBNPReLU(in_channels=mid, out_channels=mid, kernel=kernel, dilation=dil,
                               groups=mid)

        self.local = nn.Sequential(depthwise((3, 1), (1, 1)), depthwise((1, 3), (1, 1)))
        self.context = nn.Sequential(depthwise((3, 1), (dilation, 1)),
                                     depthwise((1, 3), (1, dilation)))
        self.post = BNPReLU(channels=mid)
        self.expand = nn.Conv2d(mid, channels, 1, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.reduce(self.pre(x))
        y = self.post(self.local(y) + self.context(y))
        return self.expand(y) + x


class DownsamplingBlock(nn.Module):
    """Stride-2 3x3 conv; when it widens, concatenated with a 2x2 max-pool of the input (the
    conv makes the missing channels); then BN-PReLU.

    Args:
        in_channels, out_channels: channels in and out.
    """

    def __init__(self, *, in_channels: int, out_channels: int) -> None:
        super().__init__()
        self.pool = in_channels < out_channels
        conv_out = out_channels - in_channels if self.pool else out_channels
        self.conv = nn.Conv2d(in_channels, conv_out, 3, stride=2, padding=1, bias=False)
        self.post = BNPReLU(channels=out_channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.conv(x)
        if self.pool:
            y = torch.cat([y, F.max_pool2d(x, 2, stride=2)], dim=1)
        return self.post(y)


def _image_at(rgb: torch.Tensor, halvings: int) -> torch.Tensor:
    """The image average-pooled ``halvings`` times (3x3, stride 2, padding 1), as DABNet's
    input injection."""
    for _ in range(halvings):
        rgb = F.avg_pool2d(rgb, 3, stride=2, padding=1)
    return rgb


class DABNet(nn.Module):
    """DABNet (RGB only).

    Args:
        num_classes: output classes.
        stem_channels: stem width (32).
        widths: channels of the two DAB stages (64, 128).
        dilations: one dilation per DAB module of each stage ((2, 2, 2), (4, 4, 8, 8, 16, 16)).
    """

    def __init__(self, *, num_classes: int = 19, stem_channels: int = 32,
                 widths: tuple[int, int] = (64, 128),
                 dilations: tuple[tuple[int, ...], tuple[int, ...]] = (
                     (2, 2, 2), (4, 4, 8, 8, 16, 16))) -> None:
        super().__init__()
        self.num_classes = num_classes
        s = stem_channels
        self.stem = nn.Sequential(
            ConvBNPReLU(in_channels=3, out_channels=s, kernel=(3, 3), stride=2),
            ConvBNPReLU(in_channels=s, out_channels=s, kernel=(3, 3)),
            ConvBNPReLU(in_channels=s, out_channels=s, kernel=(3, 3)))
        self.stem_post = BNPReLU(channels=s + 3)
        w1, w2 = widths
        self.down1 = DownsamplingBlock(in_channels=s + 3, out_channels=w1)
        self.stage1 = nn.Sequential(*(DABModule(channels=w1, dilation=d) for d in dilations[0]))
        self.stage1_post = BNPReLU(channels=2 * w1 + 3)
        self.down2 = DownsamplingBlock(in_channels=2 * w1 + 3, out_channels=w2)
        self.stage2 = nn.Sequential(*(DABModule(channels=w2, dilation=d) for d in dilations[1]))
        self.stage2_post = BNPReLU(channels=2 * w2 + 3)
        self.classifier = nn.Conv2d(2 * w2 + 3, num_classes, 1, bias=False)

    def forward(self, rgb: torch.Tensor) -> torch.Tensor:
        x = self.stem_post(torch.cat([self.stem(rgb), _image_at(rgb, 1)], dim=1))
        x0 = self.down1(x)
        x = self.stage1_post(torch.cat([self.stage1(x0), x0, _image_at(rgb, 2)], dim=1))
        x0 = self.down2(x)
        x = self.stage2_post(torch.cat([self.stage2(x0), x0, _image_at(rgb, 3)], dim=1))
        logits = self.classifier(x)
        return F.interpolate(logits, size=rgb.shape[-2:], mode="bilinear", align_corners=False)


def dabnet(*, num_classes: int = 19) -> DABNet:
    """DABNet as published (stem 32, stages of 3 and 6 DAB modules, 64 and 128 channels)."""
    return DABNet(num_classes=num_classes)
