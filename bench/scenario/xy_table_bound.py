"""How well could each camera position of the x-y table experiments (Tables 5-8, 11-14) have been found at all? The
Cramér-Rao bound of every estimate and a Monte Carlo of the ideal estimator (evaluator side: reads the truth; the
machinery is :mod:`bench.scenario.bounds`, shared with the in-situ scenario).

An estimate of the experiment is the position of camera ``a`` of a pair ``(a, b)`` at intraocular distance ``d_o``
relative to the reference camera, in the table's axes (:mod:`bench.vision.xy_table_positioning`). Its bound
(:func:`position_bound`) is the Cramér-Rao bound of ``g = c_a - c_ref`` (true camera centres) from the noise in
the simulation:

* the pixels of every 3D point in every view the estimate uses - the reference, the views of its map ``1p`` and the
  pair - where the pipeline's matching found it (the reference keypoint matched in that view), with the
  localisation noise of the features *measured* against the truth (:func:`measured_sigma_px`: SIFT keypoints by
  their distance from the true epipolar curves, target corners against their true projections);
* the table's readings, as the simulated table makes them (:class:`~bench.sim.scenes.xy_table.TableModel`): it
  moves in steps of its resolution and reports the step it is at, and the carriage is off that step by its
  positioning errors - scale, backlash (the sequence of moves decides where it applies), orthogonality, wobble,
  drawn at random per campaign (:func:`~bench.sim.scenes.xy_table.random_table_errors`). Those nine parameters
  are nuisance parameters with that distribution's covariance as prior (:func:`table_error_prior`; with
  ``sim.table_readout = exact`` the readings are the carriage's positions and only orthogonality and wobble
  remain). A per-view quantisation noise of ``res^2 / 12`` is *not* in the simulation: the reading is the step;
* every 3D point free (eliminated point by point);
* the pair's displacement free (6 parameters, about camera ``a``'s centre): what vision has to find, as the base
  pose of the in-situ localisation; the pair's relative pose comes from its readings.

**The complete bound** (:class:`Unknowns`, the scenario's default) adds what the experiment does not know exactly
besides the table: the intrinsics ``fx, fy, cx, cy`` under the covariance of the camera calibration the pipeline ran
on the rig views (§5.2.1), and the camera's rotation ``R0`` on its support, which the thesis's search (Eq. 197-198)
estimates from the same images (free), and the distortion's ``k1, k2, p1, p2`` under the prior the pipeline states
(its bundle's, ``pipeline.bundle_distortion_sigma``: a pin-hole calibration tells nothing about them), and the camera
centre on the stage under the tolerance ``table.yaml`` states. **Exact in the bound**: the housing's glass (the true
optics project). What no central
camera model removes of the true optics is the **model floor** (:func:`floor_positions`): the estimator on noise-free
features, reported beside the bound; the limit is their root-sum-square.

Linearisation point: the true camera poses (the table's true errors, the true ``R0`` and centre); the points where
the pipeline's map put them, moved into the true reference camera frame.

:func:`mc_ideal_positions` runs the scenario's own estimator (map, ``2p``, RANSAC + LMS + error-ratio elimination)
on exact projections of the same points in the same views with Gaussian pixel noise of the measured sigma, on
tables with errors drawn as the simulator draws them, given the true camera, ``R0`` and centre (with a port, the
lens alone: the pipeline's camera model is central) - the check of the bound and the cost of the thesis's estimator.
"""

from __future__ import annotations

import functools
import sys
from dataclasses import dataclass

import numpy as np

from bench.camera.model import distortion_parameter_jacobian, thin_prism_parameter_jacobian
from bench.geometry.quaternion import matrix_to_rotation_vector, rotation_vector_to_matrix
from bench.geometry.transforms import homogeneous, invert, transform_points
from bench.scenario.bounds import (
    Block,
    MultiViewModel,
    best_central_camera,
    crb,
    function_jacobian,
    ideal_features,
    keypoint_sigma_px,
    point_sigma_px,
    true_projector,
)
from bench.vision.insitu import build_map, one_per_detection
from bench.vision.xy_table_positioning import (
    R0_PRIOR_DEG,
    PositioningConfig,
    TableSpec,
    estimate_positions,
    map_view_names,
)

