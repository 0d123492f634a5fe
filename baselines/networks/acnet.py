"""ACNet-R50 (Hu et al., ICIP 2019), the RGB-D network of Table I, registered as the segmenter
``acnet-r50`` with its NYUv2 and SUN RGB-D cards (the network: :mod:`._acnet_net`; the official
code and the figures: docs/baselines/acnet-r50.md)."""

from __future__ import annotations

from baselines.networks.common import DatasetSetting, register_network
from evsmap.segmenters.normalization import Normalization

#: The official data loader's statistics (ACNet_data_nyuv2.py ``Normalize``): RGB in [0, 1],
#: depth in metres (NYUv2's .npy depth).
ACNET_NORMALIZATION = Normalization(
    rgb_mean=(0.4850042694973687, 0.41627756261047333, 0.3981809741523051),
    rgb_std=(0.26415541082494515, 0.2728415392982039, 0.2831175140191598),
    depth_mean=2.8424503515351494, depth_std=0.9932836506164299, depth_encoding="metres")

register_network(
    "acnet-r50", build="baselines.networks._acnet_net:acnet_r50",
    description="ACNet-R50 (Hu et al. 2019): RGB-D network of Table I, three ResNet-50 "
                "branches fused by channel attention",
    citation="X. Hu, K. Yang, L. Fei, K. Wang, 'ACNet: Attention Based Network to Exploit "
             "Complementary Features for RGBD Semantic Segmentation', ICIP 2019",
    datasets={
        "nyuv2": DatasetSetting(
            input_size=(480, 640), normalization=ACNET_NORMALIZATION, published=(
                ("miou", "table1/acnet-r50/miou_nyuv2"), ("params", "table1/acnet-r50/params"),
                ("flops", "table1/acnet-r50/flops"), ("fps", "table1/acnet-r50/fps"))),
        "sunrgbd": DatasetSetting(
            input_size=(480, 640), normalization=ACNET_NORMALIZATION, published=(
                ("miou", "table1/acnet-r50/miou_sunrgbd"),),
            note="The released code holds only the NYUv2 loader; this card keeps its "
                 "statistics."),
    },
    depth="depth",
    note="Written from anheidelonghu/ACNet ACNet_models_V1.py (116,628,168 parameters for 40 "
         "classes, the four training-only side classifiers included).")
