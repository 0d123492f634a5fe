"""``evsmap train`` end to end in this process: the network learns the colour dataset within a
few dozen steps, the files and their cards, ``evsmap eval`` on best.pt gives the card's mIoU,
``--init``, refusals."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from train_fixtures import CLASSES, SIZE

from evsmap.cli.main import main
from evsmap.registry import SEGMENTERS
from evsmap.segmenters.weights import read_checkpoint, read_weights, tensors_sha256
from evsmap.train.checkpoint import load_checkpoint
from evsmap.train.init import load_encoder_weights

LEARN_EPOCHS = 30  # x 2 steps of 4 frames: 60 SGD steps


def _run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _log(run: Path) -> list[dict[str, str]]:
    with open(run / "log.csv", newline="") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def learned(tmp_path_factory, colour_data, tiny_model, tiny_recipe) -> Path:
    out = tmp_path_factory.mktemp("learn") / "run"
    code = main(["train", tiny_model, "--dataset", str(colour_data), "--out", str(out),
                 "--recipe", str(tiny_recipe), "--epochs", str(LEARN_EPOCHS), "--device",
                 "cpu"])
    assert code == 0
    return out


@pytest.mark.slow
def test_loss_falls_and_train_miou_rises_well_above_chance(learned):
    rows = _log(learned)
    assert [int(r["epoch"]) for r in rows] == list(range(1, LEARN_EPOCHS + 1))
    losses = [float(r["loss"]) for r in rows]
    mious = [float(r["val_miou"]) for r in rows]
    # chance: the untrained network labels (nearly) everything one class, mIoU ~ 0.19 here;
    # uniform guessing over 4 classes gives ~0.14
    assert mious[0] < 0.3
    assert max(mious) > 0.6, " ".join(f"{m:.3f}" for m in mious)
    assert losses[-1] < 0.5 * losses[0] and min(losses[-5:]) < min(losses[:5]), losses
    assert all(float(r["images"]) == 8 and float(r["images_per_s"]) > 0 for r in rows)
    assert list(rows[0]) == ["epoch", "lr", "loss", "val_miou", "train_seconds",
                             "val_seconds", "seconds", "images", "images_per_s"]


def test_run_files(learned):
    names = sorted(p.name for p in learned.iterdir())
    assert names == ["best.pt", "checkpoint.pt", "last.pt", "log.csv", "run.json"]  # no temps
    run = json.loads((learned / "run.json").read_text())
    assert run["world_size"] == 1 and run["batch_per_process"] == 4
    assert run["steps_per_epoch"] == 2 and run["crop"] == list(SIZE)
    ckpt = load_checkpoint(learned / "checkpoint.pt")
    assert ckpt["epoch"] == LEARN_EPOCHS and len(ckpt["history"]) == LEARN_EPOCHS
    assert set(ckpt) >= {"state_dict", "card", "optimizer", "scheduler", "rng", "recipe", "run",
                         "best"}
    assert ckpt["scheduler"] == {"base_lrs": [0.01], "epoch": LEARN_EPOCHS - 1}
    assert set(ckpt["rng"]) == {"torch", "cuda", "numpy", "python"}


def test_cards(learned, tiny_model):
    rows = _log(learned)
    best_row = max(rows, key=lambda r: float(r["val_miou"]))
    for name in ("best.pt", "last.pt"):
        obj = read_checkpoint(learned / name)
        assert set(obj) == {"state_dict", "card"}
        card = obj["card"]
        assert card["card_version"] == 1 and card["model"] == tiny_model
        assert card["options"] == {} and card["num_classes"] == CLASSES
        assert len(card["class_names"]) == CLASSES
        assert card["tensors"] == len(obj["state_dict"])
        assert card["tensors_sha256"] == tensors_sha256(obj["state_dict"])
        assert card["recipe_name"] == "tiny" and card["recipe"]["lr"] == 0.01
        assert card["recipe"]["epochs"] == LEARN_EPOCHS == card["epochs_planned"]
        assert card["dataset"].endswith("colours") and card["reader"] == "tum"
        assert card["train_split"] is None and card["test_miou"] is None
        assert card["evsmap_version"] and "git_commit" in card and card["created"]
        assert card["input_size"] == list(SIZE) and card["world_size"] == 1
        converted = read_weights(learned / name)
        assert converted.layout == "evsmap" and converted.segmenter == tiny_model
        json.dumps(card)  # plain values
    best = read_checkpoint(learned / "best.pt")["card"]
    assert best["epochs"] == int(best_row["epoch"]) == best["val_epoch"]
    assert best["val_miou"] == float(best_row["val_miou"])
    last = read_checkpoint(learned / "last.pt")["card"]
    assert last["epochs"] == LEARN_EPOCHS and last["val_miou"] == float(rows[-1]["val_miou"])


def test_eval_on_best_gives_the_cards_miou(capsys, learned, tiny_model, colour_data):
    card = read_checkpoint(learned / "best.pt")["card"]
    code, out, err = _run(capsys, "eval", tiny_model, "--dataset", colour_data, "--weights",
                          learned / "best.pt", "--json")
    assert code == 0, err
    assert json.loads(out)["miou"] == card["val_miou"]  # the same computation, bit for bit
    seg = SEGMENTERS.create(tiny_model, weights=str(learned / "best.pt"))
    state = read_checkpoint(learned / "best.pt")["state_dict"]
    assert all(torch.equal(v, state[k]) for k, v in seg.module.state_dict().items())


def test_resume_of_a_finished_run_does_nothing(capsys, learned, tiny_model, colour_data):
    before = (learned / "checkpoint.pt").read_bytes()
    code, out, err = _run(capsys, "train", tiny_model, "--dataset", colour_data, "--out",
                          learned, "--resume")
    assert code == 0, err
    assert "nothing to do" in out
    assert (learned / "checkpoint.pt").read_bytes() == before


def test_refusals(capsys, learned, tiny_model, colour_data, tmp_path):
    base = ["train", tiny_model, "--dataset", colour_data, "--workers", "0"]
    cases = [
        ([*base, "--out", learned], "holds a training run"),
        ([*base, "--out", tmp_path / "new", "--resume"], "no checkpoint to resume"),
        ([*base, "--out", learned, "--resume", "--lr", "0.1"],
         "a resumed run keeps its recipe: lr is 0.01 in the checkpoint"),
        ([*base, "--out", learned, "--resume", "-o", "num_classes=5"],
         "was trained with -o (none), not num_classes=5"),
        (["train", "feagnet-v1", "--dataset", colour_data, "--out", learned, "--resume"],
         f"is a run of {tiny_model}"),
        ([*base, "--out", tmp_path / "r", "--recipe", "nope"], "unknown recipe 'nope'"),
        ([*base, "--out", tmp_path / "r", "--set", "colour=1"], "unknown recipe field"),
        ([*base, "--out", tmp_path / "r", "--batch-size", "16"], "fewer than one batch"),
        ([*base, "--out", tmp_path / "r", "--val-split", "test"], "has no splits"),
        ([*base, "--out", tmp_path / "r", "-o", "input_size=64x96"], "not a training option"),
        (["train", "oracle", "--dataset", colour_data, "--out", tmp_path / "r"],
         "not a network segmenter"),
        ([*base, "--out", tmp_path / "r", "-o", "num_classes=3"], "label 3, outside 0..2"),
        # raised in a data-loading process: still one line
        ([*base[:-1], "2", "--out", tmp_path / "r", "-o", "num_classes=3"],
         "label 3, outside 0..2"),
    ]
    for argv, words in cases:
        code, out, err = _run(capsys, *argv)
        assert code == 2, (argv, out, err)
        assert words in err and err.count("\n") == 1, (argv, err)
    assert not (tmp_path / "r" / "checkpoint.pt").exists()


def test_init_report(capsys, tmp_path, tiny_model, colour_data, tiny_recipe):
    torch.manual_seed(1)
    donor = SEGMENTERS.create("fchardnet-70").module  # FC-HarDNet-70: 5 blocks, FEAGNet has 4
    path = tmp_path / "fchardnet.pt"
    torch.save({"model_state": {f"module.{k}": v for k, v in donor.state_dict().items()}}, path)

    module = SEGMENTERS.create(tiny_model).module
    report = load_encoder_weights(module, path)
    by_name = {e.encoder: e for e in report.encoders}
    assert set(by_name) == {"rgb_encoder", "depth_encoder"}
    total = len(module.rgb_encoder.state_dict())
    for e in by_name.values():
        assert e.source == "'encoder.*'" and len(e.loaded) == e.total == total
        assert not e.mismatched
    assert by_name["depth_encoder"].summed == ["stem.0.0.weight"]
    assert by_name["rgb_encoder"].summed == []
    first = donor.encoder.stem[0][0].weight
    assert torch.equal(module.rgb_encoder.stem[0][0].weight, first)
    assert torch.equal(module.depth_encoder.stem[0][0].weight, first.sum(1, keepdim=True))
    for key, value in module.rgb_encoder.state_dict().items():
        assert torch.equal(value, donor.encoder.state_dict()[key])
    assert len(report.unused) == len(donor.state_dict()) - total  # block 4, decoder, head
    assert any(k.startswith("encoder.blocks.4.") for k in report.unused)
    assert set(report.untouched) == {"decoder", "context", "fusion", "side_heads", "head"}
    text = "\n".join(report.lines())
    assert "rgb_encoder: 192 of 192 tensors from 'encoder.*'" in text
    assert "summed over input channels: stem.0.0.weight" in text
    assert "not loaded from the file: 224 tensors (up_blocks.*: 144, encoder.blocks.*: 48" in text
    assert "left at their initialisation: 294 tensors (decoder: 201" in text

    # through the command line: the report is printed and recorded
    out_dir = tmp_path / "run"
    code, out, err = _run(capsys, "train", tiny_model, "--dataset", colour_data, "--out",
                          out_dir, "--recipe", tiny_recipe, "--epochs", "1", "--eval-every",
                          "0", "--init", path)
    assert code == 0, err
    assert "--init" in out and "rgb_encoder: 192 of 192 tensors" in out
    card = read_checkpoint(out_dir / "last.pt")["card"]
    assert card["init"]["loaded"] == 2 * total and card["val_miou"] is None
    assert not (out_dir / "best.pt").exists()  # never validated

    # a file with nothing for the encoders
    junk = tmp_path / "junk.pt"
    torch.save({"fc.weight": torch.zeros(3, 3)}, junk)
    code, _, err = _run(capsys, "train", tiny_model, "--dataset", colour_data, "--out",
                        tmp_path / "run2", "--init", junk)
    assert code == 2 and "no tensor of the file fits an encoder" in err


def test_help_and_startup_without_torch():
    probe = ("import sys; from evsmap.cli.main import main\n"
             "try:\n    main(['train', '--help'])\nexcept SystemExit as e:\n    code = e.code\n"
             "print(code, 'torch' in sys.modules, file=sys.stderr)")
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          timeout=120)
    assert proc.stderr.strip().splitlines()[-1] == "0 False"
    for flag in ("--recipe", "--resume", "--init", "--eval-every", "--amp", "torchrun"):
        assert flag in proc.stdout
