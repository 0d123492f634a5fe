"""``--precision int8`` and its options on ``evsmap speed``, ``eval``, ``predict`` and ``map``
(a tiny gated network, small synthetic frames)."""

from __future__ import annotations

import json

import pytest

from evsmap.cli.main import main
from evsmap.environment import instruction_set
from evsmap.segmenters.quantize import auto_scheme

SMALL_SYNTH = ["-r", "frames=4", "-r", "width=96", "-r", "height=64"]
INT8 = ["--precision", "int8", "--calibration-frames", "2"]
pytestmark = pytest.mark.isa  # the scheme auto picks depends on the instruction set


def run(capsys, *argv):
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse's own errors
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(code, err, *words):
    assert code == 2, err
    lines = [line for line in err.strip().splitlines() if ": warning: " not in line
             and ": note: " not in line]
    assert len(lines) == 1 and ": error: " in lines[0] and "Traceback" not in err, err
    for w in words:
        assert w in err, err


def test_speed_int8_record(capsys, tiny):
    code, out, err = run(capsys, "speed", tiny, *INT8, "--int8-scheme", "s8s8", "--runs", "2",
                         "--warmup", "0", "--threads", "1", "--json")
    assert code == 0, err
    r = json.loads(out)
    assert (r["precision"], r["int8_scheme"], r["backend"]) == ("int8", "s8s8", "onnxruntime")
    assert r["int8"]["calibration_frames"] == 2 and r["int8"]["fp32_nodes"] > 0
    assert "synthetic" in r["int8"]["calibration_source"] and "synthetic" in err
    assert r["int8_scheme_chosen_by"] == "given" and r["instruction_set"] == instruction_set()
    code, out, _ = run(capsys, "speed", tiny, "--runs", "1", "--warmup", "0", "--json")
    assert code == 0 and json.loads(out)["precision"] == "fp32"
    assert json.loads(out)["backend"] == "torch"  # the fp32 default is unchanged


def test_speed_int8_names_the_instruction_set_and_the_scheme_auto_chose(capsys, tiny):
    code, out, err = run(capsys, "speed", tiny, *INT8, "--runs", "1", "--warmup", "0",
                         "--threads", "1", "--json")
    assert code == 0, err
    r = json.loads(out)
    isa = instruction_set()
    assert (r["int8_scheme"], r["int8_scheme_chosen_by"]) == (auto_scheme(), f"auto for {isa}")
    assert r["instruction_set"] == isa and isa in r["int8"]["model"]
    assert f"({auto_scheme()}, auto for {isa})" in err
    code, out, err = run(capsys, "speed", tiny, *INT8, "--runs", "1", "--warmup", "0",
                         "--threads", "1")
    assert code == 0 and f"auto for {isa}" in out and f"({isa})" in out, out


@pytest.mark.parametrize("argv, words", [
    (["--precision", "int8", "--backend", "torch"], ["int8", "ONNX Runtime"]),
    (["--precision", "int4"], ["--precision"]),
    (["--precision", "int8", "--int8-scheme", "u4s4"], ["--int8-scheme"]),
    (["--precision", "int8", "--calibration-frames", "0"], ["--calibration-frames"]),
])
def test_speed_bad_values_exit_2(capsys, tiny, argv, words):
    code, _, err = run(capsys, "speed", tiny, *argv)
    assert code == 2 and "Traceback" not in err and all(w in err for w in words), err


def test_eval_int8_calibrates_on_the_scored_frames(capsys, tiny):
    code, out, err = run(capsys, "eval", tiny, "--dataset", "synthetic", *SMALL_SYNTH,
                         "-o", "num_classes=40", "--allow-random", *INT8, "--json")
    assert code == 0, err
    r = json.loads(out)
    assert (r["precision"], r["int8_scheme"], r["backend"]) == ("int8", auto_scheme(),
                                                                "onnxruntime")
    assert r["int8"]["calibration_source"].endswith("frames 0, 3")
    assert r["machine"]["instruction_set"] == r["instruction_set"] == instruction_set()
    assert "the frames processed" in r["int8"]["calibration_source"]


def test_predict_int8_held_out_calibration(capsys, tiny, tmp_path):
    code, out, err = run(capsys, "predict", tiny, "synthetic", *SMALL_SYNTH, "--out",
                         tmp_path / "pred", "--allow-random", "--frames", "2", *INT8,
                         "--calibrate-on", "synthetic", "--json")
    assert code == 0, err
    r = json.loads(out)
    assert (r["precision"], r["int8_scheme"]) == ("int8", auto_scheme())
    assert "held out" in r["int8"]["calibration_source"]
    assert r["machine"]["instruction_set"] == r["instruction_set"] == instruction_set()
    saved = json.loads((tmp_path / "pred" / "predict.json").read_text())
    assert saved["precision"] == "int8"


def test_map_int8_and_its_errors(capsys, tiny):
    code, out, err = run(capsys, "map", "synthetic", *SMALL_SYNTH, "--updater",
                         "multiclass-bayes", "--segmenter", tiny, "-s", "num_classes=40",
                         "--allow-random", "--frames", "2", *INT8, "--json")
    assert code == 0, err
    r = json.loads(out)
    assert (r["precision"], r["int8_scheme"]) == ("int8", auto_scheme())
    code, _, err = run(capsys, "map", "synthetic", *SMALL_SYNTH, "--updater", "orgb",
                       "--precision", "int8")
    one_line_error(code, err, "--precision int8", "no segmenter")
    code, _, err = run(capsys, "map", "synthetic", *SMALL_SYNTH, "--updater",
                       "multiclass-bayes", "--precision", "int8")
    one_line_error(code, err, "--precision int8", "not a network")


def test_map_text_names_precision_scheme_and_post_processing(capsys, tiny):
    code, out, err = run(capsys, "map", "synthetic", *SMALL_SYNTH, "--updater",
                         "multiclass-bayes", "--segmenter", "feagnet-v1", "-s",
                         "input_size=64x96", "-s", "postprocess=stride", "--allow-random",
                         "--frames", "2", *INT8)
    assert code == 0, err
    assert (f"network      int8 {auto_scheme()} (auto for {instruction_set()}), postprocess "
            f"stride\n") in out
    code, out, err = run(capsys, "map", "synthetic", *SMALL_SYNTH, "--updater",
                         "multiclass-bayes", "--segmenter", tiny, "-s", "num_classes=40",
                         "--allow-random", "--frames", "2")
    assert code == 0, err
    assert "network      fp32, postprocess network (the faithful path)\n" in out
    code, _, err = run(capsys, "map", "synthetic", *SMALL_SYNTH, "--updater",
                       "multiclass-bayes", "--segmenter", tiny, "-s", "postprocess=stride",
                       "--allow-random")
    one_line_error(code, err, "postprocess")  # only FEAGNet's factories take it
