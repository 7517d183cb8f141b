"""How well could the base have been found at all? Ideal features, measured keypoint noise, the Cramér-Rao bound of
the in-situ localisation and a Monte Carlo of the ideal estimator (evaluator side: reads the truth).

* :func:`true_projector` - pixels of camera-frame points through the *true* optics (lens, and the flat port in
  water): what a perfect feature detector would report.
* :func:`ideal_features` - exact projections of a fixed set of 3D points with a unique descriptor per point (perfect
  correspondences), optionally with Gaussian pixel noise: the ``sources.features = perfect`` switch and the Monte
  Carlo below.
* :func:`keypoint_sigma_px` - the localisation noise of the pipeline's SIFT keypoints, measured against the truth:
  the distance of each matched keypoint from the *true* epipolar curve of its reference keypoint (rays through the
  true optics and true camera poses), robust standard deviation over all matches, divided by sqrt(2) (both
  keypoints of a pair are noisy).
* :func:`crb_base_pose` - the Cramér-Rao lower bound on the located base pose: Fisher information of every
  observation the ideal estimator would have (each map point in the reference, surrounding and locate views, pixel
  noise sigma), with the joint angles of every view as nuisance parameters observed by the encoders (sigma_enc),
  the identified arm errors (the 25 of §2.5-2.7) with the identification's covariance as prior (tracker noise) and
  the 3D points as free nuisance parameters; the base's 6 x 6 block of the inverse (Schur complement).
  Intrinsics and mount are taken as exact (their calibration errors are systematic and largely cancel between
  survey and localisation, see the README); in water the camera is the central equivalent of lens + port.
* :func:`mc_ideal_estimator` - the pipeline's own estimator (map by Eq. 162-164, RANSAC + absolute orientation,
  reprojection refinement) run on ideal features with exactly the noise the bound assumes, over many draws.

Conventions: the site frame is the survey base frame (as in the pipeline); the base pose of the locate parking is
``T_site_b2`` perturbed as ``R' = exp(dphi) R``, ``t' = t + dt`` so that ``dt`` is the base origin's error (the
scored ``base_pos_err_mm``) and ``dphi`` its rotation (``base_rot_err_deg``).
"""

from __future__ import annotations

import numpy as np

from bench.camera.model import CameraModel
from bench.geometry.transforms import invert, rotation_angle, transform_points
from bench.robot.orientation import link5_frame
from bench.vision.features import Features
from bench.vision.insitu import MapConfig, ViewObservation, build_map, locate, reference_matches

DESCRIPTOR_SEED = 20061  # fixed: the same 3D point has the same descriptor in every view and every draw


def _exp_so3(w):
    th = np.linalg.norm(w)
    K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    if th < 1e-12:
        return np.eye(3) + K
    return np.eye(3) + np.sin(th) / th * K + (1 - np.cos(th)) / th**2 * K @ K


def true_projector(camera: CameraModel, port=None):
    """``project(p_cam (..., 3)) -> uv (..., 2)`` through the lens ``camera`` and, if given, the flat ``port``."""
    if port is None:
        return camera.project
    from bench.sim.flatport import project_flatport

    def project(p_cam):
        x_n = project_flatport(p_cam, port)
        return camera.project(np.concatenate([x_n, np.ones(x_n.shape[:-1] + (1,))], axis=-1))

    return project


def panel_points(corners_world, n: int, rng: np.random.Generator, margin: float = 0.05) -> np.ndarray:
    """``n`` points (n, 3) uniformly on the panel face spanned by its four corners (world, m)."""
    c = np.asarray(corners_world, dtype=float)
    u, v = rng.uniform(margin, 1 - margin, (2, n))
    return c[0] + u[:, None] * (c[1] - c[0]) + v[:, None] * (c[3] - c[0])


