"""DABNet (baselines.networks.dabnet): the official parameter count, the registered segmenter
and card, output shapes, FLOPs through `evsmap complexity`, ONNX Runtime equal to torch."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from baselines.networks._dabnet_net import DABModule, DABNet, DownsamplingBlock, dabnet
from evsmap.cli.main import main
from evsmap.measure import export_onnx
from evsmap.registry import SEGMENTERS
from evsmap.segmenters.model_card import MODEL_CARDS
from evsmap.testing import require_module
from tests.baselines.networks.helpers import count_params, randomise_norms

PARAMS = 756_643  # Reagan1311/DABNet model/DABNet.py, DABNet(classes=19), counted
ONNX_ATOL = 1e-4  # logits of order 1 (BN statistics randomised below)
SMALL = (64, 128)




def test_registered_segmenter_has_the_official_count() -> None:
    segmenter = SEGMENTERS.create("dabnet")
    assert isinstance(segmenter.module, DABNet)
    assert count_params(segmenter.module) == PARAMS
    assert segmenter.num_classes == 19
    assert not segmenter.uses_depth
    assert tuple(segmenter.default_size) == (1024, 2048)


def test_card_references_table2() -> None:
    card = MODEL_CARDS.get("dabnet.cityscapes")
    assert card.num_classes == 19 and card.class_set == "cityscapes-19"
    assert card.input_size == (1024, 2048)
    assert [f.cell for f in card.published] == [
        "table2/dabnet/params", "table2/dabnet/miou_2048", "table2/dabnet/fps_2048",
        "table2/dabnet/fps_1024"]


def test_parts_count() -> None:
    # a DAB module of 64 channels: BN-PReLU 3*64, 3x3 64->32 + BN-PReLU 3*32, four depth-wise
    # 3-tap convs of 32 channels each with BN-PReLU, BN-PReLU 3*32, 1x1 32->64
    assert count_params(DABModule(channels=64, dilation=2)) == (
        3 * 64 + 9 * 64 * 32 + 3 * 32 + 4 * (3 * 32 + 3 * 32) + 3 * 32 + 32 * 64)
    # widening: conv makes 64 - 35 channels, max-pool passes 35
    assert count_params(DownsamplingBlock(in_channels=35, out_channels=64)) == 9 * 35 * 29 + 3 * 64
    # not widening: conv makes all 128, no pooling
    assert count_params(DownsamplingBlock(in_channels=131, out_channels=128)) == (
        9 * 131 * 128 + 3 * 128)
    assert count_params(dabnet(num_classes=11)) == PARAMS - 8 * 259


def test_parameter_names_are_the_releases() -> None:
    keys = set(dabnet().state_dict())
    # a sample of the release's state-dict keys, one per kind of module
    release = {"init_conv.0.conv.weight", "init_conv.2.bn_prelu.bn.running_var",
               "init_conv.1.bn_prelu.acti.weight", "bn_prelu_1.bn.weight",
               "downsample_1.conv3x3.conv.weight", "downsample_1.bn_prelu.acti.weight",
               "DAB_Block_1.DAB_Module_1_2.bn_relu_1.bn.bias",
               "DAB_Block_1.DAB_Module_1_0.conv3x3.bn_prelu.bn.weight",
               "DAB_Block_2.DAB_Module_2_5.ddconv1x3.conv.weight",
               "DAB_Block_2.DAB_Module_2_0.dconv3x1.bn_prelu.acti.weight",
               "DAB_Block_2.DAB_Module_2_3.bn_relu_2.bn.running_mean",
               "DAB_Block_2.DAB_Module_2_1.conv1x1.conv.weight", "downsample_2.conv3x3.conv.weight",
               "bn_prelu_3.acti.weight", "classifier.0.conv.weight"}
    assert release <= keys
    assert len(keys) == 486  # as many as the release's (BN counters included)


def test_output_is_input_sized_logits() -> None:
    model = dabnet(num_classes=19).eval()
    with torch.no_grad():
        out = model(torch.randn(2, 3, *SMALL))
    assert out.shape == (2, 19, *SMALL)
    # any multiple of 8: the injected image and the features meet at every stage
    with torch.no_grad():
        assert model(torch.randn(1, 3, 72, 104)).shape == (1, 19, 72, 104)
        # as in the official code, the max-pool of a widening downsampling (floor) and its
        # stride-2 conv (ceil) disagree on an odd size
        with pytest.raises(RuntimeError, match="Sizes of tensors must match"):
            model(torch.randn(1, 3, 70, 90))


def test_complexity_command(capsys) -> None:
    assert main(["complexity", "dabnet", "--height", str(SMALL[0]), "--width", str(SMALL[1]),
                 "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["params"] == PARAMS
    assert record["inputs"] == ["rgb"]
    # fvcore MACs at 64x128 (x256 at 1024x2048: 41.66 G; docs/baselines/dabnet.md)
    assert record["conv_macs"] == 159_693_440
    assert record["flops"] == pytest.approx(162_724_224, rel=1e-3)
    assert set(record["uncounted_ops"]) == {"aten::add", "aten::avg_pool2d",
                                            "aten::max_pool2d", "aten::prelu"}


@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_onnx_runtime_matches_torch(tmp_path) -> None:
    ort = require_module("onnxruntime")
    torch.manual_seed(0)
    model = dabnet(num_classes=19)
    randomise_norms(model)
    rgb = torch.randn(1, 3, *SMALL, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        expected = model.eval()(rgb).numpy()
    assert expected.std() > 0.05
    path = export_onnx(model, (rgb,), ("rgb",), tmp_path / "dabnet.onnx")
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    (got,) = session.run(None, {"rgb": rgb.numpy()})
    assert got.shape == (1, 19, *SMALL)
    np.testing.assert_allclose(got, expected, rtol=0, atol=ONNX_ATOL)
