"""Absolute orientation between two 3D point sets (thesis section 3.7, Eq. 124-156).

Given the same points in two frames, ``1p_i`` and ``2p_i`` (e.g. the keypoint map triangulated before and after the
base moved), find ``R, t`` with (Eq. 124)::

    R 2p_i + t = 1p_i,        i.e.  T = T_1_2 = [[R, t], [0, 1]] maps 2p-frame coordinates into the 1p frame,

so ``p_1 = T_1_2 @ p_2`` in the design's ``T_a_b`` convention (``R = R_1_2``, ``t = t_1_2``, the origin of frame 2 in
frame 1). The rotation comes from one of three methods (:func:`absolute_orientation`'s ``method``); the translation
is always Eq. 125 (weighted when weights are given): ``t = sum_i w_i (1p_i - R 2p_i) / sum_i w_i``.

* ``method="rodrigues"`` - the thesis's quaternion / Rodrigues-parameter method (Eq. 137-156):
  linear least squares for the Rodrigues (Gibbs) vector ``x_q = tan(theta / 2) k`` from differences of consecutive
  points, then the quaternion (Eq. 133, 155-156) and the matrix (Eq. 136).
* ``method="svd"`` - the least-squares SVD method the thesis cites as [21] (Arun, Huang & Blostein
  1987; Umeyama 1991) with Umeyama's reflection fix: ``R = V diag(1, 1, det(V U^T)) U^T``.
* ``method="horn"`` - Horn's (1987) closed-form unit quaternion: the eigenvector of the largest
  eigenvalue of the symmetric 4x4 matrix ``N`` built from the cross-covariance. Always a proper rotation.

The SVD and Horn methods minimise the same cost ``sum_i w_i |1p_i - R 2p_i - t|^2`` and give the same answer to
rounding; the thesis's method minimises an algebraic error and is less efficient under noise (compare
:func:`predicted_covariance` for ``method="svd"`` and ``"rodrigues"``). All three are exact on noise-free data.

Derivation of the Rodrigues-parameter equations and misprints in the thesis
---------------------------------------------------------------------------
With ``q = [q0, q_v]`` and ``1p - t = q o 2p o q*`` (Eq. 137-138), multiplying by ``q`` on the right gives
``q o 2p = (1p - t) o q`` (Eq. 139). Its vector part is ``q0 2p + q_v x 2p = q0 (1p - t) + (1p - t) x q_v``, i.e.
``(2p + 1p - t) x q_v = q0 (2p - 1p + t)`` (Eq. 141, where the right-hand ``q`` is the scalar ``q0``), and dividing
by ``q0 = cos(theta / 2)``: ``Q(2p + 1p - t) x_q = 2p - 1p + t`` with ``Q(v) y = v x y`` (Eq. 142-144). Each
equation was checked numerically (``tests/vision/test_absolute_orientation.py``). Misprints:

1. Eq. 140 - the right-hand vector part is printed ``q (1p - t) x (1p - t)``; it is
   ``q0 (1p - t) + (1p - t) x q_v`` (the left-hand ``q 2p - 2p x q`` is right when ``q`` before ``2p`` means ``q0``).
2. Eq. 147 - printed ``Q(1p - 2p) x_q + y_q = 2p - 1p``; Eq. 144 and 146 give ``Q(1p + 2p) x_q + y_q = 2p - 1p``.
3. Eq. 148 - printed ``Q(zeta_i + rho_i) x_q = zeta_i + rho_i``; the right-hand side is ``zeta_i - rho_i``
   (``zeta_i = 2p_i - 2p_(i+1)``, ``rho_i = 1p_i - 1p_(i+1)``), as Eq. 151 and 154 have it.
4. Eq. 148 "for all i = 1:m" and Eq. 153-154 (last block index ``m``): ``m`` points give only ``m - 1`` consecutive
   differences; the blocks run over ``i = 1 .. m - 1`` (three points give the two blocks of Eq. 150-151).
5. Eq. 156 - ``theta_q = 2 atan(max(x_q) / max(k))`` equals ``2 atan(|x_q|)`` whenever the largest component of
   ``k`` is non-zero, and is ``0 / 0`` when it is zero (e.g. ``k = (-0.6, -0.8, 0)``); with Eq. 155 also ``0 / 0`` at
   ``x_q = 0``. We use ``q = [1, x_q] / sqrt(1 + |x_q|^2)``, which is Eq. 133 with Eq. 155-156 without the divisions.

Not a misprint, but a limit of the method: ``x_q = tan(theta / 2) k`` is infinite at ``theta = pi``, where
``Q(zeta + rho)`` is singular (``zeta + rho = (I + R) zeta``). Shuster's sequential-rotation remedy is applied: the
system is also solved with ``2p`` pre-rotated by pi about x, y and z (``R = R' R0``); among the candidates whose
normal matrix has a smallest eigenvalue at least a tenth of the largest such eigenvalue among the candidates (a
pre-rotation does not change the lengths of the differences, so the eigenvalues compare directly), the one with the
smallest ``|x_q'|`` (smallest residual rotation) is kept. Below 90 deg the un-rotated candidate has the smallest
``|x_q|`` and its ``I + R`` factor the largest smallest eigenvalue, so there the method is the printed one (checked in
the tests); the filter matters near pi, where the un-rotated system is nearly singular and can return a small but
meaningless ``x_q``. (A filter on the *condition number* instead fails on noisy, nearly planar point sets - the x-y
table experiment's panel: there a pre-rotated system whose eigenvalues are all tiny, and hence "well conditioned",
beat the un-rotated one and returned a rotation of ~120 deg instead of 4 deg.)

Weights ``w_i`` (relative inverse variances of the points) enter Eq. 125, the SVD/Horn cross-covariance and, for the
Rodrigues method, each difference equation with ``w_i w_(i+1) / (w_i + w_(i+1))`` (inverse of the variance of a
difference). Points with zero weight are ignored.

First-order covariance
----------------------
With ``nu_i = n1_i - R n2_i`` the combined noise of pair i (isotropic, per-axis ``sigma^2 / w_i``), the estimate
``R_hat = exp([dphi]x) R`` (``dphi`` in the 1p frame, rad) and ``t_hat = t + dt``, the least-squares methods give
``cov(dphi) = sigma^2 H^-1`` with ``H = sum_i w_i (|c_i|^2 I - c_i c_i^T)`` (``c_i`` the points about their weighted
centroid, 1p frame), ``dt = nu_bar - dphi x m`` with ``m = R 2p_bar`` (so ``cov(dt) = sigma^2 / sum w I +
[m]x cov(dphi) [m]x^T``). The Rodrigues method's residual ``Q(a_i) x - b_i`` changes by ``(I - [x]x)(nu_i - nu_(i+1))``
(using ``I + [x]x = (I - [x]x) R``), which gives its sandwich covariance, mapped to ``dphi`` by
:func:`~bench.geometry.quaternion.rodrigues_jacobian`. :func:`predicted_covariance` returns both.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bench.geometry.quaternion import (
    quaternion_to_matrix,
    rodrigues_jacobian,
    rodrigues_to_quaternion,
)
from bench.geometry.transforms import homogeneous, random_rotation, rot_x, rot_y, rot_z, skew

METHODS = ("rodrigues", "svd", "horn")

#: Above this condition number of the point spread the pose is refused (collinear points).
MAX_CONDITION = 1e8
#: Above this condition number the pose is returned with a warning in the message.
WARN_CONDITION = 1e4

# Pre-rotations for the Rodrigues method near theta = pi (identity first: the thesis's method as printed).
_PRE_ROTATIONS = np.stack([np.eye(3), rot_x(np.pi), rot_y(np.pi), rot_z(np.pi)])
_PRE_ROTATIONS = np.round(_PRE_ROTATIONS)  # exact 0 / +-1 entries


@dataclass
class AbsoluteOrientationResult:
    """Outcome of an absolute-orientation fit ``R 2p_i + t = 1p_i`` (Eq. 124).

    Attributes
    ----------
    success : bool
        False for too few usable points or a (nearly) collinear spread; then ``R``, ``t``, ``T`` are NaN.
    message : str
        "ok", a warning about ill-conditioning, or the reason for failure.
    R : ndarray (3, 3)
        ``R_1_2``, rotation of the 2p frame into the 1p frame.
    t : ndarray (3,)
        ``t_1_2`` (m), Eq. 125.
    T : ndarray (4, 4)
        ``T_1_2``: ``p_1 = T @ p_2`` (homogeneous).
    rms : float
        ``sqrt(sum_i w_i |1p_i - R 2p_i - t|^2 / sum_i w_i)`` (m).
    condition : float
        Condition number ``lambda_max / lambda_min`` of ``H = sum_i w_i (|c_i|^2 I - c_i c_i^T)`` (centred 2p
        points): the normal matrix of the rotation, infinite for collinear points, finite for planar ones.
    method : str
        "rodrigues", "svd" or "horn".
    n_points : int
        Points used (non-zero weight).
    residuals : ndarray (N,)
        ``|1p_i - R 2p_i - t|`` per point (m), also for zero-weight points (NaN on failure).
    covariance : ndarray (6, 6)
        First-order covariance of ``(dphi, dt)`` (rad, m; ``dphi`` a left rotation vector in the 1p frame) with the
        noise level estimated from the residuals, ``sigma^2 = sum w |e|^2 / (3 n - 6)`` (NaN on failure).
    """

    success: bool
    message: str
    R: np.ndarray
    t: np.ndarray
    T: np.ndarray
    rms: float
    condition: float
    method: str
    n_points: int
    residuals: np.ndarray = field(repr=False)
    covariance: np.ndarray = field(repr=False)


def check_point_sets(p1, p2, weights=None):
    """Validate corresponding point sets ``p1, p2 (N, 3)`` and weights ``(N,)``; ``ValueError`` naming the field.

    Returns float arrays ``(p1, p2, w)`` with ``w`` all ones when ``weights`` is None.
    """
    p1 = np.asarray(p1, dtype=float)
    p2 = np.asarray(p2, dtype=float)
    for name, p in (("p1", p1), ("p2", p2)):
        if p.ndim != 2 or p.shape[1] != 3:
            raise ValueError(f"{name}: expected shape (N, 3), got {p.shape}")
        if not np.all(np.isfinite(p)):
            raise ValueError(f"{name}: contains NaN or inf")
    if p1.shape != p2.shape:
        raise ValueError(f"p1, p2: mismatched shapes {p1.shape} and {p2.shape}")
    if weights is None:
        w = np.ones(len(p1))
    else:
        w = np.asarray(weights, dtype=float)
        if w.shape != (len(p1),):
            raise ValueError(f"weights: expected shape ({len(p1)},), got {w.shape}")
        if not np.all(np.isfinite(w)) or np.any(w < 0.0):
            raise ValueError("weights: must be finite and >= 0")
    return p1, p2, w


def _centre(p, w):
    """Weighted centroid ``(..., 3)`` and centred points of ``p (..., n, 3)`` with weights ``w (..., n)``."""
    pbar = np.einsum("...n,...nk->...k", w, p) / np.sum(w, axis=-1)[..., None]
    return pbar, p - pbar[..., None, :]


def _inertia(c, w):
    """``H = sum_i w_i (|c_i|^2 I - c_i c_i^T)``, shape ``(..., 3, 3)``."""
    outer = np.einsum("...n,...ni,...nj->...ij", w, c, c)
    return np.trace(outer, axis1=-2, axis2=-1)[..., None, None] * np.eye(3) - outer


def _condition(H):
    lam = np.linalg.eigvalsh(H)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(lam[..., 0] > 0.0, lam[..., -1] / np.where(lam[..., 0] > 0.0, lam[..., 0], 1.0), np.inf)


def _rotation_svd(c1, c2, w):
    """Arun/Umeyama rotation (``R c2 ~ c1``) for centred points ``(..., n, 3)``; reflection fixed."""
    Hc = np.einsum("...n,...ni,...nj->...ij", w, c2, c1)  # sum w c2 c1^T
    U, _, Vt = np.linalg.svd(Hc)
    V = np.swapaxes(Vt, -1, -2)
    d = np.sign(np.linalg.det(V @ np.swapaxes(U, -1, -2)))
    d = np.where(d == 0.0, 1.0, d)
    D = np.broadcast_to(np.eye(3), d.shape + (3, 3)).copy()
    D[..., 2, 2] = d
    return V @ D @ np.swapaxes(U, -1, -2)


def _horn_matrix(c1, c2, w):
    """Horn's symmetric 4x4 ``N`` from ``S = sum w c2 c1^T`` (left = 2p, right = 1p)."""
    S = np.einsum("...n,...ni,...nj->...ij", w, c2, c1)
    sxx, sxy, sxz = S[..., 0, 0], S[..., 0, 1], S[..., 0, 2]
    syx, syy, syz = S[..., 1, 0], S[..., 1, 1], S[..., 1, 2]
    szx, szy, szz = S[..., 2, 0], S[..., 2, 1], S[..., 2, 2]
    return np.stack(
        [
            np.stack([sxx + syy + szz, syz - szy, szx - sxz, sxy - syx], -1),
            np.stack([syz - szy, sxx - syy - szz, sxy + syx, szx + sxz], -1),
            np.stack([szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy], -1),
            np.stack([sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz], -1),
        ],
        -2,
    )


