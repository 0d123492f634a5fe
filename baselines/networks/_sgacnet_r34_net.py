"""SGACNet-R34 (Zhang et al. 2023), the network: blocks, model and builder.

Written from the official code (github.com/CyunXiong/SGACNet, ``src/models/model.py``,
``resnet.py``, ``rgb_depth_fusion.py``, ``model_utils.py``, ``context_modules.py``; the commit is
in ``docs/baselines/sgacnet-r34.md``) with the ResNet-34 encoder branch that the release
comments out restored. SGACNet is ESANet with three changes, so ESANet's blocks are reused
from :mod:`baselines.esanet` where SGACNet reuses them:

* the two encoders are ESANet's ResNet-34 with non-bottleneck-1D blocks
  (:class:`~baselines.esanet.ResNet34NBt1DEncoder`, RGB with 3 input channels, depth with 1);
* each of the five fusions reweights RGB by squeeze-and-excitation
  (:class:`~baselines.esanet.SqueezeExcite`) and depth by a spatial pyramid attention
  (:class:`SpatialPyramidAttention`, the code's "SPA-147"), then adds them;
* the context module is ESANet's adaptive pyramid pooling with bilinear upsampling (the
  official configurations use ``--upsampling bilinear``, which the context module follows);
* the decoder modules (512, 256, 128 channels) use three :class:`BRUBlock` each instead of
  non-bottleneck-1D blocks and upsample bilinearly; the classifier's output is upsampled x4
  bilinearly in two x2 steps.

The 1x1 side-output classifiers of the decoder modules run only in training mode (deep
supervision); they are part of the official parameter count.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from baselines.esanet import (
    AdaptivePyramidPooling,
    ResNet34NBt1DEncoder,
    SqueezeExcite,
)
from evsmap.errors import UnknownNameError

__all__ = [
    "BRUBlock",
    "BilinearPyramidPooling",
    "EfficientChannelAttention",
    "SGACFusion",
    "SGACNet",
    "SpatialPyramidAttention",
    "adaptive_avg_pool",
    "sgacnet_r34",
]

#: Output channels of the encoder stem and of its four stages (ResNet-34).
ENCODER_CHANNELS: tuple[int, int, int, int, int] = (64, 64, 128, 256, 512)
#: Channels of the three decoder modules, coarsest first ("--decoder_channels_mode decreasing").
DECODER_CHANNELS: tuple[int, int, int] = (512, 256, 128)
#: BRU blocks per decoder module ("--nr_decoder_blocks 3").
DECODER_BLOCKS = 3
#: Total stride of the encoder; inputs must be a multiple of it.
OUTPUT_STRIDE = 32

#: Dataset -> (context pyramid bins, training input size HxW); from the official training
#: scripts: NYUv2 / SUN RGB-D "--context_module appm" at 480x640, Cityscapes
#: "--context_module appm-1-2-4-8" at 512x1024.
DATASET_CONFIGS: dict[str, tuple[tuple[int, ...], tuple[int, int]]] = {
    "nyuv2": ((1, 5), (480, 640)),
    "sunrgbd": ((1, 5), (480, 640)),
    "cityscapes": ((1, 2, 4, 8), (512, 1024)),
}


def _pool_matrix(length: int, cells: int, like: Tensor) -> Tensor:
    """``(cells, length)`` matrix whose row ``i`` averages adaptive-pooling window ``i`` (built
    in Python, so an export holds it as one constant)."""
    rows = []
    for i in range(cells):
        start = (i * length) // cells
        end = -((-(i + 1) * length) // cells)  # ceil
        rows.append([1.0 / (end - start) if start <= j < end else 0.0 for j in range(length)])
    return torch.tensor(rows, dtype=like.dtype, device=like.device)


def adaptive_avg_pool(x: Tensor, size: tuple[int, int]) -> Tensor:
    """``F.adaptive_avg_pool2d(x, size)``; while exporting to ONNX, where the exporter rejects
    output sizes that do not divide the input, the same windows as two matrix products."""
    height, width = int(x.shape[-2]), int(x.shape[-1])
    rows, cols = int(size[0]), int(size[1])
    if not torch.onnx.is_in_onnx_export() or (height % rows == 0 and width % cols == 0):
        return F.adaptive_avg_pool2d(x, (rows, cols))
    pool_h = _pool_matrix(height, rows, x)
    pool_w = _pool_matrix(width, cols, x)
    return torch.matmul(torch.matmul(pool_h, x), pool_w.t())


def _size(x: Tensor) -> tuple[int, int]:
    """``(H, W)`` of ``x`` as Python ints, so that a trace holds them as constants (the ONNX
    exporter needs static sizes to export the adaptive pooling that follows)."""
    return int(x.shape[-2]), int(x.shape[-1])


def _upsample2x(x: Tensor) -> Tensor:
    """Bilinear x2 (``align_corners=False``), the official ``Upsample(mode='bilinear')``."""
    height, width = _size(x)
    size = (height * 2, width * 2)
    return F.interpolate(x, size=size, mode="bilinear", align_corners=False)


def _conv_bn_relu(in_channels: int, out_channels: int, kernel_size: int) -> nn.Sequential:
    """Bias-free conv ('same' padding), BatchNorm, ReLU (the official ``ConvBNAct``)."""
    return nn.Sequential(
        nn.Conv2d(in_channels, out_channels, kernel_size, padding=kernel_size // 2, bias=False),
        nn.BatchNorm2d(out_channels),
        nn.ReLU(inplace=True),
    )


# --------------------------------------------------------------------------------------------
# fusion
# --------------------------------------------------------------------------------------------


class SpatialPyramidAttention(nn.Module):
    """Spatial pyramid attention "SPA-147" (the depth branch of SGACNet's fusion).

    The input is average-pooled to 1x1, 4x4 and 7x7; the two coarse levels are upsampled to 7x7
    (nearest) and the three are summed with learned weights (one per level, initialised to 1).
    A bottleneck (1x1 conv C -> C/r, BN, ReLU, 1x1 conv C/r -> C, both without bias, sigmoid)
    turns the 7x7 map into attention weights, which are upsampled to the input size (nearest)
    and multiply the input.

    Args:
        channels: Channels C of the input.
        reduction: Bottleneck ratio r.
    """

    GRID = 7
    LEVELS = (7, 4, 1)

    def __init__(self, channels: int, *, reduction: int = 16) -> None:
        super().__init__()
        self.level_weights = nn.Parameter(torch.ones(len(self.LEVELS)))
        hidden = channels // reduction
        self.transform = nn.Sequential(
            nn.Conv2d(channels, hidden, 1, bias=False),
            nn.BatchNorm2d(hidden),
            nn.ReLU(inplace=True),
            nn.Conv2d(hidden, channels, 1, bias=False),
            nn.Sigmoid(),
        )

    def forward(self, x: Tensor) -> Tensor:
        grid = (self.GRID, self.GRID)
        mixed = None
        for index, level in enumerate(self.LEVELS):
            pooled = adaptive_avg_pool(x, (level, level))
            if level != self.GRID:
                pooled = F.interpolate(pooled, size=grid, mode="nearest")
            term = pooled * self.level_weights[index]
            mixed = term if mixed is None else mixed + term
        weights = self.transform(mixed)
        return x * F.interpolate(weights, size=_size(x), mode="nearest")


class SGACFusion(nn.Module):
    """SGACNet's fusion: ``SE(rgb) + SPA(depth)``.

    Args:
        channels: Channels of both inputs.
    """

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.se_rgb = SqueezeExcite(channels)
        self.spa_depth = SpatialPyramidAttention(channels)

    def forward(self, rgb: Tensor, depth: Tensor) -> Tensor:
        return self.se_rgb(rgb) + self.spa_depth(depth)


# --------------------------------------------------------------------------------------------
# context and decoder
# --------------------------------------------------------------------------------------------


class BilinearPyramidPooling(AdaptivePyramidPooling):
    """ESANet's (adaptive) pyramid pooling, its branches upsampled bilinearly
    (``align_corners=False``) as SGACNet's configurations ask; the parameters and the pooling
    grids are ESANet's (:class:`~baselines.esanet.AdaptivePyramidPooling`)."""

    def forward(self, x: Tensor) -> Tensor:
        size = _size(x)
        pyramid = [x]
        for grid, branch in zip(self.pool_grids(size), self.branches, strict=True):
            pooled = branch(adaptive_avg_pool(x, grid))
            pyramid.append(F.interpolate(pooled, size=size, mode="bilinear",
                                         align_corners=False))
        return self.fuse(torch.cat(pyramid, dim=1))


class _BNPReLU(nn.Sequential):
    """BatchNorm (eps 1e-3) and a per-channel PReLU."""

    def __init__(self, channels: int) -> None:
        super().__init__(nn.BatchNorm2d(channels, eps=1e-3), nn.PReLU(channels))


def _depthwise(channels: int, kernel: tuple[int, int]) -> nn.Sequential:
    """Bias-free depthwise conv with 'same' padding, then BN + PReLU."""
    padding = (kernel[0] // 2, kernel[1] // 2)
    return nn.Sequential(
        nn.Conv2d(channels, channels, kernel, padding=padding, groups=channels, bias=False),
        _BNPReLU(channels),
    )


class EfficientChannelAttention(nn.Module):
    """ECA: global average pool, a 1D conv (no bias) across channels, sigmoid, scale.

    Args:
        kernel_size: Width of the 1D conv (SGACNet's BRU block uses 9).
    """

    def __init__(self, *, kernel_size: int = 9) -> None:
        super().__init__()
        self.conv = nn.Conv1d(1, 1, kernel_size, padding=kernel_size // 2, bias=False)

    def forward(self, x: Tensor) -> Tensor:
        weights = F.adaptive_avg_pool2d(x, 1).flatten(2).transpose(1, 2)  # (B, 1, C)
        weights = torch.sigmoid(self.conv(weights)).transpose(1, 2).unsqueeze(-1)
        return x * weights


class BRUBlock(nn.Module):
    """SGACNet's decoder block ("BRU"): a two-branch factorised depthwise residual unit.

    BN-PReLU, 1x1 conv C -> C/2 (BN-PReLU); two branches of depthwise 3x1, 1x3 (each BN-PReLU),
    ECA, depthwise 1x3, 3x1 (in the official code the second branch is the "dilated" one, with
    dilation 1); their sum, BN-PReLU, 1x1 conv C/2 -> C (no BN), plus the input, then a channel
    shuffle with C/2 groups.

    Args:
        channels: Channels C of input and output (even).
    """

    def __init__(self, channels: int) -> None:
        super().__init__()
        half = channels // 2
        self.pre = _BNPReLU(channels)
        self.reduce = nn.Sequential(nn.Conv2d(channels, half, 1, bias=False), _BNPReLU(half))
        self.branches = nn.ModuleList(
            nn.Sequential(
                _depthwise(half, (3, 1)),
                _depthwise(half, (1, 3)),
                EfficientChannelAttention(),
                _depthwise(half, (1, 3)),
                _depthwise(half, (3, 1)),
            )
            for _ in range(2)
        )
        self.post = _BNPReLU(half)
        self.expand = nn.Conv2d(half, channels, 1, bias=False)
        self.shuffle_groups = half

    def forward(self, x: Tensor) -> Tensor:
        y = self.reduce(self.pre(x))
        y = self.branches[0](y) + self.branches[1](y)
        y = self.expand(self.post(y)) + x
        batch, channels, height, width = y.shape
        groups = self.shuffle_groups
        y = y.reshape(batch, groups, channels // groups, height, width).transpose(1, 2)
        return y.reshape(batch, channels, height, width)


class SGACDecoderModule(nn.Module):
    """3x3 conv-BN-ReLU, BRU blocks, bilinear x2 upsampling, then + skip.

    Args:
        in_channels: Channels of the incoming decoder (or context) map.
        out_channels: Channels of this module.
        num_classes: Classes of the 1x1 side-output classifier (training mode only).
        num_blocks: Number of :class:`BRUBlock`.
    """

    def __init__(self, in_channels: int, out_channels: int, *, num_classes: int,
                 num_blocks: int = DECODER_BLOCKS) -> None:
        super().__init__()
        self.conv = _conv_bn_relu(in_channels, out_channels, 3)
        self.blocks = nn.Sequential(*(BRUBlock(out_channels) for _ in range(num_blocks)))
        self.side_output = nn.Conv2d(out_channels, num_classes, 1)

    def forward(self, x: Tensor, skip: Tensor) -> tuple[Tensor, Tensor | None]:
        x = self.blocks(self.conv(x))
        side = self.side_output(x) if self.training else None
        return _upsample2x(x) + skip, side


# --------------------------------------------------------------------------------------------
# model
# --------------------------------------------------------------------------------------------


class SGACNet(nn.Module):
    """SGACNet with two ResNet-34-NBt1D encoders (the paper's R34 configuration).

    Inputs: RGB ``(B, 3, H, W)`` and depth ``(B, 1, H, W)`` with H and W divisible by 32. In
    eval mode the output is the logits ``(B, num_classes, H, W)``; in training mode the tuple
    ``(logits, side_8, side_16, side_32)`` (the decoder modules' side outputs at 1/8, 1/16 and
    1/32 of the input, as the official code returns them).

    Args:
        num_classes: Number of output classes.
        bins: Pyramid bins of the context module: (1, 5) for NYUv2 / SUN RGB-D, (1, 2, 4, 8) for
            Cityscapes.
        input_size: Training input size (H, W); the context module's pooling windows are tied
            to it (the "appm" of the official code).
    """

    def __init__(self, *, num_classes: int = 40, bins: tuple[int, ...] = (1, 5),
                 input_size: tuple[int, int] = (480, 640)) -> None:
        super().__init__()
        if num_classes < 1:
            raise ValueError(f"num_classes must be positive, got {num_classes}")
        self.num_classes = num_classes
        self.input_size = (int(input_size[0]), int(input_size[1]))
        self.encoder_rgb = ResNet34NBt1DEncoder(in_channels=3)
        self.encoder_depth = ResNet34NBt1DEncoder(in_channels=1)
        self.fusions = nn.ModuleList(SGACFusion(c) for c in ENCODER_CHANNELS)
        skip_out = DECODER_CHANNELS[::-1]
        self.skips = nn.ModuleList(
            _conv_bn_relu(c_in, c_out, 1)
            for c_in, c_out in zip(ENCODER_CHANNELS[1:4], skip_out, strict=True))
        train_size = (self.input_size[0] // OUTPUT_STRIDE, self.input_size[1] // OUTPUT_STRIDE)
        self.context = BilinearPyramidPooling(ENCODER_CHANNELS[-1], DECODER_CHANNELS[0],
                                              bins=tuple(bins), train_size=train_size)
        decoder_in = (DECODER_CHANNELS[0], *DECODER_CHANNELS[:-1])
        self.decoder = nn.ModuleList(
            SGACDecoderModule(c_in, c_out, num_classes=num_classes)
            for c_in, c_out in zip(decoder_in, DECODER_CHANNELS, strict=True))
        self.classifier = nn.Conv2d(DECODER_CHANNELS[-1], num_classes, 3, padding=1)

    def forward(self, rgb: Tensor, depth: Tensor) -> Tensor | tuple[Tensor, ...]:
        if not torch.jit.is_tracing():
            _check_inputs(rgb, depth)
        enc_rgb, enc_depth = self.encoder_rgb, self.encoder_depth
        d = enc_depth.stem(depth)
        r = self.fusions[0](enc_rgb.stem(rgb), d)
        r = F.max_pool2d(r, kernel_size=3, stride=2, padding=1)
        d = F.max_pool2d(d, kernel_size=3, stride=2, padding=1)
        fused = []
        for stage_rgb, stage_depth, fusion in zip(enc_rgb.stages, enc_depth.stages,
                                                  self.fusions[1:], strict=True):
            d = stage_depth(d)
            r = fusion(stage_rgb(r), d)
            fused.append(r)
        skips = [proj(f) for proj, f in zip(self.skips, fused[:3], strict=True)][::-1]
        x = self.context(fused[3])
        sides = []
        for module, skip in zip(self.decoder, skips, strict=True):
            x, side = module(x, skip)
            sides.append(side)
        logits = _upsample2x(_upsample2x(self.classifier(x)))
        if self.training:
            return (logits, *sides[::-1])
        return logits


def _check_inputs(rgb: Tensor, depth: Tensor) -> None:
    if rgb.dim() != 4 or depth.dim() != 4 or rgb.shape[1] != 3 or depth.shape[1] != 1:
        raise ValueError(f"expected rgb (B, 3, H, W) and depth (B, 1, H, W), got "
                         f"{tuple(rgb.shape)} and {tuple(depth.shape)}")
    if rgb.shape[0] != depth.shape[0] or rgb.shape[-2:] != depth.shape[-2:]:
        raise ValueError(f"rgb {tuple(rgb.shape)} and depth {tuple(depth.shape)} do not match")
    height, width = rgb.shape[-2:]
    if height % OUTPUT_STRIDE or width % OUTPUT_STRIDE:
        raise ValueError(f"SGACNet needs an input size divisible by {OUTPUT_STRIDE}, got "
                         f"{height}x{width}")


def sgacnet_r34(*, num_classes: int, dataset: str = "nyuv2") -> SGACNet:
    """SGACNet-R34 configured as the official training script of ``dataset`` does.

    Args:
        num_classes: Output classes (NYUv2 40, SUN RGB-D 37, Cityscapes 19).
        dataset: "nyuv2", "sunrgbd" (context bins 1, 5 tied to 480x640) or "cityscapes"
            (bins 1, 2, 4, 8 tied to 512x1024).

    Raises:
        UnknownNameError: ``dataset`` is not one of those.
    """
    key = str(dataset).lower()
    if key not in DATASET_CONFIGS:
        raise UnknownNameError(f"unknown SGACNet dataset {dataset!r}; expected one of "
                               f"{sorted(DATASET_CONFIGS)}")
    bins, input_size = DATASET_CONFIGS[key]
    return SGACNet(num_classes=num_classes, bins=bins, input_size=input_size)
