"""DABNet (Li et al., BMVC 2019), the real-time RGB network of Table II, registered as the
segmenter ``dabnet`` with its Cityscapes card (the network: :mod:`._dabnet_net`; the official
code and the figures: docs/baselines/dabnet.md)."""

from __future__ import annotations

from baselines.networks.common import DatasetSetting, register_network

register_network(
    "dabnet", build="baselines.networks._dabnet_net:dabnet",
    description="DABNet (Li et al. 2019): real-time RGB network of Table II",
    citation="G. Li, I. Yun, J. Kim, J. Kim, 'DABNet: Depth-wise Asymmetric Bottleneck for "
             "Real-time Semantic Segmentation', BMVC 2019",
    datasets={"cityscapes": DatasetSetting(input_size=(1024, 2048), published=(
        ("params", "table2/dabnet/params"), ("miou", "table2/dabnet/miou_2048"),
        ("fps", "table2/dabnet/fps_2048"), ("fps", "table2/dabnet/fps_1024")),
        note="Table II prints its FPS at 1024x2048 (fps_2048, this card's size) and at "
             "512x1024 (fps_1024).")},
    depth=None,
    note="Written from Reagan1311/DABNet model/DABNet.py (756,643 parameters for 19 classes). "
         "The official code feeds BGR images minus the Cityscapes mean (0-255, no std); no "
         "weights are loaded here, so the card keeps ImageNet RGB statistics.")
