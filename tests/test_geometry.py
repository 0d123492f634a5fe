import numpy as np
import pytest

from evsmap.data import Intrinsics
from evsmap.errors import InvalidDataError
from evsmap.geometry import (
    backproject,
    interpolate_poses,
    matrix_to_quat,
    quat_to_matrix,
    slerp,
)


def random_quats(n, seed=0):
    q = np.random.default_rng(seed).normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_quaternion_matrix_round_trip():
    q = random_quats(200)
    r = quat_to_matrix(q)
    np.testing.assert_allclose(r @ np.swapaxes(r, 1, 2), np.broadcast_to(np.eye(3), r.shape),
                               atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)
    q2 = matrix_to_quat(r)
    # same rotation up to sign
    np.testing.assert_allclose(np.abs(np.sum(q * q2, axis=1)), 1.0, atol=1e-12)


def test_quat_about_z():
    a = 0.3
    r = quat_to_matrix(np.array([0, 0, np.sin(a / 2), np.cos(a / 2)]))
    np.testing.assert_allclose(r, [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0],
                                   [0, 0, 1]], atol=1e-15)


def test_slerp_halfway_angle_and_endpoints():
    q0 = np.array([0, 0, 0, 1.0])
    q1 = np.array([0, 0, np.sin(0.5), np.cos(0.5)])  # 1 rad about z
    mid = slerp(q0, q1, 0.5)
    np.testing.assert_allclose(mid, [0, 0, np.sin(0.25), np.cos(0.25)], atol=1e-15)
    np.testing.assert_allclose(slerp(q0, q1, 0.0), q0)
    # shortest arc: -q1 is the same rotation
    np.testing.assert_allclose(np.abs(slerp(q0, -q1, 0.5)), np.abs(mid), atol=1e-15)


def test_interpolate_poses_linear_and_exact_at_samples():
    t = np.array([0.0, 1.0, 3.0])
    tr = np.array([[0, 0, 0], [1, 2, 3], [3, 2, 1.0]])
    q = random_quats(3, seed=2)
    out = interpolate_poses(t, tr, q, np.array([0.25, 1.0, 2.0]))
    np.testing.assert_allclose(out[0, :3, 3], [0.25, 0.5, 0.75])
    np.testing.assert_array_equal(out[1, :3, :3], quat_to_matrix(q[1]))
    np.testing.assert_allclose(out[2, :3, 3], [2, 2, 2])


def test_backproject_pinhole():
    k = Intrinsics(2.0, 4.0, 1.0, 1.0, 3, 3)
    depth = np.zeros((3, 3), np.float32)
    depth[2, 0] = 2.0
    pose = np.eye(4)
    pose[:3, 3] = [10, 0, 0]
    pts = backproject(depth, k, pose)
    np.testing.assert_allclose(pts, [[10 + (0 - 1) / 2 * 2, (2 - 1) / 4 * 2, 2]])


# --------------------------------------------------------------------------------------------
# Against independent constructions: axis-angle matrices (Rodrigues) written out here
# --------------------------------------------------------------------------------------------

def axis_angle_matrix(axis, angle):
    """Rotation by ``angle`` about ``axis`` from Rodrigues' formula (no quaternions)."""
    k = np.asarray(axis, dtype=np.float64)
    k = k / np.linalg.norm(k)
    cross = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * cross + (1 - np.cos(angle)) * cross @ cross


def axis_angle_quat(axis, angle):
    k = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    return np.concatenate([k * np.sin(angle / 2), [np.cos(angle / 2)]])


def angle_between(q0, q1):
    """The rotation angle taking unit quaternion q0 to q1 (sign-blind)."""
    return 2 * np.arccos(np.clip(np.abs(np.sum(q0 * q1, axis=-1)), 0.0, 1.0))


def test_quarter_turns_about_each_axis():
    # x -> y about z, y -> z about x, z -> x about y: columns are the images of the axes
    cases = {(0, 0, 1): [[0, -1, 0], [1, 0, 0], [0, 0, 1]],
             (1, 0, 0): [[1, 0, 0], [0, 0, -1], [0, 1, 0]],
             (0, 1, 0): [[0, 0, 1], [0, 1, 0], [-1, 0, 0]]}
    for axis, want in cases.items():
        q = axis_angle_quat(axis, np.pi / 2)
        np.testing.assert_allclose(quat_to_matrix(q), want, atol=1e-15)
        np.testing.assert_allclose(matrix_to_quat(np.array(want, dtype=float)), q, atol=1e-15)


