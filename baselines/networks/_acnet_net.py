"""ACNet (Hu et al., ICIP 2019), the network: three ResNet-50 branches (RGB, depth, merged) joined
by channel attention, and the transposed-convolution decoder that CANet reuses.

Written from anheidelonghu/ACNet ``ACNet_models_V1.py`` (docs/baselines/acnet-r50.md):

* RGB branch: a torchvision ResNet-50; depth branch: the same with a 1-channel ``conv1`` (the
  official code builds its ``conv1_d`` as ``Conv2d(1, 64, 7, 2, 3)`` and initialises it with the
  channel mean of the ImageNet ``conv1``).
* Attention complementary modules: ``sigmoid(conv1x1(global average pool(x)))`` (a 1x1 convolution
  with bias, no BatchNorm) weights each branch per channel. After the stem (before its max
  pooling) ``m0 = rgb * A_rgb0(rgb) + depth * A_d0(depth)``; after each stage ``i``
  ``m_i = merge_i(m_{i-1}) + rgb_i * A_rgb_i(rgb_i) + depth_i * A_d_i(depth_i)``, where the merged
  branch is ``layer1`` .. ``layer4`` of a third ResNet-50 (no stem of its own: it starts from the
  max-pooled ``m0``).
* Decoder (:class:`ACDecoder`): 1x1 "agant" projections of ``m0`` .. ``m4`` (64, 64, 128, 256, 512
  channels), four stages of residual :class:`TransBasicBlock` s that double the resolution with
  transposed convolutions (6, 4, 3, 3 blocks), a skip addition after each, three more blocks at
  stride 2 and a 2x2 transposed convolution to the classes at the input resolution.
* Four 1x1 side classifiers (``out5`` .. ``out2``) run in training mode only (deep supervision,
  the official training loss); they are part of the official parameter count (116,628,168 for
  40 classes), so they are kept. In eval mode ``forward`` returns the full-resolution logits only.

The input height and width must be multiples of 32.
"""

from __future__ import annotations

import torch.nn.functional as F
from torch import Tensor, nn

from baselines.backbones.resnet import ResNet, resnet50

__all__ = ["ACDecoder", "ACNet", "TransBasicBlock", "acnet_r50", "channel_attention"]

#: Channels of the fused maps m0 .. m4 (stem, layer1 .. layer4 of a ResNet-50).
FUSED_CHANNELS: tuple[int, ...] = (64, 256, 512, 1024, 2048)
#: Channels of the decoder at the strides 2, 4, 8, 16, 32 (the agant projections' outputs).
DECODER_CHANNELS: tuple[int, ...] = (64, 64, 128, 256, 512)
#: Residual blocks of the four upsampling stages (stride 32 -> 16 -> 8 -> 4 -> 2).
DECODER_BLOCKS: tuple[int, ...] = (6, 4, 3, 3)
#: Residual blocks of the final stage at stride 2.
FINAL_BLOCKS = 3
#: Total stride of the encoder; inputs must be a multiple of it.
OUTPUT_STRIDE = 32


def channel_attention(channels: int) -> nn.Sequential:
    """ACNet's attention complementary module: global average pooling, a 1x1 convolution (with
    bias) and a sigmoid, giving one weight per channel."""
    return nn.Sequential(nn.AdaptiveAvgPool2d(1), nn.Conv2d(channels, channels, 1),
                         nn.Sigmoid())


def _conv_bn_relu(in_channels: int, out_channels: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(in_channels, out_channels, 1, bias=False),
                         nn.BatchNorm2d(out_channels), nn.ReLU(inplace=True))


class TransBasicBlock(nn.Module):
    """The decoder's residual block: a 3x3 convolution keeping the channels, then either a 3x3
    convolution to ``planes`` or, when upsampling, a 3x3 stride-2 transposed convolution (output
    padding 1, doubling the size); the shortcut is the identity or ``shortcut`` (a 2x2 stride-2
    transposed convolution or a 1x1 convolution, each with BatchNorm).

    Args:
        inplanes: input channels.
        planes: output channels.
        stride: 2 to double the resolution (needs ``shortcut``), else 1.
        shortcut: projection of the input when the shape changes, or None.
    """

    def __init__(self, *, inplanes: int, planes: int, stride: int = 1,
                 shortcut: nn.Module | None = None) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(inplanes, inplanes, 3, padding=1, bias=False)
        self.bn1 = nn.BatchNorm2d(inplanes)
        if shortcut is not None and stride != 1:
            self.conv2: nn.Module = nn.ConvTranspose2d(inplanes, planes, 3, stride=stride,
                                                       padding=1, output_padding=1, bias=False)
        else:
            self.conv2 = nn.Conv2d(inplanes, planes, 3, stride=stride, padding=1, bias=False)
        self.bn2 = nn.BatchNorm2d(planes)
        self.upsample = shortcut

    def forward(self, x: Tensor) -> Tensor:
        out = F.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        identity = x if self.upsample is None else self.upsample(x)
        return F.relu(out + identity)


