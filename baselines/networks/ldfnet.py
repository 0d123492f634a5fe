"""LDFNet's registration (Table II, RGB-D, Cityscapes 19 classes); the network is in
:mod:`baselines.networks._ldfnet_net` (imported only when a segmenter is built)."""

from __future__ import annotations

from baselines.networks.common import DatasetSetting, register_network
from evsmap.segmenters.normalization import Normalization

#: The release's inputs: RGB by ``ToTensor`` alone (in [0, 1], not standardised; the network
#: derives the luminance from it), and Cityscapes' disparity PNG divided by 100.
LDFNET_CITYSCAPES = Normalization(rgb_mean=(0.0, 0.0, 0.0), rgb_std=(1.0, 1.0, 1.0),
                                  depth_mean=0.0, depth_std=100.0,
                                  depth_encoding="cityscapes-disparity")

register_network(
    "ldfnet", build="baselines.networks._ldfnet_net:ldfnet",
    description="LDFNet (Hung et al. 2019): ERFNet RGB encoder fused with a DenseNet "
                "depth-and-luminance encoder, RGB-D network of Table II",
    citation="S.-W. Hung, S.-Y. Lo and H.-M. Hang, 'Incorporating Luminance, Depth and Color "
             "Information by a Fusion-based Network for Semantic Segmentation', ICIP 2019",
    datasets={"cityscapes": DatasetSetting(
        input_size=(1024, 2048), normalization=LDFNET_CITYSCAPES,
        published=(("params", "table2/ldfnet/params"), ("miou", "table2/ldfnet/miou_1024")),
        note="Written from shangweihung/LDFNet model/LDFNet.py Net(19): 2,415,760 parameters "
             "(2,451 of them the encoder-only classifier of the first training stage). Depth "
             "is Cityscapes disparity (PNG value / 100), luminance computed from RGB.")},
    depth="depth",
    note="See docs/baselines/ldfnet.md.")
