"""The localisation's maximum-likelihood estimate with the joint readings as measurements (issue 11).

The thesis's estimators (:func:`~bench.vision.insitu.locate`: RANSAC + absolute orientation, then optionally the
reprojection refinement and the bundle over the map) take every view's pose from the joint readings as exact. The
readings are measurements: encoders have noise and quantisation, ``sigma_enc`` per joint. At 0.7 m and a survey
baseline of ~100 mm, 0.002 deg on each of six joints moves the map as much as the keypoint noise does (Eq. 123:
the disparity error is amplified by range / baseline). :func:`joint_bundle` estimates, together,

* the base pose of the locate parking in the site (survey base) frame, ``T_site_b2`` (6: ``R' = exp(w) R``,
  ``t' = t + v`` - ``v`` is the base origin's shift, as in the scored error);
* every view's six joint angles, with the readings as a Gaussian prior of ``sigma_enc`` (rad);
* every map point (site frame), eliminated point by point (Schur complement),

from every observation the matching produced: each map point in the reference view, in the surrounding views that
contributed to it (:attr:`~bench.vision.insitu.KeypointMap.observations`) and in the two locate views where the
final solve used it (:attr:`~bench.vision.insitu.LocateResult.used`). The camera poses are
``T_site_cam = link5(q, eps) T_link5_cam`` (survey) and ``T_site_b2 link5(q, eps) T_link5_cam`` (locate) through the
calibrated arm (Eq. 188). Residuals are normalized image coordinates over ``sigma_n = sigma_px / f``; ``sigma_px`` is
re-estimated from the residuals (two rounds). Jacobians: the projection and the point derivative analytic, the pose
derivatives by central differences of the kinematics (6 joints of every view at once, 6 base coordinates) -
:func:`residuals_and_jacobian` is checked against a difference quotient of :func:`residuals` in the tests.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.geometry.quaternion import rotation_vector_to_matrix
from bench.robot.orientation import link5_frame


@dataclass(frozen=True)
class JointBundleResult:
    """Outcome of :func:`joint_bundle`.

    ``T_site_base`` (4, 4) the locate parking's base in the site frame; ``covariance`` (6, 6) its first-order
    covariance (rotation vector rad in the site frame, then the base origin m: the meaning of
    :attr:`~bench.vision.insitu.LocateResult.covariance`); ``q`` (V, 6) the refined joint angles (rad);
    ``sigma_px`` the pixel noise the residuals gave; ``rms_px`` the final residual RMS; ``observations``.
    """

    success: bool
    message: str
    T_site_base: np.ndarray
    covariance: np.ndarray
    q: np.ndarray
    sigma_px: float
    rms_px: float
    observations: int
    iterations: int


class _Problem:
    """The observations and the kinematics of :func:`joint_bundle` (see the module docstring)."""

    step = 1e-7

    def __init__(self, robot, eps, T_link5_cam, is_locate, view, point, x):
        self.robot, self.eps, self.mount = robot, np.asarray(eps, float), np.asarray(T_link5_cam, float)
        self.is_locate = np.asarray(is_locate, bool)
        self.view, self.point, self.x = np.asarray(view, int), np.asarray(point, int), np.asarray(x, float)
        self.V = len(self.is_locate)

    def poses(self, xi, T_b2, q) -> np.ndarray:
        """``T_cam_site`` (V, 4, 4) of every view."""
        T = np.array(T_b2, dtype=float)
        T[:3, :3] = rotation_vector_to_matrix(xi[:3]) @ T[:3, :3]
        T[:3, 3] += xi[3:]
        T_site_cam = link5_frame(self.robot, q, self.eps) @ self.mount
        T_site_cam[self.is_locate] = T @ T_site_cam[self.is_locate]
        return np.linalg.inv(T_site_cam)

    def camera_points(self, T_cs, X) -> np.ndarray:
        R, t = T_cs[self.view, :3, :3], T_cs[self.view, :3, 3]
        return np.einsum("nij,nj->ni", R, X[self.point]) + t


def residuals(problem: _Problem, xi, T_b2, q, X) -> np.ndarray:
    """Normalized-coordinate residuals ``x - pi(p_cam)`` (N, 2) of every observation."""
    p = problem.camera_points(problem.poses(xi, T_b2, q), X)
    return problem.x - p[:, :2] / p[:, 2:3]


def residuals_and_jacobian(problem: _Problem, xi, T_b2, q, X) -> tuple:
    """Residuals (N, 2), ``J_par (N, 2, 6 + 6 V)`` (d residual / d (xi, q view by view)) and ``J_pt (N, 2, 3)``
    (d residual of observation n / d its point), and the smallest depth (m) of a point in a camera."""
    T_cs = problem.poses(xi, T_b2, q)
    p = problem.camera_points(T_cs, X)
    z = p[:, 2]
    u = p[:, :2] / z[:, None]
    Jproj = np.zeros((len(p), 2, 3))
    Jproj[:, 0, 0] = Jproj[:, 1, 1] = 1.0 / z
    Jproj[:, :, 2] = -u / z[:, None]
    N, V, h = len(p), problem.V, problem.step
    J = np.zeros((N, 2, 6 + 6 * V))
    for c in range(6):  # the base pose: its rows are the locate views'
        e = np.zeros(6)
        e[c] = h
        dp = (problem.camera_points(problem.poses(xi + e, T_b2, q), X)
              - problem.camera_points(problem.poses(xi - e, T_b2, q), X)) / (2 * h)
        J[:, :, c] = -np.einsum("nij,nj->ni", Jproj, dp)
    for c in range(6):  # joint c of every view at once: rows of view v depend on its own joints only
        e = np.zeros_like(q)
        e[:, c] = h
        dp = (problem.camera_points(problem.poses(xi, T_b2, q + e), X)
              - problem.camera_points(problem.poses(xi, T_b2, q - e), X)) / (2 * h)
        J[np.arange(N), :, 6 + 6 * problem.view + c] = -np.einsum("nij,nj->ni", Jproj, dp)
    J_pt = -Jproj @ T_cs[problem.view, :3, :3]
    return problem.x - u, J, J_pt, float(z.min())


def _normal_equations(problem, r, J, J_pt, M, prior_info, prior_res, keep=None):
    """The reduced system (points eliminated): ``S (n, n)``, gradient ``g (n,)`` and the points' back-substitution.
    Observations outside ``keep`` (N,) bool weigh nothing; a point left with fewer than two is held where it is."""
    n = J.shape[2]
    if keep is not None:
        w = keep.astype(float)
        r, J, J_pt = r * w[:, None], J * w[:, None, None], J_pt * w[:, None, None]
    A = np.einsum("nki,nkj->ij", J, J) + prior_info
    g_c = np.einsum("nki,nk->i", J, r) + prior_res
    B = np.zeros((M, n, 3))
    np.add.at(B, problem.point, np.swapaxes(J, 1, 2) @ J_pt)
    C = np.zeros((M, 3, 3))
    np.add.at(C, problem.point, np.swapaxes(J_pt, 1, 2) @ J_pt)
    g_m = np.zeros((M, 3))
    np.add.at(g_m, problem.point, np.einsum("nki,nk->ni", J_pt, r))
    Cinv = np.linalg.inv(C + 1e-9 * np.eye(3))  # regularised: a point gated down to one view (B = 0) stays put
    BCinv = B @ Cinv
    S = A - np.einsum("mik,mjk->ij", BCinv, B)
    g = g_c - np.einsum("mik,mk->i", BCinv, g_m)

    def points_step(dc):
        return -np.einsum("mkl,ml->mk", Cinv, g_m + np.einsum("mik,i->mk", B, dc))

    return 0.5 * (S + S.T), g, points_step


def joint_bundle(robot, eps, T_link5_cam, q_read, is_locate, T_site_b2, view, point, x, X, sigma_enc: float,
                 sigma_px: float, focal_px: float, iterations: int = 10, rounds: int = 3,
                 gate: float | None = 3.5) -> JointBundleResult:
    """Base pose, joints of every view and map points by maximum likelihood (see the module docstring).

    Parameters
    ----------
    robot, eps, T_link5_cam
        The calibrated arm: model, identified errors (42,), camera mount (4, 4).
    q_read : ndarray (V, 6)
        Joint readings (rad) of the views (reference, surrounding, then the locate views).
    is_locate : ndarray (V,) bool
        The views taken at the locate parking.
    T_site_b2 : ndarray (4, 4)
        Starting base pose of the locate parking in the site frame (e.g. the thesis estimator's).
    view, point : ndarray (N,) int
        Observation ``n`` is of point ``point[n]`` in view ``view[n]``; ``x (N, 2)`` its normalized keypoint.
    X : ndarray (M, 3)
        Starting points (site frame, m); every point must be observed in at least two views.
    sigma_enc : float
        Encoder standard deviation (rad per joint, quantisation included) - from the encoders' specification.
    sigma_px, focal_px : float
        Starting pixel noise (px; re-estimated from the residuals) and the focal length (px) that converts it.
    iterations, rounds : int
        Gauss-Newton iterations per round; rounds of re-estimating the pixel noise and the gate.
    gate : float or None
        After each round, observations whose residual exceeds ``gate`` x the robust sigma (median residual / 1.1774)
        weigh nothing in the next (keypoints' errors have heavy tails: measured ~0.09 px robust but 0.35 px RMS
        within 5 px under realistic imaging); ``None`` keeps every observation.
    """
    q_read = np.asarray(q_read, float)
    X = np.array(X, dtype=float)
    V, M = len(q_read), len(X)
    nan6 = np.full((6, 6), np.nan)
    if not (sigma_enc > 0 and sigma_px > 0 and focal_px > 0):
        raise ValueError(f"sigma_enc ({sigma_enc} rad), sigma_px ({sigma_px} px) and focal_px ({focal_px} px) must "
                         "be > 0")
    counts = np.bincount(np.asarray(point, int), minlength=M)
    if np.any(counts < 2):
        raise ValueError(f"{int(np.sum(counts < 2))} points observed in fewer than two views")
    problem = _Problem(robot, eps, T_link5_cam, is_locate, view, point, x)
    xi, q = np.zeros(6), q_read.copy()
    it_total, S, s_px = 0, None, float(sigma_px)
    keep = np.ones(len(problem.view), dtype=bool)
    for _ in range(rounds):
        sn = s_px / focal_px
        w_enc = 1.0 / sigma_enc**2
        prior_info = np.zeros((6 + 6 * V, 6 + 6 * V))
        prior_info[6:, 6:] = np.eye(6 * V) * w_enc * sn**2  # in units of the normalized residuals' weight
        for _ in range(iterations):
            it_total += 1
            r, J, J_pt, z_min = residuals_and_jacobian(problem, xi, T_site_b2, q, X)
            if z_min <= 0:
                return JointBundleResult(False, "points behind a camera", T_site_b2, nan6, q, s_px, np.nan,
                                         len(r), it_total)
            prior_res = np.r_[np.zeros(6), (q - q_read).ravel() * w_enc * sn**2]
            S, g, points_step = _normal_equations(problem, r, J, J_pt, M, prior_info, prior_res, keep)
            d = np.sqrt(np.diag(S))
            dc = -np.linalg.solve(S / np.outer(d, d), g / d) / d
            if not np.all(np.isfinite(dc)):
                return JointBundleResult(False, "singular reduced system", T_site_b2, nan6, q, s_px, np.nan, len(r),
                                         it_total)
            xi = xi + dc[:6]
            q = q + dc[6:].reshape(V, 6)
            X = X + points_step(dc)
            if np.abs(dc).max() < 1e-12:
                break
        r = residuals(problem, xi, T_site_b2, q, X)
        e = np.linalg.norm(r, axis=1)
        if gate:  # heavy tails (a keypoint on a similar-looking feature nearby): gate at gate x the robust sigma
            sigma_robust = float(np.median(e[keep])) / 1.1774  # the Rayleigh median of a 2D Gaussian of sigma
            keep = e <= gate * sigma_robust
        dof = max(2 * int(keep.sum()) - 3 * M - 6, 1)
        s_px = float(np.sqrt(np.sum(e[keep] ** 2) / dof)) * focal_px
    r, J, J_pt, _ = residuals_and_jacobian(problem, xi, T_site_b2, q, X)
    sn = s_px / focal_px
    prior_info = np.zeros((6 + 6 * V, 6 + 6 * V))
    prior_info[6:, 6:] = np.eye(6 * V) * sn**2 / sigma_enc**2
    S, _, _ = _normal_equations(problem, r, J, J_pt, M, prior_info, np.zeros(6 + 6 * V), keep)
    r = r[keep]
    cov = sn**2 * np.linalg.inv(S)[:6, :6]
    T = np.array(T_site_b2, dtype=float)
    T[:3, :3] = rotation_vector_to_matrix(xi[:3]) @ T[:3, :3]
    T[:3, 3] += xi[3:]
    rms = float(np.sqrt(np.mean(np.sum(r**2, axis=1)) / 2)) * focal_px
    return JointBundleResult(True, f"ok; joint bundle of {M} points, {len(r)} of {len(keep)} observations kept, {V} "
                             f"views' joints, sigma {s_px:.3g} px", T, 0.5 * (cov + cov.T), q, s_px, rms, len(r),
                             it_total)


def observations_of(kmap, used, n_surround: int) -> tuple:
    """``(view, point, x, points)`` of :func:`joint_bundle` from a map and a locate result's ``used``: the map points
    seen in the locate views (renumbered ``0..M-1``; ``points`` their map indices), each in the reference (view 0),
    its surrounding views (1..K) and the two locate views (K + 1, K + 2)."""
    idx, x_a, x_b = used
    idx = np.asarray(idx, int)
    view, point, x = [], [], []
    for j, i in enumerate(idx):
        views, xs = kmap.observations[i]
        view += [0, *(1 + np.asarray(views, int)), n_surround + 1, n_surround + 2]
        point += [j] * (len(views) + 3)
        x += [kmap.x_ref[i], *np.asarray(xs).reshape(-1, 2), x_a[j], x_b[j]]
    return np.array(view, int), np.array(point, int), np.array(x, float).reshape(-1, 2), idx
