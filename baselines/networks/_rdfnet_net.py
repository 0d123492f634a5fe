"""RDFNet-101 (Park, Hong and Lee, ICCV 2017) as ported to PyTorch in
charlesCXK/PyTorch_Semantic_Segmentation (``RDFNet_PyTorch``), the port ESANet timed.

Written from ``RDFNet_PyTorch/rdfnet.py``, ``blocks.py`` and ``resnet101.py`` at commit
da459730efe495153edaf6cb5cf70545daa3e3e4 (facts, not code):

* two ResNet-101 encoders with PSPNet's three-convolution stem (64, 64, 128 channels), one for
  RGB and one for HHA; batch-norm momentum 0.0003 as in the port;
* a multi-modal feature fusion (MMF) block per stage (256, 512, 1024, 2048 channels): each
  modality goes through a bias-free 1x1 reduction to half the channels, two residual conv units
  and a bias-free 3x3 convolution back to the full channels; the two are summed and rectified,
  and a residual pooling (5x5 max pooling, bias-free 3x3 convolution) is added;
* bias-free 3x3 projections of the fused maps to 256 channels (512 for the 1/32 map);
* RefineNet's cascade of four RefineNet blocks (two RCUs per input, multi-resolution fusion by
  bias-free 3x3 convolutions and bilinear upsampling to the finest input, a two-stage chained
  residual pooling that rectifies its input, one output RCU);
* a head of two RCUs and a 1x1 classifier with bias, upsampled (bilinear, corners aligned) to
  the input size.

Two behaviours of the port are kept on purpose: its residual conv unit applies an in-place ReLU
to its input, so the skip it adds is the rectified input (``residual_after_relu``); and the chained
residual pooling rectifies its input first. One is changed: the port's multi-resolution fusion
upsamples to a square size fixed at construction (``input_size // 4`` etc.), which only works for
square inputs of exactly that size; here it upsamples to the finest input's size (identical for
the port's square inputs, and correct for 480x640).

With 40 classes the model has 358,622,888 parameters, exactly the port's ``RDF(num_classes=40)``
(the paper's Table I prints 443.8 M).
"""

from __future__ import annotations

from functools import partial

import torch.nn.functional as F
from torch import Tensor, nn

from baselines.backbones.resnet import ResNet, resnet101
from baselines.networks._refinenet_net import (
    ChainedResidualPooling,
    ResidualConvUnit,
    conv3x3,
)

__all__ = [
    "MultiModalFusion",
    "MultiResolutionFusion",
    "RDFNet",
    "RefineNetBlock",
    "rdfnet_r101",
]

#: Channels of the decoder (the 1/32 path uses twice as many).
FEATURES = 256
#: Stages of the chained residual pooling of RDFNet's RefineNet blocks.
CRP_STAGES = 2
#: Batch-norm momentum of the port's encoders.
BN_MOMENTUM = 0.0003


def _rcu(channels: int) -> ResidualConvUnit:
    """The port's residual conv unit (its skip adds the rectified input)."""
    return ResidualConvUnit(channels=channels, residual_after_relu=True)


class MultiModalFusion(nn.Module):
    """RDFNet's MMF block: ``f = relu(rgb_branch(rgb) + hha_branch(hha))``, returns
    ``f + conv3x3(maxpool5x5(f))``.

    Args:
        channels: channels of both inputs and of the output; the branches work at half of it.
    """

    def __init__(self, *, channels: int) -> None:
        super().__init__()
        self.rgb = self._branch(channels)
        self.hha = self._branch(channels)
        self.pool = nn.MaxPool2d(kernel_size=5, stride=1, padding=2)
        self.pool_conv = conv3x3(channels, channels)

    @staticmethod
    def _branch(channels: int) -> nn.Sequential:
        half = channels // 2
        return nn.Sequential(
            nn.Conv2d(channels, half, kernel_size=1, bias=False),
            _rcu(half), _rcu(half),
            conv3x3(half, channels))

    def forward(self, rgb: Tensor, hha: Tensor) -> Tensor:
        fused = F.relu(self.rgb(rgb) + self.hha(hha))
        return fused + self.pool_conv(self.pool(fused))


