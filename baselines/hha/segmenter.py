"""The segmenter of an RGB-D network that reads HHA (:mod:`baselines.hha.encoding`) instead of
depth.

Its inputs are named ``rgb`` and ``hha`` (the ONNX export's input names, which ``evsmap speed``,
``evsmap complexity`` and the runner take from :attr:`HHASegmenter.input_names`). Preprocessing,
as the official code of the HHA networks (SA-Gate, ``charlesCXK/RGBD_Semantic_Segmentation_
PyTorch``: ``model/SA-Gate.nyu/dataloader.py`` ``normalize`` and ``config.py``; the same for
RGB and HHA): HHA (uint8, channels disparity, height, angle) is scaled to [0, 1], resized
bilinearly to the network's input size like RGB, and standardised per channel with ImageNet's
mean (0.485, 0.456, 0.406) and standard deviation (0.229, 0.224, 0.225).
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from baselines.hha.encoding import encode_hha
from evsmap.data import Frame
from evsmap.segmenters.network import NetworkSegmenter, network_inputs
from evsmap.segmenters.normalization import IMAGENET_MEAN, IMAGENET_STD

__all__ = ["HHA_MEAN", "HHA_STD", "HHASegmenter", "hha_input"]

#: Per-channel statistics HHA is standardised with after scaling to [0, 1] (SA-Gate's
#: ``config.image_mean`` / ``config.image_std``, used for both RGB and HHA).
HHA_MEAN = IMAGENET_MEAN
HHA_STD = IMAGENET_STD


def hha_input(hha: np.ndarray, size: tuple[int, int]) -> torch.Tensor:
    """The network input ``(1, 3, H, W)`` float32 of an HHA image ``(h, w, 3)`` uint8: scaled
    to [0, 1], resized bilinearly to ``size`` (H, W), standardised with :data:`HHA_MEAN` and
    :data:`HHA_STD`."""
    t = torch.from_numpy(np.ascontiguousarray(hha)).permute(2, 0, 1)[None].float() / 255.0
    if tuple(t.shape[-2:]) != tuple(size):
        t = F.interpolate(t, size=tuple(size), mode="bilinear", align_corners=False)
    mean = torch.tensor(HHA_MEAN).view(1, 3, 1, 1)
    std = torch.tensor(HHA_STD).view(1, 3, 1, 1)
    return (t - mean) / std


class HHASegmenter(NetworkSegmenter):
    """A network segmenter whose depth input is the three HHA channels of the frame's depth.

    The constructor is :class:`~evsmap.segmenters.network.NetworkSegmenter`'s (``uses_depth``
    True); the module is called as ``module(rgb, hha)`` with ``rgb`` and ``hha`` both
    ``(B, 3, H, W)``.
    """

    @property
    def input_names(self) -> tuple[str, ...]:
        return ("rgb", "hha")

    def example_inputs(self, height: int, width: int) -> tuple[torch.Tensor, ...]:
        """Inputs drawn from seed 0 (batch 1): RGB ``(1, 3, H, W)``, then HHA ``(1, 3, H, W)``;
        the same in every process."""
        gen = torch.Generator().manual_seed(0)
        rgb = torch.randn(1, 3, height, width, generator=gen)
        return rgb, torch.randn(1, 3, height, width, generator=gen)

    def preprocess(self, frame: Frame) -> tuple[torch.Tensor, ...]:
        """Normalised RGB and HHA (batch 1, float32) at the network's input size: HHA computed
        from ``frame.depth`` and ``frame.intrinsics`` (:func:`baselines.hha.encode_hha`)."""
        frame.require_images(f"segmenter {self.name!r}")
        assert frame.rgb is not None and frame.depth is not None and \
            frame.intrinsics is not None  # an image frame
        (rgb,) = network_inputs(frame.rgb, None, self.normalization, self.input_size)
        hha = encode_hha(frame.depth, frame.intrinsics)
        return rgb, hha_input(hha, self.input_size)
