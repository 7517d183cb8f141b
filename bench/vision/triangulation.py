"""Triangulation of matched image points with known camera poses (thesis sections 3.5-3.6): one family.

Every method has the same call and the same result:

``method(T_ref_cams, x_n) -> Triangulation``

* ``T_ref_cams`` - the V camera poses, ``(V, 4, 4)`` or a sequence of V ``(4, 4)``: camera frame (OpenCV optical
  frame: x right, y down, z forward) in a common reference frame, ``p_ref = T_ref_cam @ p_cam``; rigid transforms
  (a projection or intrinsic matrix in their place is refused, see :data:`RIGID_TOL`).
* ``x_n`` - the N matched points in every view, view-major: ``(V, N, 2)`` or a sequence of V ``(N, 2)``, as
  *normalized, undistorted* coordinates (``K^-1 [u v 1]^T`` after removing lens distortion). Row ``n`` of every view
  is the same scene point.

Poses first, then points, both indexed by view; :func:`triangulate_pixels` takes pixels and the camera model(s)
instead of ``x_n`` (``(T_ref_cams, uv, cameras)``) and undistorts through the camera chain's inverse
(:meth:`bench.camera.model.CameraModel.undistort_pixels`). :func:`triangulate` picks the method by name.

Methods (:data:`METHODS`):

* :func:`triangulate_midpoint` - the thesis's method (Eq. 107-117): the closest points ``P1, P2`` of the two viewing
  rays and their mid-point; two views only. The ray parameters ``gamma1, gamma2`` (Eq. 116-117) are the depths of
  ``P1, P2`` (a ray ``[x_n, y_n, 1]`` has z = gamma); the closest-approach distance ``|P1 - P2|`` is the thesis's
  coincidence filter (5 mm, section 3.4.7 / 5.2.2).
* :func:`triangulate_linear` - the homogeneous linear (DLT) triangulation, V >= 2 views.
* :func:`triangulate_optimal` - minimum reprojection error (Gauss-Newton over the 3D point), V >= 2 views, started
  from the linear solution.

The result, :class:`Triangulation`, carries a ``valid`` mask, and every per-point quantity is NaN where ``valid`` is
False. A point is invalid, for every method alike, when

* its rays are parallel (``sin`` of the angle between view 0's ray and every other view's below
  :data:`bench.geometry.lines.PARALLEL_TOL`; zero baseline with the same pixel included): no depth;
* it is not in front of every camera: the depth ``gamma_v`` of the point of view v's ray nearest the estimate is
  ``<= MIN_DEPTH_M`` (behind a camera, or at its centre, e.g. zero baseline with different pixels);
* the method's own solve is degenerate (linear: a rank-deficient system; optimal: a singular normal matrix, or an
  iterate at or behind a camera).

:func:`stereo_sensitivity` (Eq. 121-123) and :func:`required_baseline` (Eq. 199) give the depth resolution of a stereo
pair and the intraocular distance needed for a given one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.geometry.lines import PARALLEL_TOL, closest_points_between_lines

#: The triangulation methods, by the name :func:`triangulate` and :func:`triangulate_pixels` take.
METHODS = ("midpoint", "linear", "optimal")
#: A point counts as in front of a camera when its ray depth exceeds this (m); rejects points at a camera centre.
MIN_DEPTH_M = 1e-12
#: Largest departure of a camera pose from a rigid transform (``|R^T R - I|``, last row) that is accepted: a guard
#: against projection or intrinsic matrices passed as poses, loose enough for the linearised error form (Eq. 9).
RIGID_TOL = 1e-3


@dataclass(frozen=True)
class Triangulation:
    """Result of every triangulation method: N points seen in V views.

    Every per-point array is NaN where ``valid`` is False (see the module docstring for when a point is invalid).

    Attributes
    ----------
    points : ndarray (N, 3)
        The triangulated points in the reference frame (m).
    valid : ndarray (N,) of bool
        Rays not parallel, the point in front of every camera, the method's solve not degenerate.
    depth : ndarray (V, N)
        Ray parameter ``gamma_v`` of ``ray_points[v]``: the depth (z in camera v, m) of the point on view v's viewing
        ray nearest ``points``. For the mid-point method these are Eq. 116-117's ``gamma1, gamma2``.
    ray_points : ndarray (V, N, 3)
        The points of each view's viewing ray nearest ``points`` (m, reference frame). For the mid-point method,
        the closest points ``P1, P2`` of the two rays (Eq. 107-108), ``points`` being their mid-point.
    gap : ndarray (N,)
        Largest distance between two of the ``ray_points`` (m): how far the viewing rays pass from each other at the
        estimate. For the mid-point method, the closest approach ``|P1 - P2|`` of the rays, which the thesis compares
        with 5 mm to reject false matches.
    rms : ndarray (N,)
        RMS over the views of the reprojection residual ``|x_n - proj(points)|`` (normalized units; times the focal
        length gives pixels); ``inf`` for a valid point that projects behind a camera (a mid-point of rays that pass
        far apart).
    method : str
        One of :data:`METHODS`.
    """

    points: np.ndarray
    valid: np.ndarray
    depth: np.ndarray
    ray_points: np.ndarray
    gap: np.ndarray
    rms: np.ndarray
    method: str

    def __len__(self) -> int:
        return len(self.points)


def _parse(T_ref_cams, x_n, name="x_n", two_views=False):
    """``T (V, 4, 4)``, ``x (V, N, 2)`` checked: finite, the same number of views, V >= 2 (== 2 for ``two_views``)."""
    try:
        T = np.asarray(T_ref_cams, dtype=float)
    except (TypeError, ValueError):
        raise ValueError("T_ref_cams: expected one (4, 4) camera pose per view, (V, 4, 4)") from None
    if T.ndim != 3 or T.shape[1:] != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"T_ref_cams: expected finite camera poses (V, 4, 4), one per view, got shape {T.shape}")
    R = T[:, :3, :3]
    off = np.maximum(np.abs(T[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(axis=1),
                     np.abs(np.swapaxes(R, 1, 2) @ R - np.eye(3)).max(axis=(1, 2)))
    if np.any(off > RIGID_TOL) or np.any(np.linalg.det(R) < 0):
        v = int(np.argmax(off)) if np.any(off > RIGID_TOL) else int(np.argmax(np.linalg.det(R) < 0))
        raise ValueError(f"T_ref_cams: pose {v} is not a rigid transform (|R^T R - I| or last row off by "
                         f"{off[v]:.2g}, det R = {np.linalg.det(R[v]):.3g}): camera poses T_ref_cam are expected, "
                         f"not projection matrices")
    try:
        x = np.asarray(x_n, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected (V, N, 2), one (N, 2) array per view with the same N") from None
    if x.ndim != 3 or x.shape[-1] != 2:
        raise ValueError(f"{name}: expected (V, N, 2), one (N, 2) array per view (poses first, then points), got "
                         f"shape {x.shape}")
    if x.shape[0] != T.shape[0]:
        raise ValueError(f"{name}: {x.shape[0]} views of points for {T.shape[0]} camera poses in T_ref_cams")
    if two_views and T.shape[0] != 2:
        raise ValueError(f"T_ref_cams: the mid-point method takes exactly 2 views, got {T.shape[0]}")
    if T.shape[0] < 2:
        raise ValueError(f"T_ref_cams: V >= 2 views are needed to triangulate, got {T.shape[0]}")
    bad = ~np.all(np.isfinite(x), axis=-1)
    if bad.any():
        v, n = np.argwhere(bad)[0]
        raise ValueError(f"{name}: contains NaN or inf ({int(bad.sum())} entries, first: view {v}, point {n})")
    return T, x


def _homog(x):
    return np.concatenate([x, np.ones(x.shape[:-1] + (1,))], axis=-1)


def _rays(T, x):
    """Origins and directions ``R_v [x, y, 1]`` of the viewing rays, both (V, N, 3), in the reference frame."""
    d = np.einsum("vij,vnj->vni", T[:, :3, :3], _homog(x))
    return np.broadcast_to(T[:, None, :3, 3], d.shape), d


def _parallel(d):
    """(N,) True where view 0's ray is parallel (``sin < PARALLEL_TOL``) to every other view's ray."""
    n = np.cross(d[:1], d[1:])
    nn = np.sum(n * n, axis=-1)
    dd = np.sum(d * d, axis=-1)
    return ~np.any(nn > (PARALLEL_TOL * PARALLEL_TOL) * dd[:1] * dd[1:], axis=0)


def _feet(T, x, p):
    """``(depth (V, N), ray_points (V, N, 3), gap (N,))`` of points ``p (N, 3)`` on the views' rays."""
    o, d = _rays(T, x)
    with np.errstate(invalid="ignore", over="ignore"):
        depth = np.sum((p[None] - o) * d, axis=-1) / np.sum(d * d, axis=-1)
        rp = o + depth[..., None] * d
        gap = np.sqrt(np.max(np.sum((rp[:, None] - rp[None]) ** 2, axis=-1), axis=(0, 1)))
    return depth, rp, gap


