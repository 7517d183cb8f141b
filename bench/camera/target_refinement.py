"""Camera calibration on the two-plane rig that also estimates how the rig was printed and assembled.

A printed calibration target is not its file: the printer's paper feed spaces the lines unevenly, the paper on its
board bows, a hand-assembled two-plane rig is not exactly square (issue 12 measured 0.28 mm row offsets on a real
printout; ``bench.sim.imaging`` simulates them). A calibration that trusts the nominal rig absorbs those errors into
the intrinsics: on the realistic in-situ datasets the focal length came out 1.45 % off (median of 10 seeds, 3.9 % on
one) and the hand-eye mount 16 mm (docs/realistic_imaging.md). Lavest, Viala & Dhome ("Do we really need an
accurate calibration pattern to achieve a reliable camera calibration?", ECCV 1998) estimate the target together
with the camera from several views.

Free 3-D offsets for every corner are too many for a few views (the out-of-plane ones trade with the focal length:
tried, median 1.45 % -> 0.87 % with one seed much worse). This module estimates the printout's *structure*
(:func:`rig_basis`, 27 parameters for the 7 x 7-square rig): one offset per printed row and column line of each
board (in the board's plane, across the line), one cylindrical bow per board (out of its plane, the profile of
:func:`bench.sim.scenes.rig.bow_z`) and the fold (board B turned about the common edge, linearised), each with a
Gaussian prior of its tolerance. The cost is

    sum |p(K, dist, R_v (X_j + (A theta)_j) + t_v) - uv_vj|^2 / sigma_px^2 + sum_k theta_k^2 / sigma_k^2,

minimised by the Levenberg-Marquardt of :func:`bench.camera.calibration.calibrate_camera` (prior rows
``(sigma_px / sigma_k) theta_k``, px), started from the nominal calibration. The priors also fix the gauge (a
common shift of all lines is a translation of the rig). Object points must name the same physical corner by the same
coordinates in every view (the rig's frame: board A in the plane y = 0, board B in x = 0, z up the fold, as
:func:`bench.sim.scenes.rig.calibration_rig`; a view labelled by the rig's half-turn symmetry must be relabelled
first). Measured on the 10 realistic in-situ datasets' rig views (9 each): median |focal error| 1.45 % -> 0.5 %
(9 of 10 better); on ideal datasets unchanged (0.10 % -> 0.17 %).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from bench.camera.calibration import (
    CalibrationResult,
    _full_dist,
    _levenberg_marquardt,
    _Problem,
    _residual_summary,
    _State,
    calibrate_camera,
    check_views,
)
from bench.geometry.transforms import homogeneous


@dataclass
class _TargetState(_State):
    delta: np.ndarray = None  # (n_theta,) target parameters

    def copy(self):
        return _TargetState(self.fx, self.fy, self.cx, self.cy, self.skew, self.dist.copy(), self.R.copy(),
                            self.t.copy(), self.delta.copy())


class _TargetProblem(_Problem):
    """:class:`_Problem` with the rig's structure ``theta`` (offsets ``A theta``) and its prior rows."""

    def __init__(self, points, ids, image_points, model, k3, fit_skew, prior_weight, A):
        self.points, self.ids, self.w, self.A = points, ids, np.asarray(prior_weight, float), A
        super().__init__([points[i] for i in ids], image_points, model, k3, fit_skew)
        self.n_base = self.n_intr + 6 * self.n_views

    @property
    def n_params(self):
        return self.n_intr + 6 * self.n_views + self.A.shape[1]

    def residuals(self, s: _TargetState, jacobian: bool = False):
        off = (self.A @ s.delta).reshape(-1, 3)
        self.X = [self.points[i] + off[i] for i in self.ids]
        prior = self.w * s.delta
        if not jacobian:
            return np.concatenate([super().residuals(s), prior])
        r, J = super().residuals(s, jacobian=True)
        P = len(self.points)
        Jd = np.zeros((len(r), 3 * P))
        for v, ids in enumerate(self.ids):
            rows = np.arange(2 * self.offsets[v], 2 * self.offsets[v + 1])
            col = self.n_intr + 6 * v
            B = J[rows, col + 3:col + 6].reshape(len(ids), 2, 3)  # d(u, v) / d X_cam (translation columns)
            G = B @ s.R[v]  # d X_cam / d d_j = R_v
            for a in range(3):
                Jd[rows[0::2], 3 * ids + a] = G[:, 0, a]
                Jd[rows[1::2], 3 * ids + a] = G[:, 1, a]
        top = np.hstack([J[:, : self.n_base], Jd @ self.A])
        nt = self.A.shape[1]
        bottom = np.hstack([np.zeros((nt, self.n_base)), np.diag(self.w * np.ones(nt))])
        return np.concatenate([r, prior]), np.vstack([top, bottom])

    def intrinsic_vector(self, s):  # padded: _relative_step treats the target parameters as absolute
        return np.concatenate([super().intrinsic_vector(s), np.zeros(self.A.shape[1])])

    def apply_step(self, s: _TargetState, delta):
        n = super().apply_step(s, delta[: self.n_base])
        n.delta = s.delta + delta[self.n_base:]
        return n


