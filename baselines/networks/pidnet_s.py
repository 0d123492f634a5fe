"""PIDNet-S's registration (Table II, RGB, Cityscapes 19 classes); the network is in
:mod:`baselines.networks._pidnet_net` (imported only when a segmenter is built)."""

from __future__ import annotations

from baselines.networks.common import DatasetSetting, register_network

register_network(
    "pidnet-s", build="baselines.networks._pidnet_net:pidnet_s",
    description="PIDNet-S (Xu et al. 2023): real-time three-branch (P, I, D) RGB network of "
                "Table II, inference model",
    citation="J. Xu, Z. Xiong and S. P. Bhattacharyya, 'PIDNet: A Real-time Semantic "
             "Segmentation Network Inspired by PID Controllers', CVPR 2023",
    datasets={"cityscapes": DatasetSetting(
        input_size=(1024, 2048),
        published=(("params", "table2/pidnet-s/params"), ("fps", "table2/pidnet-s/fps_2048"),
                   ("fps", "table2/pidnet-s/fps_1024"), ("miou", "table2/pidnet-s/miou_2048")),
        note="Written from XuJiacong/PIDNet models/pidnet.py (get_pred_model('pidnet_s'), "
             "augment=False): 7,625,715 parameters; logits at 1/8 of the input.")},
    depth=None,
    note="See docs/baselines/pidnet-s.md.")
