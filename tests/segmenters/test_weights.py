"""Loading trained weights through ``SEGMENTERS.create(name, weights=path)``.

A checkpoint is the state dict of another (differently seeded) instance saved with
``torch.save``; loading it must reproduce that instance's outputs exactly, and every broken file
must raise a DataFormatError that names the file and the offending key.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from evsmap.errors import DataFormatError

NAME = "feagnet-s"  # the smallest registered network (2.9 M parameters, a 12 MB checkpoint)


def _state(seg) -> dict[str, torch.Tensor]:
    return {k: v.clone() for k, v in seg.module.state_dict().items()}


def _save(obj, path: Path) -> Path:
    torch.save(obj, path)
    return path


@pytest.fixture(scope="module")
def source(create):
    """The instance whose weights are saved (seed 1; the loading instances start from seed 2)."""
    return create(NAME, seed=1)


@pytest.fixture(scope="module")
def state(source) -> dict[str, torch.Tensor]:
    return _state(source)


@pytest.fixture(scope="module")
def checkpoint(state, tmp_path_factory) -> Path:
    return _save(state, tmp_path_factory.mktemp("weights") / f"{NAME}.pt")


def _outputs(seg, frame) -> torch.Tensor:
    return seg.logits(seg.preprocess(frame))


@pytest.mark.parametrize("name", ["feagnet-s", "feagnet-v2", "fchardnet-70"])
def test_loaded_weights_reproduce_the_source(create, make_frame, tmp_path, name):
    source = create(name, seed=1)
    path = _save(source.module.state_dict(), tmp_path / "weights.pth")
    loaded = create(name, seed=2, weights=path)
    fresh = create(name, seed=2)
    frame = make_frame()
    assert loaded.weights == str(path)
    assert fresh.weights is None
    assert torch.equal(_outputs(loaded, frame), _outputs(source, frame))
    assert not torch.equal(_outputs(fresh, frame), _outputs(source, frame))  # the load mattered
    a, b = loaded.predict(frame), source.predict(frame)
    np.testing.assert_array_equal(a.classes, b.classes)
    np.testing.assert_array_equal(a.probs, b.probs)


def test_weights_accept_a_string_path(create, source, checkpoint, make_frame):
    loaded = create(NAME, seed=2, weights=str(checkpoint))
    assert torch.equal(_outputs(loaded, make_frame()), _outputs(source, make_frame()))


@pytest.mark.parametrize("wrapper", ["state_dict", "model_state_dict", "model", "net"])
def test_wrapped_checkpoint(create, source, state, make_frame, tmp_path, wrapper):
    path = _save({wrapper: state, "epoch": 7, "best_miou": 0.5}, tmp_path / "ckpt.pth")
    loaded = create(NAME, seed=2, weights=path)
    assert torch.equal(_outputs(loaded, make_frame()), _outputs(source, make_frame()))


def test_data_parallel_prefix_is_removed(create, source, state, make_frame, tmp_path):
    prefixed = {f"module.{k}": v for k, v in state.items()}
    path = _save({"state_dict": prefixed}, tmp_path / "ddp.pth")
    loaded = create(NAME, seed=2, weights=path)
    assert torch.equal(_outputs(loaded, make_frame()), _outputs(source, make_frame()))


# ------------------------------------------------------------------------------------------
# broken files
# ------------------------------------------------------------------------------------------


def _error(create, path: Path) -> str:
    with pytest.raises(DataFormatError) as info:
        create(NAME, weights=path)
    message = str(info.value)
    assert str(path) in message
    return message


def test_missing_file(create, tmp_path):
    assert "not found" in _error(create, tmp_path / "nowhere.pth")


def test_folder_instead_of_a_file(create, tmp_path):
    assert "not found" in _error(create, tmp_path)


def test_corrupt_file(create, tmp_path):
    path = tmp_path / "corrupt.pth"
    path.write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    assert "not a PyTorch checkpoint" in _error(create, path)


def test_empty_file(create, tmp_path):
    path = tmp_path / "empty.pth"
    path.write_bytes(b"")
    assert "the weights file is empty" in _error(create, path)


@pytest.mark.parametrize(
    "obj",
    [[torch.zeros(3)], torch.zeros(3), {"state_dict": [torch.zeros(3)]}, {"a": 1.0}],
    ids=["list", "tensor", "wrapped-list", "dict-of-floats"],
)
def test_not_a_state_dict(create, tmp_path, obj):
    path = _save(obj, tmp_path / "other.pth")
    assert "not a state dict" in _error(create, path)


def test_missing_key(create, state, tmp_path):
    key = sorted(state)[3]
    broken = {k: v for k, v in state.items() if k != key}
    message = _error(create, _save(broken, tmp_path / "missing.pth"))
    assert "missing keys" in message and key in message
    assert "FEAGNet" in message  # the network it was loaded into


def test_unexpected_key(create, state, tmp_path):
    broken = {**state, "extra_head.weight": torch.zeros(2, 2)}
    message = _error(create, _save(broken, tmp_path / "unexpected.pth"))
    assert "unexpected keys" in message and "extra_head.weight" in message
    assert "missing" not in message


def test_wrong_shape(create, state, tmp_path):
    key = next(k for k, v in state.items() if v.dim() == 4)  # a convolution kernel
    shape = tuple(state[key].shape)
    wrong = (shape[0] + 1, *shape[1:])
    broken = {**state, key: torch.zeros(wrong)}
    message = _error(create, _save(broken, tmp_path / "shape.pth"))
    assert "shape mismatch" in message and key in message
    assert str(wrong) in message and str(shape) in message


def test_weights_of_another_class_count(create, tmp_path):
    other = create(NAME, num_classes=5)
    path = _save(other.module.state_dict(), tmp_path / "five.pth")
    message = _error(create, path)
    assert "shape mismatch" in message and "(5," in message
