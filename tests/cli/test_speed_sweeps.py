"""``evsmap speed --batch`` and ``--sweep-backends`` on the CPU (the tiny network of the int8
tests, conftest.py's ``tiny``), the new single-run options, and the combinations refused in
one line with exit 2."""

from __future__ import annotations

import json

import pytest

from evsmap.registry import SEGMENTERS
from tests.cli.test_int8_cli import one_line_error, run
from tests.segmenters.int8_net import NAME, tiny_segmenter

QUICK = ["--budget", "0.3", "--threads", "1", "--height", "32", "--width", "48"]
TWIN = "tiny-int8-test-net-twin"


@pytest.fixture
def twin(tiny):
    """A second tiny network, the batch sweep's reference."""
    SEGMENTERS.add(TWIN, lambda **kw: tiny_segmenter(**{**kw, "num_classes": 7}))
    yield TWIN
    SEGMENTERS.unregister(TWIN)


def test_batch_sweep_json_has_fps_per_image_and_the_ratio(capsys, twin):
    code, out, err = run(capsys, "speed", NAME, "--batch", "1,2", "--reference", twin, *QUICK,
                         "--json")
    assert code == 0, err
    r = json.loads(out)
    assert (r["sweep"], r["reference"], r["batches"], r["device"]) == ("batch", twin, [1, 2],
                                                                       "cpu")
    assert r["policy"]["budget_s"] == 0.3
    points = {(p["network"], p["batch"]): p for p in r["points"]}
    assert set(points) == {(NAME, 1), (twin, 1), (NAME, 2), (twin, 2)}
    for (_, batch), p in points.items():
        assert p["fps_per_image"] == pytest.approx(batch * 1000 / p["ms_median"])
        assert p["speed"]["runs"] >= 3 and p["refused"] is None
        ref = points[(twin, batch)]["fps_per_image"]
        assert p["ratio_to_reference"] == pytest.approx(p["fps_per_image"] / ref)
    code, out, err = run(capsys, "speed", NAME, "--batch", "2", "--reference", "none", *QUICK)
    assert code == 0, err
    assert "FPS/image" in out and NAME in out and twin not in out


def test_backend_sweep_json_refuses_gpu_variants_and_names_the_fastest(capsys, tiny):
    code, out, err = run(capsys, "speed", NAME, "--sweep-backends", "--variants",
                         "cuda-graph-fp32,eager-bf16", *QUICK, "--json")
    assert code == 0, err
    r = json.loads(out)
    assert r["sweep"] == "backends" and r["reference"] == "eager-fp32"
    rows = {v["variant"]: v for v in r["results"]}
    assert list(rows) == ["eager-fp32", "cuda-graph-fp32", "eager-bf16"]
    assert rows["cuda-graph-fp32"]["status"] == "refused"
    assert "needs a GPU" in rows["cuda-graph-fp32"]["why"]
    assert 0 < rows["eager-bf16"]["label_agreement"] <= 1
    assert r["fastest"] in {"eager-fp32", "eager-bf16"}
    code, out, err = run(capsys, "speed", NAME, "--sweep-backends", "--variants",
                         "cuda-graph-fp32", *QUICK)
    assert code == 0, err
    assert "cuda-graph-fp32                refused: " in out
    assert "fastest with eager fp32's labels: eager-fp32" in out


def test_channels_last_single_run_is_recorded(capsys, tiny):
    code, out, err = run(capsys, "speed", NAME, "--channels-last", "--runs", "2", "--warmup",
                         "0", "--threads", "1", "--json")
    assert code == 0, err
    r = json.loads(out)
    assert r["channels_last"] is True and r["backend"] == "torch"


@pytest.mark.parametrize("argv, words", [
    (["--batch", "1,0"], ["--batch", "distinct batch sizes"]),
    (["--batch", "2,2"], ["--batch", "distinct batch sizes"]),
    (["--batch", "a"], ["--batch"]),
    (["--budget", "0"], ["--budget", "positive"]),
    (["--batch", "1", "--sweep-backends"], ["two sweeps"]),
    (["--reference", "esanet-r34-nbt1d"], ["--reference", "--batch"]),
    (["--variants", "eager-*"], ["--variants", "--sweep-backends"]),
    (["--sweep-backends", "--variants", "warp-drive"], ["matches none"]),
    (["--sweep-backends", "--precision", "fp16"], ["--precision fp16", "--variants"]),
    (["--sweep-backends", "--backend", "torch-compile"], ["--backend", "--variants"]),
    (["--batch", "1,2", "--backend", "onnxruntime"], ["--batch", "torch backends"]),
    (["--batch", "1", "--reference", "oracle"], ["--reference oracle", "not a network"]),
    (["--compile-mode", "max-autotune"], ["--compile-mode", "--backend torch-compile"]),
    (["--compile-mode", "fastest"], ["--compile-mode", "invalid choice"]),
    (["--backend", "torch-cuda-graph"], ["torch-cuda-graph", "needs a GPU"]),
    (["--backend", "onnxruntime", "--channels-last"], ["channels-last", "ONNX Runtime"]),
])
def test_bad_values_and_combinations_are_one_line(capsys, tiny, argv, words):
    code, out, err = run(capsys, "speed", NAME, *argv, "--threads", "1", "--runs", "2")
    one_line_error(code, err, *words)
    assert out == ""


def test_the_spelled_out_names_match_the_measure_layer():
    from evsmap.cli import speed_cmd
    from evsmap.measure import batch_sweep, speed_backends

    assert speed_cmd.COMPILE_MODES == speed_backends.COMPILE_MODES
    assert sorted(speed_cmd.BACKENDS) == sorted(speed_backends.BACKENDS)
    assert speed_cmd.DEFAULT_BATCHES == batch_sweep.DEFAULT_BATCHES
    assert speed_cmd.REFERENCE == batch_sweep.REFERENCE
