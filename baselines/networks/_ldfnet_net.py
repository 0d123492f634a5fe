"""LDFNet (Hung, Lo and Hang, ICIP 2019): the light RGB-D network of Table II, written from the
official code (shangweihung/LDFNet, ``model/LDFNet.py``, ``Net(19)``; docs/baselines/ldfnet.md).

Two encoders run side by side and are fused by addition five times:

* the RGB encoder is ERFNet's (downsampler blocks to 1/2, 1/4 and 1/8, five
  non-bottleneck-1D blocks at 1/4 and eight dilated ones at 1/8);
* the "D&Y" encoder reads two channels, depth and luminance (Y of the RGB frame), through a
  downsampler and three DenseNet blocks (growth rate 42, with 1x1 transitions that halve the
  channels and average-pool), each block's output projected by a 1x1 convolution onto the RGB
  encoder's channels and added to it;

and ERFNet's decoder (two transposed-convolution upsamplers with two non-bottleneck-1D blocks
each, then a transposed 2x2 convolution to the classes) gives full-resolution logits.

The release feeds the D&Y encoder ``cat(depth, luminance)`` computed by its data loader; here
the network takes ``forward(rgb, depth)`` like every evsmap network and computes the luminance
itself from ``rgb`` in [0, 1] (the card's normalisation leaves RGB unstandardised, as the
release's ``ToTensor`` does), with PIL's ``L`` weights (ITU-R 601: 0.299, 0.587, 0.114).

``Net(19)`` has 2,415,760 parameters: 2,413,309 on the full forward pass plus the 2,451 of
``encoder_output_conv``, the 1x1 classifier of the release's first training stage (the encoder
trained alone, ``only_encoder=True``), which this module keeps on the same switch.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

__all__ = ["LDFNet", "LUMA_WEIGHTS", "ldfnet"]

#: ITU-R 601 luma weights (PIL's ``convert("L")``, which the release uses) for R, G, B.
LUMA_WEIGHTS = (0.299, 0.587, 0.114)
#: Batch-norm epsilon of the release.
BN_EPS = 1e-3
#: Growth rate and dropout of the D&Y encoder's dense blocks (``Encoder(growthRate=42,
#: drop=0.05)``).
GROWTH_RATE = 42
DENSE_DROPOUT = 0.05


class DownsamplerBlock(nn.Module):
    """ENet/ERFNet downsampler: a strided 3x3 convolution beside a 2x2 max pool, concatenated,
    batch-normalised, ReLU.

    Args:
        ninput: input channels.
        noutput: output channels (the convolution gives ``noutput - ninput``).
    """

    def __init__(self, *, ninput: int, noutput: int) -> None:
        super().__init__()
        self.conv = nn.Conv2d(ninput, noutput - ninput, 3, stride=2, padding=1)
        self.pool = nn.MaxPool2d(2, stride=2)
        self.bn = nn.BatchNorm2d(noutput, eps=BN_EPS)

    def forward(self, x: Tensor) -> Tensor:
        return F.relu(self.bn(torch.cat([self.conv(x), self.pool(x)], 1)))


class NonBottleneck1D(nn.Module):
    """ERFNet's residual block of factorised 3x1 / 1x3 convolutions, the second pair dilated.

    Args:
        chann: channels.
        dropprob: spatial dropout before the residual sum (training only).
        dilated: dilation of the second pair.
    """

    def __init__(self, *, chann: int, dropprob: float, dilated: int) -> None:
        super().__init__()
        self.conv3x1_1 = nn.Conv2d(chann, chann, (3, 1), padding=(1, 0))
        self.conv1x3_1 = nn.Conv2d(chann, chann, (1, 3), padding=(0, 1))
        self.bn1 = nn.BatchNorm2d(chann, eps=BN_EPS)
        self.conv3x1_2 = nn.Conv2d(chann, chann, (3, 1), padding=(dilated, 0),
                                   dilation=(dilated, 1))
        self.conv1x3_2 = nn.Conv2d(chann, chann, (1, 3), padding=(0, dilated),
                                   dilation=(1, dilated))
        self.bn2 = nn.BatchNorm2d(chann, eps=BN_EPS)
        self.dropout = nn.Dropout2d(dropprob)

    def forward(self, x: Tensor) -> Tensor:
        out = F.relu(self.bn1(self.conv1x3_1(F.relu(self.conv3x1_1(x)))))
        out = self.bn2(self.conv1x3_2(F.relu(self.conv3x1_2(out))))
        if self.dropout.p != 0:
            out = self.dropout(out)
        return F.relu(out + x)


class DenseLayer(nn.Module):
    """One layer of a dense block: 1x1 then (dilated) 3x3 convolution to ``growth`` channels,
    each with batch norm and ReLU, concatenated to its input.

    Args:
        in_channels: input channels.
        growth: channels added.
        dilation: dilation of the 3x3 convolution.
        drop: spatial dropout of the new channels (training only).
    """

    def __init__(self, *, in_channels: int, growth: int, dilation: int, drop: float) -> None:
        super().__init__()
        self.conv_1x1 = nn.Conv2d(in_channels, growth, 1, bias=False)
        self.bn_1x1 = nn.BatchNorm2d(growth, eps=BN_EPS)
        self.conv_b = nn.Conv2d(growth, growth, 3, padding=dilation, dilation=dilation,
                                bias=False)
        self.bn_b = nn.BatchNorm2d(growth, eps=BN_EPS)
        self.dropout = nn.Dropout2d(drop)

    def forward(self, x: Tensor) -> Tensor:
        out = F.relu(self.bn_1x1(self.conv_1x1(x)))
        out = F.relu(self.bn_b(self.conv_b(out)))
        if self.dropout.p != 0:
            out = self.dropout(out)
        return torch.cat([x, out], 1)


class DenseBlock(nn.Module):
    """Dense layers with the given dilations (one layer per dilation).

    Args:
        in_channels: input channels.
        growth: channels each layer adds.
        dilations: the layers' dilations.
        drop: spatial dropout of each layer.
    """

    def __init__(self, *, in_channels: int, growth: int, dilations: tuple[int, ...],
                 drop: float) -> None:
        super().__init__()
        self.denseblock = nn.Sequential(*(
            DenseLayer(in_channels=in_channels + index * growth, growth=growth,
                       dilation=dilation, drop=drop)
            for index, dilation in enumerate(dilations)))
        self.out_channels = in_channels + len(dilations) * growth

    def forward(self, x: Tensor) -> Tensor:
        return self.denseblock(x)


class TransitionLayer(nn.Module):
    """1x1 convolution, batch norm, ReLU, then 2x2 average pooling.

    Args:
        in_channels: input channels.
        out_channels: output channels.
    """

    def __init__(self, *, in_channels: int, out_channels: int) -> None:
        super().__init__()
        self.conv = nn.Conv2d(in_channels, out_channels, 1, bias=False)
        self.bn = nn.BatchNorm2d(out_channels, eps=BN_EPS)

    def forward(self, x: Tensor) -> Tensor:
        return F.avg_pool2d(F.relu(self.bn(self.conv(x))), 2, stride=2)


def _project(in_channels: int, out_channels: int) -> nn.Conv2d:
    return nn.Conv2d(in_channels, out_channels, 1, bias=False)


class Encoder(nn.Module):
    """The RGB (ERFNet) and D&Y (DenseNet) encoders with their five additive fusions; output
    128 channels at 1/8.

    Args:
        growth: growth rate of the dense blocks.
        drop: dropout of the dense layers.
    """

    def __init__(self, *, growth: int = GROWTH_RATE, drop: float = DENSE_DROPOUT) -> None:
        super().__init__()
        self.initial_block_rgb = DownsamplerBlock(ninput=3, noutput=16)
        self.second_downsampleblock_rgb = DownsamplerBlock(ninput=16, noutput=64)
        self.layers_1_rgb = nn.ModuleList(
            NonBottleneck1D(chann=64, dropprob=0.03, dilated=1) for _ in range(5))
        self.third_downsampleblock_rgb = DownsamplerBlock(ninput=64, noutput=128)
        self.layers_2_rgb = nn.ModuleList(
            NonBottleneck1D(chann=128, dropprob=0.3, dilated=rate)
            for _ in range(2) for rate in (2, 4, 8, 16))

        self.downsampling_1 = DownsamplerBlock(ninput=2, noutput=16)
        self.block_minus1 = DenseBlock(in_channels=16, growth=growth, dilations=(1, 1, 2, 2),
                                       drop=drop)
        c = self.block_minus1.out_channels                      # 184
        self.trans_minus1 = TransitionLayer(in_channels=c, out_channels=c // 2)
        self.downchannel_1 = _project(c, 16)
        c //= 2                                                  # 92
        self.block_1 = DenseBlock(in_channels=c, growth=growth, dilations=(1, 1, 1), drop=drop)
        self.upchannel_2 = _project(c, 64)
        c = self.block_1.out_channels                           # 218
        self.trans = TransitionLayer(in_channels=c, out_channels=c // 2)
        self.downchannel_2 = _project(c, 64)
        c //= 2                                                  # 109
        self.block_2 = DenseBlock(in_channels=c, growth=growth, dilations=(2, 4, 8, 16),
                                  drop=drop)
        self.upchannel_3 = _project(c, 128)
        self.downchannel_3 = _project(self.block_2.out_channels, 128)  # 277 -> 128

    def forward(self, rgb: Tensor, dy: Tensor) -> Tensor:
        x = self.initial_block_rgb(rgb)                          # 1/2
        d = self.block_minus1(self.downsampling_1(dy))
        x = self.second_downsampleblock_rgb(x + self.downchannel_1(d))   # fusion 1, 1/4
        d = self.trans_minus1(d)
        x = x + self.upchannel_2(d)                              # fusion 2
        for layer in self.layers_1_rgb:
            x = layer(x)
        d = self.block_1(d)
        x = self.third_downsampleblock_rgb(x + self.downchannel_2(d))    # fusion 3, 1/8
        d = self.trans(d)
        x = x + self.upchannel_3(d)                              # fusion 4
        for layer in self.layers_2_rgb:
            x = layer(x)
        return x + self.downchannel_3(self.block_2(d))           # fusion 5


class UpsamplerBlock(nn.Module):
    """Transposed 3x3 convolution (stride 2), batch norm, ReLU.

    Args:
        ninput: input channels.
        noutput: output channels.
    """

    def __init__(self, *, ninput: int, noutput: int) -> None:
        super().__init__()
        self.conv = nn.ConvTranspose2d(ninput, noutput, 3, stride=2, padding=1,
                                       output_padding=1)
        self.bn = nn.BatchNorm2d(noutput, eps=BN_EPS)

    def forward(self, x: Tensor) -> Tensor:
        return F.relu(self.bn(self.conv(x)))


class Decoder(nn.Module):
    """ERFNet's decoder: 1/8 -> 1/4 -> 1/2 -> full resolution.

    Args:
        num_classes: classes of the output.
    """

    def __init__(self, *, num_classes: int) -> None:
        super().__init__()
        self.upsample_1 = UpsamplerBlock(ninput=128, noutput=64)
        self.layers_1 = nn.ModuleList(
            NonBottleneck1D(chann=64, dropprob=0.0, dilated=1) for _ in range(2))
        self.upsample_2 = UpsamplerBlock(ninput=64, noutput=16)
        self.layers_2 = nn.ModuleList(
            NonBottleneck1D(chann=16, dropprob=0.0, dilated=1) for _ in range(2))
        self.output_conv = nn.ConvTranspose2d(16, num_classes, 2, stride=2)

    def forward(self, x: Tensor) -> Tensor:
        x = self.upsample_1(x)
        for layer in self.layers_1:
            x = layer(x)
        x = self.upsample_2(x)
        for layer in self.layers_2:
            x = layer(x)
        return self.output_conv(x)


class LDFNet(nn.Module):
    """LDFNet: ``forward(rgb, depth)`` -> logits at the input size.

    Args:
        num_classes: classes of the output.
    """

    def __init__(self, *, num_classes: int = 19) -> None:
        super().__init__()
        self.encoder = Encoder()
        self.decoder = Decoder(num_classes=num_classes)
        self.encoder_output_conv = nn.Conv2d(128, num_classes, 1)
        self.register_buffer("luma", torch.tensor(LUMA_WEIGHTS).view(1, 3, 1, 1),
                             persistent=False)

    def forward(self, rgb: Tensor, depth: Tensor, only_encoder: bool = False) -> Tensor:
        """``rgb`` (B, 3, H, W) in [0, 1], ``depth`` (B, 1, H, W) as the card encodes it; H and
        W multiples of 8. ``only_encoder``: the release's first training stage (1/8 logits)."""
        luminance = (rgb * self.luma).sum(dim=1, keepdim=True)
        features = self.encoder(rgb, torch.cat([depth, luminance], 1))
        if only_encoder:
            return self.encoder_output_conv(features)
        return self.decoder(features)


def ldfnet(*, num_classes: int) -> LDFNet:
    """LDFNet as the release's ``Net(num_classes)`` (2,415,760 parameters for 19 classes)."""
    return LDFNet(num_classes=num_classes)
