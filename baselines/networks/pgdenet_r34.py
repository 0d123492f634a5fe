"""PGDENet-R34 (Zhou et al., IEEE TMM 2023), the RGB-D network of Table I, registered as the
segmenter ``pgdenet-r34`` with its NYUv2 and SUN RGB-D cards (the network:
:mod:`._pgdenet_r34_net`; the official code and the figures: docs/baselines/pgdenet-r34.md)."""

from __future__ import annotations

from baselines.networks.common import DatasetSetting, register_network

_ROW = "table1/pgdenet-r34"

register_network(
    "pgdenet-r34", build="baselines.networks._pgdenet_r34_net:pgdenet_r34",
    description="PGDENet-R34 (Zhou et al. 2023): RGB-D network of Table I",
    citation="W. Zhou, E. Yang, J. Lei, J. Wan, L. Yu, 'PGDENet: Progressive Guided Fusion "
             "and Depth Enhancement Network for RGB-D Indoor Scene Parsing', IEEE Transactions "
             "on Multimedia 2023",
    datasets={
        "nyuv2": DatasetSetting(
            input_size=(480, 640), num_classes=41, published=(
                ("miou", f"{_ROW}/miou_nyuv2"), ("params", f"{_ROW}/params"),
                ("flops", f"{_ROW}/flops"), ("fps", f"{_ROW}/fps")),
            note="41 classes as configs/nyuv2.json: void kept as class 0. 100,691,630 "
                 "parameters, those the forward pass uses."),
        "sunrgbd": DatasetSetting(
            input_size=(480, 640), num_classes=38,
            published=(("miou", f"{_ROW}/miou_sunrgbd"),),
            note="38 classes as configs/sunrgbd.json (void kept). Table I prints only its SUN "
                 "RGB-D mIoU."),
    },
    depth="depth",
    note="Written from EnquanYang2022/PGDENet toolbox/models/BBSnetmodel/BBSnet.py: two "
         "ResNet-34 encoders, depth enhancement, progressive guided fusion, transposed-conv "
         "decoder; modules the forward pass never uses are left out. The official code reads "
         "depth as an 8-bit PNG scaled to [0, 1] and standardised (0.449 +- 0.226), first "
         "channel; no weights are released, so the card keeps evsmap's indoor depth "
         "statistics.")