def trans_stage(inplanes: int, planes: int, blocks: int, *, stride: int = 1) -> nn.Sequential:
    """``blocks - 1`` channel-keeping blocks, then one block to ``planes`` (upsampling by
    ``stride``), as the official ``_make_transpose``."""
    shortcut = None
    if stride != 1:
        shortcut = nn.Sequential(
            nn.ConvTranspose2d(inplanes, planes, 2, stride=stride, bias=False),
            nn.BatchNorm2d(planes))
    elif inplanes != planes:
        shortcut = nn.Sequential(nn.Conv2d(inplanes, planes, 1, bias=False),
                                 nn.BatchNorm2d(planes))
    layers = [TransBasicBlock(inplanes=inplanes, planes=inplanes) for _ in range(blocks - 1)]
    layers.append(TransBasicBlock(inplanes=inplanes, planes=planes, stride=stride,
                                  shortcut=shortcut))
    return nn.Sequential(*layers)


class ACDecoder(nn.Module):
    """ACNet's (and CANet's) decoder from the fused maps ``m0`` (stride 2) .. ``m4`` (stride 32)
    to logits at the input resolution.

    Args:
        num_classes: output classes.
    """

    def __init__(self, *, num_classes: int) -> None:
        super().__init__()
        self.agant = nn.ModuleList(
            _conv_bn_relu(c_in, c_out)
            for c_in, c_out in zip(FUSED_CHANNELS, DECODER_CHANNELS, strict=True))
        widths = DECODER_CHANNELS[::-1]  # 512, 256, 128, 64, 64
        self.deconv = nn.ModuleList(
            trans_stage(widths[i], widths[i + 1], DECODER_BLOCKS[i], stride=2)
            for i in range(len(DECODER_BLOCKS)))
        self.final_conv = trans_stage(widths[-1], widths[-1], FINAL_BLOCKS)
        self.final_deconv = nn.ConvTranspose2d(widths[-1], num_classes, 2, stride=2)
        # Training-only side classifiers after each upsampling stage (official out5 .. out2).
        self.side = nn.ModuleList(nn.Conv2d(w, num_classes, 1) for w in widths[1:])

    def forward(self, fused: list[Tensor]) -> Tensor | tuple[Tensor, ...]:
        """Logits ``(B, C, H, W)``; in training mode also the four side outputs (strides 16, 8,
        4, 2), the main output first."""
        x = self.agant[4](fused[4])
        sides = []
        for i, stage in enumerate(self.deconv):
            x = stage(x)
            if self.training:
                sides.append(self.side[i](x))
            x = x + self.agant[3 - i](fused[3 - i])
        out = self.final_deconv(self.final_conv(x))
        if self.training:
            return (out, *sides[::-1])
        return out


class ACNet(nn.Module):
    """ACNet with ResNet-50 branches.

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
        self.atten_rgb = nn.ModuleList(channel_attention(c) for c in FUSED_CHANNELS)
        self.atten_depth = nn.ModuleList(channel_attention(c) for c in FUSED_CHANNELS)
        self.decoder = ACDecoder(num_classes=num_classes)

    def _fuse(self, i: int, rgb: Tensor, depth: Tensor) -> Tensor:
        return rgb * self.atten_rgb[i](rgb) + depth * self.atten_depth[i](depth)

    def encode(self, rgb: Tensor, depth: Tensor) -> list[Tensor]:
        """The fused maps ``[m0, m1, m2, m3, m4]`` (strides 2, 4, 8, 16, 32)."""
        rgb = F.relu(self.rgb.bn1(self.rgb.conv1(rgb)))
        depth = F.relu(self.depth.bn1(self.depth.conv1(depth)))
        fused = [self._fuse(0, rgb, depth)]
        rgb, depth = _maxpool(rgb), _maxpool(depth)
        m = _maxpool(fused[0])
        rgb_stages = (self.rgb.layer1, self.rgb.layer2, self.rgb.layer3, self.rgb.layer4)
        depth_stages = (self.depth.layer1, self.depth.layer2, self.depth.layer3,
                        self.depth.layer4)
        for i, (rgb_stage, depth_stage, merge_stage) in enumerate(
                zip(rgb_stages, depth_stages, self.merge, strict=True), start=1):
            rgb, depth = rgb_stage(rgb), depth_stage(depth)
            m = merge_stage(m) + self._fuse(i, rgb, depth)
            fused.append(m)
        return fused

    def forward(self, rgb: Tensor, depth: Tensor) -> Tensor | tuple[Tensor, ...]:
        return self.decoder(self.encode(rgb, depth))


def _maxpool(x: Tensor) -> Tensor:
    """The ResNet stem's 3x3 stride-2 max pooling."""
    return F.max_pool2d(x, kernel_size=3, stride=2, padding=1)


def acnet_r50(*, num_classes: int) -> ACNet:
    """ACNet-R50 for ``num_classes`` classes (116,628,168 parameters for 40).

    Args:
        num_classes: output classes.
    """
    return ACNet(num_classes=num_classes)
