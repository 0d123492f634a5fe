"""RefineNet-R101 of Table I, registered as the segmenter ``refinenet-r101`` (the network is
:mod:`baselines.networks._refinenet_net`, built only when a segmenter is made).

An RGB network: it reads no depth. Table I prints its NYUv2 and SUN RGB-D mIoU, so it has a
card for each (docs/baselines/refinenet-r101.md).
"""

from __future__ import annotations

from baselines.networks.common import DatasetSetting, register_network

_ROW = "table1/refinenet-r101"

register_network(
    "refinenet-r101",
    build="baselines.networks._refinenet_net:refinenet_r101",
    description="RefineNet-R101 (Lin et al. 2017): multi-path refinement network on ResNet-101, "
                "RGB network of Table I",
    citation="G. Lin, A. Milan, C. Shen, I. Reid, 'RefineNet: Multi-Path Refinement Networks "
             "for High-Resolution Semantic Segmentation', CVPR 2017",
    datasets={
        "nyuv2": DatasetSetting(input_size=(480, 640), published=(
            ("miou", f"{_ROW}/miou_nyuv2"), ("params", f"{_ROW}/params"),
            ("flops", f"{_ROW}/flops"), ("fps", f"{_ROW}/fps"))),
        "sunrgbd": DatasetSetting(input_size=(480, 640), published=(
            ("miou", f"{_ROW}/miou_sunrgbd"),)),
    },
    depth=None,
    note="Written from DrSleep/refinenet-pytorch models/resnet.py rf101 (commit 8f25c07); "
         "logits at 1/4 of the input size.",
)
