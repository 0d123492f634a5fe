"""RefineNet-R101 (baselines.networks.refinenet): registration, the parameter count of Table I's
official code, the encoder's torchvision names, outputs, blocks and ONNX export."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from baselines.networks._refinenet_net import (
    ChainedResidualPooling,
    RefineNet,
    ResidualConvUnit,
    refinenet_r101,
)
from evsmap.measure.complexity import measure_complexity
from evsmap.models.onnx_export import export_onnx
from evsmap.registry import SEGMENTERS
from evsmap.segmenters.model_card import MODEL_CARDS
from evsmap.testing import require_module

# Counted by instantiating DrSleep/refinenet-pytorch rf101(40, pretrained=False) @ 8f25c07.
PARAMS_NYUV2 = 118_096_232
#: The classifier is a 3x3 convolution with bias on 256 channels.
HEAD_PER_CLASS = 256 * 9 + 1
SMALL = (64, 128)  # 1/32 map of 2x4
#: ONNX Runtime vs torch: largest difference relative to the largest logit. Untrained, the
#: encoder's batch norms (mean 0, variance 1) let activations grow to ~1e5 in layer4 and the
#: logits to ~1e3, so an absolute tolerance would measure the random weights, not the export.
ONNX_TOLERANCE = 1e-5


@pytest.fixture(scope="module")
def segmenter():
    torch.manual_seed(0)
    return SEGMENTERS.create("refinenet-r101")


def torchvision_resnet_keys(layers: tuple[int, int, int, int]) -> set[str]:
    """State-dict keys of torchvision's bottleneck ResNet with ``layers`` blocks (no ``fc``)."""
    bn = ("weight", "bias", "running_mean", "running_var", "num_batches_tracked")
    keys = {"conv1.weight", *(f"bn1.{k}" for k in bn)}
    for stage, blocks in enumerate(layers, start=1):
        for block in range(blocks):
            prefix = f"layer{stage}.{block}"
            for i in (1, 2, 3):
                keys |= {f"{prefix}.conv{i}.weight", *(f"{prefix}.bn{i}.{k}" for k in bn)}
            if block == 0:
                keys |= {f"{prefix}.downsample.0.weight",
                         *(f"{prefix}.downsample.1.{k}" for k in bn)}
    return keys


def test_cards_are_table_i_rows():
    nyu = MODEL_CARDS.get("refinenet-r101.nyuv2")
    assert nyu.input_size == (480, 640) and nyu.num_classes == 40 and not nyu.uses_depth
    assert {f.cell for f in nyu.published} == {
        "table1/refinenet-r101/miou_nyuv2", "table1/refinenet-r101/params",
        "table1/refinenet-r101/flops", "table1/refinenet-r101/fps"}
    sun = MODEL_CARDS.get("refinenet-r101.sunrgbd")
    assert sun.num_classes == 37 and sun.input_size == (480, 640)
    assert [f.cell for f in sun.published] == ["table1/refinenet-r101/miou_sunrgbd"]


def test_parameter_count_is_the_official_code(segmenter):
    module = segmenter.module
    assert isinstance(module, RefineNet)
    assert sum(p.numel() for p in module.parameters()) == PARAMS_NYUV2
    sun = SEGMENTERS.create("refinenet-r101", dataset="sunrgbd")
    assert sum(p.numel() for p in sun.module.parameters()) == PARAMS_NYUV2 - 3 * HEAD_PER_CLASS


def test_encoder_has_torchvision_resnet101_names(segmenter):
    keys = set(segmenter.module.encoder.state_dict())
    assert keys == torchvision_resnet_keys((3, 4, 23, 3))
    assert segmenter.module.encoder.channels == (256, 512, 1024, 2048)


def test_complexity_code_path(segmenter):
    require_module("fvcore.nn")
    record = measure_complexity(segmenter.module, segmenter.example_inputs(*SMALL))
    assert record.params == PARAMS_NYUV2
    assert (record.height, record.width) == SMALL
    # convolutions are nearly all the cost (pooling, additions and resizes are the rest)
    assert 0.95 * record.flops < record.conv_macs <= record.flops


def test_eval_output_is_quarter_resolution_logits(segmenter):
    module = segmenter.module.eval()
    with torch.no_grad():
        out = module(*segmenter.example_inputs(*SMALL))
    assert out.shape == (1, 40, SMALL[0] // 4, SMALL[1] // 4)
    assert torch.isfinite(out).all()


def test_every_path_reaches_the_output():
    """Zeroing one refinement path's output chain changes the logits: forward uses all four."""
    torch.manual_seed(2)
    net = refinenet_r101(num_classes=5).eval()
    x = torch.randn(1, 3, *SMALL)
    with torch.no_grad():
        base = net(x)
        for name in ("path1", "path2", "path3", "path4"):
            conv = getattr(net, name).refine[-1].conv_b
            saved = conv.weight.clone()
            conv.weight.mul_(10.0)
            assert not torch.allclose(net(x), base), name
            conv.weight.copy_(saved)


def test_residual_conv_unit_skip():
    unit = ResidualConvUnit(channels=4)
    torch.nn.init.zeros_(unit.conv_b.weight)  # the residual branch gives zero
    x = torch.randn(1, 4, 5, 5)
    with torch.no_grad():
        assert torch.equal(unit(x), x)  # RefineNet adds the input itself
        unit.residual_after_relu = True
        assert torch.equal(unit(x), torch.relu(x))  # RDFNet's in-place ReLU adds relu(x)


def test_chained_residual_pooling_sums_the_chain():
    crp = ChainedResidualPooling(channels=1, stages=2)
    for conv in crp.convs:  # identity convolutions: each stage max-pools the previous one
        torch.nn.init.zeros_(conv.weight)
        conv.weight.data[0, 0, 1, 1] = 1.0
    x = torch.zeros(1, 1, 9, 9)
    x[0, 0, 4, 4] = 1.0
    with torch.no_grad():
        out = crp(x)
    # stage 1 spreads the peak over 5x5, stage 2 over 9x9: centre 3, the 5x5 ring 2, the rest 1
    assert out[0, 0, 4, 4] == 3.0 and out[0, 0, 2, 2] == 2.0 and out[0, 0, 0, 0] == 1.0


@pytest.mark.slow
def test_onnx_matches_torch(segmenter, tmp_path):
    ort = require_module("onnxruntime")
    module = segmenter.module.eval()
    inputs = segmenter.example_inputs(*SMALL)
    path = export_onnx(module, inputs, ("rgb",), tmp_path / "refinenet.onnx")
    with torch.no_grad():
        expected = module(*inputs).numpy()
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    got = session.run(None, {"rgb": inputs[0].numpy()})[0]
    assert got.shape == expected.shape
    scale = float(np.abs(expected).max())
    assert scale > 0
    assert float(np.abs(got - expected).max()) <= ONNX_TOLERANCE * scale