#: the table's error parameters (:class:`~bench.sim.scenes.xy_table.TableErrors`; the wobble as its two components)
TABLE_ERRORS = ("scale_x", "scale_z", "scale_rot", "backlash_x_m", "backlash_z_m", "backlash_rot_rad",
                "orthogonality_rad", "wobble_c_rad", "wobble_s_rad")
#: those that reach the camera when the readings are the carriage's positions (``sim.table_readout = exact``)
GEOMETRY_ERRORS = ("orthogonality_rad", "wobble_c_rad", "wobble_s_rad")


def table_error_vector(errors) -> np.ndarray:
    """:class:`~bench.sim.scenes.xy_table.TableErrors` (or its ``truth.yaml`` dict) -> ``(9,)`` in
    :data:`TABLE_ERRORS` order (wobble amplitude and phase as ``w cos(phase), w sin(phase)``)."""
    e = errors if isinstance(errors, dict) else errors.__dict__
    w, ph = e["wobble_rad"], e["wobble_phase_rad"]
    return np.array([e["scale_x"], e["scale_z"], e["scale_rot"], e["backlash_x_m"], e["backlash_z_m"],
                     e["backlash_rot_rad"], e["orthogonality_rad"], w * np.cos(ph), w * np.sin(ph)], dtype=float)


def _table_errors(v):
    from bench.sim.scenes.xy_table import TableErrors

    return TableErrors(*v[:7], wobble_rad=float(np.hypot(v[7], v[8])), wobble_phase_rad=float(np.arctan2(v[8], v[7])))


@functools.lru_cache(maxsize=4)
def table_error_prior(names=TABLE_ERRORS, draws: int = 4000) -> np.ndarray:
    """Covariance of the table errors ``names`` as the simulator draws them (4000 draws of
    :func:`~bench.sim.scenes.xy_table.random_table_errors`, fixed seed): the bound's prior, without restating the
    simulator's ranges."""
    from bench.sim.scenes.xy_table import random_table_errors

    rng = np.random.default_rng(20081)
    v = np.array([table_error_vector(random_table_errors(rng)) for _ in range(draws)])
    idx = [TABLE_ERRORS.index(n) for n in names]
    cov = np.cov(v[:, idx].T)
    cov.flags.writeable = False  # cached: shared by every caller
    return cov


class TableKinematics:
    """True camera poses of a campaign as a function of the table's errors (the simulator's own table model).

    Parameters
    ----------
    truth : dict
        ``truth.yaml`` of the dataset (the campaign's steps or readings in the order visited, the camera's offset on
        the stage and its true mount ``T_mount_cam``).
    names : list of str
        The campaign's view names in the order visited.
    """

    def __init__(self, truth: dict, names):
        from bench.sim.scenes.xy_table import NO_ERRORS, TableModel

        self.names = list(names)
        self.exact = truth.get("table_readout", "steps") == "exact"
        self.table = TableModel(NO_ERRORS, camera_offset_m=truth["camera_offset_m"])
        self.steps = np.array(truth["steps"])
        self.read = np.array(truth["read"])
        self.T_mount_cam = np.array(truth["T_mount_cam"])
        self.params = GEOMETRY_ERRORS if self.exact else TABLE_ERRORS
        v = table_error_vector(truth["table_errors"])
        self.v0 = v[[TABLE_ERRORS.index(n) for n in self.params]]
        self._cache = {}

    def poses(self, v) -> np.ndarray:
        """``T_table_cam (N, 4, 4)`` of the campaign's views for the error parameters ``v`` (``self.params``)."""
        v = np.asarray(v, dtype=float)
        key = v.tobytes()
        if key not in self._cache:
            if len(self._cache) > 64:
                self._cache.clear()
            self._cache[key] = self._poses(v)
        return self._cache[key].copy()

    def _poses(self, v) -> np.ndarray:
        if self.exact:  # the readings are the true axis positions: only the table's geometry is unknown
            orth, c, s = v
            rot = self.read[:, 2]
            wobble = np.stack([c * np.cos(rot) - s * np.sin(rot), s * np.cos(rot) + c * np.sin(rot)], -1)
            T = self.table.mount_pose(self.read, wobble, orth)
        else:
            self.table.errors = _table_errors(v)
            T = self.table.run(self.steps).T_table_mount
        return T @ self.T_mount_cam


