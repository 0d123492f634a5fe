"""DenseNet-121 backbone with torchvision's parameter names.

Architecture: Huang et al., "Densely Connected Convolutional Networks", CVPR 2017; DenseNet-BC-121:
growth rate 32, bottleneck width 4 x 32, 64 stem channels, dense blocks of 6, 12, 24 and 16 layers,
transitions that halve the channels (compression 0.5) and pool 2x2.

Names (torchvision's): ``features.conv0`` (7x7 stride 2), ``features.norm0``, ``features.relu0``,
``features.pool0`` (3x3 stride-2 max pooling); ``features.denseblock{1..4}.denselayer{k}`` with
``norm1, relu1, conv1`` (1x1 to 128) and ``norm2, relu2, conv2`` (3x3 to 32);
``features.transition{1..3}`` with ``norm, relu, conv, pool``; ``features.norm5``; ``classifier``
(1000 classes, only with ``with_classifier=True``). A torchvision ImageNet state dict loads with
``load_state_dict`` (``strict=False`` without the classifier, which drops only ``classifier.*``)
after :func:`rename_legacy_keys`: torchvision's published checkpoint
(``densenet121-a639ec97.pth``) stores the dense layers under their pre-0.4 names (``norm.1``,
``conv.1``, ``norm.2``, ``conv.2``), which torchvision renames while loading.

:meth:`DenseNet.forward_features` returns, for an input of size ``H x W``:

====  =====================================================  ========  ======
out   what                                                    channels  stride
====  =====================================================  ========  ======
0     ``denseblock1`` output (before ``transition1``)          256       4
1     ``denseblock2`` output (before ``transition2``)          512       8
2     ``denseblock3`` output (before ``transition3``)          1024      16
3     ``relu(norm5(denseblock4 output))``                      1024      32
====  =====================================================  ========  ======

i.e. each dense block's concatenated features before its transition (the transition's norm,
conv and 2x2 average pooling feed the next block); the last one after ``norm5`` and ReLU as in
torchvision's classifier path.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

__all__ = ["DenseBlock", "DenseLayer", "DenseNet", "Transition", "densenet121",
           "rename_legacy_keys"]

#: A dense layer's parameter under its pre-0.4 torchvision name (``...denselayer1.norm.1.weight``).
_LEGACY_KEY = re.compile(r"^(.*denselayer\d+\.(?:norm|relu|conv))\.([12]\.[a-z_]+)$")


class DenseLayer(nn.Module):
    """BN-ReLU-1x1 conv (to ``bn_size * growth_rate``), BN-ReLU-3x3 conv (to ``growth_rate``);
    its output is concatenated to its input by the block.

    Args:
        in_channels: input channels.
        growth_rate: channels the layer adds.
        bn_size: bottleneck width as a multiple of ``growth_rate``.
    """

    def __init__(self, in_channels: int, *, growth_rate: int, bn_size: int) -> None:
        super().__init__()
        self.norm1 = nn.BatchNorm2d(in_channels)
        self.relu1 = nn.ReLU(inplace=True)
        self.conv1 = nn.Conv2d(in_channels, bn_size * growth_rate, 1, bias=False)
        self.norm2 = nn.BatchNorm2d(bn_size * growth_rate)
        self.relu2 = nn.ReLU(inplace=True)
        self.conv2 = nn.Conv2d(bn_size * growth_rate, growth_rate, 3, padding=1, bias=False)

    def forward(self, x: Tensor) -> Tensor:
        out = self.conv1(self.relu1(self.norm1(x)))
        return self.conv2(self.relu2(self.norm2(out)))


class DenseBlock(nn.ModuleDict):
    """``num_layers`` dense layers (``denselayer1`` ..), each fed with the concatenation of the
    block's input and all earlier layers' outputs; outputs ``in_channels + num_layers *
    growth_rate`` channels.

    Args:
        num_layers: dense layers.
        in_channels: input channels.
        growth_rate: channels each layer adds.
        bn_size: bottleneck width as a multiple of ``growth_rate``.
    """

    def __init__(self, *, num_layers: int, in_channels: int, growth_rate: int,
                 bn_size: int) -> None:
        super().__init__()
        for i in range(num_layers):
            self[f"denselayer{i + 1}"] = DenseLayer(
                in_channels + i * growth_rate, growth_rate=growth_rate, bn_size=bn_size)
        self.out_channels = in_channels + num_layers * growth_rate

    def forward(self, x: Tensor) -> Tensor:
        features = [x]
        for layer in self.values():
            features.append(layer(torch.cat(features, 1)))
        return torch.cat(features, 1)


class Transition(nn.Sequential):
    """BN, ReLU, 1x1 convolution to ``out_channels``, 2x2 average pooling (stride 2).

    Args:
        in_channels: input channels.
        out_channels: output channels.
    """

    def __init__(self, in_channels: int, out_channels: int) -> None:
        super().__init__()
        self.add_module("norm", nn.BatchNorm2d(in_channels))
        self.add_module("relu", nn.ReLU(inplace=True))
        self.add_module("conv", nn.Conv2d(in_channels, out_channels, 1, bias=False))
        self.add_module("pool", nn.AvgPool2d(kernel_size=2, stride=2))


class DenseNet(nn.Module):
    """A DenseNet-BC: stem, dense blocks with transitions, ``norm5``, optional classifier.

    Args:
        block_config: dense layers per block (DenseNet-121: ``(6, 12, 24, 16)``).
        growth_rate: channels each dense layer adds.
        num_init_features: stem channels.
        bn_size: bottleneck width as a multiple of ``growth_rate``.
        with_classifier: keep the global pooling and the ``classifier`` (ImageNet); ``forward``
            then returns class logits instead of the feature list.
        num_classes: classes of the classifier.
    """

    def __init__(self, *, block_config: Sequence[int] = (6, 12, 24, 16), growth_rate: int = 32,
                 num_init_features: int = 64, bn_size: int = 4, with_classifier: bool = False,
                 num_classes: int = 1000) -> None:
        super().__init__()
        self.features = nn.Sequential()
        self.features.add_module("conv0", nn.Conv2d(3, num_init_features, 7, stride=2,
                                                    padding=3, bias=False))
        self.features.add_module("norm0", nn.BatchNorm2d(num_init_features))
        self.features.add_module("relu0", nn.ReLU(inplace=True))
        self.features.add_module("pool0", nn.MaxPool2d(kernel_size=3, stride=2, padding=1))
        channels = num_init_features
        block_channels = []
        for i, num_layers in enumerate(block_config, start=1):
            block = DenseBlock(num_layers=num_layers, in_channels=channels,
                               growth_rate=growth_rate, bn_size=bn_size)
            self.features.add_module(f"denseblock{i}", block)
            channels = block.out_channels
            block_channels.append(channels)
            if i != len(block_config):
                self.features.add_module(f"transition{i}", Transition(channels, channels // 2))
                channels //= 2
        self.features.add_module("norm5", nn.BatchNorm2d(channels))
        self.num_blocks = len(block_config)
        self.channels: tuple[int, ...] = tuple(block_channels)
        self.strides: tuple[int, ...] = tuple(4 * 2 ** i for i in range(len(block_config)))
        self.with_classifier = with_classifier
        if with_classifier:
            self.classifier = nn.Linear(channels, num_classes)
        self._init_weights()

    def _init_weights(self) -> None:
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight)
            elif isinstance(m, nn.BatchNorm2d):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)
            elif isinstance(m, nn.Linear):
                nn.init.zeros_(m.bias)

    def stem(self, x: Tensor) -> Tensor:
        """``conv0``, ``norm0``, ReLU, ``pool0`` (stride 4 overall)."""
        f = self.features
        return f.pool0(f.relu0(f.norm0(f.conv0(x))))

    def forward_features(self, x: Tensor) -> list[Tensor]:
        """Each dense block's output before its transition, the last after ``norm5`` and ReLU
        (see the module notes); strides :attr:`strides`, channels :attr:`channels`."""
        f = self.features
        x = self.stem(x)
        outputs = []
        for i in range(1, self.num_blocks + 1):
            x = getattr(f, f"denseblock{i}")(x)
            if i == self.num_blocks:
                outputs.append(F.relu(f.norm5(x)))
            else:
                outputs.append(x)
                x = getattr(f, f"transition{i}")(x)
        return outputs

    def forward(self, x: Tensor) -> list[Tensor] | Tensor:
        """The feature list of :meth:`forward_features`, or ImageNet logits with
        ``with_classifier``."""
        features = self.forward_features(x)
        if not self.with_classifier:
            return features
        pooled = F.adaptive_avg_pool2d(features[-1], (1, 1))
        return self.classifier(torch.flatten(pooled, 1))


def densenet121(*, with_classifier: bool = False) -> DenseNet:
    """DenseNet-121 (growth 32, blocks 6-12-24-16); 7,978,856 parameters with the classifier,
    6,953,856 without.

    Args:
        with_classifier: keep the ImageNet classifier (1000 classes).
    """
    return DenseNet(block_config=(6, 12, 24, 16), growth_rate=32, num_init_features=64,
                    bn_size=4, with_classifier=with_classifier)


def rename_legacy_keys(state_dict: Mapping[str, Any]) -> dict[str, Any]:
    """``state_dict`` with the dense layers' pre-0.4 torchvision names (``...denselayer1.norm.1.
    weight``) renamed to the current ones (``...denselayer1.norm1.weight``); other keys as
    they are. What torchvision does when it loads its published DenseNet checkpoints."""
    renamed = {}
    for key, value in state_dict.items():
        match = _LEGACY_KEY.match(key)
        renamed[match.group(1) + match.group(2) if match else key] = value
    return renamed
