"""SwiftNet-RN18 single scale (baselines.networks.swiftnet): the official parameter count, the
torchvision names of its ResNet-18 encoder, the registered segmenter and card, shapes, FLOPs
through `evsmap complexity`, ONNX Runtime equal to torch."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from baselines.backbones.resnet import resnet18
from baselines.networks._swiftnet_net import (
    SpatialPyramidPooling,
    SwiftNet,
    UpsampleBlend,
    swiftnet_rn18,
)
from evsmap.cli.main import main
from evsmap.measure import export_onnx
from evsmap.registry import SEGMENTERS
from evsmap.segmenters.model_card import MODEL_CARDS
from evsmap.testing import require_module
from tests.baselines.networks.helpers import count_params, randomise_norms

# orsic/swiftnet configs/rn18_single_scale.py: SemsegModel(resnet18(efficient=False), 19), counted
PARAMS = 11_797_071
ENCODER = 11_176_512  # torchvision's ResNet-18 (11,689,512) without its fc (513,000)
ONNX_ATOL = 1e-4  # relative to the largest logit
SMALL = (64, 128)
# the smallest size whose 1/32 map (8x16) the pyramid's grids (8, 4, 2 rows) divide: the
# TorchScript exporter takes it directly (others go through the slower dynamo exporter)
POOLABLE = (256, 512)




def _torchvision_resnet18_keys() -> list[str]:
    """torchvision's resnet18 state-dict keys without ``fc`` (its documented layout: 7x7 stem,
    four stages of two BasicBlocks, a 1x1 projection in the first block of stages 2-4)."""
    bn = ("weight", "bias", "running_mean", "running_var", "num_batches_tracked")
    keys = ["conv1.weight", *(f"bn1.{b}" for b in bn)]
    for stage in range(1, 5):
        for block in range(2):
            p = f"layer{stage}.{block}."
            keys += [p + "conv1.weight", *(p + f"bn1.{b}" for b in bn),
                     p + "conv2.weight", *(p + f"bn2.{b}" for b in bn)]
            if stage > 1 and block == 0:
                keys += [p + "downsample.0.weight", *(p + f"downsample.1.{b}" for b in bn)]
    return keys


def test_registered_segmenter_has_the_official_count() -> None:
    segmenter = SEGMENTERS.create("swiftnet-rn18")
    assert isinstance(segmenter.module, SwiftNet)
    assert count_params(segmenter.module) == PARAMS
    assert count_params(segmenter.module.backbone) == ENCODER
    assert segmenter.num_classes == 19 and not segmenter.uses_depth
    assert tuple(segmenter.default_size) == (1024, 2048)


def test_card_references_table2_and_the_official_normalisation() -> None:
    card = MODEL_CARDS.get("swiftnet-rn18.cityscapes")
    assert card.num_classes == 19 and card.input_size == (1024, 2048)
    assert [f.cell for f in card.published] == [
        "table2/swiftnet/params", "table2/swiftnet/miou_2048", "table2/swiftnet/fps_2048",
        "table2/swiftnet/fps_1024"]
    assert np.allclose(np.array(card.normalization.rgb_mean) * 255, (73.15, 82.90, 72.3))
    assert np.allclose(np.array(card.normalization.rgb_std) * 255, (47.67, 48.49, 47.73))


def test_encoder_has_torchvision_names() -> None:
    keys = [k for k in swiftnet_rn18().state_dict() if k.startswith("backbone.")]
    assert keys == ["backbone." + k for k in _torchvision_resnet18_keys()]


def test_parts_count() -> None:
    # reduce BN(512) + 512x128, three levels BN(128) + 128x42, fuse BN(254) + 254x128
    assert count_params(SpatialPyramidPooling(in_channels=512)) == (
        2 * 512 + 512 * 128 + 3 * (2 * 128 + 128 * 42) + 2 * 254 + 254 * 128)
    # skip BN(c) + cx128, blend BN(128) + 3x3 128x128
    assert count_params(UpsampleBlend(skip_channels=64)) == 2 * 64 + 64 * 128 + 256 + 9 * 128 * 128
    # classifier BN(128) + 128 x classes + bias
    assert count_params(swiftnet_rn18(num_classes=11)) == PARAMS - 8 * 129
    assert count_params(SwiftNet(num_classes=19, backbone=resnet18())) == PARAMS


def test_output_is_input_sized_logits() -> None:
    model = swiftnet_rn18(num_classes=19).eval()
    with torch.no_grad():
        assert model(torch.randn(2, 3, *SMALL)).shape == (2, 19, *SMALL)
        # sides that no stride divides: the decoder follows the skips' sizes
        assert model(torch.randn(1, 3, 70, 90)).shape == (1, 19, 70, 90)


def test_complexity_command(capsys) -> None:
    assert main(["complexity", "swiftnet-rn18", "--height", str(POOLABLE[0]), "--width",
                 str(POOLABLE[1]), "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["params"] == PARAMS
    # fvcore at 256x512; x16 at 1024x2048 (104 G, as the SwiftNet paper)
    assert record["conv_macs"] == 6_473_730_048
    assert record["flops"] == pytest.approx(6_509_210_112, rel=1e-3)
    assert set(record["uncounted_ops"]) == {"aten::add", "aten::max_pool2d"}


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_onnx_runtime_matches_torch(tmp_path) -> None:
    ort = require_module("onnxruntime")
    torch.manual_seed(0)
    model = swiftnet_rn18(num_classes=19)
    randomise_norms(model)
    rgb = torch.randn(1, 3, *POOLABLE, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        expected = model.eval()(rgb).numpy()
    assert expected.std() > 0.05
    path = export_onnx(model, (rgb,), ("rgb",), tmp_path / "swiftnet.onnx")
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    (got,) = session.run(None, {"rgb": rgb.numpy()})
    assert got.shape == (1, 19, *POOLABLE)
    scale = float(np.abs(expected).max())
    np.testing.assert_allclose(got, expected, rtol=0, atol=ONNX_ATOL * scale)
