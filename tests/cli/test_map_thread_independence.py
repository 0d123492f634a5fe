"""``evsmap map`` writes the same map bytes with the pipeline on and off, with ``--stage-threads
torch=1`` and ``2``, and from the labels ``evsmap predict`` writes (docs/cli.md, "Thread
independence"): FEAGNet-V1 (``--allow-random``) on the TUM sample (the frames' own size) and on a
320x240 synthetic room (resized to the network's 480x640 and back).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from evsmap.cli.main import main

pytestmark = pytest.mark.slow

FRAMES = 3
NETWORK = ["--segmenter", "feagnet-v1", "--allow-random"]
MODES = {
    "pipeline": ["--pipeline"],
    "no pipeline": ["--no-pipeline"],
    "pipeline, torch 2": ["--pipeline", "--stage-threads", "torch=2"],
    "no pipeline, torch 1": ["--no-pipeline", "--stage-threads", "torch=1"],
}


@pytest.fixture(scope="module", params=["tum", "synthetic 320x240"])
def sequence(request, tmp_path_factory) -> Path:
    if request.param == "tum":
        return request.getfixturevalue("tum_dir")
    out = tmp_path_factory.mktemp("room") / "room"
    assert main(["synth", "--out", str(out), "--frames", str(FRAMES), "--width", "320",
                 "--height", "240"]) == 0
    return out


def map_bytes(sequence: Path, out: Path, *args: str, updater: str = "multiclass-bayes"
              ) -> bytes:
    code = main(["map", str(sequence), "--updater", updater, "--frames", str(FRAMES),
                 "--out", str(out), "--overwrite", *args])
    assert code == 0
    return out.read_bytes()


def with_predicted_labels(sequence: Path, predicted: Path, out: Path) -> Path:
    """A copy of the TUM-layout ``sequence`` (its images linked) whose labels are the ones
    ``evsmap predict`` wrote to ``predicted``, holding the frames predicted only."""
    out.mkdir(parents=True)
    for item in sequence.iterdir():
        if item.is_dir():
            (out / item.name).symlink_to(item.resolve())
        elif item.name != "labels.txt":
            shutil.copy(item, out / item.name)
    record = json.loads((predicted / "predict.json").read_text())
    stems = [f["name"] for f in record["files"]]
    assert record["names"] == "stem"  # TUM frames are named by their depth timestamp
    depth = [line for line in (out / "depth.txt").read_text().splitlines(keepends=True)
             if line.startswith("#") or line.split()[0] in stems]
    (out / "depth.txt").write_text("".join(depth))
    (out / "labels.txt").write_text("".join(
        f"{stem} {(predicted / 'labels' / f'{stem}.png').resolve()}\n" for stem in stems))
    return out


def test_map_bytes_hold_across_pipeline_stage_threads_and_predicted_labels(sequence, tmp_path):
    maps = {name: map_bytes(sequence, tmp_path / "map.ot", *NETWORK, *mode)
            for name, mode in MODES.items()}
    assert len(set(maps.values())) == 1, {k: hash(v) for k, v in maps.items()}

    # the labels predict writes, at the network's input size map uses (480x640), mapped as
    # ground truth: multiclass-bayes reads the top class only, so the map is the same bytes
    assert main(["predict", "feagnet-v1", str(sequence), "--allow-random", "--size", "480x640",
                 "--frames", str(FRAMES), "--out", str(tmp_path / "predicted")]) == 0
    labelled = with_predicted_labels(sequence, tmp_path / "predicted",
                                     tmp_path / "labelled" / sequence.name)
    from_labels = map_bytes(labelled, tmp_path / "labels.ot", "--segmenter", "oracle",
                            "-s", "accuracy=1", "-s", "boundary_accuracy=1")
    assert from_labels == maps["pipeline"]


def test_a_map_of_the_probabilities_holds_with_the_pipeline_on_and_off(sequence, tmp_path):
    """classic-semantic fuses the top-3 probabilities, so it sees a change in their last bit:
    before the network kept its threads in the pipeline, these two maps differed on TUM."""
    on, off = (map_bytes(sequence, tmp_path / "map.ot", *NETWORK, *MODES[name],
                         updater="classic-semantic") for name in ("pipeline", "no pipeline"))
    assert on == off
