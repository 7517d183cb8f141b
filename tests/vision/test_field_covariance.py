"""The joint bundle's covariance with each view's keypoint error field (bench.vision.field_covariance): the points'
elimination against a dense solve, and on the synthetic two-parking scene of test_joint_bundle with drawn per-view
fields the measured field is unbiased and the covariance is the estimates' scatter, where the white covariance is
several times too small; without a field it stays the white one."""

import numpy as np
import pytest

from bench.geometry.quaternion import matrix_to_rotation_vector
from bench.vision.bundle import Elimination
from bench.vision.joint_bundle import _Problem, joint_bundle, residuals_and_jacobian
from bench.vision.keypoint_field import field_basis, field_modes, mode_sd
from tests.vision.test_joint_bundle import LOC, MOUNT, K, Q, _scene

SIZE = (640, 480)
SIGMA_ENC = np.deg2rad(0.002)


def test_response_is_the_dense_least_squares_fit():
    """Elimination.response: the estimate's change and the residuals' for pixel errors b, against the dense normal
    equations over every parameter and point (priors on the joints), to 1e-9."""
    rng = np.random.default_rng(91)
    robot, eps, T_b2, X, view, point, x = _scene(rng, 12)
    problem = _Problem(robot, eps, MOUNT, LOC, view, point, x, K)
    r, J, J_pt, _ = residuals_and_jacobian(problem, np.r_[np.zeros(6), Q.ravel()], T_b2, X)
    N, n, M = J.shape[0], J.shape[2], len(X)
    Pp = np.zeros((n, n))
    Pp[6:, 6:] = np.eye(n - 6) * (0.1 / SIGMA_ENC) ** 2
    keep = rng.uniform(size=N) > 0.1
    el = Elimination(point, J, J_pt, M, Pp, keep)
    b = rng.normal(size=(N, 2, 5))
    d_theta, res = el.response(b)
    A = np.zeros((2 * N, n + 3 * M))
    A[:, :n] = J.reshape(2 * N, n)
    for i in range(N):
        A[2 * i:2 * i + 2, n + 3 * point[i]:n + 3 * point[i] + 3] = J_pt[i]
    A *= np.repeat(keep, 2)[:, None]
    H = A.T @ A
    H[:n, :n] += Pp
    H[n:, n:] += 1e-9 * np.eye(3 * M)  # the elimination's regularisation
    bf = b.reshape(2 * N, -1) * np.repeat(keep, 2)[:, None]
    d_all = -np.linalg.solve(H, A.T @ bf)
    assert np.allclose(d_theta, d_all[:n], rtol=1e-9, atol=1e-9 * np.abs(d_all[:n]).max())
    assert np.allclose(res.reshape(2 * N, -1), bf + A @ d_all, atol=1e-9 * np.abs(bf).max())


def _trials(rng, degree_px, n_trials, sigma_px=0.1, n_points=60, order=3):
    robot, eps, T_b2, X, view, point, x = _scene(rng, n_points)
    out = []
    for _ in range(n_trials):
        q_read = Q + rng.normal(0, SIGMA_ENC, Q.shape)
        xn = x + rng.normal(0, sigma_px, x.shape)
        for v in range(len(Q)):  # each view's field: its modes' amplitudes drawn, per axis
            m = view == v
            a = rng.normal(size=(len(mode_sd(degree_px)), 2)) * mode_sd(degree_px)[:, None]
            xn[m] += field_basis(x[m], SIZE, len(degree_px) - 1) @ np.linalg.solve(field_modes(x[m], SIZE, len(
                degree_px) - 1), a)
        jb = joint_bundle(robot, eps, MOUNT, q_read, LOC, T_b2, view, point, xn, X + rng.normal(0, 1e-3, X.shape),
                          SIGMA_ENC, 0.3, K, gate=None, field_order=order, image_size=SIZE)
        assert jb.success and jb.field.success, jb.message
        w = matrix_to_rotation_vector(jb.T_site_base[:3, :3] @ T_b2[:3, :3].T)
        e = np.r_[w, jb.T_site_base[:3, 3] - T_b2[:3, 3]]
        out.append((e, jb.field))
    return out


def _nees(out, which):
    return np.mean([e[3:] @ np.linalg.solve(getattr(f, which)[3:6, 3:6], e[3:]) for e, f in out])


def test_a_drawn_field_is_measured_and_covered():
    """Cubic fields of 0.05 / 0.04 / 0.03 / 0.02 px per mode on 0.1 px white noise: the white noise and each
    degree's sd come back (the offset's within its few-amplitude scatter), and the position NEES is chi-square's 3
    with the field, ~9 with the white covariance."""
    truth = np.array([0.05, 0.04, 0.03, 0.02])
    out = _trials(np.random.default_rng(92), truth, 30)
    sw = np.mean([f.sigma_white_px for _, f in out])
    deg = np.sqrt(np.mean([f.degree_px**2 for _, f in out], axis=0))
    assert sw == pytest.approx(0.1, rel=0.05)
    assert np.allclose(deg[1:], truth[1:], rtol=0.2) and deg[0] == pytest.approx(truth[0], rel=0.6)
    nees_field, nees_white = _nees(out, "covariance"), _nees(out, "white")
    assert 2.0 < nees_field < 4.5 and nees_white > 6.0, (nees_field, nees_white)


def test_without_a_field_the_covariance_stays_white():
    out = _trials(np.random.default_rng(93), np.zeros(4), 30)
    assert np.mean([f.sigma_white_px for _, f in out]) == pytest.approx(0.1, rel=0.05)
    assert np.all(np.sqrt(np.mean([f.degree_px[1:]**2 for _, f in out], axis=0)) < 0.01)
    ratio = np.mean([np.trace(f.covariance[3:6, 3:6]) / np.trace(f.white[3:6, 3:6]) for _, f in out])
    assert 0.9 < ratio < 1.3
    assert 2.0 < _nees(out, "covariance") < 4.0


def test_views_too_small_for_the_modes_leave_the_white_covariance():
    rng = np.random.default_rng(94)
    robot, eps, T_b2, X, view, point, x = _scene(rng, 12)  # 12 keypoints per view: fewer than the 30 cubic needs
    xn = x + rng.normal(0, 0.1, x.shape)
    jb = joint_bundle(robot, eps, MOUNT, Q, LOC, T_b2, view, point, xn, X, SIGMA_ENC, 0.3, K, gate=None,
                      field_order=3, image_size=SIZE)
    assert jb.success and not jb.field.success and jb.field.views == 0
    assert np.array_equal(jb.covariance, jb.field.white[:6, :6]) and "white" in jb.field.message
    with pytest.raises(ValueError, match="image_size"):
        joint_bundle(robot, eps, MOUNT, Q, LOC, T_b2, view, point, xn, X, SIGMA_ENC, 0.3, K, field_order=3)
