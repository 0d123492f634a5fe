"""``--resume`` continues exactly: 2 epochs straight equal 1 epoch + resume + 1, bit for bit on
the CPU (weights, BatchNorm statistics, momentum buffers, logged losses), the resume naming
nothing but the run's folder (its settings come from its run.json; a flag that conflicts with
them is refused); the data-loading processes change nothing."""

from __future__ import annotations

import json

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
    # the continuation names only the run: model, dataset, options, recipe, overrides, device
    # and threads come from it - in a process whose torch has another thread count, which the
    # run sets to its own (1, the tests') and puts back after
    torch.set_num_threads(2)
    try:
        assert main(["train", "--out", str(root / "resumed"), "--resume"]) == 0
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(1)
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
    assert "backends" in straight and straight["backends"] == resumed["backends"]


def test_run_json_records_the_settings(straight_and_resumed, tiny_model, colour_data):
    run = json.loads((straight_and_resumed[0] / "run.json").read_text())
    assert run["settings"] == {
        "model": tiny_model, "options": {}, "dataset": str(colour_data.resolve()),
        "reader": None, "reader_options": [], "train_split": None, "val_split": None,
        "limit": None, "device": "cpu", "channels_last": False, "deterministic": False,
        "threads": 1}  # the tests' one thread (conftest)
    assert run["threads"] == 1
    resumed = json.loads((straight_and_resumed[1] / "run.json").read_text())
    assert resumed["settings"] == run["settings"]


@pytest.mark.parametrize(("flags", "says"), [
    (["--deterministic"], "trained without --deterministic"),
    (["--threads", "3"], "with --threads 1, not 3"),
    (["--limit", "4"], "with --limit (none), not 4"),
    (["--device", "cuda"], "with --device cpu, not cuda"),
    (["-o", "multiscale=false"], "with -o (none), not multiscale=False"),
    (["--lr", "0.5"], "lr is 0.01 in the checkpoint, 0.5 here"),
])
def test_a_resume_refuses_flags_that_conflict_with_the_run(straight_and_resumed, capsys,
                                                           flags, says):
    capsys.readouterr()
    out = straight_and_resumed[1]
    before = (out / "checkpoint.pt").read_bytes()
    assert main(["train", "--out", str(out), "--resume", *flags]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and says in err, err
    assert (out / "checkpoint.pt").read_bytes() == before


def test_a_resume_given_the_same_settings_goes_on(straight_and_resumed, tiny_model, colour_data,
                                                  capsys):
    out = straight_and_resumed[1]
    assert main(["train", tiny_model, "--dataset", str(colour_data), "--device", "cpu",
                 "--threads", "1", "--out", str(out), "--resume"]) == 0
    assert "nothing to do" in capsys.readouterr().out


def test_a_new_run_needs_a_model_and_a_dataset(tmp_path, tiny_model, capsys):
    assert main(["train", "--dataset", "x", "--out", str(tmp_path / "a")]) == 2
    assert main(["train", tiny_model, "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all("a new run needs MODEL and --dataset" in e for e in err)


def test_data_loading_processes_change_nothing(tmp_path, tiny_model, colour_data, tiny_recipe):
    """Samples built in this process, with 2 intra-op threads, and in data-loading processes,
    which torch gives 1, are the same (their resize does not depend on the thread count)."""
    runs = []
    for workers in (0, 2):
        out = tmp_path / f"w{workers}"
        assert main(["train", tiny_model, "--dataset", str(colour_data), "--recipe",
                     str(tiny_recipe), "--epochs", "1", "--eval-every", "0", "--set",
                     "scale=0.5,1.5", "--workers", str(workers), "--threads", "2", "--out",
                     str(out)]) == 0
        runs.append(load_checkpoint(out / "checkpoint.pt"))
    assert _same_tensors(runs[0]["state_dict"], runs[1]["state_dict"])
    assert runs[0]["history"][0]["loss"] == runs[1]["history"][0]["loss"]
