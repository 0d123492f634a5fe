"""What a straight run carries from one epoch to the next besides its weights is saved in the
checkpoint and put back on resume: the optimiser and schedule, AMP's grad scaler, torch's CPU
and CUDA random states, numpy's and Python's, and torch's algorithm flags (cuDNN's autotuner
and determinism, TF32, deterministic algorithms). On the CPU: CUDA's random state through a
stand-in for ``torch.cuda``, the scaler as a CPU ``GradScaler``."""

from __future__ import annotations

import io
import random

import numpy as np
import pytest
import torch

from evsmap.train.checkpoint import BACKEND_FLAGS, backend_flags, set_backend_flags
from evsmap.train.hooks import carried_state, restore_carried_state
from evsmap.train.optim import EpochSchedule
from evsmap.train.setup import Optimisation

CUDA_STATE = torch.arange(16, dtype=torch.uint8)


@pytest.fixture
def flags_kept():
    """torch's algorithm flags as they were, after the test."""
    before = backend_flags()
    yield
    set_backend_flags(before)


@pytest.fixture
def fake_cuda(monkeypatch):
    """A CUDA whose random state is :data:`CUDA_STATE`; what is restored into it is recorded."""
    restored: list[list[torch.Tensor]] = []
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "is_initialized", lambda: True)
    monkeypatch.setattr(torch.cuda, "get_rng_state_all", lambda: [CUDA_STATE.clone()])
    monkeypatch.setattr(torch.cuda, "set_rng_state_all", lambda states: restored.append(
        [s.clone() for s in states]))
    return restored


def _optimisation(*, trained: bool) -> Optimisation:
    """SGD with momentum on a small layer, the epoch schedule, an enabled AMP scaler; when
    ``trained``, three scaled steps (momentum buffers, the scaler's growth tracker) after one
    whose gradients overflow (the scale backs off)."""
    torch.manual_seed(0)
    layer = torch.nn.Linear(3, 2)
    sgd = torch.optim.SGD(layer.parameters(), lr=0.1, momentum=0.9)
    schedule = EpochSchedule(sgd, lambda epoch: 0.5 ** epoch)
    scaler = torch.amp.GradScaler("cpu", init_scale=1024.0, growth_interval=100)
    optim = Optimisation(sgd, schedule, scaler, criterion=None, amp=True)  # type: ignore[arg-type]
    if trained:
        schedule.start(2)
        for step in range(4):
            loss = layer(torch.randn(4, 3)).sum() * (float("inf") if step == 0 else 1.0)
            sgd.zero_grad()
            scaler.scale(loss).backward()
            scaler.step(sgd)
            scaler.update()
    return optim


def _saved_and_loaded(state: dict) -> dict:
    """``state`` through ``torch.save`` and a weights-only load, as the checkpoint goes."""
    buffer = io.BytesIO()
    torch.save(state, buffer)
    buffer.seek(0)
    return torch.load(buffer, weights_only=True)


def _next_draws() -> tuple:
    return (torch.rand(3), np.random.random(3), random.random())  # noqa: NPY002


def test_the_checkpoint_carries_every_state(fake_cuda, flags_kept):
    optim = _optimisation(trained=True)
    flags = {name: not value for name, value in backend_flags().items()}
    flags["deterministic_warn_only"] = True  # warn-only exists with the mode on only
    flags["deterministic_algorithms"] = True
    set_backend_flags(flags)
    torch.manual_seed(5)
    np.random.seed(6)  # noqa: NPY002
    random.seed(7)
    saved = _saved_and_loaded(carried_state(optim))

    assert set(saved) == {"optimizer", "scheduler", "scaler", "rng", "backends"}
    assert saved["scaler"]["scale"] == 512.0 and saved["scaler"]["_growth_tracker"] == 3
    assert saved["scheduler"] == {"base_lrs": [0.1], "epoch": 2}
    assert all("momentum_buffer" in s for s in saved["optimizer"]["state"].values())
    assert [torch.equal(s, CUDA_STATE) for s in saved["rng"]["cuda"]] == [True]
    assert saved["backends"] == flags and set(flags) == set(BACKEND_FLAGS)
    expected = _next_draws()

    # a fresh run, other random states, torch's flags back to their defaults: then restored
    fresh = _optimisation(trained=False)
    set_backend_flags({name: not value for name, value in flags.items()}
                      | {"deterministic_algorithms": False, "deterministic_warn_only": False})
    torch.manual_seed(0)
    np.random.seed(0)  # noqa: NPY002
    random.seed(0)
    restore_carried_state(fresh, saved)

    assert fresh.scaler.state_dict() == saved["scaler"]
    assert fresh.scaler.get_scale() == 512.0
    assert fresh.schedule.state_dict() == saved["scheduler"]
    assert fresh.optimizer.param_groups[0]["lr"] == 0.025
    moments = [s["momentum_buffer"] for s in fresh.optimizer.state.values()]
    assert len(moments) == 2 and all(torch.equal(a["momentum_buffer"], b) for a, b in
                                     zip(optim.optimizer.state.values(), moments, strict=True))
    assert len(fake_cuda) == 1 and torch.equal(fake_cuda[0][0], CUDA_STATE)
    assert backend_flags() == flags
    draws = _next_draws()
    assert torch.equal(draws[0], expected[0]) and np.array_equal(draws[1], expected[1])
    assert draws[2] == expected[2]


def test_a_checkpoint_without_flags_keeps_the_runs(flags_kept):
    """A checkpoint written before the flags were saved: the flags the resumed run set stay."""
    optim = _optimisation(trained=True)
    saved = _saved_and_loaded(carried_state(optim))
    del saved["backends"]
    set_backend_flags(backend_flags() | {"cudnn_benchmark": True})
    restore_carried_state(_optimisation(trained=False), saved)
    assert backend_flags()["cudnn_benchmark"] is True


def test_no_scaler_state_without_amp():
    optim = _optimisation(trained=False)
    optim.amp = False
    assert carried_state(optim)["scaler"] is None
