"""3DGNN-R101 of Table I, registered as the segmenter ``3dgnn-r101`` (the network is
:mod:`baselines.networks._gnn3d_net`, built only when a segmenter is made; a module name cannot
start with a digit).

An RGB-D network: the unary CNN reads RGB, the depth (metres, unstandardised) places the graph's
nodes in 3D. Table I prints its NYUv2 and SUN RGB-D mIoU, so it has a card for each. No public
code has this configuration: the design is documented in docs/baselines/3dgnn-r101.md.
"""

from __future__ import annotations

from baselines.networks.common import DatasetSetting, register_network
from evsmap.segmenters.normalization import Normalization

_ROW = "table1/3dgnn-r101"
#: ImageNet RGB statistics; depth passed in metres (the graph needs metric 3D points).
_METRIC_DEPTH = Normalization(depth_mean=0.0, depth_std=1.0)
_NOTE = ("Depth in metres, not standardised: it only builds the 3D k-nearest-neighbour graph "
         "(back-projected with NYUv2's colour-camera intrinsics scaled to the input).")

register_network(
    "3dgnn-r101",
    build="baselines.networks._gnn3d_net:gnn3d_r101",
    description="3DGNN-R101 (Qi et al. 2017): graph neural network over a 3D k-nearest-neighbour "
                "graph of ResNet-101 unary features; RGB-D network of Table I, designed from "
                "the paper",
    citation="X. Qi, R. Liao, J. Jia, S. Fidler, R. Urtasun, '3D Graph Neural Networks for RGBD "
             "Semantic Segmentation', ICCV 2017",
    datasets={
        "nyuv2": DatasetSetting(input_size=(480, 640), normalization=_METRIC_DEPTH, published=(
            ("miou", f"{_ROW}/miou_nyuv2"), ("params", f"{_ROW}/params"),
            ("fps", f"{_ROW}/fps"))),
        "sunrgbd": DatasetSetting(input_size=(480, 640), normalization=_METRIC_DEPTH,
                                  published=(("miou", f"{_ROW}/miou_sunrgbd"),)),
    },
    depth="depth",
    note="No public code for this configuration (the authors' release is Caffe, ResNet-50): "
         "designed from the paper, 47,828,072 parameters with 40 classes (Table I 47.3 M, "
         "+1.1 %). " + _NOTE,
)
