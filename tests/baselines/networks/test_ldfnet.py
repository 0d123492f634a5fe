"""LDFNet (baselines.networks.ldfnet): registration, parameter count of Table II, the
depth-and-luminance input, outputs and ONNX export."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from baselines.networks._ldfnet_net import LDFNet, ldfnet
from evsmap.measure.complexity import measure_complexity
from evsmap.models.onnx_export import export_onnx
from evsmap.registry import SEGMENTERS
from evsmap.segmenters.model_card import MODEL_CARDS
from evsmap.testing import require_module

# Counted by instantiating the release's Net(19) (shangweihung/LDFNet @ e918e93).
PARAMS = 2_415_760
ENCODER_ONLY_HEAD = 128 * 19 + 19  # encoder_output_conv, the first training stage's classifier
SMALL = (64, 128)
ONNX_TOLERANCE = 1e-5  # relative to the largest logit


@pytest.fixture(scope="module")
def segmenter():
    torch.manual_seed(0)
    seg = SEGMENTERS.create("ldfnet")
    gen = torch.Generator().manual_seed(3)
    with torch.no_grad():  # non-trivial batch-norm statistics: eval mode matters
        for m in seg.module.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.copy_(torch.randn(m.num_features, generator=gen) * 0.1)
                m.running_var.copy_(torch.rand(m.num_features, generator=gen) + 0.5)
    return seg


def test_card_is_table_ii_row():
    card = MODEL_CARDS.get("ldfnet.cityscapes")
    assert card.input_size == (1024, 2048)
    assert card.num_classes == 19 and card.uses_depth
    assert {f.cell for f in card.published} == {"table2/ldfnet/params",
                                                "table2/ldfnet/miou_1024"}
    norm = card.normalization
    assert norm.rgb_mean == (0.0, 0.0, 0.0) and norm.rgb_std == (1.0, 1.0, 1.0)
    assert norm.depth_encoding == "cityscapes-disparity"
    assert (norm.depth_mean, norm.depth_std) == (0.0, 100.0)


def test_parameter_count_is_table_ii(segmenter):
    module = segmenter.module
    assert isinstance(module, LDFNet)
    assert sum(p.numel() for p in module.parameters()) == PARAMS
    assert sum(p.numel() for p in module.encoder_output_conv.parameters()) == ENCODER_ONLY_HEAD


def test_complexity_code_path(segmenter):
    record = measure_complexity(segmenter.module, segmenter.example_inputs(*SMALL))
    assert record.params == PARAMS
    assert (record.height, record.width) == SMALL
    assert 0.8 * record.flops < record.conv_macs <= record.flops


def test_eval_output_is_full_resolution_logits(segmenter):
    module = segmenter.module.eval()
    with torch.no_grad():
        out = module(*segmenter.example_inputs(*SMALL))
        encoder_only = module(*segmenter.example_inputs(*SMALL), only_encoder=True)
    assert out.shape == (1, 19, *SMALL)
    assert encoder_only.shape == (1, 19, SMALL[0] // 8, SMALL[1] // 8)
    assert torch.isfinite(out).all()


def test_depth_changes_the_output(segmenter):
    module = segmenter.module.eval()
    rgb, depth = segmenter.example_inputs(*SMALL)
    with torch.no_grad():
        assert not torch.allclose(module(rgb, depth), module(rgb, depth + 1.0))


def test_dy_encoder_reads_depth_then_pil_luminance():
    pil = require_module("PIL.Image")
    image = np.random.default_rng(0).integers(0, 256, (16, 24, 3), dtype=np.uint8)
    expected = np.asarray(pil.fromarray(image).convert("L"), dtype=np.float32) / 255.0
    net = ldfnet(num_classes=19).eval()
    seen: list[torch.Tensor] = []
    net.encoder.downsampling_1.register_forward_pre_hook(lambda _m, args: seen.append(args[0]))
    rgb = torch.from_numpy(image).permute(2, 0, 1)[None].float() / 255.0
    depth = torch.full((1, 1, 16, 24), 0.25)
    with torch.no_grad():
        net(rgb, depth)
    (dy,) = seen
    assert dy.shape == (1, 2, 16, 24)
    assert torch.equal(dy[:, :1], depth)
    np.testing.assert_allclose(dy[0, 1].numpy(), expected, atol=1 / 255 + 1e-6)


def test_classes_change_only_the_two_classifiers():
    nine = ldfnet(num_classes=9)
    # output_conv: ConvTranspose2d(16, C, 2) and encoder_output_conv: Conv2d(128, C, 1)
    assert sum(p.numel() for p in nine.parameters()) == PARAMS - 10 * (16 * 4 + 1 + 128 + 1)


@pytest.mark.slow
def test_onnx_matches_torch(tmp_path, segmenter):
    ort = require_module("onnxruntime")
    module = segmenter.module.eval()
    inputs = segmenter.example_inputs(*SMALL)
    path = export_onnx(module, inputs, segmenter.input_names, tmp_path / "ldfnet.onnx")
    with torch.no_grad():
        expected = module(*inputs).numpy()
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    got = session.run(None, {n: t.numpy() for n, t in zip(segmenter.input_names, inputs,
                                                            strict=True)})[0]
    assert got.shape == expected.shape
    scale = float(np.abs(expected).max())
    assert scale > 0
    np.testing.assert_allclose(got, expected, rtol=0, atol=ONNX_TOLERANCE * scale)
