"""Identification of the generalized errors from measured end-effector points (thesis Eq. 12-14, §4.4).

Estimated: the reduced, identifiable errors ``eps_dot`` (the kept entries of a :class:`Reduction`).
Fixed: the nominal DH parameters and the eliminated errors (zero). Measurements: end-effector points ``p_base``
(m) at joint readings ``q`` (rad), with per-axis standard deviation ``sigma`` (m) giving the weights.

* :func:`identify_linear` - one weighted least-squares solve of ``dX_t = G_t eps_dot`` (Eq. 13-14 with ``G_e``),
  the thesis's method; exact when the data come from the linearised model.
* :func:`identify_iterative` - Levenberg-Marquardt (Gauss-Newton with adaptive damping) on the exact model.

Solvers return an :class:`IdentificationResult` and never raise on non-convergence or rank deficiency.

Consistency with the stated noise (:func:`chi2_check`): with ``sigma`` the measurements' standard deviation, the
weighted residual sum ``chi2 = sum (r / sigma)^2`` of a correct model follows a chi-square distribution with
``dof = 3 m - p`` degrees of freedom. The result reports ``chi2_per_dof`` (1 on average). Outside the central 99.8 %
of that distribution the message carries a WARNING (above: model error, e.g. the linearised model on exact data, or
``sigma`` too small - the covariance is then optimistic; below: ``sigma`` overstated or noise-free data - the
covariance is pessimistic). Above :data:`CHI2_FAIL` (residuals 100 times ``sigma``) the fit explains nothing at the
stated noise - points in mm where metres belong, the wrong robot, another frame - and the result is
``success=False`` with the estimate withheld (NaN).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.stats

from bench.robot.identifiability import Reduction
from bench.robot.jacobian import identification_jacobian
from bench.robot.kinematics import ee_position
from bench.robot.model import Robot

#: Reduced chi-square ``chi2 / dof`` above which an identification is refused (residual RMS > 100 sigma).
CHI2_FAIL = 1e4


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
    chi2_per_dof : float
        ``2 cost / (3 m - p)``: 1 on average when the model fits to the stated ``sigma`` (see :func:`chi2_check`);
        NaN without redundancy.
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
    chi2_per_dof: float = float("nan")

    @property
    def std(self) -> np.ndarray:
        """Predicted standard deviations of ``eps_dot`` (m, rad)."""
        return np.sqrt(np.diag(self.covariance))


def _failure(reduction: Reduction, message: str) -> IdentificationResult:
    p = len(reduction.kept)
    nan = np.full(p, np.nan)
    return IdentificationResult(False, message, np.full(reduction.M.shape[1], np.nan), nan, np.full((p, p), np.nan),
                                np.nan, np.inf, 0, np.nan)


def chi2_check(cost: float, n_rows: int, n_params: int, points=None, robot: Robot | None = None) -> tuple:
    """Consistency of a weighted least-squares fit with its stated noise (module docstring).

    Returns ``(level, chi2_per_dof, note)`` with ``level`` one of ``"ok"``, ``"warn"`` (outside the central 99.8 % of
    the chi-square distribution with ``n_rows - n_params`` dof) and ``"fail"`` (``chi2_per_dof > CHI2_FAIL``);
    ``note`` is the sentence for the result message. With ``points`` and ``robot`` a failure also says when the
    points lie beyond ten times the arm's reach (mm given where metres belong?).
    """
    dof = n_rows - n_params
    if dof <= 0 or not np.isfinite(cost):
        return "ok", float("nan"), ""
    red = 2.0 * cost / dof
    hi = scipy.stats.chi2.ppf(0.999, dof) / dof
    lo = scipy.stats.chi2.ppf(0.001, dof) / dof
    if red > CHI2_FAIL:
        note = (f"residuals inconsistent with sigma: chi2/dof = {red:.3g} (residual RMS {np.sqrt(red):.3g} sigma; "
                f"refused above {CHI2_FAIL:.0e})")
        if points is not None and robot is not None:
            reach = float(np.sum(np.abs(robot.a)) + np.sum(np.abs(robot.d)))
            far = float(np.median(np.linalg.norm(points, axis=-1)))
            if far > 10 * reach:
                note += f"; the points lie {far:.3g} m from the base, the arm reaches {reach:.3g} m: mm given as m?"
            else:
                note += ": wrong units of sigma, wrong robot or points in another frame?"
        return "fail", red, note
    if red > hi:
        return "warn", red, (f"WARNING chi2/dof = {red:.3g} > {hi:.3g} (99.9 %): residuals exceed sigma (model error "
                             "or sigma too small); the covariance is optimistic")
    if red < lo:
        return "warn", red, (f"WARNING chi2/dof = {red:.3g} < {lo:.3g} (0.1 %): residuals below sigma (sigma "
                             "overstated, or noise-free data); the covariance is pessimistic")
    return "ok", red, ""


def _checked(res: IdentificationResult, reduction: Reduction, n_rows: int, points, robot) -> IdentificationResult:
    """Apply :func:`chi2_check` to a solved result: a failure withholds the estimate, a warning goes in the message."""
    level, red, note = chi2_check(res.cost, n_rows, len(reduction.kept), points, robot)
    if level == "fail":
        out = _failure(reduction, f"{note} ({res.message})")
        out.chi2_per_dof, out.cost, out.residual_rms, out.iterations = red, res.cost, res.residual_rms, res.iterations
        out.timings_s = res.timings_s
        return out
    res.chi2_per_dof = red
    if note:
        res.message += "; " + note
    return res


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
    out = IdentificationResult(True, "linear least squares (Eq. 14)", eps, eps[reduction.kept], cov,
                               float(np.sqrt(np.mean(res**2))), float(cond), 1, cost,
                               {"identification": time.perf_counter() - t0})
    return _checked(out, reduction, dX.size, points, robot)


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
    out = IdentificationResult(converged, msg, eps, eps[reduction.kept], cov, float(np.sqrt(np.mean(r**2))),
                               float(cond), it, cost, {"identification": time.perf_counter() - t0})
    return _checked(out, reduction, r.size, points, robot)
