"""PIDNet-S (baselines.networks.pidnet_s): registration, parameter count of Table II, outputs,
the other variants' counts and ONNX export."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from baselines.networks._pidnet_net import PAPPM, Bag, LightBag, PIDNet, pidnet
from evsmap.measure.complexity import measure_complexity
from evsmap.models.onnx_export import export_onnx
from evsmap.registry import SEGMENTERS
from evsmap.segmenters.model_card import MODEL_CARDS
from evsmap.testing import require_module

# Counted by instantiating the release's get_pred_model (XuJiacong/PIDNet @ 4c158cf, 19 classes).
PARAMS_S = 7_625_715
PARAMS_M = 28_538_515
PARAMS_L = 36_939_571
SMALL = (64, 128)  # 1/64 map of 1x2
ONNX_TOLERANCE = 1e-5  # relative to the largest logit (float32 summation order)


@pytest.fixture(scope="module")
def segmenter():
    torch.manual_seed(0)
    return SEGMENTERS.create("pidnet-s")


def _randomise_bn(module: torch.nn.Module) -> None:
    """Non-trivial batch-norm statistics, so that eval mode differs from train mode."""
    gen = torch.Generator().manual_seed(3)
    for m in module.modules():
        if isinstance(m, torch.nn.BatchNorm2d):
            m.running_mean.copy_(torch.randn(m.num_features, generator=gen) * 0.1)
            m.running_var.copy_(torch.rand(m.num_features, generator=gen) + 0.5)


def test_card_is_table_ii_row():
    card = MODEL_CARDS.get("pidnet-s.cityscapes")
    assert card.input_size == (1024, 2048)
    assert card.num_classes == 19 and not card.uses_depth
    assert {f.cell for f in card.published} == {
        "table2/pidnet-s/params", "table2/pidnet-s/fps_2048", "table2/pidnet-s/fps_1024",
        "table2/pidnet-s/miou_2048"}
    assert card.figure("fps").cell == "table2/pidnet-s/fps_2048"  # the card's own size first


def test_parameter_count_is_table_ii(segmenter):
    module = segmenter.module
    assert isinstance(module, PIDNet)
    assert sum(p.numel() for p in module.parameters()) == PARAMS_S
    assert not hasattr(module, "seghead_p") and not hasattr(module, "seghead_d")


def test_complexity_code_path(segmenter):
    record = measure_complexity(segmenter.module, segmenter.example_inputs(*SMALL))
    assert record.params == PARAMS_S
    assert (record.height, record.width) == SMALL
    # the convolutions are most of the cost, and grow with the input
    assert 0.8 * record.flops < record.conv_macs <= record.flops
    bigger = measure_complexity(segmenter.module, segmenter.example_inputs(128, 256))
    assert 3.5 * record.flops < bigger.flops < 4.5 * record.flops


def test_other_variants_match_the_release():
    m, large = pidnet(variant="m"), pidnet(variant="l")
    assert sum(p.numel() for p in m.parameters()) == PARAMS_M
    assert sum(p.numel() for p in large.parameters()) == PARAMS_L
    assert isinstance(m.spp, PAPPM) and isinstance(m.dfm, LightBag)
    assert isinstance(large.dfm, Bag) and type(large.spp).__name__ == "DAPPM"


def test_classes_change_only_the_head():
    nine = pidnet(variant="s", num_classes=9)
    assert sum(p.numel() for p in nine.parameters()) == PARAMS_S - 10 * (128 + 1)


def test_eval_output_is_one_eighth_logits(segmenter):
    module = segmenter.module.eval()
    with torch.no_grad():
        out = module(*segmenter.example_inputs(*SMALL))
    assert out.shape == (1, 19, SMALL[0] // 8, SMALL[1] // 8)
    assert torch.isfinite(out).all()


def test_branches_all_reach_the_output():
    """Zeroing the P, I or D branch's last block changes the logits: forward uses all three."""
    torch.manual_seed(1)
    net = pidnet(variant="s").eval()
    _randomise_bn(net)
    x = torch.randn(1, 3, *SMALL)
    with torch.no_grad():
        base = net(x)
        for name in ("layer5_", "layer5", "layer5_d"):
            block = getattr(net, name)[0]
            saved = block.bn3.weight.clone(), block.bn3.bias.clone()
            block.bn3.weight.zero_()
            block.bn3.bias.fill_(5.0)
            assert not torch.allclose(net(x), base), name
            block.bn3.weight.copy_(saved[0])
            block.bn3.bias.copy_(saved[1])


def test_onnx_matches_torch(tmp_path, segmenter):
    ort = require_module("onnxruntime")
    module = segmenter.module.eval()
    _randomise_bn(module)
    inputs = segmenter.example_inputs(*SMALL)
    path = export_onnx(module, inputs, segmenter.input_names, tmp_path / "pidnet-s.onnx")
    with torch.no_grad():
        expected = module(*inputs).numpy()
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    got = session.run(None, {"rgb": inputs[0].numpy()})[0]
    assert got.shape == expected.shape
    scale = float(np.abs(expected).max())
    assert scale > 0
    np.testing.assert_allclose(got, expected, rtol=0, atol=ONNX_TOLERANCE * scale)