def model_poses(kin: TableKinematics) -> dict:
    """``{view: T_table_cam}`` at the true table errors (equal to the truth's camera poses)."""
    return dict(zip(kin.names, kin.poses(kin.v0), strict=True))


def measured_sigma_px(result, features: str, T_true: dict, lens, project, truth: dict, reference: str,
                      config=None, port=None) -> tuple:
    """Localisation noise of the pipeline's features (px, per image axis) against the truth and its sample size.

    ``features = "sift"``: :func:`~bench.scenario.bounds.keypoint_sigma_px` on the reference keypoints' matches
    (``result`` a :class:`~bench.vision.xy_table_positioning.PositioningResult`); ``"corners"``: the extracted
    corners against the true projections of the rig's corners of the same id
    (:func:`~bench.scenario.bounds.point_sigma_px`). ``T_true``: the true camera poses; ``port``: the true flat
    port (the reference rays are traced through it; ``None`` for a camera in air).
    """
    obs = result.observations
    if features == "corners":
        p_table = transform_points(np.array(truth["T_table_reference"]), np.array(truth["reference_corners"]))
        det, ref = [], []
        for n, o in obs.items():
            ids = np.argmax(o.features.descriptors, axis=1)
            det.append(o.features.uv)
            ref.append(project(transform_points(invert(T_true[n]), p_table[ids])))
        sigma, _, n = point_sigma_px(np.concatenate(det), np.concatenate(ref))
        return sigma, n
    others = [n for n in obs if n != reference]
    return keypoint_sigma_px(obs[reference], [obs[n] for n in others], T_true, lens, project, config=config,
                             matches=[result.reference_matches[n] for n in others], port=port)


def map_points(result, reference: str, T_table_ref, names_for_map) -> tuple:
    """The points of the largest map (reference + ``names_for_map``) in the table frame and, per view, which of them
    the matching found there: ``(X (M, 3), {view: seen (M,) bool})``. The map is built as the pipeline builds it
    (its views' poses from the readings and the estimated ``R0``) and moved by the true reference pose
    ``T_table_ref``. Each detection counts once (:func:`~bench.vision.insitu.one_per_detection`)."""
    obs, rm = result.observations, result.reference_matches
    kmap = build_map(obs[reference], [obs[n] for n in names_for_map], matches=[rm[n] for n in names_for_map])
    one, merge = one_per_detection(kmap)  # each detection once: SIFT's twin keypoints (one pixel) are one measurement
    seen = {reference: np.ones(len(one), bool),  # the others found where either twin was
            **{n: np.isin(kmap.ref_index, m.i1) @ merge for n, m in rm.items()}}
    return transform_points(T_table_ref, kmap.p_ref[one]), seen


