"""The segmentation cache keys a network's observations by its weights' tensors, not only by the
file's path: a weights file replaced under the same name between runs gets new labels."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import pytest
import torch

from evsmap.runner import mapping_labels
from evsmap.runner.mapping_labels import observations_key, weights_identity
from evsmap.runner.segcache import cache_key
from evsmap.segmenters import cards
from evsmap.segmenters.cards import make_card
from evsmap.segmenters.weights import tensors_sha256


def _state(seed: int) -> dict[str, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    return {"head.weight": torch.randn(3, 3, generator=gen), "head.bias": torch.zeros(3)}


def _with_card(path: Path, seed: int) -> dict[str, torch.Tensor]:
    state = _state(seed)
    card = make_card(model="feagnet-v1", options={}, num_classes=3,
                     class_names=["a", "b", "c"], state_dict=state, created="fixed")
    torch.save({"state_dict": state, "card": card}, path)
    return state


def _key(path: Path) -> str:
    return cache_key(indices=[0, 1], **observations_key("feagnet-v1", path, "seq"))


@pytest.fixture(autouse=True)
def _fresh_memo(monkeypatch):
    monkeypatch.setattr(mapping_labels, "_WEIGHTS_IDS", {})


def _touch_later(path: Path, seconds: int) -> None:
    st = path.stat()
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + seconds * 1_000_000_000))


def test_replaced_weights_file_gets_a_new_key(tmp_path):
    path = tmp_path / "feagnet-v1@nyuv2.pt"
    first = _with_card(path, 0)
    size = path.stat().st_size
    key1 = _key(path)
    assert _key(path) == key1  # the same file twice
    assert weights_identity(path) == f"tensors:{tensors_sha256(first)}"

    # another run (a fresh process): the file replaced by other tensors under the same name
    second = _with_card(path, 1)
    assert path.stat().st_size == size  # same shapes: the size alone does not tell them apart
    mapping_labels._WEIGHTS_IDS.clear()
    key2 = _key(path)
    assert key2 != key1
    assert weights_identity(path) == f"tensors:{tensors_sha256(second)}"

    # in one process: a file rewritten later is read again
    _with_card(path, 0)
    _touch_later(path, 5)
    assert _key(path) == key1


def test_weights_without_card_are_keyed_by_their_bytes(tmp_path):
    path = tmp_path / "plain.pt"
    torch.save(_state(0), path)
    key1 = _key(path)
    assert weights_identity(path) == "file:" + hashlib.sha256(path.read_bytes()).hexdigest()
    torch.save(_state(1), path)
    _touch_later(path, 5)
    assert _key(path) != key1
    assert _key(path) == _key(path)


def test_identity_is_computed_once_per_file_state(tmp_path, monkeypatch):
    path = tmp_path / "w.pt"
    _with_card(path, 0)
    calls: list[Path] = []
    inspect = cards.inspect_weights
    monkeypatch.setattr(cards, "inspect_weights", lambda p: calls.append(p) or inspect(p))
    for _ in range(3):
        weights_identity(path)
    assert len(calls) == 1
