"""The bundle solver shared by the localisations' maximum-likelihood estimators (issue 11).

A problem has a parameter vector ``theta (n,)`` (poses, joints, intrinsics, ... under a Gaussian prior) and ``M``
3-D points ``X (M, 3)`` seen in ``N`` observations (``problem.point (N,)`` says which point each is). It supplies

* ``problem.residuals(theta, X) -> (N, 2)`` - measured minus predicted pixels;
* ``problem.linearise(theta, X) -> (r (N, 2), J (N, 2, n), J_pt (N, 2, 3), z_min)`` - the residuals, their
  derivatives by the parameters and by each observation's own point, and the smallest depth of a point in a camera.

:func:`solve` minimises ``sum |r|^2 / s^2 + (theta - mean)^T info (theta - mean)`` by Gauss-Newton with the points
eliminated point by point (Schur complement), a backtracking line search, and rounds that re-estimate the pixel noise
``s`` and gate the observations whose residual exceeds ``gate`` x its robust value (keypoints' errors have heavy
tails). It returns a :class:`BundleSolution` instead of raising when the system is singular or a point falls behind a
camera.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix

#: rounds :func:`solve` may add while the noise estimate still halves (exact data)
EXTRA_ROUNDS = 4
#: the smallest pixel noise (px) the final covariance weighs the priors with, and below which residuals are an exact
#: fit (no real image is this clean): on exact data the directions only the priors hold - a gauge - stay conditioned
SIGMA_FLOOR_PX = 1e-3
#: relative singular-value cut-off of the Gauss-Newton step
RCOND = 1e-12
#: the robust losses' scale, in units of the pixel noise (Huber's 1.345: 95 % efficiency under Gaussian noise)
LOSS_SCALE = 1.345


@dataclass(frozen=True)
class BundleSolution:
    """Outcome of :func:`solve`.

    ``theta`` (n,) and ``X`` (M, 3) the estimates (the start when ``success`` is False); ``keep`` (N,) bool the
    observations the gate kept; ``sigma_px`` the pixel noise the kept residuals give; ``S`` (n, n) the reduced
    normal matrix at the solution in units of the pixel residuals (its inverse times ``sigma_px^2`` is the
    parameters' covariance; NaN on failure); ``iterations`` Gauss-Newton steps taken; ``converged`` whether the last
    round ended on a convergence test rather than on its iteration limit.
    """

    success: bool
    message: str
    theta: np.ndarray
    X: np.ndarray
    keep: np.ndarray
    sigma_px: float
    S: np.ndarray
    iterations: int
    converged: bool = False

    def covariance(self) -> np.ndarray:
        """First-order covariance ``sigma_px^2 S^-1`` (n, n) of ``theta``, the points marginalised."""
        cov = self.sigma_px**2 * np.linalg.inv(self.S)
        return 0.5 * (cov + cov.T)


def normal_equations(point, r, J, J_pt, M: int, prior_info, prior_res, keep=None):
    """The reduced system (points eliminated): ``S (n, n)``, gradient ``g (n,)`` and the points' back-substitution.
    Observations outside ``keep`` (N,) bool weigh nothing; a point left with fewer than two is held where it is.
    ``keep`` may be float: each observation's residual and Jacobian are scaled by it (the square root of a weight)."""
    el = Elimination(point, J, J_pt, M, prior_info, keep)
    g_c, g_m = el.gradients(r[..., None])
    g = el.reduced(g_c, g_m)[:, 0] + prior_res

    def points_step(dc):
        return el.points_step(g_m, dc[:, None])[..., 0]

    return el.S, g, points_step


class Elimination:
    """The points of a bundle eliminated point by point (Schur complement) at one linearisation: ``J (N, 2, n)``,
    ``J_pt (N, 2, 3)``, observations weighted by ``keep`` (N,) (bool, or float: the square root of a weight), the
    priors' information ``prior_info (n, n)`` in pixel units. ``S`` (n, n) is the reduced normal matrix; the methods
    act on stacks of right-hand sides ``(..., c)`` at once."""

    def __init__(self, point, J, J_pt, M: int, prior_info, keep=None):
        N, n = J.shape[0], J.shape[2]
        self.w = np.ones(N) if keep is None else np.asarray(keep).astype(float)
        self.point, self.M = np.asarray(point, int), M
        self.J, self.J_pt = J * self.w[:, None, None], J_pt * self.w[:, None, None]
        self.by_point = csr_matrix((np.ones(N), (self.point, np.arange(N))), shape=(M, N))  # sums over each point
        B = (self.by_point @ (np.swapaxes(self.J, 1, 2) @ self.J_pt).reshape(N, 3 * n)).reshape(M, n, 3)
        C = (self.by_point @ (np.swapaxes(self.J_pt, 1, 2) @ self.J_pt).reshape(N, 9)).reshape(M, 3, 3)
        self.B = B
        self.Cinv = np.linalg.inv(C + 1e-9 * np.eye(3))  # regularised: a point gated down to one view stays put
        self.BCinv = B @ self.Cinv
        Jf = self.J.reshape(2 * N, n)
        S = Jf.T @ Jf + prior_info - np.einsum("mik,mjk->ij", self.BCinv, B)
        self.S = 0.5 * (S + S.T)

    def gradients(self, r):
        """The parameters' and the points' gradients ``(n, c)``, ``(M, 3, c)`` of residuals ``r (N, 2, c)``
        (weighted as the observations are)."""
        N, n, c = self.J.shape[0], self.J.shape[2], r.shape[-1]
        rw = r * self.w[:, None, None]
        g_c = self.J.reshape(2 * N, n).T @ rw.reshape(2 * N, c)
        g_m = (self.by_point @ np.einsum("nki,nkc->nic", self.J_pt, rw).reshape(N, 3 * c)).reshape(self.M, 3, c)
        return g_c, g_m

    def reduced(self, g_c, g_m):
        """The reduced gradient ``(n, c)``: the points' part carried onto the parameters."""
        return g_c - np.einsum("mik,mkc->ic", self.BCinv, g_m)

    def points_step(self, g_m, dc):
        """The points' step ``(M, 3, c)`` that goes with a parameter step ``dc (n, c)``."""
        return -np.einsum("mkl,mlc->mkc", self.Cinv, g_m + np.einsum("mik,ic->mkc", self.B, dc))

    def response(self, b):
        """The linear response of the estimate to pixel errors ``b (N, 2, c)`` added to the measurements: the
        parameters' change ``(n, c)`` and the residuals' ``(N, 2, c)`` (``b`` less what the fit absorbs; weighted,
        zero where an observation weighs nothing). With ``R`` the residual-maker of the weighted fit (symmetric),
        the second is ``R b``."""
        g_c, g_m = self.gradients(b)
        d_theta = -np.linalg.solve(self.S, self.reduced(g_c, g_m))
        dX = self.points_step(g_m, d_theta)
        res = (b * self.w[:, None, None] + np.einsum("nki,ic->nkc", self.J, d_theta)
               + np.einsum("nkl,nlc->nkc", self.J_pt, dX[self.point]))
        return d_theta, res


def seen_twice(point, keep, M: int) -> np.ndarray:
    """``keep`` without the observations of points it leaves in one view: such a point is unobserved along its ray
    (the step, the cost and the degrees of freedom then agree on what counts)."""
    seen = np.bincount(point[keep], minlength=M)
    return keep & (seen[point] >= 2)


def robust_sigma(e) -> float:
    """The pixel noise of residual norms ``e`` from their median: median / 1.1774, the Rayleigh median of a 2-D
    Gaussian."""
    return float(np.median(e)) / 1.1774


def _gated(e, keep, point, M: int, gate: float, groups=None) -> np.ndarray:
    """The observations to keep: residual ``e`` (N,) within ``gate`` x the robust sigma (median / 1.1774, the
    Rayleigh median of a 2-D Gaussian) of those kept so far - per group, the larger of the group's (over all its
    observations) and the whole set's, when ``groups`` (N,) is given."""
    s_all = robust_sigma(e[keep])
    if groups is None:
        return seen_twice(point, e <= gate * s_all, M)
    groups = np.asarray(groups, int)
    ok = np.zeros(len(e), bool)
    for g in np.unique(groups):
        sel = groups == g
        ok[sel] = e[sel] <= gate * max(robust_sigma(e[sel]), s_all)
    return seen_twice(point, ok, M)


def _scaled_step(S, g) -> tuple:
    """The Gauss-Newton step ``-S^-1 g`` by least squares on the system scaled by ``sqrt(diag S)`` (a direction only
    a vanishing prior holds - a gauge, on exact data - stays where it is instead of amplifying rounding): ``(step,
    scaled)``, ``scaled`` the step in units of ``1 / sqrt(diag S)`` (there a parameter's sigma is ~ the pixel noise)."""
    diag = np.diag(S)
    d = np.sqrt(np.maximum(diag, RCOND * diag.max()))  # a direction nothing holds stays where it is
    scaled = -np.linalg.lstsq(S / np.outer(d, d), g / d, rcond=RCOND)[0]
    return scaled / d, scaled


def robust_weights(e, s_px: float, loss: str | None, c: float = LOSS_SCALE) -> np.ndarray | None:
    """IRLS weights ``w = rho'(u) / u`` (N,) of residual norms ``e`` at ``u = e / s_px``: None (unweighted) for
    ``loss=None``; Huber's (1 within ``c``, ``c / u`` beyond)."""
    if loss is None:
        return None
    if loss != "huber":
        raise ValueError(f"loss: expected None or 'huber', got {loss!r}")
    u = np.asarray(e, float) / max(s_px, SIGMA_FLOOR_PX)
    return np.where(u <= c, 1.0, c / np.maximum(u, 1e-300))


def _dof(point, keep, wt, M: int, dof_offset: int) -> float:
    """The noise estimate's degrees of freedom: 2 per kept observation and -3 per point observed, each counted by
    its share ``wt`` (a point by the mean share of its kept observations: two points that are one keypoint in every
    view count as one), less ``dof_offset``; at least 1. With every share 1: ``2 N - 3 M - dof_offset``."""
    n_obs = np.bincount(point[keep], minlength=M)
    share = np.bincount(point[keep], weights=wt[keep], minlength=M)
    seen = n_obs > 0
    return max(2 * float(wt[keep].sum()) - 3 * float(np.sum(share[seen] / n_obs[seen])) - dof_offset, 1.0)


def _cost(problem, theta, X, keep, prior_info, mean, w=None) -> float:
    """Sum of the kept observations' squared pixel residuals (weighted by ``w`` (N,), IRLS) plus the priors' (in
    the same units)."""
    r = problem.residuals(theta, X)
    r2 = np.sum(r**2, axis=1) if w is None else w * np.sum(r**2, axis=1)
    d = theta - mean
    c = float(np.sum(r2[keep]) + d @ prior_info @ d)
    return c if np.isfinite(c) else np.inf


def solve(problem, theta0, mean, info0, X, sigma_px: float, iterations: int = 10, rounds: int = 3,
          gate: float | None = 3.5, dof_offset: int = 0, gate_groups=None, groups_in_rounds: bool = True,
          step_tol: float | None = None, loss: str | None = None, weights=None) -> BundleSolution:
    """Maximum-likelihood ``theta`` and points (module docstring).

    Parameters
    ----------
    problem
        With ``point``, ``residuals`` and ``linearise`` (module docstring).
    theta0, mean : ndarray (n,)
        The start and the prior's mean.
    info0 : ndarray (n, n)
        The prior's information (inverse covariance, in the parameters' units); zero rows for free parameters.
    X : ndarray (M, 3)
        Starting points; every point must be observed at least twice.
    sigma_px : float
        Starting pixel noise (px), re-estimated from the kept residuals after each round.
    iterations, rounds : int
        Gauss-Newton iterations per round; rounds of re-estimating the noise and the gate (at least; up to
        :data:`EXTRA_ROUNDS` more while the noise estimate halves from one round to the next).
    gate : float or None
        After each round, observations whose residual exceeds ``gate`` x the robust sigma (median residual /
        1.1774, the Rayleigh median of a 2-D Gaussian) weigh nothing in the next; ``None`` keeps every one.
    dof_offset : int
        Parameters the pixels determine besides the points (subtracted from the degrees of freedom of the noise
        estimate).
    gate_groups : ndarray (N,) int, optional
        Gate group by group (e.g. by view), each at ``gate`` x the larger of its own robust sigma and the whole
        set's, and gate the starting residuals too: a start may fit some views far better than others (a view whose
        model is off - a reading error the bundle will correct - then keeps its observations), and gross outliers
        (false matches hundreds of pixels off) do not steer the first round. None: one gate for all, the first
        round keeps every observation.
    groups_in_rounds : bool
        Gate by group after the rounds too (with parameters that can absorb a group's misfit, e.g. each view's
        reading); False: by group at the start only, then one gate for all (a view whose misfit the model cannot
        absorb loses its worst observations).
    step_tol : float, optional
        End a round once a step (taken) is shorter than ``step_tol`` standard deviations of the estimate (its length
        in the metric of the covariance ``s^2 S^-1``). None: iterate until the cost's decrease is at rounding level.
        Gauss-Newton converges only linearly along weakly observed directions (a camera rotation against the
        principal point), so that takes several steps more for changes far below the noise.
    loss : {None, "huber"}
        None: least squares on the kept observations. ``"huber"``: Huber's M-estimate by iteratively re-weighted least
        squares (:func:`robust_weights`, scale :data:`LOSS_SCALE` x the robust pixel noise, median / 1.1774 of the
        kept residuals, at every linearisation): keypoint errors have heavy tails below the gate too.
    weights : ndarray (N,), optional
        Each observation's share of a measurement (0 < w <= 1): its squared residual, its information and its part
        of the noise estimate's sums and degrees of freedom are multiplied by it - e.g. ``worth / k`` for each of ``k``
        observations that are one keypoint (:func:`bench.vision.joint_bundle.detection_weights`). None: 1 each (the
        gate's robust sigma is the residuals' median either way).
    """
    theta, mean, X = np.array(theta0, float), np.asarray(mean, float), np.array(X, float)
    point = np.asarray(problem.point, int)
    wt = np.ones(len(point)) if weights is None else np.asarray(weights, float)
    if wt.shape != (len(point),) or not np.all((wt > 0) & (wt <= 1)):
        raise ValueError(f"weights: expected ({len(point)},) values in (0, 1], got shape {wt.shape}")
    sw = np.sqrt(wt)
    n, M = len(theta), len(X)
    nan = np.full((n, n), np.nan)
    it_total, s_px = 0, float(sigma_px)
    keep = np.ones(len(point), dtype=bool)
    if gate and gate_groups is not None:
        keep = _gated(np.linalg.norm(problem.residuals(theta, X), axis=1), keep, point, M, gate, gate_groups)

    def failed(msg):
        return BundleSolution(False, msg, np.array(theta0, float), np.array(X, float), keep, s_px, nan, it_total)

    k, s_used = 0, np.inf
    # rounds: at least ``rounds``, and more (up to EXTRA_ROUNDS) while the noise estimate still falls by half - the
    # priors weigh s^2 info0 in pixel units, so on near-exact data they would otherwise pull the estimate by s^2
    while k < rounds or (k < rounds + EXTRA_ROUNDS and s_px < 0.5 * s_used):
        k, s_used = k + 1, s_px
        prior_info = info0 * s_px**2  # in units of the pixel residuals' weight
        converged = False
        for _ in range(iterations):
            it_total += 1
            r, J, J_pt, z_min = problem.linearise(theta, X)
            if z_min <= 0:
                return failed("points behind a camera")
            w = None if weights is None else wt  # the shares, times the robust loss's IRLS weights at this point
            if loss is not None:
                e = np.linalg.norm(r, axis=1)
                w = wt * robust_weights(e, robust_sigma(e[keep]), loss)
            S, g, points_step = normal_equations(point, r, J, J_pt, M, prior_info, prior_info @ (theta - mean),
                                                 keep if w is None else keep * np.sqrt(w))
            diag = np.diag(S)
            if not (np.all(np.isfinite(diag)) and diag.max() > 0):
                return failed("singular reduced system")
            dc, _ = _scaled_step(S, g)
            if not np.all(np.isfinite(dc)):
                return failed("singular reduced system")
            # backtracking: the Gauss-Newton step is halved until the cost (pixels kept + priors) decreases - weakly
            # observed directions (intrinsics against a mount) can make a full step overshoot and diverge
            dX, t = points_step(dc), 1.0
            c0 = _cost(problem, theta, X, keep, prior_info, mean, w)
            if -float(g @ dc) <= 1e-12 * c0:
                converged = True
                break  # the quadratic model's decrease is at rounding level: converged
            while t > 1e-4 and not _cost(problem, theta + t * dc, X + t * dX, keep, prior_info, mean, w) <= c0:
                t /= 2
            if t <= 1e-4:
                converged = True
                break  # no descent along the step: at the minimum to numerical precision
            theta, X = theta + t * dc, X + t * dX
            # the step's length in standard deviations of the estimate: dc^T S dc = -g.dc in pixel units
            short = step_tol is not None and -t * t * float(g @ dc) < (step_tol * s_px) ** 2
            if np.abs(t * dc).max() < 1e-12 or short:
                converged = True
                break
        e = np.linalg.norm(problem.residuals(theta, X), axis=1)
        if gate:
            keep = _gated(e, keep, point, M, gate, gate_groups if groups_in_rounds else None)
        s_px = float(np.sqrt(np.sum(wt[keep] * e[keep] ** 2) / _dof(point, keep, wt, M, dof_offset)))
    r, J, J_pt, _ = problem.linearise(theta, X)
    mask = keep if weights is None else keep * sw
    S, _, _ = normal_equations(point, r, J, J_pt, M, info0 * max(s_px, SIGMA_FLOOR_PX) ** 2, np.zeros(n), mask)
    d = np.sqrt(np.abs(np.diag(S)))
    if not (np.all(d > 0) and np.linalg.eigvalsh(S / np.outer(d, d)).min() > RCOND):
        # a parameter neither the pixels nor a prior hold (a degenerate view set): no covariance to report
        return BundleSolution(False, "singular reduced system (a parameter nothing observes)", theta, X, keep, s_px,
                              nan, it_total)
    if not converged:  # out of iterations: converged all the same if the step left is a tiny part of each sigma
        # the Gauss-Newton step left on the last round's objective, in units where a sigma is ~ s_px
        _, step = _scaled_step(*normal_equations(point, r, J, J_pt, M, prior_info, prior_info @ (theta - mean),
                                                 mask)[:2])
        converged = bool(np.abs(step).max() < 1e-3 * s_px) or s_px < SIGMA_FLOOR_PX  # below it: an exact fit
    return BundleSolution(True, "ok" if converged else f"ok; the last round stopped at its {iterations} iterations",
                          theta, X, keep, s_px, S, it_total, converged)
