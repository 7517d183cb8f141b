import dataclasses

import numpy as np
import pytest

from bench.geometry.transforms import homogeneous, random_transform, rot_z, rotation_angle
from bench.robot.base_from_arcs import (
    base_frame_accuracy,
    base_frame_from_arcs,
    base_frame_from_axes,
    pose_deviation,
    simulate_arcs,
    true_axes,
)
from bench.robot.kinematics import error_matrix
from bench.robot.model import random_errors

Q_START = np.deg2rad([10.0, 30.0, 100.0, 20.0, 40.0, 0.0])  # arm stretched out: probe ~1.3-1.8 m from both axes


def _run(robot, m, **kw):
    return base_frame_from_arcs(m.arc1_tracker, m.arc2_tracker, m.q1_during_arc2, m.q1_arc1, m.q2_arc2, robot, **kw)


def _errors_beyond_frame_1(rng):
    eps = random_errors(rng)
    eps[:12] = 0.0
    return eps


def _pose_err(T_est, T_ref):
    return np.linalg.norm(T_est[:3, 3] - T_ref[:3, 3]), rotation_angle(T_est[:3, :3].T @ T_ref[:3, :3])


@pytest.mark.parametrize("span1_deg, span2_deg, q_start_deg",
                         [(20.0, 20.0, [0.0, 10.0, 100.0, 20.0, 40.0, 0.0]),
                          (40.0, 30.0, [50.0, 80.0, 60.0, -30.0, 70.0, 90.0]),
                          (100.0, 110.0, [-10.0, 0.0, 120.0, 0.0, -40.0, 0.0])])
def test_noise_free_exact_without_errors_in_frames_0_1(ta40, span1_deg, span2_deg, q_start_deg):
    rng = np.random.default_rng(41)
    for _ in range(5):
        T = random_transform(rng, scale=2.0)
        eps = _errors_beyond_frame_1(rng)
        m = simulate_arcs(ta40, T, np.deg2rad(q_start_deg), np.deg2rad(span1_deg), np.deg2rad(span2_deg), 12, eps)
        res = _run(ta40, m)
        assert res.success, res.message
        pos, rot = _pose_err(res.T_tracker_base, T)
        assert pos <= 1e-9 and rot <= 1e-9
        assert res.residual_rms_m <= 1e-9
        assert res.a1_measured_m == pytest.approx(0.115, abs=1e-9)  # the model's a1 and alpha1, measured
        assert res.alpha1_measured_rad == pytest.approx(np.pi / 2, abs=1e-9)
        assert res.axis1.direction @ T[:3, 2] == pytest.approx(1.0, abs=1e-12)  # +z0, from the rotation sense


def test_point_order_does_not_matter_and_readings_give_the_sense(ta40):
    rng = np.random.default_rng(42)
    T = random_transform(rng, scale=2.0)
    m = simulate_arcs(ta40, T, Q_START, np.deg2rad(30), np.deg2rad(30), 10)
    perm1, perm2 = rng.permutation(10), rng.permutation(10)
    shuffled = dataclasses.replace(m, arc1_tracker=m.arc1_tracker[perm1], q1_arc1=m.q1_arc1[perm1],
                                   arc2_tracker=m.arc2_tracker[perm2], q2_arc2=m.q2_arc2[perm2])
    assert np.abs(_run(ta40, shuffled).T_tracker_base - T).max() <= 1e-9
    # readings that decrease along the same motion: the joint turns the other way round, z0 flips
    flipped = dataclasses.replace(m, q1_arc1=-m.q1_arc1)
    res = _run(ta40, flipped)
    assert res.success and res.axis1.direction @ T[:3, 2] == pytest.approx(-1.0, abs=1e-12)


def test_e0_is_absorbed_into_the_measured_base(ta40):
    """A perturbed E0 moves both joint axes rigidly: the arcs return the actual frame 0, T_tracker_base E0."""
    rng = np.random.default_rng(43)
    for _ in range(5):
        T = random_transform(rng, scale=2.0)
        eps = _errors_beyond_frame_1(rng)
        eps[:6] = random_errors(rng)[:6]
        res = _run(ta40, simulate_arcs(ta40, T, Q_START, np.deg2rad(40), np.deg2rad(40), 12, eps))
        pos, rot = _pose_err(res.T_tracker_base, T @ error_matrix(eps[:6]))
        assert pos <= 1e-9 and rot <= 1e-9
        assert _pose_err(res.T_tracker_base, T)[0] > 1e-4  # and it is not the nominal base


