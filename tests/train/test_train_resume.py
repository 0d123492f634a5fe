"""``--resume`` continues exactly: 2 epochs straight equal 1 epoch + resume + 1, bit for bit on
the CPU (weights, BatchNorm statistics, momentum buffers, logged losses); the data-loading
processes change nothing."""

from __future__ import annotations

import pytest
import torch

from evsmap.cli.main import main
from evsmap.segmenters.weights import read_checkpoint
from evsmap.train.checkpoint import load_checkpoint


def _same_tensors(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


@pytest.fixture(scope="module")
def straight_and_resumed(tmp_path_factory, tiny_model, colour_data, tiny_recipe):
    root = tmp_path_factory.mktemp("resume")
    # a schedule that changes the rate between the epochs, scales that pad and crop, flips
    common = ["train", tiny_model, "--dataset", str(colour_data), "--recipe", str(tiny_recipe),
              "--epochs", "2", "--set", "poly_start_epoch=0", "--set", "scale=0.5,1.5",
              "--crop", "96x160", "--device", "cpu"]
    assert main([*common, "--out", str(root / "straight")]) == 0
    assert main([*common, "--out", str(root / "resumed"), "--stop-after", "1"]) == 0
    first = load_checkpoint(root / "resumed" / "checkpoint.pt")
    assert first["epoch"] == 1
    # the continuation names only the run: recipe, options and overrides come from it
    assert main(["train", tiny_model, "--dataset", str(colour_data), "--out",
                 str(root / "resumed"), "--resume"]) == 0
    return root / "straight", root / "resumed"


def test_two_epochs_straight_equal_one_plus_resume_plus_one(straight_and_resumed):
    straight, resumed = (load_checkpoint(p / "checkpoint.pt") for p in straight_and_resumed)
    assert straight["epoch"] == resumed["epoch"] == 2
    assert _same_tensors(straight["state_dict"], resumed["state_dict"])
    a, b = straight["optimizer"], resumed["optimizer"]
    assert a["param_groups"] == b["param_groups"]
    assert a["state"].keys() == b["state"].keys()
    assert all(torch.equal(a["state"][k]["momentum_buffer"], b["state"][k]["momentum_buffer"])
               for k in a["state"])
    assert straight["scheduler"] == resumed["scheduler"]
    for key in ("epoch", "lr", "loss", "val_miou", "images"):
        assert [r[key] for r in straight["history"]] == [r[key] for r in resumed["history"]]
    lrs = [r["lr"] for r in straight["history"]]
    assert lrs == [0.01, pytest.approx(0.01 * 0.5 ** 0.9)]
    assert straight["recipe"] == resumed["recipe"]
    cards = [read_checkpoint(p / "last.pt")["card"] for p in straight_and_resumed]
    assert cards[0]["tensors_sha256"] == cards[1]["tensors_sha256"]
    assert (straight_and_resumed[1] / "log.csv").read_text().count("\n") == 3


def test_data_loading_processes_change_nothing(tmp_path, tiny_model, colour_data, tiny_recipe):
    runs = []
    for workers in (0, 2):
        out = tmp_path / f"w{workers}"
        assert main(["train", tiny_model, "--dataset", str(colour_data), "--recipe",
                     str(tiny_recipe), "--epochs", "1", "--eval-every", "0", "--set",
                     "scale=0.5,1.5", "--workers", str(workers), "--out", str(out)]) == 0
        runs.append(load_checkpoint(out / "checkpoint.pt"))
    assert _same_tensors(runs[0]["state_dict"], runs[1]["state_dict"])
    assert runs[0]["history"][0]["loss"] == runs[1]["history"][0]["loss"]