class _PairModel(MultiViewModel):
    """Pixels in the views of one estimate: blocks ``xi`` (the pair's displacement about camera ``a``'s centre:
    rotation vector, then translation), ``table`` (the table's errors, :class:`TableKinematics`), optionally
    ``d_R0`` (the camera's rotation on its support, a right perturbation ``R0 exp(w)`` about its centre, rad) and
    ``d_K`` (``dfx, dfy, dcx, dcy`` px, applied to the pixels as ``c + dc + (f + df) / f (uv - c)`` with ``K`` the
    true lens's: exact for a lens whose distortion acts before K) and ``d_dist`` (``dk1, dk2, dp1, dp2``, and with
    ``n_dist = 8`` the thin prism's ``s1..s4`` (:func:`bench.camera.model.thin_prism`), applied to
    the pixels to first order as ``K d distort(x_n) / d(k1, k2, p1, p2) d_dist`` at the points' pinhole coordinates
    ``x_n``: exact in the derivative for a lens in air, the in-water direction behind a port) and ``d_o`` (the camera
    centre on the stage, m, in the mount frame), then the points."""

    def __init__(self, kin: TableKinematics, views, locate, pivot, X, project, size, vis, K=None,
                 with_R0: bool = False, K_lens=None, with_offset: bool = False, n_dist: int = 4):
        self.kin, self.idx = kin, np.array([kin.names.index(n) for n in views])
        self.locate, self.pivot = np.asarray(locate, bool), np.asarray(pivot, float)
        self.K, self.with_R0 = (None if K is None else np.asarray(K, float)), bool(with_R0)
        self.K_lens = None if K_lens is None else np.asarray(K_lens, float)
        self.with_offset = bool(with_offset)
        blocks, values = [Block("xi", 6)], [np.zeros(6)]
        if kin.params:
            blocks.append(Block("table", len(kin.params), step=1e-8))
            values.append(kin.v0)
        if self.with_R0:
            blocks.append(Block("d_R0", 3))
            values.append(np.zeros(3))
        if self.K is not None:
            blocks.append(Block("d_K", 4, step=1e-3))
            values.append(np.zeros(4))
        if self.K_lens is not None:
            blocks.append(Block("d_dist", n_dist, step=1e-6))
            values.append(np.zeros(n_dist))
        if self.with_offset:
            blocks.append(Block("d_o", 3))
            values.append(np.zeros(3))
        super().__init__(self._poses, blocks, values, X, project, size, vis)

    def _split(self, values):
        xi, *rest = values
        v_table = rest.pop(0) if self.kin.params else None
        d_R0 = rest.pop(0) if self.with_R0 else None
        d_K = rest.pop(0) if self.K is not None else None
        d_dist = rest.pop(0) if self.K_lens is not None else None
        d_o = rest.pop(0) if self.with_offset else None
        return xi, v_table, d_R0, d_K, d_dist, d_o

    def _poses(self, *values):
        xi, v_table, d_R0, _, _, d_o = self._split(values)
        T = self.kin.poses(self.kin.v0 if v_table is None else v_table)[self.idx]
        if d_o is not None:  # the centre moved in the mount frame: R_table_mount d_o
            T[:, :3, 3] += (T[:, :3, :3] @ self.kin.T_mount_cam[:3, :3].T) @ d_o
        if d_R0 is not None:
            T[:, :3, :3] = T[:, :3, :3] @ rotation_vector_to_matrix(d_R0)
        R = rotation_vector_to_matrix(xi[:3])
        T[self.locate] = homogeneous(R, self.pivot + xi[3:] - R @ self.pivot) @ T[self.locate]
        return T

    def pixels(self, *args):
        uv = super().pixels(*args)
        *values, X = args
        _, _, _, d_K, d_dist, _ = self._split(values)
        if d_dist is not None:
            T_cam_world = np.linalg.inv(self.camera_poses(*values))
            p = np.matmul(X, np.swapaxes(T_cam_world[:, :3, :3], 1, 2)) + T_cam_world[:, None, :3, 3]  # (V, M, 3)
            x_n = (p[..., :2] / p[..., 2:3]).reshape(-1, 2)
            J = distortion_parameter_jacobian(x_n)
            if len(d_dist) == 8:  # and the thin prism's s1..s4
                J = np.concatenate([J, thin_prism_parameter_jacobian(x_n)], axis=-1)
            uv = uv + np.einsum("ij,vmjk,k->vmi", self.K_lens[:2, :2], J.reshape(*p.shape[:2], 2, -1), d_dist)
        if d_K is None:
            return uv
        f, c = np.array([self.K[0, 0], self.K[1, 1]]), self.K[:2, 2]
        return c + d_K[2:] + (1 + d_K[:2] / f) * (uv - c)


