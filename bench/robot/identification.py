"""Identification of the generalized errors from measured end-effector points (thesis Eq. 12-14, §4.4).

Estimated: the reduced, identifiable errors ``eps_dot`` (the kept entries of a :class:`Reduction`).
Fixed: the nominal DH parameters and the eliminated errors (zero). Measurements: end-effector points ``p_base``
(m) at joint readings ``q`` (rad), with per-axis standard deviation ``sigma`` (m) giving the weights.

* :func:`identify_linear` - one weighted least-squares solve of ``dX_t = G_t eps_dot`` (Eq. 13-14 with ``G_e``),
  the thesis's method; exact when the data come from the linearised model.
* :func:`identify_iterative` - Levenberg-Marquardt (``scipy.optimize.least_squares``, MINPACK) on the exact model.

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
import scipy.optimize
import scipy.stats

from bench.robot.identifiability import Reduction
from bench.robot.jacobian import identification_jacobian
from bench.robot.kinematics import ee_position
from bench.robot.model import Robot

#: Reduced chi-square ``chi2 / dof`` above which an identification is refused (residual RMS > 100 sigma).
CHI2_FAIL = 1e4
#: least_squares' ``gtol`` in :func:`identify_iterative`: largest cosine between the residual and a Jacobian column.
GTOL = 1e-10
#: least_squares' ``x_scale`` in :func:`identify_iterative` (m, rad): the errors' order of magnitude. MINPACK's first
#: trust region has radius 100 in ``x / x_scale`` (0.1 m or rad from a zero start); with ``x_scale="jac"`` it is 100
#: sigma of weighted residual, and growing it from there took twice the iterations (11 Jacobians instead of 5).
X_SCALE = 1e-3
#: least_squares' stopping tests by ``status``.
LSQ_STATUS = {2: "cost change below ftol", 3: "step below xtol", 4: "cost change below ftol and step below xtol"}


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


def _lsq_outcome(sol, cost0: float, tol: float) -> tuple:
    """``(converged, message)`` from a ``scipy.optimize.least_squares`` result and the cost at its start.

    The gradient test (status 1) is convergence. The cost-change and step tests (status 2-4) are convergence after a
    step lowered the cost; without one they only say that the damping shrank every step to nothing, and the run
    converged only if the start is already a minimum: the Gauss-Newton step there would lower the cost by at most
    ``tol`` of it. Otherwise no step was found downhill (e.g. a Jacobian that does not fit the model).
    """
    if sol.status == 1:
        return True, f"converged (first-order optimality, gtol {GTOL:g})"
    if sol.status in (2, 3, 4):
        if sol.cost < cost0:
            return True, f"converged ({LSQ_STATUS[sol.status]})"
        Q, _ = np.linalg.qr(sol.jac)
        gain = 0.5 * float(np.sum((Q.T @ sol.fun) ** 2)) / max(sol.cost, np.finfo(float).tiny)
        if gain <= tol:
            return True, f"converged: the start is a minimum (a Gauss-Newton step would lower the cost by {gain:.1e})"
        return False, (f"not converged: no step lowered the cost from the start ({LSQ_STATUS[sol.status]} after "
                       f"{sol.nfev} evaluations), though a Gauss-Newton step would lower it by {gain:.1e} of it: "
                       "a Jacobian that does not fit the model?")
    if sol.status == 0:
        return False, f"not converged: stopped after {sol.nfev} evaluations of the model (max_nfev)"
    return False, f"least_squares failed (status {sol.status}): {sol.message}"


def identify_iterative(robot: Robot, q, points, reduction: Reduction, sigma=1.0, eps0=None, form="exact",
                       max_nfev=100, tol=1e-12) -> IdentificationResult:
    """Levenberg-Marquardt (``scipy.optimize.least_squares``, MINPACK) on the exact (or linearised) error model,
    estimating the reduced errors with the analytic Jacobian.

    ``tol`` is least_squares' ``xtol`` and ``ftol`` (step and cost change, relative), :data:`GTOL` its ``gtol``;
    at most ``max_nfev`` evaluations of the model. ``success`` and the message follow least_squares' status
    (:func:`_lsq_outcome`). ``iterations`` counts Jacobian evaluations. Other parameters as :func:`identify_linear`.
    """
    t0 = time.perf_counter()
    q, points, sigma = _check_inputs(robot, q, points, sigma, reduction)
    p = len(reduction.kept)
    if 3 * q.shape[0] < p:
        return _failure(reduction, f"{q.shape[0]} poses give {3 * q.shape[0]} equations for {p} unknowns; "
                                   f"need at least {int(np.ceil(p / 3))} poses")
    w = 1.0 / sigma.ravel()
    base = np.zeros(robot.n_errors) if eps0 is None else np.asarray(eps0, dtype=float)
    kept, target, start = reduction.kept, points.ravel() * w, {}

    def full(x):
        e = base.copy()
        e[kept] = x
        return e

    def fun(x):  # weighted residuals, model minus measurement
        f = ee_position(robot, q, full(x), form).ravel() * w - target
        start.setdefault("cost", 0.5 * float(f @ f))  # the first evaluation is at the start
        return f

    def jac(x):
        if x is x0 or np.array_equal(x, x0):
            return J0
        return identification_jacobian(robot, q, full(x), form).reshape(-1, robot.n_errors)[:, kept] * w[:, None]

    x0 = base[kept]
    J0 = identification_jacobian(robot, q, base, form).reshape(-1, robot.n_errors)[:, kept] * w[:, None]
    Js = J0 / np.linalg.norm(J0, axis=0).clip(min=1e-300)
    if np.linalg.cond(Js.T @ Js) > 1e15:
        return _failure(reduction, "reduced Jacobian is rank deficient: the poses do not excite every "
                                   "identifiable error")
    sol = scipy.optimize.least_squares(fun, x0, jac=jac, method="lm", x_scale=X_SCALE, xtol=tol, ftol=tol, gtol=GTOL,
                                       max_nfev=max_nfev)
    r = -sol.fun / w
    _, cov, cond, ok = _weighted_solve(sol.jac / w[:, None], r, w)
    if not ok:
        return _failure(reduction, "reduced Jacobian is rank deficient at the solution")
    converged, msg = _lsq_outcome(sol, start["cost"], tol)
    eps = full(sol.x)
    out = IdentificationResult(converged, f"Levenberg-Marquardt (least_squares) on the {form} model: {msg}", eps,
                               eps[kept], cov, float(np.sqrt(np.mean(r**2))), float(cond), int(sol.njev),
                               float(sol.cost), {"identification": time.perf_counter() - t0})
    return _checked(out, reduction, r.size, points, robot)
