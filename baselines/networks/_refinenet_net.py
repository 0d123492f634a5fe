"""RefineNet-101 (Lin et al., CVPR 2017) as released in PyTorch by DrSleep/refinenet-pytorch.

Written from ``models/resnet.py`` (``rf101``) and ``utils/layer_factory.py`` of
DrSleep/refinenet-pytorch at commit 8f25c076016e61a835551493aae303e81cf36c53 (facts, not code):

* a torchvision ResNet-101 (7x7 stem) encoder whose four stage outputs (strides 4, 8, 16, 32)
  feed four refinement paths, coarsest first;
* each path: a bias-free 3x3 reduction (2048 -> 512, then 1024/512/256 -> 256), an adaptive
  chain of two residual conv units (RCUs), a bias-free 3x3 projection of the reduced map (not on
  the coarsest path) summed with the upsampled output of the coarser path, a ReLU, a four-stage
  chained residual pooling (CRP), an output chain of three RCUs and, except on the finest path, a
  bias-free 3x3 projection to 256 channels that is upsampled (bilinear, corners aligned) to the
  next finer stage;
* dropout (p = 0.5) on the 1/16 and 1/32 encoder maps and before the classifier (training only);
* a 3x3 classifier with bias on the 1/4 map: the network returns logits at a quarter of the input
  size (the segmenter resizes them).

With 40 classes the model has 118,096,232 parameters, exactly the official ``rf101(40)``.
The blocks (:class:`ResidualConvUnit`, :class:`ChainedResidualPooling`) are also RDFNet's.
"""

from __future__ import annotations

import torch.nn.functional as F
from torch import Tensor, nn

from baselines.backbones.resnet import ResNet, resnet101

__all__ = [
    "ChainedResidualPooling",
    "RefineNet",
    "RefinePath",
    "ResidualConvUnit",
    "conv3x3",
    "refinenet_r101",
]

#: Channels of the coarsest path (fed by the 1/32 map) and of the three finer ones.
COARSE_WIDTH = 512
WIDTH = 256
#: Residual conv units in a path's adaptive chain and in its output chain.
ADAPT_UNITS = 2
OUTPUT_UNITS = 3
#: Stages of each chained residual pooling.
CRP_STAGES = 4
#: Dropout probability of the official network (encoder maps 1/16, 1/32 and before the head).
DROPOUT = 0.5


def conv3x3(in_channels: int, out_channels: int, *, bias: bool = False) -> nn.Conv2d:
    """3x3 convolution, stride 1, padding 1."""
    return nn.Conv2d(in_channels, out_channels, kernel_size=3, padding=1, bias=bias)


class ResidualConvUnit(nn.Module):
    """RefineNet's residual conv unit: ``x + conv_b(relu(conv_a(relu(x))))``.

    ``conv_a`` has a bias, ``conv_b`` has none (as in both RefineNet's and RDFNet's official
    code).

    Args:
        channels: input and output channels.
        residual_after_relu: add ``relu(x)`` instead of ``x`` as the skip. RDFNet's official
            unit applies an in-place ReLU to its input before the convolutions, so the skip it
            adds is the rectified input; RefineNet's is the input itself.
    """

    def __init__(self, *, channels: int, residual_after_relu: bool = False) -> None:
        super().__init__()
        self.conv_a = conv3x3(channels, channels, bias=True)
        self.conv_b = conv3x3(channels, channels, bias=False)
        self.residual_after_relu = residual_after_relu

    def forward(self, x: Tensor) -> Tensor:
        rectified = F.relu(x)
        out = self.conv_b(F.relu(self.conv_a(rectified)))
        return out + (rectified if self.residual_after_relu else x)


def rcu_chain(channels: int, units: int, *, residual_after_relu: bool = False) -> nn.Sequential:
    """``units`` residual conv units of ``channels`` in sequence."""
    return nn.Sequential(*(ResidualConvUnit(channels=channels,
                                            residual_after_relu=residual_after_relu)
                           for _ in range(units)))


