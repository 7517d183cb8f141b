"""The x-y table's maximum-likelihood position estimate: a bundle over the views of one estimate (issue 11).

The thesis's estimators (:func:`~bench.vision.xy_table_positioning.estimate_positions`: the map ``1p``, ``2p``,
RANSAC and an absolute orientation) take the camera's rotation on its support ``R0`` from the search of Eq. 197-198
and the calibrated intrinsics as exact, and fix the map ``1p`` before aligning ``2p`` to it. :func:`pair_bundle`
estimates, together and from the pixels of every view the estimate uses (the reference, the views of its map and the
pair - the observation pattern of the bound in :mod:`bench.scenario.xy_table_bound`),

* the pair's displacement ``xi`` (6: rotation vector, then translation, about camera ``a``'s starting centre, table
  frame) - the unknown the experiment is about; the pair's relative pose comes from its readings;
* the rotation ``R0`` as ``R0 exp(w)`` (3, right perturbation, under a loose prior of ``R0_prior_deg`` per axis
  that holds only the rotation about the line of camera centres, which no view of a straight campaign observes);
* optionally the intrinsics ``fx, fy, cx, cy`` (4) under the rig calibration's covariance as a prior, the
  distortion's ``k1, k2, p1, p2`` (4) under a stated prior, the camera centre on the stage (3) under the tolerance
  ``table.yaml`` states, and every view's reading ``(x, z, rot)`` (3 per view) under a prior of one resolution step;
* every map point (table frame), eliminated point by point (:func:`bench.vision.bundle.solve`).

Camera poses (:mod:`bench.vision.xy_table_positioning`): ``T_table_cam = S [R0 exp(w) | o + do]`` with ``S`` the
stage pose of the view's readings; a view of the pair has ``D(xi) C0 S`` instead, ``C0`` the start (the thesis's
estimate moved onto the readings) and ``D(xi)`` the displacement. Residuals are pixels through the calibrated camera
(Eq. 50, 75-76); the projection and the point derivatives are analytic, the pose blocks central differences (checked
against a difference quotient of the residuals in the tests).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.camera.model import (
    check_dist,
    distort,
    distortion_jacobian,
    distortion_parameter_jacobian,
    thin_prism,
    thin_prism_jacobian,
    thin_prism_parameter_jacobian,
)
from bench.geometry.quaternion import rotation_vector_to_matrix
from bench.geometry.transforms import homogeneous, invert
from bench.vision.bundle import solve
from bench.vision.insitu import _proj_jac
from bench.vision.xy_table_positioning import R0_PRIOR_DEG, stage_poses

#: a round of the bundle ends when a step is shorter than this fraction of a standard deviation of the estimate
#: (:func:`bench.vision.bundle.solve`'s ``step_tol``). The experiment runs ~25 bundles of ~1,000 points; the steps
#: after it took a quarter of the time and moved the estimates by < 4e-5 mm (xy_table_webcam, seed 0)
STEP_TOL = 1e-2


@dataclass(frozen=True)
class PairBundleResult:
    """Outcome of :func:`pair_bundle`.

    ``p_table`` (3,) camera ``a``'s centre relative to the reference camera's, table axes (m; NaN on failure) with
    its first-order covariance ``cov_p`` (3, 3) (m^2); ``R0`` (3, 3) and ``K`` (3, 3) as refined; ``sigma_px`` the
    pixel noise the kept residuals give and ``rms_px`` their RMS per axis; ``observations`` those the gate kept.
    """

    success: bool
    message: str
    p_table: np.ndarray
    cov_p: np.ndarray
    R0: np.ndarray
    K: np.ndarray
    sigma_px: float
    rms_px: float
    observations: int
    iterations: int


def _displacements(xi, pivot) -> np.ndarray:
    """``D (..., 4, 4)``: rotation ``exp(xi[..., :3])`` about ``pivot``, then translation ``xi[..., 3:]``."""
    R = rotation_vector_to_matrix(xi[..., :3])
    return homogeneous(R, pivot + xi[..., 3:] - R @ pivot)


class PairProblem:
    """The observations and the camera model of :func:`pair_bundle`. Parameters: ``xi`` (6), ``w`` (3), then ``d_K``
    (4: ``dfx, dfy, dcx, dcy`` px) when ``with_K``, then every view's reading correction ``(dx, dz, drot)`` (3 V: m,
    m, rad) when ``with_readings``. Poses and camera points are computed for a batch of parameter vectors at once
    (the difference quotients of :meth:`linearise` in one pass)."""

    step = 1e-7

    def __init__(self, readings, in_pair, C0, pivot, R0, offset_m, K, dist, view, point, uv, with_K: bool,
                 with_readings: bool = False, with_dist: int = 0, with_offset: bool = False):
        self.read, self.in_pair = np.asarray(readings, float), np.asarray(in_pair, bool)
        self.C0, self.pivot = np.asarray(C0, float), np.asarray(pivot, float)
        self.R0, self.offset = np.asarray(R0, float), np.asarray(offset_m, float)
        self.K = np.asarray(K, float)
        self.dist = np.zeros(5) if dist is None or not len(dist) else check_dist(dist)
        self.view, self.point, self.uv = np.asarray(view, int), np.asarray(point, int), np.asarray(uv, float)
        if with_dist not in (0, 4, 8):
            raise ValueError(f"with_dist: 0, 4 (k1 k2 p1 p2) or 8 (and the thin prism s1..s4), got {with_dist!r}")
        self.with_K, self.with_readings, self.n_dist = bool(with_K), bool(with_readings), int(with_dist)
        self.with_dist = self.n_dist > 0
        self.with_offset = bool(with_offset)
        self.V = len(self.read)
        self.k_dist = 9 + 4 * self.with_K  # where the distortion's corrections start
        self.k_off = self.k_dist + self.n_dist  # the camera centre's on the stage
        self.k_read = self.k_off + 3 * self.with_offset  # the readings'
        #: the columns differentiated numerically with every view at once: the pair, R0 and the centre
        self.shared_fd = [*range(9), *range(self.k_off, self.k_read)]
        self.n = self.k_read + 3 * self.V * self.with_readings

    def intrinsics(self, theta) -> np.ndarray:
        K = self.K.copy()
        if self.with_K:
            K[0, 0] += theta[9]
            K[1, 1] += theta[10]
            K[:2, 2] += theta[11:13]
        return K

    def distortion(self, theta) -> np.ndarray:
        """The distortion ``(5,)`` with ``k1, k2, p1, p2`` corrected (``k3`` as calibrated)."""
        if not self.with_dist:
            return self.dist
        return self.dist + np.r_[theta[self.k_dist:self.k_dist + 4], 0.0]

    def prism(self, theta) -> np.ndarray:
        """The thin prism's ``s1, s2, s3, s4`` (zero unless estimated)."""
        return theta[self.k_dist + 4:self.k_off] if self.n_dist == 8 else np.zeros(4)

    def distorted(self, x_n, theta) -> np.ndarray:
        """Normalized points through the lens: Eq. 75-76 (and the thin prism when estimated)."""
        x_d = distort(x_n, self.distortion(theta))
        return x_d + thin_prism(x_n, self.prism(theta)) if self.n_dist == 8 else x_d

    def rotation(self, theta) -> np.ndarray:
        """``R0 exp(w)`` (..., 3, 3): the camera's rotation on its support."""
        return self.R0 @ rotation_vector_to_matrix(np.asarray(theta)[..., 6:9])

    def readings(self, theta) -> np.ndarray:
        """The views' readings ``(..., V, 3)`` with their corrections."""
        theta = np.asarray(theta, float)
        if not self.with_readings:
            return np.broadcast_to(self.read, (*theta.shape[:-1], self.V, 3))
        return self.read + theta[..., self.k_read:].reshape(*theta.shape[:-1], self.V, 3)

    def centre_on_stage(self, theta) -> np.ndarray:
        """The camera centre on the stage ``(..., 3)`` (m), corrected."""
        theta = np.asarray(theta, float)
        if not self.with_offset:
            return np.broadcast_to(self.offset, (*theta.shape[:-1], 3))
        return self.offset + theta[..., self.k_off:self.k_read]

    def poses(self, theta) -> np.ndarray:
        """``T_table_cam (..., V, 4, 4)`` of every view for parameters ``theta (..., n)``."""
        theta = np.asarray(theta, float)
        X = homogeneous(self.rotation(theta)[..., None, :, :], self.centre_on_stage(theta)[..., None, :])
        T = stage_poses(self.readings(theta)) @ X
        T[..., self.in_pair, :, :] = (_displacements(theta[..., :6], self.pivot)[..., None, :, :] @ self.C0
                                      @ T[..., self.in_pair, :, :])
        return T

    def centre_offset(self, theta) -> np.ndarray:
        """Camera ``a``'s centre relative to the reference camera's (view 0), table axes (m)."""
        T = self.poses(theta)
        return T[..., np.flatnonzero(self.in_pair)[0], :3, 3] - T[..., 0, :3, 3]

    def camera_points(self, T_cam_table, X) -> np.ndarray:
        """``p_cam (..., N, 3)`` of every observation for poses ``T_cam_table (..., V, 4, 4)`` (each observation's
        own point in its own view: a point is seen in a few of the views)."""
        R, t = T_cam_table[..., :3, :3][..., self.view, :, :], T_cam_table[..., :3, 3][..., self.view, :]
        return np.einsum("...nij,nj->...ni", R, X[self.point]) + t

    def residuals(self, theta, X) -> np.ndarray:
        """Pixel residuals ``uv - K distort(pi(p_cam))`` (N, 2) (a trial step may make ``K`` invalid: no check)."""
        p = self.camera_points(invert(self.poses(theta)), X)
        K = self.intrinsics(theta)
        return self.uv - (self.distorted(p[:, :2] / p[:, 2:3], theta) @ K[:2, :2].T + K[:2, 2])

    def linearise(self, theta, X) -> tuple:
        """Residuals (N, 2), ``J (N, 2, n)``, ``J_pt (N, 2, 3)`` and the smallest depth of a point in a camera.

        The pose parameters by central differences, in one batch: ``xi``, ``w`` and the centre one by one, the
        readings' corrections one coordinate of every view at once (an observation depends on its own view's only)."""
        ns = len(self.shared_fd)
        m = ns + 3 * self.with_readings
        E = np.zeros((1 + 2 * m, self.n))
        E[1 + np.arange(ns), self.shared_fd] = self.step
        for c in range(3 * self.with_readings):
            E[1 + ns + c, self.k_read + c::3] = self.step
        E[1 + m:] = -E[1:1 + m]
        T_ct = invert(self.poses(theta + E))
        P = self.camera_points(T_ct, X)
        p, T_ct = P[0], T_ct[0]
        K = self.intrinsics(theta)
        z = p[:, 2]
        x_n, Jproj = _proj_jac(p)
        dist = self.distortion(theta)
        x_d = self.distorted(x_n, theta)
        D = distortion_jacobian(x_n, dist)
        if self.n_dist == 8:
            D = D + thin_prism_jacobian(x_n, self.prism(theta))
        A = K[:2, :2] @ D @ Jproj  # d uv / d p_cam (N, 2, 3)
        J = np.zeros((len(p), 2, self.n))
        dr = -np.einsum("nij,cnj->nic", A, (P[1:1 + m] - P[1 + m:]) / (2 * self.step))  # (N, 2, m)
        J[:, :, self.shared_fd] = dr[:, :, :ns]
        if self.with_K:  # u = fx x_d + s y_d + cx, v = fy y_d + cy
            J[:, 0, 9], J[:, 1, 10], J[:, 0, 11], J[:, 1, 12] = -x_d[:, 0], -x_d[:, 1], -1.0, -1.0
        if self.with_dist:
            J[:, :, self.k_dist:self.k_dist + 4] = -K[:2, :2] @ distortion_parameter_jacobian(x_n)
        if self.n_dist == 8:
            J[:, :, self.k_dist + 4:self.k_off] = -K[:2, :2] @ thin_prism_parameter_jacobian(x_n)
        rows = np.arange(len(p))
        for c in range(3 * self.with_readings):
            J[rows, :, self.k_read + 3 * self.view + c] = dr[:, :, ns + c]
        J_pt = -A @ T_ct[self.view, :3, :3]
        return self.uv - (x_d @ K[:2, :2].T + K[:2, 2]), J, J_pt, float(z.min())


