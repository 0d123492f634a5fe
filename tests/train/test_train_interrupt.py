"""``evsmap train`` stopped by SIGTERM at a random moment: no process left, the checkpoint whole,
the right hint, and the run resumed from its last finished epoch (``evsmap train --out DIR
--resume``, nothing else) equals a straight one bit for bit (tests/interrupt_helpers.py).

``EVSMAP_TRAIN_INTERRUPT_RUNS=N`` makes N interruptions at N moments drawn from the seeded
generator, against one straight run (with ``EVSMAP_INTERRUPT_SEED`` replaying a sequence)."""

from __future__ import annotations

import os
import shutil
import signal
from pathlib import Path

import pytest
import torch
from train_fixtures import CLASSES

from evsmap.train.checkpoint import load_checkpoint
from tests.interrupt_helpers import (
    LINUX_ONLY,
    RNG,
    SEED,
    assert_whole,
    interrupt,
    run_evsmap,
)

pytestmark = [pytest.mark.slow, LINUX_ONLY]

# --------------------------------------------------------------------------------------- train
@pytest.fixture(scope="module")
def straight_training(tmp_path_factory, colour_data, tiny_recipe) -> Path:
    tmp = tmp_path_factory.mktemp("train")
    run_evsmap([*train_argv(colour_data, tiny_recipe), "--out", str(tmp / "run")], tmp)
    return tmp / "run"


def train_argv(data: Path, recipe: Path) -> list[str]:
    # FEAGNet-V1 with the tests' 4 classes, spelled as an option: the tiny model the conftest
    # registers exists in this process only, not in the evsmap process run here
    return ["train", "feagnet-v1", "-o", f"num_classes={CLASSES}", "--dataset", str(data),
            "--recipe", str(recipe), "--epochs", "3", "--crop", "96x160", "--device", "cpu"]


@pytest.mark.parametrize("attempt", range(int(os.environ.get("EVSMAP_TRAIN_INTERRUPT_RUNS",
                                                            "1"))))
def test_train_interrupted_and_resumed_equals_a_straight_run(straight_training, tmp_path,
                                                             colour_data, tiny_recipe, attempt):
    out = tmp_path / "run"
    argv = [*train_argv(colour_data, tiny_recipe), "--out", str(out)]
    after_s = RNG.uniform(2.0, 20.0)
    code, err = interrupt(argv, tmp_path, after_s=after_s, sig=signal.SIGTERM)
    assert_whole(out) if out.exists() else None
    if code == 128 + signal.SIGTERM:
        assert ("--resume" in err) if (out / "checkpoint.pt").exists() else \
            ("run the same command again" in err), err
    if (out / "checkpoint.pt").exists():
        run_evsmap(["train", "--out", str(out), "--resume"], tmp_path)
    else:
        shutil.rmtree(out, ignore_errors=True)
        run_evsmap(argv, tmp_path)
    a = load_checkpoint(straight_training / "checkpoint.pt")
    b = load_checkpoint(out / "checkpoint.pt")
    assert a["epoch"] == b["epoch"] == 3
    assert a["state_dict"].keys() == b["state_dict"].keys()
    assert all(torch.equal(a["state_dict"][k], b["state_dict"][k]) for k in a["state_dict"]), \
        f"seed {SEED}, attempt {attempt}: SIGTERM at {after_s:.2f} s (exit {code})"