def _projections(T_ref_cam):
    """``[R^T | -R^T t]`` (..., 3, 4): normalized projection matrices of cameras at ``T_ref_cam``."""
    R = np.swapaxes(T_ref_cam[..., :3, :3], -1, -2)
    return np.concatenate([R, -np.einsum("...ij,...j->...i", R, T_ref_cam[..., :3, 3])[..., None]], axis=-1)


def _rms(T, x, p):
    """RMS reprojection residual (N,) of points ``p``; inf where a point is at or behind a camera."""
    P = _projections(T)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        pc = np.einsum("vij,nj->vni", P[..., :3], p) + P[:, None, :, 3]
        r = x - pc[..., :2] / pc[..., 2:3]
        rms = np.sqrt(np.mean(np.sum(r**2, axis=-1), axis=0))
        rms[np.any(pc[..., 2] <= 0.0, axis=0)] = np.inf
    return rms


def _result(method, T, x, p, valid, depth=None, ray_points=None, gap=None) -> Triangulation:
    """Assemble a :class:`Triangulation`, NaN wherever ``valid`` is False."""
    p = np.array(p, dtype=float)
    p[~valid] = np.nan
    if depth is None:
        depth, ray_points, gap = _feet(T, x, p)
    depth, ray_points, gap = np.array(depth, float), np.array(ray_points, float), np.array(gap, float)
    depth[:, ~valid] = np.nan
    ray_points[:, ~valid] = np.nan
    gap[~valid] = np.nan
    rms = _rms(T, x, p)
    rms[~valid] = np.nan
    return Triangulation(p, np.asarray(valid, bool), depth, ray_points, gap, rms, method)