class ChainedResidualPooling(nn.Module):
    """Chained residual pooling: ``x + p1 + p2 + ...`` with ``p_i = conv_i(maxpool5x5(p_{i-1}))``
    and ``p_0 = x`` (max pooling 5x5, stride 1, padding 2; bias-free 3x3 convolutions).

    Args:
        channels: input and output channels.
        stages: pooling-convolution stages in the chain (4 in RefineNet, 2 in RDFNet).
        relu_first: rectify the input first (RDFNet's block does; RefineNet applies the ReLU
            before the block).
    """

    def __init__(self, *, channels: int, stages: int, relu_first: bool = False) -> None:
        super().__init__()
        self.pool = nn.MaxPool2d(kernel_size=5, stride=1, padding=2)
        self.convs = nn.ModuleList(conv3x3(channels, channels) for _ in range(stages))
        self.relu_first = relu_first

    def forward(self, x: Tensor) -> Tensor:
        if self.relu_first:
            x = F.relu(x)
        path = x
        for conv in self.convs:
            path = conv(self.pool(path))
            x = x + path
        return x


class RefinePath(nn.Module):
    """One RefineNet-101 refinement path (see the module notes).

    Args:
        in_channels: channels of the encoder map it refines.
        width: channels inside the path.
        fuses_coarser: the path adds the coarser path's output (every path but the coarsest);
            its reduced map is then projected by a 3x3 convolution first.
        out_channels: channels of the output projection, or ``None`` for the finest path (no
            projection: the classifier reads the output chain directly).
    """

    def __init__(self, *, in_channels: int, width: int, fuses_coarser: bool,
                 out_channels: int | None) -> None:
        super().__init__()
        self.reduce = conv3x3(in_channels, width)
        self.adapt = rcu_chain(width, ADAPT_UNITS)
        self.project = conv3x3(width, width) if fuses_coarser else None
        self.crp = ChainedResidualPooling(channels=width, stages=CRP_STAGES)
        self.refine = rcu_chain(width, OUTPUT_UNITS)
        self.out = conv3x3(width, out_channels) if out_channels is not None else None

    def forward(self, x: Tensor, coarser: Tensor | None = None) -> Tensor:
        x = self.adapt(self.reduce(x))
        if self.project is not None:
            if coarser is None:
                raise ValueError("this refinement path needs the coarser path's output")
            x = self.project(x) + coarser
        x = self.refine(self.crp(F.relu(x)))
        return self.out(x) if self.out is not None else x


class RefineNet(nn.Module):
    """RefineNet on a ResNet encoder (see the module notes); ``forward(rgb)`` returns logits at
    a quarter of the input size.

    Args:
        encoder: a ResNet whose ``forward_features`` gives the four stage outputs.
        num_classes: classifier outputs.
        dropout: dropout probability (training only).
    """

    def __init__(self, *, encoder: ResNet, num_classes: int, dropout: float = DROPOUT) -> None:
        super().__init__()
        c2, c3, c4, c5 = encoder.channels
        self.encoder = encoder
        self.dropout = nn.Dropout(p=dropout)
        self.path4 = RefinePath(in_channels=c5, width=COARSE_WIDTH, fuses_coarser=False,
                                out_channels=WIDTH)
        self.path3 = RefinePath(in_channels=c4, width=WIDTH, fuses_coarser=True,
                                out_channels=WIDTH)
        self.path2 = RefinePath(in_channels=c3, width=WIDTH, fuses_coarser=True,
                                out_channels=WIDTH)
        self.path1 = RefinePath(in_channels=c2, width=WIDTH, fuses_coarser=True,
                                out_channels=None)
        self.classifier = conv3x3(WIDTH, num_classes, bias=True)

    def forward(self, rgb: Tensor) -> Tensor:
        l1, l2, l3, l4 = self.encoder.forward_features(rgb)
        l3, l4 = self.dropout(l3), self.dropout(l4)
        x = _resize(self.path4(l4), l3)
        x = _resize(self.path3(l3, x), l2)
        x = _resize(self.path2(l2, x), l1)
        x = self.path1(l1, x)
        return self.classifier(self.dropout(x))


def _resize(x: Tensor, like: Tensor) -> Tensor:
    """``x`` upsampled bilinearly (corners aligned) to ``like``'s height and width."""
    return F.interpolate(x, size=like.shape[-2:], mode="bilinear", align_corners=True)


def refinenet_r101(*, num_classes: int) -> RefineNet:
    """RefineNet-101 of DrSleep/refinenet-pytorch (``rf101``) with ``num_classes`` outputs.

    Args:
        num_classes: classifier outputs (40 for NYUv2: 118,096,232 parameters; 37 for SUN
            RGB-D).
    """
    return RefineNet(encoder=resnet101(), num_classes=num_classes)
