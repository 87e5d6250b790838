import numpy as np
import pytest

from m2d2m.motion.representation.rotations import (
    cont6d_to_matrix,
    cross,
    euler_to_matrix,
    matrix_to_euler,
    qbetween,
    qinv,
    qmul,
    qnormalize,
    qrot,
    quat_from_axis_angle,
    quat_to_cont6d,
    quat_to_matrix,
)

rng = np.random.default_rng(0)


def random_quats(n: int) -> np.ndarray:
    return qnormalize(rng.normal(size=(n, 4)))


def test_cross_matches_numpy():
    a, b = rng.normal(size=(2, 50, 3))
    np.testing.assert_allclose(cross(a, b), np.cross(a, b), atol=1e-12)


def test_qrot_matches_rotation_matrix():
    q, v = random_quats(100), rng.normal(size=(100, 3))
    expected = np.einsum("nij,nj->ni", quat_to_matrix(q), v)
    np.testing.assert_allclose(qrot(q, v), expected, atol=1e-12)


def test_qmul_composes_rotations_and_qinv_inverts():
    a, b, v = random_quats(50), random_quats(50), rng.normal(size=(50, 3))
    np.testing.assert_allclose(qrot(qmul(a, b), v), qrot(a, qrot(b, v)), atol=1e-12)
    np.testing.assert_allclose(qrot(qinv(a), qrot(a, v)), v, atol=1e-12)


def test_axis_angle_quarter_turn_about_y_takes_z_to_x():
    q = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), np.pi / 2)
    np.testing.assert_allclose(qrot(q, np.array([0.0, 0.0, 1.0])), [1.0, 0.0, 0.0], atol=1e-12)


def test_qbetween_takes_u_onto_v_including_opposite_vectors():
    u = rng.normal(size=(100, 3))
    v = rng.normal(size=(100, 3))
    v[:5] = -u[:5] * 2.0  # exactly opposite: the 0/0 case of the closed form
    q = qbetween(u, v)
    rotated = qrot(q, u / np.linalg.norm(u, axis=-1, keepdims=True))
    np.testing.assert_allclose(rotated, v / np.linalg.norm(v, axis=-1, keepdims=True), atol=1e-9)


def test_cont6d_round_trip():
    q = random_quats(100)
    np.testing.assert_allclose(cont6d_to_matrix(quat_to_cont6d(q)), quat_to_matrix(q), atol=1e-12)


@pytest.mark.parametrize("order", ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"])
def test_euler_round_trip(order):
    angles = rng.uniform(-3.0, 3.0, size=(200, 3))
    angles[:, 1] = rng.uniform(-1.5, 1.5, size=200)
    np.testing.assert_allclose(matrix_to_euler(euler_to_matrix(angles, order), order), angles, atol=1e-9)


@pytest.mark.parametrize("order", ["XYZ", "ZYX"])
def test_euler_at_gimbal_lock_reproduces_the_rotation(order):
    angles = np.array([[0.3, np.pi / 2, -0.2], [0.1, -np.pi / 2, 0.5]])
    m = euler_to_matrix(angles, order)
    np.testing.assert_allclose(euler_to_matrix(matrix_to_euler(m, order), order), m, atol=1e-9)


def test_euler_rejects_proper_euler_orders():
    with pytest.raises(ValueError, match="distinct axes"):
        matrix_to_euler(np.eye(3), "ZXZ")