def triangulate_midpoint(T_ref_cams, x_n) -> Triangulation:
    """Mid-point triangulation from two views (the thesis's method, Eq. 107-117).

    The viewing rays ``P1 = O_c1 + gamma1 p^`` (Eq. 107) and ``P2 = O_c2 + gamma2 R p^'`` (Eq. 108) are intersected
    in the least-squares sense: ``P1, P2`` are their closest points (Eq. 109-117, through
    :func:`bench.geometry.lines.closest_points_between_lines`) and the estimate is their mid-point.

    Parameters
    ----------
    T_ref_cams : array_like (2, 4, 4)
        The two camera poses in the reference frame.
    x_n : array_like (2, N, 2)
        Normalized undistorted coordinates of the N matches in view 1 and view 2.

    Returns
    -------
    Triangulation
        ``ray_points`` are ``P1, P2``, ``depth`` is ``gamma1, gamma2`` (m), ``gap`` is ``|P1 - P2|`` (m).
    """
    T, x = _parse(T_ref_cams, x_n, two_views=True)
    xh = _homog(x)
    d1 = np.einsum("...ij,...j->...i", T[0, :3, :3], xh[0])  # R p^ (Eq. 107; identity R for camera 1)
    d2 = np.einsum("...ij,...j->...i", T[1, :3, :3], xh[1])  # R p^' (Eq. 108)
    o1 = np.broadcast_to(T[0, :3, 3], d1.shape)
    o2 = np.broadcast_to(T[1, :3, 3], d2.shape)
    cp = closest_points_between_lines(o1, d1, o2, d2)
    valid = ~cp.parallel & (cp.gamma1 > MIN_DEPTH_M) & (cp.gamma2 > MIN_DEPTH_M)
    return _result("midpoint", T, x, 0.5 * (cp.p1 + cp.p2), valid, np.stack([cp.gamma1, cp.gamma2]),
                   np.stack([cp.p1, cp.p2]), cp.distance)


