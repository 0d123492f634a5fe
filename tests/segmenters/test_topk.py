"""The compiled top-k + softmax of a network's logits against torch's softmax and topk."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from evsmap.segmenters import topk


def _reference(logits: torch.Tensor, k: int):
    p, c = torch.softmax(logits.permute(1, 2, 0), dim=-1).topk(k, dim=-1)
    return c.numpy(), p.numpy()


@pytest.mark.parametrize("k", [1, 2, 3, 5])
def test_top_k_matches_softmax_topk(k):
    gen = torch.Generator().manual_seed(k)
    logits = torch.randn(19, 24, 31, generator=gen) * 5
    classes, probs = topk.top_k_softmax(logits, k)
    want_c, want_p = _reference(logits, k)
    assert classes.dtype == np.int16 and probs.dtype == np.float32
    assert classes.shape == probs.shape == (24, 31, k)
    assert np.array_equal(classes, want_c)
    assert np.allclose(probs, want_p, rtol=1e-5, atol=1e-7)
    assert np.all(np.diff(probs, axis=-1) <= 0)


def test_ties_go_to_the_smaller_class():
    logits = torch.zeros(6, 2, 2)
    logits[4] = 1.0
    logits[2] = 1.0  # classes 2 and 4 tie for the top, the rest tie below
    classes, probs = topk.top_k_softmax(logits, 3)
    assert classes[0, 0].tolist() == [2, 4, 0]
    assert probs[0, 0, 0] == probs[0, 0, 1]


def test_without_the_compiler_the_reference_runs(monkeypatch):
    logits = torch.randn(7, 5, 6, generator=torch.Generator().manual_seed(3))
    fast = topk.top_k_softmax(logits, 3)
    monkeypatch.setattr(topk, "njit", None)
    slow = topk.top_k_softmax(logits, 3)
    assert np.array_equal(fast[0], slow[0])
    assert np.allclose(fast[1], slow[1], rtol=1e-5, atol=1e-7)
