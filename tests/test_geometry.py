import numpy as np

from evsmap.data import Intrinsics
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
