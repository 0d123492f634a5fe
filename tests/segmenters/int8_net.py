"""A tiny gated RGB-D network as a registered-style :class:`NetworkSegmenter` factory, shared by
the int8 tests (``tests/segmenters/test_quantize.py``, ``tests/cli/test_int8_cli.py``): conv-BN-
ReLU stages, a sigmoid gate and a 1x1 classifier - the shapes the quantiser's rules act on - and
small enough to export and quantise in a second."""

from __future__ import annotations

import torch
from torch import nn

from evsmap.segmenters.network import NetworkSegmenter

NAME = "tiny-int8-test-net"
CLASSES = 5
SIZE = (32, 48)


class GatedNet(nn.Module):
    def __init__(self, classes: int = CLASSES) -> None:
        super().__init__()

        def stage(cin: int, cout: int, stride: int) -> nn.Sequential:
            return nn.Sequential(nn.Conv2d(cin, cout, 3, stride, 1, bias=False),
                                 nn.BatchNorm2d(cout), nn.ReLU())

        self.rgb = stage(3, 16, 2)
        self.depth = stage(1, 16, 2)
        self.body = nn.Sequential(stage(16, 24, 1), stage(24, 24, 1))
        self.gate = nn.Conv2d(24, 24, 1)
        self.classifier = nn.Conv2d(24, classes, 1)

    def forward(self, rgb: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
        x = self.body(self.rgb(rgb) + self.depth(depth))
        x = x * torch.sigmoid(self.gate(x))
        logits = self.classifier(x)
        return nn.functional.interpolate(logits, size=rgb.shape[-2:], mode="bilinear",
                                         align_corners=False)


def tiny_segmenter(*, backend: str = "torch", weights=None, input_size=SIZE,
                   precision: str = "fp32", seed: int = 0,
                   num_classes: int = CLASSES) -> NetworkSegmenter:
    """The tiny network with seeded weights (BatchNorm at its initial statistics)."""
    torch.manual_seed(seed)
    return NetworkSegmenter(
        name=NAME, module=GatedNet(num_classes), num_classes=num_classes,
        class_names=tuple(f"c{i}" for i in range(num_classes)), uses_depth=True,
        default_size=SIZE, backend=backend, weights=weights, input_size=input_size,
        precision=precision)
