"""PIDNet (Xu, Xiong and Bhattacharyya, CVPR 2023): the real-time three-branch network of
Table II, written from the official code (XuJiacong/PIDNet, ``models/pidnet.py`` and
``models/model_utils.py``; docs/baselines/pidnet-s.md).

Three branches share a ResNet-like stem:

* I (integral): the deep branch down to 1/64 (``layer3``..``layer5``) with a parallel
  aggregation pyramid pooling module (PAPPM, small and medium models) or DAPPM (large);
* P (proportional): a 1/8 detail branch (``layer3_``..``layer5_``) that attends to the I branch
  through pixel-attention-guided fusion (``pag3``, ``pag4``);
* D (derivative): a 1/8 boundary branch (``layer3_d``..``layer5_d``) fed by the I branch's
  differences (``diff3``, ``diff4``);

and the three meet in the boundary-attention-guided fusion (``dfm``: Light-Bag or Bag) before
the segmentation head. The output is at 1/8 of the input (the segmenter resizes).

This is the inference model (``get_pred_model``, ``augment=False``): the two auxiliary heads of
training (``seghead_p``, ``seghead_d``) are not built, as in the release's inference model and
its 7,625,715 parameters for PIDNet-S (19 classes). Parameter names follow the release, so its
state dicts load (strip their ``model.`` prefix).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

__all__ = ["PIDNET_VARIANTS", "PIDNet", "pidnet", "pidnet_s"]

#: Batch-norm momentum of the release (PyTorch's default 0.1).
BN_MOMENTUM = 0.1

#: Variant -> (m, n, planes, ppm_planes, head_planes) as in the release's ``get_pred_model``.
PIDNET_VARIANTS: dict[str, tuple[int, int, int, int, int]] = {
    "s": (2, 3, 32, 96, 128),
    "m": (2, 3, 64, 96, 128),
    "l": (3, 4, 64, 112, 256),
}


def _bn(channels: int) -> nn.BatchNorm2d:
    return nn.BatchNorm2d(channels, momentum=BN_MOMENTUM)


def _resize(x: Tensor, like: Tensor) -> Tensor:
    """Bilinear resize of ``x`` to ``like``'s spatial size (``align_corners=False``)."""
    return F.interpolate(x, size=like.shape[-2:], mode="bilinear", align_corners=False)


class BasicBlock(nn.Module):
    """Two 3x3 convolutions with a residual; the final ReLU can be left to the caller.

    Args:
        inplanes: input channels.
        planes: output channels.
        stride: stride of the first convolution.
        downsample: projection of the residual when the shape changes.
        no_relu: return the sum before the ReLU.
    """

    expansion = 1

    def __init__(self, *, inplanes: int, planes: int, stride: int = 1,
                 downsample: nn.Module | None = None, no_relu: bool = False) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(inplanes, planes, 3, stride=stride, padding=1, bias=False)
        self.bn1 = _bn(planes)
        self.conv2 = nn.Conv2d(planes, planes, 3, padding=1, bias=False)
        self.bn2 = _bn(planes)
        self.downsample = downsample
        self.no_relu = no_relu

    def forward(self, x: Tensor) -> Tensor:
        out = self.bn2(self.conv2(F.relu(self.bn1(self.conv1(x)))))
        out = out + (x if self.downsample is None else self.downsample(x))
        return out if self.no_relu else F.relu(out)


class Bottleneck(nn.Module):
    """1x1 - 3x3 - 1x1 bottleneck with expansion 2 (PIDNet's, not ResNet's 4); by default the
    sum is returned without the final ReLU.

    Args:
        inplanes: input channels.
        planes: bottleneck channels (output: ``2 * planes``).
        stride: stride of the 3x3 convolution.
        downsample: projection of the residual when the shape changes.
        no_relu: return the sum before the ReLU.
    """

    expansion = 2

    def __init__(self, *, inplanes: int, planes: int, stride: int = 1,
                 downsample: nn.Module | None = None, no_relu: bool = True) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(inplanes, planes, 1, bias=False)
        self.bn1 = _bn(planes)
        self.conv2 = nn.Conv2d(planes, planes, 3, stride=stride, padding=1, bias=False)
        self.bn2 = _bn(planes)
        self.conv3 = nn.Conv2d(planes, planes * self.expansion, 1, bias=False)
        self.bn3 = _bn(planes * self.expansion)
        self.downsample = downsample
        self.no_relu = no_relu

    def forward(self, x: Tensor) -> Tensor:
        out = F.relu(self.bn1(self.conv1(x)))
        out = F.relu(self.bn2(self.conv2(out)))
        out = self.bn3(self.conv3(out))
        out = out + (x if self.downsample is None else self.downsample(x))
        return out if self.no_relu else F.relu(out)


