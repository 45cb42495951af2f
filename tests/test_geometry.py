"""Pins the pose conventions of lite_vo.geometry: round trips, known values, Jacobians."""
import numpy as np
import pytest

from lite_vo.geometry import (
    adjoint_se3, adjoint_sim3, compose, exp_se3, exp_sim3, exp_so3, hat, inverse_se3, inverse_sim3,
    log_se3, log_sim3, log_so3, make_pose, pose_from_tum, quat_xyzw_from_rotmat, rotmat_from_quat_xyzw,
    transform_points, tum_from_pose, vee,
)
from lite_vo.geometry.quaternion import quat_xyzw_one

RNG_SEED = 1234


def rng():
    return np.random.default_rng(RNG_SEED)


def test_hat_is_cross_product_and_vee_inverts_it():
    r = rng()
    a, b = r.normal(size=3), r.normal(size=3)
    np.testing.assert_allclose(hat(a) @ b, np.cross(a, b), atol=1e-12)
    np.testing.assert_allclose(vee(hat(a)), a, atol=1e-15)


def test_exp_so3_known_value_rotation_about_z():
    R = exp_so3(np.array([0.0, 0.0, np.pi / 2]))
    np.testing.assert_allclose(R @ [1, 0, 0], [0, 1, 0], atol=1e-12)


@pytest.mark.parametrize("scale", [1e-9, 1e-5, 0.1, 1.0, 3.0])
def test_so3_round_trip_batched(scale):
    w = rng().normal(size=(50, 3))
    w = w / np.linalg.norm(w, axis=1, keepdims=True) * scale
    np.testing.assert_allclose(log_so3(exp_so3(w)), w, atol=1e-9)


def test_log_so3_near_pi_recovers_axis():
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    for angle in (np.pi - 1e-6, np.pi - 1e-4, np.pi):
        R = exp_so3(axis * angle)
        w = log_so3(R)
        np.testing.assert_allclose(exp_so3(w), R, atol=1e-9)


def test_se3_round_trip_and_translation_of_pure_translation():
    xi = rng().normal(size=(40, 6))
    xi[:, 3:] *= 2.5 / np.maximum(np.linalg.norm(xi[:, 3:], axis=1, keepdims=True), 2.5)  # |omega| < pi
    np.testing.assert_allclose(log_se3(exp_se3(xi)), xi, atol=1e-9)
    T = exp_se3(np.array([1.0, 2.0, 3.0, 0, 0, 0]))
    np.testing.assert_allclose(T[:3, 3], [1, 2, 3])
    np.testing.assert_allclose(T[:3, :3], np.eye(3))


def test_composition_convention_maps_points_c_to_a():
    r = rng()
    T_a_b, T_b_c = exp_se3(r.normal(size=6)), exp_se3(r.normal(size=6))
    p_c = r.normal(size=(5, 3))
    p_b = transform_points(T_b_c, p_c)
    np.testing.assert_allclose(transform_points(compose(T_a_b, T_b_c), p_c), transform_points(T_a_b, p_b), atol=1e-12)
    np.testing.assert_allclose(compose(T_a_b, inverse_se3(T_a_b)), np.eye(4), atol=1e-12)


def test_se3_adjoint_identity_and_batch():
    r = rng()
    T = exp_se3(r.normal(size=(7, 6)))
    d = r.normal(size=(7, 6)) * 0.2
    lhs = T @ exp_se3(d) @ inverse_se3(T)
    rhs = exp_se3((adjoint_se3(T) @ d[..., None])[..., 0])
    np.testing.assert_allclose(lhs, rhs, atol=1e-10)


def test_exp_se3_jacobian_at_identity_matches_finite_differences():
    # d/d xi (exp(xi) p) at 0 = [I, -hat(p)] (twist order v, omega)
    p = np.array([0.3, -1.2, 2.0])
    eps = 1e-6
    J = np.zeros((3, 6))
    for k in range(6):
        d = np.zeros(6)
        d[k] = eps
        J[:, k] = (transform_points(exp_se3(d), p[None])[0] - transform_points(exp_se3(-d), p[None])[0]) / (2 * eps)
    np.testing.assert_allclose(J, np.hstack([np.eye(3), -hat(p)]), atol=1e-8)


def test_log_se3_jacobian_small_perturbation_is_additive_at_identity():
    xi = np.array([1e-7, -2e-7, 3e-7, 1e-7, 2e-7, -1e-7])
    np.testing.assert_allclose(log_se3(exp_se3(xi)), xi, atol=1e-15)


