"""DCNN-R152: Depth-aware CNN (Wang and Neumann, ECCV 2018) on ResNet-152, designed from the paper
and its VGG-16 release (laughtervv/DepthAwareCNN @ 8ae98f7f18b69f79e7df03397dec2543d3d0c8eb; no
public code has ResNet-152). docs/baselines/dcnn-r152.md gives every choice and its source.

* Depth-aware convolution: ``y(p0) = sum_n w(pn) F(p0, p0+pn) x(p0+pn) + b`` with the depth
  similarity ``F = exp(-alpha |D(p0) - D(p0+pn)|)``, ``D(p0)`` the depth at the window centre;
  it has exactly the parameters of the plain convolution it replaces. ``alpha`` = 1000/120 per
  metre: the release's kernel uses ``exp(-|dD|)`` on depth read as ``png / 120`` from
  millimetre PNGs.
* Depth-aware average pooling: the window's values weighted by ``F``, divided by ``sum F``
  (the paper's formula; the release's kernel counts each padding cell of a border window with
  weight 1, as a plain average pooling that includes padding, and so does this one).
* Encoder: a DeepLab-style ResNet-152 (output stride 8, dilated ``layer3``/``layer4``) whose
  7x7 stem convolution and the 3x3 convolution of each stage's first bottleneck are
  depth-aware (the release makes each VGG stage's first convolution depth-aware); the depth
  follows the feature maps down by 3x3 stride-2 average pooling, as in the release.
* Head (the release's ``Classifier_Module2``): depth-aware 3x3 convolution with dilation 12
  (``fc6``), ReLU, dropout, 1x1 convolution (``fc7``), ReLU, dropout, concatenation with its
  global average, 1x1 classifier (``fc8``); before it, a 3x3 depth-aware average pooling
  (the release's ``pool5a_d``). Logits at 1/8 of the input.

The head width is the one quantity neither the paper nor the release gives for ResNet-152: the
release's 1024 (VGG-16) gives 78.2 M parameters, 15 % under Table I's 92.0 M; 1664 (the
multiple of 128 closest to the table) gives 91,720,040 with 40 classes (-0.3 %).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn
from torch.nn.modules.utils import _pair

from baselines.backbones.resnet import Bottleneck, ResNet, resnet152

__all__ = [
    "ALPHA",
    "DCNN",
    "DepthAwareAvgPool2d",
    "DepthAwareConv2d",
    "dcnn_r152",
    "depth_similarity",
]

#: Depth similarity rate per metre (the release: ``exp(-|dD|)`` with ``D = mm / 120``).
ALPHA = 1000.0 / 120.0
#: Channels of the head's fc6/fc7 (see the module notes).
HEAD_WIDTH = 1664
#: Dilation of fc6 (the release's ``Classifier_Module2``).
HEAD_DILATION = 12


def depth_similarity(depth: Tensor, *, kernel_size: tuple[int, int], stride: tuple[int, int],
                     padding: tuple[int, int], dilation: tuple[int, int],
                     alpha: float = ALPHA) -> Tensor:
    """``exp(-alpha |D(centre) - D(sample)|)`` for every sample of every window,
    ``(B, kh*kw, L)`` with ``L`` output positions (``F.unfold``'s layout). Samples in the
    padding get the similarity of depth 0; the caller multiplies them by zero features."""
    windows = F.unfold(depth, kernel_size, dilation=dilation, padding=padding, stride=stride)
    centre = windows[:, (kernel_size[0] * kernel_size[1]) // 2].unsqueeze(1)
    return torch.exp(-alpha * (windows - centre).abs())


class DepthAwareConv2d(nn.Module):
    """A convolution whose every tap is scaled by the depth similarity to the window centre.

    Same parameters (``weight``, ``bias``) as :class:`torch.nn.Conv2d`, so a plain
    convolution's state dict loads into it.

    Args:
        in_channels: input channels.
        out_channels: output channels.
        kernel_size: window size (odd).
        stride: stride.
        padding: zero padding.
        dilation: dilation.
        bias: add a learned bias.
        alpha: depth similarity rate (per depth unit).
    """

    def __init__(self, *, in_channels: int, out_channels: int, kernel_size: int,
                 stride: int = 1, padding: int = 0, dilation: int = 1, bias: bool = True,
                 alpha: float = ALPHA) -> None:
        super().__init__()
        plain = nn.Conv2d(in_channels, out_channels, kernel_size, stride=stride,
                          padding=padding, dilation=dilation, bias=bias)
        self.weight = plain.weight
        self.bias = plain.bias
        self.kernel_size = _pair(kernel_size)
        self.stride = _pair(stride)
        self.padding = _pair(padding)
        self.dilation = _pair(dilation)
        self.alpha = alpha

    @classmethod
    def like(cls, conv: nn.Conv2d, *, alpha: float = ALPHA) -> DepthAwareConv2d:
        """The depth-aware version of ``conv`` (same shape, hyper-parameters and weights)."""
        out = cls(in_channels=conv.in_channels, out_channels=conv.out_channels,
                  kernel_size=conv.kernel_size[0], stride=conv.stride[0],
                  padding=conv.padding[0], dilation=conv.dilation[0],
                  bias=conv.bias is not None, alpha=alpha)
        out.weight = conv.weight
        out.bias = conv.bias
        return out

    def forward(self, x: Tensor, depth: Tensor) -> Tensor:
        batch, channels, height, width = x.shape
        kh, kw = self.kernel_size
        geometry = dict(dilation=self.dilation, padding=self.padding, stride=self.stride)
        similarity = depth_similarity(depth, kernel_size=self.kernel_size, alpha=self.alpha,
                                      **geometry)
        columns = F.unfold(x, self.kernel_size, **geometry)  # (B, C*kh*kw, L)
        columns = (columns.view(batch, channels, kh * kw, -1) * similarity.unsqueeze(1))
        out = self.weight.view(self.weight.shape[0], -1) @ columns.view(batch, channels * kh * kw,
                                                                          -1)
        if self.bias is not None:
            out = out + self.bias.view(1, -1, 1)
        out_h = (height + 2 * self.padding[0] - self.dilation[0] * (kh - 1) - 1) \
            // self.stride[0] + 1
        out_w = (width + 2 * self.padding[1] - self.dilation[1] * (kw - 1) - 1) \
            // self.stride[1] + 1
        return out.view(batch, -1, out_h, out_w)


class DepthAwareAvgPool2d(nn.Module):
    """Average pooling whose samples are weighted by the depth similarity to the window centre:
    ``sum F x / sum F``, padding cells counting as zero values of weight 1 (the release's
    kernel; on flat depth it is ``nn.AvgPool2d(k, 1, k // 2)``).

    Args:
        kernel_size: window size (odd); stride 1, padding ``kernel_size // 2``.
        alpha: depth similarity rate (per depth unit).
    """

    def __init__(self, *, kernel_size: int = 3, alpha: float = ALPHA) -> None:
        super().__init__()
        self.kernel_size = _pair(kernel_size)
        self.padding = (kernel_size // 2, kernel_size // 2)
        self.alpha = alpha

    def forward(self, x: Tensor, depth: Tensor) -> Tensor:
        batch, channels, height, width = x.shape
        k = self.kernel_size[0] * self.kernel_size[1]
        geometry = dict(dilation=(1, 1), padding=self.padding, stride=(1, 1))
        similarity = depth_similarity(depth, kernel_size=self.kernel_size, alpha=self.alpha,
                                      **geometry)
        columns = F.unfold(x, self.kernel_size, **geometry).view(batch, channels, k, -1)
        total = (columns * similarity.unsqueeze(1)).sum(2)
        inside = F.unfold(torch.ones_like(depth), self.kernel_size, **geometry)
        weight = (similarity * inside + (1.0 - inside)).sum(1, keepdim=True)
        return (total / weight).view(batch, channels, height, width)


def _downsample_depth(depth: Tensor) -> Tensor:
    """The release's depth pyramid step: 3x3 average pooling, stride 2, padding 1."""
    return F.avg_pool2d(depth, kernel_size=3, stride=2, padding=1)


def _first_block(block: Bottleneck, x: Tensor, depth: Tensor) -> Tensor:
    """A bottleneck whose 3x3 convolution is depth-aware (``depth`` at ``x``'s resolution)."""
    identity = x if block.downsample is None else block.downsample(x)
    out = block.relu(block.bn1(block.conv1(x)))
    out = block.relu(block.bn2(block.conv2(out, depth)))
    out = block.bn3(block.conv3(out))
    return block.relu(out + identity)


class DCNN(nn.Module):
    """Depth-aware CNN on a ResNet (see the module notes); ``forward(rgb, depth)`` with depth in
    metres returns logits at 1/8 of the input size.

    Args:
        encoder: a bottleneck ResNet with output stride 8; its stem convolution and each
            stage's first 3x3 convolution are made depth-aware (weights kept).
        num_classes: classifier outputs.
        head_width: channels of fc6 and fc7.
        alpha: depth similarity rate per metre.
    """

    def __init__(self, *, encoder: ResNet, num_classes: int, head_width: int = HEAD_WIDTH,
                 alpha: float = ALPHA) -> None:
        super().__init__()
        if encoder.output_stride != 8 or encoder.block is not Bottleneck:
            raise ValueError("DCNN needs a bottleneck ResNet with output stride 8")
        encoder.conv1 = DepthAwareConv2d.like(encoder.conv1, alpha=alpha)
        for stage in (encoder.layer1, encoder.layer2, encoder.layer3, encoder.layer4):
            stage[0].conv2 = DepthAwareConv2d.like(stage[0].conv2, alpha=alpha)
        self.encoder = encoder
        channels = encoder.channels[-1]
        self.pool = DepthAwareAvgPool2d(kernel_size=3, alpha=alpha)
        self.fc6 = DepthAwareConv2d(in_channels=channels, out_channels=head_width,
                                    kernel_size=3, padding=HEAD_DILATION,
                                    dilation=HEAD_DILATION, bias=True, alpha=alpha)
        self.fc7 = nn.Conv2d(head_width, head_width, kernel_size=1, bias=True)
        self.dropout = nn.Dropout(p=0.5)
        self.global_dropout = nn.Dropout(p=0.3)
        self.fc8 = nn.Conv2d(2 * head_width, num_classes, kernel_size=1, bias=True)

    def forward(self, rgb: Tensor, depth: Tensor) -> Tensor:
        e = self.encoder
        x = e.maxpool(e.relu(e.bn1(e.conv1(rgb, depth))))
        depth4 = _downsample_depth(_downsample_depth(depth))
        depth8 = _downsample_depth(depth4)
        x = _first_block(e.layer1[0], x, depth4)
        x = e.layer1[1:](x)
        x = _first_block(e.layer2[0], x, depth4)  # strides inside: its input is at 1/4
        x = e.layer2[1:](x)
        x = e.layer3[1:](_first_block(e.layer3[0], x, depth8))
        x = e.layer4[1:](_first_block(e.layer4[0], x, depth8))
        x = self.pool(x, depth8)
        x = self.dropout(F.relu(self.fc6(x, depth8)))
        x = self.dropout(F.relu(self.fc7(x)))
        context = self.global_dropout(x.mean(dim=(2, 3), keepdim=True)).expand_as(x)
        return self.fc8(torch.cat((x, context), dim=1))


def dcnn_r152(*, num_classes: int) -> DCNN:
    """Depth-aware CNN with a ResNet-152 encoder and ``num_classes`` outputs.

    Args:
        num_classes: classifier outputs (40 for NYUv2: 91,720,040 parameters).
    """
    return DCNN(encoder=resnet152(output_stride=8), num_classes=num_classes)