@dataclass
class TargetRefinedCalibration:
    """Outcome of :func:`calibrate_camera_refining_rig`.

    Attributes
    ----------
    calibration : CalibrationResult
        The camera with the target estimated (``rms_px``, residuals: the image part only; ``covariance`` of the
        intrinsics from the augmented normal matrix).
    nominal : CalibrationResult
        The ordinary calibration on the nominal target (the start).
    points : ndarray (P, 3)
        The distinct nominal target points (target unit).
    offsets : ndarray (P, 3)
        Their estimated offsets (m): the printed rig is ``points + offsets``.
    theta : ndarray (27,)
        The estimated structure (:func:`rig_basis`: line offsets m, bows m, fold rad).
    ids : list of ndarray (N_i,)
        For each view, the index into ``points`` of each object point.
    """

    calibration: CalibrationResult
    nominal: CalibrationResult
    points: np.ndarray
    offsets: np.ndarray
    ids: list
    theta: np.ndarray = None


def calibrate_camera_refining_rig(object_points, image_points, image_size, model: str = "heikkila", *,
                                     sigma_px: float = 0.1, k3: bool = False,
                                     fit_skew: bool = False, max_iterations: int = 200,
                                     tol: float = 1e-12) -> TargetRefinedCalibration:
    """Calibrate the camera and the printed rig's structure together (module docstring).

    Parameters
    ----------
    object_points, image_points, image_size, model, k3, fit_skew, max_iterations, tol
        As :func:`bench.camera.calibration.calibrate_camera`; object points equal to within 1e-9 (target unit) are
        one physical point.
    sigma_px : float
        Corner detection noise (px) the prior is weighed against.

    Returns
    -------
    TargetRefinedCalibration
        ``calibration.success`` False (with the reason) when the nominal calibration or the refinement fails.
    """
    if not (np.isfinite(sigma_px) and sigma_px > 0):
        raise ValueError(f"sigma_px: expected a positive number of px, got {sigma_px!r}")
    Xs, uvs, size = check_views(object_points, image_points, image_size)
    nominal = calibrate_camera(Xs, uvs, size, model, k3=k3, fit_skew=fit_skew, max_iterations=max_iterations,
                               tol=tol)
    allX = np.vstack(Xs)
    keys = np.round(allX / 1e-9).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    points = allX[first]
    ids = np.split(inverse.ravel(), np.cumsum([len(x) for x in Xs])[:-1])
    if not nominal.success:
        return TargetRefinedCalibration(nominal, nominal, points, np.zeros_like(points), ids, None)
    A, sig = rig_basis(points)
    problem = _TargetProblem(points, ids, uvs, model, k3, fit_skew, sigma_px / sig, A)
    k = nominal.parameters[problem.n_intr - len(problem.dist_names):]
    s = _TargetState(nominal.K[0, 0], nominal.K[1, 1], nominal.K[0, 2], nominal.K[1, 2],
                     nominal.K[0, 1] if fit_skew else 0.0, np.asarray(k, float).copy(),
                     nominal.T_cam_target[:, :3, :3].copy(), nominal.T_cam_target[:, :3, 3].copy(),
                     np.zeros(A.shape[1]))
    s, iterations, converged, message = _levenberg_marquardt(problem, s, max_iterations, tol)
    r, J = problem.residuals(s, jacobian=True)
    n_img = 2 * int(problem.offsets[-1])
    dof = n_img - problem.n_base  # the prior rows carry their own information
    sigma2 = float(r[:n_img] @ r[:n_img]) / max(dof, 1)
    try:
        cov = sigma2 * np.linalg.inv(J.T @ J)[: problem.n_intr, : problem.n_intr]
    except np.linalg.LinAlgError:
        cov = np.full((problem.n_intr, problem.n_intr), np.nan)
    off = (A @ s.delta).reshape(-1, 3)
    problem.X = [points[i] + off[i] for i in ids]
    base = _Problem(problem.X, uvs, model, k3, fit_skew)
    rms, per_view, residuals, _ = _residual_summary(base, s)
    result = replace(nominal, success=bool(converged and np.isfinite(rms)), message=f"target refined: {message}",
                     K=s.K(), dist=_full_dist(model, s.dist), T_cam_target=homogeneous(s.R, s.t), rms_px=rms,
                     per_view_rms_px=per_view, residuals_px=residuals, parameters=base.intrinsic_vector(s),
                     covariance=cov, sigma_px=float(np.sqrt(sigma2)), iterations=iterations,
                     cost=0.5 * float(r @ r), timings_s={})
    return TargetRefinedCalibration(result, nominal, points, off, ids, s.delta.copy())


