"""CANet (Zhou et al., Pattern Recognition 2022), the network: ACNet's three ResNet-50 branches
fused by plain addition, a co-attention fusion of the last stage, and ACNet's decoder.

Written from zhouhao94/CANet ``CANet_models.py`` and ``Co_attention.py`` with the configuration of
its training script (``backbone='ResNet-50', pcca5=True``; docs/baselines/canet-r50.md):

* RGB and depth branches: torchvision ResNet-50s (depth with a 1-channel ``conv1``); the merged
  branch is ``layer1`` .. ``layer4`` of a third. ``m0 = rgb + depth`` after the stems (before max
  pooling), ``m_i = merge_i(m_{i-1}) + rgb_i + depth_i`` after stages 1 - 3.
* Stage 4 (``pcca5``): each branch's 2048-channel map is reduced to 512 (3x3 conv, BN, ReLU); a
  position co-attention (:class:`PositionCoAttention`, queries from RGB, keys and values from
  depth) and a channel co-attention (:class:`ChannelCoAttention`) each give a 512-channel map,
  lifted to 1024 by a 1x1 conv, BN, ReLU; :class:`CoAttentionFusion` (a split-attention layer)
  fuses them with the merged branch's output into ``m4`` (2048 channels).
* Decoder: ACNet's (:class:`baselines.networks._acnet_net.ACDecoder`), with its four
  training-only side classifiers (counted in the official 127,306,954 parameters).

As in the official ``FusionLayer``, the channel-attention path reweights the same two maps as the
position path (the first half of the merged map and the position features): the channel
co-attention features enter only through the attention weights. Kept as released, since the
released weights were trained so.

The input height and width must be multiples of 32.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from baselines.backbones.resnet import ResNet, resnet50
from baselines.networks._acnet_net import ACDecoder

__all__ = ["CANet", "ChannelCoAttention", "CoAttentionFusion", "PositionCoAttention",
           "canet_r50"]

#: Channels of the branches' stage-4 maps after the 3x3 reduction.
ATTENTION_CHANNELS = 512
#: Channels of each half of the merged stage-4 map (2048 / 2).
HALF_CHANNELS = 1024


class PositionCoAttention(nn.Module):
    """Position co-attention (DANet's position attention across modalities): queries from
    ``x`` (RGB), keys and values from ``y`` (depth); ``gamma * attended + x``.

    Args:
        channels: input channels; queries and keys have ``channels // 8``.
    """

    def __init__(self, *, channels: int) -> None:
        super().__init__()
        self.query_conv = nn.Conv2d(channels, channels // 8, 1)
        self.key_conv = nn.Conv2d(channels, channels // 8, 1)
        self.value_conv = nn.Conv2d(channels, channels, 1)
        self.gamma = nn.Parameter(torch.zeros(1))

    def forward(self, x: Tensor, y: Tensor) -> Tensor:
        b, c, h, w = x.shape
        query = self.query_conv(x).flatten(2).transpose(1, 2)  # B, N, C/8
        key = self.key_conv(y).flatten(2)  # B, C/8, N
        attention = torch.softmax(torch.bmm(query, key), dim=-1)  # B, N (query), N (key)
        value = self.value_conv(y).flatten(2)  # B, C, N
        out = torch.bmm(value, attention.transpose(1, 2)).reshape(b, c, h, w)
        return self.gamma * out + x


class ChannelCoAttention(nn.Module):
    """Channel co-attention (DANet's channel attention across modalities): the ``C x C``
    affinity of ``x`` (RGB) with ``y`` (depth), turned into ``softmax(max - energy)``, mixes the
    channels of ``y``; ``gamma * mixed + x``. One parameter, ``gamma``."""

    def __init__(self) -> None:
        super().__init__()
        self.gamma = nn.Parameter(torch.zeros(1))

    def forward(self, x: Tensor, y: Tensor) -> Tensor:
        b, c, h, w = x.shape
        value = y.flatten(2)  # B, C, N
        energy = torch.bmm(x.flatten(2), value.transpose(1, 2))  # B, C, C
        energy = energy.amax(dim=-1, keepdim=True) - energy
        out = torch.bmm(torch.softmax(energy, dim=-1), value).reshape(b, c, h, w)
        return self.gamma * out + x


class CoAttentionFusion(nn.Module):
    """CANet's stage-4 fusion (the official ``FusionLayer``, a split attention of radix 2).

    With ``x`` split into halves ``x1, x2``: ``g_p = x1 + p``, ``g_c = x2 + c``; each is globally
    pooled and passed through 1x1 conv (with bias), BN, ReLU, 1x1 conv to ``2 * channels``; a
    softmax over the two halves gives weights ``(a0, a1)``; the output is
    ``cat(a0_p * x1 + a1_p * p, a0_c * x1 + a1_c * p)`` (see the module notes).

    Args:
        channels: channels of each half of ``x`` and of ``p`` and ``c``.
        reduction: bottleneck reduction of the attention (inner width ``max(channels //
            reduction, 32)``).
    """

    radix = 2

    def __init__(self, *, channels: int, reduction: int = 4) -> None:
        super().__init__()
        inner = max(channels // reduction, 32)
        self.fc1_p = nn.Conv2d(channels, inner, 1)
        self.fc1_c = nn.Conv2d(channels, inner, 1)
        self.bn1_p = nn.BatchNorm2d(inner)
        self.bn1_c = nn.BatchNorm2d(inner)
        self.fc2_p = nn.Conv2d(inner, channels * self.radix, 1)
        self.fc2_c = nn.Conv2d(inner, channels * self.radix, 1)
        self.channels = channels

    def _weights(self, g: Tensor, fc1: nn.Module, bn: nn.Module, fc2: nn.Module
                 ) -> tuple[Tensor, Tensor]:
        a = fc2(F.relu(bn(fc1(F.adaptive_avg_pool2d(g, 1)))))  # B, 2C, 1, 1
        a = torch.softmax(a.reshape(a.shape[0], self.radix, self.channels), dim=1)
        return a[:, 0, :, None, None], a[:, 1, :, None, None]

    def forward(self, x: Tensor, p: Tensor, c: Tensor) -> Tensor:
        x1, x2 = torch.split(x, self.channels, dim=1)
        w0_p, w1_p = self._weights(x1 + p, self.fc1_p, self.bn1_p, self.fc2_p)
        w0_c, w1_c = self._weights(x2 + c, self.fc1_c, self.bn1_c, self.fc2_c)
        return torch.cat([w0_p * x1 + w1_p * p, w0_c * x1 + w1_c * p], dim=1)


def _conv_bn_relu(in_channels: int, out_channels: int, kernel: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(in_channels, out_channels, kernel, padding=kernel // 2, bias=False),
        nn.BatchNorm2d(out_channels), nn.ReLU(inplace=True))


class CANet(nn.Module):
    """CANet with ResNet-50 branches and the stage-4 co-attention (``pcca5``).

    ``forward(rgb, depth)``: ``rgb`` ``(B, 3, H, W)``, ``depth`` ``(B, 1, H, W)``; returns logits
    ``(B, num_classes, H, W)`` (eval mode; in training mode also the side outputs).

    Args:
        num_classes: output classes (40 for NYUv2, 37 for SUN RGB-D).
    """

    def __init__(self, *, num_classes: int) -> None:
        super().__init__()
        self.rgb: ResNet = resnet50()
        self.depth: ResNet = resnet50(in_chans=1)
        merged = resnet50()  # only its stages: the merged branch starts from the pooled m0
        self.merge = nn.ModuleList([merged.layer1, merged.layer2, merged.layer3, merged.layer4])
        c5 = self.rgb.channels[-1]
        self.reduce_rgb = _conv_bn_relu(c5, ATTENTION_CHANNELS, 3)
        self.reduce_depth = _conv_bn_relu(c5, ATTENTION_CHANNELS, 3)
        self.position = PositionCoAttention(channels=ATTENTION_CHANNELS)
        self.channel = ChannelCoAttention()
        self.position_proj = _conv_bn_relu(ATTENTION_CHANNELS, HALF_CHANNELS, 1)
        self.channel_proj = _conv_bn_relu(ATTENTION_CHANNELS, HALF_CHANNELS, 1)
        self.fusion = CoAttentionFusion(channels=HALF_CHANNELS)
        self.decoder = ACDecoder(num_classes=num_classes)

    def encode(self, rgb: Tensor, depth: Tensor) -> list[Tensor]:
        """The fused maps ``[m0, m1, m2, m3, m4]`` (strides 2, 4, 8, 16, 32)."""
        rgb = F.relu(self.rgb.bn1(self.rgb.conv1(rgb)))
        depth = F.relu(self.depth.bn1(self.depth.conv1(depth)))
        fused = [rgb + depth]
        rgb, depth, m = _maxpool(rgb), _maxpool(depth), _maxpool(fused[0])
        rgb_stages = (self.rgb.layer1, self.rgb.layer2, self.rgb.layer3, self.rgb.layer4)
        depth_stages = (self.depth.layer1, self.depth.layer2, self.depth.layer3,
                        self.depth.layer4)
        for i, (rgb_stage, depth_stage, merge_stage) in enumerate(
                zip(rgb_stages, depth_stages, self.merge, strict=True)):
            rgb, depth, m = rgb_stage(rgb), depth_stage(depth), merge_stage(m)
            if i < 3:
                m = m + rgb + depth
                fused.append(m)
        rgb, depth = self.reduce_rgb(rgb), self.reduce_depth(depth)
        position = self.position_proj(self.position(rgb, depth))
        channel = self.channel_proj(self.channel(rgb, depth))
        fused.append(self.fusion(m, position, channel))
        return fused

    def forward(self, rgb: Tensor, depth: Tensor) -> Tensor | tuple[Tensor, ...]:
        return self.decoder(self.encode(rgb, depth))


def _maxpool(x: Tensor) -> Tensor:
    """The ResNet stem's 3x3 stride-2 max pooling."""
    return F.max_pool2d(x, kernel_size=3, stride=2, padding=1)


def canet_r50(*, num_classes: int) -> CANet:
    """CANet-R50 for ``num_classes`` classes (127,306,954 parameters for 40).

    Args:
        num_classes: output classes.
    """
    return CANet(num_classes=num_classes)
