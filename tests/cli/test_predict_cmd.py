"""``evsmap predict`` (per-frame label images, overlays, top-3 files) and ``evsmap map -s``."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from evsmap.cli.main import main
from evsmap.measure.mapping import map_sequence
from evsmap.registry import READERS, SEGMENTERS, UPDATERS

PERFECT = ["-o", "accuracy=1.0", "-o", "boundary_accuracy=1.0"]
SMALL = ["--allow-random", "--size", "96x128"]  # a random network, run small to stay fast


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(code, err, *words):
    assert code == 2, err
    lines = [line for line in err.strip().splitlines() if ": warning: " not in line]
    assert len(lines) == 1 and ": error: " in lines[0], err
    assert "Traceback" not in err
    for w in words:
        assert w in err, err


def read_png(path):
    with Image.open(path) as im:
        return im.mode, np.asarray(im)


@pytest.fixture(scope="module")
def synth(tmp_path_factory):
    out = tmp_path_factory.mktemp("predict") / "syn"
    assert main(["synth", "--out", str(out), "--frames", "3", "--width", "80",
                 "--height", "60"]) == 0
    return out


@pytest.fixture(scope="module")
def oracle_nyu(tmp_path_factory, nyuv2_samples_dir):
    out = tmp_path_factory.mktemp("predict") / "oracle"
    code = main(["predict", "oracle", str(nyuv2_samples_dir), "--out", str(out), "--topk",
                 "--overlay", "--json", *PERFECT])
    assert code == 0
    return out


def test_network_writes_labels_at_the_frame_size(capsys, tmp_path, nyuv2_samples_dir):
    out = tmp_path / "pred"
    code, stdout, err = run(capsys, "predict", "feagnet-v1", nyuv2_samples_dir, "--out", out,
                            *SMALL, "--json")
    assert code == 0, err
    assert "RANDOM" in err  # the random-weights warning
    for name in ("000433", "000464"):
        mode, labels = read_png(out / "labels" / f"{name}.png")
        assert mode == "L" and labels.dtype == np.uint8 and labels.shape == (480, 640)
        assert labels.max() < 40
    assert sorted(p.name for p in out.iterdir()) == ["labels", "predict.json"]
    r = json.loads(stdout)
    assert r == json.loads((out / "predict.json").read_text())
    assert r["model"] == "feagnet-v1" and r["random_weights"] is True and r["weights"] is None
    assert r["input_size"] == [96, 128] and r["frame_sizes"] == [[480, 640]]
    assert r["frames"] == 2 and r["names"] == "stem" and r["backend"] == "torch"
    assert len(r["ms_per_frame"]) == 2 and r["ms_per_frame_median"] > 0
    assert abs(sum(r["classes_seen"].values()) - 1.0) < 1e-4
    assert [f["labels"] for f in r["files"]] == ["labels/000433.png", "labels/000464.png"]
    assert r["out"] == str(out.resolve())


def test_network_runs_at_the_frame_resolution_by_default(capsys, tmp_path, synth):
    code, stdout, err = run(capsys, "predict", "feagnet-v1", synth, "--out", tmp_path / "p",
                            "--allow-random", "--frames", "1", "--json")
    assert code == 0, err
    r = json.loads(stdout)
    assert r["input_size"] == "frame" and r["frame_sizes"] == [[60, 80]]
    assert read_png(tmp_path / "p" / r["files"][0]["labels"])[1].shape == (60, 80)


def test_perfect_oracle_labels_equal_the_ground_truth(oracle_nyu, nyuv2_samples_dir):
    for name in ("000433", "000464"):
        _, labels = read_png(oracle_nyu / "labels" / f"{name}.png")
        _, truth = read_png(nyuv2_samples_dir / "label40" / f"{name}.png")
        labelled = truth != 255
        assert labelled.mean() > 0.5
        np.testing.assert_array_equal(labels[labelled], truth[labelled])


def test_topk_files_hold_the_top3_and_agree_with_the_labels(oracle_nyu):
    r = json.loads((oracle_nyu / "predict.json").read_text())
    assert r["files"][0]["topk"] == "topk/000433.npz"
    for name in ("000433", "000464"):
        with np.load(oracle_nyu / "topk" / f"{name}.npz") as z:
            classes, probs = z["classes"], z["probs"]
            assert int(z["num_classes"]) == 40
        assert classes.shape == probs.shape == (480, 640, 3)
        assert classes.dtype == np.uint8 and probs.dtype == np.float32
        _, labels = read_png(oracle_nyu / "labels" / f"{name}.png")
        np.testing.assert_array_equal(classes[..., 0], labels)
        assert np.all(np.diff(probs, axis=2) <= 1e-6) and np.all(probs.sum(axis=2) <= 1 + 1e-4)
        assert np.all(classes[..., 0] != classes[..., 1])


def test_overlay_is_the_frame_size_and_blends_the_class_colours(oracle_nyu, nyuv2_samples_dir):
    from evsmap.classes import palette

    mode, overlay = read_png(oracle_nyu / "overlays" / "000433.png")
    assert mode == "RGB" and overlay.shape == (480, 640, 3)
    _, rgb = read_png(nyuv2_samples_dir / "rgb" / "000433.png")
    _, labels = read_png(oracle_nyu / "labels" / "000433.png")
    # away from the legend (top-left), each pixel is half RGB, half its class colour
    expected = np.rint(0.5 * rgb.astype(np.float64) + 0.5 * palette(40)[labels])
    region = (slice(None), slice(320, None))
    assert np.abs(overlay[region].astype(np.float64) - expected[region]).max() <= 1
    assert not np.array_equal(overlay[:40, :40], expected[:40, :40])  # the legend is there


def test_tum_frames_are_named_by_their_depth_timestamp(capsys, tmp_path, tum_dir):
    out = tmp_path / "tum"
    code, stdout, err = run(capsys, "predict", "feagnet-v1", tum_dir, "--out", out, *SMALL,
                            "--frames", "2", "--json")
    assert code == 0, err
    seq = READERS.create("tum", path=str(tum_dir))
    stems = [seq.depth_files[i].stem for i in range(2)]
    assert stems[0].startswith("1305031") and "." in stems[0]
    assert sorted(p.stem for p in (out / "labels").iterdir()) == stems
    assert [f["name"] for f in json.loads(stdout)["files"]] == stems


def test_synth_folder_names_match_its_own_label_files(capsys, tmp_path, synth):
    out = tmp_path / "syn"
    code, _, err = run(capsys, "predict", "oracle", synth, "--out", out, *PERFECT)
    assert code == 0, err
    written = sorted(p.name for p in (out / "labels").iterdir())
    assert written == sorted(p.name for p in (synth / "labels").iterdir())
    for name in written:
        _, labels = read_png(out / "labels" / name)
        _, truth = read_png(synth / "labels" / name)
        np.testing.assert_array_equal(labels[truth != 255], truth[truth != 255])


def test_a_sequence_without_files_is_named_by_index(capsys, tmp_path):
    out = tmp_path / "idx"
    code, stdout, err = run(capsys, "predict", "oracle", "synthetic", "-r", "frames=2",
                            "-r", "width=80", "-r", "height=60", "--out", out, "--json")
    assert code == 0, err
    assert sorted(p.name for p in (out / "labels").iterdir()) == ["000000.png", "000001.png"]
    assert json.loads(stdout)["names"] == "index"


def test_text_summary(capsys, tmp_path, synth):
    code, stdout, _ = run(capsys, "predict", "oracle", synth, "--out", tmp_path / "t",
                          "--frames", "2")
    assert code == 0
    assert "oracle" in stdout and "2 frames, named by file stems" in stdout
    assert "ms per frame" in stdout and "wall" in stdout and "labels/" in stdout


def test_a_network_without_weights_is_refused(capsys, tmp_path, synth):
    code, _, err = run(capsys, "predict", "feagnet-v1", synth, "--out", tmp_path / "w")
    one_line_error(code, err, "--weights", "--allow-random")
    assert not (tmp_path / "w").exists()
    code, _, err = run(capsys, "predict", "feagnet-v1", synth, "--out", tmp_path / "w",
                       "--weights", tmp_path / "missing.pt")
    one_line_error(code, err, "missing.pt")


def test_an_existing_output_is_refused_unless_overwrite(capsys, tmp_path, synth):
    out = tmp_path / "busy"
    out.mkdir()
    (out / "keep.txt").write_text("x")
    code, _, err = run(capsys, "predict", "oracle", synth, "--out", out)
    one_line_error(code, err, "--overwrite")
    assert (out / "keep.txt").read_text() == "x"
    code, _, err = run(capsys, "predict", "oracle", synth, "--out", out, "--overwrite",
                       "--frames", "1")
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["labels", "predict.json"]


def test_an_interrupted_run_leaves_no_partial_output(capsys, tmp_path, synth, monkeypatch):
    oracle = type(SEGMENTERS.create("oracle"))
    real, calls = oracle.predict, []

    def predict(self, frame, **kw):
        calls.append(frame.name)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(self, frame, **kw)

    monkeypatch.setattr(oracle, "predict", predict)
    code, _, _ = run(capsys, "predict", "oracle", synth, "--out", tmp_path / "cut")
    assert code == 130 and len(calls) == 2
    assert list(tmp_path.iterdir()) == []  # neither the folder nor its staging copy


@pytest.mark.parametrize("args, words", [
    (["--size", "48x64"], ["--size", "oracle"]),
    (["-o", "nope=1"], ["nope", "accepted"]),
    (["-o", "input_size=48"], ["--size"]),
    (["--frames", "1", "--reader", "tum", "-r", "nope=1"], ["nope"]),
])
def test_bad_options_are_one_line_errors(capsys, tmp_path, synth, args, words):
    code, _, err = run(capsys, "predict", "oracle", synth, "--out", tmp_path / "x", *args)
    one_line_error(code, err, *words)


def test_a_size_too_small_for_the_network_is_a_one_line_error(capsys, tmp_path, synth):
    code, _, err = run(capsys, "predict", "feagnet-v1", synth, "--out", tmp_path / "x",
                       "--allow-random", "--size", "8x8", "--frames", "1")
    one_line_error(code, err, "8x8", "--size")
    assert not (tmp_path / "x").exists()


def test_bad_size_is_refused_by_the_parser(capsys, tmp_path, synth):
    with pytest.raises(SystemExit) as exc:
        main(["predict", "oracle", str(synth), "--out", str(tmp_path / "x"), "--size", "48"])
    assert exc.value.code == 2
    assert "HEIGHTxWIDTH" in capsys.readouterr().err


def test_predict_help_imports_no_heavy_library():
    probe = ("import sys; from evsmap.cli.main import main\n"
             "try:\n    main(['predict', '--help'])\nexcept SystemExit:\n    pass\n"
             "print(sorted(m for m in ('torch', 'onnxruntime', 'open3d', 'matplotlib') "
             "if m in sys.modules), file=sys.stderr)")
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.strip().splitlines()[-1] == "[]"
    assert "--overlay" in proc.stdout and "--topk" in proc.stdout


# -- evsmap map -s ----------------------------------------------------------------------------
def test_map_passes_segmenter_options(capsys, tmp_path, synth):
    noisy, default = tmp_path / "noisy.ot", tmp_path / "default.ot"
    base = ["map", synth, "--updater", "multiclass-bayes", "--resolution", "0.1"]
    assert run(capsys, *base, "--out", default)[0] == 0
    code, _, err = run(capsys, *base, "--out", noisy, "-s", "accuracy=0.3", "-s",
                       "seed=4")
    assert code == 0, err
    assert noisy.read_bytes() != default.read_bytes()
    # the same map as the Python API with the same oracle options
    updater = UPDATERS.create("multiclass-bayes", resolution=0.1, max_range=5.0)
    direct = tmp_path / "direct.ot"
    map_sequence(READERS.create("tum", path=str(synth)), updater,
                 updater_name="multiclass-bayes",
                 segmenter=SEGMENTERS.create("oracle", accuracy=0.3, seed=4),
                 segmenter_name="oracle", out=direct)
    assert direct.read_bytes() == noisy.read_bytes()


def test_map_segmenter_option_errors_are_one_line(capsys, synth):
    code, _, err = run(capsys, "map", synth, "--updater", "multiclass-bayes", "-s", "nope=1")
    one_line_error(code, err, "oracle", "nope", "accepted")
    code, _, err = run(capsys, "map", synth, "--updater", "orgb", "-s", "accuracy=0.5")
    one_line_error(code, err, "-s", "--segmenter")
