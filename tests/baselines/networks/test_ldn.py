"""LDN121 (baselines.networks.ldn): the release's parameter counts (ImageNet-initialised, as
registered, and from scratch), the torchvision names of its DenseNet-121 encoder, the
registered segmenter and card, shapes, FLOPs through `evsmap complexity`, ONNX Runtime equal to
torch."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from baselines.networks._ldn_net import (
    LDN,
    PlainDenseLayer,
    SpatialPyramidPooling,
    UpsampleResidual,
    ldn121,
    ldn121_from_scratch,
)
from evsmap.cli.main import main
from evsmap.measure import export_onnx
from evsmap.registry import SEGMENTERS
from evsmap.segmenters.model_card import MODEL_CARDS
from evsmap.testing import require_module
from tests.baselines.networks.helpers import count_params, randomise_norms

# ivankreso/LDN models/ldn_semseg.py build(depth=121, ...), 19 classes, aux_loss=0, counted:
PARAMS = 10_314_515  # pretrained=1 (eval.py's default; the released weights; Table II 10.3 M)
PARAMS_FROM_SCRATCH = 10_232_467  # pretrained=0: no norm0, four dense layers without bottleneck
ENCODER = 6_951_808  # torchvision's DenseNet-121 features (6,953,856) without norm5 (2,048)
ONNX_ATOL = 1e-4  # relative to the largest logit
SMALL = (64, 128)
# the table's 512x1024: its 1/64 map (8x16) is divided by every pyramid grid, so the TorchScript
# exporter takes it directly (a smaller size goes through the slower dynamo exporter)
TABLE_1024 = (512, 1024)




def _torchvision_densenet121_keys() -> list[str]:
    """torchvision's densenet121 ``features`` state-dict keys without ``norm5`` (its documented
    layout: conv0/norm0 stem, blocks of 6, 12, 24, 16 layers with norm1/conv1/norm2/conv2,
    transitions with norm/conv)."""
    bn = ("weight", "bias", "running_mean", "running_var", "num_batches_tracked")
    keys = ["features.conv0.weight", *(f"features.norm0.{b}" for b in bn)]
    for block, layers in enumerate((6, 12, 24, 16), start=1):
        for layer in range(1, layers + 1):
            p = f"features.denseblock{block}.denselayer{layer}."
            keys += [*(p + f"norm1.{b}" for b in bn), p + "conv1.weight",
                     *(p + f"norm2.{b}" for b in bn), p + "conv2.weight"]
        if block < 4:
            p = f"features.transition{block}."
            keys += [*(p + f"norm.{b}" for b in bn), p + "conv.weight"]
    return keys


def test_registered_segmenter_has_the_released_count() -> None:
    segmenter = SEGMENTERS.create("ldn121")
    assert isinstance(segmenter.module, LDN)
    assert count_params(segmenter.module) == PARAMS
    assert round(PARAMS / 1e6, 1) == 10.3  # Table II prints 10.3 M
    assert count_params(segmenter.module.backbone) == ENCODER
    assert segmenter.num_classes == 19 and not segmenter.uses_depth
    assert tuple(segmenter.default_size) == (1024, 2048)


def test_from_scratch_configuration_count() -> None:
    model = ldn121_from_scratch()
    assert count_params(model) == PARAMS_FROM_SCRATCH
    # norm0 (BN 64) and the 1x1 bottlenecks of the layers fed 64, 96, 128 (block 1) and 128
    # (block 2) channels: norm1 + conv1 to 128, and norm2/conv2 over 128 instead of the input
    def saved(c: int) -> int:
        return 2 * c + c * 128 + 2 * 128 + 128 * 9 * 32 - (2 * c + c * 9 * 32)

    assert PARAMS - PARAMS_FROM_SCRATCH == 2 * 64 + saved(64) + saved(96) + 2 * saved(128)
    plain = [n for n, m in model.named_modules() if isinstance(m, PlainDenseLayer)]
    assert plain == [f"backbone.features.denseblock1.denselayer{i}" for i in (1, 2, 3)] + [
        "backbone.features.denseblock2.denselayer1"]


def test_card_references_table2_and_the_release_normalisation() -> None:
    card = MODEL_CARDS.get("ldn121.cityscapes")
    assert card.num_classes == 19 and card.input_size == (1024, 2048)
    assert [f.cell for f in card.published] == [
        "table2/ldn/params", "table2/ldn/miou_2048", "table2/ldn/fps_2048"]
    assert np.allclose(np.array(card.normalization.rgb_mean) * 255,
                       (73.45286, 83.21195, 72.78044))


def test_encoder_has_torchvision_names() -> None:
    keys = [k for k in ldn121().state_dict() if k.startswith("backbone.")]
    assert keys == ["backbone." + k for k in _torchvision_densenet121_keys()]


def test_parts_count() -> None:
    # reduce BN(1024) + 1024x512, four levels BN(512) + 512x128, fuse BN(1024) + 1024x512
    assert count_params(SpatialPyramidPooling(in_channels=1024)) == (
        2 * 1024 + 1024 * 512 + 4 * (2 * 512 + 512 * 128) + 2 * 1024 + 1024 * 512)
    # skip 1024->512, blend 512->128 then 3x3 128->256, projection of the upsampled 512->256
    block = UpsampleResidual(in_channels=512, skip_channels=1024, out_channels=256)
    assert count_params(block) == (
        2 * 1024 + 1024 * 512 + 2 * 512 + 512 * 128 + 2 * 128 + 9 * 128 * 256
        + 2 * 512 + 512 * 256)
    # the finest step: 128 wide, no bottleneck before the 3x3, no projection
    assert count_params(UpsampleResidual(in_channels=128, skip_channels=256, out_channels=128)) == (
        2 * 256 + 256 * 128 + 2 * 128 + 9 * 128 * 128)
    assert count_params(ldn121(num_classes=11)) == PARAMS - 8 * 129


def test_output_is_input_sized_logits() -> None:
    model = ldn121().eval()
    with torch.no_grad():
        assert model(torch.randn(2, 3, *SMALL)).shape == (2, 19, *SMALL)
        # sides that are not multiples of 64: the decoder follows the skips' sizes
        assert model(torch.randn(1, 3, 96, 160)).shape == (1, 19, 96, 160)
    assert all(m.momentum == 0.05 for m in model.modules()
               if isinstance(m, torch.nn.BatchNorm2d))


def test_complexity_command(capsys) -> None:
    assert main(["complexity", "ldn121", "--height", str(SMALL[0]), "--width", str(SMALL[1]),
                 "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["params"] == PARAMS
    assert record["conv_macs"] == 571_146_240  # 1024x2048: docs/baselines/ldn121.md
    assert record["flops"] == pytest.approx(577_658_880, rel=1e-3)
    assert set(record["uncounted_ops"]) == {"aten::add", "aten::avg_pool2d", "aten::max_pool2d"}


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_onnx_runtime_matches_torch(tmp_path) -> None:
    ort = require_module("onnxruntime")
    torch.manual_seed(0)
    model = ldn121()
    randomise_norms(model)
    rgb = torch.randn(1, 3, *TABLE_1024, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        expected = model.eval()(rgb).numpy()
    assert expected.std() > 0.05
    path = export_onnx(model, (rgb,), ("rgb",), tmp_path / "ldn121.onnx")
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    (got,) = session.run(None, {"rgb": rgb.numpy()})
    assert got.shape == (1, 19, *TABLE_1024)
    scale = float(np.abs(expected).max())
    np.testing.assert_allclose(got, expected, rtol=0, atol=ONNX_ATOL * scale)
