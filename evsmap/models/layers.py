"""Small layers shared by the networks: conv-BN-ReLU, bilinear resizing, and the switch that
lets a network return its logits before the final resize."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


class ConvBNReLU(nn.Sequential):
    """``k x k`` convolution (no bias), batch norm, ReLU - FC-HarDNet's ``ConvLayer``.

    Args:
        in_channels: input channels.
        out_channels: output channels.
        kernel_size: square kernel size, or ``(kh, kw)``.
        stride: convolution stride.
        dilation: convolution dilation.
        groups: convolution groups (``in_channels`` for depthwise).
        relu: append the ReLU (``False`` gives conv-BN).
    """

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        kernel_size: int | tuple[int, int] = 3,
        *,
        stride: int = 1,
        dilation: int | tuple[int, int] = 1,
        groups: int = 1,
        relu: bool = True,
    ) -> None:
        kh, kw = (kernel_size, kernel_size) if isinstance(kernel_size, int) else kernel_size
        dh, dw = (dilation, dilation) if isinstance(dilation, int) else dilation
        layers: list[nn.Module] = [
            nn.Conv2d(in_channels, out_channels, (kh, kw), stride=stride,
                      padding=(dh * (kh // 2), dw * (kw // 2)), dilation=(dh, dw),
                      groups=groups, bias=False),
            nn.BatchNorm2d(out_channels),
        ]
        if relu:
            layers.append(nn.ReLU(inplace=True))
        super().__init__(*layers)


def resize_to(x: torch.Tensor, size: tuple[int, int] | torch.Size) -> torch.Tensor:
    """Bilinear resize (``align_corners=True``, as FC-HarDNet's decoder) to ``size`` (H, W)."""
    if tuple(x.shape[-2:]) == tuple(size):
        return x
    return F.interpolate(x, size=tuple(size), mode="bilinear", align_corners=True)


class StridedLogits:
    """A network whose ``forward`` ends in :func:`resize_to` of its logits to the input size,
    and returns them at its output stride instead while :attr:`upsample_logits` is False.

    :class:`~evsmap.segmenters.network.NetworkSegmenter` turns it off for its ``postprocess``
    options ``fused`` (the resize done inside the top-k, the same labels) and ``stride`` (the
    top-k at the output stride); training and every other caller see the resized logits.
    """

    upsample_logits: bool = True

    def final_resize(self, logits: torch.Tensor, size: tuple[int, int] | torch.Size
                     ) -> torch.Tensor:
        """``logits`` resized to ``size``, or as they are while :attr:`upsample_logits` is
        off."""
        return resize_to(logits, size) if self.upsample_logits else logits
