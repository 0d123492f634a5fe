"""CANet-R50 (baselines.networks.canet): the official parameter count, the registered segmenter
and cards, the co-attention parts, output shapes, FLOPs through `evsmap complexity`, ONNX
Runtime equal to torch."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from baselines.networks._canet_net import (
    CANet,
    ChannelCoAttention,
    CoAttentionFusion,
    PositionCoAttention,
    canet_r50,
)
from evsmap.cli.main import main
from evsmap.measure import export_onnx
from evsmap.registry import SEGMENTERS
from evsmap.segmenters.model_card import MODEL_CARDS
from evsmap.testing import require_module
from tests.baselines.networks.helpers import count_params

PARAMS = 127_306_954  # zhouhao94/CANet CANet_models.py, ResNet-50, pcca5=True, 40 classes
PAPER_PARAMS_M = 87.1  # Table I (and the CANet paper): the released code is larger
ACNET_PARAMS = 116_628_168
ONNX_RTOL = 1e-4  # of the logits' largest magnitude (BN statistics randomised below)
SMALL = (64, 128)


@pytest.fixture(scope="module")
def model() -> CANet:
    torch.manual_seed(0)
    return canet_r50(num_classes=40).eval()



def _randomise(model: torch.nn.Module, seed: int = 0) -> None:
    """Non-trivial BatchNorm statistics and affine terms, and non-zero attention gains, so eval
    differs from identity and the co-attention contributes."""
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for m in model.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                n = m.num_features
                m.running_mean.copy_(torch.rand(n, generator=gen) - 0.5)
                m.running_var.copy_(torch.rand(n, generator=gen) + 0.5)
                m.weight.copy_(torch.rand(n, generator=gen) + 0.5)
                m.bias.copy_(torch.rand(n, generator=gen) - 0.5)
            if isinstance(m, (PositionCoAttention, ChannelCoAttention)):
                m.gamma.fill_(0.5)


def _inputs(batch: int = 1, size: tuple[int, int] = SMALL) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(1)
    return (torch.randn(batch, 3, *size, generator=gen),
            torch.randn(batch, 1, *size, generator=gen))


def test_registered_segmenter_has_the_official_count() -> None:
    segmenter = SEGMENTERS.create("canet-r50")
    assert isinstance(segmenter.module, CANet)
    assert count_params(segmenter.module) == PARAMS
    assert PARAMS / 1e6 - PAPER_PARAMS_M > 40  # the recorded mismatch with the paper
    assert segmenter.num_classes == 40 and segmenter.uses_depth
    assert tuple(segmenter.default_size) == (480, 640)
    sun = SEGMENTERS.create("canet-r50", dataset="sunrgbd")
    assert sun.num_classes == 37
    assert count_params(sun.module) == PARAMS - 3 * (64 * 4 + 1 + 256 + 128 + 64 + 64 + 4)


def test_cards_reference_table1() -> None:
    card = MODEL_CARDS.get("canet-r50.nyuv2")
    assert card.num_classes == 40 and card.uses_depth and card.input_size == (480, 640)
    assert [f.cell for f in card.published] == [
        "table1/canet-r50/miou_nyuv2", "table1/canet-r50/params", "table1/canet-r50/flops",
        "table1/canet-r50/fps"]
    assert "87.1" in card.note
    sun = MODEL_CARDS.get("canet-r50.sunrgbd")
    assert [f.cell for f in sun.published] == ["table1/canet-r50/miou_sunrgbd"]


def test_parts_count(model: CANet) -> None:
    reduce = 9 * 2048 * 512 + 2 * 512
    position = 2 * (512 * 64 + 64) + 512 * 512 + 512 + 1
    proj = 512 * 1024 + 2 * 1024
    fusion = 2 * (1024 * 256 + 256 + 2 * 256 + 256 * 2048 + 2048)
    assert count_params(model.position) == position
    assert count_params(model.channel) == 1
    assert count_params(model.fusion) == fusion
    # CANet = ACNet without its ten channel-attention convs, plus the stage-4 co-attention
    acnet_attention = 2 * sum(c * c + c for c in (64, 256, 512, 1024, 2048))
    assert PARAMS == ACNET_PARAMS - acnet_attention + 2 * reduce + position + 1 + 2 * proj + (
        fusion)


def test_co_attention_with_zero_gain_is_the_identity() -> None:
    torch.manual_seed(0)
    x, y = torch.randn(2, 16, 3, 5), torch.randn(2, 16, 3, 5)
    position, channel = PositionCoAttention(channels=16), ChannelCoAttention()
    assert torch.equal(position(x, y), x) and torch.equal(channel(x, y), x)


def test_channel_co_attention_formula() -> None:
    torch.manual_seed(0)
    x, y = torch.randn(1, 4, 2, 3), torch.randn(1, 4, 2, 3)
    module = ChannelCoAttention()
    with torch.no_grad():
        module.gamma.fill_(2.0)
        got = module(x, y)
    xf, yf = x.reshape(4, 6), y.reshape(4, 6)
    energy = xf @ yf.T
    weights = torch.softmax(energy.max(dim=1, keepdim=True).values - energy, dim=1)
    torch.testing.assert_close(got, (2.0 * (weights @ yf)).reshape(1, 4, 2, 3) + x)


def test_fusion_reweights_the_merged_half_and_the_position_features() -> None:
    torch.manual_seed(0)
    fusion = CoAttentionFusion(channels=32).eval()
    x, p, c = torch.randn(1, 64, 2, 3), torch.randn(1, 32, 2, 3), torch.randn(1, 32, 2, 3)
    with torch.no_grad():
        for fc in (fusion.fc2_p, fusion.fc2_c):  # equal logits: both weights 1/2
            fc.weight.zero_()
            fc.bias.zero_()
        out = fusion(x, p, c)
    assert out.shape == (1, 64, 2, 3)
    half = 0.5 * x[:, :32] + 0.5 * p
    torch.testing.assert_close(out, torch.cat([half, half], 1))


def test_eval_output_is_input_sized_logits(model: CANet) -> None:
    with torch.no_grad():
        out = model(*_inputs(batch=2))
        fused = model.encode(*_inputs())
    assert out.shape == (2, 40, *SMALL)
    assert [tuple(f.shape[1:]) for f in fused] == [
        (64, 32, 64), (256, 16, 32), (512, 8, 16), (1024, 4, 8), (2048, 2, 4)]


def test_train_mode_returns_side_outputs() -> None:
    torch.manual_seed(0)
    net = canet_r50(num_classes=5).train()
    outs = net(*_inputs(batch=2))
    assert [tuple(o.shape) for o in outs] == [
        (2, 5, 64, 128), (2, 5, 32, 64), (2, 5, 16, 32), (2, 5, 8, 16), (2, 5, 4, 8)]
    sum(o.mean() for o in outs).backward()
    assert net.position.gamma.grad is not None and net.fusion.fc1_c.weight.grad is not None


def test_complexity_command(capsys) -> None:
    assert main(["complexity", "canet-r50", "--height", str(SMALL[0]), "--width",
                 str(SMALL[1]), "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["params"] == PARAMS
    assert record["inputs"] == ["rgb", "depth"]
    # fvcore MACs at 64x128; at 480x640: docs/baselines/canet-r50.md
    assert record["conv_macs"] == 3_245_867_008
    assert record["by_operator"]["bmm"] == 4_231_168
    assert record["flops"] == pytest.approx(3_264_197_632, rel=1e-3)
    assert set(record["uncounted_ops"]) == {"aten::add", "aten::amax", "aten::max_pool2d",
                                            "aten::mul", "aten::softmax", "aten::sub"}


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_onnx_runtime_matches_torch(tmp_path) -> None:
    ort = require_module("onnxruntime")
    torch.manual_seed(0)
    model = canet_r50(num_classes=40)
    _randomise(model)
    rgb, depth = _inputs()
    with torch.no_grad():
        expected = model.eval()(rgb, depth).numpy()
    assert expected.std() > 0.05
    path = export_onnx(model, (rgb, depth), ("rgb", "depth"), tmp_path / "canet.onnx")
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    (got,) = session.run(None, {"rgb": rgb.numpy(), "depth": depth.numpy()})
    assert got.shape == (1, 40, *SMALL)
    np.testing.assert_allclose(got, expected, rtol=0,
                               atol=ONNX_RTOL * float(np.abs(expected).max()))
