"""ResNet backbones (baselines.backbones.resnet): torchvision's sizes and names, the deep stem,
output strides and feature shapes."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from baselines.backbones.resnet import (
    BasicBlock,
    Bottleneck,
    ResNet,
    resnet18,
    resnet34,
    resnet50,
    resnet101,
    resnet152,
)

# torchvision's published parameter counts (ImageNet classifier included).
TORCHVISION_PARAMS = {
    resnet18: 11_689_512,
    resnet34: 21_797_672,
    resnet50: 25_557_032,
    resnet101: 44_549_160,
    resnet152: 60_192_808,
}
FC_PARAMS = {resnet18: 512 * 1000 + 1000, resnet34: 512 * 1000 + 1000}
FC_PARAMS_BOTTLENECK = 2048 * 1000 + 1000


def _num_params(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def _torchvision_keys(blocks: tuple[int, int, int, int], *, bottleneck: bool) -> set[str]:
    """The state-dict keys of torchvision's ResNet, written out from its documented layout."""
    bn = ("weight", "bias", "running_mean", "running_var", "num_batches_tracked")
    keys = {"conv1.weight", *(f"bn1.{s}" for s in bn), "fc.weight", "fc.bias"}
    convs = 3 if bottleneck else 2
    for stage, count in enumerate(blocks, start=1):
        for i in range(count):
            prefix = f"layer{stage}.{i}"
            for c in range(1, convs + 1):
                keys.add(f"{prefix}.conv{c}.weight")
                keys.update(f"{prefix}.bn{c}.{s}" for s in bn)
            # the first block of each stage projects (stage 1 only for bottlenecks: 64 -> 256)
            if i == 0 and (stage > 1 or bottleneck):
                keys.add(f"{prefix}.downsample.0.weight")
                keys.update(f"{prefix}.downsample.1.{s}" for s in bn)
    return keys


@pytest.mark.parametrize("factory", list(TORCHVISION_PARAMS), ids=lambda f: f.__name__)
def test_parameter_counts_equal_torchvision(factory) -> None:
    with_fc = factory(with_fc=True)
    assert _num_params(with_fc) == TORCHVISION_PARAMS[factory]
    fc = FC_PARAMS.get(factory, FC_PARAMS_BOTTLENECK)
    assert _num_params(factory()) == TORCHVISION_PARAMS[factory] - fc


def test_resnet50_state_dict_keys_follow_torchvision() -> None:
    keys = set(resnet50(with_fc=True).state_dict())
    expected = _torchvision_keys((3, 4, 6, 3), bottleneck=True)
    assert keys == expected
    assert len(keys) == 320
    for key in ("conv1.weight", "bn1.running_mean", "layer1.0.conv1.weight",
                "layer1.0.downsample.0.weight", "layer4.2.bn3.running_var", "fc.bias"):
        assert key in keys


def test_resnet18_state_dict_keys_follow_torchvision() -> None:
    keys = set(resnet18(with_fc=True).state_dict())
    assert keys == _torchvision_keys((2, 2, 2, 2), bottleneck=False)
    assert "layer1.0.downsample.0.weight" not in keys


def test_a_torchvision_shaped_state_dict_loads_strictly() -> None:
    source = resnet34(with_fc=True)
    with torch.no_grad():
        source.layer3[2].conv2.weight.fill_(0.25)
    target = resnet34(with_fc=True)
    target.load_state_dict(source.state_dict(), strict=True)
    assert torch.equal(target.layer3[2].conv2.weight, source.layer3[2].conv2.weight)
    # without the classifier only fc.* is left over
    headless = resnet34()
    result = headless.load_state_dict(source.state_dict(), strict=False)
    assert sorted(result.unexpected_keys) == ["fc.bias", "fc.weight"]
    assert result.missing_keys == []


@pytest.mark.parametrize(("stem_width", "out"), [(64, 128), (32, 64)])
def test_deep_stem_shapes(stem_width: int, out: int) -> None:
    model = resnet50(deep_stem=True, stem_width=stem_width).eval()
    shapes = [tuple(model.conv1[i].weight.shape) for i in (0, 3, 6)]
    assert shapes == [(stem_width, 3, 3, 3), (stem_width, stem_width, 3, 3),
                      (out, stem_width, 3, 3)]
    assert tuple(model.bn1.weight.shape) == (out,)
    assert model.layer1[0].conv1.in_channels == out
    assert model.layer1[0].downsample[0].in_channels == out
    assert isinstance(model.conv1[1], nn.BatchNorm2d) and isinstance(model.conv1[2], nn.ReLU)
    with torch.no_grad():
        stem = model.stem(torch.zeros(1, 3, 64, 96))
    assert stem.shape == (1, out, 16, 24)


def test_deep_stem_parameter_count() -> None:
    # the 7x7 stem (9,408 weights, BN(64)) replaced by 3-32-32-64 convolutions and BN(32) x2,
    # BN(64): mmseg's ResNetV1c-50 without fc
    plain = _num_params(resnet50())
    deep = _num_params(resnet50(deep_stem=True, stem_width=32))
    stem = 3 * 32 * 9 + 32 * 32 * 9 + 32 * 64 * 9 + 2 * 32 * 2
    assert deep == plain - 3 * 64 * 49 + stem


@pytest.mark.parametrize("output_stride", [32, 16, 8])
def test_feature_shapes_at_each_output_stride(output_stride: int) -> None:
    model = resnet18(output_stride=output_stride).eval()
    with torch.no_grad():
        features = model(torch.randn(1, 3, 64, 128))
    assert isinstance(features, list) and len(features) == 4
    assert model.strides[-1] == output_stride
    for f, channels, stride in zip(features, model.channels, model.strides, strict=True):
        assert f.shape == (1, channels, 64 // stride, 128 // stride)
    assert _num_params(model) == _num_params(resnet18())


def test_dilation_follows_torchvision_replace_stride_with_dilation() -> None:
    model = resnet50(output_stride=8)
    assert [b.conv2.dilation[0] for b in model.layer3] == [1] + [2] * 5
    assert [b.conv2.dilation[0] for b in model.layer4] == [2, 4, 4]
    assert all(b.conv2.stride == (1, 1) for b in (*model.layer3, *model.layer4))
    assert model.layer4[0].downsample[0].stride == (1, 1)
    os16 = resnet101(output_stride=16)
    assert [b.conv2.dilation[0] for b in os16.layer4] == [1, 2, 2]
    assert os16.layer3[0].conv2.stride == (2, 2)


def test_channels_in_chans_and_classifier() -> None:
    assert resnet34().channels == (64, 128, 256, 512)
    assert resnet152().channels == (256, 512, 1024, 2048)
    depth = resnet34(in_chans=1)
    assert tuple(depth.conv1.weight.shape) == (64, 1, 7, 7)
    model = resnet18(with_fc=True).eval()
    with torch.no_grad():
        logits = model(torch.randn(2, 3, 64, 64))
    assert logits.shape == (2, 1000)
    assert not hasattr(resnet18(), "fc")


def test_norm_layer_and_block_classes() -> None:
    model = resnet18(norm_layer=lambda c: nn.GroupNorm(8, c))
    assert isinstance(model.bn1, nn.GroupNorm) and isinstance(model.layer2[0].bn2, nn.GroupNorm)
    assert isinstance(resnet18().layer1[0], BasicBlock)
    assert isinstance(resnet50().layer1[0], Bottleneck)
    assert isinstance(resnet50(), ResNet)


def test_bad_output_stride_is_refused() -> None:
    with pytest.raises(ValueError, match="output_stride"):
        resnet18(output_stride=4)