@dataclass(frozen=True)
class Unknowns:
    """What an estimate does not know exactly besides the table's errors (the complete bound).

    ``cov_K`` (4, 4): the covariance (px^2) of the intrinsics ``fx, fy, cx, cy`` from the camera calibration the
    pipeline ran on the rig views (:attr:`~bench.camera.calibration.CalibrationResult.covariance`), ``K`` the true
    lens's (where the pixels are perturbed); ``None``: the intrinsics exact. ``R0_free``: the camera's rotation on its
    support is estimated from the same images (the thesis's search, Eq. 197-198), a free parameter of the bound, with
    a loose prior of :data:`~bench.vision.xy_table_positioning.R0_PRIOR_DEG` (the pipeline's bundle uses the same) that
    only holds the rotation about the line of camera centres (which no image of a straight campaign sees and no
    camera position depends on). ``cov_dist`` (4, 4): the covariance of the distortion's ``k1, k2, p1, p2`` the
    pipeline states (its bundle's prior: a pin-hole calibration says nothing about them); ``None``: exact.
    ``offset_sigma`` (3,): the stated tolerance (1 sigma, m) of the camera centre on the stage (``table.yaml``'s
    ``camera_offset_tolerance_mm``); ``None``: exact.
    """

    K: np.ndarray | None = None
    cov_K: np.ndarray | None = None
    R0_free: bool = False
    cov_dist: np.ndarray | None = None
    offset_sigma: np.ndarray | None = None

    def __post_init__(self):
        if (self.cov_K is not None or self.cov_dist is not None) and self.K is None:
            raise ValueError("Unknowns: the intrinsics' or the distortion's prior needs K (the true lens's)")

    def model_kwargs(self) -> dict:
        return {"K": self.K if self.cov_K is not None else None, "with_R0": self.R0_free,
                "K_lens": self.K if self.cov_dist is not None else None, "with_offset": self.offset_sigma is not None,
                "n_dist": 4 if self.cov_dist is None else len(self.cov_dist)}

    def priors(self) -> dict:
        out = {}
        if self.cov_K is not None:
            out["d_K"] = np.linalg.inv(np.asarray(self.cov_K, float))
        if self.cov_dist is not None:
            out["d_dist"] = np.linalg.inv(np.asarray(self.cov_dist, float))
        if self.offset_sigma is not None:
            out["d_o"] = np.diag(1.0 / np.square(np.asarray(self.offset_sigma, float)))
        if self.R0_free:
            out["d_R0"] = np.eye(3) / np.deg2rad(R0_PRIOR_DEG) ** 2
        return out


def position_bound(kin: TableKinematics, prior_info, reference: str, pair, map_views, X, seen: dict, project, size,
                   sigma_px: float, shared=None, unknowns: Unknowns | None = None, g_jacobians: dict | None = None
                   ) -> dict:
    """Cramér-Rao bound of one estimate (module docstring): camera ``pair[0]``'s position relative to the reference.

    Parameters
    ----------
    kin : TableKinematics
    prior_info : ndarray (k, k)
        Information of the prior on the table's errors (``inv(table_error_prior(kin.params))``).
    reference : str
    pair : (a, b)
    map_views : list of str
        The views of this estimate's map ``1p`` (besides the reference).
    X : ndarray (M, 3)
        Points (table frame); ``seen`` ``{view: (M,) bool}`` where the features found them.
    project : callable
        True optics, camera frame -> pixels.
    size : (w, h)
    sigma_px : float
        Pixel noise (px, per axis).
    shared : (views, J, Jp), optional
        :meth:`~bench.scenario.bounds.MultiViewModel.jacobian_blocks` of a model of ``views`` without a displaced
        pair (and the same ``unknowns``): the rows of the table errors and the points do not depend on the pair, so
        the experiment computes them once (:func:`experiment_bounds`) and only the pair's displacement is
        differentiated here (undisplaced at the linearisation point, the pair's other columns are the shared ones).
    unknowns : Unknowns, optional
        The intrinsics' and the camera rotation's uncertainty (the complete bound); default: both exact.
    g_jacobians : dict, optional
        ``{a: G}``, the derivative of the estimated quantities by the parameters per camera ``a``, filled and
        re-used across the pairs of one experiment (the same reference, views and unknowns).

    Returns
    -------
    dict
        ``cov_pos (3, 3)`` (m^2, table axes), ``cov_rot (3, 3)`` (rad^2, camera ``a``'s orientation),
        ``observations``, ``points``.
    """
    a, b = pair
    unknowns = Unknowns() if unknowns is None else unknowns
    views = [reference, *map_views, a, b]
    T0 = model_poses(kin)
    model = _PairModel(kin, views, [n in (a, b) for n in views], T0[a][:3, 3], X, project, size,
                       np.stack([seen[n] for n in views]), **unknowns.model_kwargs())
    jac = None
    if shared is not None:
        names, J_all, Jp_all = shared
        idx = [names.index(n) for n in views]
        loc = _PairModel(kin, [a, b], [True, True], T0[a][:3, 3], X, project, size, np.stack([seen[a], seen[b]]),
                         **unknowns.model_kwargs())
        J = J_all[idx]
        # at the linearisation point the pair is not displaced (xi = 0), so its rows by every other block are the
        # shared model's: only the displacement's columns are new
        xi = slice(loc.column("xi", 0), loc.column("xi", 0) + 6)
        J[-2:, ..., xi] = loc.jacobian_blocks(*loc.values0, X, only=("xi",), points=False)[0][..., xi]
        jac = (J, Jp_all[idx])
    ia = len(views) - 2
    Ra0 = T0[a][:3, :3]

    def g(*values):
        T = model.camera_poses(*values)
        return np.r_[T[ia, :3, 3] - T[0, :3, 3], matrix_to_rotation_vector(T[ia, :3, :3] @ Ra0.T)]

    # G depends on the pair through camera a only (its pose and the pivot; undisplaced, b and the map do not enter)
    G = g_jacobians.get(a) if g_jacobians is not None else None
    if G is None:
        G = function_jacobian(model, g)
        if g_jacobians is not None:
            g_jacobians[a] = G
    priors = {"table": prior_info} if kin.params else {}
    res = crb(model, sigma_px, {**priors, **unknowns.priors()}, G, jac)
    cov = res["cov_g"]
    return {"cov_pos": cov[:3, :3], "cov_rot": cov[3:, 3:], "observations": res["observations"],
            "points": res["points"]}


