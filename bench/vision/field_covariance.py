"""The joint bundle's covariance with each view's keypoint error field, measured on its own residuals (issue 13).

The joint bundle (:mod:`bench.vision.joint_bundle`) weighs every keypoint as independent pixel noise, and its
first-order covariance ``s^2 S^-1`` says so. Real keypoints of one view err together as well: a smooth displacement
over the image that moves all of them (the foreshortened texture, the demosaicing, the lens model's misfit - measured
against the truth in docs/bounds.md, "The field to cubic order, in each view's own modes"). The estimator does not
model it, so its error has the *sandwich* covariance of a least-squares fit under misspecified noise::

    C = S^-1 [ s_w^2 S_pix + s^4 P + sum_c delta_d(c) g_c g_c^T ] S^-1

with ``S = S_pix + s^2 P`` the reduced normal matrix the bundle solved with (pixels, then the priors' information
``P`` weighed at its pixel noise ``s``), ``s_w`` the white part of the keypoints' noise, and for every view ``v``,
image axis and field mode ``k`` of degree ``d`` the column ``b_c`` - the mode's displacement ``Q_k`` at the view's
keypoints (:func:`~bench.vision.keypoint_field.field_modes`: orthonormal in mean square over them) - whose reduced
gradient is ``g_c``; each mode's amplitude is independent with variance ``delta_d``, as in the bound.

Nothing here reads the truth: ``s_w`` and the ``delta_d`` are the method of moments on the solution's residuals
``r``. The residual-maker ``R`` of the weighted fit is symmetric, so a mode's residual amplitude
``a_c = b_c^T r / N_v`` has ``E[a_c^2] = (s_w^2 |R b_c|^2 + sum_c' delta_d(c') (b_c^T R b_c')^2 + s^4 G_c^T P G_c)
/ N_v^2`` (the last the priors' own scatter: the readings' noise, ``G_c = S^-1 g_c``): what the
fit absorbed of every view's field (a locate view's offset moves the shared base, a survey view's its joints and the
points) is accounted for, not assumed away. Pooled by degree, with the residuals' total power
``E[|r|^2] = s_w^2 tr(R^2) + s^2 (T1 - T2) + sum_c delta_d(c) |R b_c|^2`` (``T_k = tr((S^-1 s^2 P)^k)``), that is
``order + 2`` linear equations in ``order + 2`` non-negative unknowns, solved by non-negative least squares with each
equation weighed by its scatter (:func:`_weighted_moments`). Checked by Monte Carlo against drawn fields
(tests/vision/test_field_covariance.py): the moments unbiased, the covariance the estimates' scatter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.optimize
from scipy.linalg import solve_triangular
from scipy.sparse import csc_matrix

from bench.vision.bundle import SIGMA_FLOOR_PX, Elimination
from bench.vision.keypoint_field import FIELD_DEGREES, field_basis, field_degrees, field_terms, monomial_modes

#: the columns of field modes whose responses are computed at once (memory: N x 2 x this)
CHUNK = 64


@dataclass(frozen=True)
class FieldCovariance:
    """Outcome of :func:`field_covariance`.

    ``covariance`` (n, n) the estimate's covariance with the field (the white ``s^2 S^-1`` when no view resolves
    it, ``success`` False); ``sigma_white_px`` the keypoints' white noise ``s_w`` (px per axis); ``degree_px``
    (order + 1,) each degree's mode standard deviation ``sqrt(delta_d)`` (px: a mode's RMS displacement over a view's
    keypoints); ``views`` the views that resolve the field's modes; ``white`` (n, n) the bundle's own covariance
    ``s^2 S^-1`` beside it.
    """

    success: bool
    message: str
    covariance: np.ndarray
    white: np.ndarray
    sigma_white_px: float
    degree_px: np.ndarray
    views: int

    def report(self) -> dict:
        """The field's figures for ``locate.json`` (px)."""
        out = {"success": self.success, "sigma_white_px": self.sigma_white_px, "views": self.views}
        out.update({f"{name}_px": float(sd) for name, sd in zip(FIELD_DEGREES, self.degree_px, strict=False)})
        return out


