"""SA-Gate-R101 (baselines.networks.sagate): the official parameter count, the registered HHA
segmenter and card, the shared shortcuts and dilated layer4, the gate, output shapes, FLOPs
through `evsmap complexity`, ONNX Runtime equal to torch."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from baselines.networks._sagate_net import (
    ASPP,
    DeepLabV3PlusHead,
    FeatureSeparation,
    SAGate,
    SAGateNet,
    sagate_r101,
)
from evsmap.cli.main import main
from evsmap.errors import UnknownNameError
from evsmap.measure import export_onnx
from evsmap.registry import SEGMENTERS
from evsmap.segmenters.model_card import MODEL_CARDS
from evsmap.testing import require_module
from tests.baselines.networks.helpers import count_params, randomise_norms

# charlesCXK/RGBD_Semantic_Segmentation_PyTorch model/SA-Gate.nyu/network.py, DeepLab(40, ...)
PARAMS = 110_875_160
ONNX_RTOL = 1e-4  # of the logits' largest magnitude (BN statistics randomised below)
SMALL = (64, 128)
# ResNet-101 without fc, deep stem of width 64 (torchvision's 44,549,160 with fc; the 7x7 stem
# of 9,408 weights replaced by 3x3 3->64, 64->64, 64->128 and two BN(64); layer1's first
# shortcut and first 1x1 read 128 channels instead of 64)
RESNET101_DEEP = (44_549_160 - 2_049_000 - 9_408 + 9 * (3 * 64 + 64 * 64 + 64 * 128) + 4 * 64
                  + 2 * 64 + 64 * 256 + 64 * 64)


@pytest.fixture(scope="module")
def model() -> SAGateNet:
    torch.manual_seed(0)
    return sagate_r101(num_classes=40).eval()




def _inputs(batch: int = 1, size: tuple[int, int] = SMALL) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(1)
    return (torch.randn(batch, 3, *size, generator=gen),
            torch.randn(batch, 3, *size, generator=gen))


def test_registered_segmenter_has_the_official_count() -> None:
    segmenter = SEGMENTERS.create("sagate-r101")
    assert isinstance(segmenter.module, SAGateNet)
    assert count_params(segmenter.module) == PARAMS
    assert segmenter.num_classes == 40 and segmenter.uses_depth
    assert tuple(segmenter.input_names) == ("rgb", "hha")
    assert tuple(segmenter.default_size) == (480, 640)
    with pytest.raises(UnknownNameError, match="no card for dataset 'sunrgbd'"):
        SEGMENTERS.create("sagate-r101", dataset="sunrgbd")


def test_card_references_table1() -> None:
    card = MODEL_CARDS.get("sagate-r101.nyuv2")
    assert card.num_classes == 40 and card.uses_depth and card.input_size == (480, 640)
    assert [f.cell for f in card.published] == [
        "table1/sagate-r101/miou_nyuv2", "table1/sagate-r101/params",
        "table1/sagate-r101/flops", "table1/sagate-r101/fps"]


def test_encoders_share_their_shortcuts(model: SAGateNet) -> None:
    assert count_params(model.rgb) == RESNET101_DEEP
    shortcuts = 0
    for stage in ("layer1", "layer2", "layer3", "layer4"):
        rgb_block, hha_block = getattr(model.rgb, stage)[0], getattr(model.hha, stage)[0]
        assert hha_block.downsample is rgb_block.downsample
        shortcuts += count_params(rgb_block.downsample)
    assert shortcuts == 2 * (256 + 512 + 1024 + 2048) + (
        128 * 256 + 256 * 512 + 512 * 1024 + 1024 * 2048)
    both = {id(p) for p in model.rgb.parameters()} | {id(p) for p in model.hha.parameters()}
    assert len(both) == len(list(model.rgb.parameters())) * 2 - 4 * 3
    assert sum(p.numel() for p in model.parameters() if id(p) in both) == (
        2 * RESNET101_DEEP - shortcuts)


def test_layer4_keeps_stride_16_with_rates_2_4_8(model: SAGateNet) -> None:
    for backbone in (model.rgb, model.hha):
        convs = [b.conv2 for b in backbone.layer4]
        assert [c.dilation for c in convs] == [(2, 2), (4, 4), (8, 8)]
        assert [c.padding for c in convs] == [(2, 2), (4, 4), (8, 8)]
        assert all(c.stride == (1, 1) for c in convs)
        assert backbone.layer4[0].downsample[0].stride == (1, 1)
    fused = model.encode(*_inputs())
    assert [tuple(f.shape[1:]) for f in fused] == [
        (256, 16, 32), (512, 8, 16), (1024, 4, 8), (2048, 4, 8)]


def test_parts_count(model: SAGateNet) -> None:
    # the gate of 256 channels: two filters Linear(512, 16) + Linear(16, 256), two 1x1 gates
    gate = 2 * (512 * 16 + 16 + 16 * 256 + 256) + 2 * (512 + 1)
    assert count_params(SAGate(channels=256)) == gate
    assert count_params(FeatureSeparation(channels=2048)) == 4096 * 128 + 128 + 128 * 2048 + 2048
    aspp = 2048 * 256 * (1 + 3 * 9) + 2 * 1024 + 2048 * 256 + 2 * 256 + 1024 * 256 + (
        256 * 256) + 2 * 256
    assert count_params(ASPP(in_channels=2048, out_channels=256)) == aspp
    head = aspp + (256 * 48 + 96) + (9 * 304 * 256 + 512 + 9 * 256 * 256 + 512) + (
        256 * 40 + 40) + (9 * 2048 * 512 + 1024 + 512 * 40 + 40)
    assert count_params(DeepLabV3PlusHead(num_classes=40)) == head
    assert count_params(model.head) == head
    assert PARAMS == count_params(model.rgb) + count_params(model.hha) - sum(
        count_params(getattr(model.rgb, s)[0].downsample) for s in ("layer1", "layer2", "layer3",
                                                               "layer4")
    ) + count_params(model.gates) + head


def test_gate_fuses_by_a_per_pixel_softmax() -> None:
    torch.manual_seed(0)
    gate = SAGate(channels=32)
    rgb, hha = torch.randn(2, 32, 3, 4), torch.randn(2, 32, 3, 4)
    with torch.no_grad():
        for conv in (gate.gate_rgb, gate.gate_hha):  # equal gate logits: weights 1/2 each
            conv.weight.zero_()
            conv.bias.zero_()
        rgb_out, hha_out, fused = gate(rgb, hha)
    torch.testing.assert_close(fused, (rgb + hha) / 2)
    torch.testing.assert_close(rgb_out, torch.relu((rgb + fused) / 2))
    torch.testing.assert_close(hha_out, torch.relu((hha + fused) / 2))


def test_eval_output_is_input_sized_logits(model: SAGateNet) -> None:
    with torch.no_grad():
        out = model(*_inputs(batch=2))
        odd = model(*_inputs(size=(48, 80)))
    assert out.shape == (2, 40, *SMALL)
    assert odd.shape == (1, 40, 48, 80)


def test_train_mode_returns_the_auxiliary_logits() -> None:
    torch.manual_seed(0)
    net = sagate_r101(num_classes=5).train()
    pred, aux = net(*_inputs(batch=2))
    assert pred.shape == aux.shape == (2, 5, *SMALL)
    (pred.mean() + aux.mean()).backward()
    assert net.head.auxlayer[0].weight.grad is not None
    assert net.hha.layer1[0].downsample[0].weight.grad is not None


def test_complexity_command(capsys) -> None:
    assert main(["complexity", "sagate-r101", "--height", str(SMALL[0]), "--width",
                 str(SMALL[1]), "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["params"] == PARAMS
    assert record["inputs"] == ["rgb", "hha"]
    # fvcore MACs at 64x128; at 480x640: docs/baselines/sagate-r101.md
    assert record["conv_macs"] == 4_833_345_536
    assert record["flops"] == pytest.approx(4_852_310_528, rel=1e-3)  # = the release's
    assert {"aten::softmax", "aten::sigmoid", "aten::leaky_relu"} <= set(
        record["uncounted_ops"])


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_onnx_runtime_matches_torch(tmp_path) -> None:
    ort = require_module("onnxruntime")
    torch.manual_seed(0)
    model = sagate_r101(num_classes=40)
    randomise_norms(model)
    rgb, hha = _inputs()
    with torch.no_grad():
        expected = model.eval()(rgb, hha).numpy()
    assert expected.std() > 0.05
    path = export_onnx(model, (rgb, hha), ("rgb", "hha"), tmp_path / "sagate.onnx")
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    (got,) = session.run(None, {"rgb": rgb.numpy(), "hha": hha.numpy()})
    assert got.shape == (1, 40, *SMALL)
    np.testing.assert_allclose(got, expected, rtol=0,
                               atol=ONNX_RTOL * float(np.abs(expected).max()))
