"""Shared by the compared networks' tests: one intra-op thread for every test module (on a busy
2-core machine OpenMP spin-waits slow the small forward passes down)."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
