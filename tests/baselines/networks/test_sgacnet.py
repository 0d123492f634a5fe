"""SGACNet-R34 (baselines.networks.sgacnet_r34): the official parameter counts, the registered
segmenter and its cards, the parts, output shapes, FLOPs through `evsmap complexity`, and ONNX
Runtime equal to torch."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from baselines.esanet import ResNet34NBt1DEncoder
from baselines.networks._sgacnet_r34_net import (
    BRUBlock,
    SGACFusion,
    SGACNet,
    SpatialPyramidAttention,
    adaptive_avg_pool,
    sgacnet_r34,
)
from evsmap.cli.main import main
from evsmap.errors import UnknownNameError
from evsmap.measure import export_onnx
from evsmap.registry import SEGMENTERS
from evsmap.segmenters.model_card import MODEL_CARDS
from evsmap.testing import require_module
from tests.baselines.networks.helpers import count_params, randomise_norms

# CyunXiong/SGACNet src/models/model.py, ResNet-34 NBt1D encoders restored, counted
PARAMS_NYUV2 = 35_650_321
PARAMS_CITYSCAPES = 35_607_229
# one class more or less: 3x3 classifier (128*9 + 1) and the three 1x1 side outputs
# (512 + 256 + 128 + 3)
PER_CLASS = 128 * 9 + 1 + 512 + 256 + 128 + 3
ONNX_ATOL = 1e-4  # logits of order 1 (BN statistics randomised below)
SMALL = (64, 128)
# fvcore at 64x128 (NYUv2 card): conv MACs and the total (conv, BN, pooling, upsampling)
CONV_MACS_SMALL = 997_570_176
FLOPS_SMALL = 1_004_628_736



def _inputs(height: int, width: int, batch: int = 1, seed: int = 1):
    gen = torch.Generator().manual_seed(seed)
    return (torch.randn(batch, 3, height, width, generator=gen),
            torch.randn(batch, 1, height, width, generator=gen))



# --------------------------------------------------------------------------------------------
# sizes and registration
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("dataset", "classes", "expected", "bins", "train_map"), [
    ("nyuv2", 40, PARAMS_NYUV2, (1, 5), (15, 20)),
    ("sunrgbd", 37, PARAMS_NYUV2 - 3 * PER_CLASS, (1, 5), (15, 20)),
    ("cityscapes", 19, PARAMS_CITYSCAPES, (1, 2, 4, 8), (16, 32)),
])
def test_registered_segmenter_has_the_official_count(dataset, classes, expected, bins,
                                                      train_map) -> None:
    segmenter = SEGMENTERS.create("sgacnet-r34", dataset=dataset)
    module = segmenter.module
    assert isinstance(module, SGACNet)
    assert count_params(module) == expected
    assert segmenter.num_classes == classes and segmenter.uses_depth
    # the context module of the dataset's official training script
    assert module.context.bins == bins and module.context.train_size == train_map


def test_counts_differ_by_the_classifiers_only() -> None:
    assert PARAMS_NYUV2 - PARAMS_CITYSCAPES == 21 * PER_CLASS


def test_cards_reference_tables_1_and_2() -> None:
    nyu = MODEL_CARDS.get("sgacnet-r34.nyuv2")
    assert nyu.input_size == (480, 640) and nyu.num_classes == 40 and nyu.uses_depth
    assert [f.cell for f in nyu.published] == [
        "table1/sgacnet-r34/miou_nyuv2", "table1/sgacnet-r34/params",
        "table1/sgacnet-r34/flops", "table1/sgacnet-r34/fps"]
    sun = MODEL_CARDS.get("sgacnet-r34.sunrgbd")
    assert [f.cell for f in sun.published] == ["table1/sgacnet-r34/miou_sunrgbd"]
    city = MODEL_CARDS.get("sgacnet-r34.cityscapes")
    assert city.input_size == (512, 1024) and city.class_set == "cityscapes-19"
    assert {f.cell for f in city.published} == {
        f"table2/sgacnet-r34/{c}" for c in ("miou_1024", "fps_1024", "miou_2048", "fps_2048",
                                            "params")}


def test_unknown_dataset_is_a_user_error() -> None:
    with pytest.raises(UnknownNameError, match="kitti"):
        sgacnet_r34(num_classes=10, dataset="kitti")


def test_parts_count() -> None:
    # SPA of 64 channels: 3 level weights, 1x1 64->4 and 4->64 without bias, BN(4)
    assert count_params(SpatialPyramidAttention(64)) == 3 + 64 * 4 + 2 * 4 + 4 * 64
    # fusion: the SE of the RGB branch (1x1 convs with bias) and the SPA of the depth branch
    assert count_params(SGACFusion(64)) == (64 * 4 + 4 + 4 * 64 + 64) + (3 + 2 * 64 * 4 + 8)
    # BRU of 128 channels: BN-PReLU(128), 1x1 128->64 + BN-PReLU(64), two branches of four
    # depthwise 3-tap convs with BN-PReLU(64) and a 9-tap ECA, BN-PReLU(64), 1x1 64->128
    assert count_params(BRUBlock(128)) == (
        3 * 128 + 128 * 64 + 3 * 64 + 2 * (4 * (3 * 64 + 3 * 64) + 9) + 3 * 64 + 64 * 128)
    # the encoders are ESANet's ResNet-34 NBt1D ones
    model = sgacnet_r34(num_classes=40)
    assert isinstance(model.encoder_rgb, ResNet34NBt1DEncoder)
    assert count_params(model.encoder_depth) == count_params(model.encoder_rgb) - 7 * 7 * 2 * 64


# --------------------------------------------------------------------------------------------
# behaviour
# --------------------------------------------------------------------------------------------


def test_spatial_pyramid_attention_by_hand() -> None:
    torch.manual_seed(0)
    spa = SpatialPyramidAttention(32).eval()
    with torch.no_grad():
        spa.level_weights.copy_(torch.tensor([0.5, 2.0, -1.0]))
        x = torch.randn(2, 32, 21, 30)
        grid = (7, 7)
        mixed = (0.5 * F.adaptive_avg_pool2d(x, 7)
                 + 2.0 * F.interpolate(F.adaptive_avg_pool2d(x, 4), size=grid)
                 - 1.0 * F.interpolate(F.adaptive_avg_pool2d(x, 1), size=grid))
        expected = x * F.interpolate(spa.transform(mixed), size=(21, 30))
        torch.testing.assert_close(spa(x), expected)


def test_bru_block_shuffles_channel_pairs() -> None:
    block = BRUBlock(8).eval()
    with torch.no_grad():
        block.expand.weight.zero_()  # the residual branch adds nothing: output = shuffle(x)
        x = torch.arange(8.0).view(1, 8, 1, 1).expand(1, 8, 2, 3)
        out = block(x)
    # 4 groups of 2 channels: [0 1 | 2 3 | 4 5 | 6 7] -> [0 2 4 6 1 3 5 7]
    assert out[0, :, 0, 0].tolist() == [0, 2, 4, 6, 1, 3, 5, 7]


def test_export_pooling_equals_adaptive_pooling(monkeypatch) -> None:
    x = torch.randn(1, 3, 30, 40)
    monkeypatch.setattr(torch.onnx, "is_in_onnx_export", lambda: True)
    for size in ((7, 7), (4, 4), (3, 6)):
        torch.testing.assert_close(adaptive_avg_pool(x, size), F.adaptive_avg_pool2d(x, size))


def test_eval_output_is_input_sized_logits() -> None:
    model = sgacnet_r34(num_classes=40).eval()
    with torch.no_grad():
        out = model(*_inputs(*SMALL, batch=2))
    assert out.shape == (2, 40, *SMALL) and torch.isfinite(out).all()
    with pytest.raises(ValueError, match="divisible by 32"):
        model(*_inputs(60, 128))


def test_train_mode_returns_side_outputs_and_backprops() -> None:
    torch.manual_seed(0)
    model = sgacnet_r34(num_classes=19, dataset="cityscapes").train()
    height, width = SMALL
    outs = model(*_inputs(height, width, batch=2))
    assert isinstance(outs, tuple) and len(outs) == 4
    expected = [(height, width)] + [(height // s, width // s) for s in (8, 16, 32)]
    assert [tuple(o.shape) for o in outs] == [(2, 19, h, w) for h, w in expected]
    sum(o.mean() for o in outs).backward()
    assert all(m.side_output.weight.grad is not None for m in model.decoder)
    assert model.fusions[0].spa_depth.level_weights.grad is not None


def test_complexity_command(capsys) -> None:
    assert main(["complexity", "sgacnet-r34", "--height", str(SMALL[0]), "--width",
                 str(SMALL[1]), "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["params"] == PARAMS_NYUV2
    assert record["inputs"] == ["rgb", "depth"]
    # fvcore MACs at 64x128 (37.6 G in the paper at 480x640; docs/baselines/sgacnet-r34.md)
    assert record["conv_macs"] == CONV_MACS_SMALL
    assert record["flops"] == pytest.approx(FLOPS_SMALL, rel=1e-3)
    assert {"aten::add", "aten::mul", "aten::sigmoid"} <= set(record["uncounted_ops"])


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_onnx_runtime_matches_torch(tmp_path) -> None:
    ort = require_module("onnxruntime")
    torch.manual_seed(0)
    model = sgacnet_r34(num_classes=40)
    randomise_norms(model)
    rgb, depth = _inputs(*SMALL)
    with torch.no_grad():
        expected = model.eval()(rgb, depth).numpy()
    assert expected.std() > 0.05
    path = export_onnx(model, (rgb, depth), ("rgb", "depth"), tmp_path / "sgacnet.onnx")
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    (got,) = session.run(None, {"rgb": rgb.numpy(), "depth": depth.numpy()})
    assert got.shape == (1, 40, *SMALL)
    np.testing.assert_allclose(got, expected, rtol=0, atol=ONNX_ATOL)