def _bn_relu_conv(inplanes: int, planes: int, kernel_size: int = 1,
                  groups: int = 1) -> nn.Sequential:
    return nn.Sequential(_bn(inplanes), nn.ReLU(inplace=True),
                         nn.Conv2d(inplanes, planes, kernel_size, padding=kernel_size // 2,
                                   groups=groups, bias=False))


def _pooled_scales(inplanes: int, branch_planes: int) -> list[nn.Sequential]:
    """The four pooled branches of (P)APPM: average pools of 5/2, 9/4, 17/8 and global."""
    pools: list[nn.Module] = [nn.AvgPool2d(kernel_size=k, stride=s, padding=k // 2)
                              for k, s in ((5, 2), (9, 4), (17, 8))]
    pools.append(nn.AdaptiveAvgPool2d((1, 1)))
    return [nn.Sequential(pool, *_bn_relu_conv(inplanes, branch_planes)) for pool in pools]


class PAPPM(nn.Module):
    """Parallel aggregation pyramid pooling (PIDNet-S/M): the four pooled scales, each added to
    the unpooled branch, processed together by one grouped 3x3 convolution.

    Args:
        inplanes: input channels.
        branch_planes: channels of each scale.
        outplanes: output channels.
    """

    def __init__(self, *, inplanes: int, branch_planes: int, outplanes: int) -> None:
        super().__init__()
        self.scale1, self.scale2, self.scale3, self.scale4 = _pooled_scales(inplanes,
                                                                            branch_planes)
        self.scale0 = _bn_relu_conv(inplanes, branch_planes)
        self.scale_process = _bn_relu_conv(branch_planes * 4, branch_planes * 4, 3, groups=4)
        self.compression = _bn_relu_conv(branch_planes * 5, outplanes)
        self.shortcut = _bn_relu_conv(inplanes, outplanes)

    def forward(self, x: Tensor) -> Tensor:
        base = self.scale0(x)
        scales = [_resize(scale(x), x) + base
                  for scale in (self.scale1, self.scale2, self.scale3, self.scale4)]
        processed = self.scale_process(torch.cat(scales, 1))
        return self.compression(torch.cat([base, processed], 1)) + self.shortcut(x)


class DAPPM(nn.Module):
    """Deep aggregation pyramid pooling (PIDNet-L, from DDRNet): the pooled scales processed
    one after the other, each with the previous one added.

    Args:
        inplanes: input channels.
        branch_planes: channels of each scale.
        outplanes: output channels.
    """

    def __init__(self, *, inplanes: int, branch_planes: int, outplanes: int) -> None:
        super().__init__()
        self.scale1, self.scale2, self.scale3, self.scale4 = _pooled_scales(inplanes,
                                                                            branch_planes)
        self.scale0 = _bn_relu_conv(inplanes, branch_planes)
        self.process1, self.process2, self.process3, self.process4 = (
            _bn_relu_conv(branch_planes, branch_planes, 3) for _ in range(4))
        self.compression = _bn_relu_conv(branch_planes * 5, outplanes)
        self.shortcut = _bn_relu_conv(inplanes, outplanes)

    def forward(self, x: Tensor) -> Tensor:
        outs = [self.scale0(x)]
        for scale, process in ((self.scale1, self.process1), (self.scale2, self.process2),
                               (self.scale3, self.process3), (self.scale4, self.process4)):
            outs.append(process(_resize(scale(x), x) + outs[-1]))
        return self.compression(torch.cat(outs, 1)) + self.shortcut(x)


def _conv_bn(inplanes: int, planes: int, kernel_size: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(inplanes, planes, kernel_size, padding=kernel_size // 2,
                                   bias=False), _bn(planes))


class PagFM(nn.Module):
    """Pixel-attention-guided fusion: the detail map ``x`` takes in the context map ``y``
    (upsampled) where their 1x1 embeddings agree (sigmoid of the channel-summed product).

    Args:
        in_channels: channels of ``x`` and ``y``.
        mid_channels: embedding channels.
    """

    def __init__(self, *, in_channels: int, mid_channels: int) -> None:
        super().__init__()
        self.f_x = _conv_bn(in_channels, mid_channels)
        self.f_y = _conv_bn(in_channels, mid_channels)

    def forward(self, x: Tensor, y: Tensor) -> Tensor:
        y_q = _resize(self.f_y(y), x)
        similarity = torch.sigmoid(torch.sum(self.f_x(x) * y_q, dim=1, keepdim=True))
        return (1 - similarity) * x + similarity * _resize(y, x)


class LightBag(nn.Module):
    """Light boundary-attention-guided fusion (PIDNet-S/M): the boundary map ``d`` weighs the
    detail ``p`` against the context ``i``, through two 1x1 convolutions.

    Args:
        in_channels: channels of ``p`` and ``i``.
        out_channels: output channels.
    """

    def __init__(self, *, in_channels: int, out_channels: int) -> None:
        super().__init__()
        self.conv_p = _conv_bn(in_channels, out_channels)
        self.conv_i = _conv_bn(in_channels, out_channels)

    def forward(self, p: Tensor, i: Tensor, d: Tensor) -> Tensor:
        edge = torch.sigmoid(d)
        return self.conv_p((1 - edge) * i + p) + self.conv_i(i + edge * p)


class Bag(nn.Module):
    """Boundary-attention-guided fusion (PIDNet-L): ``conv(e p + (1 - e) i)``, ``e`` the sigmoid
    of the boundary map.

    Args:
        in_channels: channels of ``p`` and ``i``.
        out_channels: output channels.
    """

    def __init__(self, *, in_channels: int, out_channels: int) -> None:
        super().__init__()
        self.conv = _bn_relu_conv(in_channels, out_channels, 3)

    def forward(self, p: Tensor, i: Tensor, d: Tensor) -> Tensor:
        edge = torch.sigmoid(d)
        return self.conv(edge * p + (1 - edge) * i)


class SegmentHead(nn.Module):
    """BN-ReLU-3x3 conv, BN-ReLU-1x1 conv (with bias) to the classes.

    Args:
        inplanes: input channels.
        interplanes: channels of the 3x3 convolution.
        outplanes: output channels (classes).
    """

    def __init__(self, *, inplanes: int, interplanes: int, outplanes: int) -> None:
        super().__init__()
        self.bn1 = _bn(inplanes)
        self.conv1 = nn.Conv2d(inplanes, interplanes, 3, padding=1, bias=False)
        self.bn2 = _bn(interplanes)
        self.conv2 = nn.Conv2d(interplanes, outplanes, 1, bias=True)

    def forward(self, x: Tensor) -> Tensor:
        return self.conv2(F.relu(self.bn2(self.conv1(F.relu(self.bn1(x))))))


def _layer(block: type[BasicBlock | Bottleneck], inplanes: int, planes: int, blocks: int,
           stride: int = 1) -> nn.Sequential:
    """``blocks`` residual blocks; the last of several skips its ReLU (the release's
    ``_make_layer``)."""
    out = planes * block.expansion
    downsample = (_conv_bn_stride(inplanes, out, stride)
                  if stride != 1 or inplanes != out else None)
    layers = [block(inplanes=inplanes, planes=planes, stride=stride, downsample=downsample)]
    layers += [block(inplanes=out, planes=planes, no_relu=index == blocks - 1)
               for index in range(1, blocks)]
    return nn.Sequential(*layers)


def _single(block: type[BasicBlock | Bottleneck], inplanes: int, planes: int) -> nn.Module:
    """One residual block without the final ReLU (the release's ``_make_single_layer``)."""
    out = planes * block.expansion
    downsample = _conv_bn_stride(inplanes, out, 1) if inplanes != out else None
    return block(inplanes=inplanes, planes=planes, downsample=downsample, no_relu=True)


def _conv_bn_stride(inplanes: int, planes: int, stride: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(inplanes, planes, 1, stride=stride, bias=False), _bn(planes))


class PIDNet(nn.Module):
    """PIDNet's inference model.

    Args:
        m: basic blocks of the shallow stages (and of the P branch).
        n: basic blocks of the I branch's 1/16 and 1/32 stages.
        num_classes: classes of the head.
        planes: base width (32 for PIDNet-S, 64 for M and L).
        ppm_planes: channels of each pyramid pooling scale.
        head_planes: channels of the head's 3x3 convolution.
    """

    def __init__(self, *, m: int = 2, n: int = 3, num_classes: int = 19, planes: int = 64,
                 ppm_planes: int = 96, head_planes: int = 128) -> None:
        super().__init__()
        p = planes
        # I branch
        self.conv1 = nn.Sequential(
            nn.Conv2d(3, p, 3, stride=2, padding=1), _bn(p), nn.ReLU(inplace=True),
            nn.Conv2d(p, p, 3, stride=2, padding=1), _bn(p), nn.ReLU(inplace=True))
        self.layer1 = _layer(BasicBlock, p, p, m)
        self.layer2 = _layer(BasicBlock, p, 2 * p, m, stride=2)
        self.layer3 = _layer(BasicBlock, 2 * p, 4 * p, n, stride=2)
        self.layer4 = _layer(BasicBlock, 4 * p, 8 * p, n, stride=2)
        self.layer5 = _layer(Bottleneck, 8 * p, 8 * p, 2, stride=2)
        # P branch
        self.compression3 = _conv_bn(4 * p, 2 * p)
        self.compression4 = _conv_bn(8 * p, 2 * p)
        self.pag3 = PagFM(in_channels=2 * p, mid_channels=p)
        self.pag4 = PagFM(in_channels=2 * p, mid_channels=p)
        self.layer3_ = _layer(BasicBlock, 2 * p, 2 * p, m)
        self.layer4_ = _layer(BasicBlock, 2 * p, 2 * p, m)
        self.layer5_ = _layer(Bottleneck, 2 * p, 2 * p, 1)
        # D branch
        if m == 2:
            self.layer3_d = _single(BasicBlock, 2 * p, p)
            self.layer4_d = _layer(Bottleneck, p, p, 1)
            self.diff3 = _conv_bn(4 * p, p, 3)
            self.spp: nn.Module = PAPPM(inplanes=16 * p, branch_planes=ppm_planes,
                                        outplanes=4 * p)
            self.dfm: nn.Module = LightBag(in_channels=4 * p, out_channels=4 * p)
        else:
            self.layer3_d = _single(BasicBlock, 2 * p, 2 * p)
            self.layer4_d = _single(BasicBlock, 2 * p, 2 * p)
            self.diff3 = _conv_bn(4 * p, 2 * p, 3)
            self.spp = DAPPM(inplanes=16 * p, branch_planes=ppm_planes, outplanes=4 * p)
            self.dfm = Bag(in_channels=4 * p, out_channels=4 * p)
        self.diff4 = _conv_bn(8 * p, 2 * p, 3)
        self.layer5_d = _layer(Bottleneck, 2 * p, 2 * p, 1)
        self.final_layer = SegmentHead(inplanes=4 * p, interplanes=head_planes,
                                       outplanes=num_classes)
        self._init_weights()

    def _init_weights(self) -> None:
        for module in self.modules():
            if isinstance(module, nn.Conv2d):
                nn.init.kaiming_normal_(module.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(module, nn.BatchNorm2d):
                nn.init.ones_(module.weight)
                nn.init.zeros_(module.bias)

    def forward(self, rgb: Tensor) -> Tensor:
        """Logits at 1/8 of ``rgb``'s size (``rgb`` a multiple of 64 keeps every stage whole)."""
        x = F.relu(self.layer1(self.conv1(rgb)))
        x = F.relu(self.layer2(x))                      # 1/8
        p = self.layer3_(x)
        d = self.layer3_d(x)
        x = F.relu(self.layer3(x))                      # 1/16
        p = self.pag3(p, self.compression3(x))
        d = d + _resize(self.diff3(x), d)
        x = F.relu(self.layer4(x))                      # 1/32
        p = self.layer4_(F.relu(p))
        d = self.layer4_d(F.relu(d))
        p = self.pag4(p, self.compression4(x))
        d = d + _resize(self.diff4(x), d)
        p = self.layer5_(F.relu(p))
        d = self.layer5_d(F.relu(d))
        i = _resize(self.spp(self.layer5(x)), p)        # 1/64 -> 1/8
        return self.final_layer(self.dfm(p, i, d))


def pidnet(*, variant: str = "s", num_classes: int = 19) -> PIDNet:
    """PIDNet-S, -M or -L (``variant``) as the release's inference model builds it."""
    m, n, planes, ppm_planes, head_planes = PIDNET_VARIANTS[variant]
    return PIDNet(m=m, n=n, num_classes=num_classes, planes=planes, ppm_planes=ppm_planes,
                  head_planes=head_planes)


def pidnet_s(*, num_classes: int) -> PIDNet:
    """PIDNet-S (Table II: 7,625,715 parameters with 19 classes)."""
    return pidnet(variant="s", num_classes=num_classes)