def rig_basis(points, line_sigma: float = 0.3e-3, bow_sigma: float = 0.6e-3, fold_sigma: float = 0.0035):
    """The printout's structure as a linear basis: corner offsets ``(3 P,) = A theta``.

    Parameters
    ----------
    points : ndarray (P, 3)
        The rig's distinct corners (m, rig frame: board A in y = 0, board B in x = 0).
    line_sigma, bow_sigma, fold_sigma : float
        Prior standard deviations: a printed line's offset (m), a board's bow sagitta (m), the fold (rad; 0.2
        deg). Defaults: the real printout's measured 0.28 mm line offsets, 0.6 mm bow (docs/realistic_imaging.md).

    Returns
    -------
    A : ndarray (3 P, n)
        Columns: per board, one per column line (moves its corners across the board), one per row line (along z),
        one bow (out of the board's plane, ``1 - (2 u / W - 1)^2`` across the pattern of width W), then the fold
        (board B's corners turned about z: ``(-y, x, 0)``).
    sigma : ndarray (n,)
    """
    points = np.asarray(points, float)
    P = len(points)
    on_a, on_b = np.isclose(points[:, 1], 0.0, atol=1e-9), np.isclose(points[:, 0], 0.0, atol=1e-9)
    if not (on_a.any() and on_b.any() and np.all(on_a | on_b)):
        raise ValueError("rig_basis: expected the two-plane rig's corners (board A in y = 0, board B in x = 0, rig "
                         f"frame); {int(np.sum(~(on_a | on_b)))} of {P} points lie on neither plane")
    cols, sig = [], []
    for axis, across in ((1, 0), (0, 1)):  # board A: y = 0, across = x; board B: x = 0, across = y
        on = np.isclose(points[:, axis], 0.0, atol=1e-9) & ~np.isclose(points[:, across], 0.0, atol=1e-9)
        for coord, direction in ((across, across), (2, 2)):  # column lines move 'across', row lines move z
            for val in np.unique(np.round(points[on, coord], 9)):
                a = np.zeros((P, 3))
                sel = on & np.isclose(points[:, coord], val, atol=1e-9)
                a[sel, direction] = 1.0
                cols.append(a.ravel())
                sig.append(line_sigma)
        u = points[on, across]
        lo, hi = u.min(), u.max()
        s_ = (hi - lo) / 5  # square size (6 corners per line)
        W, u0 = 7 * s_, lo - s_
        a = np.zeros((P, 3))
        a[on, axis] = 1 - (2 * (u - u0) / W - 1) ** 2  # out of plane
        cols.append(a.ravel())
        sig.append(bow_sigma)
    on_b = np.isclose(points[:, 0], 0.0, atol=1e-9) & ~np.isclose(points[:, 1], 0.0, atol=1e-9)
    a = np.zeros((P, 3))
    a[on_b, 0] = -points[on_b, 1]
    a[on_b, 1] = points[on_b, 0]
    cols.append(a.ravel())
    sig.append(fold_sigma)
    return np.column_stack(cols), np.array(sig)
