import dataclasses

import numpy as np
import pytest

from bench.geometry.transforms import homogeneous, rotation_angle, vee
from bench.robot.ik import IKResult, analytic_ik, compensated_ik, geometric_jacobian, select_solution
from bench.robot.kinematics import ee_position, forward_kinematics
from bench.robot.model import random_errors

DEG = np.pi / 180


def _wrap(x):
    return (x + np.pi) % (2 * np.pi) - np.pi


def _pose_err(robot, q, T, eps=None, form="exact"):
    F = forward_kinematics(robot, q, eps, form)
    dp = np.linalg.norm(F[..., :3, 3] - T[:3, 3], axis=-1)
    dr = rotation_angle(T[:3, :3].T @ F[..., :3, :3])
    return dp, dr


def _interior(robot, rng, n, margin=5 * DEG):
    return rng.uniform(robot.q_min + margin, robot.q_max - margin, size=(n, robot.n))


def test_fk_of_ik_reproduces_500_random_poses(ta40):
    rng = np.random.default_rng(4501)
    Q = ta40.random_configurations(rng, 500)
    T = forward_kinematics(ta40, Q)
    counts = []
    for q, t in zip(Q, T, strict=True):
        res = analytic_ik(ta40, t)
        assert res.success, res.message
        dp, dr = _pose_err(ta40, res.solutions, t)
        assert dp.max() <= 1e-9 and dr.max() <= 1e-9
        assert res.position_error_m <= 1e-9 and res.orientation_error_rad <= 1e-9
        # the original configuration is one of the branches, and it is flagged within the limits
        dist = np.abs(_wrap(res.solutions - q)).max(axis=1)
        assert dist.min() <= 1e-8
        assert res.within_limits[np.argmin(dist)]
        counts.append(len(res.solutions))
    # 8 branches where the shoulder-flipped branch (theta1 + pi) is in reach, else 4
    assert set(counts) <= {4, 8} and 8 in counts


def test_lateral_offset_and_joint_offsets_are_supported(ta40):
    rng = np.random.default_rng(4502)
    robot = dataclasses.replace(ta40, d=ta40.d + np.array([0.1, 0.05, -0.02, 0.0, 0.0, 0.0]),
                                theta_offset=rng.uniform(-0.5, 0.5, 6) * np.array([1, 1, 1, 1, 0, 1]))
    Q = robot.random_configurations(rng, 100)
    for q, t in zip(Q, forward_kinematics(robot, Q), strict=True):
        res = analytic_ik(robot, t)
        assert len(res.solutions) >= 4
        dp, dr = _pose_err(robot, res.solutions, t)
        assert dp.max() <= 1e-9 and dr.max() <= 1e-9
        assert np.abs(_wrap(res.solutions - q)).max(axis=1).min() <= 1e-8


@pytest.mark.parametrize("theta5", [0.0, 1e-9, -1e-9, 1e-13])
def test_wrist_singularity(ta40, theta5):
    q = np.array([30, 40, 100, 50, 0, -20]) * DEG
    q[4] = theta5
    T = forward_kinematics(ta40, q)
    res = analytic_ik(ta40, T, q4_hint=0.3)
    assert res.success, res.message
    dp, dr = _pose_err(ta40, res.solutions, T)
    assert dp.max() <= 1e-9 and dr.max() <= 1e-9
    # a branch with the original arm and the same total wrist roll theta4 + theta6
    match = np.abs(_wrap(res.solutions[:, :3] - q[:3])).max(axis=1) < 1e-9
    match &= np.abs(_wrap(res.solutions[:, 3] + res.solutions[:, 5] - q[3] - q[5])) < 1e-8
    match &= np.abs(res.solutions[:, 4]) < 1e-8
    assert match.any()
    wrist_singular = np.abs(np.sin(res.solutions[:, 4])) < 1e-9
    if abs(theta5) < 1e-12:  # singular: theta4 held at the hint, one wrist branch for this arm branch
        assert res.wrist_singular and "singular" in res.message
        assert np.allclose(res.solutions[wrist_singular, 3], 0.3) and wrist_singular.sum() == 1
        assert len(res.solutions) % 2 == 1  # the other arm branches in reach keep both wrist flips
    else:
        assert not res.wrist_singular and len(res.solutions) >= 4


def test_singular_hint_defaults_to_zero(ta40):
    q = np.array([10, 30, 80, 70, 0, 40]) * DEG
    res = analytic_ik(ta40, forward_kinematics(ta40, q))
    same_arm = np.abs(_wrap(res.solutions[:, :3] - q[:3])).max(axis=1) < 1e-9
    assert res.wrist_singular and same_arm.sum() == 1 and np.allclose(res.solutions[same_arm, 3], 0.0)
    assert np.allclose(_wrap(res.solutions[same_arm, 5]), 110 * DEG)  # the whole roll theta4 + theta6 in theta6


