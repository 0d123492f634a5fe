"""CANet-R50 (Zhou et al., Pattern Recognition 2022), the RGB-D network of Table I, registered as
the segmenter ``canet-r50`` with its NYUv2 and SUN RGB-D cards (the network: :mod:`._canet_net`;
the official code and the figures: docs/baselines/canet-r50.md)."""

from __future__ import annotations

from baselines.networks.common import DatasetSetting, register_network
from evsmap.segmenters.normalization import Normalization

#: The official data loader's statistics (CANet_data_nyuv2.py ``Normalize``, ACNet's): RGB in
#: [0, 1], depth in metres (NYUv2's .npy depth).
CANET_NORMALIZATION = Normalization(
    rgb_mean=(0.4850042694973687, 0.41627756261047333, 0.3981809741523051),
    rgb_std=(0.26415541082494515, 0.2728415392982039, 0.2831175140191598),
    depth_mean=2.8424503515351494, depth_std=0.9932836506164299, depth_encoding="metres")

register_network(
    "canet-r50", build="baselines.networks._canet_net:canet_r50",
    description="CANet-R50 (Zhou et al. 2022): RGB-D network of Table I, ResNet-50 branches "
                "with position and channel co-attention",
    citation="H. Zhou, L. Qi, H. Huang, X. Yang, Z. Wan, X. Wen, 'CANet: Co-attention network "
             "for RGB-D semantic segmentation', Pattern Recognition 124, 108468, 2022",
    datasets={
        "nyuv2": DatasetSetting(
            input_size=(480, 640), normalization=CANET_NORMALIZATION, published=(
                ("miou", "table1/canet-r50/miou_nyuv2"), ("params", "table1/canet-r50/params"),
                ("flops", "table1/canet-r50/flops"), ("fps", "table1/canet-r50/fps")),
            note="Table I prints 87.1 M parameters; the released code counts 127,306,954."),
        "sunrgbd": DatasetSetting(
            input_size=(480, 640), normalization=CANET_NORMALIZATION, published=(
                ("miou", "table1/canet-r50/miou_sunrgbd"),),
            note="The released code holds only the NYUv2 loader; this card keeps its "
                 "statistics."),
    },
    depth="depth",
    note="Written from zhouhao94/CANet CANet_models.py with its training configuration "
         "(backbone='ResNet-50', pcca5=True): 127,306,954 parameters for 40 classes, the four "
         "training-only side classifiers included.")
