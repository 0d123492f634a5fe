"""``evsmap train --channels-last --deterministic`` on the CPU: the run trains, ``run.json``
says how it ran, a deterministic run repeats itself bit for bit, and torch's process-wide
algorithm settings are as they were after the run (a run called from Python changes nothing
around it)."""

from __future__ import annotations

import json

import torch

from evsmap.cli.main import main
from evsmap.train.checkpoint import load_checkpoint


def test_channels_last_and_deterministic(tmp_path, tiny_model, colour_data, tiny_recipe):
    before = (torch.are_deterministic_algorithms_enabled(), torch.backends.cudnn.benchmark,
              torch.backends.cudnn.deterministic)
    states = []
    for name in ("a", "b"):
        out = tmp_path / name
        assert main(["train", tiny_model, "--dataset", str(colour_data), "--recipe",
                     str(tiny_recipe), "--epochs", "1", "--eval-every", "0", "--device", "cpu",
                     "--channels-last", "--deterministic", "--out", str(out)]) == 0
        run = json.loads((out / "run.json").read_text())
        assert run["channels_last"] is True and run["deterministic"] is True
        assert run["gpu"] == {}  # no GPU facts for a CPU run
        states.append(load_checkpoint(out / "checkpoint.pt")["state_dict"])
    assert all(torch.equal(states[0][k], states[1][k]) for k in states[0])
    assert any(t.is_floating_point() and t.abs().sum() > 0 for t in states[0].values())
    assert (torch.are_deterministic_algorithms_enabled(), torch.backends.cudnn.benchmark,
            torch.backends.cudnn.deterministic) == before
