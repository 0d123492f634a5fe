import json

import numpy as np
from PIL import Image

from evsmap.cli.main import main
from evsmap.datasets.sunrgbd import prepare_sunrgbd


def run(capsys, *argv):
    try:
        code = main(list(argv))
    except SystemExit as exc:  # argparse errors
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def test_prepare_list_and_info(capsys, nyu_source, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, out, err = run(capsys, "datasets", "prepare", "nyuv2", "--from", str(nyu_source[0]))
    assert code == 0 and err == ""
    assert out.splitlines()[0].startswith(
        f"prepared nyuv2 in datasets/nyuv2 from {nyu_source[0]} (5 frames, ")
    assert "  train       3 frames  (official 795)" in out
    assert "  test        2 frames  (official 654)" in out
    assert (tmp_path / "datasets" / "nyuv2" / "evsmap-dataset.json").is_file()

    code, out, err = run(capsys, "datasets", "prepare", "nyuv2", "--from", str(nyu_source[0]))
    assert code == 2 and out == ""
    assert err == ("evsmap datasets: error: the output folder datasets/nyuv2: folder exists and "
                   "is not empty (pass --overwrite to replace it once the new one is "
                   "complete)\n")
    code, out, _ = run(capsys, "datasets", "prepare", "nyuv2", "--from", str(nyu_source[0]),
                       "--limit", "1", "--overwrite")
    assert code == 0 and "limited to the first 1 frames of each split" in out

    code, out, _ = run(capsys, "datasets", "list")
    assert code == 0
    assert out.split()[:5] == ["nyuv2", "datasets/nyuv2", "train", "1,", "test"]
    code, out, _ = run(capsys, "datasets", "list", "--json")
    listed = json.loads(out)
    assert listed[0]["name"] == "nyuv2" and listed[0]["splits"] == {"train": 1, "test": 1}

    code, out, _ = run(capsys, "info", "datasets/nyuv2", "--json")
    info = json.loads(out)
    assert code == 0 and info["reader"] == "nyuv2" and info["layout"] == "nyuv2"
    assert info["frames"] == 2 and info["poses"] is None
    assert info["labels"]["classes_present"] > 10
    code, out, _ = run(capsys, "info", "datasets/nyuv2", "-r", "split=test")
    assert code == 0 and "poses       none (segmentation dataset)" in out
    assert "frames      1" in out and "reader: nyuv2" in out


def test_info_on_mixed_sizes(capsys, sun_source, tmp_path):
    prepare_sunrgbd(sun_source[0], tmp_path / "sun")
    code, out, err = run(capsys, "info", str(tmp_path / "sun"))
    assert code == 0, err
    assert "reader: sunrgbd" in out and "frames      5" in out
    assert "sizes       16x12 x2, 20x10 x2, 18x14 x1  (mixed" in out
    assert "poses       none (segmentation dataset)" in out


def test_one_line_errors(capsys, nyu_prepared, tmp_path):
    code, out, err = run(capsys, "datasets", "prepare", "nyuv2", "--from", str(tmp_path),
                         "--out", str(tmp_path / "o"))
    assert code == 2 and out == ""
    assert err == (f"evsmap datasets: error: {tmp_path / 'nyu_depth_v2_labeled.mat'}: NYUv2 "
                   "labelled data not found\n")

    code, _, err = run(capsys, "datasets", "prepare", "nyuv2", "--from", str(tmp_path),
                       "--raw-depth")
    assert code == 2 and err == "evsmap datasets: error: --raw-depth applies to sunrgbd only\n"

    code, _, err = run(capsys, "datasets", "prepare", "kitti", "--from", str(tmp_path))
    assert code == 2 and "invalid choice: 'kitti'" in err and err.count("\n") == 1

    code, _, err = run(capsys, "datasets", "list", "--root", str(tmp_path / "none"))
    assert code == 2 and err.count("\n") == 1 and "none: no such folder" in err

    bad = nyu_prepared / "depth" / "000003.png"
    Image.fromarray(np.zeros((480, 640), np.uint8)).save(bad)
    code, _, err = run(capsys, "info", str(nyu_prepared))
    assert code == 2 and err.count("\n") == 1
    assert err.startswith(f"evsmap info: error: {bad}: expected a 16-bit")
    code, out, _ = run(capsys, "info", str(nyu_prepared), "--skip-bad", "--json")
    assert code == 0 and json.loads(out)["frames"] == 4