def test_matrices_match_rodrigues_and_compose_like_them():
    rng = np.random.default_rng(11)
    axes = rng.normal(size=(50, 3))
    angles = rng.uniform(-np.pi, np.pi, 50)
    quats = np.stack([axis_angle_quat(a, t) for a, t in zip(axes, angles, strict=True)])
    want = np.stack([axis_angle_matrix(a, t) for a, t in zip(axes, angles, strict=True)])
    np.testing.assert_allclose(quat_to_matrix(quats), want, atol=1e-14)
    # a scaled quaternion is the same rotation (normalised first)
    np.testing.assert_allclose(quat_to_matrix(3.5 * quats), want, atol=1e-14)
    # the Hamilton product of two quaternions is the product of their matrices
    a, b = quats[:25], quats[25:]
    prod = np.stack([
        a[:, 3] * b[:, 0] + a[:, 0] * b[:, 3] + a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
        a[:, 3] * b[:, 1] - a[:, 0] * b[:, 2] + a[:, 1] * b[:, 3] + a[:, 2] * b[:, 0],
        a[:, 3] * b[:, 2] + a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0] + a[:, 2] * b[:, 3],
        a[:, 3] * b[:, 3] - a[:, 0] * b[:, 0] - a[:, 1] * b[:, 1] - a[:, 2] * b[:, 2],
    ], axis=1)
    np.testing.assert_allclose(quat_to_matrix(prod), want[:25] @ want[25:], atol=1e-14)


def test_matrix_to_quat_picks_nonnegative_w_and_recovers_axis_angle():
    rng = np.random.default_rng(12)
    axes = rng.normal(size=(40, 3))
    angles = rng.uniform(0.01, 2 * np.pi - 0.01, 40)  # past pi: w < 0 before the sign choice
    mats = np.stack([axis_angle_matrix(a, t) for a, t in zip(axes, angles, strict=True)])
    q = matrix_to_quat(mats)
    assert np.all(q[:, 3] >= 0)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-15)
    want = np.stack([axis_angle_quat(a, t) for a, t in zip(axes, angles, strict=True)])
    want *= np.where(want[:, 3:] < 0, -1.0, 1.0)
    np.testing.assert_allclose(q, want, atol=1e-14)
    # half turns (w = 0), written exactly as 2 k k^T - I: the first non-zero component is positive
    s = np.sqrt(0.5)
    for axis, want in (([-1, 1, 0], [s, -s, 0, 0]), ([0, -1, 1], [0, s, -s, 0]),
                       ([0, 0, -1], [0, 0, 1, 0])):
        k = np.array(axis, dtype=np.float64) / np.linalg.norm(axis)
        half = np.round(2 * np.outer(k, k) - np.eye(3), 12)
        np.testing.assert_allclose(matrix_to_quat(half), want, atol=1e-15)


def test_batch_shapes_and_empty_batches():
    q = random_quats(24, seed=4).reshape(2, 3, 4, 4)
    r = quat_to_matrix(q)
    assert r.shape == (2, 3, 4, 3, 3)
    np.testing.assert_allclose(r[1, 2, 3], quat_to_matrix(q[1, 2, 3]), atol=0)
    assert matrix_to_quat(r).shape == (2, 3, 4, 4)
    assert quat_to_matrix(np.zeros((0, 4))).shape == (0, 3, 3)
    assert matrix_to_quat(np.zeros((0, 3, 3))).shape == (0, 4)
    # slerp: t broadcasts against the quaternions' leading dimensions
    q0, q1 = random_quats(1, seed=5)[0], random_quats(1, seed=6)[0]
    assert slerp(q0, q1, 0.5).shape == (4,)
    assert slerp(q0, q1, np.linspace(0, 1, 7)).shape == (7, 4)
    assert slerp(q[0], q[1], np.full((3, 1), 0.25)).shape == (3, 4, 4)
    assert slerp(np.zeros((0, 4)), np.zeros((0, 4)), np.zeros(0)).shape == (0, 4)