def triangulate_linear(T_ref_cams, x_n) -> Triangulation:
    """Linear (DLT) triangulation from V >= 2 views.

    Each view contributes the rows ``x P_3 - P_1`` and ``y P_3 - P_2`` of the normalized projection matrix
    ``P = [R^T | -R^T t]``; the homogeneous point is the right singular vector of the stacked, row-normalized system.

    Parameters
    ----------
    T_ref_cams : array_like (V, 4, 4)
        Camera poses in the reference frame.
    x_n : array_like (V, N, 2)
        Normalized undistorted coordinates of the N points in each view.

    Returns
    -------
    Triangulation
        Also invalid where the system is rank-deficient or the homogeneous point is at infinity.
    """
    T, x = _parse(T_ref_cams, x_n)
    xh = _homog(x)
    P = _projections(T)  # (V, 3, 4)
    # rows x P3 - P1, y P3 - P2 per view -> A (N, 2V, 4)
    A = np.concatenate([xh[..., 0:1] * P[:, None, 2, :] - P[:, None, 0, :],
                        xh[..., 1:2] * P[:, None, 2, :] - P[:, None, 1, :]], axis=0)  # (2V, N, 4)
    A = np.moveaxis(A, 1, 0)
    A = A / np.linalg.norm(A, axis=-1, keepdims=True)
    if len(A):
        _, s, vt = np.linalg.svd(A)
        X = vt[:, -1, :]
    else:
        s, X = np.ones((0, 4)), np.ones((0, 4))
    with np.errstate(divide="ignore", invalid="ignore"):
        p = X[:, :3] / X[:, 3:4]
    valid = (s[:, -2] >= 1e-12 * s[:, 0]) & (np.abs(X[:, 3]) >= 1e-15) & ~_parallel(_rays(T, x)[1])
    depth, _, _ = _feet(T, x, np.where(valid[:, None], p, 0.0))
    valid &= np.all(depth > MIN_DEPTH_M, axis=0)  # behind a camera or at its centre (e.g. zero baseline)
    return _result("linear", T, x, p, valid)


def reprojection_jacobian(T_ref_cams, p_ref):
    """Projections ``proj(p) (V, N, 2)`` of points ``p_ref (N, 3)`` and their Jacobian ``d proj / d p (V, N, 2, 3)``.

    ``d proj / d p = (1 / z) [I2 | -proj] R^T`` for a camera-frame point ``(x, y, z) = R^T (p - t)``; the residual
    ``x_n - proj(p)`` has the opposite sign. Points at or behind a camera (``z <= 0``) give NaN.
    """
    T = np.asarray(T_ref_cams, dtype=float)
    if T.ndim != 3 or T.shape[1:] != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"T_ref_cams: expected finite camera poses (V, 4, 4), got shape {T.shape}")
    P = _projections(T)
    pc = np.einsum("vij,nj->vni", P[..., :3], np.asarray(p_ref, dtype=float)) + P[:, None, :, 3]
    z = pc[..., 2:3]
    z = np.where(z > 0.0, z, np.nan)
    proj = pc[..., :2] / z
    Jp = np.concatenate([np.broadcast_to(np.eye(2), proj.shape + (2,)), -proj[..., None]], axis=-1)
    return proj, np.einsum("vnab,vbc->vnac", Jp / z[..., None], P[..., :3])


