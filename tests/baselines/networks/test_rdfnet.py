"""RDFNet-R101 (baselines.networks.rdfnet): registration, the parameter count of the PyTorch port
ESANet timed, the encoders' names, the fusion blocks, outputs and ONNX export."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from baselines.networks._rdfnet_net import (
    MultiModalFusion,
    MultiResolutionFusion,
    RDFNet,
)
from evsmap.errors import UnknownNameError
from evsmap.measure.complexity import measure_complexity
from evsmap.models.onnx_export import export_onnx
from evsmap.registry import SEGMENTERS
from evsmap.segmenters.model_card import MODEL_CARDS
from evsmap.testing import require_module

# Counted by instantiating charlesCXK/PyTorch_Semantic_Segmentation RDFNet_PyTorch/rdfnet.py
# RDF(input_size=480, num_classes=40) @ da45973 (Table I prints 443.8 M).
PARAMS_NYUV2 = 358_622_888
PAPER_PARAMS_M = 443.8
SMALL = (64, 128)  # 1/32 map of 2x4
#: ONNX Runtime vs torch: largest difference relative to the largest logit (untrained, the
#: encoders' activations reach ~1e5, so an absolute tolerance would measure the weights).
ONNX_TOLERANCE = 1e-5


@pytest.fixture(scope="module")
def segmenter():
    torch.manual_seed(0)
    return SEGMENTERS.create("rdfnet-r101")


@pytest.fixture(scope="module")
def net(segmenter) -> RDFNet:
    return segmenter.module.eval()


def _inputs(height: int, width: int) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(1)
    return (torch.randn(1, 3, height, width, generator=gen),
            torch.randn(1, 3, height, width, generator=gen))


def deep_stem_resnet_keys(layers: tuple[int, int, int, int]) -> set[str]:
    """State-dict keys of a bottleneck ResNet with the three-convolution stem in timm's naming
    (``conv1.0/1/3/4/6``, ``bn1``) and torchvision's for the stages (no ``fc``)."""
    bn = ("weight", "bias", "running_mean", "running_var", "num_batches_tracked")
    keys = {"conv1.0.weight", "conv1.3.weight", "conv1.6.weight",
            *(f"conv1.{i}.{k}" for i in (1, 4) for k in bn), *(f"bn1.{k}" for k in bn)}
    for stage, blocks in enumerate(layers, start=1):
        for block in range(blocks):
            prefix = f"layer{stage}.{block}"
            for i in (1, 2, 3):
                keys |= {f"{prefix}.conv{i}.weight", *(f"{prefix}.bn{i}.{k}" for k in bn)}
            if block == 0:
                keys |= {f"{prefix}.downsample.0.weight",
                         *(f"{prefix}.downsample.1.{k}" for k in bn)}
    return keys


def test_card_is_table_i_row():
    card = MODEL_CARDS.get("rdfnet-r101.nyuv2")
    assert card.input_size == (480, 640) and card.num_classes == 40 and card.uses_depth
    assert {f.cell for f in card.published} == {
        "table1/rdfnet-r101/miou_nyuv2", "table1/rdfnet-r101/params",
        "table1/rdfnet-r101/flops", "table1/rdfnet-r101/fps"}
    with pytest.raises(UnknownNameError):
        MODEL_CARDS.get("rdfnet-r101.sunrgbd")


def test_parameter_count_is_the_port(net):
    assert sum(p.numel() for p in net.parameters()) == PARAMS_NYUV2
    # the paper's figure is not this code's: 85 M more than the port
    assert abs(PARAMS_NYUV2 / 1e6 - PAPER_PARAMS_M) > 80


def test_segmenter_reads_hha(segmenter):
    assert isinstance(segmenter.module, RDFNet) and segmenter.uses_depth
    assert type(segmenter).__name__ == "HHASegmenter"
    rgb, hha = segmenter.example_inputs(*SMALL)
    assert rgb.shape == hha.shape == (1, 3, *SMALL)


def test_encoders_have_the_deep_stem_resnet101_names(net):
    expected = deep_stem_resnet_keys((3, 4, 23, 3))
    assert set(net.rgb_encoder.state_dict()) == expected
    assert set(net.hha_encoder.state_dict()) == expected
    assert net.rgb_encoder.conv1[0].in_channels == net.hha_encoder.conv1[0].in_channels == 3
    assert net.rgb_encoder.bn1.num_features == 128  # PSPNet's stem: 64, 64, 128
    assert net.rgb_encoder.bn1.momentum == pytest.approx(0.0003)


def test_fusion_block_sizes(net):
    """MMF(c): two branches of 1x1 c->c/2, four 3x3 (c/2) convs (two with bias), 3x3 c/2->c;
    plus the 3x3 c->c residual pooling convolution."""
    assert all(isinstance(m, MultiModalFusion) for m in net.mmf)
    for c, mmf in zip((256, 512, 1024, 2048), net.mmf, strict=True):
        h = c // 2
        branch = c * h + 2 * (2 * 9 * h * h + h) + 9 * h * c
        assert sum(p.numel() for p in mmf.parameters()) == 2 * branch + 9 * c * c


def test_multi_resolution_fusion_upsamples_to_the_finest_input():
    fuse = MultiResolutionFusion(in_channels=(2, 1), out_channels=3)
    out = fuse(torch.randn(1, 2, 3, 4), torch.randn(1, 1, 6, 8))
    assert out.shape == (1, 3, 6, 8)


def test_complexity_code_path(net):
    require_module("fvcore.nn")
    record = measure_complexity(net, _inputs(*SMALL))
    assert record.params == PARAMS_NYUV2
    assert 0.95 * record.flops < record.conv_macs <= record.flops


def test_eval_output_is_full_resolution_and_uses_both_inputs(net):
    rgb, hha = _inputs(*SMALL)
    with torch.no_grad():
        out = net(rgb, hha)
        other = net(rgb, torch.zeros_like(hha))
    assert out.shape == (1, 40, *SMALL)
    assert torch.isfinite(out).all()
    assert not torch.allclose(out, other)


@pytest.mark.slow
def test_onnx_matches_torch(net, tmp_path):
    ort = require_module("onnxruntime")
    inputs = _inputs(*SMALL)
    path = export_onnx(net, inputs, ("rgb", "depth"), tmp_path / "rdfnet.onnx")
    with torch.no_grad():
        expected = net(*inputs).numpy()
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    got = session.run(None, {"rgb": inputs[0].numpy(), "depth": inputs[1].numpy()})[0]
    path.unlink()  # 1.4 GB
    assert got.shape == expected.shape
    scale = float(np.abs(expected).max())
    assert scale > 0
    assert float(np.abs(got - expected).max()) <= ONNX_TOLERANCE * scale
