"""int8 quantisation (:mod:`evsmap.segmenters.quantize`, ``NetworkSegmenter.calibrate``) on a
tiny gated network and frames of the built-in synthetic scene."""

from __future__ import annotations

import json

import numpy as np
import onnx
import pytest

from evsmap.errors import EvsmapError, InvalidDataError, UnknownNameError
from evsmap.segmenters.quantize import (
    Int8Settings,
    evenly_spaced,
    float_nodes,
    reestimate_batchnorm,
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


def test_calibrate_quantises_and_caches(frames, state, tmp_path):
    cal = frames[0::2]
    first = network(state).calibrate(cal, cache_dir=tmp_path, source="test frames")
    assert not first.cached and first.path.is_file()
    assert first.path.parent == tmp_path and "-int8-u8s8-" in first.path.name
    again = network(state).calibrate(cal, cache_dir=tmp_path)
    assert again.cached and again.path == first.path and again.excluded == first.excluded
    other_frames = network(state).calibrate(cal[:-1], cache_dir=tmp_path)
    other_scheme = network(state).calibrate(cal, scheme="s8s8", cache_dir=tmp_path)
    assert not other_frames.cached and not other_scheme.cached
    assert len({first.path, other_frames.path, other_scheme.path}) == 3
    assert "-int8-s8s8-" in other_scheme.path.name

    sidecar = json.loads(first.path.with_suffix(".json").read_text())
    assert sidecar["settings"]["scheme"] == "u8s8" and sidecar["settings"]["method"] == "minmax"
    assert sidecar["calibration_frames"] == len(cal)
    assert sidecar["calibration_source"] == "test frames"
    assert sidecar["excluded"] == list(first.excluded)


def test_weights_change_the_cache_key(frames, state, tmp_path):
    q = network(state).calibrate(frames[:2], cache_dir=tmp_path)
    other = tiny_segmenter(backend="onnxruntime", seed=1)
    assert other.calibrate(frames[:2], cache_dir=tmp_path).path != q.path


def test_int8_agrees_with_fp32_on_held_out_frames(frames, state, tmp_path):
    fp32, int8 = network(state), network(state)
    int8.calibrate(frames[0::2], cache_dir=tmp_path)
    assert int8.precision == "int8"
    agreement = [float(np.mean(int8.predict(f, k=1).argmax == fp32.predict(f, k=1).argmax))
                 for f in frames[1::2]]
    labels = {int(c) for f in frames[1::2] for c in np.unique(fp32.predict(f, k=1).argmax)}
    assert len(labels) > 1  # not one class everywhere: agreement means something
    assert min(agreement) > 0.8, agreement


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
        tiny_segmenter(backend="onnxruntime").calibrate(frames[:1], scheme="u8u8")
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