def _rotation_horn(c1, c2, w):
    """Horn's unit-quaternion rotation: eigenvector of the largest eigenvalue of ``N``."""
    _, vec = np.linalg.eigh(_horn_matrix(c1, c2, w))
    return quaternion_to_matrix(vec[..., :, -1])


def _difference_system(p1, p2, w, R0):
    """Normal equations of Eq. 148-154 for ``2p`` pre-rotated by ``R0``: ``M x = r`` plus the blocks' data."""
    zeta = (p2[..., :-1, :] - p2[..., 1:, :]) @ R0.T  # zeta_i (pre-rotated)
    rho = p1[..., :-1, :] - p1[..., 1:, :]  # rho_i
    wa, wb = w[..., :-1], w[..., 1:]
    wd = np.where(wa + wb > 0.0, wa * wb / np.where(wa + wb > 0.0, wa + wb, 1.0), 0.0)
    a = zeta + rho  # Eq. 150 / 153: A_q blocks Q(a_i)
    b = zeta - rho  # Eq. 151 / 154: b_q blocks
    # A^T W A = sum w (|a|^2 I - a a^T);  A^T W b = sum w Q(a)^T b = sum w (b x a)
    M = _inertia(a, wd)
    r = np.einsum("...n,...nk->...k", wd, np.cross(b, a))
    return M, r, a, wd


