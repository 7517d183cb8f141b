import numpy as np

from bench.geometry.transforms import rot_x, rot_y, rot_z
from bench.robot.identifiability import closed_form_reduction
from bench.robot.kinematics import link_frames
from bench.robot.model import random_errors
from bench.robot.orientation import link5_frame, orientation_analysis, yxz_angles


def test_yxz_angles_round_trip(rng):
    a = rng.uniform(-0.5, 0.5, size=(50, 3))
    R = rot_y(a[:, 1]) @ rot_x(a[:, 0]) @ rot_z(a[:, 2])
    assert np.abs(yxz_angles(R) - a).max() < 1e-12


def test_link5_frame_is_eq188(ta40, rng):
    q = ta40.random_configurations(rng, 10)
    eps = random_errors(rng)
    T5 = link5_frame(ta40, q, eps)
    # Eq. 188 differs from frame 5 of Eq. 10 by E5 only
    F = link_frames(ta40, q, eps)
    from bench.robot.kinematics import error_matrix

    assert np.abs(T5 @ error_matrix(eps[30:36]) - F[:, 5]).max() < 1e-12


def test_link5_deviation_is_constant_after_calibration(ta40, rng):
    eps = random_errors(rng)
    eps[36:] = 0.0
    red = closed_form_reduction(ta40)
    # the exact-model reduced errors that reproduce every end-effector point: fit them noise-free
    from bench.robot.identification import identify_iterative
    from bench.robot.kinematics import ee_position

    q = ta40.random_configurations(rng, 60)
    est = identify_iterative(ta40, q, ee_position(ta40, q, eps), red).eps
    dev = orientation_analysis(ta40, ta40.random_configurations(rng, 100), eps, est)
    assert np.abs(dev["ee_pos_m"]).max() < 1e-10
    assert np.ptp(dev["link5_rot_rad"], axis=0).max() < 1e-10  # constant bias (section 4.6)
    assert np.ptp(dev["link5_pos_m"], axis=0).max() < 1e-10
    assert np.ptp(dev["ee_rot_rad"], axis=0).max() > 1e-3  # while the end effector's rotation error varies
