"""SGACNet-R34 (Zhang et al., IEEE Sensors Journal 2023), the RGB-D network of Tables I and II,
registered as the segmenter ``sgacnet-r34`` with its NYUv2, SUN RGB-D and Cityscapes cards (the
network: :mod:`._sgacnet_r34_net`; the official code and the figures:
docs/baselines/sgacnet-r34.md)."""

from __future__ import annotations

from baselines.networks.common import DatasetSetting, register_network
from evsmap.segmenters.normalization import CITYSCAPES_ESANET, INDOOR, SUNRGBD_ESANET

_ROW1 = "table1/sgacnet-r34"
_ROW2 = "table2/sgacnet-r34"

register_network(
    "sgacnet-r34", build="baselines.networks._sgacnet_r34_net:sgacnet_r34",
    description="SGACNet-R34 (Zhang et al. 2023): RGB-D network of Tables I and II",
    citation="Y. Zhang, C. Xiong, J. Liu, X. Ye, G. Sun, 'Spatial-information Guided Adaptive "
             "Context-aware Network for Efficient RGB-D Semantic Segmentation', IEEE Sensors "
             "Journal 2023",
    datasets={
        "nyuv2": DatasetSetting(
            input_size=(480, 640), normalization=INDOOR, published=(
                ("miou", f"{_ROW1}/miou_nyuv2"), ("params", f"{_ROW1}/params"),
                ("flops", f"{_ROW1}/flops"), ("fps", f"{_ROW1}/fps")),
            note="35,650,321 parameters (40 classes), as the official code counts them."),
        "sunrgbd": DatasetSetting(
            input_size=(480, 640), normalization=SUNRGBD_ESANET,
            published=(("miou", f"{_ROW1}/miou_sunrgbd"),),
            note="Table I prints only its SUN RGB-D mIoU."),
        "cityscapes": DatasetSetting(
            input_size=(512, 1024), normalization=CITYSCAPES_ESANET, published=(
                ("miou", f"{_ROW2}/miou_1024"), ("fps", f"{_ROW2}/fps_1024"),
                ("miou", f"{_ROW2}/miou_2048"), ("fps", f"{_ROW2}/fps_2048"),
                ("params", f"{_ROW2}/params")),
            note="Trained at 512x1024 (this card's size); Table II also prints its mIoU and FPS "
                 "at 1024x2048 (miou_2048, fps_2048). 35,607,229 parameters (19 classes)."),
    },
    depth="depth",
    note="Written from CyunXiong/SGACNet src/models/model.py with its commented-out ResNet-34 "
         "encoder branch restored; configuration of the official training scripts "
         "(NBt1D encoders, SE + SPA fusion, appm context, BRU decoder, bilinear upsampling). "
         "Depth as ESANet reads it (the same dataset code and statistics). The released "
         "checkpoints (Google Drive) use the official module names and load into no evsmap "
         "layout yet.")