def experiment_bounds(result, kin: TableKinematics, config: PositioningConfig, X, seen, project, size,
                      sigma_px: float, verbose: bool = False, unknowns: Unknowns | None = None) -> dict:
    """The bound of every pair of the experiment: ``{(d_mm, a, b): position_bound(...)}`` (the same views as the
    pipeline: :func:`~bench.vision.xy_table_positioning.map_view_names` minus the pair)."""
    unknowns = Unknowns() if unknowns is None else unknowns
    names = list(result.observations)
    centres = np.stack([result.T_table_cam[n][:3, 3] for n in names])
    prior = np.linalg.inv(table_error_prior(kin.params)) if kin.params else None
    base = _PairModel(kin, names, np.zeros(len(names), bool), np.zeros(3), X, project, size,
                      np.stack([seen[n] for n in names]), **unknowns.model_kwargs())
    shared = (names, *base.jacobian_blocks(*base.values0, X))
    out, g_jacobians = {}, {}
    n_all = sum(len(p) for p in result.pairs.values())
    for d_mm, plist in result.pairs.items():
        for a, b in plist:
            used = map_view_names(names, centres, config.reference, (a, b), config.map_min_baseline_m,
                                  config.map_exclude)
            if used:
                out[(d_mm, a, b)] = position_bound(kin, prior, config.reference, (a, b), used, X, seen, project,
                                                   size, sigma_px, shared, unknowns, g_jacobians)
            if verbose:
                print(f"\r  bound: {len(out)}/{n_all} estimates", end="", file=sys.stderr)
    if verbose:
        print(file=sys.stderr)
    return out