def _rotation_rodrigues(p1, p2, w, return_parts=False):
    """The thesis's method (Eq. 148-156) with pre-rotation candidates; ``R (..., 3, 3)`` (NaN where degenerate).

    Candidate selection: a candidate is usable when the smallest eigenvalue of its normal matrix is at least a tenth
    of the largest smallest eigenvalue among the candidates (a nearly singular system - the un-rotated one near
    ``theta = pi`` - can return a small but meaningless ``x_q``); among the usable ones the smallest ``|x_q'|``
    (smallest residual rotation) wins.
    """
    xs, lams = [], []
    for R0 in _PRE_ROTATIONS:
        M, r, _, _ = _difference_system(p1, p2, w, R0)
        ok = _condition(M) < 1e12
        Ms = np.where(ok[..., None, None], M, np.eye(3))
        xs.append(np.linalg.solve(Ms, r[..., None])[..., 0])  # Eq. 152
        lams.append(np.where(ok, np.linalg.eigvalsh(M)[..., 0], -np.inf))
    xs, lams = np.stack(xs), np.stack(lams)  # (4, ..., 3), (4, ...)
    usable = np.isfinite(lams) & (lams >= 0.1 * lams.max(axis=0))
    norms = np.where(usable, np.linalg.norm(xs, axis=-1), np.inf)
    best_k = np.argmin(norms, axis=0)
    valid = np.isfinite(np.min(norms, axis=0))
    x = np.take_along_axis(xs, best_k[None, ..., None], axis=0)[0]
    x = np.where(valid[..., None], x, 0.0)
    Rp = quaternion_to_matrix(rodrigues_to_quaternion(x))  # Eq. 155-156, 133, 136
    R = Rp @ _PRE_ROTATIONS[best_k]
    R = np.where(valid[..., None, None], R, np.nan)
    if return_parts:
        return R, x, best_k
    return R


