"""How well could the base have been found at all? The Cramér-Rao bound of the in-situ localisation and a Monte Carlo
of the ideal estimator (evaluator side: reads the truth). The generic parts - the true optics, ideal features, the
measured keypoint noise (:func:`keypoint_sigma_px`) and the bound's machinery - are in :mod:`bench.scenario.bounds`
(re-exported here).

* :func:`crb_base_pose` - the Cramér-Rao lower bound on the located base pose: Fisher information of every
  observation the ideal estimator would have (each map point in the reference, surrounding and locate views, pixel
  noise sigma), with the joint angles of every view as nuisance parameters observed by the encoders (sigma_enc),
  the identified arm errors (the 25 of §2.5-2.7) with the identification's covariance as prior (tracker noise) and
  the 3D points as free nuisance parameters (eliminated point by point); the base's 6 x 6 block of the inverse.
  Intrinsics and mount are taken as exact (their calibration errors are systematic and largely cancel between
  survey and localisation, see docs/bounds.md); in water the camera is the central equivalent of lens + port.
* :func:`mc_ideal_estimator` - the pipeline's own estimator (map by Eq. 162-164, RANSAC + absolute orientation,
  reprojection refinement) run on ideal features with exactly the noise the bound assumes, over many draws.

Conventions: the site frame is the survey base frame (as in the pipeline); the base pose of the locate parking is
``T_site_b2`` perturbed as ``R' = exp(dphi) R``, ``t' = t + dt`` so that ``dt`` is the base origin's error (the
scored ``base_pos_err_mm``) and ``dphi`` its rotation (``base_rot_err_deg``).
"""

from __future__ import annotations

import numpy as np

from bench.camera.model import CameraModel
from bench.geometry.quaternion import rotation_vector_to_matrix
from bench.geometry.transforms import rotation_angle
from bench.robot.orientation import link5_frame
from bench.scenario.bounds import (  # noqa: F401 - the generic parts, re-exported for the in-situ scenario
    Block,
    MultiViewModel,
    crb,
    ideal_features,
    keypoint_sigma_px,
    true_projector,
)
from bench.vision.insitu import ViewObservation, build_map, locate


def panel_points(corners_world, n: int, rng: np.random.Generator, margin: float = 0.05) -> np.ndarray:
    """``n`` points (n, 3) uniformly on the panel face spanned by its four corners (world, m)."""
    c = np.asarray(corners_world, dtype=float)
    u, v = rng.uniform(margin, 1 - margin, (2, n))
    return c[0] + u[:, None] * (c[1] - c[0]) + v[:, None] * (c[3] - c[0])


class _Model(MultiViewModel):
    """Pixels of every (view, point) observation as a function of the parameters: blocks ``xi`` (the locate
    parking's base pose, 6), ``q`` (joints, 6 per view), ``d_eps`` (identified arm errors), then the points."""

    def __init__(self, robot, eps_true, kept, mount, project, T_site_b2, views, X_site, size):
        self.robot, self.eps0, self.kept, self.mount = robot, eps_true, kept, mount
        self.T_b2 = T_site_b2
        self.q0 = np.array([q for q, _ in views])
        self.locate = np.array([loc for _, loc in views], dtype=bool)
        blocks = [Block("xi", 6), Block("q", 6, per_view=True), Block("d_eps", len(kept))]
        super().__init__(self._poses, blocks, [np.zeros(6), self.q0, np.zeros(len(kept))], X_site, project, size)

    def _poses(self, xi, q, d_eps):
        eps = self.eps0.copy()
        eps[self.kept] += d_eps
        T_b2 = self.T_b2.copy()
        T_b2[:3, :3] = rotation_vector_to_matrix(xi[:3]) @ T_b2[:3, :3]
        T_b2[:3, 3] += xi[3:]
        T_site_cam = link5_frame(self.robot, q, eps) @ self.mount  # (V, 4, 4)
        T_site_cam[self.locate] = T_b2 @ T_site_cam[self.locate]
        return T_site_cam


def crb_base_pose(robot, eps_true, kept, cov_eps_dot, mount, project, T_site_b2, views, X_site, size, sigma_px,
                  sigma_enc) -> dict:
    """Cramér-Rao bound of the located base pose (see the module docstring; :func:`bench.scenario.bounds.crb`).

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
    # the encoders observe the joints, the lab identification observed the arm errors; the base pose is free
    res = crb(model, sigma_px, {"q": np.eye(6) / sigma_enc**2, "d_eps": np.linalg.inv(cov_eps_dot)})
    cov = res["cov"][:6, :6]
    return {"cov": cov, "pos_bound_m": float(np.sqrt(np.trace(cov[3:, 3:]))),
            "rot_bound_rad": float(np.sqrt(np.trace(cov[:3, :3]))), "observations": res["observations"]}


def mc_ideal_estimator(robot, eps_true, kept, cov_eps_dot, mount, camera: CameraModel, T_site_b2, views, names,
                       X_site, sigma_px, encoders, rng: np.random.Generator, trials: int = 30, method: str = "svd",
                       ransac: dict | None = None, refine="pose") -> dict:
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
        res = locate(kmap, obs[n_survey], obs[n_survey + 1], method=method, rng=rng, refine=refine, **(ransac or {}))
        if not res.success:
            fails += 1
            continue
        pos.append(np.linalg.norm(res.T_world_base[:3, 3] - T_site_b2[:3, 3]))
        rot.append(rotation_angle(res.T_world_base[:3, :3].T @ T_site_b2[:3, :3]))
    pos, rot = np.array(pos), np.array(rot)
    return {"pos_rms_m": float(np.sqrt(np.mean(pos**2))) if len(pos) else float("nan"),
            "rot_rms_rad": float(np.sqrt(np.mean(rot**2))) if len(rot) else float("nan"),
            "trials": trials, "failures": fails}
