"""ResNet-18/34/50/101/152 backbones with torchvision's parameter names.

Architecture: He et al., "Deep Residual Learning for Image Recognition", CVPR 2016, in
torchvision's "v1.5" form (a bottleneck block strides in its 3x3 convolution, not its first 1x1).

Parameter names are torchvision's: ``conv1``, ``bn1``, ``layer1`` .. ``layer4`` whose blocks hold
``conv1, bn1, conv2, bn2`` (and ``conv3, bn3`` in a bottleneck) and, where the block changes shape,
``downsample.0`` (1x1 convolution) and ``downsample.1`` (BatchNorm); ``fc`` (1000 classes) only with
``with_fc=True``. A torchvision ImageNet state dict therefore loads with ``load_state_dict``
(``strict=False`` when ``with_fc=False``, which drops only ``fc.weight`` and ``fc.bias``).

Options the segmentation networks need:

* ``deep_stem=True``: the three-convolution stem of PSPNet / mmseg "v1c" / timm "resnet*d":
  ``conv1`` is ``nn.Sequential(conv3x3 s2 in->w, BN(w), ReLU, conv3x3 w->w, BN(w), ReLU,
  conv3x3 w->2w)`` (indices 0..6) and ``bn1`` is ``BN(2w)``, with ``w = stem_width`` (PSPNet: 64,
  giving 128 channels into ``layer1``; mmseg v1c: 32, giving 64). Without it, ``conv1`` is the 7x7
  stride-2 convolution with ``stem_width`` (default 64) output channels.
* ``output_stride`` 8 or 16: ``layer4`` (and for 8 also ``layer3``) keep their resolution and
  dilate their 3x3 convolutions instead (DeepLab). As torchvision's
  ``replace_stride_with_dilation``, the first block of a dilated stage uses the previous stage's
  dilation and the following blocks the new one (layer3 at OS 8: 1 then 2; layer4 at OS 16: 1
  then 2; layer4 at OS 8: 2 then 4). Parameter counts do not depend on it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
from torch import Tensor, nn

__all__ = [
    "BasicBlock",
    "Bottleneck",
    "ResNet",
    "resnet18",
    "resnet34",
    "resnet50",
    "resnet101",
    "resnet152",
]

NormLayer = Callable[[int], nn.Module]

#: Output strides the backbone supports, and the stages (layer3, layer4) they dilate.
_DILATED_STAGES = {32: (False, False), 16: (False, True), 8: (True, True)}


def conv3x3(in_channels: int, out_channels: int, *, stride: int = 1,
            dilation: int = 1) -> nn.Conv2d:
    """3x3 convolution without bias, padded to keep the size (at stride 1)."""
    return nn.Conv2d(in_channels, out_channels, 3, stride=stride, padding=dilation,
                     dilation=dilation, bias=False)


def conv1x1(in_channels: int, out_channels: int, *, stride: int = 1) -> nn.Conv2d:
    """1x1 convolution without bias."""
    return nn.Conv2d(in_channels, out_channels, 1, stride=stride, bias=False)


class BasicBlock(nn.Module):
    """Two 3x3 convolutions with a residual connection (ResNet-18/34).

    Args:
        inplanes: input channels.
        planes: output channels (``expansion`` is 1).
        stride: stride of the first convolution.
        downsample: projection of the input when the shape changes (``downsample.0`` conv,
            ``downsample.1`` BN), or None for the identity.
        dilation: dilation of both 3x3 convolutions.
        norm_layer: normalisation constructor (``channels -> module``).
    """

    expansion = 1

    def __init__(self, inplanes: int, planes: int, *, stride: int = 1,
                 downsample: nn.Module | None = None, dilation: int = 1,
                 norm_layer: NormLayer = nn.BatchNorm2d) -> None:
        super().__init__()
        self.conv1 = conv3x3(inplanes, planes, stride=stride, dilation=dilation)
        self.bn1 = norm_layer(planes)
        self.relu = nn.ReLU(inplace=True)
        self.conv2 = conv3x3(planes, planes, dilation=dilation)
        self.bn2 = norm_layer(planes)
        self.downsample = downsample
        self.stride = stride

    def forward(self, x: Tensor) -> Tensor:
        identity = x if self.downsample is None else self.downsample(x)
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        return self.relu(out + identity)


class Bottleneck(nn.Module):
    """1x1 reduce, 3x3 (strided, dilated), 1x1 expand by 4, with a residual connection
    (ResNet-50/101/152).

    Args:
        inplanes: input channels.
        planes: bottleneck width; the block outputs ``planes * 4`` channels.
        stride: stride of the 3x3 convolution (torchvision's v1.5 placement).
        downsample: projection of the input when the shape changes, or None for the identity.
        dilation: dilation of the 3x3 convolution.
        norm_layer: normalisation constructor (``channels -> module``).
    """

    expansion = 4

    def __init__(self, inplanes: int, planes: int, *, stride: int = 1,
                 downsample: nn.Module | None = None, dilation: int = 1,
                 norm_layer: NormLayer = nn.BatchNorm2d) -> None:
        super().__init__()
        self.conv1 = conv1x1(inplanes, planes)
        self.bn1 = norm_layer(planes)
        self.conv2 = conv3x3(planes, planes, stride=stride, dilation=dilation)
        self.bn2 = norm_layer(planes)
        self.conv3 = conv1x1(planes, planes * self.expansion)
        self.bn3 = norm_layer(planes * self.expansion)
        self.relu = nn.ReLU(inplace=True)
        self.downsample = downsample
        self.stride = stride

    def forward(self, x: Tensor) -> Tensor:
        identity = x if self.downsample is None else self.downsample(x)
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.relu(self.bn2(self.conv2(out)))
        out = self.bn3(self.conv3(out))
        return self.relu(out + identity)


Block = type[BasicBlock] | type[Bottleneck]


class ResNet(nn.Module):
    """A ResNet: stem, four stages of residual blocks, optionally the ImageNet classifier.

    Args:
        block: :class:`BasicBlock` or :class:`Bottleneck`.
        layers: blocks per stage (e.g. ``(3, 4, 6, 3)``).
        in_chans: input channels (3 for RGB; e.g. 1 for a depth branch).
        deep_stem: the three-convolution stem (see the module notes) instead of the 7x7 one.
        stem_width: width ``w`` of the deep stem (it outputs ``2w`` channels), or the output
            channels of the 7x7 stem.
        output_stride: 32, 16 or 8 (dilated ``layer4`` / ``layer3`` and ``layer4``).
        with_fc: keep the global pooling and the ``fc`` classifier; ``forward`` then returns
            class logits instead of the feature list.
        num_classes: classes of ``fc`` (1000 for ImageNet).
        norm_layer: normalisation constructor (``channels -> module``).
    """

    def __init__(self, *, block: Block, layers: Sequence[int], in_chans: int = 3,
                 deep_stem: bool = False, stem_width: int = 64, output_stride: int = 32,
                 with_fc: bool = False, num_classes: int = 1000,
                 norm_layer: NormLayer = nn.BatchNorm2d) -> None:
        super().__init__()
        if output_stride not in _DILATED_STAGES:
            raise ValueError(f"output_stride must be one of {sorted(_DILATED_STAGES)}, "
                             f"got {output_stride}")
        if len(layers) != 4:
            raise ValueError(f"layers must give 4 stages, got {tuple(layers)}")
        self.block = block
        self.output_stride = output_stride
        self.deep_stem = deep_stem
        if deep_stem:
            self.conv1: nn.Module = nn.Sequential(
                conv3x3(in_chans, stem_width, stride=2), norm_layer(stem_width),
                nn.ReLU(inplace=True),
                conv3x3(stem_width, stem_width), norm_layer(stem_width), nn.ReLU(inplace=True),
                conv3x3(stem_width, 2 * stem_width))
            self.inplanes = 2 * stem_width
        else:
            self.conv1 = nn.Conv2d(in_chans, stem_width, 7, stride=2, padding=3, bias=False)
            self.inplanes = stem_width
        self.bn1 = norm_layer(self.inplanes)
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(kernel_size=3, stride=2, padding=1)
        self._norm_layer = norm_layer
        self.dilation = 1
        dilate3, dilate4 = _DILATED_STAGES[output_stride]
        self.layer1 = self._make_layer(64, layers[0])
        self.layer2 = self._make_layer(128, layers[1], stride=2)
        self.layer3 = self._make_layer(256, layers[2], stride=2, dilate=dilate3)
        self.layer4 = self._make_layer(512, layers[3], stride=2, dilate=dilate4)
        e = block.expansion
        self.channels: tuple[int, int, int, int] = (64 * e, 128 * e, 256 * e, 512 * e)
        self.strides: tuple[int, int, int, int] = (
            4, 8, 8 if dilate3 else 16, output_stride)
        self.with_fc = with_fc
        if with_fc:
            self.avgpool = nn.AdaptiveAvgPool2d((1, 1))
            self.fc = nn.Linear(512 * e, num_classes)
        self._init_weights()

    def _make_layer(self, planes: int, blocks: int, *, stride: int = 1,
                    dilate: bool = False) -> nn.Sequential:
        norm_layer = self._norm_layer
        previous_dilation = self.dilation
        if dilate:
            self.dilation *= stride
            stride = 1
        out_channels = planes * self.block.expansion
        downsample = None
        if stride != 1 or self.inplanes != out_channels:
            downsample = nn.Sequential(conv1x1(self.inplanes, out_channels, stride=stride),
                                       norm_layer(out_channels))
        modules = [self.block(self.inplanes, planes, stride=stride, downsample=downsample,
                              dilation=previous_dilation, norm_layer=norm_layer)]
        self.inplanes = out_channels
        modules += [self.block(self.inplanes, planes, dilation=self.dilation,
                               norm_layer=norm_layer) for _ in range(1, blocks)]
        return nn.Sequential(*modules)

    def _init_weights(self) -> None:
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(m, (nn.BatchNorm2d, nn.GroupNorm)):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)

    def stem(self, x: Tensor) -> Tensor:
        """``conv1``, ``bn1``, ReLU and the 3x3 stride-2 max pooling (stride 4 overall)."""
        return self.maxpool(self.relu(self.bn1(self.conv1(x))))

    def forward_features(self, x: Tensor) -> list[Tensor]:
        """``[c2, c3, c4, c5]``: the outputs of ``layer1`` .. ``layer4`` (strides
        :attr:`strides`, channels :attr:`channels`)."""
        c2 = self.layer1(self.stem(x))
        c3 = self.layer2(c2)
        c4 = self.layer3(c3)
        c5 = self.layer4(c4)
        return [c2, c3, c4, c5]

    def forward(self, x: Tensor) -> list[Tensor] | Tensor:
        """The feature list of :meth:`forward_features`, or ImageNet logits with ``with_fc``."""
        features = self.forward_features(x)
        if not self.with_fc:
            return features
        return self.fc(torch.flatten(self.avgpool(features[-1]), 1))


def _resnet(block: Block, layers: tuple[int, int, int, int], *, in_chans: int,
            deep_stem: bool, stem_width: int, output_stride: int, with_fc: bool,
            norm_layer: NormLayer) -> ResNet:
    return ResNet(block=block, layers=layers, in_chans=in_chans, deep_stem=deep_stem,
                  stem_width=stem_width, output_stride=output_stride, with_fc=with_fc,
                  norm_layer=norm_layer)


def resnet18(*, in_chans: int = 3, deep_stem: bool = False, stem_width: int = 64,
             output_stride: int = 32, with_fc: bool = False,
             norm_layer: NormLayer = nn.BatchNorm2d) -> ResNet:
    """ResNet-18 (BasicBlock, 2-2-2-2); 11,689,512 parameters with ``with_fc``.

    Args: see :class:`ResNet`.
    """
    return _resnet(BasicBlock, (2, 2, 2, 2), in_chans=in_chans, deep_stem=deep_stem,
                   stem_width=stem_width, output_stride=output_stride, with_fc=with_fc,
                   norm_layer=norm_layer)


def resnet34(*, in_chans: int = 3, deep_stem: bool = False, stem_width: int = 64,
             output_stride: int = 32, with_fc: bool = False,
             norm_layer: NormLayer = nn.BatchNorm2d) -> ResNet:
    """ResNet-34 (BasicBlock, 3-4-6-3); 21,797,672 parameters with ``with_fc``.

    Args: see :class:`ResNet`.
    """
    return _resnet(BasicBlock, (3, 4, 6, 3), in_chans=in_chans, deep_stem=deep_stem,
                   stem_width=stem_width, output_stride=output_stride, with_fc=with_fc,
                   norm_layer=norm_layer)


def resnet50(*, in_chans: int = 3, deep_stem: bool = False, stem_width: int = 64,
             output_stride: int = 32, with_fc: bool = False,
             norm_layer: NormLayer = nn.BatchNorm2d) -> ResNet:
    """ResNet-50 (Bottleneck, 3-4-6-3); 25,557,032 parameters with ``with_fc``.

    Args: see :class:`ResNet`.
    """
    return _resnet(Bottleneck, (3, 4, 6, 3), in_chans=in_chans, deep_stem=deep_stem,
                   stem_width=stem_width, output_stride=output_stride, with_fc=with_fc,
                   norm_layer=norm_layer)


def resnet101(*, in_chans: int = 3, deep_stem: bool = False, stem_width: int = 64,
              output_stride: int = 32, with_fc: bool = False,
              norm_layer: NormLayer = nn.BatchNorm2d) -> ResNet:
    """ResNet-101 (Bottleneck, 3-4-23-3); 44,549,160 parameters with ``with_fc``.

    Args: see :class:`ResNet`.
    """
    return _resnet(Bottleneck, (3, 4, 23, 3), in_chans=in_chans, deep_stem=deep_stem,
                   stem_width=stem_width, output_stride=output_stride, with_fc=with_fc,
                   norm_layer=norm_layer)


def resnet152(*, in_chans: int = 3, deep_stem: bool = False, stem_width: int = 64,
              output_stride: int = 32, with_fc: bool = False,
              norm_layer: NormLayer = nn.BatchNorm2d) -> ResNet:
    """ResNet-152 (Bottleneck, 3-8-36-3); 60,192,808 parameters with ``with_fc``.

    Args: see :class:`ResNet`.
    """
    return _resnet(Bottleneck, (3, 8, 36, 3), in_chans=in_chans, deep_stem=deep_stem,
                   stem_width=stem_width, output_stride=output_stride, with_fc=with_fc,
                   norm_layer=norm_layer)
