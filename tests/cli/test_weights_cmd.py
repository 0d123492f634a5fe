"""``evsmap weights list`` and ``evsmap weights show``: cards read without the tensors, files
without a card named by their layout, unreadable files in one line, the tensors checked against
the card."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from evsmap.cli.main import main
from evsmap.segmenters import cards
from evsmap.segmenters.cards import make_card
from evsmap.segmenters.weights import tensors_sha256


def _cli(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _state(seed: int = 0, n: int = 3) -> dict[str, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    return {f"layer{i}.weight": torch.randn(4, 4, generator=gen) for i in range(n)}


def _card(state: dict[str, torch.Tensor], **fields) -> dict:
    """A card with the fields ``evsmap train`` adds."""
    train = {"dataset": "datasets/nyuv2", "reader": "nyuv2", "train_split": "train",
             "val_split": "test", "recipe_name": "synth-proxy",
             "recipe": {"epochs": 40, "lr": 0.005}, "epochs": 40, "val_miou": 0.4123,
             "test_miou": 0.4123}
    train.update(fields)
    return make_card(model="feagnet-v2", options={"cfim": False, "num_classes": 5},
                     num_classes=5, class_names=["wall", "floor", "chair", "table", "bed"],
                     state_dict=state, **train)


@pytest.fixture
def folder(tmp_path) -> Path:
    """A carded file in a sub-folder, a plain state dict, an official ESANet-layout file, a
    truncated file, an empty one, and files the listing skips."""
    root = tmp_path / "weights"
    (root / "runs" / "v2").mkdir(parents=True)
    state = _state()
    torch.save({"state_dict": state, "card": _card(state)}, root / "runs" / "v2" / "best.pt")
    torch.save(_state(1), root / "plain.pth")
    esanet = {"encoder_rgb.conv1.weight": torch.zeros(2, 3, 1, 1),
              "decoder.conv_out.weight": torch.zeros(40, 2, 1, 1)}
    torch.save({"state_dict": esanet}, root / "esanet_nyuv2.pth")
    whole = (root / "runs" / "v2" / "best.pt").read_bytes()
    (root / "broken.pt").write_bytes(whole[: len(whole) // 2])
    (root / "empty.pt").write_bytes(b"")
    (root / "notes.txt").write_text("not weights")
    (root / ".hidden").mkdir()
    torch.save(_state(2), root / ".hidden" / "skipped.pt")
    return root


def test_list_names_every_file_in_one_line(capsys, folder):
    code, out, err = _cli(capsys, "weights", "list", folder)
    assert code == 0, err
    lines = out.splitlines()
    assert lines[0].split()[:3] == ["FILE", "MODEL", "DATASET"]
    by_file = {line.split()[0]: line for line in lines[1:-1]}
    assert set(by_file) == {str(folder / n) for n in (
        "broken.pt", "empty.pt", "esanet_nyuv2.pth", "plain.pth", "runs/v2/best.pt")}
    carded = by_file[str(folder / "runs" / "v2" / "best.pt")]
    assert "feagnet-v2(cfim=false,num_classes=5)" in carded and " nyuv2 " in carded
    assert carded.count("41.2 %") == 2 and carded.rstrip().endswith("kB")
    assert "no card (plain state dict, 3 tensors)" in by_file[str(folder / "plain.pth")]
    assert "no card (official release layout esanet-release" in \
        by_file[str(folder / "esanet_nyuv2.pth")]
    assert "unreadable: cannot read weights" in by_file[str(folder / "broken.pt")]
    assert "unreadable: empty file" in by_file[str(folder / "empty.pt")]
    assert "Traceback" not in out + err
    assert lines[-1] == "5 files: 1 with a card, 2 without, 2 unreadable"


def test_list_json_and_the_default_folder(capsys, folder, monkeypatch):
    monkeypatch.chdir(folder)
    code, out, err = _cli(capsys, "weights", "list", "--json")
    assert code == 0, err
    files = {Path(f["file"]).as_posix(): f for f in json.loads(out)}
    assert set(files) == {"broken.pt", "empty.pt", "esanet_nyuv2.pth", "plain.pth",
                          "runs/v2/best.pt"}
    best = files["runs/v2/best.pt"]
    assert best["model"] == "feagnet-v2" and best["dataset"] == "nyuv2"
    assert best["spec"] == "feagnet-v2(cfim=false,num_classes=5)"
    assert best["val_miou"] == pytest.approx(0.4123) and best["num_classes"] == 5
    assert best["card"]["recipe"] == {"epochs": 40, "lr": 0.005} and best["layout"] == "evsmap"
    assert files["plain.pth"]["card"] is None and files["plain.pth"]["layout"] == "plain"
    assert files["esanet_nyuv2.pth"]["layout"] == "esanet-release"
    assert files["broken.pt"]["error"] and files["broken.pt"]["layout"] is None
    # a file given directly is listed whatever its name
    code, out, _ = _cli(capsys, "weights", "list", "notes.txt", "--json")
    assert code == 0 and json.loads(out)[0]["error"]
    code, _, err = _cli(capsys, "weights", "list", "missing")
    assert code == 2 and "missing: no such file or folder" in err and err.count("\n") == 1


def test_list_maps_the_tensors_instead_of_reading_them(folder, monkeypatch):
    calls = []
    load = torch.load

    def spy(*args, **kwargs):
        calls.append(kwargs.get("mmap"))
        return load(*args, **kwargs)

    monkeypatch.setattr(torch, "load", spy)
    info = cards.inspect_weights(folder / "runs" / "v2" / "best.pt")
    assert info.card is not None and calls == [True]
    # a legacy (non-zip) file cannot be mapped: it is read whole (from memory, not mapped)
    legacy = folder / "legacy.pt"
    torch.save({"state_dict": _state(), "card": _card(_state())}, legacy,
               _use_new_zipfile_serialization=False)
    calls.clear()
    info = cards.inspect_weights(legacy)
    assert info.card is not None and info.error is None and calls == [None]


def test_show_prints_the_card_and_verifies_the_tensors(capsys, folder):
    path = folder / "runs" / "v2" / "best.pt"
    code, out, err = _cli(capsys, "weights", "show", path)
    assert code == 0, err
    assert "evsmap weights file with a card" in out.splitlines()[0]
    assert "val_miou" in out and "0.4123 (41.23 %)" in out and "wall, floor, chair" in out
    assert out.splitlines()[-1].startswith("tensors match the card (3 tensors, sha256 ")

    code, out, err = _cli(capsys, "weights", "show", path, "--json")
    assert code == 0, err
    shown = json.loads(out)
    state = _state()
    assert shown["card"] == _card(state) and shown["verified"] is True
    assert shown["tensors_sha256"] == tensors_sha256(state) and shown["tensors"] == 3


def test_show_detects_a_tampered_tensor(capsys, folder):
    state = _state()
    card = _card(state)
    state["layer1.weight"][2, 3] += 1e-3  # changed after the card was written
    tampered = folder / "tampered.pt"
    torch.save({"state_dict": state, "card": card}, tampered)
    code, out, _ = _cli(capsys, "weights", "show", tampered)
    assert code == 1
    assert out.splitlines()[-1].startswith(
        "tensors differ from the card: the file was changed after it was written")
    code, out, _ = _cli(capsys, "weights", "show", tampered, "--json")
    assert code == 1 and json.loads(out)["verified"] is False


def test_show_without_a_card_and_unreadable(capsys, folder):
    code, out, err = _cli(capsys, "weights", "show", folder / "plain.pth")
    assert code == 0, err
    assert "no card (plain state dict, 3 tensors)" in out and "no card to check against" in out
    code, _, err = _cli(capsys, "weights", "show", folder / "broken.pt")
    assert code == 2 and err.count("\n") == 1 and "cannot read weights" in err


def test_card_dataset_and_miou_fields():
    assert cards.card_dataset({"dataset": "/data/sets/nyuv2"}) == "nyuv2"
    assert cards.card_dataset({"dataset": "/x/rooms", "reader": "synthrooms"}) == \
        "synthrooms"
    assert cards.card_dataset({"options": {"dataset": "cityscapes"}}) == "cityscapes"
    assert cards.card_dataset({"model": "x"}) is None
    assert cards.card_miou({"metrics": {"miou_val": 0.3}}, "val") == 0.3
    assert cards.card_miou({"val_miou": None}, "val") is None


def test_list_and_show_start_without_torch():
    probe = ("import sys\nfrom evsmap.cli.main import main\n"
             "for argv in (['weights', 'list', '--help'], ['weights', 'show', '--help']):\n"
             "    try:\n        main(argv)\n    except SystemExit:\n        pass\n"
             "print('torch' in sys.modules, file=sys.stderr)")
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          timeout=120)
    assert "PATH" in proc.stdout and "FILE" in proc.stdout
    assert proc.stderr.strip().splitlines()[-1] == "False"