def test_target_out_of_reach(ta40):
    T = homogeneous(np.eye(3), [5.0, 0.0, 0.0])
    res = analytic_ik(ta40, T)
    assert not res.success and res.solutions.shape == (0, 6) and res.within_limits.shape == (0,)
    assert "out of reach" in res.message
    assert select_solution(ta40, res) is None
    comp = compensated_ik(ta40, random_errors(np.random.default_rng(1)), T)
    assert not comp.success and "out of reach" in comp.message and comp.position_error_m > 1.0


def test_target_reachable_only_outside_joint_limits(ta40):
    q = np.array([-50, 30, 90, 0, 40, 0]) * DEG  # joint 1 below -10 deg; theta1 + pi = 130 deg is above 90 deg
    T = forward_kinematics(ta40, q)
    res = analytic_ik(ta40, T)
    assert not res.success and len(res.solutions) > 0 and not res.within_limits.any()
    assert "joint limits" in res.message and "joint1" in res.message
    dp, dr = _pose_err(ta40, res.solutions, T)  # the branches still reproduce the pose
    assert dp.max() <= 1e-9 and dr.max() <= 1e-9
    assert select_solution(ta40, res) is None
    comp = compensated_ik(ta40, None, T)
    assert not comp.success and comp.at_limit[0, 0] and "limit" in comp.message
    assert comp.within_limits.all()  # clipped, reported


def test_select_solution(ta40):
    q = np.array([20, 50, 60, 30, 40, -70]) * DEG
    res = analytic_ik(ta40, forward_kinematics(ta40, q))
    assert res.within_limits.sum() >= 2
    assert np.allclose(select_solution(ta40, res, q + 0.01), q, atol=1e-9)
    other = res.solutions[res.within_limits][np.abs(_wrap(res.solutions[res.within_limits] - q)).max(axis=1) > 1e-3]
    assert np.allclose(select_solution(ta40, res.solutions, other[0]), other[0])
    assert select_solution(ta40, res.solutions) is not None  # default reference: centre of the ranges
    outside = q + np.array([-100, 0, 0, 0, 0, 0]) * DEG  # joint 1 at -80 deg: never selected, even if closest
    chosen = select_solution(ta40, np.vstack([res.solutions, outside]), outside)
    assert chosen is not None and np.all((chosen >= ta40.q_min - 1e-9) & (chosen <= ta40.q_max + 1e-9))


@pytest.mark.parametrize("form", ["exact", "linear"])
def test_compensated_ik_reaches_target_on_error_model(ta40, form):
    rng = np.random.default_rng(4503)
    Q = _interior(ta40, rng, 15)
    for q in Q:
        eps = random_errors(rng)  # +-2 mm, +-1 deg
        T = forward_kinematics(ta40, q, eps, form)
        u, _, vt = np.linalg.svd(T[:3, :3])
        T[:3, :3] = u @ vt  # rotation (polar) factor: the linear form's R is orthonormal to first order only
        res = compensated_ik(ta40, eps, T, form=form)
        assert res.success, res.message
        assert res.solutions.shape == (1, 6) and res.within_limits.all() and res.iterations >= 1
        p = forward_kinematics(ta40, res.solutions[0], eps, form)
        assert np.linalg.norm(p[:3, 3] - T[:3, 3]) <= 1e-9
        assert np.abs(vee(T[:3, :3].T @ p[:3, :3])).max() <= 1e-9  # (skew part: zero iff polar factor == R_t)
        assert res.position_error_m <= 1e-9 and res.orientation_error_rad <= 1e-9
        # the nominal solution alone misses by centimetres (or lies outside the limits): the compensation matters
        nominal = select_solution(ta40, analytic_ik(ta40, T), q)
        assert nominal is None or np.linalg.norm(forward_kinematics(ta40, nominal, eps, form)[:3, 3] - T[:3, 3]) > 1e-3
        # seeding near the true configuration returns its branch (up to the ill-conditioned direction theta1 +
        # theta4 when the forearm points along the joint-1 axis, as in one of these draws)
        res_q = compensated_ik(ta40, eps, T, q_seed=q + 0.02, form=form)
        assert res_q.success and np.abs(_wrap(res_q.solutions[0] - q)).max() < 0.05


