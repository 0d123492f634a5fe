"""DDRNet-23-slim (Hong et al.), the real-time RGB network of Table II ("DDRNet-S"),
registered as the segmenter ``ddrnet-23-slim`` with its Cityscapes card (the network:
:mod:`._ddrnet_net`; the official code and the figures: docs/baselines/ddrnet-23-slim.md)."""

from __future__ import annotations

from baselines.networks.common import DatasetSetting, register_network

register_network(
    "ddrnet-23-slim", build="baselines.networks._ddrnet_net:ddrnet_23_slim",
    description="DDRNet-23-slim (Hong et al. 2021): real-time RGB network of Table II",
    citation="Y. Hong, H. Pan, W. Sun, Y. Jia, 'Deep Dual-resolution Networks for Real-time "
             "and Accurate Semantic Segmentation of Road Scenes', arXiv:2101.06085",
    datasets={"cityscapes": DatasetSetting(input_size=(1024, 2048), published=(
        ("params", "table2/ddrnet-s/params"), ("miou", "table2/ddrnet-s/miou_2048"),
        ("fps", "table2/ddrnet-s/fps_2048"), ("fps", "table2/ddrnet-s/fps_1024")),
        note="Table II prints its FPS at 1024x2048 (fps_2048, this card's size) and at "
             "512x1024 (fps_1024), both marked as the paper's own measurements.")},
    depth=None,
    note="Written from ydhongHIT/DDRNet segmentation/DDRNet_23_slim.py, the inference model "
         "without the auxiliary head (5,695,987 parameters for 19 classes; 5,734,342 with it). "
         "Logits at 1/8 of the input, as the official model; the segmenter upsamples them.")
