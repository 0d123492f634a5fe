"""SA-Gate-R101 (Chen et al., ECCV 2020), the RGB-D network of Table I, registered as the segmenter
``sagate-r101`` with its NYUv2 card (the network: :mod:`._sagate_net`; the official code and the
figures: docs/baselines/sagate-r101.md).

It reads HHA (``depth="hha"``: the segmenter encodes each frame's depth with
:mod:`baselines.hha`, normalised with the ImageNet statistics as the official loader does). Table
I prints no SUN RGB-D figure for it, so it has no SUN RGB-D card.
"""

from __future__ import annotations

from baselines.networks.common import DatasetSetting, register_network

_ROW = "table1/sagate-r101"

register_network(
    "sagate-r101", build="baselines.networks._sagate_net:sagate_r101",
    description="SA-Gate-R101 (Chen et al. 2020): RGB and HHA ResNet-101 encoders joined by "
                "separation-and-aggregation gates, DeepLabV3+ head; RGB-D network of Table I",
    citation="X. Chen, K.-Y. Lin, J. Wang, W. Wu, C. Qian, H. Li, G. Zeng, 'Bi-directional "
             "Cross-Modality Feature Propagation with Separation-and-Aggregation Gate for "
             "RGB-D Semantic Segmentation', ECCV 2020",
    datasets={
        "nyuv2": DatasetSetting(input_size=(480, 640), published=(
            ("miou", f"{_ROW}/miou_nyuv2"), ("params", f"{_ROW}/params"),
            ("flops", f"{_ROW}/flops"), ("fps", f"{_ROW}/fps"))),
    },
    depth="hha",
    note="Written from charlesCXK/RGBD_Semantic_Segmentation_PyTorch model/SA-Gate.nyu "
         "(network.py, dual_resnet.py, net_util.py): 110,875,160 parameters with 40 classes, "
         "the training-only auxiliary FCN head included.",
)
