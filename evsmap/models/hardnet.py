"""Harmonic dense blocks (HarDBlock) from "HarDNet: A Low Memory Traffic Network" (Chao et al.,
ICCV 2019), the feature extractor of FC-HarDNet-70 and of FEAGNet's two encoders.

Layer ``k`` (1-based; layer 0 is the block input) reads the layers ``k - 2**i`` for every ``i``
with ``2**i`` dividing ``k``. Its width is ``growth * multiplier**(links - 1)`` rounded to an even
number. The block returns the concatenation of the odd-numbered layers and the last layer.
"""

from __future__ import annotations

import torch
from torch import nn

from evsmap.models.layers import ConvBNReLU


def hard_links(layer: int) -> list[int]:
    """Indices of the earlier layers that ``layer`` (1-based) reads, nearest first."""
    if layer < 1:
        raise ValueError(f"HarDBlock layers are numbered from 1, got {layer}")
    links = []
    step = 1
    while layer % step == 0 and layer - step >= 0:
        links.append(layer - step)
        step *= 2
    return links


def hard_widths(in_channels: int, growth: int, multiplier: float, layers: int) -> list[int]:
    """Output width of every layer 0..``layers`` (index 0 is the block input)."""
    widths = [in_channels]
    for k in range(1, layers + 1):
        raw = growth * multiplier ** (len(hard_links(k)) - 1)
        widths.append(int(int(raw + 1) / 2) * 2)
    return widths


class HarDBlock(nn.Module):
    """One harmonic dense block of 3x3 conv-BN-ReLU layers.

    Args:
        in_channels: channels of the block input.
        growth: base width ``k`` of a layer with a single link.
        layers: number of conv layers.
        multiplier: width multiplier per extra link (1.7 in HarDNet-68/70).
    """

    def __init__(self, in_channels: int, growth: int, layers: int, *,
                 multiplier: float = 1.7) -> None:
        super().__init__()
        self.widths = hard_widths(in_channels, growth, multiplier, layers)
        self.links = [hard_links(k) for k in range(1, layers + 1)]
        self.layers = nn.ModuleList(
            ConvBNReLU(sum(self.widths[j] for j in links), self.widths[k], 3)
            for k, links in enumerate(self.links, start=1)
        )
        self.kept = [k for k in range(1, layers + 1) if k % 2 == 1 or k == layers]
        self.out_channels = sum(self.widths[k] for k in self.kept)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        outputs = [x]
        for links, layer in zip(self.links, self.layers, strict=True):
            inp = outputs[links[0]] if len(links) == 1 else torch.cat(
                [outputs[j] for j in links], dim=1)
            outputs.append(layer(inp))
        return torch.cat([outputs[k] for k in self.kept], dim=1)


class HarDNetEncoder(nn.Module):
    """FC-HarDNet's encoder: a conv stem, then HarDBlocks each followed by a 1x1 conv-BN-ReLU
    transition, with a 2x2 average pool in front of every block but the first.

    :meth:`forward` returns, per block, the block output (the decoder's skip) and the
    transition output (the next block's input before pooling).

    Args:
        in_channels: image channels (3 for RGB, 1 for depth).
        stem_channels: widths of the stem's 3x3 convs (FC-HarDNet-70: 16, 24, 32, 48).
        stem_strides: their strides (FC-HarDNet-70: 2, 1, 2, 1, i.e. the stem ends at 1/4).
        growth: growth rate of each block.
        layers: layer count of each block.
        transitions: output width of each block's 1x1 transition.
        multiplier: HarDBlock width multiplier.
    """

    def __init__(
        self,
        *,
        in_channels: int = 3,
        stem_channels: tuple[int, ...] = (16, 24, 32, 48),
        stem_strides: tuple[int, ...] = (2, 1, 2, 1),
        growth: tuple[int, ...] = (10, 16, 18, 24, 32),
        layers: tuple[int, ...] = (4, 4, 8, 8, 8),
        transitions: tuple[int, ...] = (64, 96, 160, 224, 320),
        multiplier: float = 1.7,
    ) -> None:
        super().__init__()
        if not len(growth) == len(layers) == len(transitions):
            raise ValueError("growth, layers and transitions need one entry per block")
        if len(stem_channels) != len(stem_strides):
            raise ValueError("stem_channels and stem_strides need the same length")
        stem: list[nn.Module] = []
        ch = in_channels
        for width, stride in zip(stem_channels, stem_strides, strict=True):
            stem.append(ConvBNReLU(ch, width, 3, stride=stride))
            ch = width
        self.stem = nn.Sequential(*stem)
        self.stem_channels = ch
        self.blocks = nn.ModuleList()
        self.transitions = nn.ModuleList()
        self.skip_channels: list[int] = []
        for g, n, t in zip(growth, layers, transitions, strict=True):
            block = HarDBlock(ch, g, n, multiplier=multiplier)
            self.blocks.append(block)
            self.skip_channels.append(block.out_channels)
            self.transitions.append(ConvBNReLU(block.out_channels, t, 1))
            ch = t
        self.out_channels = ch
        self.pool = nn.AvgPool2d(2, 2)

    def run_stem(self, x: torch.Tensor) -> torch.Tensor:
        return self.stem(x)

    def run_block(self, index: int, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Block ``index`` on ``x`` (the stem output or the previous transition output):
        returns (block output, transition output)."""
        if index > 0:
            x = self.pool(x)
        skip = self.blocks[index](x)
        return skip, self.transitions[index](skip)

    def forward(self, x: torch.Tensor) -> tuple[list[torch.Tensor], torch.Tensor]:
        """Skips of every block and the last transition output."""
        x = self.run_stem(x)
        skips = []
        for i in range(len(self.blocks)):
            skip, x = self.run_block(i, x)
            skips.append(skip)
        return skips, x
