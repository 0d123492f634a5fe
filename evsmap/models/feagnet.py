"""FEAGNet, the RGB-D segmentation network of "EVSMaP: An Efficient Volumetric-Semantic Mapping
Approach for Embedded Systems" (Section III-A, Fig. 2-5, Tables I-III).

Two symmetric FC-HarDNet-70 encoders (RGB and depth) of five stages - the init layer and four
HarDBlocks, as FASSD-Net keeps them - exchange information through a Cross-Modal Feature
Interaction Module (CFIM) after every stage. A Dilated Asymmetric Pooling Pyramid Fusion module
(DAPPF) aggregates context on the last encoder output, and a Lightweight Attention Decoder (LAD)
of three stages returns to 1/4 resolution; each stage runs three Lightweight Bottleneck Units at
its input resolution, upsamples x2, merges the encoder skip and applies height- and
width-direction attention to the merged map. A 1x1 convolution and bilinear upsampling restore
the input size. Training adds multi-scale supervision heads.

The blocks live in :mod:`evsmap.models.feagnet_blocks`; this module assembles them (the model)
and names the variants (small factories, timm's layout). Each block has the reading that fits
its own Table III row by default and the earlier readings as named options
(:data:`~evsmap.models.feagnet_blocks.CFIM_READINGS`, ``DAPPF_READINGS``,
``ATTENTION_READINGS``).
The paper leaves most module internals open; every choice made here, with the sentence it serves,
the lineage it follows and the arithmetic against Table III, is written down in
``docs/feagnet.md``."""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

from evsmap.models.feagnet_blocks import (
    ATTENTION_READINGS,
    CFIM_READINGS,
    DAPPF_READINGS,
    LADStage,
)
from evsmap.models.hardnet import HarDNetEncoder
from evsmap.models.layers import StridedLogits

# ---------------------------------------------------------------------------------------------
# model


