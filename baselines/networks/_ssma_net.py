"""SSMA (Valada, Mohan and Burgard, IJCV 2019): two AdapNet++ encoders, one per modality, fused
by self-supervised model adaptation (SSMA) blocks into one decoder; the RGB-D network of
Table II, written from the official TensorFlow code (DeepSceneSeg/SSMA, ``models/SSMA.py``,
``models/ssma_helper.py``, ``models/network_base.py``; docs/baselines/ssma.md).

AdapNet++'s encoder is a ResNet-50 with full pre-activation units (batch norm and ReLU open
each unit; the sum is passed on un-normalised), "multiscale" units whose 3x3 convolution is
split into a plain and a dilated half (the last unit of stage 2, units 3-6 of stage 3), a
dilated stage 4 at stride 16 (both halves dilation 2), and an efficient atrous spatial pyramid
pooling (eASPP: rates 3, 6, 12 as cascades of two 3x3 atrous convolutions inside 1x1
bottlenecks, plus a 1x1 and an image-pooling branch). It is not torchvision's ResNet-50 (no
``baselines.backbones.resnet``): the units, their order of normalisation and the first
unit's shortcut differ, so torchvision weights do not load into it.

SSMA fuses the two eASPP outputs and the two pairs of skip maps (1/8 and 1/4) by concatenation,
a 3x3 bottleneck with a sigmoid gate re-weighting the concatenation, and a projection. The
decoder upsamples x2 twice with learned transposed convolutions, each time gating the fused
skip map by a channel vector pooled from the upsampled map, and a final x4 transposed
convolution gives the logits.

Inputs follow the release: both encoders read 0-255 BGR images, normalised by a batch norm on
the input. The second modality of the Cityscapes model is the depth colourised with the jet
colour map (the README's ``city1_jet.jpg``); the network builds it from a one-channel disparity
map in [0, 1] (see :func:`jet_bgr`).

Convolutions with stride 2 and the max pool pad as TensorFlow's ``SAME`` does (the extra row
and column at the bottom and right), so that feature maps line up with the release's.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

__all__ = ["SSMA", "AdapNetPPEncoder", "SSMAFusion", "jet_bgr", "ssma"]

#: Batch-norm epsilon of the release (``variance_epsilon=0.00001``).
BN_EPS = 1e-5
#: Atrous rates of the eASPP branches.
EASPP_RATES = (3, 6, 12)
#: Channels of the eASPP output, the skip projections and the decoder.
EASPP_CHANNELS = 256
SKIP_CHANNELS = 24
DECODER_CHANNELS = 256
#: Bottleneck channels of the SSMA blocks (eASPP fusion, skip fusions).
SSMA_REDUCED = 32
SSMA_SKIP_REDUCED = 8


def _same_padding(size: int, kernel: int, stride: int, dilation: int) -> tuple[int, int]:
    """TensorFlow's ``SAME`` padding (before, after) of one axis."""
    out = math.ceil(size / stride)
    total = max((out - 1) * stride + (kernel - 1) * dilation + 1 - size, 0)
    return total // 2, total - total // 2


class SameConv2d(nn.Conv2d):
    """``nn.Conv2d`` padded like TensorFlow's ``SAME`` (asymmetric when strided).

    Args:
        in_channels: input channels.
        out_channels: output channels.
        kernel_size: square kernel size.
        stride: stride.
        dilation: dilation.
        bias: add a bias (the release's ``conv_bias``).
    """

    def __init__(self, in_channels: int, out_channels: int, kernel_size: int, *,
                 stride: int = 1, dilation: int = 1, bias: bool = False) -> None:
        symmetric = stride == 1 and kernel_size % 2 == 1
        super().__init__(in_channels, out_channels, kernel_size, stride=stride,
                         padding=dilation * (kernel_size - 1) // 2 if symmetric else 0,
                         dilation=dilation, bias=bias)
        self._symmetric = symmetric

    def forward(self, x: Tensor) -> Tensor:
        if not self._symmetric:
            k, s, d = self.kernel_size[0], self.stride[0], self.dilation[0]
            top, bottom = _same_padding(x.shape[-2], k, s, d)
            left, right = _same_padding(x.shape[-1], k, s, d)
            x = F.pad(x, (left, right, top, bottom))
        return super().forward(x)


def _bn(channels: int) -> nn.BatchNorm2d:
    return nn.BatchNorm2d(channels, eps=BN_EPS)


