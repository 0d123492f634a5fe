"""DDP: ``torchrun --nproc-per-node 2 -m evsmap train ...`` on the CPU (gloo): both processes
train on their half of every batch, the weights stay identical, only rank 0 writes, and the
files load (``evsmap eval`` on them gives the validation mIoU both processes computed)."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys

import pytest

from evsmap.cli.main import main
from evsmap.registry import SEGMENTERS
from evsmap.segmenters.weights import read_checkpoint
from evsmap.train.checkpoint import load_checkpoint

EPOCHS = 2


@pytest.mark.slow
def test_torchrun_two_cpu_processes(tmp_path, colour_data, tiny_recipe, capsys):
    out = tmp_path / "ddp"
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONUNBUFFERED="1")
    # feagnet-v1 as registered (input 480x640: validation runs there, as evsmap eval does);
    # training on 128x192 crops
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node",
           "2", "-m", "evsmap", "train", "feagnet-v1", "-o", "num_classes=4", "--dataset",
           str(colour_data), "--out", str(out), "--recipe", str(tiny_recipe), "--epochs",
           str(EPOCHS), "--crop", "128x192", "--device", "cpu"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=env,
                          cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr

    # only rank 0 printed and wrote
    lines = proc.stdout.splitlines()
    training = [line for line in lines if line.startswith("training ")]
    assert len(training) == 1 and "(2 processes x 2, gloo)" in training[0]
    assert len([line for line in lines if line.startswith("epoch ")]) == EPOCHS
    assert sorted(p.name for p in out.iterdir()) == ["best.pt", "checkpoint.pt", "last.pt",
                                                     "log.csv", "run.json"]
    assert not list(tmp_path.glob("**/.*.tmp-*"))

    # both ranks ran on disjoint halves of the batch and hold the same weights
    run = json.loads((out / "run.json").read_text())
    assert (run["world_size"], run["backend"], run["batch_per_process"]) == (2, "gloo", 2)
    assert run["steps_per_epoch"] == 2
    ranks = run["ranks"]
    assert [r["rank"] for r in ranks] == [0, 1]
    assert [r["images"] for r in ranks] == [4, 4]  # 2 steps x 2 frames each
    halves = [set(r["indices"]) for r in ranks]
    assert not halves[0] & halves[1] and halves[0] | halves[1] == set(range(8))
    assert ranks[0]["params_sha256"] == ranks[1]["params_sha256"]
    with open(out / "log.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [int(r["images"]) for r in rows] == [8] * EPOCHS  # the global batch: 2 x 2 x 2

    # the files load like any weights file
    ckpt = load_checkpoint(out / "checkpoint.pt")
    assert ckpt["epoch"] == EPOCHS and ckpt["run"]["world_size"] == 2
    assert not any(k.startswith("module.") for k in ckpt["state_dict"])
    card = read_checkpoint(out / "last.pt")["card"]
    assert card["world_size"] == 2 and card["options"] == {"num_classes": 4}
    SEGMENTERS.create("feagnet-v1", num_classes=4, weights=str(out / "last.pt"))
    # the validation both processes computed (frames shared, matrices summed, rank 0's
    # BatchNorm statistics) is what evsmap eval computes on the saved weights
    capsys.readouterr()
    assert main(["eval", "feagnet-v1", "-o", "num_classes=4", "--dataset", str(colour_data),
                 "--weights", str(out / "last.pt"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["miou"] == card["val_miou"]
