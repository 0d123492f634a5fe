"""int8 quantisation (:mod:`evsmap.segmenters.quantize`, ``NetworkSegmenter.calibrate``) on a
tiny gated network and frames of the built-in synthetic scene."""

from __future__ import annotations

import json
import platform

import numpy as np
import onnx
import pytest

from evsmap.errors import EvsmapError, InvalidDataError, UnknownNameError
from evsmap.segmenters.quantize import (
    SCHEMES,
    Int8Settings,
    auto_scheme,
    evenly_spaced,
    float_nodes,
    reestimate_batchnorm,
    resolve_scheme,
    rule_exclusions,
)
from evsmap.synth.sequence import SyntheticSequence
from tests.segmenters.int8_net import tiny_segmenter


@pytest.fixture(scope="module")
def frames():
    """12 small synthetic frames: even indices calibrate, odd ones are held out."""
    sequence = SyntheticSequence(frames=12, width=96, height=64)
    return [sequence.frame(i) for i in range(len(sequence))]


@pytest.fixture(scope="module")
def state(frames):
    """Seeded weights with BatchNorm statistics from the frames (activations of realistic
    scale; at BatchNorm's initial statistics the logits are biases alone)."""
    net = tiny_segmenter()
    reestimate_batchnorm(net.module, [net.preprocess(f) for f in frames[::2]])
    return net.module.state_dict()


def network(state, **options):
    net = tiny_segmenter(backend="onnxruntime", **options)
    net.module.load_state_dict(state)
    return net


@pytest.mark.isa
def test_calibrate_quantises_and_caches(frames, state, tmp_path):
    cal = frames[0::2]
    first = network(state).calibrate(cal, cache_dir=tmp_path, source="test frames")
    assert not first.cached and first.path.is_file()
    assert first.path.parent == tmp_path and f"-int8-{auto_scheme()}-" in first.path.name
    again = network(state).calibrate(cal, cache_dir=tmp_path)
    assert again.cached and again.path == first.path and again.excluded == first.excluded
    other_frames = network(state).calibrate(cal[:-1], cache_dir=tmp_path)
    other_scheme = network(state).calibrate(cal, scheme="s8s8", cache_dir=tmp_path)
    assert not other_frames.cached and not other_scheme.cached
    assert len({first.path, other_frames.path, other_scheme.path}) == 3
    assert "-int8-s8s8-" in other_scheme.path.name

    sidecar = json.loads(first.path.with_suffix(".json").read_text())
    assert sidecar["settings"]["scheme"] == auto_scheme()
    assert sidecar["settings"]["method"] == "minmax"
    assert sidecar["calibration_frames"] == len(cal)
    assert sidecar["calibration_source"] == "test frames"
    assert sidecar["excluded"] == list(first.excluded)


def test_weights_change_the_cache_key(frames, state, tmp_path):
    q = network(state).calibrate(frames[:2], cache_dir=tmp_path)
    other = tiny_segmenter(backend="onnxruntime", seed=1)
    assert other.calibrate(frames[:2], cache_dir=tmp_path).path != q.path


# Worst held-out frame's top-1 agreement of int8 with fp32 on these frames, measured per kind
# (docs/int8.md, "Per instruction set"; the saturating kind on AVX2 emulated by
# benchmarks/emulate_isa.py, which reproduced the AVX2 machine's CI failure to 0.004):
#   exact (AVX-512 VNNI):  u8s8 0.977, u8s7 0.969, u8u8 0.975, s8s8 0.977
#   saturating (AVX2):     u8s8 0.651, u8s7 0.970, u8u8 0.973, s8s8 0.651
SATURATING_SCHEMES = ("u8s8", "s8s8")
"""Where u8 x s8 products saturate (x86 without VNNI) these schemes lose accuracy."""
GOOD = 0.95
"""A scheme that is exact enough: every held-out frame above this."""
SATURATED = 0.85
"""A scheme that saturates: some frame below this."""


def _agreement(state, frames, tmp_path, scheme):
    fp32, int8 = network(state), network(state)
    int8.calibrate(frames[0::2], scheme=scheme, cache_dir=tmp_path)
    assert int8.precision == "int8"
    labels = {int(c) for f in frames[1::2] for c in np.unique(fp32.predict(f, k=1).argmax)}
    assert len(labels) > 1  # not one class everywhere: agreement means something
    return int8, [float(np.mean(int8.predict(f, k=1).argmax == fp32.predict(f, k=1).argmax))
                  for f in frames[1::2]]


@pytest.mark.isa
def test_int8_agrees_with_fp32_on_held_out_frames(frames, state, tmp_path):
    """The default (auto) scheme is exact enough on every instruction set."""
    int8, agreement = _agreement(state, frames, tmp_path, None)
    assert int8.int8_scheme == auto_scheme() and int8.int8_scheme_chosen_by.startswith("auto")
    assert min(agreement) > GOOD, (int8.int8_scheme, agreement)


@pytest.mark.isa
@pytest.mark.parametrize("scheme", SCHEMES)
def test_each_scheme_agrees_as_measured_on_this_instruction_set(frames, state, tmp_path,
                                                                 scheme):
    """What each scheme gives here: all are exact enough where int8 products accumulate
    exactly; without VNNI u8s8 (and s8s8, which ORT runs as u8s8 on x86) saturates and the
    7-bit or uint8 weights do not - the reason ``auto`` differs by instruction set."""
    from evsmap.environment import int8_exact

    int8, agreement = _agreement(state, frames, tmp_path, scheme)
    assert int8.int8_scheme_chosen_by == "given"
    if int8_exact() or scheme not in SATURATING_SCHEMES:
        assert min(agreement) > GOOD, agreement
    else:
        assert min(agreement) < SATURATED, agreement