@pytest.mark.parametrize("k, value", [(0, 2e-3), (1, 2e-3), (2, -2e-3), (3, 0.02), (4, -0.02), (5, 0.02)])
def test_single_e1_errors(ta40, k, value):
    """Of E1 only y1 (along z0: origin shift) and s1 (about z0: x0 turn) move the measured base, exactly
    ``T Tz(y1) Rz(s1)``; x1, z1, r1, p1 change only the measured a1 / alpha1."""
    rng = np.random.default_rng(44)
    T = random_transform(rng, scale=2.0)
    eps = np.zeros(42)
    eps[6 + k] = value
    res = _run(ta40, simulate_arcs(ta40, T, Q_START, np.deg2rad(40), np.deg2rad(40), 12, eps))
    expected = {1: homogeneous(np.eye(3), [0, 0, value]), 3: homogeneous(rot_z(value), np.zeros(3))}
    pos, rot = _pose_err(res.T_tracker_base, T @ expected.get(k, np.eye(4)))
    assert pos <= 1e-9 and rot <= 1e-9
    if k == 0:
        assert res.a1_measured_m == pytest.approx(0.115 + value, abs=1e-9)
    if k == 5:
        assert res.alpha1_measured_rad == pytest.approx(np.pi / 2 + value, abs=1e-9)


def test_general_e1_is_first_order_exact(ta40):
    """All of E0, E1 random: deviation from ``T E0 Tz(y1) Rz(s1)`` is second order (1/10 errors -> 1/100)."""
    rng = np.random.default_rng(45)
    T = random_transform(rng, scale=2.0)
    eps = random_errors(rng)

    def deviation(e):
        res = _run(ta40, simulate_arcs(ta40, T, Q_START, np.deg2rad(40), np.deg2rad(40), 12, e))
        e1 = e[6:12]
        F = T @ error_matrix(e[:6]) @ homogeneous(rot_z(e1[3]), [0, 0, e1[1]])
        # and the arcs agree with the construction on the true axes
        truth = base_frame_from_axes(*true_axes(ta40, e, T, Q_START[0]), Q_START[0], ta40).T_tracker_base
        assert np.abs(res.T_tracker_base - truth).max() <= 1e-9
        return np.linalg.norm(pose_deviation(res.T_tracker_base, F)[:3])

    big, small = deviation(eps), deviation(eps / 10)
    assert 1e-6 < big < 1e-4  # second-order products such as z1 p1 (mm x deg)
    assert 0.005 < small / big < 0.02


@pytest.mark.parametrize("span_deg", [20.0, 40.0])
def test_noise_vs_predicted_accuracy(ta40, span_deg):
    """sigma = 0.05 mm: the errors over 200 noise draws match the linear prediction (RMS and chi-square)."""
    rng = np.random.default_rng(46)
    T = random_transform(rng, scale=2.0)
    sigma, span = 5e-5, np.deg2rad(span_deg)
    clean = simulate_arcs(ta40, T, Q_START, span, span, 20, _errors_beyond_frame_1(rng))
    pred = base_frame_accuracy(clean.arc1_tracker, clean.arc2_tracker, clean.q1_during_arc2, clean.q1_arc1,
                               clean.q2_arc2, ta40, sigma)
    devs = []
    for _ in range(200):
        noisy = dataclasses.replace(clean, arc1_tracker=clean.arc1_tracker + rng.normal(scale=sigma, size=(20, 3)),
                                    arc2_tracker=clean.arc2_tracker + rng.normal(scale=sigma, size=(20, 3)))
        res = _run(ta40, noisy)
        assert res.success, res.message
        devs.append(pose_deviation(res.T_tracker_base, T))
    D = np.array(devs)
    pos_rms = np.sqrt(np.mean(np.sum(D[:, :3] ** 2, axis=1)))
    rot_rms = np.sqrt(np.mean(np.sum(D[:, 3:] ** 2, axis=1)))
    assert 0.8 < pos_rms / pred.pos_std_m < 1.2
    assert 0.8 < rot_rms / pred.rot_std_rad < 1.2
    chi2 = np.einsum("ki,ij,kj->k", D, np.linalg.inv(pred.covariance), D)
    assert abs(chi2.mean() - 6.0) < 4 * np.sqrt(12.0 / len(D))  # E = 6, var = 12 for 6 dof


