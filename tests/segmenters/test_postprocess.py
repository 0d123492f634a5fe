"""How logits become an observation (``postprocess``): the fused resize + top-k against the
network's own resize, only the pixels the map reads, the nearest-neighbour ``stride`` variant,
and the same map whichever exact path ran."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from evsmap.classes import class_names_for
from evsmap.data import SemanticObservation
from evsmap.errors import InvalidDataError, UnknownNameError
from evsmap.measure.engine import run_mapping
from evsmap.measure.evaluators import MapFiles
from evsmap.models.layers import StridedLogits, resize_to
from evsmap.registry import READERS, SEGMENTERS, UPDATERS
from evsmap.segmenters import topk
from evsmap.segmenters.network import NetworkSegmenter
from evsmap.updaters.base import FramePoints

CLASSES = 7


class Tiny(StridedLogits, nn.Module):
    """RGB-D logits at stride 4 from one strided convolution, resized like FEAGNet's head."""

    def __init__(self) -> None:
        super().__init__()
        torch.manual_seed(0)
        self.conv = nn.Conv2d(4, CLASSES, 5, stride=4, padding=2)

    def forward(self, rgb, depth):
        return self.final_resize(self.conv(torch.cat([rgb, depth], 1)) * 4, rgb.shape[-2:])


def _tiny(postprocess: str, size=(60, 80)) -> NetworkSegmenter:
    return NetworkSegmenter(name="tiny", module=Tiny(), num_classes=CLASSES,
                            class_names=class_names_for(CLASSES), uses_depth=True,
                            default_size=size, postprocess=postprocess)


@pytest.mark.parametrize(("low", "size", "k"), [((12, 16), (48, 64), 3), ((15, 20), (60, 80), 2),
                                                ((7, 9), (50, 61), 1), ((1, 5), (3, 17), 3)])
def test_fused_equals_the_resize_then_the_top_k(low, size, k):
    gen = torch.Generator().manual_seed(sum(low))
    logits = torch.randn(1, 11, *low, generator=gen) * 4
    want_c, want_p = topk.top_k_softmax(resize_to(logits, size)[0], k)
    classes, probs = topk.top_k_upsampled(logits[0], size, k)
    assert classes.dtype == np.int16 and probs.dtype == np.float32
    assert np.array_equal(classes, want_c)
    np.testing.assert_allclose(probs, want_p, rtol=2e-6, atol=1e-7)


def test_fused_computes_only_the_pixels_asked_for(monkeypatch):
    monkeypatch.setattr(topk, "BLOCK", 37)  # several blocks, runs of a row split across them
    gen = torch.Generator().manual_seed(5)
    logits = torch.randn(9, 10, 14, generator=gen) * 3
    size = (40, 56)
    every_c, every_p = topk.top_k_upsampled(logits, size, 3)
    mask = np.random.default_rng(1).random(size) < 0.6
    classes, probs = topk.top_k_upsampled(logits, size, 3, np.flatnonzero(mask))
    assert np.array_equal(classes[mask], every_c[mask])
    assert np.array_equal(probs[mask], every_p[mask])  # bit for bit: blocks do not matter
    assert not classes[~mask].any() and not probs[~mask].any()
    empty_c, empty_p = topk.top_k_upsampled(logits, size, 3, np.array([], np.int64))
    assert not empty_c.any() and not empty_p.any()


def test_nearest_observation_takes_the_pixel_under_each_centre():
    classes = np.arange(6, dtype=np.int16).reshape(2, 3, 1)
    probs = np.linspace(0.1, 0.6, 6, dtype=np.float32).reshape(2, 3, 1)
    c, p = topk.nearest_observation(classes, probs, (4, 6))
    assert c[..., 0].tolist() == [[0, 0, 1, 1, 2, 2], [0, 0, 1, 1, 2, 2],
                                  [3, 3, 4, 4, 5, 5], [3, 3, 4, 4, 5, 5]]
    assert p[3, 5, 0] == probs[1, 2, 0]
    c, _ = topk.nearest_observation(classes, probs, (3, 7))  # not a whole multiple
    assert c[..., 0].tolist() == [[0, 0, 1, 1, 1, 2, 2], [3, 3, 4, 4, 4, 5, 5],
                                  [3, 3, 4, 4, 4, 5, 5]]


@pytest.fixture(scope="module")
def seq():
    return READERS.create("synthetic", frames=4, width=80, height=60)


