"""The oracle's profiles (evsmap/segmenters/oracle_profile.py) and its correlated error fields
(evsmap/segmenters/oracle_field.py)."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from evsmap.data import VOID, Frame, Intrinsics
from evsmap.errors import InvalidDataError
from evsmap.registry import SEGMENTERS
from evsmap.segmenters.oracle import OracleSegmenter
from evsmap.segmenters.oracle_field import FieldMemo, uniform_fields, world_fields
from evsmap.segmenters.oracle_profile import PROFILE_NAMES, load_profile

H, W = 120, 160


def digest_frame() -> Frame:
    yy, xx = np.mgrid[0:H, 0:W]
    labels = (((yy // 20) * 7 + (xx // 20) * 3) % 40).astype(np.uint8)
    labels[50:70, 70:90] = VOID
    return Frame(rgb=np.zeros((H, W, 3), np.uint8), depth=np.ones((H, W), np.float32),
                 intrinsics=Intrinsics(100.0, 100.0, W / 2, H / 2, W, H), pose=np.eye(4),
                 timestamp=2.5, labels=labels, name="digest")


def digest(seg: OracleSegmenter, frame: Frame) -> str:
    obs = seg.predict(frame)
    return hashlib.sha256(obs.classes.tobytes() + obs.probs.tobytes()).hexdigest()


# sha256 of the predictions of the oracle as it was before profiles (commit 3871e55), with its
# defaults and with error_block=4, confusion=adjacent, seed=3, on digest_frame()
BEFORE = {"defaults": "22c53980930fb4609fc821970e0880a595011954824c8ab29310e40f82a3f992",
          "blocks": "9c07193e1e35ea6b3faad8898f818348024470b1ee92e2706735ee66f4757a66"}


def test_per_pixel_profile_is_the_model_before_profiles_byte_for_byte():
    frame = digest_frame()
    assert digest(OracleSegmenter(profile="per-pixel"), frame) == BEFORE["defaults"]
    seg = OracleSegmenter(profile="per-pixel", error_block=4, confusion="adjacent", seed=3)
    assert digest(seg, frame) == BEFORE["blocks"]


def test_shipped_profiles_load_and_fitted_is_the_default():
    for name in PROFILE_NAMES:
        assert load_profile(name).name == name
    seg = SEGMENTERS.create("oracle")
    assert seg.profile.name == "fitted"
    assert seg.profile.settings() == load_profile("fitted").settings()


def test_noise_free_profile_keeps_every_true_class():
    frame = digest_frame()
    obs = OracleSegmenter(profile="noise-free").predict(frame)
    labelled = frame.labels != VOID
    assert np.array_equal(obs.argmax[labelled], frame.labels[labelled])


def test_options_override_the_profile_and_change_its_identity(tmp_path):
    base = OracleSegmenter(profile="per-pixel")
    other = OracleSegmenter(profile="per-pixel", accuracy=0.5)
    assert other.accuracy == 0.5 and "accuracy=0.5" in other.profile.name
    assert base.identity()["settings"] != other.identity()["settings"]
    assert base.identity() == OracleSegmenter(profile="per-pixel").identity()


def test_a_profile_file_round_trips_and_bad_files_say_which(tmp_path):
    p = load_profile("per-pixel").replace(name="mine", class_accuracy={3: 0.25},
                                          confusion="fitted", confusers={3: [(5, 0.7), (6, 0.3)]},
                                          error_scale=4.0, world_share=0.5)
    path = p.save(tmp_path / "mine.json")
    back = load_profile(path)
    assert back.settings() == p.settings() and back.name == str(path)
    seg = OracleSegmenter(profile=path)
    assert seg.class_accuracy[3] == 0.25 and list(seg.confusers[3][:2]) == [5, 6]
    data = json.loads(path.read_text())
    data["bogus"] = 1
    (tmp_path / "bad.json").write_text(json.dumps(data))
    with pytest.raises(InvalidDataError, match="bad.json: unknown oracle profile field"):
        load_profile(tmp_path / "bad.json")
    data.pop("bogus")
    data["accuracy"] = 1.5
    (tmp_path / "bad.json").write_text(json.dumps(data))
    with pytest.raises(InvalidDataError, match="accuracy must lie in"):
        load_profile(tmp_path / "bad.json")
    with pytest.raises(InvalidDataError, match="neither one of"):
        load_profile(tmp_path / "missing.json")


def test_per_class_accuracy_is_what_each_class_gets():
    frame = digest_frame()
    profile = load_profile("per-pixel").replace(class_accuracy={0: 0.2}, accuracy=0.9,
                                                boundary_blur=0)
    obs = OracleSegmenter(profile=profile).predict(frame)
    zero = frame.labels == 0
    rest = (frame.labels != VOID) & ~zero
    assert abs((obs.argmax[zero] == 0).mean() - 0.2) < 0.05
    assert abs((obs.argmax[rest] == frame.labels[rest]).mean() - 0.9) < 0.02


def plane_frame(pose: np.ndarray, name: str) -> Frame:
    """A camera 2 m in front of a wall (depth 2 everywhere), labelled class 1."""
    labels = np.ones((H, W), np.uint8)
    return Frame(rgb=np.zeros((H, W, 3), np.uint8), depth=np.full((H, W), 2.0, np.float32),
                 intrinsics=Intrinsics(100.0, 100.0, W / 2, H / 2, W, H), pose=pose,
                 timestamp=0.0, labels=labels, name=name)


def test_fields_are_uniform_whatever_their_correlation():
    frame = plane_frame(np.eye(4), "a")
    rng = np.random.default_rng(0)
    for sigma, share in ((0.0, 0.0), (6.0, 0.0), (6.0, 0.7), (0.0, 1.0)):
        u = uniform_fields(rng, frame, 1, sigma=sigma, world_share=share, world_scale=0.05,
                           key=0)[0]
        assert 0.0 <= u.min() and u.max() < 1.0
        if share < 1.0:
            assert abs(u.mean() - 0.5) < 0.06 and abs(u.var() - 1 / 12) < 0.02
    # across many lattice cells the world field is standard normal
    pts = np.random.default_rng(1).uniform(-50, 50, size=(20000, 3))
    (g,) = world_fields(pts, 1.0, [3])
    assert abs(g.mean()) < 0.05 and abs(g.std() - 1.0) < 0.05


def test_the_world_share_of_errors_follows_the_surface_between_frames():
    """A camera shifted 10 px sideways sees the same wall points 10 px over: with the whole
    field anchored to the scene, the errors shift with them."""
    shift = np.eye(4)
    shift[0, 3] = 10 * 2.0 / 100.0  # 10 px at 2 m and f = 100
    a, b = plane_frame(np.eye(4), "a"), plane_frame(shift, "b")
    seg = OracleSegmenter(profile="per-pixel", accuracy=0.5, boundary_blur=0, world_share=1.0)
    wa, wb = seg.error_mask(a), seg.error_mask(b)
    assert 0.3 < wa.mean() < 0.7
    assert (wa[:, 10:] == wb[:, :-10]).mean() > 0.99
    image_only = OracleSegmenter(profile="per-pixel", accuracy=0.5, boundary_blur=0,
                                 error_scale=2.0)
    ia, ib = image_only.error_mask(a), image_only.error_mask(b)
    assert (ia[:, 10:] == ib[:, :-10]).mean() < 0.7


def test_a_memo_never_changes_a_prediction():
    frame = plane_frame(np.eye(4), "a")
    frame.labels[:, 80:] = 5
    profile = load_profile("per-pixel").replace(error_scale=3.0, world_share=0.5)
    memo = FieldMemo()
    plain = OracleSegmenter(profile=profile).predict(frame)
    for _ in range(2):
        kept = OracleSegmenter(profile=profile, memo=memo).predict(frame)
        assert np.array_equal(plain.classes, kept.classes)
        assert np.array_equal(plain.probs, kept.probs)
    assert np.array_equal(OracleSegmenter(profile=profile, memo=memo).error_mask(frame),
                          plain.argmax != frame.labels)


def test_an_accuracy_given_holds_for_every_class():
    frame = digest_frame()
    profile = load_profile("per-pixel").replace(class_accuracy={0: 0.1},
                                                class_boundary_accuracy={0: 0.1})
    seg = OracleSegmenter(profile=profile, accuracy=1.0, boundary_accuracy=1.0)
    obs = seg.predict(frame)
    labelled = frame.labels != VOID
    assert np.array_equal(obs.argmax[labelled], frame.labels[labelled])
