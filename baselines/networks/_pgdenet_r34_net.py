"""PGDENet-R34 (Zhou et al. 2023), the network: blocks, model and builder.

Written from the official code (github.com/EnquanYang2022/PGDENet,
``toolbox/models/BBSnetmodel/BBSnet.py`` with ``DEM.py``, ``fusion.py``, ``SG.py`` and
``ResNet.py``; the commit is in ``docs/baselines/pgdenet-r34.md``), keeping only what the
forward pass uses:

* two torchvision ResNet-34 encoders (:func:`baselines.backbones.resnet.resnet34`; RGB, and
  depth with a one-channel first convolution - the official code keeps the first of the three
  replicated depth channels);
* a depth-enhancement module (:class:`DepthEnhancement`, the code's ``DA``) at each of the five
  encoder levels: RGB-guided attention added to the depth features;
* progressive guided fusion (:class:`GuidedFusion`, the code's ``yfusion``, and
  :class:`TopFusion`, ``yfusion_layer4``) from 1/32 down to 1/2, each guided by the fusion of
  the level above, each ending in a multi-branch context block (:class:`GlobalContext`, ``GCM``);
* a decoder of four transposed-convolution steps (:class:`DecoderStep`, ``SG``) from 1/16 to the
  input resolution and a 1x1 classifier (41 classes on NYUv2: void kept).

Left out because the forward pass never calls them (6,700,649 parameters of the official
107,402,898): each ``DA``'s ``conv1``, ``conv2`` and ``bn1``, and the auxiliary classifier
``conv_aux4``. The auxiliary classifiers ``conv_aux1..3`` (10,619 parameters) are computed by the
official forward but only returned in training mode; the eval network here omits them, which
gives the 100,691,630 parameters "used in forward" of the table.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from baselines.backbones.resnet import ResNet, resnet34

__all__ = [
    "DecoderStep",
    "DepthEnhancement",
    "GlobalContext",
    "GuidedFusion",
    "PGDENet",
    "TopFusion",
    "pgdenet_r34",
]

#: Channels of the stem and of the four ResNet-34 stages.
LEVEL_CHANNELS: tuple[int, int, int, int, int] = (64, 64, 128, 256, 512)
#: Total stride of the encoder; inputs must be a multiple of it.
OUTPUT_STRIDE = 32


def _conv_bn_relu(in_channels: int, out_channels: int, kernel_size: int | tuple[int, int], *,
                  dilation: int = 1) -> nn.Sequential:
    """Bias-free conv with 'same' padding, BatchNorm, ReLU (the official ``BasicConv2d``)."""
    kh, kw = (kernel_size, kernel_size) if isinstance(kernel_size, int) else kernel_size
    padding = (dilation * (kh // 2), dilation * (kw // 2))
    return nn.Sequential(
        nn.Conv2d(in_channels, out_channels, (kh, kw), padding=padding, dilation=dilation,
                  bias=False),
        nn.BatchNorm2d(out_channels),
        nn.ReLU(inplace=True),
    )


def _size(x: Tensor) -> tuple[int, int]:
    """``(H, W)`` of ``x`` as Python ints (constants in a trace)."""
    return int(x.shape[-2]), int(x.shape[-1])


def _upsample_to(x: Tensor, size: tuple[int, int]) -> Tensor:
    """Bilinear resize with ``align_corners=True``, as every upsampling of the official code."""
    return F.interpolate(x, size=size, mode="bilinear", align_corners=True)


# --------------------------------------------------------------------------------------------
# depth enhancement
# --------------------------------------------------------------------------------------------


class _EdgeRefine(nn.Module):
    """The official ``ER``: three 3x3 conv-BN-LeakyReLU(0.1) at dilations 1, 4, 8, concatenated
    and fused by a 3x3 conv-BN-ReLU, plus a 1x1 conv-BN-ReLU shortcut, then ReLU."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.branches = nn.ModuleList(
            nn.Sequential(
                nn.Conv2d(channels, channels, 3, padding=d, dilation=d, bias=False),
                nn.BatchNorm2d(channels),
                nn.LeakyReLU(0.1, inplace=True),
            )
            for d in (1, 4, 8)
        )
        self.fuse = _conv_bn_relu(3 * channels, channels, 3)
        self.shortcut = _conv_bn_relu(channels, channels, 1)

    def forward(self, x: Tensor) -> Tensor:
        fused = self.fuse(torch.cat([branch(x) for branch in self.branches], dim=1))
        return F.relu(fused + self.shortcut(x))