def triangulate_optimal(T_ref_cams, x_n, *, p0=None, iterations: int = 10) -> Triangulation:
    """Minimum-reprojection-error triangulation (Gauss-Newton on each point), V >= 2 views.

    Parameters
    ----------
    T_ref_cams : array_like (V, 4, 4)
        Camera poses in the reference frame.
    x_n : array_like (V, N, 2)
        Normalized undistorted coordinates of the N points in each view.
    p0 : array_like (N, 3), optional
        Start (m, reference frame); default :func:`triangulate_linear`.
    iterations : int
        At most this many Gauss-Newton steps.

    Returns
    -------
    Triangulation
        Also invalid where the start is invalid (degenerate linear start, or not in front of every camera), an iterate
        is at or behind a camera, or the normal matrix is singular (condition > 1e12: rays too close to parallel for
        the depth to be determined). ``rms`` is the minimised residual.
    """
    T, x = _parse(T_ref_cams, x_n)
    if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) or iterations < 0:
        raise ValueError(f"iterations: expected a non-negative integer, got {iterations!r}")
    if p0 is None:
        p = triangulate_linear(T, x).points
    else:
        p = np.array(p0, dtype=float)
        if p.shape != (x.shape[1], 3):
            raise ValueError(f"p0: expected shape ({x.shape[1]}, 3), got {p.shape}")
    ok = np.all(np.isfinite(p), axis=1) & ~_parallel(_rays(T, x)[1])
    for _ in range(iterations):
        proj, J = reprojection_jacobian(T, np.where(ok[:, None], p, 0.0))
        ok &= np.all(np.isfinite(proj), axis=(0, 2))  # a point at or behind a camera cannot be refined
        r = np.where(ok[None, :, None], x - proj, 0.0)  # (V, N, 2)
        J = np.where(ok[None, :, None, None], J, 0.0)
        H = np.einsum("vnai,vnaj->nij", J, J)
        g = np.einsum("vnai,vna->ni", J, r)  # r = x - proj, so the step is +H^-1 J^T r
        cond = np.full(len(p), np.inf)
        cond[ok] = np.linalg.cond(H[ok]) if np.any(ok) else cond[ok]
        ok &= cond < 1e12
        dp = np.zeros_like(p)
        dp[ok] = np.linalg.solve(H[ok], g[ok][..., None])[..., 0]
        p = np.where(ok[:, None], p + dp, p)
        if np.all(np.abs(dp[ok]) < 1e-14 * (1 + np.abs(p[ok]))):
            break
    proj, _ = reprojection_jacobian(T, np.where(ok[:, None], p, 0.0))
    ok &= np.all(np.isfinite(proj), axis=(0, 2))
    depth, _, _ = _feet(T, x, np.where(ok[:, None], p, 0.0))
    ok &= np.all(depth > MIN_DEPTH_M, axis=0)
    return _result("optimal", T, x, p, ok)


_METHOD_FUNCTIONS = {"midpoint": triangulate_midpoint, "linear": triangulate_linear, "optimal": triangulate_optimal}


def triangulate(T_ref_cams, x_n, method: str = "midpoint", **options) -> Triangulation:
    """Triangulate normalized coordinates with the method named ``method`` (one of :data:`METHODS`).

    ``options`` go to the method (``p0``, ``iterations`` for ``"optimal"``). See :func:`triangulate_midpoint`,
    :func:`triangulate_linear`, :func:`triangulate_optimal`.
    """
    if method not in _METHOD_FUNCTIONS:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    return _METHOD_FUNCTIONS[method](T_ref_cams, x_n, **options)


