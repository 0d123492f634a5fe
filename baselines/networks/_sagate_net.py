"""SA-Gate (Chen et al., ECCV 2020), the network: RGB and HHA ResNet-101 encoders joined after
every stage by separation-and-aggregation gates, and a DeepLabV3+ head on the gates' fused maps.

Written from charlesCXK/RGBD_Semantic_Segmentation_PyTorch ``model/SA-Gate.nyu`` (``network.py``,
``dual_resnet.py``, ``net_util.py``; docs/baselines/sagate-r101.md):

* Two ResNet-101s with the deep stem of width 64 (three 3x3 convolutions, 128 channels into
  ``layer1``; the "v1c" ImageNet weights the official code loads): one for RGB, one for HHA
  (three channels). Each block's shortcut projection (``downsample``) is ONE module shared by the
  two encoders, as in the official dual block (``self.hha_downsample = downsample``), so it is
  counted once.
* ``layer4`` of both keeps stride 16 and dilates the 3x3 convolutions of its three blocks by 2, 4
  and 8 (the official ``_nostride_dilate`` with a doubling rate per block).
* After each stage a :class:`SAGate`: feature separation (each modality re-calibrated by the
  other through a squeeze-excitation filter on their concatenation), then a per-pixel softmax
  gate between the two modalities gives the fused map; each encoder continues with
  ``relu((own + fused) / 2)``.
* Head (:class:`DeepLabV3PlusHead`): ASPP (1x1 and 3x3 at rates 6, 12, 18, with an image-pooling
  branch; leaky ReLU) on the stage-4 fused map, upsampled to the stage-1 fused map (reduced to 48
  channels) and concatenated, two 3x3 convolutions and the 1x1 classifier; the logits are
  upsampled to the input (bilinear, corners aligned).
* The auxiliary FCN head on the stage-4 fused map (part of the official 110,875,160 parameters)
  runs in training mode only; the official ``forward`` also computes it in eval mode and
  discards it, which this network does not (docs: its FLOPs).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from baselines.backbones.resnet import ResNet, resnet101

__all__ = ["ASPP", "DeepLabV3PlusHead", "FeatureSeparation", "SAGate", "SAGateNet",
           "sagate_r101"]

#: Dilation rates of the three blocks of ``layer4`` (stride removed).
LAYER4_DILATIONS: tuple[int, int, int] = (2, 4, 8)
#: ASPP rates of the head (the official ``Head`` passes [6, 12, 18]).
ASPP_RATES: tuple[int, int, int] = (6, 12, 18)
#: Reduction of the squeeze-excitation filters of the gates.
GATE_REDUCTION = 16


class FeatureSeparation(nn.Module):
    """Feature separation part of the gate (official ``FSP``): channel weights from the
    concatenation of both modalities (global pooling, ``Linear(2C, C/r)``, ReLU,
    ``Linear(C/r, C)``, sigmoid) re-weight the guide modality, added to the main one.

    Args:
        channels: channels of each modality.
        reduction: squeeze ratio ``r``.
    """

    def __init__(self, *, channels: int, reduction: int = GATE_REDUCTION) -> None:
        super().__init__()
        self.fc = nn.Sequential(nn.Linear(2 * channels, channels // reduction),
                                nn.ReLU(inplace=True),
                                nn.Linear(channels // reduction, channels), nn.Sigmoid())

    def forward(self, guide: Tensor, main: Tensor) -> Tensor:
        pooled = F.adaptive_avg_pool2d(torch.cat([guide, main], dim=1), 1).flatten(1)
        weights = self.fc(pooled)[:, :, None, None]
        return main + weights * guide


class SAGate(nn.Module):
    """Separation-and-aggregation gate after one encoder stage.

    ``forward(rgb, hha)`` returns ``(rgb_out, hha_out, fused)``: ``fused = a_rgb * rgb + a_hha *
    hha`` with per-pixel weights from a softmax over two 1x1 convolutions (with bias) of the
    concatenated re-calibrated features; ``rgb_out = relu((rgb + fused) / 2)`` and likewise for
    HHA.

    Args:
        channels: channels of each modality at this stage.
    """

    def __init__(self, *, channels: int) -> None:
        super().__init__()
        self.fsp_rgb = FeatureSeparation(channels=channels)
        self.fsp_hha = FeatureSeparation(channels=channels)
        self.gate_rgb = nn.Conv2d(2 * channels, 1, 1)
        self.gate_hha = nn.Conv2d(2 * channels, 1, 1)

    def forward(self, rgb: Tensor, hha: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        recalibrated = torch.cat([self.fsp_rgb(hha, rgb), self.fsp_hha(rgb, hha)], dim=1)
        gates = torch.softmax(
            torch.cat([self.gate_rgb(recalibrated), self.gate_hha(recalibrated)], dim=1), dim=1)
        fused = rgb * gates[:, 0:1] + hha * gates[:, 1:2]
        return F.relu((rgb + fused) / 2), F.relu((hha + fused) / 2), fused


class ASPP(nn.Module):
    """The official head's atrous spatial pyramid pooling: a 1x1 and three dilated 3x3
    convolutions (no bias) concatenated, BN, leaky ReLU, 1x1 reduction; plus an image-pooling
    branch (global mean, 1x1, BN, leaky ReLU, 1x1) added everywhere; BN, leaky ReLU.

    Args:
        in_channels: input channels.
        out_channels: output channels.
        rates: dilation rates of the 3x3 convolutions.
        hidden_channels: channels of each branch.
    """

    def __init__(self, *, in_channels: int, out_channels: int,
                 rates: tuple[int, int, int] = ASPP_RATES, hidden_channels: int = 256) -> None:
        super().__init__()
        self.map_convs = nn.ModuleList(
            [nn.Conv2d(in_channels, hidden_channels, 1, bias=False)]
            + [nn.Conv2d(in_channels, hidden_channels, 3, padding=r, dilation=r, bias=False)
               for r in rates])
        self.map_bn = nn.BatchNorm2d(hidden_channels * 4)
        self.global_pooling_conv = nn.Conv2d(in_channels, hidden_channels, 1, bias=False)
        self.global_pooling_bn = nn.BatchNorm2d(hidden_channels)
        self.red_conv = nn.Conv2d(hidden_channels * 4, out_channels, 1, bias=False)
        self.pool_red_conv = nn.Conv2d(hidden_channels, out_channels, 1, bias=False)
        self.red_bn = nn.BatchNorm2d(out_channels)

    def forward(self, x: Tensor) -> Tensor:
        out = torch.cat([conv(x) for conv in self.map_convs], dim=1)
        out = self.red_conv(F.leaky_relu(self.map_bn(out)))
        pool = self.global_pooling_conv(x.mean(dim=(2, 3), keepdim=True))
        pool = self.pool_red_conv(F.leaky_relu(self.global_pooling_bn(pool)))
        return F.leaky_relu(self.red_bn(out + pool))


def _conv_bn_relu(in_channels: int, out_channels: int, kernel: int) -> list[nn.Module]:
    return [nn.Conv2d(in_channels, out_channels, kernel, padding=kernel // 2, bias=False),
            nn.BatchNorm2d(out_channels), nn.ReLU(inplace=True)]


class DeepLabV3PlusHead(nn.Module):
    """The official ``Head``: ASPP on the deepest fused map, the stage-1 fused map reduced to 48
    channels, two 3x3 convolutions on their concatenation and a 1x1 classifier; and the
    auxiliary FCN head (3x3 to a quarter of the channels, BN, ReLU, dropout, 1x1 classifier) on
    the deepest map, run in training mode only.

    Args:
        num_classes: output classes.
        deep_channels: channels of the deepest fused map (2048).
        low_channels: channels of the stage-1 fused map (256).
    """

    def __init__(self, *, num_classes: int, deep_channels: int = 2048,
                 low_channels: int = 256) -> None:
        super().__init__()
        self.aspp = ASPP(in_channels=deep_channels, out_channels=256)
        self.reduce = nn.Sequential(*_conv_bn_relu(low_channels, 48, 1))
        self.last_conv = nn.Sequential(*_conv_bn_relu(256 + 48, 256, 3),
                                       *_conv_bn_relu(256, 256, 3), nn.Dropout2d(0.1))
        self.classify = nn.Conv2d(256, num_classes, 1)
        self.auxlayer = nn.Sequential(*_conv_bn_relu(deep_channels, deep_channels // 4, 3),
                                      nn.Dropout(0.1),
                                      nn.Conv2d(deep_channels // 4, num_classes, 1))

    def forward(self, low: Tensor, deep: Tensor) -> Tensor | tuple[Tensor, Tensor]:
        """Logits at the stride of ``low``; in training mode also the auxiliary logits at the
        stride of ``deep``."""
        x = F.interpolate(self.aspp(deep), size=low.shape[2:], mode="bilinear",
                          align_corners=True)
        pred = self.classify(self.last_conv(torch.cat([x, self.reduce(low)], dim=1)))
        if self.training:
            return pred, self.auxlayer(deep)
        return pred


def _share_shortcuts(source: ResNet, target: ResNet) -> None:
    """Make ``target``'s shortcut projections ``source``'s modules (one set of weights)."""
    for stage in ("layer1", "layer2", "layer3", "layer4"):
        for src, dst in zip(getattr(source, stage), getattr(target, stage), strict=True):
            if src.downsample is not None:
                dst.downsample = src.downsample


def _dilate_layer4(backbone: ResNet, rates: tuple[int, ...] = LAYER4_DILATIONS) -> None:
    """Remove ``layer4``'s stride and dilate each block's 3x3 convolution by its rate."""
    for block, rate in zip(backbone.layer4, rates, strict=True):
        for conv in block.modules():
            if isinstance(conv, nn.Conv2d):
                conv.stride = (1, 1)
                if conv.kernel_size == (3, 3):
                    conv.dilation = (rate, rate)
                    conv.padding = (rate, rate)


class SAGateNet(nn.Module):
    """SA-Gate with ResNet-101 encoders (DeepLabV3+ head, output stride 16).

    ``forward(rgb, hha)``: both ``(B, 3, H, W)`` (HHA normalised like RGB); returns logits
    ``(B, num_classes, H, W)`` (eval mode; in training mode also the auxiliary logits, both at
    the input size).

    Args:
        num_classes: output classes (40 for NYUv2).
    """

    def __init__(self, *, num_classes: int) -> None:
        super().__init__()
        self.rgb: ResNet = resnet101(deep_stem=True, stem_width=64)
        self.hha: ResNet = resnet101(deep_stem=True, stem_width=64)
        _share_shortcuts(self.rgb, self.hha)
        for backbone in (self.rgb, self.hha):
            _dilate_layer4(backbone)
        self.gates = nn.ModuleList(SAGate(channels=c) for c in self.rgb.channels)
        self.head = DeepLabV3PlusHead(num_classes=num_classes,
                                      deep_channels=self.rgb.channels[-1],
                                      low_channels=self.rgb.channels[0])

    def encode(self, rgb: Tensor, hha: Tensor) -> list[Tensor]:
        """The gates' fused maps after stages 1 - 4 (strides 4, 8, 16, 16)."""
        rgb, hha = self.rgb.stem(rgb), self.hha.stem(hha)
        fused = []
        rgb_stages = (self.rgb.layer1, self.rgb.layer2, self.rgb.layer3, self.rgb.layer4)
        hha_stages = (self.hha.layer1, self.hha.layer2, self.hha.layer3, self.hha.layer4)
        for rgb_stage, hha_stage, gate in zip(rgb_stages, hha_stages, self.gates, strict=True):
            rgb, hha, merged = gate(rgb_stage(rgb), hha_stage(hha))
            fused.append(merged)
        return fused

    def forward(self, rgb: Tensor, hha: Tensor) -> Tensor | tuple[Tensor, Tensor]:
        size = rgb.shape[2:]
        fused = self.encode(rgb, hha)
        out = self.head(fused[0], fused[-1])
        if self.training:
            return tuple(F.interpolate(o, size=size, mode="bilinear", align_corners=True)
                         for o in out)
        return F.interpolate(out, size=size, mode="bilinear", align_corners=True)


def sagate_r101(*, num_classes: int) -> SAGateNet:
    """SA-Gate-R101 for ``num_classes`` classes (110,875,160 parameters for 40).

    Args:
        num_classes: output classes.
    """
    return SAGateNet(num_classes=num_classes)