class DepthEnhancement(nn.Module):
    """RGB-guided depth enhancement (the official ``DA``).

    ``r1 = conv3x3(ER(rgb))``; a channel gate ``g = FC-ReLU-FC-sigmoid(GAP(rgb))`` (reduction
    16, with biases); the enhanced depth is ``depth + r1 * sigmoid(r1 - (g * depth + depth))``.

    Args:
        channels: Channels of both inputs.
        reduction: Reduction of the channel gate.
    """

    def __init__(self, channels: int, *, reduction: int = 16) -> None:
        super().__init__()
        self.refine = _EdgeRefine(channels)
        self.conv = nn.Conv2d(channels, channels, 3, padding=1)
        hidden = channels // reduction
        self.gate = nn.Sequential(
            nn.Linear(channels, hidden), nn.ReLU(inplace=True),
            nn.Linear(hidden, channels), nn.Sigmoid())

    def forward(self, rgb: Tensor, depth: Tensor) -> Tensor:
        r1 = self.conv(self.refine(rgb))
        gate = self.gate(F.adaptive_avg_pool2d(rgb, 1).flatten(1))[:, :, None, None]
        attention = torch.sigmoid(r1 - (gate * depth + depth))
        return depth + r1 * attention


# --------------------------------------------------------------------------------------------
# fusion
# --------------------------------------------------------------------------------------------


class GlobalContext(nn.Module):
    """The official ``GCM``: four branches (1x1; 1x1 then 3x3; 1x1 then 5x5; 3x3 max-pool then
    1x1; all conv-BN-ReLU), concatenated and fused by a 3x3 conv-BN-ReLU.

    Args:
        channels: Channels of input and output.
    """

    def __init__(self, channels: int) -> None:
        super().__init__()
        c = channels
        self.branch0 = _conv_bn_relu(c, c, 1)
        self.branch1 = nn.Sequential(_conv_bn_relu(c, c, 1), _conv_bn_relu(c, c, 3))
        self.branch2 = nn.Sequential(_conv_bn_relu(c, c, 1), _conv_bn_relu(c, c, 5))
        self.branch3 = _conv_bn_relu(c, c, 1)
        self.fuse = _conv_bn_relu(4 * c, c, 3)

    def forward(self, x: Tensor) -> Tensor:
        pooled = F.max_pool2d(x, kernel_size=3, stride=1, padding=1)
        return self.fuse(torch.cat(
            (self.branch0(x), self.branch1(x), self.branch2(x), self.branch3(pooled)), dim=1))


