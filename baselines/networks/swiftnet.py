"""SwiftNet-RN18 (Orsic et al., CVPR 2019), the real-time RGB network of Table II, registered
as the segmenter ``swiftnet-rn18`` with its Cityscapes card (the network:
:mod:`._swiftnet_net`; the official code and the figures: docs/baselines/swiftnet-rn18.md)."""

from __future__ import annotations

from baselines.networks.common import DatasetSetting, register_network
from evsmap.segmenters.normalization import Normalization

CITYSCAPES_SWIFTNET = Normalization(
    rgb_mean=(73.15 / 255, 82.90 / 255, 72.3 / 255),
    rgb_std=(47.67 / 255, 48.49 / 255, 47.73 / 255), depth_mean=0.0, depth_std=1.0)
"""The official single-scale configuration's Cityscapes RGB statistics (0-255 values / 255),
which its model applies inside (``img_mean``, ``img_std``)."""

register_network(
    "swiftnet-rn18", build="baselines.networks._swiftnet_net:swiftnet_rn18",
    description="SwiftNet-RN18 single scale (Orsic et al. 2019): real-time RGB network of "
                "Table II",
    citation="M. Orsic, I. Kreso, P. Bevandic, S. Segvic, 'In Defense of Pre-trained ImageNet "
             "Architectures for Real-time Semantic Segmentation of Road-driving Images', "
             "CVPR 2019",
    datasets={"cityscapes": DatasetSetting(
        input_size=(1024, 2048), normalization=CITYSCAPES_SWIFTNET, published=(
            ("params", "table2/swiftnet/params"), ("miou", "table2/swiftnet/miou_2048"),
            ("fps", "table2/swiftnet/fps_2048"), ("fps", "table2/swiftnet/fps_1024")),
        note="Table II prints its FPS at 1024x2048 (fps_2048, this card's size) and at "
             "512x1024 (fps_1024).")},
    depth=None,
    note="Written from orsic/swiftnet configs/rn18_single_scale.py (11,797,071 parameters for "
         "19 classes); the ResNet-18 encoder has torchvision's parameter names under "
         "'backbone.'.")