class FEAGNet(StridedLogits, nn.Module):
    """FEAGNet: RGB-D (or RGB-only) semantic segmentation.

    In eval mode ``forward`` returns logits at the input resolution (at the output stride, 4
    for V2 and 8 for V1, while :attr:`~evsmap.models.layers.StridedLogits.upsample_logits` is
    off); in training mode with
    ``multiscale=True`` it returns ``(main, side, side)``: the main logits, then the side heads
    of the second and first decoder stages (1/8 and 1/16 of the input for V2, 1/16 and 1/32 for
    V1), for multi-scale supervision.

    Args:
        num_classes: number of output classes.
        use_depth: two encoders (RGB-D, V1/V2) or the RGB encoder only (S/L).
        init_strides: strides of the four init-layer convs; V2 uses FC-HarDNet's (2, 1, 2, 1),
            V1 strides the second conv too, (2, 2, 2, 1), so every later layer sees a quarter of
            the pixels.
        growth: HarDBlock growth rate per encoder stage.
        layers: HarDBlock layer count per encoder stage.
        transitions: encoder transition widths (stage output channels).
        decoder_channels: channels of the three LAD stages, deepest first.
        cfim: fuse the modalities with CFIM (``True``: the default reading, or a name of
            :data:`~evsmap.models.feagnet_blocks.CFIM_READINGS`; ``False``: element-wise
            addition, the baseline).
        cfim_reduction: ``v`` of the CFIM's fully connected layers (None: the reading's own
            default).
        dappf: apply DAPPF to the last encoder output (``True``: the default reading, or a
            name of :data:`~evsmap.models.feagnet_blocks.DAPPF_READINGS`).
        attention: HA and WA in every decoder stage (``True``: the default reading, or a name
            of :data:`~evsmap.models.feagnet_blocks.ATTENTION_READINGS`).
        multiscale: add the training-only 1x1 supervision heads on the first two decoder
            stages.
    """

    def __init__(
        self,
        *,
        num_classes: int = 40,
        use_depth: bool = True,
        init_strides: tuple[int, int, int, int] = (2, 1, 2, 1),
        growth: tuple[int, ...] = (10, 16, 18, 24),
        layers: tuple[int, ...] = (4, 4, 8, 8),
        transitions: tuple[int, ...] = (64, 96, 160, 224),
        decoder_channels: tuple[int, int, int] = (128, 116, 64),
        cfim: bool | str = True,
        cfim_reduction: int | None = None,
        dappf: bool | str = True,
        attention: bool | str = True,
        multiscale: bool = True,
    ) -> None:
        super().__init__()
        if num_classes < 1:
            raise ValueError(f"num_classes must be positive, got {num_classes}")
        cfim_name = _reading("cfim", cfim, CFIM_READINGS)
        dappf_name = _reading("dappf", dappf, DAPPF_READINGS)
        attention_name = _reading("attention", attention, ATTENTION_READINGS)
        self.readings = {"cfim": cfim_name, "dappf": dappf_name, "attention": attention_name}
        self.num_classes = num_classes
        self.use_depth = use_depth
        enc: dict[str, Any] = dict(stem_strides=init_strides, growth=growth, layers=layers,
                   transitions=transitions)
        self.rgb_encoder = HarDNetEncoder(in_channels=3, **enc)
        self.depth_encoder = HarDNetEncoder(in_channels=1, **enc) if use_depth else None
        stage_channels = [self.rgb_encoder.stem_channels, *transitions]
        if use_depth and cfim_name is not None:
            extra = {} if cfim_reduction is None else {"reduction": cfim_reduction}
            self.fusion: nn.ModuleList | None = nn.ModuleList(
                CFIM_READINGS[cfim_name](c, **extra) for c in stage_channels)
        else:
            self.fusion = None
        deepest = transitions[-1]
        self.context = (DAPPF_READINGS[dappf_name](deepest) if dappf_name is not None
                        else nn.Identity())
        skips = list(reversed(transitions[:-1]))[:3]
        if len(skips) != 3:
            raise ValueError("FEAGNet needs at least four encoder stages after the init layer")
        self.decoder = nn.ModuleList()
        ch = deepest
        for skip, out in zip(skips, decoder_channels, strict=True):
            self.decoder.append(LADStage(ch, skip, out, attention=attention_name))
            ch = out
        self.head = nn.Conv2d(ch, num_classes, 1)
        stage_inputs = [deepest, *decoder_channels[:2]]
        self.side_heads = (nn.ModuleList(nn.Conv2d(c, num_classes, 1) for c in stage_inputs[1:])
                           if multiscale else None)

    def _fuse(self, index: int, rgb: torch.Tensor, depth: torch.Tensor | None
              ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(RGB stream, depth stream) after stage ``index``'s fusion."""
        if depth is None:
            return rgb, None
        if self.fusion is None:
            return rgb + depth, depth
        return self.fusion[index](rgb, depth)

    def forward(self, rgb: torch.Tensor, depth: torch.Tensor | None = None
                ) -> torch.Tensor | tuple[torch.Tensor, ...]:
        if self.use_depth and depth is None:
            raise ValueError("this FEAGNet is RGB-D: forward(rgb, depth) needs the depth image")
        size = rgb.shape[-2:]
        r = self.rgb_encoder.run_stem(rgb)
        depth_encoder = self.depth_encoder  # None unless use_depth
        d = None
        if self.use_depth:
            assert depth_encoder is not None and depth is not None
            d = depth_encoder.run_stem(depth)
        r, d = self._fuse(0, r, d)
        features = []
        for i in range(len(self.rgb_encoder.blocks)):
            _, r = self.rgb_encoder.run_block(i, r)
            if d is not None:
                assert depth_encoder is not None
                _, d = depth_encoder.run_block(i, d)
            r, d = self._fuse(i + 1, r, d)
            features.append(r)
        x = self.context(features[-1])
        stage_outputs = []
        for stage, skip in zip(self.decoder, reversed(features[-4:-1]), strict=True):
            inner, x = stage(x, skip)
            stage_outputs.append(inner)
        main = self.final_resize(self.head(x), size)
        if self.training and self.side_heads is not None:
            sides = [head(out) for head, out in zip(self.side_heads, stage_outputs[1:],
                                                    strict=True)]
            return (main, *reversed(sides))
        return main


def _reading(module: str, choice: bool | str, readings: dict) -> str | None:
    """The reading name a switch selects: ``False`` none, ``True`` the default (first)."""
    if choice is False:
        return None
    if choice is True:
        return next(iter(readings))
    if choice not in readings:
        raise ValueError(f"{module}={choice!r}: unknown reading (known: true, false, "
                         f"{', '.join(readings)})")
    return str(choice)


# ---------------------------------------------------------------------------------------------
# variants

V2_INIT_STRIDES = (2, 1, 2, 1)
"""FC-HarDNet-70's init layer: the encoders start at 1/4 resolution."""
V1_INIT_STRIDES = (2, 2, 2, 1)
"""V1 strides the init layer's second conv too: the encoders start at 1/8 resolution."""

ABLATIONS: dict[str, dict[str, bool]] = {
    "basel": dict(cfim=False, dappf=False, attention=False, multiscale=False),
    "basel+cfim": dict(cfim=True, dappf=False, attention=False, multiscale=False),
    "basel+dappf": dict(cfim=False, dappf=True, attention=False, multiscale=False),
    "basel+cfim+dappf": dict(cfim=True, dappf=True, attention=False, multiscale=False),
    "basel+cfim+dappf+waha": dict(cfim=True, dappf=True, attention=True, multiscale=False),
    "full": dict(cfim=True, dappf=True, attention=True, multiscale=True),
}
"""The six rows of Table III (ablation on NYUv2, FEAGNet-V2), top to bottom."""


def feagnet_v1(*, num_classes: int = 40, **switches: Any) -> FEAGNet:
    """FEAGNet-V1: RGB-D, strided init layer (Table I: 4.5 M, 1.9 G at 480x640)."""
    return FEAGNet(num_classes=num_classes, init_strides=V1_INIT_STRIDES, **switches)


def feagnet_v2(*, num_classes: int = 40, **switches: Any) -> FEAGNet:
    """FEAGNet-V2: RGB-D, FC-HarDNet's init layer (Table I: 4.5 M, 7.8 G at 480x640)."""
    return FEAGNet(num_classes=num_classes, init_strides=V2_INIT_STRIDES, **switches)


def feagnet_s(*, num_classes: int = 19, **switches: Any) -> FEAGNet:
    """FEAGNet-S: RGB only, strided init layer (Table II: 2.8 M, Cityscapes)."""
    return FEAGNet(num_classes=num_classes, use_depth=False, init_strides=V1_INIT_STRIDES,
                   **switches)


def feagnet_l(*, num_classes: int = 19, **switches: Any) -> FEAGNet:
    """FEAGNet-L: RGB only, FC-HarDNet's init layer (Table II: 2.8 M, Cityscapes)."""
    return FEAGNet(num_classes=num_classes, use_depth=False, init_strides=V2_INIT_STRIDES,
                   **switches)