def fit_rotation(p1, p2, w, method):
    """Rotation ``R (..., 3, 3)`` with ``R 2p ~ 1p - t`` for validated, batched sets ``(..., n, 3)``, no checks.

    For the Rodrigues method the points are used in the given order (consecutive differences). Used by RANSAC.
    """
    if method not in METHODS:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    if method == "rodrigues":
        return _rotation_rodrigues(p1, p2, w)
    _, c1 = _centre(p1, w)
    _, c2 = _centre(p2, w)
    return _rotation_svd(c1, c2, w) if method == "svd" else _rotation_horn(c1, c2, w)


def _failure(message, method, n_points, N, condition=np.nan):
    nan3 = np.full((3, 3), np.nan)
    return AbsoluteOrientationResult(
        success=False, message=message, R=nan3, t=np.full(3, np.nan), T=np.full((4, 4), np.nan), rms=np.nan,
        condition=float(condition), method=method, n_points=n_points, residuals=np.full(N, np.nan),
        covariance=np.full((6, 6), np.nan),
    )


def absolute_orientation(p1, p2, weights=None, method="svd", max_condition=MAX_CONDITION):
    """Rigid transform ``T_1_2`` with ``R 2p_i + t = 1p_i`` (Eq. 124-125) by one of :data:`METHODS`.

    Parameters
    ----------
    p1, p2 : array_like (N, 3)
        Corresponding points in frame 1 and frame 2 (m).
    weights : array_like (N,), optional
        Relative inverse variances of the points (>= 0); zero excludes a point.
    method : {"rodrigues", "svd", "horn"}
        Thesis Eq. 137-156, Arun/Umeyama SVD [21], or Horn's quaternion.
    max_condition : float
        Refuse poses whose point-spread condition number (see :class:`AbsoluteOrientationResult`) is larger.

    Returns
    -------
    AbsoluteOrientationResult
        ``success=False`` with the reason for fewer than 3 usable points or a (nearly) collinear spread.

    Raises
    ------
    ValueError
        Malformed input: wrong shapes, mismatched sets, NaN/inf, negative weights, unknown method.
    """
    if method not in METHODS:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    p1, p2, w = check_point_sets(p1, p2, weights)
    N = len(p1)
    use = w > 0.0
    n = int(np.count_nonzero(use))
    if n < 3:
        return _failure(f"absolute orientation needs >= 3 points with non-zero weight, got {n}", method, n, N)
    q1, q2, wu = p1[use], p2[use], w[use]
    p2bar, c2 = _centre(q2, wu)
    condition = float(_condition(_inertia(c2, wu)))
    if not condition < max_condition:
        return _failure(
            f"points are collinear or coincident (condition {condition:.3g} > {max_condition:.3g})",
            method, n, N, condition,
        )
    R = fit_rotation(q1, q2, wu, method)
    if not np.all(np.isfinite(R)):
        return _failure("rotation could not be determined (degenerate differences)", method, n, N, condition)
    t = np.sum(wu[:, None] * (q1 - q2 @ R.T), axis=0) / np.sum(wu)  # Eq. 125 (weighted)
    e = p1 - p2 @ R.T - t
    residuals = np.linalg.norm(e, axis=1)
    rms = float(np.sqrt(np.sum(w * residuals**2) / np.sum(w)))
    dof = 3 * n - 6
    covariance = np.full((6, 6), np.nan)
    if dof > 0:
        sigma = np.sqrt(np.sum(w * residuals**2) / dof)
        covariance = predicted_covariance(p1, p2, R, sigma, weights=w, method=method)
    message = (f"ok, but ill-conditioned (condition {condition:.3g}): points nearly collinear"
               if condition > WARN_CONDITION else "ok")
    return AbsoluteOrientationResult(
        success=True, message=message, R=R, t=t, T=homogeneous(R, t), rms=rms, condition=condition, method=method,
        n_points=n, residuals=residuals, covariance=covariance,
    )


