import numpy as np
import pytest

from evsmap.data import Frame, FrameList, Intrinsics, SemanticObservation
from evsmap.errors import InvalidDataError

K = Intrinsics(100.0, 100.0, 15.5, 11.5, 32, 24)


def frame(**over):
    args = dict(rgb=np.zeros((24, 32, 3), np.uint8), depth=np.ones((24, 32), np.float32),
                intrinsics=K, pose=np.eye(4), timestamp=1.0)
    args.update(over)
    return Frame(**args)


def test_valid_frame():
    f = frame(labels=np.full((24, 32), 255, np.uint8))
    assert (f.height, f.width) == (24, 32)
    assert f.valid.all()


@pytest.mark.parametrize(
    "over, message",
    [
        ({"rgb": np.zeros((24, 32, 3), np.float32)}, "rgb must have dtype uint8"),
        ({"rgb": np.zeros((24, 32), np.uint8)}, "rgb must have 3 dimensions"),
        ({"depth": np.ones((24, 32), np.float64)}, "depth must have dtype float32"),
        ({"depth": np.ones((24, 31), np.float32)}, "depth shape"),
        ({"depth": np.full((24, 32), np.nan, np.float32)}, "NaN or inf"),
        ({"depth": -np.ones((24, 32), np.float32)}, "negative"),
        ({"pose": np.eye(4, dtype=np.float32)}, "pose must have dtype float64"),
        ({"pose": np.eye(3)}, "pose must be 4x4"),
        ({"pose": np.diag([2.0, 1, 1, 1])}, "not a proper rotation"),
        ({"pose": np.array([[1.0, 0, 0, 3e38], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])},
         "beyond 1e"),
        ({"timestamp": float("inf")}, "timestamp must be finite"),
        ({"labels": np.zeros((24, 32), np.int32)}, "labels must have dtype uint8"),
        ({"intrinsics": Intrinsics(100.0, 100.0, 15.5, 11.5, 64, 48)}, "intrinsics are for 64x48"),
    ],
)
def test_frame_validation_names_the_problem(over, message):
    with pytest.raises(InvalidDataError, match=message):
        frame(name="f7", **over)


def test_intrinsics_validation_and_scaling():
    with pytest.raises(InvalidDataError, match="fx"):
        Intrinsics(float("nan"), 1.0, 0.0, 0.0, 4, 4)
    with pytest.raises(InvalidDataError, match="width"):
        Intrinsics(1.0, 1.0, 0.0, 0.0, 0, 4)
    half = Intrinsics(525.0, 525.0, 319.5, 239.5, 640, 480).scaled(320, 240)
    assert (half.fx, half.cx, half.cy) == (262.5, 159.5, 119.5)


def test_observation_from_probabilities_keeps_sorted_top_k():
    rng = np.random.default_rng(0)
    logits = rng.normal(size=(5, 6, 10))
    p = np.exp(logits) / np.exp(logits).sum(axis=2, keepdims=True)
    obs = SemanticObservation.from_probabilities(p, k=3)
    assert obs.k == 3 and obs.shape == (5, 6) and obs.num_classes == 10
    np.testing.assert_array_equal(obs.argmax, p.argmax(axis=2))
    np.testing.assert_allclose(obs.probs, -np.sort(-p, axis=2)[..., :3], rtol=1e-6)
    np.testing.assert_allclose(obs.others, 1 - obs.probs.sum(axis=2), atol=1e-6)


@pytest.mark.parametrize(
    "classes, probs, message",
    [
        (np.zeros((2, 2, 3), np.int16), np.full((2, 2, 3), 0.5, np.float32), "sum to more than 1"),
        (np.zeros((2, 2, 3), np.int16), np.tile(np.float32([0.1, 0.2, 0.3]), (2, 2, 1)), "sorted"),
        (np.full((2, 2, 3), 40, np.int16), np.full((2, 2, 3), 0.1, np.float32), r"\[0, 39\]"),
        (np.zeros((2, 2, 3), np.float32), np.full((2, 2, 3), 0.1, np.float32), "integer array"),
    ],
)
def test_observation_validation(classes, probs, message):
    with pytest.raises(InvalidDataError, match=message):
        SemanticObservation(classes=classes, probs=probs, num_classes=40)


def test_frame_list_checks_intrinsics_and_indexes():
    seq = FrameList("mem", K, [frame(timestamp=float(i)) for i in range(3)])
    assert len(seq) == 3 and seq[-1].timestamp == 2.0
    assert [f.timestamp for f in seq] == [0.0, 1.0, 2.0]
    with pytest.raises(IndexError):
        seq[3]
    other = Intrinsics(90.0, 90.0, 15.5, 11.5, 32, 24)
    with pytest.raises(InvalidDataError, match="intrinsics"):
        FrameList("mem", other, [frame()])


def test_point_cloud_frames_validate():
    from evsmap.data import Frame

    pose = np.eye(4)
    f = Frame.from_points(np.zeros((5, 3), dtype=np.float64), pose, 1.0, name="c")
    assert f.is_cloud and f.points.dtype == np.float32 and f.colors() is None
    with pytest.raises(InvalidDataError, match="Nx3"):
        Frame.from_points(np.zeros((5, 2), dtype=np.float32), pose, 1.0)
    with pytest.raises(InvalidDataError, match="NaN"):
        Frame.from_points(np.full((2, 3), np.nan, dtype=np.float32), pose, 1.0)
    with pytest.raises(InvalidDataError, match="point_colors"):
        Frame.from_points(np.zeros((5, 3), dtype=np.float32), pose, 1.0,
                          colors=np.zeros((4, 3), dtype=np.uint8))
    with pytest.raises(InvalidDataError, match="needs rgb, depth and intrinsics"):
        Frame(rgb=None, depth=None, intrinsics=None, pose=pose, timestamp=0.0)
