"""LDN121 (Kreso et al., T-ITS 2020), the Ladder-DenseNet of Table II ("LDN"), registered as the
segmenter ``ldn121`` with its Cityscapes card (the network: :mod:`._ldn_net`; the official code,
its two encoder configurations and the figures: docs/baselines/ldn121.md)."""

from __future__ import annotations

from baselines.networks.common import DatasetSetting, register_network
from evsmap.segmenters.normalization import Normalization

CITYSCAPES_LDN = Normalization(
    rgb_mean=(73.45286 / 255, 83.21195 / 255, 72.78044 / 255),
    rgb_std=(45.19961 / 255, 46.3659 / 255, 45.48506 / 255), depth_mean=0.0, depth_std=1.0)
"""The release's Cityscapes RGB statistics (0-255 values / 255,
``data/cityscapes/cityscapes_reader.py``)."""

register_network(
    "ldn121", build="baselines.networks._ldn_net:ldn121",
    description="LDN121 (Kreso et al. 2020): Ladder-DenseNet-121, RGB network of Table II",
    citation="I. Kreso, J. Krapac, S. Segvic, 'Efficient Ladder-Style DenseNets for Semantic "
             "Segmentation of Large Images', IEEE T-ITS 2020",
    datasets={"cityscapes": DatasetSetting(
        input_size=(1024, 2048), normalization=CITYSCAPES_LDN, published=(
            ("params", "table2/ldn/params"), ("miou", "table2/ldn/miou_2048"),
            ("fps", "table2/ldn/fps_2048")),
        note="Table II prints LDN's FPS at 1024x2048 only (fps_2048).")},
    depth=None,
    note="Written from ivankreso/LDN models/ldn_semseg.py as released and evaluated "
         "(ImageNet-initialised DenseNet-121 encoder): 10,314,515 parameters for 19 classes; "
         "the release's encoder without ImageNet initialisation (10,232,467) is "
         "baselines.networks._ldn_net.ldn121_from_scratch.")