def ideal_features(p_world, T_world_cam, project, size, noise_px: float = 0.0, rng=None) -> Features:
    """Exact projections of ``p_world (M, 3)`` seen by a camera at ``T_world_cam`` (only those inside the image).

    Point ``j`` always gets descriptor ``j`` (a fixed random unit vector), orientation 0 and size 10 px, so the
    pipeline's ratio test and orientation filter match exactly the same 3D point in every view.
    """
    p_world = np.asarray(p_world, dtype=float)
    uv = project(transform_points(invert(T_world_cam), p_world))
    w, h = size
    ok = np.all(np.isfinite(uv), axis=1) & (uv[:, 0] > 0) & (uv[:, 0] < w - 1) & (uv[:, 1] > 0) & (uv[:, 1] < h - 1)
    idx = np.flatnonzero(ok)
    desc = np.random.default_rng(DESCRIPTOR_SEED).normal(size=(len(p_world), 128)).astype(np.float32)
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    uv = uv[idx]
    if noise_px > 0:
        uv = uv + rng.normal(0.0, noise_px, uv.shape)
    n = len(idx)
    return Features(uv, np.zeros(n), np.full(n, 10.0), np.ones(n), desc[idx] * 512)


def _epipolar_distance(uv_ref, T_ref_k, unproject_ref, project_k, depths):
    """Distance (px) of ``uv_k`` points to the image in view k of the true rays through ``uv_ref`` (sampled)."""
    rays = unproject_ref(uv_ref)  # (N, 3) directions in the reference camera frame (central approximation)
    pts = rays[:, None, :] * depths[None, :, None]  # (N, D, 3)
    return project_k(transform_points(invert(T_ref_k), pts))  # (N, D, 2) the epipolar curve


def keypoint_sigma_px(reference: ViewObservation, views: list, T_world_cam_true: dict, camera_true: CameraModel,
                      project, depth_range=(0.2, 3.0), config: MapConfig | None = None) -> tuple:
    """Measured SIFT localisation noise (px, 1-sigma per image axis) and the number of matches it is based on.

    ``T_world_cam_true`` maps view names to true camera poses; ``camera_true`` back-projects the reference keypoints
    (in water the central equivalent, an approximation of the port's rays good to a fraction of a pixel over the
    short epipolar segments involved); ``project`` maps into the other views through the true optics.
    """
    depths = np.geomspace(*depth_range, 400)
    d_all = []
    T_wr = T_world_cam_true[reference.name]
    for view, m in zip(views, reference_matches(reference, views, config), strict=True):
        if len(m) == 0:
            continue
        T_ref_k = invert(T_wr) @ T_world_cam_true[view.name]
        curve = _epipolar_distance(reference.features.uv[m.i1], T_ref_k, camera_true.unproject, project, depths)
        p = view.features.uv[m.i2][:, None, :]
        a, b = curve[:, :-1], curve[:, 1:]
        ab = b - a
        t = np.clip(np.sum((p - a) * ab, axis=-1) / np.maximum(np.sum(ab * ab, axis=-1), 1e-12), 0, 1)
        dist = np.linalg.norm(a + t[..., None] * ab - p, axis=-1)
        d_all.append(np.nanmin(dist, axis=1))
    if not d_all:
        return float("nan"), 0
    d = np.concatenate(d_all)
    d = d[np.isfinite(d) & (d < 5.0)]  # gross mismatches are not localisation noise
    # the distance is |n . (e_k - g e_ref)|: a half-normal of sigma * sqrt(1 + g^2) ~ sigma sqrt(2)
    return float(np.median(d) / 0.6745 / np.sqrt(2)), int(len(d))


