"""``evsmap eval`` on an `evsmap synth` folder and on small in-memory readers."""

from __future__ import annotations

import json

import numpy as np
import pytest

from evsmap.cli.main import main
from evsmap.data import Frame, FrameList, Intrinsics
from evsmap.metrics import ConfusionMatrix
from evsmap.registry import READERS, SEGMENTERS

PERFECT = ["-o", "accuracy=1.0", "-o", "boundary_accuracy=1.0"]


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def synth(tmp_path_factory):
    out = tmp_path_factory.mktemp("eval") / "syn"
    assert main(["synth", "--out", str(out), "--frames", "3", "--width", "80",
                 "--height", "60"]) == 0
    return out


def test_perfect_oracle_scores_one(capsys, synth):
    code, out, err = run(capsys, "eval", "oracle", "--dataset", synth, *PERFECT, "--json")
    assert code == 0, err
    r = json.loads(out)
    assert r["miou"] == 1.0 and r["pixel_accuracy"] == 1.0 and r["mean_accuracy"] == 1.0
    assert r["frames"] == 3 and r["reader"] == "tum" and r["split"] is None
    assert r["num_classes"] == 40 and r["random_weights"] is False
    assert r["pixels"] > 0 and r["present_classes"] >= 3
    assert set(r["per_class_iou"].values()) == {1.0}
    assert {"wall", "floor"} <= set(r["per_class_iou"])  # class names, not ids


def test_text_report(capsys, synth):
    code, out, _ = run(capsys, "eval", "oracle", "--dataset", synth, *PERFECT)
    assert code == 0
    assert "mIoU             100.00 %" in out
    assert "pixel accuracy   100.00 %" in out
    assert "  wall" in out and "per-class IoU" in out


def test_noisy_oracle_matches_a_direct_confusion_matrix(capsys, synth):
    code, out, _ = run(capsys, "eval", "oracle", "--dataset", synth, "-o", "accuracy=0.7",
                       "--json")
    assert code == 0
    r = json.loads(out)
    seq = READERS.create("tum", path=str(synth))
    seg = SEGMENTERS.create("oracle", accuracy=0.7)
    cm = ConfusionMatrix(40)
    for frame in seq:
        cm.update(seg.predict(frame).argmax, frame.labels)
    expected = cm.result()
    assert r["miou"] == pytest.approx(expected.miou) and r["miou"] < 1.0
    assert r["pixel_accuracy"] == pytest.approx(expected.pixel_accuracy)
    assert r["pixels"] == expected.pixels


def test_limit(capsys, synth):
    code, out, _ = run(capsys, "eval", "oracle", "--dataset", synth, "--limit", "2", "--json")
    assert code == 0 and json.loads(out)["frames"] == 2


def test_reader_without_path(capsys):
    code, out, err = run(capsys, "eval", "oracle", "--dataset", "synthetic", "-r", "frames=2",
                         "-r", "width=48", "-r", "height=40", *PERFECT, "--json")
    assert code == 0, err
    r = json.loads(out)
    assert r["frames"] == 2 and r["miou"] == 1.0


def test_network_without_weights_is_refused(capsys, synth):
    code, out, err = run(capsys, "eval", "feagnet-v1", "--dataset", synth)
    assert code == 2 and out == ""
    assert "no trained weights" in err and "--allow-random" in err
    assert err.count("\n") == 1


def test_allow_random_warns_and_marks_the_record(capsys, synth):
    code, out, err = run(capsys, "eval", "feagnet-v1", "--dataset", synth, "--limit", "1",
                         "--allow-random", "--json")
    assert code == 0
    assert "RANDOM weights" in err
    r = json.loads(out)
    assert r["random_weights"] is True and r["weights"] is None and r["frames"] == 1


def test_weights_file(capsys, synth, tmp_path):
    import torch

    path = tmp_path / "v1.pt"
    torch.save(SEGMENTERS.create("feagnet-v1").module.state_dict(), path)
    code, out, err = run(capsys, "eval", "feagnet-v1", "--dataset", synth, "--limit", "1",
                         "--weights", path, "--json")
    assert code == 0, err
    r = json.loads(out)
    assert r["random_weights"] is False and r["weights"] == str(path)
    assert "RANDOM" not in err


