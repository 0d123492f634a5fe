"""Two straight ``evsmap train`` runs in two processes give the same checkpoint bit for bit:
other hash seeds (set and dict orders), another default thread count in torch (the run sets its
own, ``--threads``), samples built in this process or in data-loading processes (``--workers``)."""

from __future__ import annotations

import json

import pytest
import torch
from train_fixtures import CLASSES

from evsmap.train.checkpoint import load_checkpoint
from tests.interrupt_helpers import run_evsmap

pytestmark = pytest.mark.slow


def test_straight_runs_in_two_processes_are_equal(tmp_path, monkeypatch, colour_data,
                                                  tiny_recipe):
    common = ["train", "feagnet-v1", "-o", f"num_classes={CLASSES}", "--dataset",
              str(colour_data), "--recipe", str(tiny_recipe), "--epochs", "2", "--crop",
              "96x160", "--eval-every", "0", "--device", "cpu", "--threads", "2"]
    runs = {}
    for name, hash_seed, omp, workers in (("a", "1", "1", "0"), ("b", "2", "2", "2")):
        monkeypatch.setenv("PYTHONHASHSEED", hash_seed)
        monkeypatch.setenv("OMP_NUM_THREADS", omp)  # torch's default thread count
        run_evsmap([*common, "--workers", workers, "--out", str(tmp_path / name)], tmp_path)
        runs[name] = load_checkpoint(tmp_path / name / "checkpoint.pt")
        assert json.loads((tmp_path / name / "run.json").read_text())["threads"] == 2
    a, b = runs["a"], runs["b"]
    assert a["state_dict"].keys() == b["state_dict"].keys()
    different = [k for k in a["state_dict"] if not torch.equal(a["state_dict"][k],
                                                              b["state_dict"][k])]
    assert not different, f"{len(different)} tensors differ, first {different[:3]}"
    assert [r["loss"] for r in a["history"]] == [r["loss"] for r in b["history"]]