def test_compensated_ik_position_only(ta40):
    rng = np.random.default_rng(4504)
    robot = ta40.with_ee_point([0.02, -0.01, 0.05])
    for q in _interior(robot, rng, 10):
        eps = random_errors(rng)
        T = forward_kinematics(robot, q, eps)
        res = compensated_ik(robot, eps, T, position_only=True)
        assert res.success, res.message
        p = ee_position(robot, res.solutions[0], eps)
        assert np.linalg.norm(p - ee_position(robot, q, eps)) <= 1e-9
        assert res.orientation_error_rad < 1e-6  # secondary objective: reached whenever the full pose is reachable
    # full pose unreachable (it needs |theta5| = 60 deg, joint 5 limited to +-20 deg), the point is reachable:
    # the position is met exactly and the orientation gives
    narrow = dataclasses.replace(robot, q_min=robot.q_min.copy(), q_max=robot.q_max.copy())
    narrow.q_min[4], narrow.q_max[4] = -20 * DEG, 20 * DEG
    T = forward_kinematics(narrow, np.array([40, 50, 90, 30, 60, 10]) * DEG)
    full = compensated_ik(narrow, None, T)
    assert not full.success and full.at_limit[0, 4] and "limit" in full.message
    pos = compensated_ik(narrow, None, T, position_only=True)
    assert pos.success and pos.position_error_m <= 1e-9 and pos.orientation_error_rad > 0.1, pos.message
    assert "position-only refinement" in pos.message and pos.within_limits.all()


def test_geometric_jacobian_matches_finite_differences(ta40):
    rng = np.random.default_rng(4505)
    eps = random_errors(rng)
    point = np.array([0.03, -0.02, 0.1])
    h = 1e-6
    for form in ("exact", "linear"):
        Q = ta40.random_configurations(rng, 5)
        J = geometric_jacobian(ta40, Q, eps, form, point)
        assert J.shape == (5, 6, 6)
        for k in range(6):
            dq = np.zeros(6)
            dq[k] = h
            T1, T2 = forward_kinematics(ta40, Q + dq, eps, form), forward_kinematics(ta40, Q - dq, eps, form)
            T0 = forward_kinematics(ta40, Q, eps, form)
            dp = (T1[..., :3, :3] @ point + T1[..., :3, 3] - T2[..., :3, :3] @ point - T2[..., :3, 3]) / (2 * h)
            w = vee((T1[..., :3, :3] - T2[..., :3, :3]) / (2 * h) @ np.linalg.inv(T0[..., :3, :3]))
            assert np.abs(J[..., :3, k] - dp).max() <= 1e-6
            assert np.abs(J[..., 3:, k] - w).max() <= 1e-6
    # nominal, exact form: the textbook z-axis / origin columns (z0 = base z axis for joint 1)
    J0 = geometric_jacobian(ta40, np.zeros(6))
    assert np.allclose(J0[3:, 0], [0, 0, 1]) and np.allclose(J0[:3, 0], np.cross([0, 0, 1], forward_kinematics(
        ta40, np.zeros(6))[:3, 3]))


@pytest.mark.parametrize("bad, match", [
    (np.full((4, 4), np.nan), "T_base_ee: contains NaN"),
    (np.eye(3), r"T_base_ee: expected shape \(4, 4\)"),
    (np.diag([2.0, 1.0, 1.0, 1.0]), "T_base_ee: rotation part is not orthonormal"),
    (np.stack([np.eye(4)] * 2), r"T_base_ee: expected shape \(4, 4\)"),
])
def test_malformed_target_raises(ta40, bad, match):
    with pytest.raises(ValueError, match=match):
        analytic_ik(ta40, bad)


def test_malformed_inputs_raise(ta40):
    T = forward_kinematics(ta40, np.full(6, 0.5))
    nan_T = T.copy()
    nan_T[0, 3] = np.nan
    with pytest.raises(ValueError, match="T_target: contains NaN"):
        compensated_ik(ta40, None, nan_T)
    with pytest.raises(ValueError, match="eps: expected shape"):
        compensated_ik(ta40, np.zeros(41), T)
    with pytest.raises(ValueError, match="q_seed"):
        compensated_ik(ta40, None, T, q_seed=np.full(6, np.nan))
    with pytest.raises(ValueError, match="form"):
        compensated_ik(ta40, None, T, form="quadratic")
    with pytest.raises(ValueError, match="q4_hint"):
        analytic_ik(ta40, T, q4_hint=np.nan)
    with pytest.raises(ValueError, match="solutions"):
        select_solution(ta40, np.zeros((2, 5)))


@pytest.mark.parametrize("field, value, match", [
    ("a", np.array([0.115, 0.753, 0.188, 0.01, 0.0, 0.0]), "spherical wrist"),
    ("d", np.array([0.0, 0.0, 0.0, 0.747, 0.02, 0.36]), "spherical wrist"),
    ("alpha", np.deg2rad([90, 0, -90, -90, 90, 0]), "twists"),
])
def test_unsupported_structure_raises(ta40, field, value, match):
    robot = dataclasses.replace(ta40, **{field: value})
    with pytest.raises(ValueError, match=f"robot: .*{match}"):
        analytic_ik(robot, np.eye(4))


def test_result_type(ta40):
    res = analytic_ik(ta40, forward_kinematics(ta40, np.full(6, 0.5)))
    assert isinstance(res, IKResult) and res.iterations == 0 and res.at_limit is None
    assert res.solutions.shape[1] == 6 and res.within_limits.dtype == bool
