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

Parameter names are the release's (``init_conv``, ``bn_prelu_1``, ``downsample_1``,
``DAB_Block_1.DAB_Module_1_0.conv3x3.conv``, ..., ``classifier.0.conv``), so a state dict of
the release loads with ``strict=True``.

This module imports torch; :mod:`baselines.networks.dabnet` registers the network without it.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["BNPReLU", "ConvBNPReLU", "DABModule", "DABNet", "DownsamplingBlock", "dabnet"]

_BN_EPS = 1e-3


class BNPReLU(nn.Module):
    """BatchNorm (``eps=1e-3``) then a per-channel PReLU (``bn``, ``acti``).

    Args:
        channels: the feature channels.
    """

    def __init__(self, *, channels: int) -> None:
        super().__init__()
        self.bn = nn.BatchNorm2d(channels, eps=_BN_EPS)
        self.acti = nn.PReLU(channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.acti(self.bn(x))


class ConvBNPReLU(nn.Module):
    """A bias-free convolution (``conv``), then :class:`BNPReLU` (``bn_prelu``, when
    ``activate``).

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
        super().__init__()
        padding = (dilation[0] * (kernel[0] // 2), dilation[1] * (kernel[1] // 2))
        self.conv = nn.Conv2d(in_channels, out_channels, kernel, stride=stride, padding=padding,
                              dilation=dilation, groups=groups, bias=False)
        self.bn_prelu = BNPReLU(channels=out_channels) if activate else None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.conv(x)
        return x if self.bn_prelu is None else self.bn_prelu(x)


class DABModule(nn.Module):
    """Depth-wise asymmetric bottleneck with a residual connection.

    Args:
        channels: input and output channels (the bottleneck has half).
        dilation: the dilation of the second depth-wise branch.
    """

    def __init__(self, *, channels: int, dilation: int) -> None:
        super().__init__()
        mid = channels // 2

        def depthwise(kernel: tuple[int, int], dil: tuple[int, int]) -> ConvBNPReLU:
            return ConvBNPReLU(in_channels=mid, out_channels=mid, kernel=kernel, dilation=dil,
                               groups=mid)

        self.bn_relu_1 = BNPReLU(channels=channels)
        self.conv3x3 = ConvBNPReLU(in_channels=channels, out_channels=mid, kernel=(3, 3))
        self.dconv3x1 = depthwise((3, 1), (1, 1))  # the local branch
        self.dconv1x3 = depthwise((1, 3), (1, 1))
        self.ddconv3x1 = depthwise((3, 1), (dilation, 1))  # the dilated branch
        self.ddconv1x3 = depthwise((1, 3), (1, dilation))
        self.bn_relu_2 = BNPReLU(channels=mid)
        self.conv1x1 = ConvBNPReLU(in_channels=mid, out_channels=channels, kernel=(1, 1),
                                   activate=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.conv3x3(self.bn_relu_1(x))
        y = self.dconv1x3(self.dconv3x1(y)) + self.ddconv1x3(self.ddconv3x1(y))
        return self.conv1x1(self.bn_relu_2(y)) + x


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
        self.conv3x3 = ConvBNPReLU(in_channels=in_channels, out_channels=conv_out, kernel=(3, 3),
                                   stride=2, activate=False)
        self.bn_prelu = BNPReLU(channels=out_channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.conv3x3(x)
        if self.pool:
            y = torch.cat([y, F.max_pool2d(x, 2, stride=2)], dim=1)
        return self.bn_prelu(y)


def _image_at(rgb: torch.Tensor, halvings: int) -> torch.Tensor:
    """The image average-pooled ``halvings`` times (3x3, stride 2, padding 1), as DABNet's
    input injection."""
    for _ in range(halvings):
        rgb = F.avg_pool2d(rgb, 3, stride=2, padding=1)
    return rgb


def _dab_stage(stage: int, channels: int, dilations: tuple[int, ...]) -> nn.Sequential:
    """DAB modules named as the release's (``DAB_Module_<stage>_<i>``)."""
    block = nn.Sequential()
    for i, d in enumerate(dilations):
        block.add_module(f"DAB_Module_{stage}_{i}", DABModule(channels=channels, dilation=d))
    return block


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
        self.init_conv = nn.Sequential(
            ConvBNPReLU(in_channels=3, out_channels=s, kernel=(3, 3), stride=2),
            ConvBNPReLU(in_channels=s, out_channels=s, kernel=(3, 3)),
            ConvBNPReLU(in_channels=s, out_channels=s, kernel=(3, 3)))
        self.bn_prelu_1 = BNPReLU(channels=s + 3)
        w1, w2 = widths
        self.downsample_1 = DownsamplingBlock(in_channels=s + 3, out_channels=w1)
        self.DAB_Block_1 = _dab_stage(1, w1, dilations[0])
        self.bn_prelu_2 = BNPReLU(channels=2 * w1 + 3)
        self.downsample_2 = DownsamplingBlock(in_channels=2 * w1 + 3, out_channels=w2)
        self.DAB_Block_2 = _dab_stage(2, w2, dilations[1])
        self.bn_prelu_3 = BNPReLU(channels=2 * w2 + 3)
        self.classifier = nn.Sequential(ConvBNPReLU(in_channels=2 * w2 + 3,
                                                    out_channels=num_classes, kernel=(1, 1),
                                                    activate=False))

    def forward(self, rgb: torch.Tensor) -> torch.Tensor:
        x = self.bn_prelu_1(torch.cat([self.init_conv(rgb), _image_at(rgb, 1)], dim=1))
        x0 = self.downsample_1(x)
        x = self.bn_prelu_2(torch.cat([self.DAB_Block_1(x0), x0, _image_at(rgb, 2)], dim=1))
        x0 = self.downsample_2(x)
        x = self.bn_prelu_3(torch.cat([self.DAB_Block_2(x0), x0, _image_at(rgb, 3)], dim=1))
        logits = self.classifier(x)
        return F.interpolate(logits, size=rgb.shape[-2:], mode="bilinear", align_corners=False)


def dabnet(*, num_classes: int = 19) -> DABNet:
    """DABNet as published (stem 32, stages of 3 and 6 DAB modules, 64 and 128 channels)."""
    return DABNet(num_classes=num_classes)