def test_invalid_rotations_raise_one_clear_error():
    with pytest.raises(InvalidDataError, match="quaternion"):
        quat_to_matrix(np.zeros(4))
    with pytest.raises(InvalidDataError, match="non-finite"):
        quat_to_matrix([0.0, np.nan, 0.0, 1.0])
    with pytest.raises(InvalidDataError, match="not a rotation matrix"):
        matrix_to_quat(np.diag([1.0, 1.0, -1.0]))  # a reflection
    with pytest.raises(InvalidDataError, match="non-finite"):
        matrix_to_quat(np.full((3, 3), np.inf))


def test_slerp_moves_at_constant_rate_along_the_great_circle():
    rng = np.random.default_rng(13)
    axes, angles = rng.normal(size=(30, 3)), rng.uniform(0.1, 3.0, 30)
    q0 = random_quats(30, seed=14)
    # q1 = q0 then a turn of `angle` about `axis` (in q0's frame): matrices compose the same way
    r1 = quat_to_matrix(q0) @ np.stack([axis_angle_matrix(a, t)
                                        for a, t in zip(axes, angles, strict=True)])
    q1 = matrix_to_quat(r1)
    for t in (0.0, 0.3, 0.5, 1.0):
        out = slerp(q0, q1, t)
        np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-15)
        np.testing.assert_allclose(angle_between(q0, out), t * angles, atol=1e-7)
        np.testing.assert_allclose(angle_between(out, q1), (1 - t) * angles, atol=1e-7)
        # the intermediate rotation is q0's turned by t * angle about the same axis
        want = quat_to_matrix(q0) @ np.stack([axis_angle_matrix(a, t * s)
                                              for a, s in zip(axes, angles, strict=True)])
        np.testing.assert_allclose(quat_to_matrix(out), want, atol=1e-12)


def test_slerp_takes_the_shortest_arc_and_stays_on_q0s_side():
    q0 = axis_angle_quat([0, 0, 1], 0.2)
    far = axis_angle_quat([0, 0, 1], 0.2 + 2 * np.pi - 0.4)  # = -(turn of -0.4): 0.4 rad away
    assert far @ q0 < 0  # the long way round in 4D
    mid = slerp(q0, far, 0.5)
    np.testing.assert_allclose(mid, axis_angle_quat([0, 0, 1], 0.0), atol=1e-15)
    # output on q0's side: t = 0 gives q0 itself (normalised) even with w < 0
    neg = -axis_angle_quat([1, 2, 3], 0.7)
    np.testing.assert_allclose(slerp(2 * neg, far, 0.0), neg, atol=1e-16)
    assert slerp(neg, far, 0.3)[3] < 0
    # nearly equal quaternions: no division by a vanishing sine
    close = axis_angle_quat([0, 0, 1], 0.2 + 1e-12)
    out = slerp(q0, close, 0.5)
    assert np.all(np.isfinite(out))
    np.testing.assert_allclose(out, q0, atol=1e-12)


def test_interpolate_poses_midpoints_and_single_sample():
    t = np.array([10.0, 12.0])
    tr = np.array([[0, 0, 0], [2, 4, -6.0]])
    q = np.stack([axis_angle_quat([1, 1, 0], 0.1), axis_angle_quat([1, 1, 0], 0.9)])
    out = interpolate_poses(t, tr, q, np.array([10.0, 10.5, 11.0, 12.0]))
    np.testing.assert_allclose(out[:, :3, 3], [[0, 0, 0], [0.5, 1, -1.5], [1, 2, -3], [2, 4, -6]])
    for k, angle in enumerate((0.1, 0.3, 0.5, 0.9)):
        np.testing.assert_allclose(out[k, :3, :3], axis_angle_matrix([1, 1, 0], angle),
                                   atol=1e-14)
    np.testing.assert_array_equal(out[0, :3, :3], quat_to_matrix(q[0]))
    np.testing.assert_array_equal(out[-1, :3, :3], quat_to_matrix(q[1]))
    np.testing.assert_array_equal(out[:, 3], np.broadcast_to([0, 0, 0, 1.0], (4, 4)))
    # one sample: its pose at its own time
    one = interpolate_poses(t[:1], tr[:1], q[:1], np.array([10.0]))
    np.testing.assert_array_equal(one[0, :3, :3], quat_to_matrix(q[0]))