def _columns(view, uv, keep, size, order: int, min_points: int) -> tuple:
    """The field modes' columns as a sparse ``(2 N, c)`` matrix over the flattened residuals (u, v of observation
    ``i`` at rows ``2 i``, ``2 i + 1``), each column's degree (c,) and its view's kept count N_v (c,), and the
    number of views."""
    n, deg = field_terms(order), field_degrees(order)
    rows, cols, vals, degree, count = [], [], [], [], []
    views = 0
    for v in np.unique(view[keep]):
        idx = np.flatnonzero(keep & (view == v))
        if len(idx) < min_points:
            continue
        X = field_basis(uv[idx], size, order)
        try:
            R = monomial_modes(X, order)
        except ValueError:  # keypoints that do not resolve the modes: the view's field is not modelled
            continue
        Q = solve_triangular(R, X.T, trans="T", lower=False).T  # X R^-1: (N_v, n), Q^T Q / N_v = I
        views += 1
        for axis in (0, 1):
            for k in range(n):
                c = len(degree)
                rows.append(2 * idx + axis)
                cols.append(np.full(len(idx), c))
                vals.append(Q[:, k])
                degree.append(deg[k])
                count.append(len(idx))
    if not degree:
        return None, np.zeros(0, int), np.zeros(0), 0
    shape = (2 * len(view), len(degree))
    Bc = csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=shape)
    return Bc, np.array(degree), np.array(count, float), views


def _weighted_moments(A, y, per_mode, prior_a2, degree, tr_R2: float, prior_power: float,
                      rounds: int = 4) -> np.ndarray:
    """The non-negative ``[s_w^2, delta_0, ...]`` of the moment equations ``A z = y``, each row weighed by its
    scatter at the current estimate (a sum of squared Gaussian amplitudes: variance ``2 sum E[a_c^2]^2``; the total
    power's ``2 E[|r|^2]^2 / tr(R^2)``), from white noise at the total power: the degree rows pool a few dozen
    amplitudes, the total power thousands, and an equal weighing lets a degree's chance excess take the white
    noise's share."""
    z = np.zeros(A.shape[1])
    z[0] = max(y[-1], 0.0) / A[-1, 0]
    for _ in range(rounds):
        e_mode = per_mode @ z + prior_a2
        sd = np.array([np.sqrt(2.0 * np.sum(e_mode[degree == d] ** 2)) for d in range(A.shape[0] - 1)]
                      + [np.sqrt(2.0 / tr_R2) * (A[-1] @ z + prior_power)])
        sd = np.maximum(sd, 1e-300)
        z, _ = scipy.optimize.nnls(A / sd[:, None], y / sd)
    return z


