"""Triangulation of matched image points with known camera poses (thesis sections 3.5-3.6).

Image points enter as *normalized, undistorted* coordinates ``x_n (..., 2)`` (``K^-1 [u v 1]^T`` after removing lens
distortion); camera poses as ``T_ref_cam (..., 4, 4)``: camera frame (OpenCV: z forward) in a common reference frame.

* :func:`triangulate_midpoint` - the thesis's method (Eq. 107-117): closest points of the two viewing rays, their
  mid-point, the ray parameters ``gamma1, gamma2`` (depth along each normalized ray, z = gamma for a ray
  ``[x_n, y_n, 1]``) and the closest-approach distance used as a match filter (thesis: 5 mm).
* :func:`triangulate_linear` - the homogeneous linear (DLT) triangulation from any number of views.
* :func:`triangulate_optimal` - minimum reprojection error (Gauss-Newton over the 3D point, any number of views),
  started from the linear solution.
* :func:`stereo_sensitivity` (Eq. 121-123) and :func:`required_baseline` (Eq. 199): the depth resolution of a
  stereo pair, and the intraocular distance needed for a given one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.geometry.lines import closest_points_between_lines


def _homog(x_n):
    x_n = np.asarray(x_n, dtype=float)
    if x_n.shape[-1] != 2:
        raise ValueError(f"x_n: expected (..., 2) normalized coordinates, got shape {x_n.shape}")
    if not np.all(np.isfinite(x_n)):
        raise ValueError("x_n: contains NaN or inf")
    return np.concatenate([x_n, np.ones(x_n.shape[:-1] + (1,))], axis=-1)


def _check_poses(T, name="T_ref_cam"):
    T = np.asarray(T, dtype=float)
    if T.shape[-2:] != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"{name}: expected finite (..., 4, 4) transforms, got shape {T.shape}")
    return T


@dataclass(frozen=True)
class MidpointResult:
    """Output of :func:`triangulate_midpoint`, arrays over the batch shape ``(...)``.

    Attributes
    ----------
    p_ref : ndarray (..., 3)
        The mid-point of the closest points (reference frame, m).
    p1, p2 : ndarray (..., 3)
        Closest points on ray 1 and ray 2 (Eq. 107, 108).
    gamma1, gamma2 : ndarray (...)
        Ray parameters (Eq. 116, 117): depths along the normalized rays of camera 1 and 2 (m).
    gap : ndarray (...)
        Closest-approach distance ``|p1 - p2|`` (m): the thesis's coincidence filter compares it with 5 mm.
    valid : ndarray (...) of bool
        Rays not parallel and the point in front of both cameras (gamma1, gamma2 > 0).
    """

    p_ref: np.ndarray
    p1: np.ndarray
    p2: np.ndarray
    gamma1: np.ndarray
    gamma2: np.ndarray
    gap: np.ndarray
    valid: np.ndarray


def triangulate_midpoint(T_ref_cam1, x1_n, T_ref_cam2, x2_n) -> MidpointResult:
    """Mid-point triangulation of matches ``x1_n <-> x2_n`` (Eq. 107-117), batched.

    Parameters
    ----------
    T_ref_cam1, T_ref_cam2 : array_like (..., 4, 4)
        Camera poses in the reference frame (broadcast against the points).
    x1_n, x2_n : array_like (..., 2)
        Normalized undistorted image coordinates in camera 1 and 2.

    Returns
    -------
    MidpointResult
    """
    T1, T2 = _check_poses(T_ref_cam1, "T_ref_cam1"), _check_poses(T_ref_cam2, "T_ref_cam2")
    d1 = np.einsum("...ij,...j->...i", T1[..., :3, :3], _homog(x1_n))  # R p^ (Eq. 107; identity R for camera 1)
    d2 = np.einsum("...ij,...j->...i", T2[..., :3, :3], _homog(x2_n))  # R p^' (Eq. 108)
    o1 = np.broadcast_to(T1[..., :3, 3], d1.shape)
    o2 = np.broadcast_to(T2[..., :3, 3], d2.shape)
    cp = closest_points_between_lines(o1, d1, o2, d2)
    valid = ~cp.parallel & (cp.gamma1 > 0) & (cp.gamma2 > 0)
    return MidpointResult(0.5 * (cp.p1 + cp.p2), cp.p1, cp.p2, cp.gamma1, cp.gamma2, cp.distance, valid)


def _projections(T_ref_cam):
    """``[R^T | -R^T t]`` (..., 3, 4): normalized projection matrices of cameras at ``T_ref_cam``."""
    R = np.swapaxes(T_ref_cam[..., :3, :3], -1, -2)
    return np.concatenate([R, -np.einsum("...ij,...j->...i", R, T_ref_cam[..., :3, 3])[..., None]], axis=-1)


def triangulate_linear(T_ref_cams, x_n):
    """Linear (DLT) triangulation from V >= 2 views.

    Parameters
    ----------
    T_ref_cams : array_like (V, 4, 4)
        Camera poses in the reference frame.
    x_n : array_like (V, N, 2)
        Normalized undistorted coordinates of N points in each view.

    Returns
    -------
    p_ref : ndarray (N, 3)
        Points in the reference frame (m); NaN where the system is degenerate or the point is not in front of every
        camera (e.g. zero baseline, which puts the solution at the camera centre).
    """
    T = _check_poses(T_ref_cams, "T_ref_cams")
    x = _homog(x_n)
    if T.ndim != 3 or x.ndim != 3 or x.shape[0] != T.shape[0] or T.shape[0] < 2:
        raise ValueError(f"expected T_ref_cams (V, 4, 4) and x_n (V, N, 2) with V >= 2, got {T.shape}, "
                         f"{np.shape(x_n)}")
    P = _projections(T)  # (V, 3, 4)
    # rows x P3 - P1, y P3 - P2 per view -> A (N, 2V, 4)
    A = np.concatenate([x[..., 0:1] * P[:, None, 2, :] - P[:, None, 0, :],
                        x[..., 1:2] * P[:, None, 2, :] - P[:, None, 1, :]], axis=0)  # (2V, N, 4)
    A = np.moveaxis(A, 1, 0)
    A = A / np.linalg.norm(A, axis=-1, keepdims=True)
    _, s, vt = np.linalg.svd(A)
    X = vt[:, -1, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        p = X[:, :3] / X[:, 3:4]
    degenerate = (s[:, -2] < 1e-12 * s[:, 0]) | (np.abs(X[:, 3]) < 1e-15)
    with np.errstate(invalid="ignore"):
        depth = np.einsum("vj,nj->vn", P[:, 2, :3], p) + P[:, None, 2, 3]
    degenerate |= ~np.all(depth > 1e-12, axis=0)  # behind a camera or at its centre (e.g. zero baseline)
    p[degenerate] = np.nan
    return p


def reprojection_residuals(T_ref_cams, x_n, p_ref):
    """Normalized-coordinate residuals ``x_n - proj(p)``, shape (V, N, 2)."""
    T = _check_poses(T_ref_cams, "T_ref_cams")
    P = _projections(T)
    pc = np.einsum("vij,nj->vni", P[..., :3], p_ref) + P[:, None, :, 3]
    return np.asarray(x_n, float) - pc[..., :2] / pc[..., 2:3]


def reprojection_jacobian(T_ref_cams, p_ref):
    """Projections ``proj(p) (V, N, 2)`` of points ``p_ref (N, 3)`` and their Jacobian ``d proj / d p (V, N, 2, 3)``.

    ``d proj / d p = (1 / z) [I2 | -proj] R^T`` for a camera-frame point ``(x, y, z) = R^T (p - t)``; the residual
    ``x_n - proj(p)`` has the opposite sign. Points at or behind a camera (``z <= 0``) give NaN.
    """
    T = _check_poses(T_ref_cams, "T_ref_cams")
    P = _projections(T)
    pc = np.einsum("vij,nj->vni", P[..., :3], np.asarray(p_ref, dtype=float)) + P[:, None, :, 3]
    z = pc[..., 2:3]
    z = np.where(z > 0.0, z, np.nan)
    proj = pc[..., :2] / z
    Jp = np.concatenate([np.broadcast_to(np.eye(2), proj.shape + (2,)), -proj[..., None]], axis=-1)
    return proj, np.einsum("vnab,vbc->vnac", Jp / z[..., None], P[..., :3])


def triangulate_optimal(T_ref_cams, x_n, p0=None, iterations: int = 10):
    """Minimum-reprojection-error triangulation (Gauss-Newton on each point), V >= 2 views.

    Parameters
    ----------
    T_ref_cams : array_like (V, 4, 4)
    x_n : array_like (V, N, 2)
    p0 : array_like (N, 3), optional
        Start (default: :func:`triangulate_linear`).
    iterations : int

    Returns
    -------
    p_ref : ndarray (N, 3)
        NaN for points that cannot be triangulated: a degenerate linear start (zero baseline, parallel rays), a
        start or a result not in front of every camera, or a singular normal matrix (condition > 1e12: rays too
        close to parallel for the depth to be determined).
    rms : ndarray (N,)
        RMS reprojection residual per point (normalized units; times the focal length gives pixels); NaN where
        ``p_ref`` is.
    """
    T = _check_poses(T_ref_cams, "T_ref_cams")
    x = _homog(x_n)[..., :2]
    if T.ndim != 3 or x.ndim != 3 or x.shape[0] != T.shape[0] or T.shape[0] < 2:
        raise ValueError(f"expected T_ref_cams (V, 4, 4) and x_n (V, N, 2) with V >= 2, got {T.shape}, "
                         f"{np.shape(x_n)}")
    if p0 is None:
        p = triangulate_linear(T, x)
    else:
        p = np.array(p0, dtype=float)
        if p.shape != (x.shape[1], 3):
            raise ValueError(f"p0: expected shape ({x.shape[1]}, 3), got {p.shape}")
    ok = np.all(np.isfinite(p), axis=1)
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
    p[~ok] = np.nan
    rms = np.full(len(p), np.nan)
    rms[ok] = np.sqrt(np.mean(np.sum((x - proj)[:, ok] ** 2, axis=-1), axis=0))
    return p, rms


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
