"""Identification of the generalized errors from measured end-effector points (thesis Eq. 12-14, §4.4).

Estimated: the reduced, identifiable errors ``eps_dot`` (the kept entries of a :class:`Reduction`).
Fixed: the nominal DH parameters and the eliminated errors (zero). Measurements: end-effector points ``p_base``
(m) at joint readings ``q`` (rad), with per-axis standard deviation ``sigma`` (m) giving the weights.

* :func:`identify_linear` - one weighted least-squares solve of ``dX_t = G_t eps_dot`` (Eq. 13-14 with ``G_e``),
  the thesis's method; exact when the data come from the linearised model.
* :func:`identify_iterative` - Levenberg-Marquardt (Gauss-Newton with adaptive damping) on the exact model.

Solvers return an :class:`IdentificationResult` and never raise on non-convergence or rank deficiency.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from bench.robot.identifiability import Reduction
from bench.robot.jacobian import identification_jacobian
from bench.robot.kinematics import ee_position
from bench.robot.model import Robot


@dataclass
class IdentificationResult:
    """Outcome of an identification.

    Attributes
    ----------
    success : bool
    message : str
    eps : ndarray (6 (n + 1),)
        Full error vector (m, rad): the estimate at the kept positions, zero elsewhere.
    eps_dot : ndarray (p,)
        The estimated reduced errors.
    covariance : ndarray (p, p)
        Of ``eps_dot``: ``(G^T W G)^-1`` with ``W = 1 / sigma^2`` (a-priori sigma).
    residual_rms : float
        RMS of the 3D point residuals after the fit (m), over all coordinates.
    condition_number : float
        Of the weighted, column-scaled reduced Jacobian.
    iterations : int
    cost : float
        Half the weighted sum of squared residuals.
    """

    success: bool
    message: str
    eps: np.ndarray
    eps_dot: np.ndarray
    covariance: np.ndarray
    residual_rms: float
    condition_number: float
    iterations: int
    cost: float
    timings_s: dict = field(default_factory=dict)

    @property
    def std(self) -> np.ndarray:
        """Predicted standard deviations of ``eps_dot`` (m, rad)."""
        return np.sqrt(np.diag(self.covariance))


def _failure(reduction: Reduction, message: str) -> IdentificationResult:
    p = len(reduction.kept)
    nan = np.full(p, np.nan)
    return IdentificationResult(False, message, np.full(reduction.M.shape[1], np.nan), nan, np.full((p, p), np.nan),
                                np.nan, np.inf, 0, np.nan)


def _check_inputs(robot: Robot, q, points, sigma, reduction: Reduction):
    q = robot.check_q(q, "q")
    points = np.asarray(points, dtype=float)
    if q.ndim != 2:
        raise ValueError(f"q: expected shape (m, {robot.n}), got {q.shape}")
    if points.shape != (q.shape[0], 3):
        raise ValueError(f"points: expected shape ({q.shape[0]}, 3) to match q, got {points.shape}")
    if not np.all(np.isfinite(points)):
        raise ValueError("points: contains NaN or inf")
    sigma = np.broadcast_to(np.asarray(sigma, dtype=float), points.shape)
    if not np.all(np.isfinite(sigma)) or np.any(sigma <= 0):
        raise ValueError("sigma: measurement standard deviations must be positive and finite (m)")
    if reduction.M.shape[1] != robot.n_errors:
        raise ValueError(f"reduction: built for {reduction.M.shape[1]} errors, robot has {robot.n_errors}")
    return q, points, sigma


def _weighted_solve(G, r, w):
    """Solve ``min ||sqrt(w) (G x - r)||`` by SVD of the column-scaled system; returns x, cov, cond, rank_ok."""
    Gw = G * w[:, None]
    rw = r * w
    scale = np.linalg.norm(Gw, axis=0)
    scale[scale == 0] = 1.0
    U, s, Vt = np.linalg.svd(Gw / scale, full_matrices=False)
    cond = s[0] / s[-1] if s[-1] > 0 else np.inf
    rank_ok = s[-1] > s[0] * max(Gw.shape) * np.finfo(float).eps * 10
    if not rank_ok:
        return None, None, cond, False
    x = (Vt.T @ ((U.T @ rw) / s)) / scale
    Vs = Vt.T / s
    cov = (Vs @ Vs.T) / np.outer(scale, scale)
    return x, cov, cond, True


def identify_linear(robot: Robot, q, points, reduction: Reduction, sigma=1.0, eps0=None,
                    form="linear") -> IdentificationResult:
    """Linear least squares of Eq. 14 on the reduced Jacobian ``G_e`` (one step from the nominal model).

    Parameters
    ----------
    robot : Robot
    q : ndarray (m, n)
        Joint readings (rad).
    points : ndarray (m, 3)
        Measured end-effector points in the base frame (m).
    reduction : Reduction
        Which errors are estimated (e.g. :func:`closed_form_reduction`).
    sigma : float or ndarray broadcastable to (m, 3)
        Measurement standard deviation per coordinate (m); sets weights and the covariance scale.
    eps0 : ndarray, optional
        Linearisation point (default zero: the thesis's ``dX = X_real - X_ideal``, Eq. 11).
    form : {"linear", "exact"}
        Model whose Jacobian and prediction are used at ``eps0``.
    """
    t0 = time.perf_counter()
    q, points, sigma = _check_inputs(robot, q, points, sigma, reduction)
    p = len(reduction.kept)
    if 3 * q.shape[0] < p:
        return _failure(reduction, f"{q.shape[0]} poses give {3 * q.shape[0]} equations for {p} unknowns; "
                                   f"need at least {int(np.ceil(p / 3))} poses")
    eps0 = np.zeros(robot.n_errors) if eps0 is None else np.asarray(eps0, dtype=float)
    dX = (points - ee_position(robot, q, eps0, form)).ravel()  # Eq. 11, stacked as Eq. 13
    G = identification_jacobian(robot, q, eps0, form).reshape(-1, robot.n_errors)[:, reduction.kept]
    w = 1.0 / sigma.ravel()
    x, cov, cond, ok = _weighted_solve(G, dX, w)
    if not ok:
        return _failure(reduction, f"reduced Jacobian is rank deficient (condition number {cond:.3g}): the poses do "
                                   "not excite every identifiable error")
    eps = eps0.copy()
    eps[reduction.kept] += x
    res = dX - G @ x
    cost = 0.5 * float(np.sum((res * w) ** 2))
    return IdentificationResult(True, "linear least squares (Eq. 14)", eps, eps[reduction.kept], cov,
                                float(np.sqrt(np.mean(res**2))), float(cond), 1, cost,
                                {"identification": time.perf_counter() - t0})


def identify_iterative(robot: Robot, q, points, reduction: Reduction, sigma=1.0, eps0=None, form="exact",
                       max_iter=50, tol=1e-12) -> IdentificationResult:
    """Levenberg-Marquardt on the exact (or linearised) error model, estimating the reduced errors.

    Converged when the step is below ``tol`` (relative to the parameters' scale) or the cost stops falling.
    Parameters as :func:`identify_linear`.
    """
    t0 = time.perf_counter()
    q, points, sigma = _check_inputs(robot, q, points, sigma, reduction)
    p = len(reduction.kept)
    if 3 * q.shape[0] < p:
        return _failure(reduction, f"{q.shape[0]} poses give {3 * q.shape[0]} equations for {p} unknowns; "
                                   f"need at least {int(np.ceil(p / 3))} poses")
    w = 1.0 / sigma.ravel()
    eps = np.zeros(robot.n_errors) if eps0 is None else np.asarray(eps0, dtype=float).copy()

    def residual(e):
        return (points - ee_position(robot, q, e, form)).ravel()

    r = residual(eps)
    cost = 0.5 * float(np.sum((r * w) ** 2))
    lam = 1e-6
    converged, it = False, 0
    while it < max_iter:
        it += 1
        G = identification_jacobian(robot, q, eps, form).reshape(-1, robot.n_errors)[:, reduction.kept]
        Gw = G * w[:, None]
        scale = np.linalg.norm(Gw, axis=0)
        scale[scale == 0] = 1.0
        A = (Gw / scale).T @ (Gw / scale)
        g = (Gw / scale).T @ (r * w)
        if np.linalg.cond(A) > 1e15:
            return _failure(reduction, "reduced Jacobian is rank deficient: the poses do not excite every "
                                       "identifiable error")
        while True:
            step = np.linalg.solve(A + lam * np.diag(np.diag(A)), g) / scale
            trial = eps.copy()
            trial[reduction.kept] += step
            r_new = residual(trial)
            cost_new = 0.5 * float(np.sum((r_new * w) ** 2))
            if cost_new <= cost or lam > 1e10:
                break
            lam *= 10.0
        small_step = np.max(np.abs(step * scale)) < tol * max(1.0, np.sqrt(2 * cost_new))
        stalled = cost - cost_new <= 1e-15 * max(cost, 1e-300)
        if cost_new <= cost:
            eps, r, cost = trial, r_new, cost_new
            lam = max(lam / 10.0, 1e-12)
        if small_step or stalled:
            converged = True
            break
    G = identification_jacobian(robot, q, eps, form).reshape(-1, robot.n_errors)[:, reduction.kept]
    _, cov, cond, ok = _weighted_solve(G, r, w)
    if not ok:
        return _failure(reduction, "reduced Jacobian is rank deficient at the solution")
    msg = f"Levenberg-Marquardt on the {form} model: " + ("converged" if converged else
                                                          f"stopped after {max_iter} iterations without converging")
    return IdentificationResult(converged, msg, eps, eps[reduction.kept], cov, float(np.sqrt(np.mean(r**2))),
                                float(cond), it, cost, {"identification": time.perf_counter() - t0})
