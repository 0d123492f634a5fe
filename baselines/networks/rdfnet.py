"""RDFNet-R101 of Table I, registered as the segmenter ``rdfnet-r101`` (the network is
:mod:`baselines.networks._rdfnet_net`, built only when a segmenter is made).

An RGB-D network that reads HHA (``depth="hha"``: the segmenter encodes each frame's depth with
:mod:`baselines.hha`). Table I prints only its NYUv2 mIoU, so it has an NYUv2 card
(docs/baselines/rdfnet-r101.md).
"""

from __future__ import annotations

from baselines.networks.common import DatasetSetting, register_network

_ROW = "table1/rdfnet-r101"

register_network(
    "rdfnet-r101",
    build="baselines.networks._rdfnet_net:rdfnet_r101",
    description="RDFNet-R101 (Park et al. 2017): RGB and HHA ResNet-101 encoders fused by "
                "multi-modal feature fusion blocks, RefineNet decoder; RGB-D network of Table I",
    citation="S.-J. Park, K.-S. Hong, S. Lee, 'RDFNet: RGB-D Multi-level Residual Feature "
             "Fusion for Indoor Semantic Segmentation', ICCV 2017",
    datasets={
        "nyuv2": DatasetSetting(input_size=(480, 640), published=(
            ("miou", f"{_ROW}/miou_nyuv2"), ("params", f"{_ROW}/params"),
            ("flops", f"{_ROW}/flops"), ("fps", f"{_ROW}/fps"))),
    },
    depth="hha",
    note="Written from the PyTorch port charlesCXK/PyTorch_Semantic_Segmentation "
         "RDFNet_PyTorch/rdfnet.py (commit da45973), the one ESANet timed: 358,622,888 "
         "parameters with 40 classes; Table I prints 443.8 M.",
)
