"""The final test pass of ``evsmap train``: a run that validates on ``val`` (synthrooms) scores
``best.pt`` on ``test`` after its last epoch; the card and run.json get ``test_miou``, which is
what ``evsmap eval`` reports, and the tensors are unchanged. Runs that validate on test or
datasets whose test labels are all void get no pass."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import pytest
from train_fixtures import SIZE

from evsmap.cli.main import main
from evsmap.segmenters.weights import read_checkpoint, tensors_sha256
from evsmap.train.evaluate import open_test_split
from evsmap.train.options import RunOptions

ROOMS, VIEWS = 8, 2  # splits: train 8 frames, val 4, test 4


@pytest.fixture(scope="module")
def rooms(tmp_path_factory) -> Path:
    from evsmap.datasets.synthrooms import prepare_synthrooms

    out = tmp_path_factory.mktemp("synthrooms") / "synthrooms"
    prepare_synthrooms(out, rooms=ROOMS, frames_per_room=VIEWS, size=SIZE, seed=0)
    return out


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory, rooms, tiny_model, tiny_recipe) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("test-pass") / "run"
    log = out.parent / "messages.txt"
    with open(log, "w") as messages:
        from evsmap.train.loop import train

        summary = train(RunOptions(model=tiny_model, dataset=str(rooms), out=out,
                                   recipe=str(tiny_recipe), overrides={"epochs": 1},
                                   options={"num_classes": 40}, device="cpu",
                                   messages=messages))
    assert summary["finished"] and summary["test_miou"] is not None
    return out, log.read_text()


def test_best_card_has_the_test_miou_eval_reports(capsys, run_dir, rooms, tiny_model):
    out, messages = run_dir
    saved = read_checkpoint(out / "best.pt")
    card = saved["card"]
    assert card["val_split"] == "val" and card["test_split"] == "test"
    assert card["test_frames"] == 4 and card["val_miou"] is not None
    assert card["tensors_sha256"] == tensors_sha256(saved["state_dict"])  # tensors unchanged
    assert set(saved) == {"state_dict", "card"}
    code = main(["eval", tiny_model, "-o", "num_classes=40", "--dataset", str(rooms),
                 "--split", "test", "--weights", str(out / "best.pt"), "--json"])
    got, err = capsys.readouterr()
    assert code == 0, err
    record = json.loads(got)
    assert record["split"] == "test" and record["frames"] == 4
    assert record["miou"] == card["test_miou"]  # the same computation, bit for bit
    run = json.loads((out / "run.json").read_text())
    assert (run["test_miou"], run["test_split"], run["test_frames"]) == \
        (card["test_miou"], "test", 4)
    lines = [line for line in messages.splitlines() if line.startswith("test mIoU")]
    assert len(lines) == 1 and f"{100 * card['test_miou']:.2f} %" in lines[0]
    assert "best.pt, epoch 1" in lines[0] and "4 frames of split test" in lines[0]
    # last.pt and the checkpoint keep the card written after the epoch
    assert "test_split" not in read_checkpoint(out / "last.pt")["card"]
    names = sorted(p.name for p in out.iterdir())
    assert names == ["best.pt", "checkpoint.pt", "last.pt", "log.csv", "run.json"]  # no temps


def test_resuming_a_finished_run_does_not_test_again(capsys, run_dir, rooms, tiny_model):
    out, _ = run_dir
    before = (out / "best.pt").read_bytes()
    code = main(["train", tiny_model, "--dataset", str(rooms), "--out", str(out), "--resume"])
    got, err = capsys.readouterr()
    assert code == 0, err
    assert "test mIoU" not in got and (out / "best.pt").read_bytes() == before


def test_resuming_a_finished_run_without_a_test_pass_makes_it(capsys, run_dir, rooms, tiny_model,
                                                             tmp_path):
    """A run that finished before evsmap made the final test pass gets it on --resume; the
    weights stay the same."""
    import shutil

    from evsmap.train.checkpoint import save_weights

    src, _ = run_dir
    out = tmp_path / "old-run"
    shutil.copytree(src, out)
    saved = read_checkpoint(out / "best.pt")
    card = {k: v for k, v in saved["card"].items()
            if k not in ("test_split", "test_frames")}
    card["test_miou"] = None
    save_weights(out / "best.pt", saved["state_dict"], card)
    code = main(["train", tiny_model, "--dataset", str(rooms), "--out", str(out), "--resume"])
    got, err = capsys.readouterr()
    assert code == 0, err
    assert "test mIoU" in got
    after = read_checkpoint(out / "best.pt")
    assert after["card"]["test_split"] == "test"
    assert after["card"]["test_miou"] == read_checkpoint(src / "best.pt")["card"]["test_miou"]
    assert tensors_sha256(after["state_dict"]) == tensors_sha256(saved["state_dict"])


def _splits(val_split, reader="synthrooms"):
    return SimpleNamespace(val_split=val_split, reader=reader)


def test_which_runs_get_a_test_pass(rooms, tmp_path, monkeypatch):
    opts = RunOptions(model="x", dataset=str(rooms), out=tmp_path)
    sequence, why = open_test_split(opts, _splits("val"))
    assert why is None and len(sequence) == 4 and sequence.frame(0).labels is not None
    assert open_test_split(opts, _splits("test")) == (None, None)  # card: test_miou = val_miou
    assert open_test_split(opts, _splits(None, "tum")) == (None, None)  # no splits

    # a test split marked all-void by its reader (Cityscapes) is skipped
    from evsmap.train import data

    real = data.open_splits

    def void_test(*args, **kwargs):
        splits = real(*args, **kwargs)
        splits.val.meta["void_label_splits"] = ["test"]
        return splits

    monkeypatch.setattr(data, "open_splits", void_test)
    sequence, why = open_test_split(opts, _splits("val", "cityscapes"))
    assert sequence is None and "test labels of cityscapes are all void" in why