class MultiResolutionFusion(nn.Module):
    """Sum of bias-free 3x3 projections of the inputs, each upsampled (bilinear, corners
    aligned) to the finest (last) input's size where it differs.

    Args:
        in_channels: channels of each input.
        out_channels: channels of the output.
    """

    def __init__(self, *, in_channels: tuple[int, ...], out_channels: int) -> None:
        super().__init__()
        self.projections = nn.ModuleList(conv3x3(c, out_channels) for c in in_channels)

    def forward(self, *xs: Tensor) -> Tensor:
        size = xs[-1].shape[-2:]
        out: Tensor | None = None
        for projection, x in zip(self.projections, xs, strict=True):
            y = projection(x)
            if y.shape[-2:] != size:
                y = F.interpolate(y, size=size, mode="bilinear", align_corners=True)
            out = y if out is None else out + y
        assert out is not None
        return out


class RefineNetBlock(nn.Module):
    """RDFNet's RefineNet block: two RCUs per input, multi-resolution fusion (more than one
    input), a two-stage chained residual pooling and an output RCU.

    Args:
        features: channels of the fused map and of the output.
        in_channels: channels of each input, coarsest first.
    """

    def __init__(self, *, features: int, in_channels: tuple[int, ...]) -> None:
        super().__init__()
        self.adapt = nn.ModuleList(nn.Sequential(_rcu(c), _rcu(c)) for c in in_channels)
        self.fuse = (MultiResolutionFusion(in_channels=in_channels, out_channels=features)
                     if len(in_channels) > 1 else None)
        self.crp = ChainedResidualPooling(channels=features, stages=CRP_STAGES,
                                          relu_first=True)
        self.out = _rcu(features)

    def forward(self, *xs: Tensor) -> Tensor:
        adapted = [adapt(x) for adapt, x in zip(self.adapt, xs, strict=True)]
        x = self.fuse(*adapted) if self.fuse is not None else adapted[0]
        return self.out(self.crp(x))


class RDFNet(nn.Module):
    """RDFNet on two ResNet encoders (see the module notes); ``forward(rgb, hha)`` returns
    logits at the input size.

    Args:
        rgb_encoder: the RGB ResNet (``forward_features`` gives the four stage outputs).
        hha_encoder: the HHA ResNet, of the same shape.
        num_classes: classifier outputs.
        features: decoder channels.
    """

    def __init__(self, *, rgb_encoder: ResNet, hha_encoder: ResNet, num_classes: int,
                 features: int = FEATURES) -> None:
        super().__init__()
        if rgb_encoder.channels != hha_encoder.channels:
            raise ValueError("the RGB and HHA encoders must have the same stage channels")
        channels = rgb_encoder.channels
        self.rgb_encoder = rgb_encoder
        self.hha_encoder = hha_encoder
        self.mmf = nn.ModuleList(MultiModalFusion(channels=c) for c in channels)
        widths = (features, features, features, 2 * features)
        self.reduce = nn.ModuleList(conv3x3(c, w) for c, w in zip(channels, widths, strict=True))
        self.refine4 = RefineNetBlock(features=2 * features, in_channels=(2 * features,))
        self.refine3 = RefineNetBlock(features=features, in_channels=(2 * features, features))
        self.refine2 = RefineNetBlock(features=features, in_channels=(features, features))
        self.refine1 = RefineNetBlock(features=features, in_channels=(features, features))
        self.head = nn.Sequential(_rcu(features), _rcu(features),
                                  nn.Conv2d(features, num_classes, kernel_size=1, bias=True))

    def forward(self, rgb: Tensor, hha: Tensor) -> Tensor:
        rgb_maps = self.rgb_encoder.forward_features(rgb)
        hha_maps = self.hha_encoder.forward_features(hha)
        l1, l2, l3, l4 = (reduce(mmf(r, h)) for reduce, mmf, r, h
                          in zip(self.reduce, self.mmf, rgb_maps, hha_maps, strict=True))
        x = self.refine4(l4)
        x = self.refine3(x, l3)
        x = self.refine2(x, l2)
        x = self.refine1(x, l1)
        out = self.head(x)
        return F.interpolate(out, size=rgb.shape[-2:], mode="bilinear", align_corners=True)


def _encoder() -> ResNet:
    return resnet101(deep_stem=True, stem_width=64,
                     norm_layer=partial(nn.BatchNorm2d, momentum=BN_MOMENTUM))


def rdfnet_r101(*, num_classes: int) -> RDFNet:
    """RDFNet-101 of the charlesCXK port with ``num_classes`` outputs.

    Args:
        num_classes: classifier outputs (40 for NYUv2: 358,622,888 parameters).
    """
    return RDFNet(rgb_encoder=_encoder(), hha_encoder=_encoder(), num_classes=num_classes)
