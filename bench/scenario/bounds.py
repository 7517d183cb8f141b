"""Cramér-Rao bounds of camera localisation from pixels - one implementation for every scenario that finds camera
poses from features (evaluator side: reads the truth). Used by :mod:`bench.scenario.in_situ_bound` (the TA-40's base
pose) and :mod:`bench.scenario.xy_table_bound` (the x-y table's camera positions).

* :func:`true_projector` - pixels of camera-frame points through the *true* optics (lens, and the flat port where
  there is one): what a perfect feature detector would report.
* :func:`best_central_camera` - the central camera closest to the true optics over a depth range (what no central
  model removes is the model floor).
* :func:`ideal_features` - exact projections of a fixed set of 3D points with a unique descriptor per point (perfect
  correspondences), optionally with Gaussian pixel noise.
* :func:`keypoint_sigma_px` - SIFT localisation noise measured against the truth (distance from the true epipolar
  curves); :func:`point_sigma_px` - the same for features whose true projections are known (target corners).
* :class:`MultiViewModel` - the pixels of M 3D points in V views whose camera poses are a function of parameter
  blocks, each block either shared by all views (a base pose, arm errors) or one per view (joint or table readings);
  its Jacobian by block central differences: a shared block's coordinate ``c`` at once for every row, a per-view
  block's coordinate ``c`` of every view at once (the rows of view ``v`` depend on its own parameters only), point
  coordinate ``c`` of every point at once (the rows of point ``m`` depend on that point only).
* :func:`reduced_information` - the Fisher information of every observed (view, point) pixel (Gaussian noise,
  ``sigma_px`` per image axis) with the 3D points eliminated point by point (each point's 3 x 3 block: the Schur
  complement that bundle adjustment calls the reduced camera system; every point is a free nuisance parameter).
* :func:`crb` - that information plus the priors of the nuisance parameters (encoders, an identification, a table's
  errors), inverted: the bound on the covariance of any unbiased estimator of the parameters, or of a function
  ``g`` of them (``G C G^T``, ``G`` its Jacobian by :func:`function_jacobian`).
* :func:`ml_estimate` - the estimator the bound is attained by for small noise: maximum likelihood (a bundle
  adjustment over every parameter and point, priors included), by ``scipy.optimize.least_squares``; the tests'
  reference.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.optimize

from bench.camera.model import CameraModel
from bench.geometry.quaternion import rotation_vector_to_matrix
from bench.geometry.transforms import invert, transform_points
from bench.vision.features import Features
from bench.vision.insitu import MapConfig, ViewObservation, reference_matches
from bench.vision.keypoint_field import (  # noqa: F401 - re-exported: the bound's field is the localisation's
    FIELD_DEGREES,
    FIELD_UNIT_PX,
    field_basis,
    field_degrees,
    field_displacement,
    field_modes,
    field_order,
    field_terms,
    mode_sd,
    monomial_modes,
)

DESCRIPTOR_SEED = 20061  # fixed: the same 3D point has the same descriptor in every view and every draw


# ------------------------------------------------------------------------------------------------ the true optics


def true_projector(camera: CameraModel, port=None, profile=None):
    """``project(p_cam (..., 3)) -> uv (..., 2)`` through the true lens ``camera`` and, if given, the flat ``port``
    (:func:`bench.camera.flatport.lens_port_projector`), and with a realistic imaging ``profile``
    (:class:`bench.sim.imaging.ImagingProfile`) its static geometric warp: the thin prism of its ``distortion``
    stage, ``d = ((s1 r^2 + s2 r^4) fx, (s3 r^2 + s4 r^4) fy)`` in the lens's normalized coordinates
    (:class:`bench.sim.imaging.ImagingChain`; evaluated at the ideal pixel: the chain's inverse warp is smooth, the
    difference ~1e-4 px). Per-frame effects (rolling shutter under camera shake) and lateral chromatic aberration
    (|c| < 1e-4) are not in it."""
    from bench.camera.flatport import lens_port_projector

    base = lens_port_projector(camera, port)
    if profile is None or not profile.on("distortion"):
        return base
    s1, s2, s3, s4 = profile["distortion"]["thin_prism"]
    K = camera.K

    def project(p_cam):
        uv = base(p_cam)
        x, y = (uv[..., 0] - K[0, 2]) / K[0, 0], (uv[..., 1] - K[1, 2]) / K[1, 1]
        r2 = x**2 + y**2
        return uv + np.stack([(s1 * r2 + s2 * r2**2) * K[0, 0], (s3 * r2 + s4 * r2**2) * K[1, 1]], axis=-1)

    return project


def best_central_camera(lens: CameraModel, port, depth_range, n: int = 3000, rng=None, profile=None) -> tuple:
    """The central camera closest to lens + flat ``port`` over a depth range: ``(camera, T_lens_central (4, 4))``.

    Least squares over ``fx, fy, cx, cy, k1, k2, k3`` and the central camera's pose in the lens frame (rotation
    vector, centre) of the pixel difference between the central projection and the true one (lens + port) for
    ``n`` points spread over the image at depths ``depth_range`` (m): what a calibration on noise-free data at
    those ranges would find at best. Without a port: the lens itself, identity. A realistic imaging ``profile``
    adds its static warp to the true optics (:func:`~bench.scenario.bounds.true_projector`).
    """
    if port is None and (profile is None or not profile.on("distortion")):
        return lens, np.eye(4)
    rng = np.random.default_rng(0) if rng is None else rng
    true = true_projector(lens, port, profile)
    mag = port.n_water / port.n_air if port is not None else 1.0
    K0 = lens.K.copy()
    K0[:2, :2] *= mag
    x_max = (lens.width / 2) / K0[0, 0]
    y_max = (lens.height / 2) / K0[1, 1]
    z = rng.uniform(*depth_range, n)
    p = np.c_[rng.uniform(-x_max, x_max, n) * z, rng.uniform(-y_max, y_max, n) * z, z]
    uv = true(p)
    w, h = lens.size
    ok = np.all(np.isfinite(uv), axis=1) & (uv[:, 0] > 0) & (uv[:, 0] < w - 1) & (uv[:, 1] > 0) & (uv[:, 1] < h - 1)
    p, uv = p[ok], uv[ok]
    d0 = np.r_[lens.dist, np.zeros(5 - len(lens.dist))] if len(lens.dist) < 5 else np.array(lens.dist, float)

    def camera(x):
        K = K0.copy()
        K[0, 0], K[1, 1], K[0, 2], K[1, 2] = x[:4]
        d = d0.copy()
        d[[0, 1, 4]] = x[4:7]
        return lens.replace(K=K, dist=d, name="best central camera")

    def pose(x):
        T = np.eye(4)  # T_lens_central
        T[:3, :3], T[:3, 3] = rotation_vector_to_matrix(x[7:10]), x[10:13]
        return T

    def residual(x):
        T = pose(x)
        p_c = (p - T[:3, 3]) @ T[:3, :3]
        return (camera(x).project(p_c) - uv).ravel()

    z_v = 0.0 if port is None else \
        (port.d0 + port.t) - (port.d0 + port.t * port.n_air / port.n_glass) * port.n_water / port.n_air
    x0 = np.r_[K0[0, 0], K0[1, 1], K0[0, 2], K0[1, 2], d0[[0, 1, 4]], np.zeros(3), 0.0, 0.0, z_v]
    sol = scipy.optimize.least_squares(residual, x0, x_scale=np.r_[np.full(4, 10.0), np.full(3, 0.01), np.full(3, 1e-3),
                                                   np.full(3, 1e-3)], method="lm")
    return camera(sol.x), pose(sol.x)


def ideal_features(p_world, T_world_cam, project, size, noise_px: float = 0.0, rng=None) -> Features:
    """Exact projections of ``p_world (M, 3)`` seen by a camera at ``T_world_cam`` (only those inside the image).

    Point ``j`` always gets descriptor ``j`` (a fixed random unit vector), orientation 0 and size 10 px, so the
    pipeline's ratio test and orientation filter match exactly the same 3D point in every view. Rows of
    ``p_world`` that are NaN (points a view does not see) are left out of that view and keep the indices of the
    others.
    """
    p_world = np.asarray(p_world, dtype=float)
    seen = np.all(np.isfinite(p_world), axis=1)
    uv = np.full((len(p_world), 2), np.nan)
    uv[seen] = project(transform_points(invert(T_world_cam), p_world[seen]))
    w, h = size
    ok = np.all(np.isfinite(uv), axis=1)
    ok[ok] = (uv[ok, 0] > 0) & (uv[ok, 0] < w - 1) & (uv[ok, 1] > 0) & (uv[ok, 1] < h - 1)
    idx = np.flatnonzero(ok)
    uv = uv[idx]
    if noise_px > 0:
        uv = uv + rng.normal(0.0, noise_px, uv.shape)
    return point_features(uv, idx, len(p_world))


def point_features(uv, idx, n_points: int) -> Features:
    """Keypoints at pixels ``uv (N, 2)`` of points ``idx (N,)`` among ``n_points``: point ``j`` gets descriptor ``j``
    (a fixed random unit vector, :data:`DESCRIPTOR_SEED`), orientation 0 and size 10 px (:func:`ideal_features`)."""
    desc = np.random.default_rng(DESCRIPTOR_SEED).normal(size=(n_points, 128)).astype(np.float32)
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    n = len(idx)
    return Features(np.asarray(uv, float).reshape(n, 2), np.zeros(n), np.full(n, 10.0), np.ones(n),
                    desc[np.asarray(idx, int)] * 512)


# ------------------------------------------------------------------------------------------------ measured noise


def _epipolar_curve(uv_ref, T_ref_k, rays_ref, project_k, depths):
    """Images in view k of the true rays through ``uv_ref`` (sampled at ``depths`` along them), ``(N, D, 2)``."""
    o, d = rays_ref(uv_ref)  # (N, 3) origins and directions in the reference camera frame
    pts = o[:, None, :] + d[:, None, :] * depths[None, :, None]  # (N, D, 3)
    return project_k(transform_points(invert(T_ref_k), pts))


def keypoint_sigma_px(reference: ViewObservation, views: list, T_world_cam_true: dict, camera_true: CameraModel,
                      project, depth_range=(0.2, 3.0), config: MapConfig | None = None, matches=None,
                      port=None, statistic: str = "robust", gross_px: float = 5.0) -> tuple:
    """Measured SIFT localisation noise (px, 1-sigma per image axis) and the number of matches it is based on.

    The distance of each matched keypoint from the *true* epipolar curve of its reference keypoint (rays through the
    true optics and true camera poses), robust standard deviation over all matches, divided by sqrt(2) (both
    keypoints of a pair are noisy). ``T_world_cam_true`` maps view names to true camera poses; ``camera_true`` (the
    lens) back-projects the reference keypoints, and with a flat ``port`` the rays are traced through it into the
    water (exact, the camera is not central there); ``project`` maps into the other views through the true optics.
    ``matches`` (one :class:`~bench.vision.features.Matches` per view, as
    :func:`~bench.vision.insitu.reference_matches` gives them) saves matching again. ``statistic``: ``robust``
    (1.4826 x the median distance: the core of the distribution) or ``rms`` (the root-mean-square distance: the
    variance a least-squares estimator meets, heavy tails included); distances above ``gross_px`` are gross
    mismatches either way and left out.
    """
    if statistic not in ("robust", "rms"):
        raise ValueError(f"statistic: expected 'robust' or 'rms', got {statistic!r}")
    depths = np.geomspace(*depth_range, 400)

    def rays(uv):
        dirs = camera_true.unproject(uv)
        if port is None:
            return np.zeros_like(dirs), dirs
        from bench.camera.flatport import trace_rays

        origin, direction, _ = trace_rays(dirs, port)
        return origin, direction

    d_all = []
    T_wr = T_world_cam_true[reference.name]
    matches = reference_matches(reference, views, config) if matches is None else matches
    for view, m in zip(views, matches, strict=True):
        if len(m) == 0:
            continue
        T_ref_k = invert(T_wr) @ T_world_cam_true[view.name]
        curve = _epipolar_curve(reference.features.uv[m.i1], T_ref_k, rays, project, depths)
        p = view.features.uv[m.i2][:, None, :]
        a, b = curve[:, :-1], curve[:, 1:]
        ab = b - a
        t = np.clip(np.sum((p - a) * ab, axis=-1) / np.maximum(np.sum(ab * ab, axis=-1), 1e-12), 0, 1)
        dist = np.linalg.norm(a + t[..., None] * ab - p, axis=-1)
        d_all.append(np.nanmin(dist, axis=1))
    if not d_all:
        return float("nan"), 0
    d = np.concatenate(d_all)
    d = d[np.isfinite(d) & (d < gross_px)]  # gross mismatches are not localisation noise
    # the distance is |n . (e_k - g e_ref)|: a half-normal of sigma * sqrt(1 + g^2) ~ sigma sqrt(2)
    if statistic == "rms":
        return float(np.sqrt(np.mean(d**2) / 2)) if len(d) else float("nan"), int(len(d))
    return float(np.median(d) / 0.6745 / np.sqrt(2)), int(len(d))


def point_sigma_px(uv_detected, uv_true, gross_px: float = 5.0) -> tuple:
    """Localisation noise (px, 1-sigma per image axis) of features whose true projections are known (target corners):
    robust standard deviation (1.4826 MAD about the median) of the detected minus the true pixels over both axes,
    gross errors (> ``gross_px``) left out; returns ``(sigma_px, bias_px (2,), n)``."""
    r = np.asarray(uv_detected, float) - np.asarray(uv_true, float)
    r = r[np.all(np.isfinite(r), axis=1)]
    r = r[np.linalg.norm(r, axis=1) < gross_px]
    if len(r) < 2:
        return float("nan"), np.full(2, np.nan), int(len(r))
    med = np.median(r, axis=0)
    return float(1.4826 * np.median(np.abs(r - med))), med, int(len(r))


# ------------------------------------------------------------------------------------------------ the bound


@dataclass(frozen=True)
class Block:
    """A block of parameters of a :class:`MultiViewModel`: ``size`` coordinates shared by all views, or ``size`` per
    view (``per_view``); ``step`` is the central-difference step of its coordinates (their unit: m, rad)."""

    name: str
    size: int
    per_view: bool = False
    step: float = 1e-7


class MultiViewModel:
    """Pixels of M 3D points in V views whose camera poses are a function of parameter blocks.

    Parameter vector layout (the columns of :meth:`jacobian` and of the information): the blocks in order (a per-view
    block view by view), then the points (``3 m + c``).

    Parameters
    ----------
    camera_poses : callable
        ``camera_poses(*values) -> T_world_cam (V, 4, 4)``, ``values`` one array per block (shared: ``(size,)``; per
        view: ``(V, size)``): the model's kinematics.
    blocks : list of Block
    values0 : list of ndarray
        The linearisation point, one array per block.
    X0 : ndarray (M, 3)
        The points (world frame).
    project : callable
        Camera-frame points (..., 3) -> pixels (..., 2).
    size : (w, h)
        Image size: an observation exists where the point projects inside the image (``vis``), unless ``vis`` (V, M)
        is given.
    """

    point_step = 1e-6

    def __init__(self, camera_poses, blocks, values0, X0, project, size, vis=None):
        self.camera_poses = camera_poses
        self.blocks = list(blocks)
        self.values0 = [np.asarray(v, dtype=float) for v in values0]
        self.X0 = np.asarray(X0, dtype=float)
        self.project = project
        self.n_views = len(self.camera_poses(*self.values0))
        offsets, n = [], 0
        for b in self.blocks:
            offsets.append(n)
            n += b.size * (self.n_views if b.per_view else 1)
        self.offsets, self.n_params = offsets, n
        uv = self.pixels(*self.values0, self.X0)
        w, h = size
        inside = np.all(np.isfinite(uv), axis=-1) & (uv[..., 0] > 0) & (uv[..., 0] < w - 1) & \
            (uv[..., 1] > 0) & (uv[..., 1] < h - 1)
        self.vis = inside if vis is None else inside & np.asarray(vis, bool)

    def column(self, block: str, coordinate: int, view: int = 0) -> int:
        """Column of ``coordinate`` of ``block`` (of ``view`` for a per-view block) in the parameter vector."""
        i = [b.name for b in self.blocks].index(block)
        b = self.blocks[i]
        return self.offsets[i] + (view * b.size if b.per_view else 0) + coordinate

    def pack(self, values) -> np.ndarray:
        """Block values -> the parameter vector (n_params,)."""
        return np.concatenate([np.asarray(v, float).ravel() for v in values])

    def unpack(self, theta) -> list:
        """The parameter vector (n_params,) -> block values (shared ``(size,)``, per view ``(V, size)``)."""
        out = []
        for b, off in zip(self.blocks, self.offsets, strict=True):
            k = b.size * (self.n_views if b.per_view else 1)
            v = np.asarray(theta[off:off + k], float)
            out.append(v.reshape(self.n_views, b.size) if b.per_view else v)
        return out

    def pixels(self, *args) -> np.ndarray:
        """``pixels(*values, X)`` -> (V, M, 2)."""
        *values, X = args
        T_cam_world = np.linalg.inv(self.camera_poses(*values))
        p_cam = np.matmul(X, np.swapaxes(T_cam_world[:, :3, :3], 1, 2)) + T_cam_world[:, None, :3, 3]  # (V, M, 3)
        return self.project(p_cam)

    def _perturbations(self, values, only=None):
        """``(block index, coordinate, values + e, values - e, step)`` for every block coordinate (all views at once
        for a per-view block); of the blocks named in ``only`` when given."""
        for i, b in enumerate(self.blocks):
            if only is not None and b.name not in only:
                continue
            for c in range(b.size):
                e = np.zeros_like(values[i])
                e[..., c] = b.step
                plus, minus = list(values), list(values)
                plus[i], minus[i] = values[i] + e, values[i] - e
                yield i, c, plus, minus, b.step

    def jacobian_blocks(self, *args, only=None, points: bool = True) -> tuple:
        """``jacobian_blocks(*values, X)`` -> ``(J_par (V, M, 2, n_params), J_pts (V, M, 2, 3))``: d pixels / d
        parameters and d pixels of point m / d point m, by central differences in blocks (class docstring).

        ``only``: the names of the blocks to differentiate (the other columns stay zero); ``points=False``: ``J_pts``
        is None (a caller that has those columns already)."""
        *values, X = args
        V, M = self.n_views, len(X)
        J = np.zeros((V, M, 2, self.n_params))
        for i, c, plus, minus, h in self._perturbations(values, only):
            d = (self.pixels(*plus, X) - self.pixels(*minus, X)) / (2 * h)
            b = self.blocks[i]
            if b.per_view:  # rows of view v depend on the parameters of view v only
                for v in range(V):
                    J[v, :, :, self.offsets[i] + v * b.size + c] = d[v]
            else:
                J[..., self.offsets[i] + c] = d
        if not points:
            return J, None
        Jp = np.zeros((V, M, 2, 3))
        for c in range(3):  # rows of point m depend on X_m only
            dX = np.zeros_like(X)
            dX[:, c] = h = self.point_step
            Jp[..., c] = (self.pixels(*values, X + dX) - self.pixels(*values, X - dX)) / (2 * h)
        return J, Jp

    def jacobian(self, *args) -> np.ndarray:
        """``jacobian(*values, X)``: the dense Jacobian (2 V M, n_params + 3 M), rows ``(view, point, axis)``."""
        J, Jp = self.jacobian_blocks(*args)
        V, M = J.shape[:2]
        out = np.zeros((V, M, 2, self.n_params + 3 * M))
        out[..., :self.n_params] = J
        for m in range(M):
            out[:, m, :, self.n_params + 3 * m:self.n_params + 3 * m + 3] = Jp[:, m]
        return out.reshape(2 * V * M, -1)

    def jacobian_columnwise(self, *args) -> np.ndarray:
        """The dense Jacobian one column at a time (the check of :meth:`jacobian`'s block differences)."""
        *values, X = args
        theta0, M = np.r_[self.pack(values), np.ravel(X)], len(X)

        def f(theta):
            return self.pixels(*self.unpack(theta[:self.n_params]), theta[self.n_params:].reshape(M, 3)).ravel()

        steps = np.r_[np.concatenate([np.full(b.size * (self.n_views if b.per_view else 1), b.step)
                                      for b in self.blocks]), np.full(3 * M, self.point_step)]
        J = np.empty((2 * self.n_views * M, len(theta0)))
        for i, h in enumerate(steps):
            e = np.zeros_like(theta0)
            e[i] = h
            J[:, i] = (f(theta0 + e) - f(theta0 - e)) / (2 * h)
        return J

    def prior_information(self, priors: dict) -> np.ndarray:
        """The priors' information matrix (n_params, n_params) from ``{block name: information}``: a (size, size)
        matrix (a per-view block: the same for every view) or (V, size, size) per view; other blocks are free. A
        tuple of names of blocks that are not per view and lie next to each other takes one joint information
        matrix (a prior with cross-covariances)."""
        info = np.zeros((self.n_params, self.n_params))
        names = [b.name for b in self.blocks]
        for name, P in priors.items():
            if isinstance(name, tuple):
                i = [names.index(n) for n in name]
                if i != list(range(i[0], i[0] + len(i))) or any(self.blocks[k].per_view for k in i):
                    raise ValueError(f"joint prior over {name}: the blocks must be adjacent and not per view")
                off, size = self.offsets[i[0]], sum(self.blocks[k].size for k in i)
                info[off:off + size, off:off + size] += np.asarray(P, dtype=float)
                continue
            i = names.index(name)
            b, off = self.blocks[i], self.offsets[i]
            P = np.asarray(P, dtype=float)
            if not b.per_view:
                info[off:off + b.size, off:off + b.size] += P
                continue
            P = np.broadcast_to(P, (self.n_views, b.size, b.size))
            for v in range(self.n_views):
                s = slice(off + v * b.size, off + (v + 1) * b.size)
                info[s, s] += P[v]
        return info


def _eliminate_points(J, Jp, vis) -> tuple:
    """Normal matrix of the (view, point) rows with every point eliminated (the reduced camera system).

    ``J`` (V, M, 2, n) and ``Jp`` (V, M, 2, 3), already divided by the pixel noise; rows of ``vis == False`` are left
    out, and so are points seen in fewer than two views (they carry no information). Returns ``(S, use)``:
    ``S = A - sum_m B_m C_m^-1 B_m^T`` (n, n), ``use`` (M,) the points used.
    """
    use = vis.sum(axis=0) >= 2
    w = vis[:, use][..., None, None].astype(float)
    J, Jp = J[:, use] * w, Jp[:, use] * w
    V, M, _, n = J.shape
    Jm = J.transpose(1, 0, 2, 3).reshape(M, 2 * V, n)  # rows of point m
    Pm = Jp.transpose(1, 0, 2, 3).reshape(M, 2 * V, 3)
    A = Jm.reshape(-1, n).T @ Jm.reshape(-1, n)
    B = np.swapaxes(Jm, 1, 2) @ Pm  # (M, n, 3)
    Cinv = np.linalg.inv(np.swapaxes(Pm, 1, 2) @ Pm)  # (M, 3, 3), invertible for a point seen in >= 2 views
    S = A - (B @ Cinv).transpose(1, 0, 2).reshape(n, -1) @ B.transpose(1, 0, 2).reshape(n, -1).T
    return 0.5 * (S + S.T), use


def view_sigma(sigma_px, n_views: int) -> np.ndarray:
    """The pixel noise per view ``(V,)`` (px, per axis) from a scalar (every view alike) or a ``(V,)`` sequence;
    each must be finite and > 0."""
    s = np.broadcast_to(np.asarray(sigma_px, float), (n_views,)).copy()
    if not np.all(np.isfinite(s) & (s > 0)):
        raise ValueError(f"sigma_px: expected finite values > 0 (px), got {sigma_px}")
    return s


# ----------------------------------------------------------------------------------------------- the views' error field
# (its basis and modes: bench.vision.keypoint_field, shared with the localisation's covariance)


def field_prior_information(uv, degree_px, size, floor_px: float = 1e-6) -> np.ndarray:
    """The prior information (2 n, 2 n) of a view's monomial field coefficients (u's, then v's; :func:`field_basis`)
    when its mode amplitudes ``a = R c`` (:func:`field_modes` at its keypoints ``uv``) are independent,
    ``N(0, mode_sd^2)`` on each axis: ``R^T diag(1 / sd^2) R`` per axis. A degree measured at zero is known to be
    zero (``floor_px``, numerically so)."""
    sd = np.maximum(mode_sd(degree_px), floor_px)
    R = field_modes(uv, size, len(np.asarray(degree_px)) - 1)
    one = R.T @ np.diag(1.0 / sd**2) @ R
    n = len(sd)
    info = np.zeros((2 * n, 2 * n))
    info[:n, :n] = info[n:, n:] = one
    return info


def draw_field(rng: np.random.Generator, uv, degree_px, size) -> np.ndarray:
    """A view's field (2 n,: monomial coefficients, u's then v's) drawn for its keypoints ``uv (N, 2)``: each mode's
    amplitude ``N(0, mode_sd^2)`` per axis, ``c = R^-1 a`` (:func:`field_modes`)."""
    sd = mode_sd(degree_px)
    R = field_modes(uv, size, len(np.asarray(degree_px)) - 1)
    a = rng.normal(size=(2, len(sd))) * sd
    return np.linalg.solve(R, a.T).T.reshape(-1)


def measure_field(dev, uv, view, shrink, size, order: int = 1, gate: float = 3.5, min_points: int | None = None
                  ) -> dict:
    """The keypoints' error field per view, measured on their errors: the part of the errors that moves a whole view's
    keypoints together (a polynomial of ``order`` over the image per axis: offset, slope, ...), which the white pixel
    noise of the bound does not describe.

    For every view with ``min_points`` (default ``max(20, 3 n)``, ``n`` = :func:`field_terms`) or more errors inside
    ``gate`` robust sigmas (of all the errors, then of the view's errors about a first fit of its field: the gross
    mismatches out, the keypoints the field moves far in), the least-squares field of its errors in the view's own
    orthonormal modes (:func:`field_modes`: ``a = R c``); each amplitude's square less the variance white noise of
    the view's residual scatter gives it (``s^2 / N``), divided by the view's mean ``shrink`` (what subtracting each
    track's mean left of a field: ``1 - 1/n`` in the n views the mean is over, ``1 + 1/n`` in a view outside it).
    Pooled over the views, the two axes and the modes of one degree: each degree's variance - the field's prior
    (:func:`field_prior_information`, :func:`draw_field`: every mode independent). Modes, not monomials: the
    monomials of one view are far from orthogonal over its keypoints, and their coefficients' large, opposed
    scatter is no field's.

    Parameters
    ----------
    dev : ndarray (N, 2)
        The errors (px): detected minus true, about each track's mean.
    uv : ndarray (N, 2)
        Their pixels (px).
    view : ndarray (N,) int
        Their views.
    shrink : ndarray (N,)
        Each error's share of its view's field (above).
    size : (w, h)
    order : int
        The field's order (1 affine, 2 quadratic, 3 cubic).

    Rows whose error or pixel is not finite are left out.

    Returns
    -------
    dict
        ``degree_px`` (order + 1,): each degree's sd, px (a mode's RMS displacement over a view's keypoints; 0 when
        the amplitudes scatter no more than white noise makes them); the same as ``offset_px``, ``slope_px``,
        ``quadratic_px``, ``cubic_px`` (to the order); ``views`` (the views measured; with none, the sds are NaN).
    """
    n = field_terms(order)
    min_points = max(20, 3 * n) if min_points is None else min_points
    dev, uv = np.asarray(dev, float).reshape(-1, 2), np.asarray(uv, float).reshape(-1, 2)
    view, shrink = np.asarray(view), np.asarray(shrink, float)
    ok = np.all(np.isfinite(dev), axis=1) & np.all(np.isfinite(uv), axis=1)  # an error or pixel that is not one
    dev, uv, view, shrink = dev[ok], uv[ok], view[ok], shrink[ok]
    keep = _gated(dev, gate)
    excess, factor = [], []
    for v in np.unique(view):
        m = keep & (view == v)
        if m.sum() < min_points:
            continue
        X = field_basis(uv[view == v], size, order)
        c, *_ = np.linalg.lstsq(X[m[view == v]], dev[m], rcond=None)
        inside = _gated(dev[view == v] - X @ c, gate)  # gated again, about the view's field
        m = np.flatnonzero(view == v)[inside]
        X = X[inside]
        if len(m) < min_points:
            continue
        try:
            R = monomial_modes(X, order)
        except ValueError:  # keypoints that do not resolve the modes measure nothing
            continue
        c, *_ = np.linalg.lstsq(X, dev[m], rcond=None)  # (n, 2): u's, v's
        a = R @ c  # the modes' amplitudes (px)
        s2 = np.sum((dev[m] - X @ c) ** 2) / (2 * (len(m) - n))
        excess.append(a**2 - s2 / len(m))
        factor.append(float(np.mean(shrink[m])))
    if not excess:
        sd = np.full(order + 1, np.nan)
    else:
        e = np.array(excess) / np.array(factor)[:, None, None]  # (views, n, 2)
        deg = field_degrees(order)
        sd = np.array([np.sqrt(max(np.mean(e[:, deg == d]), 0.0)) for d in range(order + 1)])
    out = {"degree_px": sd, "views": len(excess)}
    out.update({f"{name}_px": float(s) for name, s in zip(FIELD_DEGREES, sd, strict=False)})
    return out


def _gated(dev, gate: float) -> np.ndarray:
    """The errors ``dev (N, 2)`` within ``gate`` robust sigmas (1.4826 MAD of both axes' values) of zero."""
    if not len(dev):
        return np.zeros(0, bool)
    return np.linalg.norm(dev, axis=1) < gate * 1.4826 * np.median(np.abs(dev))


def reduced_information(model: MultiViewModel, sigma_px, jacobians=None) -> tuple:
    """Fisher information of every observed pixel (``model.vis``; Gaussian, ``sigma_px`` per axis: a scalar, or one
    per view ``(V,)``) on the model's parameters with every point a free nuisance parameter, eliminated point by
    point (Schur complement of its 3 x 3 block). Points seen in fewer than two views carry no information and are
    left out. ``jacobians``: the model's :meth:`~MultiViewModel.jacobian_blocks` at its linearisation point, when the
    caller has them (assembled from blocks shared between models).

    Returns ``(information (n_params, n_params), observations, points)``: the numbers of (view, point) observations
    and of points used.
    """
    J, Jp = model.jacobian_blocks(*model.values0, model.X0) if jacobians is None else jacobians
    s = view_sigma(sigma_px, model.n_views)[:, None, None, None]
    S, use = _eliminate_points(J / s, Jp / s, model.vis)
    return S, int(model.vis[:, use].sum()), int(use.sum())


def crb(model: MultiViewModel, sigma_px, priors: dict, G=None, jacobians=None) -> dict:
    """The Cramér-Rao bound: ``cov`` = inverse of (the pixels' reduced information + the priors' information).
    ``sigma_px``: the pixel noise, one for every view or one per view (:func:`reduced_information`).

    ``priors`` as :meth:`MultiViewModel.prior_information`; the sum must be positive definite (every parameter
    observed by the pixels or by a prior). With ``G`` (k, n_params), the bound on a function ``g`` of the
    parameters (``G = dg/dtheta``, :func:`function_jacobian`): ``cov_g = G cov G^T``. ``jacobians`` as for
    :func:`reduced_information`.

    Returns
    -------
    dict
        ``cov`` (n_params, n_params), ``cov_g`` (k, k) when ``G`` is given, ``observations``, ``points``.
    """
    info, n_obs, n_pts = reduced_information(model, sigma_px, jacobians)
    info = info + model.prior_information(priors)
    cov = np.linalg.inv(info)
    cov = 0.5 * (cov + cov.T)
    out = {"cov": cov, "observations": n_obs, "points": n_pts}
    if G is not None:
        G = np.atleast_2d(G)
        out["cov_g"] = G @ cov @ G.T
    return out


def function_jacobian(model: MultiViewModel, g) -> np.ndarray:
    """``G = d g(*values) / d parameters`` (k, n_params) at the linearisation point, by central differences with the
    blocks' steps (a per-view block view by view)."""
    values = model.values0
    g0 = np.atleast_1d(g(*values))
    G = np.zeros((len(g0), model.n_params))
    for i, b in enumerate(model.blocks):
        for v in range(model.n_views if b.per_view else 1):
            for c in range(b.size):
                e = np.zeros_like(values[i])
                if b.per_view:
                    e[v, c] = b.step
                else:
                    e[c] = b.step
                plus, minus = list(values), list(values)
                plus[i], minus[i] = values[i] + e, values[i] - e
                G[:, model.column(b.name, c, v)] = (np.atleast_1d(g(*plus)) - np.atleast_1d(g(*minus))) / (2 * b.step)
    return G


#: least_squares' method in :func:`ml_estimate`: "trf" (a LAPACK SVD of the dense Jacobian per step) was as fast as
#: MINPACK's "lm" on the in-situ model and ~10 % faster on the x-y table's.
ML_METHOD = "trf"
#: least_squares' ``ftol`` and ``gtol`` in :func:`ml_estimate` (its ``xtol`` is the caller's ``tol``).
ML_FTOL = 1e-12


def ml_estimate(model: MultiViewModel, uv, sigma_px, priors: dict, prior_means: list, values, X,
                iterations: int = 10, tol: float = 1e-10) -> dict:
    """Maximum-likelihood estimate of every parameter and point from the observed pixels ``uv`` (V, M, 2) (those of
    ``model.vis``) and the priors: ``scipy.optimize.least_squares`` from ``values``, ``X`` on the pixel residuals
    over ``sigma_px`` (a scalar, or one per view ``(V,)``) and the priors' rows ``R (theta - mean)`` (``R^T R`` their
    information), with the Jacobian of :meth:`MultiViewModel.jacobian`; points seen in fewer than two views stay
    where they are.

    ``priors`` as :meth:`MultiViewModel.prior_information`, centred on ``prior_means`` (block values, e.g. the
    encoder readings and the lab's identified errors). At most ``iterations`` steps (``max_nfev = iterations + 1``);
    ``tol`` is least_squares' ``xtol``, relative to the parameters in the Jacobian's column scaling (``x_scale="jac"``:
    parameters of very different units - rad, m, scale factors). Returns ``values``, ``X``, ``iterations`` (Jacobian
    evaluations), ``step`` (the last step's largest parameter change; NaN without a step), ``success`` (one of
    least_squares' tests met, not its evaluation budget; a run without a step that lowered the cost only by the
    gradient test) and least_squares' ``message``.
    """
    s = view_sigma(sigma_px, model.n_views)[:, None, None]
    lam, vec = np.linalg.eigh(model.prior_information(priors))
    R = (vec[:, lam > 0] * np.sqrt(lam[lam > 0])).T  # priors as residual rows: R^T R = P
    mean, n = model.pack(prior_means), model.n_params
    X = np.asarray(X, float).copy()
    use = model.vis.sum(axis=0) >= 2
    obs = model.vis[:, use]  # the residual rows: observed pixels of the points used
    cols = np.r_[np.arange(n), n + (3 * np.flatnonzero(use)[:, None] + np.arange(3)).ravel()]
    R_rows = np.c_[R, np.zeros((len(R), len(cols) - n))]
    iterates, cache = [], {}

    def split(x):
        Xu = X.copy()
        Xu[use] = x[n:].reshape(-1, 3)
        return model.unpack(x[:n]), Xu

    def fun(x):
        vals, Xu = split(x)
        r = ((model.pixels(*vals, Xu) - uv) / s)[:, use][obs]
        return np.r_[r.ravel(), R @ (x[:n] - mean)]

    def jac(x):
        if "x" not in cache or not np.array_equal(cache["x"], x):
            vals, Xu = split(x)
            J = (model.jacobian(*vals, Xu).reshape(model.n_views, len(X), 2, -1) / s[..., None])[:, use][obs][..., cols]
            cache["x"], cache["J"] = x.copy(), np.r_[J.reshape(-1, len(cols)), R_rows]
            iterates.append(cache["x"])  # the Jacobian is evaluated at the accepted iterates
        return cache["J"]

    x0 = np.r_[model.pack(values), X[use].ravel()]
    f0 = fun(x0)
    sol = scipy.optimize.least_squares(fun, x0, jac=jac, method=ML_METHOD, x_scale="jac", xtol=tol, ftol=ML_FTOL,
                                       gtol=ML_FTOL, max_nfev=iterations + 1)
    vals, X = split(sol.x)
    step = float(np.abs(iterates[-1][:n] - iterates[-2][:n]).max()) if len(iterates) > 1 else float("nan")
    success = sol.status == 1 or (sol.status > 1 and sol.cost < 0.5 * float(f0 @ f0))
    return {"values": vals, "X": X, "iterations": int(sol.njev), "step": step, "success": bool(success),
            "message": sol.message}