def test_the_fused_segmenter_keeps_the_labels_and_stride_is_a_variant(seq):
    frame = seq.frame(1)
    network, fused, stride = (_tiny(p).predict(frame) for p in ("network", "fused", "stride"))
    assert np.array_equal(fused.classes, network.classes)
    np.testing.assert_allclose(fused.probs, network.probs, rtol=2e-6, atol=1e-7)
    assert stride.shape == network.shape
    assert 0.5 < (stride.argmax == network.argmax).mean() < 1.0  # boundaries move
    for obs in (network, fused, stride):  # of_kernel skipped checks the kernels satisfy
        SemanticObservation(classes=obs.classes, probs=obs.probs, num_classes=CLASSES)
    # a frame of another size than the input: the two resizes of the network path
    other = _tiny("fused", size=(48, 64))
    want = _tiny("network", size=(48, 64)).predict(frame)
    assert np.array_equal(other.predict(frame).classes, want.classes)
    assert _tiny("fused").precision_record() == {"precision": "fp32", "postprocess": "fused"}


def test_postprocess_refusals():
    with pytest.raises(UnknownNameError, match="unknown postprocess 'sparse'"):
        _tiny("sparse")
    with pytest.raises(InvalidDataError, match="postprocess=stride needs a network"):
        NetworkSegmenter(name="plain", module=nn.Conv2d(3, 2, 1), num_classes=2,
                         class_names=("a", "b"), uses_depth=False, default_size=(8, 8),
                         postprocess="stride")
    seg = SEGMENTERS.create("feagnet-v1", input_size=(64, 96), postprocess="fused")
    assert seg.module.upsample_logits is False
    frame = READERS.create("synthetic", frames=1, width=96, height=64).frame(0)
    with pytest.raises(InvalidDataError, match="pixels must be a 64x96 mask"):
        seg.predict_at(frame, np.ones((60, 80), bool))


@pytest.mark.parametrize("discretize", [True, False])
def test_semantic_pixels_hold_every_end_point(seq, discretize):
    updater = UPDATERS.create("multiclass-bayes", resolution=0.2, max_range=2.5,
                              discretize=discretize, front_end="direct")
    for i in range(len(seq)):
        frame = seq.frame(i)
        mask = updater.semantic_pixels(frame)
        points = FramePoints(frame, 0.2, 2.5, discretize)
        ends = points.pixels[points.endpoint]
        assert mask.ravel()[ends].all()
        assert mask.sum() < mask.size  # something is left out: beyond the range, no depth
    unlimited = UPDATERS.create("multiclass-bayes", max_range=-1).semantic_pixels(frame)
    assert np.array_equal(unlimited, frame.depth > 0)
    # semantic_slam labels every centroid, beyond the range too: every valid pixel
    assert np.array_equal(UPDATERS.create("classic-semantic", max_range=2.5)
                          .semantic_pixels(frame), frame.depth > 0)
    assert UPDATERS.create("orgb").semantic_pixels(frame) is None


def _map(tmp_path, seq, name, updater, segmenter, pipeline, **options):
    out = tmp_path / f"{name}.ot"
    run_mapping(seq, UPDATERS.create(updater, resolution=0.1, max_range=2.5, **options),
                segmenter=segmenter, pipeline=pipeline, measure_memory=False,
                evaluators=[MapFiles(out=out)])
    return out.read_bytes()


@pytest.mark.parametrize(("pipeline", "front_end"),
                         [(False, "generator"), (True, "generator"), (False, "direct")])
def test_evsmap_is_the_same_map_whichever_exact_path_ran(tmp_path, seq, pipeline, front_end):
    network, fused = (_map(tmp_path, seq, p, "multiclass-bayes", _tiny(p), pipeline,
                           front_end=front_end) for p in ("network", "fused"))
    assert fused == network


@pytest.mark.parametrize("front_end", ["generator", "direct"])
def test_only_the_pixels_the_map_reads_change_nothing(tmp_path, seq, monkeypatch, front_end):
    """classic-semantic stores the probabilities themselves (whose last float32 bits the fused
    resize may change): the map of the pixels it reads equals the map of every pixel."""
    read = _map(tmp_path, seq, "read", "classic-semantic", _tiny("fused"), True,
                front_end=front_end)
    monkeypatch.setattr(type(UPDATERS.create("classic-semantic", front_end=front_end)),
                        "semantic_pixels", lambda self, frame: None)
    every = _map(tmp_path, seq, "every", "classic-semantic", _tiny("fused"), True,
                 front_end=front_end)
    assert read == every
