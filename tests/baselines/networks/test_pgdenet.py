"""PGDENet-R34 (baselines.networks.pgdenet_r34): the official parameter count of what the
forward pass uses, the registered segmenter and its cards, the parts, the encoders' torchvision
names, output shapes, FLOPs through `evsmap complexity`, and ONNX Runtime equal to torch."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from baselines.networks._pgdenet_r34_net import (
    DecoderStep,
    DepthEnhancement,
    GlobalContext,
    GuidedFusion,
    PGDENet,
    TopFusion,
    pgdenet_r34,
)
from evsmap.cli.main import main
from evsmap.measure import export_onnx
from evsmap.registry import SEGMENTERS
from evsmap.segmenters.model_card import MODEL_CARDS
from evsmap.testing import require_module
from tests.baselines.networks.helpers import count_params, randomise_norms

# EnquanYang2022/PGDENet toolbox/models/BBSnetmodel/BBSnet.py, BBSNet(n_class=41): 107,402,898
# in all, of which the eval forward pass uses 100,691,630
PARAMS = 100_691_630
PARAMS_OFFICIAL_ALL = 107_402_898
ONNX_ATOL = 1e-4  # logits of order 1 (BN statistics randomised below)
SMALL = (64, 128)
# fvcore at 64x128: conv MACs and the total (conv, BN, pooling, upsampling)
CONV_MACS_SMALL = 4_337_594_368
FLOPS_SMALL = 4_350_186_496



def _inputs(height: int, width: int, batch: int = 1, seed: int = 1):
    gen = torch.Generator().manual_seed(seed)
    return (torch.randn(batch, 3, height, width, generator=gen),
            torch.randn(batch, 1, height, width, generator=gen))



@pytest.fixture(scope="module")
def model() -> PGDENet:
    torch.manual_seed(0)
    return pgdenet_r34(num_classes=41).eval()


# --------------------------------------------------------------------------------------------
# sizes and registration
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("dataset", "classes"), [("nyuv2", 41), ("sunrgbd", 38)])
def test_registered_segmenter_has_the_official_count(dataset: str, classes: int) -> None:
    segmenter = SEGMENTERS.create("pgdenet-r34", dataset=dataset)
    assert isinstance(segmenter.module, PGDENet)
    # the 1x1 classifier has 64 weights and a bias per class
    assert count_params(segmenter.module) == PARAMS - (41 - classes) * 65
    assert segmenter.num_classes == classes and segmenter.uses_depth
    assert segmenter.class_names[0] == "void" and len(segmenter.class_names) == classes


def test_card_references_table1() -> None:
    card = MODEL_CARDS.get("pgdenet-r34.nyuv2")
    assert card.num_classes == 41 and card.class_set == "nyuv2-40"
    assert card.input_size == (480, 640) and card.uses_depth
    assert [f.cell for f in card.published] == [
        "table1/pgdenet-r34/miou_nyuv2", "table1/pgdenet-r34/params",
        "table1/pgdenet-r34/flops", "table1/pgdenet-r34/fps"]
    sun = MODEL_CARDS.get("pgdenet-r34.sunrgbd")
    assert [f.cell for f in sun.published] == ["table1/pgdenet-r34/miou_sunrgbd"]


def test_left_out_modules_account_for_the_official_total() -> None:
    # per DA module of C channels: conv1 (3x3, 2C -> C, BN), conv2 (1x1 with bias), bn1
    unused_da = sum(18 * c * c + 2 * c + c * c + c + 2 * c for c in (64, 64, 128, 256, 512))
    aux_heads = (128 + 1) * 41 + 3 * (64 + 1) * 41  # conv_aux1..4
    assert PARAMS + unused_da + aux_heads == PARAMS_OFFICIAL_ALL


def test_parts_count() -> None:
    c = 64
    bcr = 2 * c  # a conv-BN-ReLU's BN
    # DA: ER (three 3x3 CxC + BN, 3x3 3C -> C, 1x1), 3x3 conv with bias, gate C -> C/16 -> C
    assert count_params(DepthEnhancement(c)) == (
        3 * (9 * c * c + bcr) + 27 * c * c + bcr + c * c + bcr + 9 * c * c + c
        + c * 4 + 4 + 4 * c + c)
    # GCM: 1x1; 1x1 + 3x3; 1x1 + 5x5; 1x1; 3x3 4C -> C (all conv-BN-ReLU)
    gcm = 4 * c * c + 9 * c * c + 25 * c * c + 36 * c * c + 7 * bcr
    assert count_params(GlobalContext(c)) == gcm
    cross = 4 * (3 * c * c + bcr) + 9 * c + 1
    assert count_params(TopFusion(c)) == cross + 2 * c * c + c + gcm
    # guided: + 1x1 aux (2C -> C), two 3x3 gates, 3x3 projection of the 128-channel guide
    assert count_params(GuidedFusion(128, c)) == (
        cross + 2 * (2 * c * c + c) + 2 * (9 * c * c + c) + 9 * 128 * c + c + gcm)
    assert count_params(DecoderStep(128, 64)) == 9 * 128 * 128 + 2 * 128 + 128 * 64 + 2 * 64


def test_encoders_have_torchvision_resnet34_names(model: PGDENet) -> None:
    keys = set(model.encoder_rgb.state_dict())
    expected = {"conv1.weight", *(f"bn1.{s}" for s in _BN)}
    stages = zip((3, 4, 6, 3), (64, 128, 256, 512), strict=True)
    for layer, (blocks, width) in enumerate(stages, start=1):
        for block in range(blocks):
            prefix = f"layer{layer}.{block}"
            expected |= {f"{prefix}.conv1.weight", f"{prefix}.conv2.weight"}
            expected |= {f"{prefix}.bn{i}.{s}" for i in (1, 2) for s in _BN}
            if block == 0 and layer > 1:
                expected |= {f"{prefix}.downsample.0.weight",
                             *(f"{prefix}.downsample.1.{s}" for s in _BN)}
        assert model.encoder_rgb.state_dict()[f"layer{layer}.0.conv2.weight"].shape[0] == width
    assert keys == expected
    assert set(model.encoder_depth.state_dict()) == expected
    assert model.encoder_depth.conv1.weight.shape == (64, 1, 7, 7)


_BN = ("weight", "bias", "running_mean", "running_var", "num_batches_tracked")


# --------------------------------------------------------------------------------------------
# behaviour
# --------------------------------------------------------------------------------------------


def test_depth_enhancement_by_hand() -> None:
    torch.manual_seed(0)
    module = DepthEnhancement(32).eval()
    rgb, depth = torch.randn(2, 32, 8, 12), torch.randn(2, 32, 8, 12)
    with torch.no_grad():
        r1 = module.conv(module.refine(rgb))
        gate = module.gate(rgb.mean(dim=(2, 3)))[:, :, None, None]
        expected = depth + r1 * torch.sigmoid(r1 - (gate * depth + depth))
        torch.testing.assert_close(module(rgb, depth), expected)


def test_output_is_input_sized_logits(model: PGDENet) -> None:
    with torch.no_grad():
        out = model(*_inputs(*SMALL, batch=2))
    assert out.shape == (2, 41, *SMALL) and torch.isfinite(out).all()
    with pytest.raises(ValueError, match="divisible by 32"):
        model(*_inputs(64, 120))


def test_complexity_command(capsys) -> None:
    assert main(["complexity", "pgdenet-r34", "--height", str(SMALL[0]), "--width",
                 str(SMALL[1]), "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["params"] == PARAMS
    assert record["inputs"] == ["rgb", "depth"]
    # fvcore MACs at 64x128 (178.8 G in the paper at 480x640; docs/baselines/pgdenet-r34.md)
    assert record["conv_macs"] == CONV_MACS_SMALL
    assert record["flops"] == pytest.approx(FLOPS_SMALL, rel=1e-3)
    assert {"aten::add", "aten::mul", "aten::sigmoid"} <= set(record["uncounted_ops"])


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_onnx_runtime_matches_torch(tmp_path) -> None:
    ort = require_module("onnxruntime")
    torch.manual_seed(0)
    net = pgdenet_r34(num_classes=41)
    randomise_norms(net)
    rgb, depth = _inputs(*SMALL)
    with torch.no_grad():
        expected = net.eval()(rgb, depth).numpy()
    assert expected.std() > 0.05
    path = export_onnx(net, (rgb, depth), ("rgb", "depth"), tmp_path / "pgdenet.onnx")
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    (got,) = session.run(None, {"rgb": rgb.numpy(), "depth": depth.numpy()})
    assert got.shape == (1, 41, *SMALL)
    np.testing.assert_allclose(got, expected, rtol=0, atol=ONNX_ATOL)