def test_sim3_round_trip_scale_and_inverse():
    r = rng()
    xi = r.normal(size=(20, 7)) * 0.7
    S = exp_sim3(xi)
    np.testing.assert_allclose(log_sim3(S), xi, atol=1e-9)
    np.testing.assert_allclose(np.cbrt(np.linalg.det(S[:, :3, :3])), np.exp(xi[:, 6]), rtol=1e-12)
    np.testing.assert_allclose(S @ inverse_sim3(S), np.broadcast_to(np.eye(4), S.shape), atol=1e-10)


def test_sim3_reduces_to_se3_without_scale():
    xi = rng().normal(size=6)
    np.testing.assert_allclose(exp_sim3(np.append(xi, 0.0)), exp_se3(xi), atol=1e-12)


def test_sim3_adjoint_identity():
    r = rng()
    S = exp_sim3(r.normal(size=7) * 0.5)
    d = r.normal(size=7) * 0.2
    np.testing.assert_allclose(S @ exp_sim3(d) @ inverse_sim3(S), exp_sim3(adjoint_sim3(S) @ d), atol=1e-10)


def test_quaternion_known_values_tum_order():
    # 90 deg about z: q = (0, 0, sin45, cos45) in xyzw order
    q = np.array([0, 0, np.sin(np.pi / 4), np.cos(np.pi / 4)])
    np.testing.assert_allclose(rotmat_from_quat_xyzw(q), exp_so3(np.array([0, 0, np.pi / 2])), atol=1e-12)
    np.testing.assert_allclose(quat_xyzw_from_rotmat(np.eye(3)), [0, 0, 0, 1])


def test_quaternion_round_trip_and_sign():
    R = exp_so3(rng().normal(size=(200, 3)) * 1.5)
    q = quat_xyzw_from_rotmat(R)
    assert np.all(q[:, 3] >= 0)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(rotmat_from_quat_xyzw(q), R, atol=1e-12)


def test_one_pose_quaternion_has_the_bits_of_the_vectorised_one():
    """The trajectory writer's per-frame quaternion (Python floats) equals quat_xyzw_from_rotmat bit for
    bit: small and large angles, 180-degree turns about each axis (every branch of Shepperd's method)."""
    r = rng()
    Rs = list(exp_so3(r.normal(size=(3000, 3)) * r.choice([1e-7, 0.1, 1.0, 3.0, np.pi], size=(3000, 1))))
    Rs += [np.eye(3), np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1])]
    branches = set()
    for R in Rs:
        q = quat_xyzw_from_rotmat(R)
        assert np.array_equal(np.array(quat_xyzw_one(R)), q)
        branches.add(int(np.argmax([1 + np.trace(R), *(1 + 2 * R[i, i] - np.trace(R) for i in range(3))])))
    assert branches == {0, 1, 2, 3}


def test_zero_quaternion_is_an_error():
    with pytest.raises(ValueError):
        rotmat_from_quat_xyzw(np.zeros(4))


def test_tum_row_round_trip():
    T = exp_se3(rng().normal(size=(10, 6)))
    np.testing.assert_allclose(pose_from_tum(tum_from_pose(T)), T, atol=1e-12)
    np.testing.assert_allclose(make_pose(np.eye(3), [1, 2, 3])[:3, 3], [1, 2, 3])


def test_project_to_se3_restores_a_drifted_rotation():
    from lite_vo.geometry import project_to_se3
    T = exp_se3(rng().normal(size=6))
    drifted = T.copy()
    drifted[:3, :3] *= 1.007
    fixed = project_to_se3(drifted)
    np.testing.assert_allclose(fixed[:3, :3] @ fixed[:3, :3].T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(fixed, T, atol=1e-12)
    np.testing.assert_allclose(project_to_se3(T), T, atol=1e-12)


def test_project_to_se3_single_pose_path_equals_the_batched_one_bit_for_bit():
    """One 4x4 pose takes a shortcut (the tracking hot path): it must give exactly what the batched
    code gives, also for drifted rotations and reflections (det -1: the last singular vector flips)."""
    from lite_vo.geometry import project_to_se3
    g = rng()
    poses = exp_se3(g.normal(size=(300, 6)))
    poses[:, :3, :3] += g.normal(scale=1e-3, size=(300, 3, 3))
    poses[::3, :3, :3] = -poses[::3, :3, :3]                           # reflections
    poses[1::3, :3, :3] = poses[1::3, :3, :3] @ np.diag([1.0, 1.0, -1.0])
    batched = project_to_se3(poses)
    for T, B in zip(poses, batched):
        assert np.array_equal(project_to_se3(T), B)
    assert np.all(np.linalg.det(batched[:, :3, :3]) > 0)