def mc_ideal_positions(kin: TableKinematics, X, seen: dict, camera, spec: TableSpec, R0, config: PositioningConfig,
                       sigma_px: float, rng: np.random.Generator, trials: int, table_errors: bool = True,
                       project=None) -> dict:
    """Errors of the scenario's estimator on ideal features (module docstring) over ``trials`` draws.

    Each draw: the table's errors as the simulator draws them (none if ``table_errors`` is false), the true camera
    poses and the readings the table then gives, exact projections of ``X`` where ``seen`` with Gaussian noise
    ``sigma_px`` through ``camera`` (a central camera: the true lens, which also undistorts the keypoints), the true
    camera centre on the support (``spec``) and rotation ``R0``. Returns ``{d_mm: (K, 3) errors (m)}`` of the
    successful estimates of ``config.methods`` pooled over the draws, and ``"failures"``. ``project``: the pixels
    through other optics than ``camera`` (the model floor, :func:`floor_positions`), from the true lens poses. The
    errors are of the true lens centres, as :func:`bench.scenario.xy_table.score` scores the run's estimates.
    """
    from bench.sim.scenes.xy_table import NO_ERRORS, TableModel, random_table_errors

    names = kin.names
    out, fails = {}, 0
    for _ in range(trials):
        table = TableModel(random_table_errors(rng) if table_errors else NO_ERRORS, kin.table.camera_offset_m)
        run = table.run(kin.steps)
        T = dict(zip(names, run.T_table_mount @ kin.T_mount_cam, strict=True))
        read = {n: r for n, r in zip(names, run.true if kin.exact else run.read, strict=True) if n in seen}
        feats = {n: ideal_features(np.where(seen[n][:, None], X, np.nan), T[n], project or camera.project,
                                   camera.size, sigma_px, rng) for n in read}
        res = estimate_positions(feats, read, camera, spec, config, R0=R0)
        c_ref = T[config.reference][:3, 3]
        for c in res.combinations:
            if not c.success:
                fails += 1
                continue
            out.setdefault(round(c.d_m * 1e3, 6), []).append(c.p_table - (T[c.a][:3, 3] - c_ref))
    return {**{d: np.array(e) for d, e in out.items()}, "failures": fails}


def floor_positions(kin: TableKinematics, X, seen: dict, lens, port, profile, spec: TableSpec, R0,
                    config: PositioningConfig) -> tuple:
    """The model floor of every estimate: the scenario's estimator on *noise-free* features through the true optics
    (``lens``, the flat ``port`` or None, a realistic imaging ``profile``'s static warp or None), the table exact (no
    errors: its readings are the carriage's positions), and as the pipeline's camera the best central camera over
    the points' depths (:func:`~bench.scenario.bounds.best_central_camera`) with its pose in the lens frame: its
    centre on the stage and its rotation there are the true lens's (``spec``, ``R0``) moved onto it, as the in-situ
    floor moves the mount. Scored, as the run is, against the true *lens* centres: a central camera's centre is
    the port's virtual one (a flat glass plate moves it ~``t (1 - 1/n)`` along the axis, 4.5 mm for the underwater
    preset), so its estimate of camera ``a``'s displacement differs from the lens's by ``(R_a - R_ref) t``, which no
    image tells a central model. ~0 without a port and warp (a central model is exact); with them, what no central
    camera model removes.

    Returns ``({d_mm: (K, 3) errors (m)}, failures, misfit_px)``: the estimates' errors as
    :func:`mc_ideal_positions` gives them, and the central camera's RMS pixel misfit over the observations.
    """
    T0 = model_poses(kin)
    depths = np.concatenate([transform_points(invert(T0[n]), X[seen[n]])[:, 2] for n in seen if n in T0])
    central, T_lc = best_central_camera(lens, port, (float(depths.min()), float(depths.max())), profile=profile)
    project = true_projector(lens, port, profile)
    R0 = np.asarray(R0, float)
    spec_c = TableSpec(np.asarray(spec.camera_offset_m, float) + R0 @ T_lc[:3, 3], spec.travel_m, spec.resolution_m,
                       spec.resolution_rad)  # the central camera's centre on the stage
    out = mc_ideal_positions(kin, X, seen, central, spec_c, R0 @ T_lc[:3, :3], config, 0.0,
                             np.random.default_rng(0), 1, table_errors=False, project=project)
    fails = out.pop("failures")
    T_cl = invert(T_lc)
    miss = np.concatenate([np.linalg.norm(central.project(transform_points(T_cl, p)) - project(p), axis=1)
                           for p in (transform_points(invert(T0[n]), X[seen[n]]) for n in seen if n in T0)])
    return out, fails, float(np.sqrt(np.nanmean(miss**2)))
