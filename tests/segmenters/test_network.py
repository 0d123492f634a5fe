"""NetworkSegmenter with the real registered networks at a small input size (64x96).

Frames are 60x80, so every prediction goes through both resizes (frame -> network input ->
frame). The networks keep their random initial weights (seeded), which is all these behaviour
tests need.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from evsmap.classes import CITYSCAPES19_CLASSES, NYU40_CLASSES, SUNRGBD37_CLASSES
from evsmap.cli.main import main
from evsmap.data import SemanticObservation
from evsmap.errors import EvsmapError, InvalidDataError, UnknownNameError
from evsmap.registry import SEGMENTERS
from evsmap.segmenters.network import NetworkSegmenter

SIZE = (64, 96)  # network input (see conftest.SIZE)
RGBD = ("feagnet-v1", "feagnet-v2", "esanet-r34-nbt1d")
RGB_ONLY = ("feagnet-s", "feagnet-l", "fchardnet-70")
ALL = RGBD + RGB_ONLY

# Normalisation constants written out here, so the reference computation below does not reuse
# the code under test: ImageNet RGB statistics, NYUv2 depth statistics in metres.
MEAN = np.array([0.485, 0.456, 0.406])
STD = np.array([0.229, 0.224, 0.225])
DEPTH_MEAN = 2.84194941272766  # ESANet nyuv2/pytorch_dataset.py: 2841.94941272766 mm
DEPTH_STD = 1.4172594281672277


def _reference_logits(seg: NetworkSegmenter, frame) -> torch.Tensor:
    """The network's logits for ``frame`` at the frame's size, computed without ``predict``:
    resize the [0, 1] RGB (bilinear) and the depth (nearest) to the input size, normalise,
    run the module, upsample bilinearly."""
    rgb = torch.from_numpy(frame.rgb.astype(np.float32) / 255.0).permute(2, 0, 1)[None]
    rgb = F.interpolate(rgb, size=SIZE, mode="bilinear", align_corners=False)
    rgb = (rgb - torch.tensor(MEAN, dtype=torch.float32).view(1, 3, 1, 1)) \
        / torch.tensor(STD, dtype=torch.float32).view(1, 3, 1, 1)
    inputs = [rgb]
    if seg.uses_depth:
        depth = F.interpolate(torch.from_numpy(frame.depth)[None, None], size=SIZE,
                              mode="nearest")
        inputs.append(torch.where(depth > 0, (depth - DEPTH_MEAN) / DEPTH_STD, 0.0))
    with torch.inference_mode():
        logits = seg.module(*inputs)
    return F.interpolate(logits, size=frame.rgb.shape[:2], mode="bilinear", align_corners=False)


# ------------------------------------------------------------------------------------------
# registration
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ALL)
def test_registered_network_attributes(segmenter, name):
    seg = segmenter(name)
    assert isinstance(seg, NetworkSegmenter)
    assert seg.name == name
    assert seg.backend == "torch"
    assert seg.input_size == SIZE
    assert seg.default_size == SEGMENTERS.get(name).extras["paper_size"]
    assert seg.uses_depth == (name in RGBD)
    assert seg.input_names == (("rgb", "depth") if name in RGBD else ("rgb",))
    assert len(seg.class_names) == seg.num_classes
    assert not seg.module.training


def test_input_size_defaults_to_the_paper_size(create):
    seg = create("feagnet-s", input_size=None)
    assert seg.input_size == seg.default_size == (512, 1024)


@pytest.mark.parametrize(
    ("name", "options", "names"),
    [
        ("feagnet-v1", {}, NYU40_CLASSES),
        ("feagnet-v2", {}, NYU40_CLASSES),
        ("feagnet-s", {}, CITYSCAPES19_CLASSES),
        ("feagnet-l", {}, CITYSCAPES19_CLASSES),
        ("esanet-r34-nbt1d", {}, NYU40_CLASSES),
        ("esanet-r34-nbt1d", {"dataset": "sunrgbd"}, SUNRGBD37_CLASSES),
        ("esanet-r34-nbt1d", {"dataset": "cityscapes"}, CITYSCAPES19_CLASSES),
        ("fchardnet-70", {}, NYU40_CLASSES),
        ("fchardnet-70", {"dataset": "cityscapes"}, CITYSCAPES19_CLASSES),
    ],
)
def test_class_names(create, segmenter, name, options, names):
    seg = create(name, **options) if options else segmenter(name)
    assert seg.class_names == names
    assert seg.num_classes == len(names)
    assert len(set(seg.class_names)) == len(names)


def test_class_names_of_a_custom_class_count(create, make_frame):
    seg = create("feagnet-v2", num_classes=5)
    assert seg.class_names == tuple(f"class_{i}" for i in range(5))
    obs = seg.predict(make_frame(), k=5)
    assert obs.num_classes == 5
    assert obs.classes.max() < 5


def test_dataset_option_sets_classes_and_paper_size(create, make_frame):
    seg = create("esanet-r34-nbt1d", dataset="sunrgbd")
    assert (seg.num_classes, seg.default_size) == (37, (480, 640))
    assert seg.predict(make_frame()).classes.max() < 37
    assert create("fchardnet-70", dataset="Cityscapes").default_size == (512, 1024)


# ------------------------------------------------------------------------------------------
# predict
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ALL)
def test_predict_returns_a_valid_observation(segmenter, make_frame, name):
    seg = segmenter(name)
    frame = make_frame(60, 80)
    top1 = None
    for k in (1, 3, 5):
        obs = seg.predict(frame, k=k)
        assert isinstance(obs, SemanticObservation)
        assert obs.shape == (60, 80)
        assert obs.k == k
        assert obs.classes.shape == obs.probs.shape == (60, 80, k)
        assert obs.classes.dtype == np.int16
        assert obs.probs.dtype == np.float32
        assert obs.num_classes == seg.num_classes
        assert obs.classes.min() >= 0
        assert obs.classes.max() < seg.num_classes
        assert obs.probs.min() >= 0.0
        assert obs.probs.max() <= 1.0
        assert np.all(np.diff(obs.probs, axis=2) <= 0.0), "probs must be sorted, largest first"
        assert np.all(obs.probs.sum(axis=2) <= 1.0 + 1e-5)
        # the k classes of a pixel are distinct
        sorted_classes = np.sort(obs.classes, axis=2)
        assert np.all(np.diff(sorted_classes, axis=2) > 0)
        if top1 is None:
            top1 = obs
        else:  # a larger k extends the smaller one
            np.testing.assert_array_equal(obs.classes[..., 0], top1.classes[..., 0])
            np.testing.assert_allclose(obs.probs[..., 0], top1.probs[..., 0], rtol=0, atol=1e-7)


def test_predict_keeps_all_classes(segmenter, make_frame):
    seg = segmenter("feagnet-s")
    obs = seg.predict(make_frame(), k=seg.num_classes)
    assert obs.k == 19
    np.testing.assert_allclose(obs.probs.sum(axis=2), 1.0, atol=1e-4)
    np.testing.assert_array_equal(np.sort(obs.classes, axis=2)[0, 0], np.arange(19))


@pytest.mark.parametrize("name", ALL)
def test_top1_is_the_argmax_of_the_upsampled_logits(segmenter, make_frame, name):
    seg = segmenter(name)
    frame = make_frame(60, 80, seed=1)
    assert seg.normalization.rgb_mean == tuple(MEAN)
    assert seg.normalization.rgb_std == tuple(STD)
    if seg.uses_depth:
        assert (seg.normalization.depth_mean, seg.normalization.depth_std) == \
            (DEPTH_MEAN, DEPTH_STD)
    logits = _reference_logits(seg, frame)[0]  # C x H x W
    obs = seg.predict(frame, k=3)
    # exact: with this frame the two best logits of every pixel lie >= 4e-3 apart (seeded
    # weights), far above the rounding differences of the two computations
    np.testing.assert_array_equal(obs.argmax, logits.argmax(dim=0).numpy())
    # and the kept probabilities are the softmax of those logits
    probs = torch.softmax(logits, dim=0).numpy()
    top = np.take_along_axis(probs, obs.classes.transpose(2, 0, 1).astype(np.int64), 0)
    np.testing.assert_allclose(obs.probs.transpose(2, 0, 1), top, atol=1e-4)


@pytest.mark.parametrize("name", RGB_ONLY)
def test_rgb_only_networks_ignore_depth(segmenter, make_frame, name):
    seg = segmenter(name)
    frame = make_frame(seed=2)
    other = make_frame(seed=2, depth=np.full((60, 80), 7.5, dtype=np.float32))
    np.testing.assert_array_equal(other.rgb, frame.rgb)
    assert len(seg.preprocess(frame)) == 1
    a, b = seg.predict(frame), seg.predict(other)
    np.testing.assert_array_equal(a.classes, b.classes)
    np.testing.assert_array_equal(a.probs, b.probs)


@pytest.mark.parametrize("name", RGBD)
def test_rgbd_networks_react_to_depth(segmenter, make_frame, name):
    seg = segmenter(name)
    near = make_frame(seed=3, depth=np.full((60, 80), 0.8, dtype=np.float32))
    far = make_frame(seed=3, depth=np.full((60, 80), 7.5, dtype=np.float32))
    a = seg.logits(seg.preprocess(near))
    assert torch.equal(seg.logits(seg.preprocess(near)), a)  # deterministic: no noise floor
    b = seg.logits(seg.preprocess(far))
    # randomly initialised networks respond weakly (their logits are nearly constant), but a
    # network that reads depth responds far above float rounding
    assert (a - b).abs().max().item() > 1e-5


def test_predict_accepts_a_frame_of_the_input_size(segmenter, make_frame):
    obs = segmenter("feagnet-v2").predict(make_frame(*SIZE))
    assert obs.shape == SIZE


# ------------------------------------------------------------------------------------------
# preprocessing
# ------------------------------------------------------------------------------------------


def test_preprocess_normalises_hand_made_pixels(segmenter, make_frame):
    seg = segmenter("feagnet-v2")
    h, w = SIZE  # no resizing: pixels map one to one
    depth = np.full((h, w), 1.0, dtype=np.float32)
    depth[0, 0] = 0.0
    depth[0, 1] = DEPTH_MEAN
    depth[0, 2] = DEPTH_MEAN + DEPTH_STD
    frame = make_frame(h, w, depth=depth)
    frame.rgb[0, 0] = 255
    frame.rgb[0, 1] = 0
    frame.rgb[0, 2] = (255, 0, 51)
    rgb, dep = seg.preprocess(frame)
    assert rgb.shape == (1, 3, h, w) and dep.shape == (1, 1, h, w)
    assert rgb.dtype == dep.dtype == torch.float32
    np.testing.assert_allclose(rgb[0, :, 0, 0].numpy(), (1 - MEAN) / STD, rtol=1e-6)
    np.testing.assert_allclose(rgb[0, :, 0, 1].numpy(), -MEAN / STD, rtol=1e-6)
    np.testing.assert_allclose(rgb[0, :, 0, 2].numpy(),
                               (np.array([1.0, 0.0, 0.2]) - MEAN) / STD, rtol=1e-5)
    assert dep[0, 0, 0, 0].item() == 0.0  # invalid depth
    assert dep[0, 0, 0, 1].item() == pytest.approx(0.0, abs=1e-6)  # the mean depth
    assert dep[0, 0, 0, 2].item() == pytest.approx(1.0, abs=1e-6)  # one std above it
    assert dep[0, 0, 1, 0].item() == pytest.approx((1.0 - DEPTH_MEAN) / DEPTH_STD, abs=1e-6)


def test_preprocess_resizes_to_the_input_size(segmenter, make_frame):
    seg = segmenter("feagnet-v2")
    depth = np.zeros((60, 80), dtype=np.float32)
    depth[:, 40:] = 3.0  # left half invalid
    frame = make_frame(60, 80, depth=depth)
    frame.rgb[:] = 255
    rgb, dep = seg.preprocess(frame)
    assert rgb.shape[-2:] == dep.shape[-2:] == SIZE
    np.testing.assert_allclose(rgb[0].numpy(),
                               np.broadcast_to(((1 - MEAN) / STD)[:, None, None], (3, *SIZE)),
                               rtol=1e-6)
    # nearest-neighbour depth: invalid pixels are never blended with valid ones
    values = np.unique(dep.numpy())
    np.testing.assert_allclose(values, [0.0, (3.0 - DEPTH_MEAN) / DEPTH_STD], atol=1e-6)
    assert np.all(dep[0, 0, :, : SIZE[1] // 2].numpy() == 0.0)


def test_preprocess_of_an_rgb_only_network(segmenter, make_frame):
    frame = make_frame(*SIZE)
    frame.rgb[0, 0] = 255
    (rgb,) = segmenter("feagnet-s").preprocess(frame)
    assert rgb.shape == (1, 3, *SIZE)
    np.testing.assert_allclose(rgb[0, :, 0, 0].numpy(), (1 - MEAN) / STD, rtol=1e-6)


# ------------------------------------------------------------------------------------------
# ONNX Runtime backend
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["feagnet-v2", "fchardnet-70"])
def test_onnxruntime_backend_agrees_with_torch(monkeypatch, tmp_path, segmenter, create,
                                               make_frame, name):
    monkeypatch.setenv("EVSMAP_CACHE_DIR", str(tmp_path))
    reference = segmenter(name)
    seg = create(name, backend="onnxruntime", seed=1)
    seg.module.load_state_dict(reference.module.state_dict())
    assert seg.backend == "onnxruntime"
    frame = make_frame(seed=4)
    a, b = reference.predict(frame, k=3), seg.predict(frame, k=3)
    assert b.shape == (60, 80) and b.k == 3
    assert np.mean(a.argmax == b.argmax) >= 0.99
    agree = a.argmax == b.argmax
    np.testing.assert_allclose(a.probs[..., 0][agree], b.probs[..., 0][agree], atol=1e-3)
    exports = list((tmp_path / "onnx").glob("*.onnx"))
    assert len(exports) == 1 and exports[0].name.startswith(name)
    # the session is reused: a second frame exports nothing new
    seg.predict(make_frame(seed=5))
    assert list((tmp_path / "onnx").glob("*.onnx")) == exports


# ------------------------------------------------------------------------------------------
# errors
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["feagnet-s", "fchardnet-70"])
def test_unknown_backend(create, name):
    with pytest.raises(UnknownNameError, match="tensorrt"):
        create(name, backend="tensorrt")


@pytest.mark.parametrize("k", [0, -1, 41])
def test_k_out_of_range(segmenter, make_frame, k):
    with pytest.raises(InvalidDataError, match=r"k must lie in \[1, 40\]"):
        segmenter("feagnet-v2").predict(make_frame(), k=k)


@pytest.mark.parametrize("name", ALL)
def test_unknown_option_is_named(name):
    with pytest.raises(EvsmapError, match="bogus_option") as info:
        SEGMENTERS.create(name, bogus_option=1)
    assert name in str(info.value)
    assert "input_size" in str(info.value)  # the accepted options are listed


@pytest.mark.parametrize("name", ["esanet-r34-nbt1d", "fchardnet-70"])
def test_unknown_dataset(name):
    with pytest.raises(UnknownNameError, match="ade20k"):
        SEGMENTERS.create(name, dataset="ade20k")


# ------------------------------------------------------------------------------------------
# command line
# ------------------------------------------------------------------------------------------


def test_complexity_command_at_a_small_size(capsys, segmenter):
    # `evsmap complexity` has no --weights option, so only the measurement itself is tested
    code = main(["complexity", "feagnet-v2", "--height", "64", "--width", "96", "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    record = json.loads(out)
    assert record["model"] == "feagnet-v2"
    assert record["num_classes"] == 40
    assert record["inputs"] == ["rgb", "depth"]
    assert (record["height"], record["width"]) == (64, 96)
    assert record["params"] == sum(p.numel() for p in segmenter("feagnet-v2").module.parameters())
    assert 0 < record["conv_macs"] <= record["flops"]


def test_input_size_option_reads_hxw_and_rejects_anything_else_in_one_line():
    from evsmap.errors import InvalidDataError
    from evsmap.segmenters.network import as_size

    assert as_size("240x320") == (240, 320) and as_size([480, 640]) == (480, 640)
    for bad in ("240,320", "[240,320]", "0x320", (1, 2, 3), "big"):
        with pytest.raises(InvalidDataError, match="input_size must be HEIGHTxWIDTH"):
            as_size(bad)


def test_eval_with_a_bad_input_size_is_a_user_error_not_a_traceback(tmp_path):
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "evsmap", "eval", "feagnet-s", "--dataset",
                        "synthetic", "--allow-random", "--limit", "1", "-o",
                        "input_size=[240,320]"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "input_size must be HEIGHTxWIDTH" in r.stderr