def test_class_count_mismatch_exits_2(capsys, synth):
    code, _, err = run(capsys, "eval", "oracle", "--dataset", synth, "-o", "num_classes=19")
    assert code == 2
    assert "predicts 19 classes" in err and "labelled with 40" in err


# -- readers with and without split / limit ------------------------------------------------

def _frames(n: int, labels: bool = True) -> FrameList:
    intr = Intrinsics(20.0, 20.0, 7.5, 5.5, 16, 12)
    rng = np.random.default_rng(0)
    frames = []
    for i in range(n):
        lab = rng.integers(0, 5, (12, 16)).astype(np.uint8)
        lab[0] = 255
        frames.append(Frame(rgb=np.zeros((12, 16, 3), np.uint8),
                            depth=np.ones((12, 16), np.float32), intrinsics=intr,
                            pose=np.eye(4), timestamp=float(i),
                            labels=lab if labels else None, name=f"f{i}"))
    return FrameList("toy", intr, frames, meta={"class_names": [f"c{i}" for i in range(5)],
                                                "num_classes": 5})


@pytest.fixture
def split_reader():
    calls: list[dict] = []

    def factory(*, path: str, split: str = "all", limit: int | None = None) -> FrameList:
        calls.append({"path": path, "split": split, "limit": limit})
        return _frames(4 if limit is None else min(limit, 4))

    def plain(*, labelled: bool = True) -> FrameList:
        return _frames(3, labels=labelled)

    READERS.add("evaltest-split", factory)
    READERS.add("evaltest-plain", plain)
    try:
        yield calls
    finally:
        READERS.unregister("evaltest-split")
        READERS.unregister("evaltest-plain")


def test_split_and_limit_reach_the_reader(capsys, split_reader, tmp_path):
    code, out, err = run(capsys, "eval", "oracle", "--dataset", tmp_path, "--reader",
                         "evaltest-split", "-o", "num_classes=5", *PERFECT, "--json")
    assert code == 0, err
    assert split_reader[-1] == {"path": str(tmp_path), "split": "test", "limit": None}
    r = json.loads(out)
    assert r["split"] == "test" and r["frames"] == 4 and r["miou"] == 1.0
    assert set(r["per_class_iou"]) == {f"c{i}" for i in range(5)}  # the dataset's names
    code, out, _ = run(capsys, "eval", "oracle", "--dataset", tmp_path, "--reader",
                       "evaltest-split", "-o", "num_classes=5", "--split", "val", "--limit",
                       "2", "--json")
    assert code == 0
    assert split_reader[-1] == {"path": str(tmp_path), "split": "val", "limit": 2}
    assert json.loads(out)["frames"] == 2


def test_reader_without_splits(capsys, split_reader):
    code, _, err = run(capsys, "eval", "oracle", "--dataset", "evaltest-plain", "-o",
                       "num_classes=5", "--split", "test")
    assert code == 2 and "has no splits" in err
    code, out, _ = run(capsys, "eval", "oracle", "--dataset", "evaltest-plain", "-o",
                       "num_classes=5", "--limit", "2", "--json")
    assert code == 0 and json.loads(out)["frames"] == 2  # limit applied while reading
    code, _, err = run(capsys, "eval", "oracle", "--dataset", "evaltest-plain", "-o",
                       "num_classes=5", "-r", "labelled=false")
    assert code == 2 and "no ground-truth labels" in err


def test_missing_prepared_dataset(capsys, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("EVSMAP_DATA_ROOT", str(tmp_path / "nothing"))
    assert "nyuv2" in READERS.names()
    code, _, err = run(capsys, "eval", "oracle", "--dataset", "nyuv2")
    assert code == 2 and "datasets/nyuv2" in err


def test_help(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["eval", "--help"])
    assert exc.value.code == 0
    assert "--allow-random" in capsys.readouterr().out