def test_monte_carlo_helper_agrees_with_linear_propagation(ta40):
    rng = np.random.default_rng(47)
    T = random_transform(rng, scale=2.0)
    sigma = 5e-5
    m = simulate_arcs(ta40, T, Q_START, np.deg2rad(60), np.deg2rad(50), 15, _errors_beyond_frame_1(rng), sigma, rng)
    args = (m.arc1_tracker, m.arc2_tracker, m.q1_during_arc2, m.q1_arc1, m.q2_arc2, ta40, sigma)
    lin = base_frame_accuracy(*args, sigma_q_rad=1e-4)
    mc = base_frame_accuracy(*args, sigma_q_rad=1e-4, method="monte_carlo", n_samples=300, rng=rng)
    assert mc.n_failed == 0 and mc.method == "monte_carlo" and lin.method == "linear"
    assert 0.85 < mc.pos_std_m / lin.pos_std_m < 1.15 and 0.85 < mc.rot_std_rad / lin.rot_std_rad < 1.15
    # the reading noise of q1 during arc 2 turns x0 about z0 by exactly that much
    no_q = base_frame_accuracy(*args)
    assert lin.rot_std_rad**2 - no_q.rot_std_rad**2 == pytest.approx(1e-8, rel=1e-3)


def test_longer_arcs_are_more_accurate(ta40):
    rng = np.random.default_rng(48)
    T = random_transform(rng, scale=2.0)
    stds = []
    for span in (20.0, 45.0, 90.0):
        m = simulate_arcs(ta40, T, np.r_[-0.17, 0.0, Q_START[2:]], np.deg2rad(span), np.deg2rad(span), 15)
        stds.append(base_frame_accuracy(m.arc1_tracker, m.arc2_tracker, m.q1_during_arc2, m.q1_arc1, m.q2_arc2,
                                        ta40, 5e-5).pos_std_m)
    assert stds[0] > 2 * stds[1] > 4 * stds[2]


def test_arcs_must_stay_within_the_joint_limits(ta40):
    T = np.eye(4)
    with pytest.raises(ValueError, match=r"span1: joint 1 .* leaves its limits \[-10, 90\] deg"):
        simulate_arcs(ta40, T, Q_START, np.deg2rad(85), np.deg2rad(20), 10)
    with pytest.raises(ValueError, match="span2: joint 2"):
        simulate_arcs(ta40, T, Q_START, np.deg2rad(20), np.deg2rad(-40), 10)


def test_three_nearly_identical_points(ta40):
    rng = np.random.default_rng(49)
    T = random_transform(rng, scale=2.0)
    m = simulate_arcs(ta40, T, Q_START, np.deg2rad(1e-4), np.deg2rad(30), 3, sigma_m=5e-5, rng=rng)
    res = _run(ta40, m)
    assert not res.success and "q1_arc1: the arc spans" in res.message and np.isnan(res.T_tracker_base).all()
    res = _run(ta40, m, min_span_deg=0.0)  # without the span guard the noisy fit no longer follows the readings
    assert not res.success and "arc1_tracker: angles on the fitted circle do not follow q1_arc1" in res.message


def test_degenerate_arcs_return_a_reason(ta40):
    rng = np.random.default_rng(50)
    m = simulate_arcs(ta40, random_transform(rng), Q_START, np.deg2rad(30), np.deg2rad(30), 8)
    line = m.arc1_tracker[0] + np.outer(np.linspace(0, 1, 8), [0.1, 0.2, -0.3])
    res = _run(ta40, dataclasses.replace(m, arc1_tracker=line))
    assert not res.success and res.message.startswith("arc1_tracker: points are collinear")
    same = _run(ta40, dataclasses.replace(m, arc2_tracker=np.repeat(m.arc2_tracker[:1], 8, axis=0)))
    assert not same.success and same.message.startswith("arc2_tracker: all points coincide")
    # the joint-1 arc measured twice: both axes coincide, no common normal
    twice = _run(ta40, dataclasses.replace(m, arc2_tracker=m.arc1_tracker + 0.3 * m.arc1_tracker[0],
                                           q2_arc2=m.q1_arc1))
    assert not twice.success and "parallel" in twice.message


