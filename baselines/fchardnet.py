"""FC-HarDNet-70 from "HarDNet: A Low Memory Traffic Network" (Chao et al., ICCV 2019), the
baseline that FEAGNet is built on (EVSMaP Table III "Basel.").

Encoder: a four-conv stem to 1/4 resolution and five HarDBlocks down to 1/64. Decoder: four
stages of bilinear upsampling to the skip's size, concatenation with the skip, a 1x1 conv-BN-ReLU
halving the channels and a HarDBlock; a 1x1 head and a x4 bilinear upsampling.
"""

from __future__ import annotations

import torch
from torch import nn

from evsmap.models.hardnet import HarDBlock, HarDNetEncoder
from evsmap.models.layers import ConvBNReLU, resize_to


class FCHarDNet(nn.Module):
    """FC-HarDNet (RGB only).

    Args:
        num_classes: number of output classes.
        growth: encoder block growth rates (the decoder reuses the first four in reverse).
        layers: encoder block layer counts.
        transitions: encoder transition widths.
    """

    def __init__(
        self,
        *,
        num_classes: int = 19,
        growth: tuple[int, ...] = (10, 16, 18, 24, 32),
        layers: tuple[int, ...] = (4, 4, 8, 8, 8),
        transitions: tuple[int, ...] = (64, 96, 160, 224, 320),
    ) -> None:
        super().__init__()
        self.num_classes = num_classes
        self.encoder = HarDNetEncoder(in_channels=3, growth=growth, layers=layers,
                                      transitions=transitions)
        ch = self.encoder.out_channels
        self.reduce = nn.ModuleList()
        self.up_blocks = nn.ModuleList()
        for i in range(len(growth) - 2, -1, -1):
            cat = ch + self.encoder.skip_channels[i]
            self.reduce.append(ConvBNReLU(cat, cat // 2, 1))
            block = HarDBlock(cat // 2, growth[i], layers[i])
            self.up_blocks.append(block)
            ch = block.out_channels
        self.head = nn.Conv2d(ch, num_classes, 1)

    def forward(self, rgb: torch.Tensor) -> torch.Tensor:
        size = rgb.shape[-2:]
        skips, x = self.encoder(rgb)
        for reduce, block, skip in zip(self.reduce, self.up_blocks, reversed(skips[:-1]),
                                       strict=True):
            x = torch.cat([resize_to(x, skip.shape[-2:]), skip], dim=1)
            x = block(reduce(x))
        return resize_to(self.head(x), size)


def fchardnet70(*, num_classes: int = 19) -> FCHarDNet:
    """FC-HarDNet-70 as published (growth 10/16/18/24/32, layers 4/4/8/8/8)."""
    return FCHarDNet(num_classes=num_classes)
