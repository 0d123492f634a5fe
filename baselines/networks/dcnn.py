"""DCNN-R152 of Table I, registered as the segmenter ``dcnn-r152`` (the network is
:mod:`baselines.networks._dcnn_net`, built only when a segmenter is made).

An RGB-D network: convolutions and pooling read RGB features, the depth (metres,
unstandardised) weights their taps by depth similarity. Table I prints only its NYUv2 mIoU, so
it has an NYUv2 card. The public code is VGG-16 only: the ResNet-152 design is documented in
docs/baselines/dcnn-r152.md.
"""

from __future__ import annotations

from baselines.networks.common import DatasetSetting, register_network
from evsmap.segmenters.normalization import Normalization

_ROW = "table1/dcnn-r152"

register_network(
    "dcnn-r152",
    build="baselines.networks._dcnn_net:dcnn_r152",
    description="DCNN-R152 (Wang and Neumann 2018): depth-aware convolution and average pooling "
                "in a DeepLab ResNet-152; RGB-D network of Table I, designed from the paper and "
                "its VGG-16 release",
    citation="W. Wang, U. Neumann, 'Depth-aware CNN for RGB-D Segmentation', ECCV 2018",
    datasets={
        "nyuv2": DatasetSetting(
            input_size=(480, 640), normalization=Normalization(depth_mean=0.0, depth_std=1.0),
            published=(("miou", f"{_ROW}/miou_nyuv2"), ("params", f"{_ROW}/params"),
                       ("fps", f"{_ROW}/fps"))),
    },
    depth="depth",
    note="No public code for ResNet-152 (laughtervv/DepthAwareCNN is VGG-16): 91,720,040 "
         "parameters with 40 classes (Table I 92.0 M, -0.3 %). Depth in metres, not "
         "standardised: it only weights the depth-aware taps.",
)