@pytest.mark.parametrize(
    "change, match",
    [
        ({"arc1_tracker": np.full((5, 3), np.nan)}, "arc1_tracker: contains NaN"),
        ({"arc2_tracker": np.zeros((2, 3))}, "arc2_tracker: needs at least 3 points"),
        ({"q1_arc1": np.zeros(4)}, r"q1_arc1: expected shape \(10,\)"),
        ({"q2_arc2": np.linspace(0, 40, 10)}, "q2_arc2: .*degrees"),
        ({"q1_during_arc2": float("nan")}, "q1_during_arc2: must be finite"),
    ],
)
def test_malformed_input_names_the_argument(ta40, change, match):
    m = simulate_arcs(ta40, np.eye(4), Q_START, np.deg2rad(30), np.deg2rad(30), 10)
    with pytest.raises(ValueError, match=match) as info:
        _run(ta40, dataclasses.replace(m, **change))
    assert "\n" not in str(info.value)


def test_robot_with_parallel_first_axes_is_rejected(ta40):
    m = simulate_arcs(ta40, np.eye(4), Q_START, np.deg2rad(30), np.deg2rad(30), 10)
    planar = dataclasses.replace(ta40, alpha=np.r_[0.0, ta40.alpha[1:]])
    with pytest.raises(ValueError, match="robot: alpha1"):
        _run(planar, m)


def test_accuracy_bad_input(ta40):
    m = simulate_arcs(ta40, np.eye(4), Q_START, np.deg2rad(30), np.deg2rad(30), 10)
    args = (m.arc1_tracker, m.arc2_tracker, m.q1_during_arc2, m.q1_arc1, m.q2_arc2, ta40)
    with pytest.raises(ValueError, match="sigma_m"):
        base_frame_accuracy(*args, -1e-5)
    with pytest.raises(ValueError, match="rng"):
        base_frame_accuracy(*args, 1e-5, method="monte_carlo")
    with pytest.raises(ValueError, match="method"):
        base_frame_accuracy(*args, 1e-5, method="bootstrap")


def test_cramer_rao_bound_of_the_arcs(ta40):
    """The geometry-only bound equals the circle fit's own first-order spread (the fit is efficient with what it
    uses); knowing the angles from the joint readings bounds the origin ~3x tighter at 90 deg arcs; a Monte Carlo of
    the fit agrees with its bound."""
    from bench.robot.base_from_arcs import base_frame_bound

    rng = np.random.default_rng(17)
    T = random_transform(rng, scale=2.0)
    q0 = np.deg2rad([-10, 0, 100, 20, 40, 0])
    clean = simulate_arcs(ta40, T, q0, np.deg2rad(90), np.deg2rad(90), 20)
    args = (clean.arc1_tracker, clean.arc2_tracker, clean.q1_during_arc2, clean.q1_arc1, clean.q2_arc2, ta40, 5e-5)
    geometry = base_frame_bound(*args, readings=False)
    bound = base_frame_bound(*args)
    lin = base_frame_accuracy(*args)
    assert geometry.pos_std_m == pytest.approx(lin.pos_std_m, rel=1e-3)
    assert geometry.rot_std_rad == pytest.approx(lin.rot_std_rad, rel=1e-3)
    assert bound.pos_std_m < 0.5 * geometry.pos_std_m and bound.method == "cramer_rao"
    err = [np.linalg.norm(base_frame_from_arcs(clean.arc1_tracker + rng.normal(0, 5e-5, (20, 3)),
                                               clean.arc2_tracker + rng.normal(0, 5e-5, (20, 3)),
                                               clean.q1_during_arc2, clean.q1_arc1, clean.q2_arc2,
                                               ta40).T_tracker_base[:3, 3] - T[:3, 3]) for _ in range(200)]
    assert np.sqrt(np.mean(np.square(err))) == pytest.approx(geometry.pos_std_m, rel=0.15)  # 200 draws
    with pytest.raises(ValueError, match="sigma_m"):
        base_frame_bound(*args[:-1], -1.0)