class ConvBN(nn.Sequential):
    """Convolution (no bias), batch norm, optional ReLU: the release's ``conv_batchN_relu``.

    Args:
        in_channels: input channels.
        out_channels: output channels.
        kernel_size: kernel size.
        stride: stride.
        dilation: dilation (``aconv_batchN_relu``).
        relu: end with a ReLU.
    """

    def __init__(self, in_channels: int, out_channels: int, kernel_size: int = 1, *,
                 stride: int = 1, dilation: int = 1, relu: bool = True) -> None:
        layers: list[nn.Module] = [
            SameConv2d(in_channels, out_channels, kernel_size, stride=stride,
                       dilation=dilation), _bn(out_channels)]
        if relu:
            layers.append(nn.ReLU(inplace=True))
        super().__init__(*layers)


class SplitConv(nn.Module):
    """AdapNet++'s multiscale 3x3 convolution: half the output channels at dilation
    ``rates[0]``, half at ``rates[1]``, concatenated (one convolution when the rates agree).

    Args:
        channels: input and output channels.
        rates: dilations of the two halves.
    """

    def __init__(self, *, channels: int, rates: tuple[int, int]) -> None:
        super().__init__()
        self.rates = rates
        if rates[0] == rates[1]:
            self.conv = SameConv2d(channels, channels, 3, dilation=rates[0])
        else:
            self.conv_a = SameConv2d(channels, channels // 2, 3, dilation=rates[0])
            self.conv_b = SameConv2d(channels, channels - channels // 2, 3, dilation=rates[1])

    def forward(self, x: Tensor) -> Tensor:
        if self.rates[0] == self.rates[1]:
            return self.conv(x)
        return torch.cat([self.conv_a(x), self.conv_b(x)], 1)


class PreActUnit(nn.Module):
    """One bottleneck unit of AdapNet++'s encoder (the release's ``unit_0``/``1``/``3``/``4``).

    ``x`` is the previous unit's un-normalised sum; with ``preact`` the unit first applies
    batch norm and ReLU to it. The residual is ``x`` itself, or a 1x1 (strided) projection of
    the pre-activated input (``shortcut``) or, in the very first unit, of the 1x1 reduction's
    output (``shortcut_from_reduce``, as the release's ``unit_0`` does).

    Args:
        in_channels: input channels.
        out_channels: output channels (the bottleneck has a quarter).
        stride: stride of the 3x3 convolution and the projection.
        preact: open with batch norm and ReLU.
        shortcut: project the residual.
        shortcut_from_reduce: project the reduction instead of the input.
        rates: dilations of a multiscale 3x3 convolution; ``None`` for a plain one.
    """

    def __init__(self, *, in_channels: int, out_channels: int, stride: int = 1,
                 preact: bool = True, shortcut: bool = False,
                 shortcut_from_reduce: bool = False,
                 rates: tuple[int, int] | None = None) -> None:
        super().__init__()
        mid = out_channels // 4
        self.preact = _bn(in_channels) if preact else None
        self.reduce = ConvBN(in_channels, mid, 1)
        if rates is None:
            self.conv = ConvBN(mid, mid, 3, stride=stride)
        else:
            self.conv = nn.Sequential(SplitConv(channels=mid, rates=rates), _bn(mid),
                                      nn.ReLU(inplace=True))
        self.expand = SameConv2d(mid, out_channels, 1)
        self.shortcut_from_reduce = shortcut_from_reduce
        self.shortcut = (SameConv2d(mid if shortcut_from_reduce else in_channels,
                                    out_channels, 1, stride=stride) if shortcut else None)

    def forward(self, x: Tensor) -> Tensor:
        h = x if self.preact is None else F.relu(self.preact(x))
        reduced = self.reduce(h)
        out = self.expand(self.conv(reduced))
        if self.shortcut is None:
            return out + x
        return out + self.shortcut(reduced if self.shortcut_from_reduce else h)


class EASPP(nn.Module):
    """Efficient atrous spatial pyramid pooling.

    Args:
        in_channels: input channels.
        out_channels: channels of each branch and of the output.
        rates: atrous rates of the three cascaded branches.
    """

    def __init__(self, *, in_channels: int, out_channels: int = EASPP_CHANNELS,
                 rates: tuple[int, ...] = EASPP_RATES) -> None:
        super().__init__()
        self.conv1x1 = ConvBN(in_channels, out_channels, 1)
        self.branches = nn.ModuleList(
            nn.Sequential(ConvBN(in_channels, 64, 1), ConvBN(64, 64, 3, dilation=rate),
                          ConvBN(64, 64, 3, dilation=rate), ConvBN(64, out_channels, 1))
            for rate in rates)
        self.image_pool = ConvBN(in_channels, out_channels, 1)
        self.project = ConvBN(out_channels * (len(rates) + 2), out_channels, 1, relu=False)

    def forward(self, x: Tensor) -> Tensor:
        pooled = self.image_pool(x.mean(dim=(2, 3), keepdim=True))
        outs = [self.conv1x1(x), *(branch(x) for branch in self.branches),
                pooled.expand(-1, -1, x.shape[-2], x.shape[-1])]
        return self.project(torch.cat(outs, 1))


class AdapNetPPEncoder(nn.Module):
    """AdapNet++'s encoder (a pre-activation ResNet-50 with multiscale units, output stride 16)
    and eASPP; returns the eASPP output and the two skip projections (1/8 and 1/4).

    Args:
        in_channels: channels of the modality's image.
    """

    def __init__(self, *, in_channels: int = 3) -> None:
        super().__init__()
        self.input_bn = _bn(in_channels)
        self.conv1 = ConvBN(in_channels, 64, 7, stride=2)
        self.block1 = nn.Sequential(
            PreActUnit(in_channels=64, out_channels=256, preact=False, shortcut=True,
                       shortcut_from_reduce=True),
            *(PreActUnit(in_channels=256, out_channels=256) for _ in range(2)))
        self.block1_out = _bn(256)
        self.block2 = nn.Sequential(
            PreActUnit(in_channels=256, out_channels=512, stride=2, preact=False,
                       shortcut=True),
            *(PreActUnit(in_channels=512, out_channels=512) for _ in range(2)),
            PreActUnit(in_channels=512, out_channels=512, rates=(1, 2)))
        self.block2_out = _bn(512)
        self.block3 = nn.Sequential(
            PreActUnit(in_channels=512, out_channels=1024, stride=2, preact=False,
                       shortcut=True),
            PreActUnit(in_channels=1024, out_channels=1024),
            *(PreActUnit(in_channels=1024, out_channels=1024, rates=(1, 2)) for _ in range(4)))
        self.block4 = nn.Sequential(
            PreActUnit(in_channels=1024, out_channels=2048, shortcut=True, rates=(2, 2)),
            *(PreActUnit(in_channels=2048, out_channels=2048, rates=(2, 2)) for _ in range(2)))
        self.block4_out = _bn(2048)
        self.skip1 = ConvBN(256, SKIP_CHANNELS, 1, relu=False)
        self.skip2 = ConvBN(512, SKIP_CHANNELS, 1, relu=False)
        self.easpp = EASPP(in_channels=2048)

    def forward(self, x: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        x = self.conv1(self.input_bn(x))
        top, bottom = _same_padding(x.shape[-2], 3, 2, 1)
        left, right = _same_padding(x.shape[-1], 3, 2, 1)
        x = F.max_pool2d(F.pad(x, (left, right, top, bottom), value=float("-inf")), 3, 2)
        c2 = F.relu(self.block1_out(self.block1(x)))            # 1/4, 256
        c3 = F.relu(self.block2_out(self.block2(c2)))           # 1/8, 512
        c5 = F.relu(self.block4_out(self.block4(self.block3(c3))))  # 1/16, 2048
        return self.easpp(c5), self.skip2(c3), self.skip1(c2)


class SSMAFusion(nn.Module):
    """The SSMA block: concatenate the two modalities' maps and re-weight every channel and
    pixel by a sigmoid gate from a 3x3 bottleneck of the concatenation.

    Args:
        channels: channels of the concatenation.
        reduced: bottleneck channels.
    """

    def __init__(self, *, channels: int, reduced: int) -> None:
        super().__init__()
        self.reduce = SameConv2d(channels, reduced, 3, bias=True)
        self.expand = SameConv2d(reduced, channels, 3, bias=True)

    def forward(self, a: Tensor, b: Tensor) -> Tensor:
        x = torch.cat([a, b], 1)
        return x * torch.sigmoid(self.expand(F.relu(self.reduce(x))))


class SkipGate(nn.Module):
    """A channel vector pooled from the upsampled decoder map (1x1 conv, BN, ReLU) that
    multiplies the fused skip map.

    Args:
        channels: channels of the decoder map.
        skip_channels: channels of the skip map.
    """

    def __init__(self, *, channels: int, skip_channels: int) -> None:
        super().__init__()
        self.conv = ConvBN(channels, skip_channels, 1)

    def forward(self, decoder: Tensor, skip: Tensor) -> Tensor:
        return self.conv(decoder.mean(dim=(2, 3), keepdim=True)) * skip


class SSMA(nn.Module):
    """SSMA with AdapNet++ experts: ``forward(rgb, depth)`` -> logits at the input size.

    Args:
        num_classes: classes of the output.
    """

    def __init__(self, *, num_classes: int = 19) -> None:
        super().__init__()
        self.rgb_encoder = AdapNetPPEncoder()
        self.depth_encoder = AdapNetPPEncoder()
        self.fuse_easpp = SSMAFusion(channels=2 * EASPP_CHANNELS, reduced=SSMA_REDUCED)
        self.fuse_skip2 = SSMAFusion(channels=2 * SKIP_CHANNELS, reduced=SSMA_SKIP_REDUCED)
        self.fuse_skip1 = SSMAFusion(channels=2 * SKIP_CHANNELS, reduced=SSMA_SKIP_REDUCED)
        self.project = ConvBN(2 * EASPP_CHANNELS, DECODER_CHANNELS, 1, relu=False)
        self.skip2_out = SameConv2d(2 * SKIP_CHANNELS, SKIP_CHANNELS, 3, bias=True)
        self.skip1_out = SameConv2d(2 * SKIP_CHANNELS, SKIP_CHANNELS, 3, bias=True)
        d, s = DECODER_CHANNELS, SKIP_CHANNELS
        self.up1 = nn.Sequential(nn.ConvTranspose2d(d, d, 4, stride=2, padding=1, bias=False),
                                 _bn(d))
        self.gate1 = SkipGate(channels=d, skip_channels=s)
        self.refine1 = nn.Sequential(ConvBN(d + s, d, 3), ConvBN(d, d, 3))
        self.up2 = nn.Sequential(nn.ConvTranspose2d(d, d, 4, stride=2, padding=1, bias=False),
                                 _bn(d))
        self.gate2 = SkipGate(channels=d, skip_channels=s)
        self.refine2 = nn.Sequential(ConvBN(d + s, d, 3), ConvBN(d, d, 3),
                                     ConvBN(d, num_classes, 1))
        self.up3 = nn.Sequential(
            nn.ConvTranspose2d(num_classes, num_classes, 8, stride=4, padding=2, bias=False),
            _bn(num_classes))

    def forward(self, rgb: Tensor, depth: Tensor) -> Tensor:
        """``rgb`` (B, 3, H, W) in 0-255, ``depth`` (B, 1, H, W) disparity scaled to [0, 1];
        H and W multiples of 16."""
        a_easpp, a_skip2, a_skip1 = self.rgb_encoder(rgb.flip(1))    # the release reads BGR
        b_easpp, b_skip2, b_skip1 = self.depth_encoder(jet_bgr(depth))
        x = self.project(self.fuse_easpp(a_easpp, b_easpp))          # 1/16
        skip2 = self.skip2_out(self.fuse_skip2(a_skip2, b_skip2))     # 1/8
        skip1 = self.skip1_out(self.fuse_skip1(a_skip1, b_skip1))     # 1/4
        x = self.up1(x)
        x = self.refine1(torch.cat([x, self.gate1(x, skip2)], 1))
        x = self.up2(x)
        x = self.refine2(torch.cat([x, self.gate2(x, skip1)], 1))
        return self.up3(x)


def jet_bgr(value: Tensor) -> Tensor:
    """The jet colour map of ``value`` (B, 1, H, W; clipped to [0, 1]) as a 0-255 BGR image
    (B, 3, H, W): dark blue at 0 (invalid and far), through cyan, yellow and red, to dark red
    at 1 (MATLAB's and OpenCV's piecewise-linear jet)."""
    t = value.clamp(0.0, 1.0) * 4.0
    blue = (1.5 - (t - 1.0).abs()).clamp(0.0, 1.0)
    green = (1.5 - (t - 2.0).abs()).clamp(0.0, 1.0)
    red = (1.5 - (t - 3.0).abs()).clamp(0.0, 1.0)
    return torch.cat([blue, green, red], 1) * 255.0


def ssma(*, num_classes: int) -> SSMA:
    """SSMA with two AdapNet++ (ResNet-50) experts: 56,198,136 parameters for 19 classes."""
    return SSMA(num_classes=num_classes)
