"""LDN121 (Ladder-DenseNet-121), the network: "Efficient Ladder-Style DenseNets for Semantic
Segmentation of Large Images" (Kreso, Krapac, Segvic; IEEE T-ITS 2020), written from the
official code (ivankreso/LDN, ``models/ldn_semseg.py``, ``layers.py``,
``data/cityscapes/cityscapes_reader.py``; docs/baselines/ldn121.md).

Encoder: DenseNet-121 (:mod:`baselines.backbones.densenet`, torchvision's parameter names
under ``backbone.``) changed as LDN changes it: the stem's max pooling is 2x2 (stride 2), the
third dense block is split after its 12th layer by a 2x2 average pooling (so it spans 1/16 and
1/32 and the fourth block runs at 1/64), and ``norm5`` is dropped. Skips: the first two blocks'
outputs (256 channels at 1/4, 512 at 1/8), the third block's first half before its pooling (640
at 1/16) and its output (1024 at 1/32).

Context and decoder: a spatial pyramid pooling on the 1/64 map (BN-ReLU-1x1 to 512, four levels
average-pooled to grids of 8, 4, 2 and 1 rows with columns following the aspect ratio, each
BN-ReLU-1x1 to 128 and upsampled back, fused by BN-ReLU-1x1 to 512); four residual upsampling
modules to 1/32, 1/16, 1/8 and 1/4 (256, 256, 128, 128 channels): the skip through BN-ReLU-1x1
to the incoming width plus the upsampled features, a BN-ReLU-1x1 to 128 where wider, a
BN-ReLU-3x3 to the output width, plus the upsampled features (through BN-ReLU-1x1 where the
width changes); a BN-ReLU-1x1 classifier (with bias) and a bilinear upsampling to the input.
Every BatchNorm has momentum 0.05 (the Cityscapes reader's).

Two configurations, because the release builds a different encoder with and without ImageNet
initialisation (its ``imagenet_init`` switch):

* :func:`ldn121` (the default, registered): ImageNet-initialised, as the release evaluates
  (``eval.py --pretrained=1``) and its Cityscapes weights are: the DenseNet-121 encoder in full
  (``norm0``, every dense layer with its 1x1 bottleneck), 10,314,515 parameters for 19 classes.
* :func:`ldn121_from_scratch`: the release's encoder without ImageNet initialisation: no
  ``norm0``/``relu0`` and no bottleneck in the dense layers whose input is at most 128 channels
  (the first three of block 1 and the first of block 2), 10,232,467 parameters.

This module imports torch; :mod:`baselines.networks.ldn` registers the network without it.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from baselines.backbones.densenet import DenseBlock, DenseNet, densenet121

__all__ = ["LDN", "BNReLUConv", "PlainDenseLayer", "SpatialPyramidPooling", "UpsampleResidual",
           "ldn121", "ldn121_from_scratch"]

BN_MOMENTUM = 0.05  # ivankreso/LDN data/cityscapes/cityscapes_reader.py


def _up(x: torch.Tensor, size: tuple[int, int] | torch.Size) -> torch.Tensor:
    return F.interpolate(x, size=tuple(size), mode="bilinear", align_corners=False)


class BNReLUConv(nn.Sequential):
    """BatchNorm, ReLU, conv (same size).

    Args:
        in_channels, out_channels: channels in and out.
        kernel: kernel size (1 or 3).
        bias: the conv has a bias (the classifier's does).
    """

    def __init__(self, *, in_channels: int, out_channels: int, kernel: int = 1,
                 bias: bool = False) -> None:
        super().__init__()
        self.norm = nn.BatchNorm2d(in_channels, momentum=BN_MOMENTUM)
        self.relu = nn.ReLU()
        self.conv = nn.Conv2d(in_channels, out_channels, kernel, padding=kernel // 2, bias=bias)


class SpatialPyramidPooling(nn.Module):
    """LDN's pyramid pooling on the 1/64 map.

    Args:
        in_channels: encoder channels (1024).
        channels: width of the reduced map (512).
        level_channels: width of each pooled level (128).
        out_channels: output width (512).
        grids: rows of each level's pooling grid; its columns follow the map's aspect ratio.
    """

    def __init__(self, *, in_channels: int, channels: int = 512, level_channels: int = 128,
                 out_channels: int = 512, grids: tuple[int, ...] = (8, 4, 2, 1)) -> None:
        super().__init__()
        self.grids = grids
        self.reduce = BNReLUConv(in_channels=in_channels, out_channels=channels)
        self.levels = nn.ModuleList(BNReLUConv(in_channels=channels, out_channels=level_channels)
                                    for _ in grids)
        self.fuse = BNReLUConv(in_channels=channels + len(grids) * level_channels,
                               out_channels=out_channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        size = (int(x.shape[-2]), int(x.shape[-1]))  # plain ints, also when traced
        x = self.reduce(x)
        levels = [x]
        for rows, level in zip(self.grids, self.levels, strict=True):
            pooled = F.adaptive_avg_pool2d(x, (rows, max(1, round(size[1] / size[0] * rows))))
            levels.append(_up(level(pooled), size))
        return self.fuse(torch.cat(levels, dim=1))


class UpsampleResidual(nn.Module):
    """One ladder step: ``blend(skip' + up(x)) + project(up(x))`` where ``skip'`` is the skip
    through BN-ReLU-1x1 to ``in_channels``, ``blend`` is BN-ReLU-1x1 to ``bottleneck`` (when
    ``in_channels`` is wider) and BN-ReLU-3x3 to ``out_channels``, and ``project`` is
    BN-ReLU-1x1 to ``out_channels`` (identity when the widths agree).

    Args:
        in_channels: channels of the incoming (coarser) features.
        skip_channels: channels of the encoder skip.
        out_channels: output channels.
        bottleneck: width of the 3x3 conv's input (128).
    """

    def __init__(self, *, in_channels: int, skip_channels: int, out_channels: int,
                 bottleneck: int = 128) -> None:
        super().__init__()
        self.skip = BNReLUConv(in_channels=skip_channels, out_channels=in_channels)
        self.project = (BNReLUConv(in_channels=in_channels, out_channels=out_channels)
                        if out_channels != in_channels else None)
        blend: list[nn.Module] = []
        width = in_channels
        if in_channels > bottleneck:
            blend.append(BNReLUConv(in_channels=in_channels, out_channels=bottleneck))
            width = bottleneck
        blend.append(BNReLUConv(in_channels=width, out_channels=out_channels, kernel=3))
        self.blend = nn.Sequential(*blend)

    def forward(self, x: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        skip = self.skip(skip)
        x = _up(x, skip.shape[-2:])
        out = self.blend(skip + x)
        return out + (x if self.project is None else self.project(x))


class PlainDenseLayer(nn.Module):
    """A dense layer without the 1x1 bottleneck: BN-ReLU-3x3 conv to ``growth_rate`` (what the
    release builds, without ImageNet initialisation, where the input is at most the bottleneck
    width). Names ``norm2``/``conv2`` as the release's.

    Args:
        in_channels: input channels.
        growth_rate: channels the layer adds.
    """

    def __init__(self, in_channels: int, *, growth_rate: int) -> None:
        super().__init__()
        self.norm2 = nn.BatchNorm2d(in_channels)
        self.relu2 = nn.ReLU()
        self.conv2 = nn.Conv2d(in_channels, growth_rate, 3, padding=1, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv2(self.relu2(self.norm2(x)))


def _in_channels(layer: nn.Module) -> int:
    """A dense layer's input channels (its first BatchNorm's)."""
    norm = layer.norm1 if hasattr(layer, "norm1") else layer.norm2
    return int(norm.num_features)


def _dense(block: DenseBlock, x: torch.Tensor, layers: slice) -> torch.Tensor:
    """``x`` through ``block``'s dense ``layers``: each layer sees the concatenation so far."""
    features = [x]
    for layer in list(block.values())[layers]:
        features.append(layer(torch.cat(features, 1)))
    return torch.cat(features, 1)


class LDN(nn.Module):
    """Ladder-DenseNet on a torchvision-style DenseNet (see the module notes).

    Args:
        num_classes: output classes.
        backbone: the DenseNet encoder (its ``pool0`` and ``norm5`` are replaced/dropped here).
        split_block: the 1-based dense block split by an average pooling after half its layers.
        up_channels: output widths of the four upsampling modules, coarsest first.
    """

    def __init__(self, *, num_classes: int = 19, backbone: DenseNet | None = None,
                 split_block: int = 3,
                 up_channels: tuple[int, int, int, int] = (256, 256, 128, 128)) -> None:
        super().__init__()
        self.num_classes = num_classes
        backbone = backbone if backbone is not None else densenet121()
        features = backbone.features
        features.pool0 = nn.MaxPool2d(kernel_size=2, stride=2)
        if hasattr(features, "norm5"):
            del features.norm5  # LDN's context module reads the last block directly
        self.backbone = backbone
        self.split_block = split_block
        blocks = [getattr(features, f"denseblock{i}") for i in range(1, backbone.num_blocks + 1)]
        split = blocks[split_block - 1]
        self._half = len(split) // 2
        half_channels = _in_channels(list(split.values())[self._half])
        skips = [*backbone.channels[:split_block - 1], half_channels,
                 *backbone.channels[split_block - 1:-1]]
        self.spp = SpatialPyramidPooling(in_channels=backbone.channels[-1])
        self.up = nn.ModuleList()
        width = self.spp.fuse.conv.out_channels
        for out, skip in zip(up_channels, reversed(skips), strict=True):
            self.up.append(UpsampleResidual(in_channels=width, skip_channels=skip,
                                            out_channels=out))
            width = out
        self.classifier = BNReLUConv(in_channels=width, out_channels=num_classes, bias=True)
        for m in self.modules():
            if isinstance(m, nn.BatchNorm2d):
                m.momentum = BN_MOMENTUM

    def encode(self, rgb: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """The 1/64 map and the skips (finest first)."""
        f = self.backbone.features
        x = f.pool0(f.relu0(f.norm0(f.conv0(rgb))))
        skips = []
        for i in range(1, self.backbone.num_blocks + 1):
            block = getattr(f, f"denseblock{i}")
            if i == self.split_block:
                x = _dense(block, x, slice(0, self._half))
                skips.append(x)
                x = _dense(block, F.avg_pool2d(x, 2, stride=2), slice(self._half, None))
            else:
                x = _dense(block, x, slice(None))
            if i < self.backbone.num_blocks:
                skips.append(x)
                x = getattr(f, f"transition{i}")(x)
        return x, skips

    def forward(self, rgb: torch.Tensor) -> torch.Tensor:
        x, skips = self.encode(rgb)
        x = self.spp(x)
        for up, skip in zip(self.up, reversed(skips), strict=True):
            x = up(x, skip)
        return _up(self.classifier(x), rgb.shape[-2:])


def ldn121(*, num_classes: int = 19) -> LDN:
    """LDN121 as released and evaluated (ImageNet-initialised DenseNet-121 encoder)."""
    return LDN(num_classes=num_classes, backbone=densenet121())


def ldn121_from_scratch(*, num_classes: int = 19) -> LDN:
    """LDN121 as the release builds it without ImageNet initialisation: no ``norm0``/``relu0``
    and no bottleneck in the dense layers whose input is at most ``4 * growth`` channels."""
    backbone = densenet121()
    f = backbone.features
    f.norm0, f.relu0 = nn.Identity(), nn.Identity()
    for i in range(1, backbone.num_blocks + 1):
        block: DenseBlock = getattr(f, f"denseblock{i}")
        for name, layer in block.items():
            width = layer.conv1.out_channels
            if layer.conv1.in_channels <= width:
                block[name] = PlainDenseLayer(layer.conv1.in_channels,
                                              growth_rate=layer.conv2.out_channels)
    return LDN(num_classes=num_classes, backbone=backbone)