def pair_observations(kmap, views: list, matches: dict, features: dict, pair) -> tuple:
    """``(view, point, uv, points)`` of one estimate: every map point in the reference (view 0), in the map's views
    where the map found it (``kmap.observations``; ``views[1:-2]`` in the map's order) and in the pair's two views
    (``views[-2:]``) where the reference keypoint was matched (``matches[name]``, reference -> view). ``points``
    are the map indices of the points kept (those seen at least twice), renumbered ``0..M-1`` in ``point``."""
    ref = views[0]
    lookup = {name: dict(zip(np.asarray(matches[name].i1, int).tolist(), np.asarray(matches[name].i2, int).tolist(),
                             strict=True)) for name in views[1:]}
    view, point, uv, points = [], [], [], []
    for i, r in enumerate(np.asarray(kmap.ref_index, int)):
        obs = [(0, features[ref].uv[r])]
        for k in kmap.observations[i][0]:
            name = views[1 + int(k)]
            if r in lookup[name]:
                obs.append((1 + int(k), features[name].uv[lookup[name][r]]))
        for j, name in zip((len(views) - 2, len(views) - 1), pair, strict=True):
            if r in lookup[name]:
                obs.append((j, features[name].uv[lookup[name][r]]))
        if len(obs) < 2:
            continue
        view += [o[0] for o in obs]
        point += [len(points)] * len(obs)
        uv += [o[1] for o in obs]
        points.append(i)
    return (np.array(view, int), np.array(point, int), np.array(uv, float).reshape(-1, 2),
            np.array(points, int))