class _Model:
    """Pixels of every (view, point) observation as a function of the parameters (base pose, joints, arm errors,
    points); rows of one point depend on that point only, rows of one view on that view's joints only."""

    def __init__(self, robot, eps_true, kept, mount, project, T_site_b2, views, X_site, size):
        self.robot, self.eps0, self.kept, self.mount, self.project = robot, eps_true, kept, mount, project
        self.T_b2 = T_site_b2
        self.q0 = np.array([q for q, _ in views])
        self.locate = np.array([loc for _, loc in views], dtype=bool)
        self.X0 = X_site
        uv = self.pixels(np.zeros(6), self.q0, np.zeros(len(kept)), X_site)
        w, h = size
        self.vis = np.all(np.isfinite(uv), axis=-1) & (uv[..., 0] > 0) & (uv[..., 0] < w - 1) & \
            (uv[..., 1] > 0) & (uv[..., 1] < h - 1)

    def jacobian(self, xi, q, d_eps, X) -> np.ndarray:
        """d pixels / d (xi (6), q (6V), d_eps (P), X (3M)), shape (2 V M, 6 + 6V + P + 3M), by central differences
        in blocks: every point's coordinate c at once, every view's joint c at once (their rows do not overlap)."""
        V, M, P = len(q), len(X), len(d_eps)
        J = np.zeros((2 * V * M, 6 + 6 * V + P + 3 * M))

        def diff(plus, minus, h):
            return ((self.pixels(*plus) - self.pixels(*minus)) / (2 * h)).reshape(V, M, 2)

        for c in range(6):  # base pose: locate views only
            e = np.zeros(6)
            e[c] = h = 1e-7
            J[:, c] = diff((xi + e, q, d_eps, X), (xi - e, q, d_eps, X), h).ravel()
        for c in range(6):  # joint c of every view at once: rows of view v depend on q_v only
            dq = np.zeros_like(q)
            dq[:, c] = h = 1e-7
            d = diff((xi, q + dq, d_eps, X), (xi, q - dq, d_eps, X), h)
            for v in range(V):
                J[v * M * 2:(v + 1) * M * 2, 6 + 6 * v + c] = d[v].ravel()
        for c in range(P):  # identified arm errors: every row
            de = np.zeros(P)
            de[c] = h = 1e-7
            J[:, 6 + 6 * V + c] = diff((xi, q, d_eps + de, X), (xi, q, d_eps - de, X), h).ravel()
        for c in range(3):  # coordinate c of every point at once: rows of point m depend on X_m only
            dX = np.zeros_like(X)
            dX[:, c] = h = 1e-6
            d = diff((xi, q, d_eps, X + dX), (xi, q, d_eps, X - dX), h)
            for m in range(M):
                J[np.arange(V)[:, None] * M * 2 + m * 2 + np.arange(2), 6 + 6 * V + P + 3 * m + c] = d[:, m, :]
        return J

    def pixels(self, xi, q, d_eps, X):
        eps = self.eps0.copy()
        eps[self.kept] += d_eps
        T_b2 = self.T_b2.copy()
        T_b2[:3, :3] = _exp_so3(xi[:3]) @ T_b2[:3, :3]
        T_b2[:3, 3] += xi[3:]
        T_site_cam = link5_frame(self.robot, q, eps) @ self.mount  # (V, 4, 4)
        T_site_cam[self.locate] = T_b2 @ T_site_cam[self.locate]
        T_cam_site = np.linalg.inv(T_site_cam)
        p_cam = np.einsum("vij,mj->vmi", T_cam_site[:, :3, :3], X) + T_cam_site[:, None, :3, 3]
        return self.project(p_cam)  # (V, M, 2)