@pytest.mark.isa
@pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64"), reason="x86 only")
def test_s8s8_runs_as_u8s8_on_x86(frames, state, tmp_path):
    a, b = network(state), network(state)
    a.calibrate(frames[0::2], scheme="u8s8", cache_dir=tmp_path)
    b.calibrate(frames[0::2], scheme="s8s8", cache_dir=tmp_path)
    inputs = a.preprocess(frames[1])
    np.testing.assert_array_equal(a.logits(inputs).numpy(), b.logits(inputs).numpy())


def test_auto_scheme_follows_the_instruction_set():
    assert resolve_scheme("auto", "avx512-vnni") == ("u8s8", "auto for avx512-vnni")
    assert resolve_scheme(None, "avx2") == ("u8s7", "auto for avx2")
    assert resolve_scheme("auto", "avx512") == ("u8s7", "auto for avx512")
    assert resolve_scheme("auto", "arm64-dotprod")[0] == "u8s8"
    assert resolve_scheme("u8s8", "avx2") == ("u8s8", "given")
    with pytest.raises(UnknownNameError, match="auto, u8s8"):
        resolve_scheme("u4s4")


def test_a_model_for_another_instruction_set_is_not_reused(frames, state, tmp_path):
    from evsmap.environment import instruction_set
    from evsmap.segmenters.quantize import quantize_model

    net = network(state)
    inputs = [dict(zip(net.input_names, (t.numpy() for t in net.preprocess(f)), strict=True))
              for f in frames[:2]]
    fp32 = net._fp32_onnx(net.preprocess(frames[0]), tmp_path)
    here = quantize_model(fp32_path=fp32, calibration=inputs, cache_dir=tmp_path)
    other_isa = "avx2" if instruction_set() != "avx2" else "avx512-vnni"
    there = quantize_model(fp32_path=fp32, calibration=inputs, cache_dir=tmp_path,
                           settings=Int8Settings(instruction_set=other_isa))
    assert not there.cached and there.path != here.path
    assert here.instruction_set == instruction_set() and there.instruction_set == other_isa
    assert f"-{instruction_set()}-" in here.path.name and f"-{other_isa}-" in there.path.name
    assert quantize_model(fp32_path=fp32, calibration=inputs, cache_dir=tmp_path).cached
    sidecar = json.loads(here.path.with_suffix(".json").read_text())
    assert sidecar["settings"]["instruction_set"] == instruction_set()


def test_rule_nodes_stay_fp32_in_the_saved_graph(frames, state, tmp_path):
    q = network(state).calibrate(frames[0::2], cache_dir=tmp_path)
    model = onnx.load(str(q.path))
    ops = {n.name: n.op_type for n in model.graph.node}
    rules = rule_exclusions(model)
    assert {ops[n] for n in rules} >= {"Sigmoid", "Conv", "Resize"}  # gate, classifier, tail
    assert all(float_nodes(q.path, rules).values())
    quantised = [n for n, op in ops.items() if op == "Conv" and n not in q.excluded]
    assert quantised and not any(float_nodes(q.path, quantised).values())


def test_without_rules_every_conv_is_quantised(frames, state, tmp_path):
    from evsmap.segmenters.quantize import quantize_model

    net = network(state)
    inputs = [dict(zip(net.input_names, (t.numpy() for t in net.preprocess(f)), strict=True))
              for f in frames[0::2]]
    q = quantize_model(fp32_path=net._fp32_onnx(net.preprocess(frames[0]), tmp_path),
                       calibration=inputs, settings=Int8Settings(rules=False),
                       cache_dir=tmp_path)
    assert q.excluded == ()
    convs = [n.name for n in onnx.load(str(q.path)).graph.node if n.op_type == "Conv"]
    assert not any(float_nodes(q.path, convs).values())


def test_auto_exclude_ranks_tensors_and_keeps_their_nodes_fp32(frames, state, tmp_path):
    rules = network(state).calibrate(frames[0::2], cache_dir=tmp_path)
    auto = network(state).calibrate(frames[0::2], auto_exclude=2, cache_dir=tmp_path)
    assert len(auto.auto_ranking) == 2
    assert auto.auto_ranking[0][1] <= auto.auto_ranking[1][1]  # worst SQNR first
    assert set(rules.excluded) < set(auto.excluded)


def test_int8_needs_onnxruntime_and_calibration(frames, state):
    with pytest.raises(InvalidDataError, match="ONNX Runtime"):
        tiny_segmenter(backend="torch", precision="int8")
    with pytest.raises(InvalidDataError, match="ONNX Runtime"):
        tiny_segmenter(backend="torch").calibrate(frames[:1])
    uncalibrated = tiny_segmenter(backend="onnxruntime", precision="int8")
    with pytest.raises(EvsmapError, match="calibrat"):
        uncalibrated.predict(frames[0])
    with pytest.raises(UnknownNameError, match="int8 scheme"):
        tiny_segmenter(backend="onnxruntime").calibrate(frames[:1], scheme="u4s4")
    with pytest.raises(InvalidDataError, match="at least one frame"):
        tiny_segmenter(backend="onnxruntime").calibrate([])


def test_fp32_record_is_unchanged(state):
    net = network(state)
    assert net.precision == "fp32" and net.quantization is None
    assert net.precision_record() == {"precision": "fp32"}


def test_evenly_spaced():
    assert evenly_spaced(60, 4) == [0, 20, 39, 59]
    assert evenly_spaced(3, 16) == [0, 1, 2]
    assert evenly_spaced(10, 1) == [5]
    with pytest.raises(InvalidDataError):
        evenly_spaced(0, 4)