def predicted_covariance(p1, p2, R, sigma, weights=None, method="svd"):
    """First-order covariance ``(6, 6)`` of ``(dphi, dt)`` for an estimate by ``method`` (see module docstring).

    Parameters
    ----------
    p1, p2 : array_like (N, 3)
        The (true or estimated) corresponding points (m); the Rodrigues method uses their order.
    R : array_like (3, 3)
        ``R_1_2`` at which to linearise.
    sigma : float
        Per-axis standard deviation (m) of the combined noise ``nu_i = n1_i - R n2_i`` of a unit-weight point
        (``sigma^2 = sigma_1^2 + sigma_2^2`` for independent isotropic noise on both sets).
    weights : array_like (N,), optional
        Relative inverse variances: point i has per-axis variance ``sigma^2 / w_i``.
    method : {"rodrigues", "svd", "horn"}

    Returns
    -------
    ndarray (6, 6)
        Order ``(dphi_x, dphi_y, dphi_z, dt_x, dt_y, dt_z)``; ``dphi`` (rad) is the left rotation error
        ``R_hat = exp([dphi]x) R`` in the 1p frame, ``dt`` (m) the error of ``t``.
    """
    if method not in METHODS:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    p1, p2, w = check_point_sets(p1, p2, weights)
    R = np.asarray(R, dtype=float)
    use = w > 0.0
    p1, p2, w = p1[use], p2[use], w[use]
    n = len(w)
    W = np.sum(w)
    p2bar, c2 = _centre(p2, w)
    c = c2 @ R.T  # centred points in the 1p frame (model-consistent)
    m = R @ p2bar
    # G: d(dphi) / d(nu_j), shape (n, 3, 3)
    if method in ("svd", "horn"):
        Hinv = np.linalg.inv(_inertia(c, w))
        G = -np.einsum("ij,njk->nik", Hinv, w[:, None, None] * np.swapaxes(skew(c), -1, -2))  # -H^-1 w_j [c_j]x^T
    else:
        # the candidate the estimator picks on these points, linearised at R
        _, _, k = _rotation_rodrigues(p1, p2, w, return_parts=True)
        k = int(k)
        Rp = R @ _PRE_ROTATIONS[k].T  # residual rotation after the pre-rotation, R = Rp R0
        x = np.array([Rp[2, 1] - Rp[1, 2], Rp[0, 2] - Rp[2, 0], Rp[1, 0] - Rp[0, 1]]) / (1.0 + np.trace(Rp))
        M, _, a, wd = _difference_system(p1, p2, w, _PRE_ROTATIONS[k])
        ImX = np.eye(3) - skew(x)
        B = wd[:, None, None] * (np.swapaxes(skew(a), -1, -2) @ ImX)  # w'_i Q(a_i)^T (I - [x]x), (n - 1, 3, 3)
        Gx = np.zeros((n, 3, 3))
        Gx[:-1] -= B  # residual i depends on +nu_i
        Gx[1:] += B  # ... and on -nu_(i+1)
        Minv = np.linalg.inv(M)
        Gx = np.einsum("ij,njk->nik", Minv, Gx)
        G = np.einsum("ij,njk->nik", rodrigues_jacobian(x), Gx)
    # dt = nu_bar + [m]x dphi
    Gt = (w / W)[:, None, None] * np.eye(3) + np.einsum("ij,njk->nik", skew(m), G)
    Gall = np.concatenate([G, Gt], axis=1)  # (n, 6, 3)
    return sigma**2 * np.einsum("nij,n,nkj->ik", Gall, 1.0 / w, Gall)