def triangulate_pixels(T_ref_cams, uv, cameras, method: str = "midpoint", **options) -> Triangulation:
    """Triangulate pixel coordinates through the camera model(s): undistort, then :func:`triangulate`.

    Parameters
    ----------
    T_ref_cams : array_like (V, 4, 4)
        Camera poses in the reference frame.
    uv : array_like (V, N, 2)
        Pixel coordinates of the N matches in each view (OpenCV convention, as detected: distorted), px.
    cameras : CameraModel or sequence of V CameraModel
        The calibrated camera of every view (one model for all views, or one per view): anything with
        ``undistort_pixels(uv) -> x_n`` (:class:`bench.camera.model.CameraModel`), which inverts the camera chain
        (intrinsics, Eq. 51, then the distortion, Eq. 75-76).
    method : str
        One of :data:`METHODS`.
    **options
        Passed to the method (``p0`` (N, 3) and ``iterations`` for ``"optimal"``).

    Returns
    -------
    Triangulation
        Also invalid (NaN) for a match whose pixel the camera cannot undistort (outside the region where its
        distortion is one-to-one).
    """
    try:
        uv_arr = np.asarray(uv, dtype=float)
    except (TypeError, ValueError):
        raise ValueError("uv: expected pixels (V, N, 2), one (N, 2) array per view with the same N") from None
    if uv_arr.ndim != 3 or uv_arr.shape[-1] != 2:
        raise ValueError(f"uv: expected pixels (V, N, 2), one (N, 2) array per view, got shape {uv_arr.shape}")
    n_views = uv_arr.shape[0]
    if hasattr(cameras, "undistort_pixels"):
        cams = [cameras] * n_views
    else:
        try:
            cams = list(cameras)
        except TypeError:
            cams = []
        if not cams or not all(hasattr(c, "undistort_pixels") for c in cams):
            raise ValueError(f"cameras: expected a camera model (bench.camera.model.CameraModel) or a sequence of one "
                             f"per view, got {type(cameras).__name__}")
        if len(cams) != n_views:
            raise ValueError(f"cameras: {len(cams)} camera models for {n_views} views of pixels")
    if not np.all(np.isfinite(uv_arr)):
        raise ValueError("uv: contains NaN or inf")
    T, _ = _parse(T_ref_cams, np.zeros((n_views, 0, 2)), name="uv")
    x = np.stack([np.asarray(c.undistort_pixels(uv_arr[v]), dtype=float) for v, c in enumerate(cams)])
    ok = np.all(np.isfinite(x), axis=(0, 2))
    if options.get("p0") is not None:
        p0 = np.asarray(options["p0"], dtype=float)
        if p0.shape != (uv_arr.shape[1], 3):
            raise ValueError(f"p0: expected shape ({uv_arr.shape[1]}, 3), got {p0.shape}")
        options = {**options, "p0": p0[ok]}
    sub = triangulate(T, x[:, ok], method, **options)
    if ok.all():
        return sub
    n = uv_arr.shape[1]

    def scatter(a, axis):
        out = np.full(a.shape[:axis] + (n,) + a.shape[axis + 1:], np.nan)
        out[(slice(None),) * axis + (ok,)] = a
        return out

    valid = np.zeros(n, bool)
    valid[ok] = sub.valid
    return Triangulation(scatter(sub.points, 0), valid, scatter(sub.depth, 1), scatter(sub.ray_points, 1),
                         scatter(sub.gap, 0), scatter(sub.rms, 0), sub.method)


def stereo_sensitivity(u, v, u0, v0, alpha, beta, d_int, z, ds=1.0):
    """Position error ``(dx, dy, dz)`` (m) of a stereo point for a disparity error ``ds`` px (Eq. 121-123).

    ``u, v`` pixel coordinates in the reference camera, ``u0, v0`` its principal point, ``alpha, beta`` focal lengths
    (px), ``d_int`` the baseline (intraocular distance, m), ``z`` the depth (m). Broadcasts.
    """
    u, v, z, d_int = (np.asarray(a, dtype=float) for a in (u, v, z, d_int))
    if np.any(d_int <= 0) or alpha <= 0 or beta <= 0:
        raise ValueError("stereo_sensitivity: d_int, alpha and beta must be > 0")
    dx = -((u - u0) / (alpha**2 * d_int)) * z**2 * ds  # Eq. 121
    dy = -((v - v0) / (beta**2 * d_int)) * z**2 * ds  # Eq. 122
    dz = -(1.0 / (alpha * d_int)) * z**2 * ds  # Eq. 123
    return np.stack(np.broadcast_arrays(dx, dy, dz), axis=-1)


def required_baseline(z, alpha, dz, ds=1.0):
    """Intraocular distance (m) that gives a depth resolution ``dz`` (m) at depth ``z`` (m): Eq. 199, magnitude."""
    z, dz = np.asarray(z, dtype=float), np.asarray(dz, dtype=float)
    if np.any(z <= 0) or alpha <= 0 or np.any(dz <= 0) or ds <= 0:
        raise ValueError("required_baseline: z, alpha, dz and ds must be > 0")
    return z**2 * ds / (alpha * dz)  # Eq. 199: d_int = -(1 / (alpha dz)) z^2 ds