def field_covariance(problem, sol, info0, view, uv, size, order: int = 3, min_points: int | None = None
                     ) -> FieldCovariance:
    """The covariance of a :func:`bench.vision.bundle.solve` solution with each view's keypoint error field
    (module docstring), the field measured on the solution's residuals.

    Parameters
    ----------
    problem
        The solved problem (``point``, ``linearise``; :mod:`bench.vision.bundle`).
    sol : BundleSolution
        Its successful solution.
    info0 : ndarray (n, n)
        The priors' information the solve was given (in the parameters' units).
    view : ndarray (N,) int
        Each observation's view.
    uv : ndarray (N, 2)
        Each observation's pixel as measured (px): where the view's field is evaluated.
    size : (w, h)
        The image size (px).
    order : int
        The field's order (0 offset, 1 affine, 2 quadratic, 3 cubic).
    min_points : int, optional
        Views with fewer kept observations have no field modelled (default ``max(20, 3 n)``, ``n`` the modes per
        axis).
    """
    n_modes = field_terms(order)
    min_points = max(20, 3 * n_modes) if min_points is None else int(min_points)
    view, uv = np.asarray(view, int), np.asarray(uv, float)
    point, keep = np.asarray(problem.point, int), np.asarray(sol.keep, bool)
    s = max(float(sol.sigma_px), SIGMA_FLOOR_PX)
    n = len(sol.theta)
    r, J, J_pt, _ = problem.linearise(sol.theta, sol.X)
    el = Elimination(point, J, J_pt, len(sol.X), info0 * s**2, keep)
    Sinv = np.linalg.inv(el.S)
    white = s**2 * Sinv
    white = 0.5 * (white + white.T)
    nan = np.full(order + 1, np.nan)
    Bc, degree, count, views = _columns(view, uv, keep, size, order, min_points)
    if Bc is None:
        return FieldCovariance(False, f"no view has {min_points} keypoints resolving the field's modes: white",
                               white, white, s, nan, 0)
    N, c_all = len(view), len(degree)
    G = np.empty((n, c_all))  # each mode's response of the estimate, d_theta = -S^-1 g_c
    M = np.empty((c_all, c_all))  # b_c^T R b_c'
    Rb2 = np.empty(c_all)  # |R b_c|^2 (R is symmetric, not idempotent: the priors hold some directions)
    for lo in range(0, c_all, CHUNK):
        hi = min(lo + CHUNK, c_all)
        b = Bc[:, lo:hi].toarray().reshape(N, 2, hi - lo)
        d_theta, res = el.response(b)
        G[:, lo:hi] = d_theta
        M[:, lo:hi] = Bc.T @ res.reshape(2 * N, hi - lo)
        Rb2[lo:hi] = np.sum(res**2, axis=(0, 1))
    M = 0.5 * (M + M.T)
    rk = (r * keep[:, None]).reshape(-1)
    a2 = (Bc.T @ rk / count) ** 2  # each mode's residual amplitude, squared
    # what the priors' own scatter leaves in the residuals (the readings' noise, the lab's errors; known, not fitted):
    # r = R e - J H^-1 P_s u, u ~ N(0, P^-1), P_s = s^2 P the priors in pixel units
    Pp = info0 * s**2
    SP = Sinv @ Pp
    T1, T2 = float(np.trace(SP)), float(np.sum(SP * SP.T))
    prior_a2 = s**2 * np.einsum("ic,ij,jc->c", G, Pp, G) / count**2  # (b_c^T J H^-1 P_s u)^2: s^4 G^T P G
    kept_points = np.unique(point[keep]).size
    # E|r|^2 = s_w^2 tr(R^2) + s^2 (T1 - T2), tr(R^2) = 2 N_kept - (n + 3 M) + T2 (the points free, the rest held by
    # their priors as much as T2 says)
    tr_R2 = 2 * int(keep.sum()) - (n + 3 * kept_points) + T2
    if tr_R2 < 1.0:  # as many parameters as pixels: no residual to measure a noise on
        return FieldCovariance(False, f"{tr_R2:.3g} residual degrees of freedom: white", white, white, s, nan, views)
    # the moments: a row per degree (pooled over views, axes and modes), then the residuals' total power; per mode
    # first (E[a_c^2] = per_mode @ [s_w^2, delta_0, ...] + prior_a2), to weigh each row by its scatter
    per_mode = np.zeros((c_all, order + 2))
    per_mode[:, 0] = Rb2 / count**2
    for e in range(order + 1):
        per_mode[:, 1 + e] = np.sum(M[:, degree == e] ** 2, axis=1) / count**2
    A = np.zeros((order + 2, order + 2))
    y = np.zeros(order + 2)
    for d in range(order + 1):
        A[d] = per_mode[degree == d].sum(axis=0)
        y[d] = a2[degree == d].sum() - prior_a2[degree == d].sum()
    y[-1] = float(rk @ rk) - s**2 * (T1 - T2)
    A[-1, 0] = tr_R2
    for e in range(order + 1):
        A[-1, 1 + e] = Rb2[degree == e].sum()
    z = _weighted_moments(A, y, per_mode, prior_a2, degree, tr_R2, s**2 * (T1 - T2))
    s_w2, delta = z[0], z[1:]
    # the white part (pixels at s_w, the priors at their own covariance, both weighed as the solve did), then the
    # field's: each mode's response d_theta = -S^-1 g_c, times its variance
    C = Sinv @ (s_w2 * el.S + (s**2 - s_w2) * s**2 * info0) @ Sinv + (G * delta[degree]) @ G.T
    C = 0.5 * (C + C.T)
    sd = np.sqrt(delta)
    return FieldCovariance(True, f"field of order {order} over {views} views: white {np.sqrt(s_w2):.3g} px, modes "
                           + ", ".join(f"{x:.3g}" for x in sd) + " px", C, white, float(np.sqrt(s_w2)), sd, views)