class _CrossWeighting(nn.Module):
    """The shared front of both fusions: RGB through 1x3 then 3x1 conv-BN-ReLU, depth through
    3x1 then 1x3; a one-channel 3x3 conv (with bias) of their product is added to both, which
    are then concatenated."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        c = channels
        self.rgb = nn.Sequential(_conv_bn_relu(c, c, (1, 3)), _conv_bn_relu(c, c, (3, 1)))
        self.depth = nn.Sequential(_conv_bn_relu(c, c, (3, 1)), _conv_bn_relu(c, c, (1, 3)))
        self.weight = nn.Conv2d(c, 1, 3, padding=1)

    def forward(self, rgb: Tensor, depth: Tensor) -> Tensor:
        r, d = self.rgb(rgb), self.depth(depth)
        w = self.weight(r * d)
        return torch.cat((r + w, d + w), dim=1)


class TopFusion(nn.Module):
    """Fusion at 1/32 (the official ``yfusion_layer4``): cross weighting, 1x1 conv (bias) of the
    concatenation, global context.

    Args:
        channels: Channels of both inputs and of the output.
    """

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.cross = _CrossWeighting(channels)
        self.merge = nn.Conv2d(2 * channels, channels, 1)
        self.context = GlobalContext(channels)

    def forward(self, rgb: Tensor, depth: Tensor) -> Tensor:
        return self.context(self.merge(self.cross(rgb, depth)))


class GuidedFusion(nn.Module):
    """Fusion guided by the level above (the official ``yfusion``).

    ``aux = conv1x1([rgb, depth])``; the coarser fusion ``pre`` is projected by a 3x3 conv and
    gates ``aux`` twice: ``aux += sigmoid(conv3x3(aux)) * up2(pre)`` and then
    ``aux += sigmoid(conv3x3(aux)) * GAP(pre)``. The result is
    ``GCM(conv1x1(cross weighting) + aux)``. All these convs carry biases.

    Args:
        pre_channels: Channels of the coarser fusion (twice smaller resolution).
        channels: Channels of the RGB and depth inputs and of the output.
    """

    def __init__(self, pre_channels: int, channels: int) -> None:
        super().__init__()
        c = channels
        self.cross = _CrossWeighting(c)
        self.merge = nn.Conv2d(2 * c, c, 1)
        self.aux = nn.Conv2d(2 * c, c, 1)
        self.gate_local = nn.Conv2d(c, c, 3, padding=1)
        self.gate_global = nn.Conv2d(c, c, 3, padding=1)
        self.pre = nn.Conv2d(pre_channels, c, 3, padding=1)
        self.context = GlobalContext(c)

    def forward(self, rgb: Tensor, depth: Tensor, pre: Tensor) -> Tensor:
        aux = self.aux(torch.cat((rgb, depth), dim=1))
        pre = self.pre(pre)
        height, width = _size(pre)
        aux = aux + torch.sigmoid(self.gate_local(aux)) * _upsample_to(pre, (2 * height,
                                                                             2 * width))
        aux = aux + torch.sigmoid(self.gate_global(aux)) * F.adaptive_avg_pool2d(pre, 1)
        return self.context(self.merge(self.cross(rgb, depth)) + aux)


# --------------------------------------------------------------------------------------------
# decoder and model
# --------------------------------------------------------------------------------------------


class DecoderStep(nn.Module):
    """The official ``SG``: sum of the two inputs, 3x3 stride-2 transposed conv (no bias) -
    BN - ReLU, then a 1x1 conv-BN-ReLU to the next width.

    Args:
        in_channels: Channels of both inputs.
        out_channels: Channels of the output (twice the resolution).
    """

    def __init__(self, in_channels: int, out_channels: int) -> None:
        super().__init__()
        self.up = nn.Sequential(
            nn.ConvTranspose2d(in_channels, in_channels, 3, stride=2, padding=1,
                               output_padding=1, bias=False),
            nn.BatchNorm2d(in_channels),
            nn.ReLU(inplace=True),
        )
        self.project = _conv_bn_relu(in_channels, out_channels, 1)

    def forward(self, x: Tensor, skip: Tensor) -> Tensor:
        return self.project(self.up(x + skip))


class PGDENet(nn.Module):
    """PGDENet with two ResNet-34 encoders (the official configuration).

    Inputs: RGB ``(B, 3, H, W)`` and depth ``(B, 1, H, W)``, H and W divisible by 32. Output:
    logits ``(B, num_classes, H, W)``.

    Args:
        num_classes: Number of output classes (41 for NYUv2 in the official code: void kept).
    """

    def __init__(self, *, num_classes: int = 41) -> None:
        super().__init__()
        if num_classes < 1:
            raise ValueError(f"num_classes must be positive, got {num_classes}")
        self.num_classes = num_classes
        self.encoder_rgb: ResNet = resnet34()
        self.encoder_depth: ResNet = resnet34(in_chans=1)
        self.enhance = nn.ModuleList(DepthEnhancement(c) for c in LEVEL_CHANNELS)
        c1, c2, c3, c4, c5 = LEVEL_CHANNELS
        self.fuse_top = TopFusion(c5)
        # finest first: 1/2 (guided by the 1/4 fusion widened to 128), 1/4, 1/8, 1/16
        self.fuse = nn.ModuleList([GuidedFusion(2 * c2, c1), GuidedFusion(c3, c2),
                                   GuidedFusion(c4, c3), GuidedFusion(c5, c4)])
        self.widen = nn.Conv2d(c2, 2 * c2, 3, padding=1)
        self.top_project = nn.Sequential(nn.ConvTranspose2d(c5, c4, 1), nn.BatchNorm2d(c4))
        self.decoder = nn.ModuleList([DecoderStep(c4, c3), DecoderStep(c3, c2),
                                      DecoderStep(c2, c1), DecoderStep(c1, c1)])
        self.classifier = nn.Conv2d(c1, num_classes, 1)

    def forward(self, rgb: Tensor, depth: Tensor) -> Tensor:
        if not torch.jit.is_tracing():
            _check_inputs(rgb, depth)
        er, ed = self.encoder_rgb, self.encoder_depth
        rgb_levels = [er.relu(er.bn1(er.conv1(rgb)))]
        depth_levels = [ed.relu(ed.bn1(ed.conv1(depth)))]
        r, d = er.maxpool(rgb_levels[0]), ed.maxpool(depth_levels[0])
        for layer_rgb, layer_depth in ((er.layer1, ed.layer1), (er.layer2, ed.layer2),
                                       (er.layer3, ed.layer3), (er.layer4, ed.layer4)):
            r, d = layer_rgb(r), layer_depth(d)
            rgb_levels.append(r)
            depth_levels.append(d)
        depth_levels = [enhance(r, d) for enhance, r, d
                        in zip(self.enhance, rgb_levels, depth_levels, strict=True)]

        fused = [self.fuse_top(rgb_levels[4], depth_levels[4])]  # 1/32, then 1/16 ... 1/4
        for level in (3, 2, 1):
            fused.append(self.fuse[level](rgb_levels[level], depth_levels[level], fused[-1]))
        fused.append(self.fuse[0](rgb_levels[0], depth_levels[0], self.widen(fused[-1])))
        top, f16, f8, f4, f2 = fused

        x = _upsample_to(self.top_project(top), _size(f16))
        for step, skip in zip(self.decoder, (f16, f8, f4, f2), strict=True):
            x = step(x, skip)
        return self.classifier(x)


def _check_inputs(rgb: Tensor, depth: Tensor) -> None:
    if rgb.dim() != 4 or depth.dim() != 4 or rgb.shape[1] != 3 or depth.shape[1] != 1:
        raise ValueError(f"expected rgb (B, 3, H, W) and depth (B, 1, H, W), got "
                         f"{tuple(rgb.shape)} and {tuple(depth.shape)}")
    if rgb.shape[0] != depth.shape[0] or rgb.shape[-2:] != depth.shape[-2:]:
        raise ValueError(f"rgb {tuple(rgb.shape)} and depth {tuple(depth.shape)} do not match")
    height, width = rgb.shape[-2:]
    if height % OUTPUT_STRIDE or width % OUTPUT_STRIDE:
        raise ValueError(f"PGDENet needs an input size divisible by {OUTPUT_STRIDE}, got "
                         f"{height}x{width}")


def pgdenet_r34(*, num_classes: int) -> PGDENet:
    """PGDENet-R34 as the official NYUv2 configuration builds it (``configs/nyuv2.json``).

    Args:
        num_classes: Output classes (41 on NYUv2: the 40 classes and void).
    """
    return PGDENet(num_classes=num_classes)
