"""``--device`` and the GPU-era options on the commands (speed, map, eval, predict, train,
reproduce, gate): on a machine without a GPU every GPU option refuses in one line with exit 2
and writes nothing; the CPU side of each new option works (torch.compile's backend is tested in
tests/measure/test_speed_devices.py, on a smaller module)."""

from __future__ import annotations

import json

import pytest
import torch

from tests.cli.test_int8_cli import one_line_error, run
from tests.segmenters.int8_net import NAME

SMALL_SYNTH = ["-r", "frames=2", "-r", "width=96", "-r", "height=64"]
# the command-line helpers of the int8 tests; the tiny network: conftest.py's `tiny`
pytestmark = pytest.mark.skipif(torch.cuda.is_available(), reason="tests the refusals where "
                                "there is no GPU")


@pytest.mark.parametrize("argv", [
    ["speed", NAME, "--device", "cuda"],
    ["speed", NAME, "--device", "cuda:1", "--precision", "fp16"],
    ["eval", NAME, "--dataset", "synthetic", *SMALL_SYNTH, "-o", "num_classes=40",
     "--allow-random", "--device", "cuda"],
    ["map", "synthetic", *SMALL_SYNTH, "--updater", "multiclass-bayes", "--segmenter", NAME,
     "-s", "num_classes=40", "--allow-random", "--device", "cuda"],
])
def test_a_gpu_where_there_is_none_is_one_line(capsys, tiny, argv):
    code, out, err = run(capsys, *argv)
    one_line_error(code, err, "--device cuda", "torch")
    assert out == ""


def test_predict_on_a_missing_gpu_writes_nothing(capsys, tiny, tmp_path):
    code, _, err = run(capsys, "predict", NAME, "synthetic", *SMALL_SYNTH, "--out",
                       tmp_path / "pred", "--allow-random", "--device", "cuda")
    one_line_error(code, err, "--device cuda")
    assert not (tmp_path / "pred").exists() or not any((tmp_path / "pred").iterdir())


@pytest.mark.parametrize("argv, words", [
    (["speed", NAME, "--device", "gpu"], ["--device", "unknown device 'gpu'"]),
    (["speed", NAME, "--provider", "cuda"], ["provider cuda", "does not run on"]),
    (["speed", NAME, "--backend", "torch", "--provider", "cpu"], ["needs backend onnxruntime"]),
    (["speed", NAME, "--backend", "onnxruntime", "--precision", "fp16"], ["autocast",
                                                                          "--backend torch"]),
    (["speed", NAME, "--backend", "onnxruntime", "--device", "cuda", "--provider", "tensorrt",
      "--precision", "fp16"], ["--device cuda"]),
    (["speed", NAME, "--precision", "int8", "--device", "cuda"], ["--device cuda"]),
])
def test_speed_refusals(capsys, tiny, argv, words):
    code, _, err = run(capsys, *argv)
    one_line_error(code, err, *words)


def test_map_device_without_a_network_is_refused(capsys):
    code, _, err = run(capsys, "map", "synthetic", *SMALL_SYNTH, "--updater", "orgb",
                       "--device", "cuda")
    one_line_error(code, err, "--device cuda:0", "runs no segmenter")
    code, _, err = run(capsys, "map", "synthetic", *SMALL_SYNTH, "--updater",
                       "multiclass-bayes", "--precision", "bf16")
    one_line_error(code, err, "--precision bf16", "not a network")


def test_speed_bf16_on_the_cpu(capsys, tiny):
    code, out, err = run(capsys, "speed", NAME, "--precision", "bf16", "--runs", "2",
                         "--warmup", "0", "--threads", "1", "--json")
    assert code == 0, err
    r = json.loads(out)
    assert (r["autocast"], r["device"], r["timer"], r["backend"]) == ("bf16", "cpu",
                                                                      "host clock", "torch")
    assert r["precision"] == "bf16"
    code, out, err = run(capsys, "speed", NAME, "--precision", "bf16", "--runs", "2",
                         "--warmup", "0", "--threads", "1")
    assert code == 0 and "bf16 autocast" in out, out


def test_eval_bf16_on_the_cpu_records_its_precision(capsys, tiny):
    code, out, err = run(capsys, "eval", NAME, "--dataset", "synthetic", *SMALL_SYNTH, "-o",
                         "num_classes=40", "--allow-random", "--precision", "bf16", "--json")
    assert code == 0, err
    r = json.loads(out)
    assert r["precision"] == "bf16" and "device" not in r and "gpu" not in r
    assert 0.0 <= r["miou"] <= 1.0


def test_train_reproduce_and_gate_refuse_a_missing_gpu(capsys, tmp_path):
    code, _, err = run(capsys, "train", "feagnet-v1", "--dataset", "synthetic", "--out",
                       tmp_path / "run", "--device", "cuda")
    one_line_error(code, err, "--device cuda", "torch")
    assert not (tmp_path / "run").exists()
    code, _, err = run(capsys, "reproduce", "--quick", "--device", "cuda", "--out",
                       tmp_path / "rep")
    one_line_error(code, err, "--device cuda", "torch")
    assert not (tmp_path / "rep").exists()
    code, _, err = run(capsys, "gate", "--device", "cuda", "--only", "net/feagnet-s/torch")
    one_line_error(code, err, "--device cuda", "torch")
    code, _, err = run(capsys, "gate", "--device", "gpu")
    one_line_error(code, err, "--device", "unknown device")
