"""DDRNet-23-slim, the network: "Deep Dual-resolution Networks for Real-time and Accurate
Semantic Segmentation of Road Scenes" (Hong, Pan, Sun, Jia; arXiv:2101.06085),
written from the official code (ydhongHIT/DDRNet, ``segmentation/DDRNet_23_slim.py``;
docs/baselines/ddrnet-23-slim.md). SyncBatchNorm is BatchNorm here (same parameters).

Layout (width ``w = 32``): a stem of two stride-2 3x3 convs (with bias) to 1/4; residual stages
of two basic blocks: ``w`` at 1/4, ``2w`` at 1/8; then two branches, the low-resolution one
(``4w`` at 1/16, ``8w`` at 1/32, a bottleneck to ``16w`` at 1/64) and the high-resolution one
that stays at 1/8 with ``2w`` channels (two stages of two basic blocks and a bottleneck to
``4w``). After each of the first two branch stages the branches exchange features: the high
branch adds a strided-conv projection to the low one ("down3"/"down4"), the low branch adds a
1x1 projection upsampled to the high one ("compression3"/"compression4"). The 1/64 map goes
through the deep aggregation pyramid pooling module (DAPPM), is upsampled to 1/8 and added to
the high branch; a BN-ReLU-3x3-BN-ReLU-1x1 head gives the logits at 1/8 of the input, as the
official model does (the segmenter upsamples them).

The inference model: without the auxiliary training head (``augment=False`` in the official
builder), 5,695,987 parameters for 19 classes (Table II's 5.7 M; with the auxiliary head
5,734,342). The input height and width must be multiples of 8 (the branches meet at
``input // 8``, as in the official code).

Parameter names are the release's (``conv1`` for the stem, ``layer3_``/``layer4_``/``layer5_``
for the high-resolution branch, ``spp.scale1..4`` with their pooling at index 0,
``final_layer``), so a state dict of the release loads with ``strict=True``.

This module imports torch; :mod:`baselines.networks.ddrnet` registers the network without it.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["DAPPM", "BasicBlock", "Bottleneck", "DualResNet", "SegHead", "ddrnet_23_slim"]

_BN_MOMENTUM = 0.1


def _bn(channels: int) -> nn.BatchNorm2d:
    return nn.BatchNorm2d(channels, momentum=_BN_MOMENTUM)


def _up(x: torch.Tensor, size: tuple[int, int] | torch.Size) -> torch.Tensor:
    return F.interpolate(x, size=tuple(size), mode="bilinear", align_corners=False)


class BasicBlock(nn.Module):
    """Two 3x3 conv-BN with a residual; the final ReLU optional (``relu_out``).

    Args:
        in_channels, channels: channels in and out.
        stride: stride of the first conv (and of the 1x1 projection of the residual).
        relu_out: ReLU after the sum.
    """

    expansion = 1

    def __init__(self, *, in_channels: int, channels: int, stride: int = 1,
                 relu_out: bool = True) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(in_channels, channels, 3, stride=stride, padding=1, bias=False)
        self.bn1 = _bn(channels)
        self.conv2 = nn.Conv2d(channels, channels, 3, padding=1, bias=False)
        self.bn2 = _bn(channels)
        self.downsample = _projection(in_channels, channels, stride)
        self.relu_out = relu_out

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.bn2(self.conv2(F.relu(self.bn1(self.conv1(x)))))
        y = y + (x if self.downsample is None else self.downsample(x))
        return F.relu(y) if self.relu_out else y


class Bottleneck(nn.Module):
    """1x1-3x3-1x1 conv-BN bottleneck, output ``2 * channels`` (DDRNet's expansion), with a
    residual; the final ReLU optional (``relu_out``, off as in the official blocks).

    Args:
        in_channels, channels: input channels and bottleneck width.
        stride: stride of the 3x3 conv (and of the residual's projection).
        relu_out: ReLU after the sum.
    """

    expansion = 2

    def __init__(self, *, in_channels: int, channels: int, stride: int = 1,
                 relu_out: bool = False) -> None:
        super().__init__()
        out = channels * self.expansion
        self.conv1 = nn.Conv2d(in_channels, channels, 1, bias=False)
        self.bn1 = _bn(channels)
        self.conv2 = nn.Conv2d(channels, channels, 3, stride=stride, padding=1, bias=False)
        self.bn2 = _bn(channels)
        self.conv3 = nn.Conv2d(channels, out, 1, bias=False)
        self.bn3 = _bn(out)
        self.downsample = _projection(in_channels, out, stride)
        self.relu_out = relu_out

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(self.bn1(self.conv1(x)))
        y = F.relu(self.bn2(self.conv2(y)))
        y = self.bn3(self.conv3(y))
        y = y + (x if self.downsample is None else self.downsample(x))
        return F.relu(y) if self.relu_out else y


def _projection(in_channels: int, out_channels: int, stride: int) -> nn.Module | None:
    """The residual's 1x1 conv-BN where the shape changes, else None."""
    if stride == 1 and in_channels == out_channels:
        return None
    return nn.Sequential(nn.Conv2d(in_channels, out_channels, 1, stride=stride, bias=False),
                         _bn(out_channels))


def _stage(block: type[BasicBlock] | type[Bottleneck], in_channels: int, channels: int,
           blocks: int, stride: int = 1) -> nn.Sequential:
    """``blocks`` blocks; the first strided with the block's default final ReLU, the middle
    ones with a ReLU, the last (if not the first) without: the official ``_make_layer``."""
    layers: list[nn.Module] = [block(in_channels=in_channels, channels=channels, stride=stride)]
    width = channels * block.expansion
    layers += [block(in_channels=width, channels=channels, relu_out=i < blocks - 1)
               for i in range(1, blocks)]
    return nn.Sequential(*layers)


def _bn_relu_conv(in_channels: int, out_channels: int, kernel: int = 1) -> nn.Sequential:
    """Pre-activation conv: BN, ReLU, bias-free conv (same size)."""
    return nn.Sequential(_bn(in_channels), nn.ReLU(),
                         nn.Conv2d(in_channels, out_channels, kernel, padding=kernel // 2,
                                   bias=False))


class DAPPM(nn.Module):
    """Deep aggregation pyramid pooling: the map and four poolings of it (5/2, 9/4, 17/8 average
    pooling and global), each BN-ReLU-1x1 to ``branch`` channels; each pooled branch is
    upsampled, added to the previous branch's output and refined by BN-ReLU-3x3; the five are
    concatenated, BN-ReLU-1x1 to ``out_channels``, plus a BN-ReLU-1x1 shortcut of the input.

    Args:
        in_channels: input channels.
        branch: channels of each branch.
        out_channels: output channels.
    """

    _POOLS = ((5, 2, 2), (9, 4, 4), (17, 8, 8))  # kernel, stride, padding

    def __init__(self, *, in_channels: int, branch: int, out_channels: int) -> None:
        super().__init__()
        # the release's names: scale0 (the map), scale1..4 (pooling, BN, ReLU, 1x1),
        # process1..4 (BN-ReLU-3x3), compression, shortcut
        self.scale0 = _bn_relu_conv(in_channels, branch)
        pools: list[nn.Module] = [nn.AvgPool2d(k, stride=st, padding=p)
                                  for k, st, p in self._POOLS]
        pools.append(nn.AdaptiveAvgPool2d((1, 1)))
        for i, pool in enumerate(pools, start=1):
            setattr(self, f"scale{i}", nn.Sequential(pool, *_bn_relu_conv(in_channels, branch)))
        for i in range(1, 5):
            setattr(self, f"process{i}", _bn_relu_conv(branch, branch, 3))
        self.compression = _bn_relu_conv(5 * branch, out_channels)
        self.shortcut = _bn_relu_conv(in_channels, out_channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        size = x.shape[-2:]
        outs = [self.scale0(x)]
        for i in range(1, 5):
            scale, process = getattr(self, f"scale{i}"), getattr(self, f"process{i}")
            outs.append(process(_up(scale(x), size) + outs[-1]))
        return self.compression(torch.cat(outs, dim=1)) + self.shortcut(x)


class SegHead(nn.Module):
    """BN-ReLU-3x3 conv (bias-free), BN-ReLU-1x1 conv (with bias) to the classes.

    Args:
        in_channels: input channels.
        channels: the hidden width.
        num_classes: output classes.
    """

    def __init__(self, *, in_channels: int, channels: int, num_classes: int) -> None:
        super().__init__()
        self.bn1 = _bn(in_channels)
        self.conv1 = nn.Conv2d(in_channels, channels, 3, padding=1, bias=False)
        self.bn2 = _bn(channels)
        self.conv2 = nn.Conv2d(channels, num_classes, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.conv1(F.relu(self.bn1(x)))
        return self.conv2(F.relu(self.bn2(x)))


class DualResNet(nn.Module):
    """DDRNet with basic-block stages of ``blocks`` (2, 2, 2, 2 for DDRNet-23).

    Args:
        num_classes: output classes.
        width: the stem width ``w`` (32 for the slim model, 64 for DDRNet-23).
        blocks: basic blocks per stage (the high branch takes the third and fourth).
        spp_channels: DAPPM branch width.
        head_channels: hidden width of the head.
    """

    def __init__(self, *, num_classes: int = 19, width: int = 32,
                 blocks: tuple[int, int, int, int] = (2, 2, 2, 2), spp_channels: int = 128,
                 head_channels: int = 64) -> None:
        super().__init__()
        self.num_classes = num_classes
        w, high = width, 2 * width
        self.conv1 = nn.Sequential(  # the stem
            nn.Conv2d(3, w, 3, stride=2, padding=1), _bn(w), nn.ReLU(),
            nn.Conv2d(w, w, 3, stride=2, padding=1), _bn(w), nn.ReLU())
        self.layer1 = _stage(BasicBlock, w, w, blocks[0])
        self.layer2 = _stage(BasicBlock, w, 2 * w, blocks[1], stride=2)
        self.layer3 = _stage(BasicBlock, 2 * w, 4 * w, blocks[2], stride=2)
        self.layer4 = _stage(BasicBlock, 4 * w, 8 * w, blocks[3], stride=2)
        self.layer5 = _stage(Bottleneck, 8 * w, 8 * w, 1, stride=2)
        # the high-resolution branch (the release's trailing-underscore names)
        self.layer3_ = _stage(BasicBlock, 2 * w, high, 2)
        self.layer4_ = _stage(BasicBlock, high, high, 2)
        self.layer5_ = _stage(Bottleneck, high, high, 1)
        self.compression3 = nn.Sequential(nn.Conv2d(4 * w, high, 1, bias=False), _bn(high))
        self.compression4 = nn.Sequential(nn.Conv2d(8 * w, high, 1, bias=False), _bn(high))
        self.down3 = nn.Sequential(nn.Conv2d(high, 4 * w, 3, stride=2, padding=1, bias=False),
                                   _bn(4 * w))
        self.down4 = nn.Sequential(
            nn.Conv2d(high, 4 * w, 3, stride=2, padding=1, bias=False), _bn(4 * w), nn.ReLU(),
            nn.Conv2d(4 * w, 8 * w, 3, stride=2, padding=1, bias=False), _bn(8 * w))
        self.spp = DAPPM(in_channels=16 * w, branch=spp_channels, out_channels=4 * w)
        self.final_layer = SegHead(in_channels=4 * w, channels=head_channels,
                                   num_classes=num_classes)

    def forward(self, rgb: torch.Tensor) -> torch.Tensor:
        out_size = (rgb.shape[-2] // 8, rgb.shape[-1] // 8)
        c2 = self.layer1(self.conv1(rgb))
        c3 = self.layer2(F.relu(c2))
        low = self.layer3(F.relu(c3))
        high = self.layer3_(F.relu(c3))
        low, high = (low + self.down3(F.relu(high)),
                     high + _up(self.compression3(F.relu(low)), out_size))
        c5 = self.layer4(F.relu(low))
        high = self.layer4_(F.relu(high))
        low, high = (c5 + self.down4(F.relu(high)),
                     high + _up(self.compression4(F.relu(c5)), out_size))
        high = self.layer5_(F.relu(high))
        low = _up(self.spp(self.layer5(F.relu(low))), out_size)
        return self.final_layer(low + high)


def ddrnet_23_slim(*, num_classes: int = 19) -> DualResNet:
    """DDRNet-23-slim as published (width 32, DAPPM branches 128, head 64), inference model."""
    return DualResNet(num_classes=num_classes)
