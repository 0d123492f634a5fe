"""SSMA (baselines.networks.ssma): registration, parameter count against the README's 56.44 M,
TensorFlow SAME padding, the jet-coloured depth input, outputs and ONNX export."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from baselines.networks._ssma_net import (
    SSMA,
    AdapNetPPEncoder,
    SameConv2d,
    _same_padding,
    jet_bgr,
    ssma,
)
from evsmap.measure.complexity import measure_complexity
from evsmap.models.onnx_export import export_onnx
from evsmap.registry import SEGMENTERS
from evsmap.segmenters.model_card import MODEL_CARDS
from evsmap.testing import require_module

# Counted from the release's variable shapes (models/SSMA.py, ssma_helper.py, network_base.py;
# gammas, betas, kernels and biases; DeepSceneSeg/SSMA @ 7066905), 19 classes.
PARAMS = 56_198_136
EXPERT = 25_562_918  # one AdapNet++ encoder with eASPP
README_PARAMS = 56.44e6
SMALL = (64, 128)  # 1/16 map of 4x8
ONNX_TOLERANCE = 1e-5  # relative to the largest logit


def _calibrate(module: torch.nn.Module) -> None:
    """Batch-norm statistics of a trained network's magnitude: the input batch norms see
    0-255 images, the others random statistics, so activations neither vanish nor explode."""
    gen = torch.Generator().manual_seed(3)
    with torch.no_grad():
        for m in module.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.copy_(torch.randn(m.num_features, generator=gen) * 0.1)
                m.running_var.copy_(torch.rand(m.num_features, generator=gen) * 2 + 1)
        for encoder in (module.rgb_encoder, module.depth_encoder):
            encoder.input_bn.running_mean.fill_(128.0)
            encoder.input_bn.running_var.fill_(64.0 ** 2)


@pytest.fixture(scope="module")
def segmenter():
    torch.manual_seed(0)
    seg = SEGMENTERS.create("ssma")
    _calibrate(seg.module)
    return seg


def _inputs(height: int, width: int) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(1)
    return (torch.rand(1, 3, height, width, generator=gen) * 255,
            torch.rand(1, 1, height, width, generator=gen))


def test_card_is_table_ii_row():
    card = MODEL_CARDS.get("ssma.cityscapes")
    assert card.input_size == (1024, 2048)
    assert card.num_classes == 19 and card.uses_depth
    assert {f.cell for f in card.published} == {"table2/ssma/params", "table2/ssma/miou_2048"}
    norm = card.normalization
    assert norm.rgb_mean == (0.0, 0.0, 0.0)
    assert np.allclose(np.array(norm.rgb_std) * 255, 1.0)  # 0-255 images, as the release
    assert norm.depth_encoding == "cityscapes-disparity"
    assert norm.depth_std == 256 * 128  # disparity of 128 px -> top of the jet map


def test_parameter_count_within_one_percent_of_readme(segmenter):
    module = segmenter.module
    assert isinstance(module, SSMA)
    total = sum(p.numel() for p in module.parameters())
    assert total == PARAMS
    assert abs(total - README_PARAMS) / README_PARAMS < 0.01
    assert sum(p.numel() for p in module.rgb_encoder.parameters()) == EXPERT
    assert sum(p.numel() for p in AdapNetPPEncoder().parameters()) == EXPERT


def test_classes_change_only_the_last_layers():
    # conv78 (1x1, 256 -> C, BN) and the x4 transposed convolution (8x8, C -> C, BN)
    def head(c: int) -> int:
        return 256 * c + 2 * c + 64 * c * c + 2 * c

    twelve = ssma(num_classes=12)
    assert sum(p.numel() for p in twelve.parameters()) == PARAMS - head(19) + head(12)


def test_complexity_code_path(segmenter):
    record = measure_complexity(segmenter.module, segmenter.example_inputs(*SMALL))
    assert record.params == PARAMS
    assert (record.height, record.width) == SMALL
    assert 0.95 * record.flops < record.conv_macs <= record.flops


def test_eval_output_is_full_resolution_logits(segmenter):
    module = segmenter.module.eval()
    with torch.no_grad():
        out = module(*_inputs(*SMALL))
    assert out.shape == (1, 19, *SMALL)
    assert torch.isfinite(out).all() and out.abs().max() > 0


def test_depth_and_colour_order_reach_the_output(segmenter):
    module = segmenter.module.eval()
    rgb, depth = _inputs(*SMALL)
    with torch.no_grad():
        base = module(rgb, depth)
        assert not torch.allclose(module(rgb, (depth + 0.3) % 1.0), base)
        assert not torch.allclose(module(rgb.flip(1), depth), base)


@pytest.mark.parametrize(("size", "kernel", "stride", "expected"), [
    (64, 3, 2, (0, 1)),   # TensorFlow pads the extra row at the bottom
    (64, 7, 2, (2, 3)),
    (65, 3, 2, (1, 1)),
    (64, 1, 2, (0, 0)),
    (64, 3, 1, (1, 1)),
])
def test_same_padding_is_tensorflows(size, kernel, stride, expected):
    assert _same_padding(size, kernel, stride, 1) == expected


def test_strided_same_conv_pads_bottom_right():
    conv = SameConv2d(1, 1, 3, stride=2)
    with torch.no_grad():
        conv.weight.fill_(1.0)
    x = torch.arange(16.0).view(1, 1, 4, 4)
    out = conv(x)
    assert out.shape == (1, 1, 2, 2)
    # top-left output: rows 0-2, columns 0-2, no padding above or left
    assert out[0, 0, 0, 0] == x[0, 0, :3, :3].sum()
    # bottom-right: rows 2-3 and columns 2-3 plus zero padding
    assert out[0, 0, 1, 1] == x[0, 0, 2:, 2:].sum()


def test_jet_colour_map():
    values = torch.tensor([0.0, 0.125, 0.375, 0.5, 0.625, 0.875, 1.0, -1.0, 2.0])
    bgr = jet_bgr(values.view(1, 1, 1, -1))[0, :, 0].T / 255
    expected = torch.tensor([
        [0.5, 0.0, 0.0],    # dark blue (invalid, far)
        [1.0, 0.0, 0.0],    # blue
        [1.0, 1.0, 0.0],    # cyan (B, G)
        [0.5, 1.0, 0.5],    # green
        [0.0, 1.0, 1.0],    # yellow (G, R)
        [0.0, 0.0, 1.0],    # red (near)
        [0.0, 0.0, 0.5],    # dark red
        [0.5, 0.0, 0.0],    # clipped below
        [0.0, 0.0, 0.5],    # clipped above
    ])
    torch.testing.assert_close(bgr, expected)


@pytest.mark.slow
def test_onnx_matches_torch(tmp_path, segmenter):
    ort = require_module("onnxruntime")
    module = segmenter.module.eval()
    inputs = _inputs(*SMALL)
    path = export_onnx(module, inputs, segmenter.input_names, tmp_path / "ssma.onnx")
    with torch.no_grad():
        expected = module(*inputs).numpy()
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    got = session.run(None, {n: t.numpy() for n, t in zip(segmenter.input_names, inputs,
                                                            strict=True)})[0]
    assert got.shape == expected.shape
    scale = float(np.abs(expected).max())
    assert scale > 0
    np.testing.assert_allclose(got, expected, rtol=0, atol=ONNX_TOLERANCE * scale)
