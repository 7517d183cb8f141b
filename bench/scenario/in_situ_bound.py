"""How well could the base have been found at all? The Cramér-Rao bound of the in-situ localisation and a Monte Carlo
of the ideal estimator (evaluator side: reads the truth). The generic parts - the true optics, ideal features, the
measured keypoint noise (:func:`keypoint_sigma_px`) and the bound's machinery - are in :mod:`bench.scenario.bounds`
(re-exported here).

* :func:`crb_base_pose` - the Cramér-Rao lower bound on the located base pose: Fisher information of every
  observation the ideal estimator would have (each map point in the reference, surrounding and locate views, pixel
  noise sigma: the survey's, and the locate views' own, :func:`track_noise_on_surface`; optionally each view's
  polynomial keypoint error field, to cubic order in the view's own modes, as a nuisance under its measured prior),
  with the joint angles of every view as nuisance parameters observed by the encoders (sigma_enc), the identified
  arm errors (the 25 of §2.5-2.7) with the identification's covariance as prior (tracker noise) and the 3D points
  as free nuisance parameters (eliminated point by point), optionally the intrinsics and the mount under the lab
  calibrations' covariances and the observation pattern the matching produced; the base's 6 x 6 block of the
  inverse. In water the camera is the best central equivalent of lens + port (:func:`best_central_camera`);
  what no central model removes is the model floor (:func:`model_floor`), reported beside it (docs/bounds.md).
* :func:`mc_joint_bundle` - refine 'joints' (:mod:`bench.vision.joint_bundle`) under exactly the bound's model: the
  check that the estimator reaches the bound.
* :func:`mc_ideal_estimator` - the pipeline's own estimator (map by Eq. 162-164, RANSAC + absolute orientation,
  reprojection refinement) run on ideal features with exactly the noise the bound assumes, over many draws.

Conventions: the site frame is the survey base frame (as in the pipeline); the base pose of the locate parking is
``T_site_b2`` perturbed as ``R' = exp(dphi) R``, ``t' = t + dt`` so that ``dt`` is the base origin's error (the
scored ``base_pos_err_mm``) and ``dphi`` its rotation (``base_rot_err_deg``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from bench.camera.model import CameraModel, check_dist, distort
from bench.geometry.quaternion import matrix_to_rotation_vector, rotation_vector_to_matrix
from bench.geometry.transforms import homogeneous, transform_points
from bench.robot.orientation import link5_frame
from bench.scenario.bounds import (  # noqa: F401 - the generic parts, re-exported for the in-situ scenario
    FIELD_DEGREES,
    Block,
    MultiViewModel,
    best_central_camera,
    crb,
    draw_field,
    field_displacement,
    field_prior_information,
    field_terms,
    ideal_features,
    keypoint_sigma_px,
    measure_field,
    true_projector,
    view_sigma,
)
from bench.vision.insitu import ViewObservation, build_map, locate, locate_pnp
from bench.vision.locate_dataset import normalised


class _Model(MultiViewModel):
    """Pixels of every (view, point) observation as a function of the parameters: blocks ``xi`` (the locate
    parking's base pose, 6), ``q`` (joints, 6 per view), ``d_eps`` (identified arm errors), optionally ``d_K``
    (``dfx, dfy, dcx, dcy`` px: the intrinsics' error, applied to the pixels as ``c + dc + (f + df) / f (uv - c)``,
    exact for a lens whose distortion acts before K), ``d_dist`` (``dk1 dk2 dp1 dp2``, and ``dk3`` with ``k3``)
    and ``d_mount`` (the camera mount's error, a right perturbation
    ``T_mount [[exp(w), v], [0, 1]]``, rad then m), optionally ``field`` (per view: the keypoints' error field of
    order ``field``, :func:`~bench.scenario.bounds.field_displacement`, px), then the points."""

    def __init__(self, robot, eps_true, kept, mount, project, T_site_b2, views, X_site, size, K=None,
                 with_mount=False, vis=None, dist=None, field: int | None = None, k3=False):
        self.robot, self.eps0, self.kept, self.mount = robot, eps_true, kept, mount
        self.T_b2 = T_site_b2
        self.q0 = np.array([q for q, _ in views])
        self.locate = np.array([loc for _, loc in views], dtype=bool)
        self.K = None if K is None else np.asarray(K, float)
        self.dist = None if dist is None else check_dist(dist)  # given: d_dist (k1 k2 p1 p2 [k3]) is a block
        self.with_mount = bool(with_mount)
        blocks = [Block("xi", 6), Block("q", 6, per_view=True), Block("d_eps", len(kept))]
        values = [np.zeros(6), self.q0, np.zeros(len(kept))]
        if self.K is not None:
            blocks.append(Block("d_K", 4, step=1e-3))
            values.append(np.zeros(4))
        if self.dist is not None:
            if self.K is None:
                raise ValueError("a distortion block needs the intrinsics K")
            nd = 5 if k3 else 4
            blocks.append(Block("d_dist", nd, step=1e-5))
            values.append(np.zeros(nd))
        elif k3:
            raise ValueError("k3 is a block with the distortion's (dist)")
        if self.with_mount:
            blocks.append(Block("d_mount", 6))
            values.append(np.zeros(6))
        self.field, self.size = field is not None, size
        if self.field:
            n = 2 * field_terms(field)
            blocks.append(Block("field", n, per_view=True, step=1e-3))
            values.append(np.zeros((len(self.q0), n)))
        super().__init__(self._poses, blocks, values, X_site, project, size, vis=vis)

    def _split(self, values):
        xi, q, d_eps, *rest = values
        d_K = rest.pop(0) if self.K is not None else None
        d_dist = rest.pop(0) if self.dist is not None else None
        d_mount = rest.pop(0) if self.with_mount else None
        return xi, q, d_eps, d_K, d_dist, d_mount

    def _poses(self, *values):  # the camera poses: every block but the field
        return self._kinematics(values[:len(values) - self.field])

    def _kinematics(self, values):
        xi, q, d_eps, _, _, d_mount = self._split(values)
        eps = self.eps0.copy()
        eps[self.kept] += d_eps
        T_b2 = self.T_b2.copy()
        T_b2[:3, :3] = rotation_vector_to_matrix(xi[:3]) @ T_b2[:3, :3]
        T_b2[:3, 3] += xi[3:]
        mount = self.mount
        if d_mount is not None:
            mount = mount @ homogeneous(rotation_vector_to_matrix(d_mount[:3]), d_mount[3:])
        T_site_cam = link5_frame(self.robot, q, eps) @ mount  # (V, 4, 4)
        T_site_cam[self.locate] = T_b2 @ T_site_cam[self.locate]
        return T_site_cam

    def pixels(self, *args):
        uv = super().pixels(*args)
        *values, X = args
        if self.field:  # each view's keypoints moved by its field, evaluated where they are imaged
            *values, fields = values
            uv = self._camera_pixels(uv, values, X)
            return uv + field_displacement(uv, fields[:, None, :], self.size)
        return self._camera_pixels(uv, values, X)

    def _camera_pixels(self, uv, values, X):
        _, _, _, d_K, d_dist, _ = self._split(values)
        if d_dist is not None:  # the lens's k1 k2 p1 p2 [k3] moved by d_dist: the pixel change, exactly
            T_cam_world = np.linalg.inv(self._kinematics(values))
            p = np.matmul(X, np.swapaxes(T_cam_world[:, :3, :3], 1, 2)) + T_cam_world[:, None, :3, 3]
            x = p[..., :2] / p[..., 2:3]
            moved = self.dist + (np.r_[d_dist, 0.0] if len(d_dist) == 4 else d_dist)
            uv = uv + (distort(x, moved) - distort(x, self.dist)) @ self.K[:2, :2].T
        if d_K is None:
            return uv
        f, c = np.array([self.K[0, 0], self.K[1, 1]]), self.K[:2, 2]
        return c + d_K[2:] + (1 + d_K[:2] / f) * (uv - c)


def observation_pattern(kmap, n_views: int, locate_idx, n_locate: int = 2) -> np.ndarray:
    """``vis (n_views, M)``: which view observed which map point, as the matching found it - every point in the
    reference (row 0), in the surrounding views that contributed to it (``kmap.observations``, rows 1..K) and in the
    ``n_locate`` locate views (the last rows: two for the two-view solve, one for PnP) where the final solve used it
    (``locate_idx``, map indices)."""
    vis = np.zeros((n_views, len(kmap)), dtype=bool)
    vis[0] = True
    for i, (views, _) in enumerate(kmap.observations):
        vis[1 + np.asarray(views, int), i] = True
    vis[n_views - n_locate:, np.asarray(locate_idx, int)] = True
    return vis


def _robust_sd(a) -> float:
    a = np.asarray(a, float).ravel()
    return float(1.4826 * np.median(np.abs(a - np.median(a))))


def fisher_factor(errors, components: int = 3, iterations: int = 200) -> float:
    """How much less a pixel tells than the robust sigma says: ``sigma_F / sigma_robust`` of 2-D errors (N, 2).

    The Cramér-Rao bound of a location under noise of density ``f`` has the per-axis Fisher information
    ``I = E[(d log f / dx)^2]`` where a Gaussian of sigma ``s`` has ``1 / s^2``; ``sigma_F = I^(-1/2)`` is the sigma of
    the Gaussian that carries as much. ``f`` is a zero-mean isotropic Gaussian scale mixture ``sum pi_k N(0, s_k^2 I)``
    fitted by EM (the keypoints' errors: a core and heavier tails), ``I`` its integral in the radius; the robust sigma
    is 1.4826 MAD over both axes, the bound's statistic (:func:`track_noise_on_surface`). 1 for Gaussian errors; above 1
    when the tails take information from the core, below 1 when rare, far tails widen the robust sigma beyond the
    core's; NaN for fewer than 20 errors or exact ones."""
    e = np.asarray(errors, float).reshape(-1, 2)
    r2 = np.sum(e**2, axis=1)
    s_rob = _robust_sd(e) if len(e) >= 20 else 0.0
    if not s_rob > 1e-6:  # px: exact pixels to rounding, no shape to measure
        return float("nan")
    s2 = (s_rob * np.geomspace(1.0, 6.0, components)) ** 2
    pi = np.full(components, 1.0 / components)

    def density(r2_, pi_, s2_):  # (N, K) pi_k N_k(r), 2-D
        return pi_ / (2 * np.pi * s2_) * np.exp(-np.asarray(r2_)[:, None] / (2 * s2_))

    for _ in range(iterations):  # EM
        post = density(r2, pi, s2)
        post /= np.maximum(post.sum(axis=1, keepdims=True), 1e-300)
        pi = np.maximum(post.mean(axis=0), 1e-12)
        s2 = np.maximum((post * r2[:, None]).sum(axis=0) / (2 * np.maximum(post.sum(axis=0), 1e-12)), 1e-6 * s_rob**2)
    r = np.linspace(0.0, 12.0 * np.sqrt(s2.max()), 20001)[1:]
    N = density(r**2, pi, s2)
    f = N.sum(axis=1)
    score = r * (N / s2).sum(axis=1) / f  # |grad log f|
    information = 0.5 * np.trapezoid(2 * np.pi * r * f * score**2, r)  # per axis: half of E|grad log f|^2
    return float(1.0 / np.sqrt(information) / s_rob)


def surface_points(uv_ref, T_world_ref, lens: CameraModel, port, surface) -> np.ndarray:
    """Where the rays of pixels ``uv_ref (N, 2)`` of a camera at ``T_world_ref`` (the true ``lens``, behind the flat
    ``port`` if any) first meet ``surface`` (``first_hits``): world points (N, 3), NaN where a ray misses (evaluator
    side: the true surface point of a detected keypoint)."""
    from bench.camera.flatport import trace_rays

    dirs = lens.unproject(np.asarray(uv_ref, float))
    origins = np.zeros_like(dirs)
    if port is not None:
        origins, dirs, _ = trace_rays(dirs, port)
    R, t = np.asarray(T_world_ref, float)[:3, :3], np.asarray(T_world_ref, float)[:3, 3]
    return surface.first_hits(origins @ R.T + t, dirs @ R.T)


def track_noise_on_surface(uv_ref, survey, uv_locate, T_world_ref, T_world_survey, T_world_locate, lens: CameraModel,
                           port, project, surface, field_order: int = 1) -> dict:
    """The survey's and the locate views' own keypoint noise, measured on the scene's true surfaces (evaluator side).

    A locate view sees the panel from the other parking, so SIFT may place a keypoint differently there than in the
    survey views that made the map (the detector's response to the changed foreshortening and shading). For each track
    (map point), the reference keypoint's ray (the true ``lens``, the flat ``port`` if any, the reference's true pose)
    meets ``surface`` (``first_hits(origins, directions)``, e.g. :class:`bench.scenario.scene_points.SceneRays`) at
    ``P``; ``P`` through the true optics (``project``) into each view that observed the track gives its true pixel,
    and detected minus true is that observation's own error - nothing fitted hides any of it.

    * ``survey_px``: robust sigma (1.4826 MAD per axis) of the survey views' errors about each track's survey mean,
      times ``sqrt(n / (n - 1))`` for the mean's degrees of freedom (``n`` survey views per track, on average);
    * ``locate_px``: robust sigma of the locate views' errors about the same mean, less the mean's own variance
      ``survey_px^2 / n``;
    * ``ratio`` = ``locate_px / survey_px``; ``points``: the tracks measured (a ray that misses the surface, or a
      track seen in fewer than two survey views, is left out);
    * ``survey_fisher``, ``locate_fisher``: :func:`fisher_factor` of the survey's and the locate views' errors (within
      5 px, the gross mismatches left out), what the bound's robust sigmas take for the information lost to the
      tails;
    * ``field_px`` (field_order + 1,), ``field_views``: the errors' field per view, of order ``field_order`` (every
      survey and locate view, :func:`~bench.scenario.bounds.measure_field`'s ``degree_px``): what moves a whole
      view's keypoints together.

    Parameters
    ----------
    uv_ref : ndarray (N, 2)
        The tracks' reference keypoints (px, as detected).
    survey : list of N (ndarray (n_i,) int, ndarray (n_i, 2))
        Each track's survey views (indices into ``T_world_survey``) and its keypoints there (px).
    uv_locate : ndarray (N, L, 2)
        Its keypoints in the L locate views (px).
    T_world_ref, T_world_survey, T_world_locate : ndarray (4, 4), (K, 4, 4), (L, 4, 4)
        The true camera poses.
    """
    from bench.geometry.transforms import invert

    P = surface_points(uv_ref, T_world_ref, lens, port, surface)

    def error(T_world_cam, uv, point):
        return np.asarray(uv, float) - project(transform_points(invert(T_world_cam), point[None]))[0]

    dev_survey, dev_locate, n_views = [], [], []
    field = ([], [], [], [])  # every error, its pixel, view (the locate views after the survey's) and shrink
    n_survey = len(T_world_survey)
    for j in np.flatnonzero(np.all(np.isfinite(P), axis=1)):
        views, uv = survey[j]
        uv = np.asarray(uv, float).reshape(-1, 2)
        e = np.array([error(T_world_survey[k], x, P[j]) for k, x in zip(views, uv, strict=True)])
        if len(e) < 2:
            continue
        mean = e.mean(axis=0)
        dev_survey.append(e - mean)
        n_views.append(len(e))
        loc = [error(T, x, P[j]) - mean for T, x in zip(T_world_locate, uv_locate[j], strict=True)]
        dev_locate += loc
        for d, x, v, s in ((e - mean, uv, views, 1 - 1 / len(e)),
                           (np.reshape(loc, (-1, 2)), uv_locate[j], n_survey + np.arange(len(loc)), 1 + 1 / len(e))):
            field[0].append(d)
            field[1].append(x)
            field[2].append(np.asarray(v))
            field[3].append(np.full(len(d), s))
    if not n_views:
        return {"survey_px": float("nan"), "locate_px": float("nan"), "ratio": float("nan"), "points": 0,
                "survey_fisher": float("nan"), "locate_fisher": float("nan"),
                "field_px": np.full(field_order + 1, np.nan), "field_views": 0}
    n = float(np.mean(n_views))
    s_survey = _robust_sd(np.concatenate(dev_survey)) * np.sqrt(n / (n - 1))
    s_locate = float(np.sqrt(max(_robust_sd(dev_locate) ** 2 - s_survey**2 / n, 0.0)))
    dev_survey, dev_locate = np.concatenate(dev_survey), np.asarray(dev_locate, float)
    fisher = [fisher_factor(d[np.linalg.norm(d, axis=1) < 5.0]) for d in (dev_survey, dev_locate)]
    fld = measure_field(*(np.concatenate(f) for f in field), lens.size, order=field_order)
    return {"survey_px": s_survey, "locate_px": s_locate, "ratio": s_locate / s_survey if s_survey > 0 else np.nan,
            "points": len(n_views), "survey_fisher": fisher[0], "locate_fisher": fisher[1],
            "field_px": fld["degree_px"], "field_views": fld["views"]}


def detected_pixels(observation: ViewObservation, x_n) -> np.ndarray:
    """The pixels (N, 2) the detector returned for normalized keypoints ``x_n (N, 2)`` of ``observation``: each
    looked up among the view's own (``ViewObservation.x_n``, the nearest)."""
    d = np.linalg.norm(observation.x_n[None] - np.asarray(x_n, float).reshape(-1, 1, 2), axis=2)
    return observation.features.uv[d.argmin(axis=1)]


def track_pixels(kmap, used, observations: dict, reference: str, survey: list, locate: list) -> tuple:
    """The detected pixels of the tracks the final solve used, for :func:`track_noise_on_surface`: ``(uv_ref (N, 2),
    [(survey view indices, uv (n_i, 2))] * N, uv_locate (N, L, 2))``. ``used`` is the result's ``(map indices, x_a,
    x_b)`` (PnP: ``x_b`` None, one locate view); each normalized keypoint is looked up among its view's
    (``ViewObservation.x_n``) to give the pixel the detector returned (:func:`detected_pixels`)."""
    def pixels(name, x):
        return detected_pixels(observations[name], x)

    idx = np.asarray(used[0], int)
    uv_ref = observations[reference].features.uv[np.asarray(kmap.ref_index)[idx]]
    tracks = []
    for i in idx:
        views, xs = kmap.observations[i]
        xs = np.asarray(xs, float).reshape(-1, 2)
        tracks.append((np.asarray(views, int), np.array([pixels(survey[k], x)[0] for k, x in zip(views, xs,
                                                                                                   strict=True)])))
    uv_locate = np.stack([pixels(name, x) for name, x in zip(locate, used[1:1 + len(locate)], strict=True)], axis=1)
    return uv_ref, tracks, uv_locate


def crb_base_pose(robot, eps_true, kept, cov_eps_dot, mount, project, T_site_b2, views, X_site, size, sigma_px,
                  sigma_enc, cov_K=None, K=None, cov_mount=None, vis=None, cov_K_mount=None, dist=None,
                  cov_dist=None, cov_K_dist=None, cov_dist_mount=None, field=None, k3_sd=None) -> dict:
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
    sigma_px : float or ndarray (V,)
        Pixel noise (px, per axis): every view's, or one per view (the survey's and the locate views' own,
        :func:`track_noise_on_surface`).
    sigma_enc : float
        Encoder noise (rad, per joint, quantisation included).
    cov_K : ndarray (4, 4), optional
        Covariance (px^2) of the calibrated ``fx, fy, cx, cy`` (the lab calibration's own); with ``K`` (3, 3) the
        true central camera's intrinsics. Omitted: the intrinsics are exact.
    cov_mount : ndarray (6, 6), optional
        Covariance of the calibrated mount (right perturbation: rotation vector rad, then m). Omitted: exact.
    vis : ndarray (V, M) bool, optional
        The observation pattern (:func:`observation_pattern`); default every point in every view it projects into.
    field : ndarray (order + 1,), optional
        Each degree's sd (px) of every view's keypoint error field in the view's own modes (offset, slope, ... to
        the order; :func:`~bench.scenario.bounds.measure_field`'s ``degree_px``, measured by
        :func:`track_noise_on_surface`): each view's field a nuisance parameter under that prior
        (:func:`~bench.scenario.bounds.field_prior_information` at the view's observed keypoints), on top of the
        white ``sigma_px``. Omitted (or all zero): the keypoints' errors are white.
    k3_sd : float, optional
        With a (4, 4) ``cov_dist``: the lens's k3 is unknown to the estimator too, under that prior standard
        deviation (the joint bundle refines it, :func:`bench.vision.joint_bundle.lab_prior`). Omitted: k3 is the
        camera's, exact - unless ``cov_dist`` is (5, 5), the lab's covariance with k3 (and the cross-covariances
        then 4 x 5 and 5 x 6).

    Returns
    -------
    dict
        ``cov (6, 6)`` (rotation vector rad, then base origin m), ``pos_bound_m``, ``rot_bound_rad``,
        ``observations``.
    """
    from bench.vision.joint_bundle import distortion_block_size, lab_prior

    with_K = cov_K is not None
    k3_sd = k3_sd if cov_dist is not None else None
    model = _Model(robot, np.asarray(eps_true, float), np.asarray(kept), mount, project, T_site_b2, views, X_site,
                   size, K=K if with_K else None, with_mount=cov_mount is not None, vis=vis,
                   dist=dist if cov_dist is not None else None,
                   field=len(field) - 1 if field is not None and np.any(field) else None,
                   k3=distortion_block_size(cov_dist, k3_sd) == 5)
    # the encoders observe the joints, the lab identification observed the arm errors, the lab calibrations the
    # intrinsics, the distortion and the mount (one joint prior over those given); the base pose is free
    priors = {"q": np.eye(6) / sigma_enc**2, "d_eps": np.linalg.inv(cov_eps_dot)}
    names = tuple(n for n, C in (("d_K", cov_K), ("d_dist", cov_dist), ("d_mount", cov_mount)) if C is not None)
    if names:
        priors[names] = np.linalg.inv(lab_prior(cov_K, cov_dist, cov_mount, cov_K_dist, cov_K_mount, cov_dist_mount,
                                                k3_sd))
    if model.field:  # each view's modes at the keypoints it observes (of points seen twice: those that inform)
        uv = model.pixels(*model.values0, model.X0)
        inform = model.vis & (model.vis.sum(axis=0) >= 2)
        priors["field"] = np.stack([_field_information(uv[v, inform[v]], field, size) for v in range(len(views))])
    res = crb(model, sigma_px, priors)
    cov = res["cov"][:6, :6]
    return {"cov": cov, "pos_bound_m": float(np.sqrt(np.trace(cov[3:, 3:]))),
            "rot_bound_rad": float(np.sqrt(np.trace(cov[:3, :3]))), "observations": res["observations"]}


def _field_information(uv, field, size) -> np.ndarray:
    """The prior information of a view's field at its keypoints ``uv`` (:func:`~bench.scenario.bounds.
    field_prior_information`); a view whose keypoints do not resolve the field's modes has none (fixed at zero)."""
    try:
        return field_prior_information(uv, field, size)
    except ValueError:
        return np.eye(2 * field_terms(len(field) - 1)) * 1e12


def _drawn_field(rng, uv, field, size) -> np.ndarray:
    """The displacement (N, 2) px of a field drawn for a view's keypoints ``uv`` (:func:`~bench.scenario.bounds.
    draw_field`); none where the keypoints do not resolve its modes."""
    try:
        return field_displacement(uv, draw_field(rng, uv, field, size), size)
    except ValueError:
        return np.zeros_like(np.asarray(uv, float))


def _estimate(obs, is_loc, method, rng, refine, ransac, focal_px):
    """The pipeline's estimator on the views ``obs`` (reference, surrounding, then the locate views): the map from
    the survey views, then the two-view solve (:func:`~bench.vision.insitu.locate`) for two locate views, or PnP
    (:func:`~bench.vision.insitu.locate_pnp`, seeded from ``rng`` when it is an int) for one."""
    n_survey = int(np.sum(~is_loc))
    kmap = build_map(obs[0], obs[1:n_survey])
    if len(obs) - n_survey == 1:
        seed = rng if isinstance(rng, (int, np.integer)) else int(rng.integers(2**31))
        return locate_pnp(kmap, obs[n_survey], focal_px=focal_px, rng_seed=seed)
    return locate(kmap, obs[n_survey], obs[n_survey + 1], method=method, rng=rng, refine=refine, **(ransac or {}))


def model_floor(robot, eps_true, mount, lens: CameraModel, port, T_site_b2, views, names, X_site, method="svd",
                ransac: dict | None = None, refine="bundle", rng=None, central=None, profile=None) -> dict:
    """The model floor: the base error the pipeline's estimator leaves on *noise-free* features through the true
    optics (lens, flat port, a realistic ``profile``'s static warp), with exact joints, arm errors and the best
    central camera model
    (:func:`best_central_camera` over the points' depths; its mount the true one moved onto that camera). Without a
    port it is ~0 (the central model is exact); with one it is what no central camera model removes.

    ``central = (camera, T_lens_central)`` replaces the best central camera (e.g. the lab's calibrated camera and
    its mount: what *that* model leaves on noise-free features). ``views``, ``names`` as :func:`mc_ideal_estimator`.
    Returns ``pos_m``, ``rot_rad`` (NaN when the localisation fails) and the error ``xi`` (6,: :func:`pose_error`),
    the central camera's RMS pixel misfit over the observations, ``misfit_px``, the central ``camera`` and
    ``T_lens_central`` (4, 4).
    """
    q_true = np.array([q for q, _ in views])
    is_loc = np.array([loc for _, loc in views], dtype=bool)
    T_site_cam = link5_frame(robot, q_true, eps_true) @ mount
    T_site_cam[is_loc] = T_site_b2 @ T_site_cam[is_loc]
    depths = np.concatenate([transform_points(np.linalg.inv(T), X_site)[:, 2] for T in T_site_cam])
    central, T_lens_c = (best_central_camera(lens, port, (float(np.min(depths)), float(np.max(depths))),
                                             profile=profile) if central is None else central)
    project = true_projector(lens, port, profile)
    obs, misfit = [], []
    for k, name in enumerate(names):
        f, x_n = normalised(ideal_features(X_site, T_site_cam[k], project, lens.size), central)
        obs.append(ViewObservation(name, f, x_n, link5_frame(robot, q_true[k], eps_true) @ mount @ T_lens_c))
        uv_c = central.project(transform_points(np.linalg.inv(T_site_cam[k] @ T_lens_c), X_site))
        misfit.append(np.linalg.norm(uv_c[:len(X_site)] - project(transform_points(np.linalg.inv(T_site_cam[k]),
                                                                                   X_site)), axis=1))
    res = _estimate(obs, is_loc, method, rng if rng is not None else 0, refine, ransac, central.fx)
    m = np.concatenate(misfit)
    out = {"misfit_px": float(np.sqrt(np.nanmean(m**2))), "pos_m": float("nan"), "rot_rad": float("nan"),
           "xi": np.full(6, np.nan), "camera": central, "T_lens_central": T_lens_c}
    if res.success:
        out["xi"] = pose_error(res.T_world_base, T_site_b2)
        out["pos_m"], out["rot_rad"] = float(np.linalg.norm(out["xi"][3:])), float(np.linalg.norm(out["xi"][:3]))
    return out


def pose_error(T_est, T_true) -> np.ndarray:
    """The error (6,) of a base pose in the bound's convention (module docstring): ``R_est = exp(dphi) R_true``,
    ``t_est = t_true + dt``; rotation vector (rad), then m."""
    return np.r_[matrix_to_rotation_vector(np.asarray(T_est)[:3, :3] @ np.asarray(T_true)[:3, :3].T),
                 np.asarray(T_est)[:3, 3] - np.asarray(T_true)[:3, 3]]


def mc_ideal_estimator(robot, eps_true, kept, cov_eps_dot, mount, camera: CameraModel, T_site_b2, views, names,
                       X_site, sigma_px, encoders, rng: np.random.Generator, trials: int = 30, method: str = "svd",
                       ransac: dict | None = None, refine="pose", ins=None, field=None) -> dict:
    """RMS base error of the pipeline's estimator on ideal features with the bound's noise, over ``trials`` draws.

    Each draw: pixel noise ``sigma_px`` on exact projections (``camera``: the true central camera), encoder readings
    drawn by ``encoders`` (an :class:`~bench.sim.encoders.EncoderModel`), arm errors drawn from the identification
    covariance; intrinsics and mount exact. ``views`` as for :func:`crb_base_pose` (``names``: reference first, then
    the surrounding views, then the locate views: two for the two-view solve, one for PnP). ``ins``, a
    :class:`~bench.vision.tilt.TiltUpdate`: each draw's error fused with a draw of the INS's tilt. ``field``
    (order + 1,), the keypoint error field's sd per degree (:func:`crb_base_pose`): each draw adds a field drawn
    per view for its keypoints (:func:`~bench.scenario.bounds.draw_field`).
    """
    q_true = np.array([q for q, _ in views])
    is_loc = np.array([loc for _, loc in views], dtype=bool)
    L = np.linalg.cholesky(cov_eps_dot)
    T_site_cam_true = link5_frame(robot, q_true, eps_true) @ mount
    T_site_cam_true[is_loc] = T_site_b2 @ T_site_cam_true[is_loc]
    sigma = view_sigma(sigma_px, len(views))
    errs, fails = [], 0
    for _ in range(trials):
        eps = np.array(eps_true, float)
        eps[kept] += L @ rng.normal(size=len(kept))
        q_read = encoders.read(q_true, rng)
        obs = []
        for k, name in enumerate(names):
            f = ideal_features(X_site, T_site_cam_true[k], camera.project, camera.size, sigma[k], rng)
            if field is not None:
                f = dataclasses.replace(f, uv=f.uv + _drawn_field(rng, f.uv, field, camera.size))
            obs.append(ViewObservation(name, f, camera.undistort_pixels(f.uv), link5_frame(robot, q_read[k], eps)
                                       @ mount))
        res = _estimate(obs, is_loc, method, rng, refine, ransac, camera.fx)
        if not res.success:
            fails += 1
            continue
        errs.append(pose_error(res.T_world_base, T_site_b2))
    return _mc_summary(errs, trials, fails, ins, rng)


def mc_joint_bundle(robot, eps_true, kept, cov_eps_dot, mount, camera: CameraModel, T_site_b2, views, X_site, vis,
                    sigma_px, sigma_enc, rng: np.random.Generator, trials: int = 20, cov_K=None,
                    cov_mount=None, refine: bool = True, cov_K_mount=None, cov_dist=None, cov_K_dist=None,
                    cov_dist_mount=None, ins=None, field=None, k3_sd=None) -> dict:
    """RMS base error of ``refine: joints`` (:func:`bench.vision.joint_bundle.joint_bundle`) under exactly the
    bound's model, over ``trials`` draws: the check that the estimator reaches :func:`crb_base_pose`.

    Each draw: exact projections through the central ``camera`` of the points ``X_site`` in the pattern ``vis``
    (V, M) plus Gaussian noise ``sigma_px``; joint readings ``q_true + N(0, sigma_enc)``; the arm errors, and with
    ``cov_K`` / ``cov_dist`` / ``cov_mount`` the intrinsics, the distortion and the mount, drawn jointly from their
    calibrations' covariances (with the cross-covariances given) and given to the estimator as its (wrong by that
    much) calibration, which it refines under those priors (``refine``) or keeps; with ``field``, every view's
    keypoints also moved by a field drawn for it (the estimator does not model it). Arguments as
    :func:`crb_base_pose`; ``ins`` as :func:`mc_ideal_estimator`'s. Returns ``pos_rms_m``, ``rot_rms_rad``,
    ``trials``, ``failures``.
    """
    from bench.vision.joint_bundle import distortion_block_size, joint_bundle, lab_prior

    q_true = np.array([q for q, _ in views])
    is_loc = np.array([loc for _, loc in views], dtype=bool)
    T_site_cam = link5_frame(robot, q_true, eps_true) @ mount
    T_site_cam[is_loc] = T_site_b2 @ T_site_cam[is_loc]
    vis = np.asarray(vis, bool)
    use = vis.sum(axis=0) >= 2
    vis, X = vis[:, use], np.asarray(X_site, float)[use]
    view, point = np.nonzero(vis)
    uv0 = np.concatenate([camera.project(transform_points(np.linalg.inv(T_site_cam[v]), X[point[view == v]]))
                          for v in range(len(views))])
    order = np.concatenate([np.flatnonzero(view == v) for v in range(len(views))])
    view, point = view[order], point[order]
    sigma = view_sigma(sigma_px, len(views))
    L_eps = np.linalg.cholesky(cov_eps_dot)
    k3_sd = k3_sd if cov_dist is not None else None
    nd = distortion_block_size(cov_dist, k3_sd)  # the distortion's coefficients drawn and refined: k1 k2 p1 p2 [k3]
    lab = lab_prior(cov_K, cov_dist, cov_mount, cov_K_dist, cov_K_mount, cov_dist_mount, k3_sd)
    L_lab = None if lab is None else np.linalg.cholesky(lab)
    priors = dict(cov_K=cov_K, cov_mount=cov_mount, cov_K_mount=cov_K_mount, cov_dist=cov_dist,
                  cov_K_dist=cov_K_dist, cov_dist_mount=cov_dist_mount, k3_sd=k3_sd) if refine else {}
    errs, fails = [], 0
    for _ in range(trials):
        eps = np.array(eps_true, float)
        eps[kept] += L_eps @ rng.normal(size=len(kept))
        d = [] if L_lab is None else list(L_lab @ rng.normal(size=len(lab)))  # K, dist, mount: those given
        K, dist, m = camera.K.copy(), check_dist(camera.dist), mount.copy()
        if cov_K is not None:
            dK, d = d[:4], d[4:]
            K[0, 0] += dK[0]
            K[1, 1] += dK[1]
            K[:2, 2] += dK[2:]
        if cov_dist is not None:
            dist[:nd] += d[:nd]
            d = d[nd:]
        if cov_mount is not None:
            m = m @ homogeneous(rotation_vector_to_matrix(np.array(d[:3])), d[3:])
        q_read = q_true + rng.normal(0, sigma_enc, q_true.shape)
        uv = uv0 + rng.normal(0, 1.0, uv0.shape) * sigma[view][:, None]
        if field is not None:
            uv = uv + np.concatenate([_drawn_field(rng, uv0[view == v], field, camera.size)
                                      for v in range(len(views))])
        jb = joint_bundle(robot, eps, m, q_read, is_loc, T_site_b2, view, point, uv, X, sigma_enc,
                          float(sigma.min()), K, dist, gate=None, **priors)
        if not jb.success:
            fails += 1
            continue
        errs.append(pose_error(jb.T_site_base, T_site_b2))
    return _mc_summary(errs, trials, fails, ins, rng)


def _mc_summary(errs, trials: int, fails: int, ins=None, rng=None) -> dict:
    """A Monte Carlo's RMS base position (m) and rotation (rad) errors over its successful draws' errors ``errs``
    (:func:`pose_error`), each fused with a draw of the INS's tilt by ``ins`` (a
    :class:`~bench.vision.tilt.TiltUpdate`) when given."""
    e = np.reshape(np.asarray(errs, float), (-1, 6))
    if ins is not None and len(e):
        e = ins.error(e, rng)
    return {"pos_rms_m": float(np.sqrt(np.mean(np.sum(e[:, 3:] ** 2, axis=1)))) if len(e) else float("nan"),
            "rot_rms_rad": float(np.sqrt(np.mean(np.sum(e[:, :3] ** 2, axis=1)))) if len(e) else float("nan"),
            "trials": trials, "failures": fails}
