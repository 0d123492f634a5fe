"""SSMA's registration (Table II, RGB-D, Cityscapes 19 classes); the network is in
:mod:`baselines.networks._ssma_net` (imported only when a segmenter is built)."""

from __future__ import annotations

from baselines.networks.common import DatasetSetting, register_network
from evsmap.segmenters.normalization import Normalization

#: The release's inputs: 0-255 images (its first layer is a batch norm of the raw image) and,
#: as the second modality, the disparity coloured with the jet map; the disparity PNG value
#: (256 d + 1) is divided by 256 x 128, so that a disparity of 128 px is the map's top end.
SSMA_CITYSCAPES = Normalization(rgb_mean=(0.0, 0.0, 0.0),
                                rgb_std=(1 / 255, 1 / 255, 1 / 255),
                                depth_mean=0.0, depth_std=256.0 * 128.0,
                                depth_encoding="cityscapes-disparity")

register_network(
    "ssma", build="baselines.networks._ssma_net:ssma",
    description="SSMA (Valada et al. 2019): two AdapNet++ ResNet-50 experts (RGB, jet-coloured "
                "depth) fused by self-supervised model adaptation blocks, RGB-D network of "
                "Table II",
    citation="A. Valada, R. Mohan and W. Burgard, 'Self-Supervised Model Adaptation for "
             "Multimodal Semantic Segmentation', IJCV 2019",
    datasets={"cityscapes": DatasetSetting(
        input_size=(1024, 2048), normalization=SSMA_CITYSCAPES,
        published=(("params", "table2/ssma/params"), ("miou", "table2/ssma/miou_2048")),
        note="Written from DeepSceneSeg/SSMA (TensorFlow) models/SSMA.py with AdapNet++ "
             "experts: 56,198,136 parameters for 19 classes, 0.43 % below the README's "
             "56.44 M. Depth enters as Cityscapes disparity coloured with the jet map (the "
             "README's RGB_Depth model).")},
    depth="depth",
    note="See docs/baselines/ssma.md.")
