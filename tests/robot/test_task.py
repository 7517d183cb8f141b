"""Re-targeting a taught tool pose after the base moved (bench.robot.task)."""

import numpy as np
import pytest

from bench.geometry.transforms import homogeneous, rot_z, transform_points
from bench.robot.kinematics import forward_kinematics
from bench.robot.model import default_robot_path, load_robot, random_errors
from bench.robot.task import retarget_taught_pose, taught_pose


@pytest.fixture(scope="module")
def ta40():
    return load_robot(default_robot_path())


def test_noise_free_retarget_puts_the_tool_back_exactly(ta40):
    """Exact errors and base pose: the tool returns to the taught pose (position exactly, orientation secondary)."""
    rng = np.random.default_rng(41)
    eps = random_errors(rng)
    q_taught = np.deg2rad([30.0, 40.0, 60.0, 20.0, 50.0, 10.0])
    T_site_ee = taught_pose(ta40, eps, q_taught)
    assert np.allclose(T_site_ee, forward_kinematics(ta40, q_taught, eps), atol=1e-15)
    T_site_base = homogeneous(rot_z(np.deg2rad(4.0)), [0.12, -0.08, 0.03])  # the ROV parked again
    res = retarget_taught_pose(ta40, eps, q_taught, T_site_base)
    assert res.success, res.message
    T_new = T_site_base @ forward_kinematics(ta40, res.solutions[0], eps)
    tip = transform_points(T_new, ta40.p_ee)
    assert np.linalg.norm(tip - transform_points(T_site_ee, ta40.p_ee)) < 1e-9
    assert res.orientation_error_rad < 1e-6  # reachable: the secondary objective is met too
    full = retarget_taught_pose(ta40, eps, q_taught, T_site_base, position_only=False)
    T_full = T_site_base @ forward_kinematics(ta40, full.solutions[0], eps)
    assert full.success and np.abs(T_full - T_site_ee).max() < 1e-9


def test_base_error_moves_the_tool_by_the_same_amount(ta40):
    """A located base that is off by a small translation puts the tool off by that translation (first order)."""
    rng = np.random.default_rng(42)
    eps = random_errors(rng)
    q_taught = np.deg2rad([25.0, 35.0, 70.0, -30.0, 40.0, 0.0])
    T_true = homogeneous(rot_z(0.05), [0.1, 0.05, 0.0])
    delta = np.array([1e-3, -2e-3, 0.5e-3])
    T_est = T_true.copy()
    T_est[:3, 3] += delta
    res = retarget_taught_pose(ta40, eps, q_taught, T_est)
    tip = transform_points(T_true @ forward_kinematics(ta40, res.solutions[0], eps), ta40.p_ee)
    target = transform_points(forward_kinematics(ta40, q_taught, eps), ta40.p_ee)
    assert np.allclose(tip - target, -delta, atol=1e-9)


def test_taught_pose_from_another_base_and_failures(ta40):
    q = np.deg2rad([30.0, 40.0, 60.0, 20.0, 50.0, 10.0])
    T_b = homogeneous(rot_z(0.3), [0.5, 0.2, 0.0])
    assert np.allclose(taught_pose(ta40, None, q, T_b), T_b @ forward_kinematics(ta40, q), atol=1e-15)
    far = retarget_taught_pose(ta40, None, q, homogeneous(np.eye(3), [-3.0, 0.0, 0.0]))  # 3 m away: out of reach
    assert not far.success and far.message
    with pytest.raises(ValueError, match="q_taught"):
        taught_pose(ta40, None, [np.nan] * 6)
    with pytest.raises(ValueError, match="q_taught"):
        taught_pose(ta40, None, np.rad2deg(q))  # degrees where radians belong
    with pytest.raises(ValueError, match="T_site_base"):
        retarget_taught_pose(ta40, None, q, np.ones((4, 4)))
