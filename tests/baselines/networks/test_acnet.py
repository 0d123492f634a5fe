"""ACNet-R50 (baselines.networks.acnet): the official parameter count, the registered segmenter
and cards, the branch layout, output shapes, FLOPs through `evsmap complexity`, ONNX Runtime
equal to torch."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from baselines.networks._acnet_net import (
    ACDecoder,
    ACNet,
    TransBasicBlock,
    acnet_r50,
    channel_attention,
    trans_stage,
)
from evsmap.cli.main import main
from evsmap.measure import export_onnx
from evsmap.registry import SEGMENTERS
from evsmap.segmenters.model_card import MODEL_CARDS
from evsmap.testing import require_module
from tests.baselines.networks.helpers import count_params, randomise_norms

PARAMS = 116_628_168  # anheidelonghu/ACNet ACNet_models_V1.py, ACNet(num_class=40), counted
SIDE_PARAMS = 40 * (256 + 128 + 64 + 64) + 4 * 40  # training-only side classifiers
ONNX_RTOL = 1e-4  # of the logits' largest magnitude (BN statistics randomised below)
SMALL = (64, 128)

# torchvision's ResNet-50 state-dict keys of one stage's first block (the other blocks lack
# the downsample), written out from its documented layout.
_BLOCK0 = ("conv1.weight", "bn1.weight", "bn1.bias", "bn1.running_mean", "bn1.running_var",
           "bn1.num_batches_tracked", "conv2.weight", "bn2.weight", "bn2.bias",
           "bn2.running_mean", "bn2.running_var", "bn2.num_batches_tracked", "conv3.weight",
           "bn3.weight", "bn3.bias", "bn3.running_mean", "bn3.running_var",
           "bn3.num_batches_tracked", "downsample.0.weight", "downsample.1.weight",
           "downsample.1.bias", "downsample.1.running_mean", "downsample.1.running_var",
           "downsample.1.num_batches_tracked")


def _torchvision_resnet50_keys() -> set[str]:
    keys = {"conv1.weight", "bn1.weight", "bn1.bias", "bn1.running_mean", "bn1.running_var",
            "bn1.num_batches_tracked"}
    for stage, blocks in enumerate((3, 4, 6, 3), start=1):
        for b in range(blocks):
            keys |= {f"layer{stage}.{b}.{k}" for k in _BLOCK0
                     if b == 0 or not k.startswith("downsample")}
    return keys


@pytest.fixture(scope="module")
def model() -> ACNet:
    torch.manual_seed(0)
    return acnet_r50(num_classes=40).eval()




def _inputs(batch: int = 1, size: tuple[int, int] = SMALL) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(1)
    return (torch.randn(batch, 3, *size, generator=gen),
            torch.randn(batch, 1, *size, generator=gen))


def test_registered_segmenter_has_the_official_count() -> None:
    segmenter = SEGMENTERS.create("acnet-r50")
    assert isinstance(segmenter.module, ACNet)
    assert count_params(segmenter.module) == PARAMS
    assert segmenter.num_classes == 40 and segmenter.uses_depth
    assert tuple(segmenter.default_size) == (480, 640)
    sun = SEGMENTERS.create("acnet-r50", dataset="sunrgbd")
    assert sun.num_classes == 37
    assert count_params(sun.module) == PARAMS - 3 * (64 * 4 + 1 + 256 + 128 + 64 + 64 + 4)


def test_cards_reference_table1() -> None:
    card = MODEL_CARDS.get("acnet-r50.nyuv2")
    assert card.num_classes == 40 and card.uses_depth and card.input_size == (480, 640)
    assert [f.cell for f in card.published] == [
        "table1/acnet-r50/miou_nyuv2", "table1/acnet-r50/params", "table1/acnet-r50/flops",
        "table1/acnet-r50/fps"]
    assert card.normalization.depth_mean == pytest.approx(2.8424503515351494)
    sun = MODEL_CARDS.get("acnet-r50.sunrgbd")
    assert sun.num_classes == 37
    assert [f.cell for f in sun.published] == ["table1/acnet-r50/miou_sunrgbd"]


def test_branches_are_torchvision_resnet50s(model: ACNet) -> None:
    expected = _torchvision_resnet50_keys()
    assert set(model.rgb.state_dict()) == expected
    assert set(model.depth.state_dict()) == expected
    assert model.rgb.conv1.weight.shape == (64, 3, 7, 7)
    assert model.depth.conv1.weight.shape == (64, 1, 7, 7)  # one depth channel
    # the merged branch has the four stages only (its stem is never run)
    merge = {f"layer{int(k[0]) + 1}{k[1:]}" for k in model.merge.state_dict()}
    assert merge == {k for k in expected if k.startswith("layer")}


def test_parts_count(model: ACNet) -> None:
    resnet50 = 25_557_032 - (2048 * 1000 + 1000)  # torchvision's, without fc
    stem = 64 * 3 * 49 + 2 * 64
    assert count_params(model.rgb) == resnet50
    assert count_params(model.depth) == resnet50 - 64 * 2 * 49
    assert count_params(model.merge) == resnet50 - stem
    assert count_params(channel_attention(256)) == 256 * 256 + 256
    # decoder block: 3x3 in->in + BN, 3x3 (transposed) in->planes + BN, shortcut
    assert count_params(TransBasicBlock(inplanes=64, planes=64)) == 2 * (9 * 64 * 64 + 128)
    up = trans_stage(128, 64, 3, stride=2)
    assert count_params(up) == 2 * 2 * (9 * 128 * 128 + 256) + (9 * 128 * 128 + 256) + (
        9 * 128 * 64 + 128) + (4 * 128 * 64 + 128)
    assert count_params(ACDecoder(num_classes=40)) == PARAMS - (
        count_params(model.rgb) + count_params(model.depth) + count_params(model.merge)
        + count_params(model.atten_rgb) + count_params(model.atten_depth))
    assert count_params(model.decoder.side) == SIDE_PARAMS


def test_eval_output_is_input_sized_logits(model: ACNet) -> None:
    with torch.no_grad():
        out = model(*_inputs(batch=2))
    assert out.shape == (2, 40, *SMALL)
    fused = model.encode(*_inputs())
    assert [tuple(f.shape[1:]) for f in fused] == [
        (64, 32, 64), (256, 16, 32), (512, 8, 16), (1024, 4, 8), (2048, 2, 4)]


def test_train_mode_returns_side_outputs() -> None:
    torch.manual_seed(0)
    net = acnet_r50(num_classes=5).train()
    outs = net(*_inputs(batch=2))
    assert [tuple(o.shape) for o in outs] == [
        (2, 5, 64, 128), (2, 5, 32, 64), (2, 5, 16, 32), (2, 5, 8, 16), (2, 5, 4, 8)]
    sum(o.mean() for o in outs).backward()
    assert net.decoder.side[0].weight.grad is not None
    assert net.depth.conv1.weight.grad is not None


def test_complexity_command(capsys) -> None:
    assert main(["complexity", "acnet-r50", "--height", str(SMALL[0]), "--width",
                 str(SMALL[1]), "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["params"] == PARAMS
    assert record["inputs"] == ["rgb", "depth"]
    # fvcore MACs at 64x128; at 480x640: docs/baselines/acnet-r50.md
    assert record["conv_macs"] == 3_093_438_464
    assert record["flops"] == pytest.approx(3_108_225_024, rel=1e-3)
    assert set(record["uncounted_ops"]) == {"aten::add", "aten::max_pool2d", "aten::mul",
                                            "aten::sigmoid"}


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_onnx_runtime_matches_torch(tmp_path) -> None:
    ort = require_module("onnxruntime")
    torch.manual_seed(0)
    model = acnet_r50(num_classes=40)
    randomise_norms(model)
    rgb, depth = _inputs()
    with torch.no_grad():
        expected = model.eval()(rgb, depth).numpy()
    assert expected.std() > 0.05
    path = export_onnx(model, (rgb, depth), ("rgb", "depth"), tmp_path / "acnet.onnx")
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    (got,) = session.run(None, {"rgb": rgb.numpy(), "depth": depth.numpy()})
    assert got.shape == (1, 40, *SMALL)
    np.testing.assert_allclose(got, expected, rtol=0,
                               atol=ONNX_RTOL * float(np.abs(expected).max()))
