"""DDRNet-23-slim (baselines.networks.ddrnet): the official parameter count of the inference
model, the registered segmenter and card, shapes, FLOPs through `evsmap complexity`, ONNX
Runtime equal to torch."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from baselines.networks._ddrnet_net import (
    DAPPM,
    BasicBlock,
    Bottleneck,
    DualResNet,
    SegHead,
    ddrnet_23_slim,
)
from evsmap.cli.main import main
from evsmap.measure import export_onnx
from evsmap.registry import SEGMENTERS
from evsmap.segmenters.model_card import MODEL_CARDS
from evsmap.testing import require_module
from tests.baselines.networks.helpers import count_params, randomise_norms

# ydhongHIT/DDRNet segmentation/DDRNet_23_slim.py, DualResNet_imagenet() (augment=False), counted
PARAMS = 5_695_987
AUX_HEAD = 5_734_342 - PARAMS  # segmenthead(64, 64, 19) of augment=True, not in the inference model
ONNX_RTOL = 1e-4  # relative to the logits' spread (they reach ~1e2 with random weights)
SMALL = (64, 128)
# fvcore at 64x128 (evsmap complexity); 1024x2048 in docs/baselines/ddrnet-23-slim.md
CONV_MACS_SMALL = 141_942_784
UNCOUNTED = {"aten::add", "aten::avg_pool2d"}




def test_registered_segmenter_has_the_official_count() -> None:
    segmenter = SEGMENTERS.create("ddrnet-23-slim")
    assert isinstance(segmenter.module, DualResNet)
    assert count_params(segmenter.module) == PARAMS
    assert round(PARAMS / 1e6, 1) == 5.7  # Table II prints 5.7 M: the inference model
    assert segmenter.num_classes == 19 and not segmenter.uses_depth
    assert tuple(segmenter.default_size) == (1024, 2048)


def test_card_references_table2() -> None:
    card = MODEL_CARDS.get("ddrnet-23-slim.cityscapes")
    assert card.num_classes == 19 and card.input_size == (1024, 2048)
    assert [f.cell for f in card.published] == [
        "table2/ddrnet-s/params", "table2/ddrnet-s/miou_2048", "table2/ddrnet-s/fps_2048",
        "table2/ddrnet-s/fps_1024"]


def test_parts_count() -> None:
    # the auxiliary head the inference model leaves out: BN(64), 3x3 64->64, BN(64), 1x1 +bias
    assert count_params(SegHead(in_channels=64, channels=64, num_classes=19)) == AUX_HEAD
    assert count_params(BasicBlock(in_channels=32, channels=64, stride=2)) == (
        9 * 32 * 64 + 9 * 64 * 64 + 2 * 2 * 64 + 32 * 64 + 2 * 64)
    assert count_params(Bottleneck(in_channels=64, channels=64)) == (
        64 * 64 + 9 * 64 * 64 + 64 * 128 + 2 * (64 + 64 + 128) + 64 * 128 + 2 * 128)
    # scale0 + 4 scales (BN 512, 1x1 512->128), 4 processes (BN 128, 3x3), compression
    # (BN 640, 1x1 640->128), shortcut (BN 512, 1x1 512->128)
    assert count_params(DAPPM(in_channels=512, branch=128, out_channels=128)) == (
        5 * (2 * 512 + 512 * 128) + 4 * (2 * 128 + 9 * 128 * 128)
        + 2 * 640 + 640 * 128 + 2 * 512 + 512 * 128)
    assert count_params(ddrnet_23_slim(num_classes=11)) == PARAMS - 8 * 65


def test_parameter_names_are_the_releases() -> None:
    keys = set(ddrnet_23_slim().state_dict())
    # a sample of the release's state-dict keys, one per kind of module
    release = {"conv1.0.weight", "conv1.0.bias", "conv1.4.running_var", "layer1.0.conv1.weight",
               "layer2.0.downsample.1.weight", "layer3_.1.bn2.bias", "layer5_.0.conv3.weight",
               "layer5.0.downsample.0.weight", "compression3.0.weight", "down4.3.weight",
               "spp.scale0.2.weight", "spp.scale1.1.running_mean", "spp.scale4.3.weight",
               "spp.process4.2.weight", "spp.compression.0.weight", "spp.shortcut.2.weight",
               "final_layer.bn1.weight", "final_layer.conv2.bias"}
    assert release <= keys
    assert not any(k.startswith("seghead_extra.") for k in keys)  # no auxiliary head
    assert len(keys) == 333  # as many as the release's inference model (BN counters included)


def test_logits_at_an_eighth() -> None:
    model = ddrnet_23_slim(num_classes=19).eval()
    with torch.no_grad():
        assert model(torch.randn(2, 3, *SMALL)).shape == (2, 19, 8, 16)
        assert model(torch.randn(1, 3, 72, 200)).shape == (1, 19, 9, 25)


def test_segmenter_upsamples_to_the_frame() -> None:
    segmenter = SEGMENTERS.create("ddrnet-23-slim", input_size=SMALL)
    with torch.no_grad():
        logits = segmenter.module.eval()(torch.randn(1, 3, *SMALL))
    observation = segmenter.top_k(logits, SMALL, 3)
    assert observation.classes.shape == (*SMALL, 3)
    assert int(observation.classes.max()) < 19


def test_complexity_command(capsys) -> None:
    assert main(["complexity", "ddrnet-23-slim", "--height", str(SMALL[0]), "--width",
                 str(SMALL[1]), "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["params"] == PARAMS
    assert record["conv_macs"] == CONV_MACS_SMALL
    assert record["flops"] == pytest.approx(142_843_392, rel=1e-3)
    assert set(record["uncounted_ops"]) == UNCOUNTED


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_onnx_runtime_matches_torch(tmp_path) -> None:
    ort = require_module("onnxruntime")
    torch.manual_seed(0)
    model = ddrnet_23_slim(num_classes=19)
    randomise_norms(model)
    rgb = torch.randn(1, 3, *SMALL, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        expected = model.eval()(rgb).numpy()
    path = export_onnx(model, (rgb,), ("rgb",), tmp_path / "ddrnet.onnx")
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    (got,) = session.run(None, {"rgb": rgb.numpy()})
    assert got.shape == (1, 19, 8, 16)
    np.testing.assert_allclose(got, expected, rtol=0, atol=ONNX_RTOL * float(np.ptp(expected)))