def random_correspondences(rng: np.random.Generator, n, *, spread=0.5, sigma1=0.0, sigma2=0.0, T_1_2=None,
                           outlier_fraction=0.0, outlier_distance=(0.1, 1.0)):
    """Synthetic corresponding sets for tests: ``p1 = T_1_2 p2`` plus noise, some pairs replaced by outliers.

    Parameters
    ----------
    rng : numpy.random.Generator
    n : int
        Number of pairs.
    spread : float
        Standard deviation (m) of the 2p points about their centre (normal distribution).
    sigma1, sigma2 : float
        Per-axis noise (m) added to p1 and p2.
    T_1_2 : array_like (4, 4), optional
        The truth; random rotation and translation (std 1 m) when None.
    outlier_fraction : float
        Fraction of pairs (rounded) whose p1 is displaced by a random direction times a distance drawn uniformly
        from ``outlier_distance`` (m).

    Returns
    -------
    p1, p2 : ndarray (n, 3)
    T_1_2 : ndarray (4, 4)
    inlier : ndarray (n,) of bool
    """
    if T_1_2 is None:
        T_1_2 = homogeneous(random_rotation(rng), rng.normal(size=3))
    T_1_2 = np.asarray(T_1_2, dtype=float)
    p2_true = rng.normal(scale=spread, size=(n, 3)) + rng.normal(size=3)
    p1_true = p2_true @ T_1_2[:3, :3].T + T_1_2[:3, 3]
    p1 = p1_true + rng.normal(scale=sigma1, size=(n, 3)) if sigma1 > 0 else p1_true.copy()
    p2 = p2_true + rng.normal(scale=sigma2, size=(n, 3)) if sigma2 > 0 else p2_true.copy()
    inlier = np.ones(n, dtype=bool)
    n_out = int(round(outlier_fraction * n))
    if n_out:
        idx = rng.choice(n, size=n_out, replace=False)
        d = rng.normal(size=(n_out, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        p1[idx] += d * rng.uniform(*outlier_distance, size=(n_out, 1))
        inlier[idx] = False
    return p1, p2, T_1_2, inlier
