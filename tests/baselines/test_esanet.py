"""ESANet-R34-NBt1D (baselines.esanet): sizes, FLOPs, outputs and ONNX export."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from baselines.esanet import (
    AdaptivePyramidPooling,
    ESANet,
    LearnedUpsample2x,
    NonBottleneck1D,
    esanet_r34_nbt1d,
)
from evsmap.errors import UnknownNameError
from evsmap.testing import require_module

# Reference figures (shared/reference/segmentation.md, "ESANet-R34-NBt1D", pretrained=False).
PARAMS_NYUV2 = 46_955_840
PARAMS_NYUV2_NO_SIDE = 46_919_880
PARAMS_SUNRGBD = 46_949_624
PARAMS_CITYSCAPES = 46_912_328
FVCORE_TOLERANCE = 5e-3  # relative

SMALL = (64, 96)  # smallest size with a non-trivial 1/32 map (2x3)


def _num_params(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def _inputs(height: int, width: int, batch: int = 1, seed: int = 0):
    gen = torch.Generator().manual_seed(seed)
    rgb = torch.randn(batch, 3, height, width, generator=gen)
    depth = torch.randn(batch, 1, height, width, generator=gen)
    return rgb, depth


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    """Run this module on one intra-op thread.

    On a busy 2-core runner, OpenMP threads spin-wait for each other at every small op, which
    made the 64x96 forward passes here 50-100x slower (seconds instead of ~0.1 s).
    """
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def nyuv2_model() -> ESANet:
    torch.manual_seed(0)
    return esanet_r34_nbt1d(dataset="nyuv2").eval()


# --------------------------------------------------------------------------------------------
# sizes
# --------------------------------------------------------------------------------------------


def test_param_count_nyuv2(nyuv2_model: ESANet) -> None:
    assert _num_params(nyuv2_model) == PARAMS_NYUV2
    assert nyuv2_model.num_classes == 40


@pytest.mark.parametrize(
    ("build", "expected"),
    [
        (lambda: ESANet(num_classes=40, side_outputs=False), PARAMS_NYUV2_NO_SIDE),
        (lambda: esanet_r34_nbt1d(dataset="sunrgbd"), PARAMS_SUNRGBD),
        (lambda: esanet_r34_nbt1d(num_classes=37, dataset="sunrgbd"), PARAMS_SUNRGBD),
        (lambda: esanet_r34_nbt1d(dataset="cityscapes"), PARAMS_CITYSCAPES),
        (
            lambda: ESANet(num_classes=19, context="appm-1-2-4-8", input_size=(512, 1024)),
            PARAMS_CITYSCAPES,
        ),
    ],
    ids=["nyuv2-no-side", "sunrgbd", "sunrgbd-explicit", "cityscapes", "cityscapes-explicit"],
)
def test_param_counts(build, expected: int) -> None:
    assert _num_params(build()) == expected


def _fvcore_total(model: nn.Module, height: int, width: int) -> tuple[int, set[str]]:
    fvcore_nn = require_module("fvcore.nn")
    rgb, depth = _inputs(height, width)
    with torch.no_grad():
        flops = fvcore_nn.FlopCountAnalysis(model.eval(), (rgb, depth))
        flops.unsupported_ops_warnings(False)
        flops.uncalled_modules_warnings(False)
        total = flops.total()
    return total, set(flops.unsupported_ops())


def test_fvcore_nyuv2_480x640(nyuv2_model: ESANet) -> None:
    total, skipped = _fvcore_total(nyuv2_model, 480, 640)
    assert total == pytest.approx(45_275_112_448, rel=FVCORE_TOLERANCE)
    # the operators fvcore does not count, to be reported next to the total
    assert skipped == {"aten::add", "aten::mul", "aten::sigmoid", "aten::max_pool2d"}


@pytest.mark.slow
@pytest.mark.parametrize(
    ("dataset", "size", "expected"),
    [
        ("sunrgbd", (480, 640), 45_197_237_248),
        ("cityscapes", (512, 1024), 76_339_391_744),
        ("cityscapes", (1024, 2048), 305_357_302_784),
    ],
    ids=["sunrgbd-480x640", "cityscapes-512x1024", "cityscapes-1024x2048"],
)
def test_fvcore_other_configs(dataset: str, size: tuple[int, int], expected: int) -> None:
    total, _ = _fvcore_total(esanet_r34_nbt1d(dataset=dataset), *size)
    assert total == pytest.approx(expected, rel=FVCORE_TOLERANCE)


# --------------------------------------------------------------------------------------------
# outputs
# --------------------------------------------------------------------------------------------


def test_eval_output_is_logits_at_input_size(nyuv2_model: ESANet) -> None:
    rgb, depth = _inputs(*SMALL, batch=2)
    with torch.no_grad():
        out = nyuv2_model(rgb, depth)
    assert isinstance(out, torch.Tensor)
    assert out.shape == (2, 40, *SMALL)
    assert torch.isfinite(out).all()


def test_train_mode_returns_side_outputs_and_backprops() -> None:
    torch.manual_seed(0)
    model = esanet_r34_nbt1d(dataset="sunrgbd").train()
    height, width = SMALL
    outs = model(*_inputs(height, width, batch=2))
    assert isinstance(outs, tuple) and len(outs) == 4
    expected = [(height, width)] + [(height // s, width // s) for s in (8, 16, 32)]
    assert [tuple(o.shape) for o in outs] == [(2, 37, h, w) for h, w in expected]
    sum(o.mean() for o in outs).backward()
    side_convs = [m.side_output for m in model.decoder]
    assert all(conv.weight.grad is not None for conv in side_convs)


def test_train_mode_without_side_outputs_returns_logits() -> None:
    model = ESANet(num_classes=13, side_outputs=False).train()
    with torch.no_grad():
        out = model(*_inputs(*SMALL, batch=2))  # batch > 1: BN on the 1x1 pyramid level
    assert isinstance(out, torch.Tensor) and out.shape == (2, 13, *SMALL)


def test_cityscapes_model_runs_below_and_above_training_size() -> None:
    model = esanet_r34_nbt1d(dataset="cityscapes").eval()
    with torch.no_grad():
        for size in (SMALL, (128, 256)):
            assert model(*_inputs(*size)).shape == (1, 19, *size)


def test_appm_windows_keep_their_size() -> None:
    appm = AdaptivePyramidPooling(512, 512, bins=(1, 2, 4, 8), train_size=(16, 32))
    assert appm.pool_grids((16, 32)) == [(1, 1), (2, 2), (4, 4), (8, 8)]  # = adaptive pooling
    assert appm.pool_grids((32, 64)) == [(2, 2), (4, 4), (8, 8), (16, 16)]  # 2x input
    assert appm.pool_grids((2, 3)) == [(1, 1), (2, 2), (4, 4), (8, 8)]  # clamped below
    ppm = AdaptivePyramidPooling(512, 512, bins=(1, 5))
    assert ppm.pool_grids((32, 64)) == [(1, 1), (5, 5)]
    assert [branch[0].out_channels for branch in ppm.branches] == [256, 256]
    assert ppm.fuse[0].in_channels == 1024


def test_learned_upsample_starts_bilinear() -> None:
    up = LearnedUpsample2x(4).requires_grad_(False)
    expected = torch.tensor([[1.0, 2.0, 1.0], [2.0, 4.0, 2.0], [1.0, 2.0, 1.0]]) / 16
    assert torch.equal(up.conv.weight, expected.expand(4, 1, 3, 3))
    assert torch.count_nonzero(up.conv.bias) == 0
    assert all(p.requires_grad for p in LearnedUpsample2x(4).parameters())  # trainable
    out = up(torch.ones(1, 4, 5, 6))
    assert out.shape == (1, 4, 10, 12)
    assert torch.allclose(out[..., 1:-1, 1:-1], torch.ones(()))  # zero padding only at borders
    assert out[0, 0, 0, 0] == pytest.approx(9 / 16)


def test_non_bottleneck_1d_layout() -> None:
    block = NonBottleneck1D(64, 128, stride=2)
    assert block.bn1.eps == block.bn2.eps == 1e-3
    convs = [block.conv_v1, block.conv_h1, block.conv_v2, block.conv_h2]
    assert all(conv.bias is not None for conv in convs)
    assert [conv.kernel_size for conv in convs] == [(3, 1), (1, 3)] * 2
    assert isinstance(block.shortcut, nn.Sequential)
    assert block(torch.randn(1, 64, 8, 10)).shape == (1, 128, 4, 5)
    assert isinstance(NonBottleneck1D(64, 64).shortcut, nn.Identity)


# --------------------------------------------------------------------------------------------
# errors
# --------------------------------------------------------------------------------------------


def test_unknown_names_raise() -> None:
    with pytest.raises(UnknownNameError, match="kitti"):
        esanet_r34_nbt1d(dataset="kitti")
    with pytest.raises(UnknownNameError, match="aspp"):
        ESANet(context="aspp")


def test_bad_input_sizes_raise(nyuv2_model: ESANet) -> None:
    with pytest.raises(ValueError, match="divisible by 32"):
        nyuv2_model(*_inputs(60, 96))
    rgb, _ = _inputs(*SMALL)
    with pytest.raises(ValueError, match="do not match"):
        nyuv2_model(rgb, torch.zeros(1, 1, 32, 96))


# --------------------------------------------------------------------------------------------
# ONNX
# --------------------------------------------------------------------------------------------


def _tame(model: ESANet, rgb: torch.Tensor, depth: torch.Tensor) -> None:
    """Give the randomly initialised model O(1) logits, so that ``atol=1e-3`` means something.

    Every BatchNorm takes the statistics of one small random batch (as after a little training),
    then the classifier is scaled so that the logits for ``(rgb, depth)`` have unit spread.
    """
    for module in model.modules():
        if isinstance(module, nn.BatchNorm2d):
            module.reset_running_stats()
            module.momentum = None  # cumulative average: after one batch, that batch's stats
    with torch.no_grad():
        model.train()(*_inputs(96, 128, batch=2, seed=1))
        spread = model.eval()(rgb, depth).std()
        model.classifier.weight /= spread
        model.classifier.bias /= spread


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_onnx_export_at_480x640_matches_torch(tmp_path) -> None:
    ort = require_module("onnxruntime")
    torch.manual_seed(0)
    model = esanet_r34_nbt1d(dataset="nyuv2")
    rgb, depth = _inputs(480, 640)
    _tame(model, rgb, depth)
    with torch.no_grad():
        expected = model(rgb, depth).numpy()
    assert 0.5 < expected.std() < 2

    path = tmp_path / "esanet.onnx"
    torch.onnx.export(
        model,
        (rgb, depth),
        str(path),
        dynamo=False,
        input_names=["rgb", "depth"],
        output_names=["logits"],
        opset_version=17,
    )
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    (got,) = session.run(None, {"rgb": rgb.numpy(), "depth": depth.numpy()})

    assert got.shape == (1, 40, 480, 640)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-3)