def pair_bundle(readings, in_pair, T_table_a0, R0, offset_m, K, dist, view, point, uv, X, cov_K=None,
                reading_sigma=None, cov_dist=None, offset_sigma=None, R0_prior_deg: float = R0_PRIOR_DEG,
                sigma_px: float = 0.5,
                iterations: int = 50, rounds: int = 2, gate: float | None = 3.5) -> PairBundleResult:
    """Camera ``a``'s position relative to the reference by maximum likelihood (module docstring).

    Parameters
    ----------
    readings : ndarray (V, 3)
        The table's readings ``[x_m, z_m, rot_rad]`` of the views: the reference first, the pair's two last.
    in_pair : ndarray (V,) bool
        The pair's views (``a`` the first of them).
    T_table_a0 : ndarray (4, 4)
        Camera ``a``'s starting pose (the thesis's estimate, e.g. LMS + error ratio, in the table frame).
    R0 : ndarray (3, 3)
        The camera's rotation on its support to start from (the search's) and the prior's mean.
    offset_m : ndarray (3,)
        The camera centre on the stage (``table.yaml``).
    K, dist : ndarray (3, 3), (5,) or None
        The calibrated camera.
    view, point, uv : ndarray (N,), (N,), (N, 2)
        Observation ``n`` is of point ``point[n]`` in view ``view[n]`` at ``uv[n]`` (px) (:func:`pair_observations`).
    X : ndarray (M, 3)
        Starting points (table frame, m); each observed at least twice.
    cov_K : ndarray (4, 4), optional
        Covariance (px^2) of ``fx, fy, cx, cy`` from the rig calibration: given, they are refined under it.
    cov_dist : ndarray (4, 4) or (8, 8), optional
        Covariance of the distortion's ``k1, k2, p1, p2`` (from the calibration, or a loose prior about zero for a
        pin-hole calibration), and of the thin prism's ``s1, s2, s3, s4`` about zero with 8: given, they are refined
        under it.
    offset_sigma : (3,), optional
        The stated tolerance (1 sigma per axis, m) of the camera centre on the stage (``table.yaml``): given, the
        centre is refined under it; None: exact.
    reading_sigma : (3,), optional
        Standard deviations of the readings (m, m, rad; e.g. a resolution step / sqrt(12)): given, every view's
        reading is refined under it as a prior; None: the readings are exact.
    R0_prior_deg : float
        Standard deviation (deg, per axis) of the prior on ``R0``'s correction.
    sigma_px, iterations, rounds, gate
        As :func:`bench.vision.bundle.solve` (the starting residuals are gated too). ``iterations`` is a budget per
        round, not a tolerance: on the desk robot's scene (depths 0.7-1.15 m) the backtracking Gauss-Newton steps of
        a round took up to 49 in all (seed 3 of ``xy_table_webcam``), and at 20 every pair of that seed was refused
        as not converged.
    """
    readings, in_pair = np.asarray(readings, float), np.asarray(in_pair, bool)
    nan3 = np.full(3, np.nan)
    if in_pair.sum() < 1 or not in_pair[-1] or in_pair[0]:
        raise ValueError("in_pair: the pair's views come last and the reference first")
    if not R0_prior_deg > 0:
        raise ValueError(f"R0_prior_deg must be > 0, got {R0_prior_deg}")
    if offset_sigma is not None and not (np.shape(offset_sigma) == (3,) and np.all(np.asarray(offset_sigma) > 0)):
        raise ValueError(f"offset_sigma: three standard deviations > 0 expected, got {offset_sigma!r}")
    if reading_sigma is not None and not (np.shape(reading_sigma) == (3,) and np.all(np.asarray(reading_sigma) > 0)):
        raise ValueError(f"reading_sigma: three standard deviations > 0 expected, got {reading_sigma!r}")
    X0 = homogeneous(R0, offset_m)
    i_a = int(np.flatnonzero(in_pair)[0])
    C0 = np.asarray(T_table_a0, float) @ invert(stage_poses(readings[i_a])[0] @ X0)  # the readings' pair moved
    problem = PairProblem(readings, in_pair, C0, np.asarray(T_table_a0, float)[:3, 3], R0, offset_m, K, dist, view,
                          point, uv, cov_K is not None, reading_sigma is not None,
                          0 if cov_dist is None else len(cov_dist), offset_sigma is not None)
    n = problem.n
    info0 = np.zeros((n, n))
    info0[6:9, 6:9] = np.eye(3) / np.deg2rad(R0_prior_deg) ** 2
    if cov_K is not None:
        info0[9:13, 9:13] = np.linalg.inv(np.asarray(cov_K, float))
    if cov_dist is not None:
        info0[problem.k_dist:problem.k_off, problem.k_dist:problem.k_off] = np.linalg.inv(np.asarray(cov_dist, float))
    if offset_sigma is not None:
        info0[problem.k_off:problem.k_read, problem.k_off:problem.k_read] = np.diag(1.0 / np.square(offset_sigma))
    if reading_sigma is not None:
        k = problem.k_read
        info0[k:, k:] = np.diag(np.tile(1.0 / np.asarray(reading_sigma, float) ** 2, problem.V))
    if len(np.asarray(X)) < 3:
        return PairBundleResult(False, f"{len(X)} points (need >= 3)", nan3, np.full((3, 3), np.nan), problem.R0,
                                problem.K, np.nan, np.nan, 0, 0)
    sol = solve(problem, np.zeros(n), np.zeros(n), info0, X, sigma_px, iterations, rounds, gate, dof_offset=6,
                gate_groups=problem.view,
                groups_in_rounds=reading_sigma is not None,  # a view's misfit: its reading, when refined
                step_tol=STEP_TOL)
    if not (sol.success and sol.converged):  # an estimate off its optimum is not offered with a covariance
        return PairBundleResult(False, sol.message if not sol.success else f"not converged ({sol.message})", nan3,
                                np.full((3, 3), np.nan), problem.R0, problem.K, sol.sigma_px, np.nan, 0,
                                sol.iterations)
    G = np.zeros((3, n))  # d (c_a - c_ref) / d theta, every column (the pair, the centre, the readings of ref and a)
    for c, e in enumerate(np.eye(n) * problem.step):
        G[:, c] = (problem.centre_offset(sol.theta + e) - problem.centre_offset(sol.theta - e)) / (2 * problem.step)
    cov_p = G @ sol.covariance() @ G.T
    r = problem.residuals(sol.theta, sol.X)[sol.keep]
    rms = float(np.sqrt(np.mean(r**2)))
    kept = int(sol.keep.sum())
    extra = ((", intrinsics" if cov_K is not None else "") + (", distortion" if cov_dist is not None else "")
             + (", camera centre" if offset_sigma is not None else "")
             + (", readings" if reading_sigma is not None else ""))
    return PairBundleResult(True, f"ok; bundle of {len(X)} points, {kept} of {len(sol.keep)} observations kept, "
                            f"R0{extra}, sigma {sol.sigma_px:.3g} px", problem.centre_offset(sol.theta),
                            0.5 * (cov_p + cov_p.T), problem.rotation(sol.theta), problem.intrinsics(sol.theta),
                            sol.sigma_px, rms, kept, sol.iterations)
