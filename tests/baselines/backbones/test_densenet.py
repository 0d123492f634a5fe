"""DenseNet-121 backbone (baselines.backbones.densenet): torchvision's size and names, feature
shapes."""

from __future__ import annotations

import torch
from torch import nn

from baselines.backbones.densenet import DenseNet, densenet121, rename_legacy_keys

TORCHVISION_PARAMS = 7_978_856  # torchvision densenet121, ImageNet classifier included
CLASSIFIER_PARAMS = 1024 * 1000 + 1000


def _num_params(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def _torchvision_keys() -> set[str]:
    """torchvision's densenet121 state-dict keys, written out from its documented layout."""
    bn = ("weight", "bias", "running_mean", "running_var", "num_batches_tracked")
    keys = {"features.conv0.weight", *(f"features.norm0.{s}" for s in bn),
            *(f"features.norm5.{s}" for s in bn), "classifier.weight", "classifier.bias"}
    for b, layers in enumerate((6, 12, 24, 16), start=1):
        for k in range(1, layers + 1):
            p = f"features.denseblock{b}.denselayer{k}"
            keys |= {f"{p}.conv1.weight", f"{p}.conv2.weight"}
            keys |= {f"{p}.norm{n}.{s}" for n in (1, 2) for s in bn}
        if b < 4:
            keys.add(f"features.transition{b}.conv.weight")
            keys |= {f"features.transition{b}.norm.{s}" for s in bn}
    return keys


def test_parameter_count_equals_torchvision() -> None:
    assert _num_params(densenet121(with_classifier=True)) == TORCHVISION_PARAMS
    assert _num_params(densenet121()) == TORCHVISION_PARAMS - CLASSIFIER_PARAMS


def test_state_dict_keys_follow_torchvision() -> None:
    model = densenet121(with_classifier=True)
    assert set(model.state_dict()) == _torchvision_keys()
    assert tuple(model.features.denseblock3.denselayer24.conv1.weight.shape) == (128, 992, 1, 1)
    assert tuple(model.features.transition2.conv.weight.shape) == (256, 512, 1, 1)
    result = densenet121().load_state_dict(model.state_dict(), strict=False)
    assert sorted(result.unexpected_keys) == ["classifier.bias", "classifier.weight"]
    assert result.missing_keys == []


def test_feature_shapes_and_channels() -> None:
    model = densenet121().eval()
    assert model.channels == (256, 512, 1024, 1024)
    assert model.strides == (4, 8, 16, 32)
    with torch.no_grad():
        features = model(torch.randn(1, 3, 64, 128))
    assert [tuple(f.shape) for f in features] == [
        (1, 256, 16, 32), (1, 512, 8, 16), (1, 1024, 4, 8), (1, 1024, 2, 4)]
    assert float(features[-1].min()) >= 0.0  # after norm5 and ReLU


def test_forward_features_match_the_sequential_features() -> None:
    model = densenet121().eval()
    x = torch.randn(1, 3, 64, 64)
    with torch.no_grad():
        last = model.forward_features(x)[-1]
        sequential = torch.relu(model.features(x))
    torch.testing.assert_close(last, sequential)


def test_classifier_logits() -> None:
    model = densenet121(with_classifier=True).eval()
    with torch.no_grad():
        assert model(torch.randn(2, 3, 64, 64)).shape == (2, 1000)
    assert isinstance(model, DenseNet)


def test_torchvision_checkpoint_names_are_renamed() -> None:
    model = densenet121(with_classifier=True)
    legacy = {}
    for key, value in model.state_dict().items():
        for new, old in (("norm1.", "norm.1."), ("conv1.", "conv.1."), ("norm2.", "norm.2."),
                         ("conv2.", "conv.2.")):
            if ".denselayer" in key and f".{new}" in key:
                key = key.replace(f".{new}", f".{old}")
        legacy[key] = value
    assert "features.denseblock1.denselayer1.norm.1.weight" in legacy
    assert "features.transition1.norm.weight" in legacy  # transitions keep their names
    renamed = rename_legacy_keys(legacy)
    assert set(renamed) == set(model.state_dict())
    densenet121(with_classifier=True).load_state_dict(renamed, strict=True)
