"""``--skip-bad`` on ``evsmap map`` and ``evsmap info``: a corrupt frame stops the run with a
one-line error naming the file, or is left out and reported."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from evsmap.cli.main import main


@pytest.fixture(scope="module")
def broken_sequence(tmp_path_factory):
    out = tmp_path_factory.mktemp("seq") / "synth"
    assert main(["synth", "--out", str(out), "--frames", "5", "--width", "80",
                 "--height", "60"]) == 0
    depth = sorted((out / "depth").iterdir(), key=lambda p: float(p.stem))
    depth[1].write_bytes(depth[1].read_bytes()[:40])  # truncated PNG
    # an 8-bit depth image where a uint16 one is expected
    Image.fromarray(np.zeros((60, 80), dtype=np.uint8)).save(depth[3])
    return out, depth


def test_map_stops_at_the_first_bad_frame(broken_sequence, capsys, tmp_path):
    out, depth = broken_sequence
    target = tmp_path / "map.ot"
    code = main(["map", str(out), "--updater", "orgb", "--out", str(target)])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and depth[1].name in err and "Traceback" not in err
    assert not target.exists()


def test_map_skip_bad_reports_the_skipped_frames(broken_sequence, capsys):
    out, depth = broken_sequence
    assert main(["map", str(out), "--updater", "orgb", "--skip-bad", "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["frames"] == 3
    skipped = record["extra"]["skipped"]
    assert skipped["count"] == 2
    assert [f["index"] for f in skipped["frames"]] == [1, 3]
    assert depth[1].name in skipped["frames"][0]["reason"]
    assert depth[3].name in skipped["frames"][1]["reason"]
    assert "expected a 16-bit" in skipped["frames"][1]["reason"]


def test_info_skip_bad(broken_sequence, capsys):
    out, _ = broken_sequence
    assert main(["info", str(out)]) == 2
    capsys.readouterr()
    assert main(["info", str(out), "--skip-bad"]) == 0
    text = capsys.readouterr().out
    assert "frames      3" in text and "skipped 2 bad frame(s): #1" in text


def test_reader_options_reach_the_reader(broken_sequence, capsys):
    out, _ = broken_sequence
    assert main(["info", str(out), "-r", "nonsense=1"]) == 2
    assert "has no option 'nonsense'" in capsys.readouterr().err