def crb_base_pose(robot, eps_true, kept, cov_eps_dot, mount, project, T_site_b2, views, X_site, size, sigma_px,
                  sigma_enc) -> dict:
    """Cramér-Rao bound of the located base pose (see the module docstring).

    Parameters
    ----------
    robot : Robot
    eps_true : ndarray (42,)
        True generalized errors (the linearisation point).
    kept : ndarray (25,) of int
        Indices of the identifiable errors (§2.5-2.7); ``cov_eps_dot`` (25, 25) their identification covariance.
    mount : ndarray (4, 4)
        True camera mount on link 5.
    project : callable
        Camera-frame points (..., 3) -> pixels (..., 2) (a central camera).
    T_site_b2 : ndarray (4, 4)
        True base pose of the locate parking in the site (survey base) frame.
    views : list of (q_true (6,), is_locate_view)
    X_site : ndarray (M, 3)
        The 3D points (site frame).
    size : (w, h)
    sigma_px, sigma_enc : float
        Pixel noise (px, per axis) and encoder noise (rad, per joint, quantisation included).

    Returns
    -------
    dict
        ``cov (6, 6)`` (rotation vector rad, then base origin m), ``pos_bound_m``, ``rot_bound_rad``,
        ``observations``.
    """
    model = _Model(robot, np.asarray(eps_true, float), np.asarray(kept), mount, project, T_site_b2, views, X_site,
                   size)
    V, P = len(views), len(kept)
    rows = np.flatnonzero(np.repeat(model.vis.ravel(), 2))  # observed (view, point, axis) rows
    J = model.jacobian(np.zeros(6), model.q0, np.zeros(P), model.X0)
    J = J[rows]
    info = J.T @ J / sigma_px**2
    info[6:6 + 6 * V, 6:6 + 6 * V] += np.eye(6 * V) / sigma_enc**2  # the encoders observe the joints
    s = slice(6 + 6 * V, 6 + 6 * V + P)
    info[s, s] += np.linalg.inv(cov_eps_dot)  # the lab identification observed the arm errors
    # Schur complement onto the base pose (the nuisance block is positive definite given the priors and >= 2 views)
    A, B, C = info[:6, :6], info[:6, 6:], info[6:, 6:]
    cov = np.linalg.inv(A - B @ np.linalg.solve(C, B.T))
    cov = 0.5 * (cov + cov.T)
    return {"cov": cov, "pos_bound_m": float(np.sqrt(np.trace(cov[3:, 3:]))),
            "rot_bound_rad": float(np.sqrt(np.trace(cov[:3, :3]))), "observations": int(len(rows) // 2)}


def mc_ideal_estimator(robot, eps_true, kept, cov_eps_dot, mount, camera: CameraModel, T_site_b2, views, names,
                       X_site, sigma_px, encoders, rng: np.random.Generator, trials: int = 30, method: str = "svd",
                       ransac: dict | None = None) -> dict:
    """RMS base error of the pipeline's estimator on ideal features with the bound's noise, over ``trials`` draws.

    Each draw: pixel noise ``sigma_px`` on exact projections (``camera``: the true central camera), encoder readings
    drawn by ``encoders`` (an :class:`~bench.sim.encoders.EncoderModel`), arm errors drawn from the identification
    covariance; intrinsics and mount exact. ``views`` as for :func:`crb_base_pose` (``names``: reference first, then
    the surrounding views, then the two locate views).
    """
    q_true = np.array([q for q, _ in views])
    is_loc = np.array([loc for _, loc in views], dtype=bool)
    L = np.linalg.cholesky(cov_eps_dot)
    T_site_cam_true = link5_frame(robot, q_true, eps_true) @ mount
    T_site_cam_true[is_loc] = T_site_b2 @ T_site_cam_true[is_loc]
    pos, rot, fails = [], [], 0
    for _ in range(trials):
        eps = np.array(eps_true, float)
        eps[kept] += L @ rng.normal(size=len(kept))
        q_read = encoders.read(q_true, rng)
        obs = []
        for k, name in enumerate(names):
            f = ideal_features(X_site, T_site_cam_true[k], camera.project, camera.size, sigma_px, rng)
            obs.append(ViewObservation(name, f, camera.undistort_pixels(f.uv), link5_frame(robot, q_read[k], eps)
                                       @ mount))
        n_survey = int(np.sum(~is_loc))
        kmap = build_map(obs[0], obs[1:n_survey])
        res = locate(kmap, obs[n_survey], obs[n_survey + 1], method=method, rng=rng, **(ransac or {}))
        if not res.success:
            fails += 1
            continue
        pos.append(np.linalg.norm(res.T_world_base[:3, 3] - T_site_b2[:3, 3]))
        rot.append(rotation_angle(res.T_world_base[:3, :3].T @ T_site_b2[:3, :3]))
    pos, rot = np.array(pos), np.array(rot)
    return {"pos_rms_m": float(np.sqrt(np.mean(pos**2))) if len(pos) else float("nan"),
            "rot_rms_rad": float(np.sqrt(np.mean(rot**2))) if len(rot) else float("nan"),
            "trials": trials, "failures": fails}
