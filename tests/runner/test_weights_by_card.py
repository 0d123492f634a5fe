"""The runner finds a cell's weights by card: any file name under the weights folder, options
compared as the factory takes them, a deterministic choice among several, the folder indexed
once per run, and the card named in the record's notes and the table's notes."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest
import torch

from evsmap.runner import context as context_module
from evsmap.runner.context import RunContext, WeightsChoice, parse_spec
from evsmap.segmenters import cards
from evsmap.segmenters.cards import make_card
from evsmap.segmenters.weights import tensors_sha256

ABLATION = "feagnet-v2(attention=false,cfim=false,dappf=false,multiscale=false)"


def _save(path: Path, *, model: str = "feagnet-v2", options: dict | None = None,
          seed: int = 0, state: dict | None = None, **fields) -> Path:
    """A small weights file with a card as ``evsmap train`` writes it (the runner reads the
    card only; these tensors fit no network)."""
    if state is None:
        gen = torch.Generator().manual_seed(seed)
        state = {"head.weight": torch.randn(3, 3, generator=gen)}
    n = fields.pop("num_classes", 40)
    card = make_card(model=model, options=options or {}, num_classes=n,
                     class_names=[f"c{i}" for i in range(n)], state_dict=state, **fields)
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"state_dict": state, "card": card}, path)
    return path


@pytest.fixture
def weights(tmp_path) -> Path:
    root = tmp_path / "weights"
    _save(root / "runs" / "monday" / "best.pt", dataset="datasets/nyuv2", reader="nyuv2",
          epochs=40, val_miou=0.412, created="2025-03-01T10:00:00+00:00", seed=1)
    _save(root / "ablations" / "base.pt", dataset="nyuv2", epochs=40, val_miou=0.30,
          options={"cfim": False, "dappf": False, "attention": False, "multiscale": False})
    _save(root / "sun" / "v2-37.pth", dataset="/data/sunrgbd", reader="sunrgbd",
          options={"num_classes": 37}, num_classes=37, val_miou=0.35)
    _save(root / "city.pt", model="feagnet-v1", options={"num_classes": 19}, num_classes=19,
          dataset="cityscapes", val_miou=0.6)
    _save(root / "esanet.pt", model="esanet-r34-nbt1d", options={"dataset": "cityscapes"},
          num_classes=19, source_layout="esanet-release")  # as `weights convert` writes it
    (root / "broken.pt").write_bytes(b"not a weights file")
    return root


@pytest.fixture
def ctx(tmp_path, weights) -> RunContext:
    (tmp_path / "run").mkdir()
    return RunContext.create(tmp_path / "run", data_root=tmp_path, weights_dir=weights)


def _found(ctx: RunContext, spec: str, dataset: str) -> str | None:
    choice = ctx.weights_choice(spec, dataset)
    return None if choice is None else choice.file


def test_parse_spec():
    assert parse_spec("feagnet-v2") == ("feagnet-v2", {})
    assert parse_spec("feagnet-v1(num_classes=19)") == ("feagnet-v1", {"num_classes": 19})
    assert parse_spec(ABLATION) == ("feagnet-v2", {"attention": False, "cfim": False,
                                                   "dappf": False, "multiscale": False})


def test_cells_find_their_weights_by_card(ctx):
    assert _found(ctx, "feagnet-v2", "nyuv2") == "runs/monday/best.pt"
    # every default spelled out is the same network
    assert _found(ctx, "feagnet-v2(attention=true,cfim=true,dappf=true,multiscale=true)",
                  "nyuv2") == "runs/monday/best.pt"
    assert _found(ctx, ABLATION, "nyuv2") == "ablations/base.pt"
    assert _found(ctx, "feagnet-v2(attention=true,cfim=false,dappf=false,multiscale=false)",
                  "nyuv2") is None
    assert _found(ctx, "feagnet-v2(num_classes=37)", "sunrgbd") == "sun/v2-37.pth"
    assert _found(ctx, "feagnet-v2", "sunrgbd") is None  # 40 classes, the card has 37
    assert _found(ctx, "feagnet-v1(num_classes=19)", "cityscapes") == "city.pt"
    assert _found(ctx, "feagnet-v1", "nyuv2") is None
    assert _found(ctx, "esanet-r34-nbt1d(dataset=cityscapes)", "cityscapes") == "esanet.pt"
    assert _found(ctx, "esanet-r34-nbt1d(dataset=nyuv2)", "nyuv2") is None
    assert ctx.weights_path("feagnet-v2", "nyuv2") == ctx.weights_choice(
        "feagnet-v2", "nyuv2").path
    assert ctx.available(["weights:feagnet-v2@nyuv2", f"weights:{ABLATION}@nyuv2",
                          "weights:feagnet-v1@nyuv2"]) == [
        "weights:feagnet-v2@nyuv2", f"weights:{ABLATION}@nyuv2"]


def test_a_card_with_empty_options_matches_the_bare_name(ctx, weights):
    shutil.rmtree(weights / "runs")
    _save(weights / "x" / "all-defaults.pt", dataset="nyuv2",
          options={"cfim": True, "dappf": True, "attention": True, "multiscale": True,
                   "num_classes": 40, "backend": "onnxruntime", "input_size": [480, 640]})
    assert _found(ctx, "feagnet-v2", "nyuv2") == "x/all-defaults.pt"


def test_several_matches_choose_deterministically(ctx, weights):
    _save(weights / "runs" / "tuesday" / "best.pt", dataset="nyuv2", epochs=60,
          val_miou=0.45, created="2025-03-02T10:00:00+00:00", seed=2)
    _save(weights / "runs" / "tuesday" / "last.pt", dataset="nyuv2", epochs=80,
          val_miou=0.43, created="2025-03-02T12:00:00+00:00", seed=3)
    choice = ctx.weights_choice("feagnet-v2", "nyuv2")
    assert choice.found_by == "card" and choice.file == "runs/tuesday/best.pt"
    assert choice.candidates == ("runs/tuesday/best.pt", "runs/tuesday/last.pt",
                                 "runs/monday/best.pt")
    # equal val mIoU: the newest; then weights files before training checkpoints, then path
    assert [e["file"] for e in sorted(
        [{"file": "b.pt", "card": {"val_miou": 0.4}, "mtime_ns": 1},
         {"file": "a.pt", "card": {"val_miou": 0.4, "created": "2025-01-01T00:00:00+00:00"}},
         {"file": "c.pt", "card": {"val_miou": 0.4}, "mtime_ns": 1, "checkpoint": True},
         {"file": "d.pt", "card": {"val_miou": None}, "mtime_ns": 9 * 10**18},
         {"file": "e.pt", "card": {"val_miou": 0.4}, "mtime_ns": 1}],
        key=context_module._rank)] == ["a.pt", "b.pt", "e.pt", "c.pt", "d.pt"]
    note = choice.note()
    assert note.startswith("weights: runs/tuesday/best.pt (card: feagnet-v2, nyuv2, 60 epochs, "
                           "val mIoU 45.0 %, sha256 ")
    assert "found by its card, the first of 3 matching files by val mIoU" in note
    assert "also matching: runs/tuesday/last.pt, runs/monday/best.pt" in note


def test_names_come_first_then_cards_then_the_bare_name(ctx, weights):
    # <spec>@<dataset> wins over a matching card; a card that disagrees is named in the note
    _save(weights / "feagnet-v2@nyuv2.pt", dataset="sunrgbd", seed=5)
    choice = ctx.weights_choice("feagnet-v2", "nyuv2")
    assert choice.found_by == "name" and choice.file == "feagnet-v2@nyuv2.pt"
    assert "named for this cell, but its card is for dataset sunrgbd" in choice.note()
    # an ablation spec: the card of the ablation comes before the bare-name file
    assert _found(ctx, ABLATION, "nyuv2") == "ablations/base.pt"
    assert _found(ctx, "feagnet-v2(attention=true,cfim=false,dappf=false,multiscale=false)",
                  "nyuv2") == "feagnet-v2@nyuv2.pt"
    # a plain state dict named for the cell has no card
    torch.save({"w": torch.zeros(1)}, weights / "feagnet-l@cityscapes.pth")
    assert ctx.weights_choice("feagnet-l", "cityscapes").note() == \
        "weights: feagnet-l@cityscapes.pth (no card)"


def test_the_folder_is_indexed_once_per_run(ctx, weights, monkeypatch):
    read = []
    inspect = cards.inspect_weights

    def counting(path):
        read.append(Path(path).relative_to(weights).as_posix())
        return inspect(path)

    monkeypatch.setattr(cards, "inspect_weights", counting)
    for _ in range(3):
        ctx.weights_path("feagnet-v2", "nyuv2")
        ctx.weights_path(ABLATION, "nyuv2")
        ctx.available(["weights:feagnet-v1@nyuv2"])
    assert sorted(read) == ["ablations/base.pt", "broken.pt", "city.pt", "esanet.pt",
                            "runs/monday/best.pt", "sun/v2-37.pth"]
    index = json.loads((Path(ctx.out) / "cache" / context_module.WEIGHTS_INDEX).read_text())
    assert index["files"]["runs/monday/best.pt"]["card"]["dataset"] == "nyuv2"
    assert index["files"]["broken.pt"]["card"] is None and index["files"]["broken.pt"]["error"]

    # a cell's own process (a context rebuilt from the run's settings) reads the stored index
    read.clear()
    worker = RunContext(**ctx.as_dict())
    assert worker.weights_choice(ABLATION, "nyuv2").file == "ablations/base.pt"
    assert read == []
    # ... and reads again only a file that changed since
    _save(weights / "ablations" / "base.pt", dataset="nyuv2", val_miou=0.31, seed=9,
          options={"cfim": False, "dappf": False, "attention": False, "multiscale": False},
          state={"a": torch.zeros(5), "b": torch.ones(2)})
    os.utime(weights / "ablations" / "base.pt", ns=(1, 1))
    again = RunContext(**ctx.as_dict())
    assert again.weights_choice(ABLATION, "nyuv2").card["val_miou"] == 0.31
    assert read == ["ablations/base.pt"]


def test_the_note_names_the_card_in_the_record_and_the_table(tmp_path, nyuv2_samples_dir):
    from evsmap.registry import SEGMENTERS
    from evsmap.report.tables import table_markdown
    from evsmap.runner import matrix
    from evsmap.runner.execute import execute_spec
    from evsmap.tables.schema import load_tables

    root = tmp_path / "data"
    shutil.copytree(nyuv2_samples_dir, root / "nyuv2")
    (root / "nyuv2" / "test.txt").write_text("000433\n000464\n")
    (root / "nyuv2" / "train.txt").write_text("")
    torch.manual_seed(1)
    state = SEGMENTERS.create("feagnet-v1").module.state_dict()
    weights = tmp_path / "weights"
    path = _save(weights / "2025-03-01" / "best.pt", model="feagnet-v1", state=state,
                 dataset="datasets/nyuv2", reader="nyuv2", epochs=40, val_miou=0.123)
    ctx = RunContext.create(tmp_path / "run", data_root=root, weights_dir=weights, quick=True)
    plan = matrix.plan(ctx, ["table1"])
    spec = next(s for s in plan.specs if s.key == "table1/feagnet-v1/accuracy/nyuv2:test[miou]")
    assert spec.needs == ()
    rec = execute_spec(spec, ctx)
    assert rec.status == "ok", rec.error
    sha = tensors_sha256(state)[:8]
    expected = (f"weights: 2025-03-01/best.pt (card: feagnet-v1, nyuv2, 40 epochs, "
                f"val mIoU 12.3 %, sha256 {sha}); found by its card")
    assert rec.notes[0] == "nyuv2 test split, 2 images, weights 2025-03-01/best.pt"
    assert rec.notes[1] == expected
    assert path.is_file()
    text = table_markdown(load_tables()["table1"], {rec.key: rec}, plan.specs)
    assert expected in text.split("Notes:")[1]


def test_weights_choice_note_without_optional_fields():
    choice = WeightsChoice(path=Path("w/x.pt"), file="x.pt", found_by="card",
                           card={"model": "feagnet-s", "options": {}, "dataset": "cityscapes"},
                           candidates=("x.pt",))
    assert choice.note() == "weights: x.pt (card: feagnet-s, cityscapes); found by its card"
    both = WeightsChoice(path=Path("w/y.pt"), file="y.pt", found_by="card",
                         card={"model": "feagnet-v2", "options": {"cfim": False},
                               "dataset": "nyuv2", "epochs": 3, "val_miou": 0.25,
                               "test_miou": 0.2, "tensors_sha256": "ab" * 32},
                         candidates=("y.pt",))
    assert both.note() == ("weights: y.pt (card: feagnet-v2(cfim=false), nyuv2, 3 epochs, val "
                           "mIoU 25.0 %, test mIoU 20.0 %, sha256 abababab); found by its card")
