"""ESANet-R34-NBt1D, the RGB-D segmentation baseline.

Paper: D. Seichter, M. Koehler, B. Lewandowski, T. Wengefeld and H.-M. Gross, "Efficient RGB-D
Semantic Scene Analysis for Indoor Environments", ICRA 2021 (arXiv:2011.06961).

Layout, written from the description in ``shared/reference/segmentation.md``:

* two ResNet-34-shaped encoders (RGB with 3 input channels, depth with 1) whose residual blocks
  are ERFNet's "non-bottleneck-1D" blocks;
* squeeze-and-excitation fusion (``SE(rgb) + SE(depth)``) after the stem and after each of the
  four stages; the fused map continues in the RGB encoder, the depth encoder keeps its own;
* a pyramid-pooling context module on the 1/32 map;
* three decoder modules (512, 256, 128 channels) fed with 1x1 skip projections of the fused
  encoder maps, then a 3x3 classifier and two learned x2 upsamplings back to the input size;
* three 1x1 side-output classifiers that only run in training mode (deep supervision).

``pretrained=False`` sizes (sum of ``numel`` over parameters): NYUv2 (40 classes) 46,955,840,
SUN RGB-D (37) 46,949,624, Cityscapes (19, ``appm-1-2-4-8``) 46,912,328.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from evsmap.errors import UnknownNameError

__all__ = [
    "AdaptivePyramidPooling",
    "DecoderModule",
    "ESANet",
    "LearnedUpsample2x",
    "NonBottleneck1D",
    "ResNet34NBt1DEncoder",
    "SEFusionAdd",
    "SqueezeExcite",
    "esanet_r34_nbt1d",
]

#: Blocks per stage of a ResNet-34.
STAGE_BLOCKS: tuple[int, int, int, int] = (3, 4, 6, 3)
#: Output channels of the stem and of the four encoder stages.
ENCODER_CHANNELS: tuple[int, int, int, int, int] = (64, 64, 128, 256, 512)
#: Channels of the three decoder modules, coarsest first.
DECODER_CHANNELS: tuple[int, int, int] = (512, 256, 128)
#: Non-bottleneck-1D blocks in each decoder module.
DECODER_BLOCKS = 3
#: Total stride of the encoder; inputs must be a multiple of it.
OUTPUT_STRIDE = 32

#: Context-module name -> (pyramid bins, whether windows are tied to the training size).
CONTEXT_MODULES: dict[str, tuple[tuple[int, ...], bool]] = {
    "ppm": ((1, 5), False),
    "ppm-1-2-4-8": ((1, 2, 4, 8), False),
    "appm": ((1, 5), True),
    "appm-1-2-4-8": ((1, 2, 4, 8), True),
}

#: Dataset -> (context module, training input size HxW, number of classes).
DATASET_CONFIGS: dict[str, tuple[str, tuple[int, int], int]] = {
    "nyuv2": ("ppm", (480, 640), 40),
    "sunrgbd": ("ppm", (480, 640), 37),
    "cityscapes": ("appm-1-2-4-8", (512, 1024), 19),
}


def _conv_bn_relu(in_channels: int, out_channels: int, kernel_size: int) -> nn.Sequential:
    """Bias-free ``kernel_size`` conv ('same' padding), BatchNorm, ReLU."""
    return nn.Sequential(
        nn.Conv2d(in_channels, out_channels, kernel_size, padding=kernel_size // 2, bias=False),
        nn.BatchNorm2d(out_channels),
        nn.ReLU(inplace=True),
    )


# --------------------------------------------------------------------------------------------
# blocks
# --------------------------------------------------------------------------------------------


class NonBottleneck1D(nn.Module):
    """ERFNet's factorised residual block: (3x1, ReLU, 1x3, BN, ReLU) twice, add, ReLU.

    The four convolutions carry biases and both BatchNorms use ``eps=1e-3``. A stride is split
    over the first 3x1 (rows) and 1x3 (columns) pair; the shortcut then becomes a strided 1x1
    conv + BN, as it also does when the channel count changes.

    Args:
        in_channels: Channels of the input.
        out_channels: Channels of the output.
        stride: 1, or 2 to halve the resolution.
    """

    def __init__(self, in_channels: int, out_channels: int, *, stride: int = 1) -> None:
        super().__init__()
        self.conv_v1 = nn.Conv2d(
            in_channels, out_channels, (3, 1), stride=(stride, 1), padding=(1, 0)
        )
        self.conv_h1 = nn.Conv2d(
            out_channels, out_channels, (1, 3), stride=(1, stride), padding=(0, 1)
        )
        self.bn1 = nn.BatchNorm2d(out_channels, eps=1e-3)
        self.conv_v2 = nn.Conv2d(out_channels, out_channels, (3, 1), padding=(1, 0))
        self.conv_h2 = nn.Conv2d(out_channels, out_channels, (1, 3), padding=(0, 1))
        self.bn2 = nn.BatchNorm2d(out_channels, eps=1e-3)
        self.shortcut: nn.Module
        if stride != 1 or in_channels != out_channels:
            self.shortcut = nn.Sequential(
                nn.Conv2d(in_channels, out_channels, 1, stride=stride, bias=False),
                nn.BatchNorm2d(out_channels),
            )
        else:
            self.shortcut = nn.Identity()

    def forward(self, x: Tensor) -> Tensor:
        y = F.relu(self.conv_v1(x))
        y = F.relu(self.bn1(self.conv_h1(y)))
        y = F.relu(self.conv_v2(y))
        y = self.bn2(self.conv_h2(y))
        return F.relu(y + self.shortcut(x))


class ResNet34NBt1DEncoder(nn.Module):
    """ResNet-34 layout (stages of 3, 4, 6, 3 blocks) built from :class:`NonBottleneck1D`.

    The stem (7x7/2 conv, BN, ReLU) and the stages are exposed separately because ESANet fuses
    the two modalities between them; the 3x3/2 max-pool after the stem is applied by the caller,
    after fusion.

    Args:
        in_channels: 3 for RGB, 1 for depth.
    """

    def __init__(self, *, in_channels: int) -> None:
        super().__init__()
        stem_channels = ENCODER_CHANNELS[0]
        self.stem = nn.Sequential(
            nn.Conv2d(in_channels, stem_channels, 7, stride=2, padding=3, bias=False),
            nn.BatchNorm2d(stem_channels),
            nn.ReLU(inplace=True),
        )
        stages = []
        channels = stem_channels
        for index, (blocks, width) in enumerate(
            zip(STAGE_BLOCKS, ENCODER_CHANNELS[1:], strict=True)
        ):
            stride = 1 if index == 0 else 2
            layers = [NonBottleneck1D(channels, width, stride=stride)]
            layers += [NonBottleneck1D(width, width) for _ in range(blocks - 1)]
            stages.append(nn.Sequential(*layers))
            channels = width
        self.stages = nn.ModuleList(stages)

    def forward(self, x: Tensor) -> list[Tensor]:
        """Unfused use: the outputs of the four stages (1/4, 1/8, 1/16, 1/32)."""
        x = F.max_pool2d(self.stem(x), kernel_size=3, stride=2, padding=1)
        outputs = []
        for stage in self.stages:
            x = stage(x)
            outputs.append(x)
        return outputs


class SqueezeExcite(nn.Module):
    """Channel attention: global average pool, 1x1 conv C -> C/r, ReLU, 1x1 conv, sigmoid, scale.

    Args:
        channels: Channels C of the input.
        reduction: Squeeze ratio r.
    """

    def __init__(self, channels: int, *, reduction: int = 16) -> None:
        super().__init__()
        self.squeeze = nn.Conv2d(channels, channels // reduction, 1)
        self.excite = nn.Conv2d(channels // reduction, channels, 1)

    def forward(self, x: Tensor) -> Tensor:
        weights = F.adaptive_avg_pool2d(x, 1)
        weights = torch.sigmoid(self.excite(F.relu(self.squeeze(weights))))
        return x * weights


class SEFusionAdd(nn.Module):
    """ESANet's "SE-add" fusion: each modality reweighted by its own SE block, then summed.

    Args:
        channels: Channels of both inputs.
    """

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.se_rgb = SqueezeExcite(channels)
        self.se_depth = SqueezeExcite(channels)

    def forward(self, rgb: Tensor, depth: Tensor) -> Tensor:
        return self.se_rgb(rgb) + self.se_depth(depth)


class AdaptivePyramidPooling(nn.Module):
    """Pyramid-pooling context module ("ppm" / "appm" in the ESANet code).

    Every bin average-pools the input to a ``bin x bin`` grid, projects it with a 1x1
    conv-BN-ReLU to ``in_channels // len(bins)`` channels and upsamples it back (nearest). The
    input and all branches are concatenated and fused by a 1x1 conv-BN-ReLU.

    With ``train_size`` set (the "appm" variants) the pooling windows are tied to the training
    resolution: at a feature map ``k`` times the training one (``k`` rounded half up, per axis)
    the grid is ``k * bin`` cells, so each cell keeps the window it had in training. At the
    training size it is plain adaptive pooling. Without ``train_size`` ("ppm") the grid is
    always ``bin x bin``.

    Args:
        in_channels: Channels of the input (the 1/32 encoder map).
        out_channels: Channels of the output.
        bins: Grid sizes of the pyramid levels.
        train_size: Feature-map size (H, W) at the training resolution, or None.
    """

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        *,
        bins: tuple[int, ...],
        train_size: tuple[int, int] | None = None,
    ) -> None:
        super().__init__()
        self.bins = tuple(bins)
        self.train_size = train_size
        branch_channels = in_channels // len(self.bins)
        self.branches = nn.ModuleList(
            _conv_bn_relu(in_channels, branch_channels, 1) for _ in self.bins
        )
        self.fuse = _conv_bn_relu(in_channels + branch_channels * len(self.bins), out_channels, 1)

    def pool_grids(self, size: tuple[int, ...]) -> list[tuple[int, int]]:
        """Pooling grid (rows, columns) of each bin for a feature map of ``size`` (H, W)."""
        if self.train_size is None:
            return [(b, b) for b in self.bins]
        # a whole multiple of the training map, rounded half up as in the reference code, and
        # never below one cell per bin (the reference code would fail there)
        mult_h = max(1, int(int(size[0]) / self.train_size[0] + 0.5))
        mult_w = max(1, int(int(size[1]) / self.train_size[1] + 0.5))
        return [(b * mult_h, b * mult_w) for b in self.bins]

    def forward(self, x: Tensor) -> Tensor:
        size = x.shape[-2:]
        pyramid = [x]
        for grid, branch in zip(self.pool_grids(size), self.branches, strict=True):
            pooled = branch(F.adaptive_avg_pool2d(x, grid))
            pyramid.append(F.interpolate(pooled, size=size, mode="nearest"))
        return self.fuse(torch.cat(pyramid, dim=1))


class LearnedUpsample2x(nn.Module):
    """ESANet's "learned-3x3-zeropad" upsampling: nearest x2, then a depthwise 3x3 conv.

    The conv (zero padding, with bias) starts as the bilinear kernel
    ``[1, 2, 1; 2, 4, 2; 1, 2, 1] / 16`` with bias 0 and is trained with the rest.

    Args:
        channels: Channels of input and output.
    """

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.conv = nn.Conv2d(channels, channels, 3, padding=1, groups=channels)
        taps = torch.tensor([1.0, 2.0, 1.0])
        kernel = torch.outer(taps, taps) / 16.0
        with torch.no_grad():
            self.conv.weight.copy_(kernel.expand_as(self.conv.weight))
            assert self.conv.bias is not None  # Conv2d's default bias=True
            self.conv.bias.zero_()

    def forward(self, x: Tensor) -> Tensor:
        return self.conv(F.interpolate(x, scale_factor=2.0, mode="nearest"))


class DecoderModule(nn.Module):
    """3x3 conv-BN-ReLU, non-bottleneck-1D blocks, learned x2 upsampling, then + skip.

    Args:
        in_channels: Channels of the incoming decoder (or context) map.
        out_channels: Channels of this module.
        num_blocks: Number of :class:`NonBottleneck1D` blocks.
        side_classes: Classes of the 1x1 side-output classifier (deep supervision), or None for
            no side output.
    """

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        *,
        num_blocks: int = DECODER_BLOCKS,
        side_classes: int | None = None,
    ) -> None:
        super().__init__()
        self.conv = _conv_bn_relu(in_channels, out_channels, 3)
        self.blocks = nn.Sequential(
            *(NonBottleneck1D(out_channels, out_channels) for _ in range(num_blocks))
        )
        self.upsample = LearnedUpsample2x(out_channels)
        self.side_output = (
            nn.Conv2d(out_channels, side_classes, 1) if side_classes is not None else None
        )

    def forward(self, x: Tensor, skip: Tensor) -> tuple[Tensor, Tensor | None]:
        x = self.blocks(self.conv(x))
        side = self.side_output(x) if self.training and self.side_output is not None else None
        return self.upsample(x) + skip, side


# --------------------------------------------------------------------------------------------
# model
# --------------------------------------------------------------------------------------------


def _check_inputs(rgb: Tensor, depth: Tensor) -> None:
    if rgb.dim() != 4 or depth.dim() != 4 or rgb.shape[1] != 3 or depth.shape[1] != 1:
        raise ValueError(
            f"expected rgb (B, 3, H, W) and depth (B, 1, H, W), got {tuple(rgb.shape)} and "
            f"{tuple(depth.shape)}"
        )
    height, width = rgb.shape[-2:]
    if height % OUTPUT_STRIDE or width % OUTPUT_STRIDE:
        raise ValueError(
            f"ESANet needs an input size divisible by {OUTPUT_STRIDE}, got {height}x{width}"
        )
    if depth.shape[-2:] != rgb.shape[-2:] or depth.shape[0] != rgb.shape[0]:
        raise ValueError(f"rgb {tuple(rgb.shape)} and depth {tuple(depth.shape)} do not match")


class ESANet(nn.Module):
    """ESANet-R34-NBt1D: RGB-D semantic segmentation with two fused ResNet-34 encoders.

    Inputs must have a height and width divisible by 32. In eval mode the output is the logits
    ``(B, num_classes, H, W)``. In training mode with side outputs the result is the tuple
    ``(logits, side_8, side_16, side_32)``: the decoder modules' deep-supervision logits at 1/8,
    1/16 and 1/32 of the input size (taken before each module's upsampling, finest first, as in
    the reference code). Without side outputs training mode also returns only the logits.

    Args:
        num_classes: Number of output classes.
        context: Context module: "ppm" (bins 1 and 5, NYUv2 / SUN RGB-D), "appm-1-2-4-8" (bins 1,
            2, 4, 8 with windows tied to ``input_size``, Cityscapes), or "ppm-1-2-4-8" / "appm".
        input_size: Training input size (H, W); only the "appm" variants use it.
        side_outputs: Build the three 1x1 side-output classifiers used for deep supervision.
    """

    def __init__(
        self,
        *,
        num_classes: int = 40,
        context: str = "ppm",
        input_size: tuple[int, int] = (480, 640),
        side_outputs: bool = True,
    ) -> None:
        super().__init__()
        if context not in CONTEXT_MODULES:
            raise UnknownNameError(
                f"unknown ESANet context module {context!r}; "
                f"expected one of {sorted(CONTEXT_MODULES)}"
            )
        if num_classes < 1:
            raise ValueError(f"num_classes must be positive, got {num_classes}")
        self.num_classes = num_classes
        self.context_name = context
        self.input_size = (int(input_size[0]), int(input_size[1]))

        self.encoder_rgb = ResNet34NBt1DEncoder(in_channels=3)
        self.encoder_depth = ResNet34NBt1DEncoder(in_channels=1)
        self.fusions = nn.ModuleList(SEFusionAdd(c) for c in ENCODER_CHANNELS)

        # 1x1 projections of the fused 1/4, 1/8 and 1/16 maps to the decoder widths
        skip_in = ENCODER_CHANNELS[1:4]
        skip_out = DECODER_CHANNELS[::-1]
        self.skips = nn.ModuleList(
            _conv_bn_relu(c_in, c_out, 1) for c_in, c_out in zip(skip_in, skip_out, strict=True)
        )

        bins, tied = CONTEXT_MODULES[context]
        train_size = (
            (self.input_size[0] // OUTPUT_STRIDE, self.input_size[1] // OUTPUT_STRIDE)
            if tied
            else None
        )
        self.context = AdaptivePyramidPooling(
            ENCODER_CHANNELS[-1], DECODER_CHANNELS[0], bins=bins, train_size=train_size
        )

        side_classes = num_classes if side_outputs else None
        decoder_in = (DECODER_CHANNELS[0], *DECODER_CHANNELS[:-1])
        self.decoder = nn.ModuleList(
            DecoderModule(c_in, c_out, side_classes=side_classes)
            for c_in, c_out in zip(decoder_in, DECODER_CHANNELS, strict=True)
        )
        self.classifier = nn.Conv2d(DECODER_CHANNELS[-1], num_classes, 3, padding=1)
        self.upsample = nn.Sequential(
            LearnedUpsample2x(num_classes), LearnedUpsample2x(num_classes)
        )
        self._init_weights()

    def _init_weights(self) -> None:
        """He (fan-out) init for the convs, except classifiers, SE excitations and upsamplers."""
        keep: set[nn.Module] = {self.classifier}
        for module in self.modules():
            if isinstance(module, DecoderModule) and module.side_output is not None:
                keep.add(module.side_output)
            elif isinstance(module, SqueezeExcite):
                keep.add(module.excite)
            elif isinstance(module, LearnedUpsample2x):
                keep.add(module.conv)
        for module in self.modules():
            if isinstance(module, nn.Conv2d) and module not in keep:
                nn.init.kaiming_normal_(module.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(module, nn.BatchNorm2d):
                nn.init.ones_(module.weight)
                nn.init.zeros_(module.bias)

    def forward(self, rgb: Tensor, depth: Tensor) -> Tensor | tuple[Tensor, ...]:
        if not torch.jit.is_tracing():  # the checks would only litter a trace with constants
            _check_inputs(rgb, depth)

        enc_rgb, enc_depth = self.encoder_rgb, self.encoder_depth
        r = enc_rgb.stem(rgb)
        d = enc_depth.stem(depth)
        r = F.max_pool2d(self.fusions[0](r, d), kernel_size=3, stride=2, padding=1)
        d = F.max_pool2d(d, kernel_size=3, stride=2, padding=1)

        fused = []
        for stage_rgb, stage_depth, fusion in zip(
            enc_rgb.stages, enc_depth.stages, self.fusions[1:], strict=True
        ):
            d = stage_depth(d)
            r = fusion(stage_rgb(r), d)
            fused.append(r)
        # fused: 1/4 (64), 1/8 (128), 1/16 (256), 1/32 (512)

        skips = [proj(f) for proj, f in zip(self.skips, fused[:3], strict=True)][::-1]
        x = self.context(fused[3])
        sides = []
        for module, skip in zip(self.decoder, skips, strict=True):
            x, side = module(x, skip)
            sides.append(side)

        logits = self.upsample(self.classifier(x))
        if self.training and sides[0] is not None:
            return (logits, *sides[::-1])
        return logits


# --------------------------------------------------------------------------------------------
# factories
# --------------------------------------------------------------------------------------------


def esanet_r34_nbt1d(*, num_classes: int | None = None, dataset: str = "nyuv2") -> ESANet:
    """ESANet-R34-NBt1D configured as in the paper for one dataset.

    Args:
        num_classes: Output classes; None takes the dataset's usual count (NYUv2 40, SUN RGB-D
            37, Cityscapes 19).
        dataset: "nyuv2" or "sunrgbd" (context "ppm", trained at 480x640) or "cityscapes"
            (context "appm-1-2-4-8", trained at 512x1024, i.e. 1024x512 in WxH).

    Raises:
        UnknownNameError: ``dataset`` is not one of the names above.
    """
    key = dataset.lower()
    if key not in DATASET_CONFIGS:
        raise UnknownNameError(
            f"unknown ESANet dataset {dataset!r}; expected one of {sorted(DATASET_CONFIGS)}"
        )
    context, input_size, default_classes = DATASET_CONFIGS[key]
    return ESANet(
        num_classes=default_classes if num_classes is None else num_classes,
        context=context,
        input_size=input_size,
    )
