"""Linear camera calibration: DLT projection matrix, its decomposition, and the planar (Zhang) path (thesis §3.3).

* :func:`dlt_projection_matrix` - the projection matrix ``M`` (Eq. 54) from 3D-2D correspondences by the eigenvector
  of ``L_o^T L_o`` with the smallest eigenvalue (Eq. 55-58), with Hartley's point normalisation (or without, for
  comparison). Needs a non-planar target (the thesis's rig of two perpendicular planes): for points on one plane the
  DLT is degenerate (the Z-columns of ``L_o`` vanish and the null space has dimension 4); this is detected and
  reported as a one-line ``ValueError``.
* :func:`decompose_projection` - ``rho M = K (R t)`` (Eq. 59-66, after Forsyth & Ponce): the thesis's ``alpha``,
  ``beta``, skew angle ``theta``, ``u0``, ``v0`` and the pose ``T_cam_world``.
* Planar targets (Zhang): :func:`homography_dlt`, :func:`intrinsics_from_homographies` (the absolute-conic
  constraints ``h1^T B h2 = 0``, ``h1^T B h1 = h2^T B h2``) and :func:`pose_from_homography`.

Intrinsic matrix convention (Eq. 50, OpenCV layout): ``K = [[alpha, -alpha cot(theta), u0], [0, beta / sin(theta),
v0], [0, 0, 1]]``, i.e. ``fx = alpha``, ``skew = -alpha cot(theta)``, ``fy = beta / sin(theta)``; pixels, OpenCV camera
frame (x right, y down, z forward).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.geometry.transforms import homogeneous

#: relative singular-value threshold below which a point set counts as planar / collinear
PLANAR_TOL = 1e-9


# ----------------------------------------------------------------------------------------------------------------------
# validation and geometry of the point sets
# ----------------------------------------------------------------------------------------------------------------------
def check_correspondences(X, uv, name_X="X", name_uv="uv", dim=3, min_points=6):
    """Validate ``X (N, dim)`` and ``uv (N, 2)``: finite, matching lengths, at least ``min_points``.

    Returns the two arrays as float; raises a one-line ``ValueError`` naming the field otherwise.
    """
    X = np.asarray(X, dtype=float)
    uv = np.asarray(uv, dtype=float)
    if X.ndim != 2 or X.shape[1] != dim:
        raise ValueError(f"{name_X}: expected shape (N, {dim}), got {X.shape}")
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise ValueError(f"{name_uv}: expected shape (N, 2), got {uv.shape}")
    if len(X) != len(uv):
        raise ValueError(f"{name_uv}: {len(uv)} image points for {len(X)} object points in {name_X}")
    if not np.all(np.isfinite(X)):
        raise ValueError(f"{name_X}: contains NaN or inf")
    if not np.all(np.isfinite(uv)):
        raise ValueError(f"{name_uv}: contains NaN or inf")
    if len(X) < min_points:
        raise ValueError(f"{name_X}: at least {min_points} points are needed, got {len(X)}")
    return X, uv


def point_set_rank(X, tol=PLANAR_TOL) -> int:
    """Affine dimension of the points ``X (N, d)``: 0 (one point), 1 (a line), 2 (a plane), 3 (a volume).

    A direction counts when its singular value of the centred points exceeds ``tol`` times the largest one.
    """
    X = np.asarray(X, dtype=float)
    s = np.linalg.svd(X - X.mean(axis=0), compute_uv=False)
    if s[0] == 0.0:
        return 0
    return int(np.sum(s > tol * s[0]))


def is_planar(X, tol=PLANAR_TOL) -> bool:
    """True when the 3D points ``X (N, 3)`` lie on one plane (or a line) within ``tol`` relative."""
    return point_set_rank(X, tol) <= 2


def plane_frame(X, tol=PLANAR_TOL):
    """Frame of the plane through planar points ``X (N, 3)``: ``T_world_plane (4, 4)``, the points' plane z = 0.

    The origin is the first point, x points along the first principal direction; right-handed. Raises
    ``ValueError`` when the points are not planar or are collinear.
    """
    X = np.asarray(X, dtype=float)
    rank = point_set_rank(X, tol)
    if rank < 2:
        raise ValueError("X: the points are collinear (or coincide): no plane, no calibration")
    if rank > 2:
        raise ValueError("X: the points are not planar")
    _, _, Vt = np.linalg.svd(X - X.mean(axis=0))
    R = Vt.copy()
    if np.linalg.det(R) < 0:
        R[2] *= -1.0
    return homogeneous(R.T, X[0])


def normalization_matrix(x):
    """Hartley normalisation ``T ((d+1), (d+1))`` of points ``x (N, d)``: centroid to 0, mean distance sqrt(d)."""
    x = np.asarray(x, dtype=float)
    d = x.shape[1]
    c = x.mean(axis=0)
    mean_dist = np.mean(np.linalg.norm(x - c, axis=1))
    if not mean_dist > 0:
        raise ValueError("points: all coincide, cannot normalise")
    s = np.sqrt(d) / mean_dist
    T = np.eye(d + 1)
    T[:d, :d] *= s
    T[:d, d] = -s * c
    return T


def _null_vector(L, solver, what):
    """Unit vector minimising ``|L m|``: eigenvector of ``L^T L`` of the smallest eigenvalue (Eq. 58).

    ``solver="svd"`` takes the last right singular vector of ``L`` (the same vector, without squaring the condition
    number); ``solver="eig"`` is Eq. 58 literally. Raises when the minimiser is not unique.
    """
    if solver == "svd":
        _, s, Vt = np.linalg.svd(L, full_matrices=L.shape[0] < L.shape[1])  # full: keep the null space of a wide L
        sv = np.concatenate([s, np.zeros(L.shape[1] - len(s))])  # descending; implicit zeros of a wide L
        m = Vt[-1]
    elif solver == "eig":
        w, V = np.linalg.eigh(L.T @ L)  # ascending
        sv = np.sqrt(np.clip(w[::-1], 0.0, None))
        m = V[:, 0]
    else:
        raise ValueError(f"solver: expected 'svd' or 'eig', got {solver!r}")
    if sv[-2] <= 1e3 * np.finfo(float).eps * sv[0]:
        raise ValueError(f"{what}: the linear system has a null space of dimension > 1 (degenerate configuration)")
    return m


# ----------------------------------------------------------------------------------------------------------------------
# DLT (Eq. 55-58)
# ----------------------------------------------------------------------------------------------------------------------
def observation_matrix(X, uv):
    """The observation matrix ``L_o (2N, 12)`` of Eq. 55 for points ``X (N, 3)`` and pixels ``uv (N, 2)``."""
    X = np.asarray(X, dtype=float)
    uv = np.asarray(uv, dtype=float)
    n = len(X)
    Xh = np.hstack([X, np.ones((n, 1))])
    L = np.zeros((2 * n, 12))
    L[0::2, 0:4] = Xh  # Eq. 55, u rows
    L[0::2, 8:12] = -uv[:, :1] * Xh
    L[1::2, 4:8] = Xh  # v rows
    L[1::2, 8:12] = -uv[:, 1:] * Xh
    return L


def dlt_projection_matrix(X, uv, normalize: bool = True, solver: str = "svd"):
    """Projection matrix ``M (3, 4)`` with ``[u v 1]^T ~ M [X 1]^T`` by the DLT (Eq. 55-58).

    Parameters
    ----------
    X : array (N, 3)
        Object points in the target (world) frame, N >= 6, not all on one plane (any unit, e.g. m).
    uv : array (N, 2)
        Their pixels (undistorted for an exact fit).
    normalize : bool
        Hartley normalisation of both point sets before building ``L_o`` (recommended; ``False`` is the thesis's
        plain Eq. 55-58, kept for comparison).
    solver : {"svd", "eig"}
        See :func:`_null_vector`; "eig" is Eq. 58 literally.

    Returns
    -------
    M : ndarray (3, 4)
        Scaled to unit Frobenius norm, sign such that ``det(M[:, :3]) > 0``.

    Raises
    ------
    ValueError
        NaN, wrong shapes, fewer than 6 points, planar or collinear points (one line, naming the cause).
    """
    X, uv = check_correspondences(X, uv)
    rank = point_set_rank(X)
    if rank < 2:
        raise ValueError("X: the points are collinear (or coincide): the DLT needs a non-planar 3D target")
    if rank == 2:
        raise ValueError("X: all points lie on one plane: the DLT is degenerate for a planar target "
                         "(use the homography path, intrinsics_from_homographies, with several views)")
    if point_set_rank(uv) < 2:
        raise ValueError("uv: the image points are collinear: degenerate view")
    if normalize:
        T2 = normalization_matrix(uv)
        T3 = normalization_matrix(X)
        Xn = (T3[:3, :3] @ X.T).T + T3[:3, 3]
        uvn = (T2[:2, :2] @ uv.T).T + T2[:2, 2]
    else:
        Xn, uvn = X, uv
    m = _null_vector(observation_matrix(Xn, uvn), solver, "X")  # Eq. 57-58
    M = m.reshape(3, 4)  # Eq. 56
    if normalize:
        M = np.linalg.solve(T2, M @ T3)
    M = M / np.linalg.norm(M)
    if np.linalg.det(M[:, :3]) < 0:
        M = -M
    return M


def project(M, X):
    """Pixels ``uv (N, 2)`` of points ``X (N, 3)`` through ``M (3, 4)`` (Eq. 195)."""
    X = np.asarray(X, dtype=float)
    p = X @ M[:, :3].T + M[:, 3]
    return p[:, :2] / p[:, 2:]


def reprojection_rms(M, X, uv) -> float:
    """The thesis's chi (Eq. 196): RMS over points of the pixel distance between ``uv`` and the projection (px)."""
    d = project(M, X) - np.asarray(uv, dtype=float)
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


# ----------------------------------------------------------------------------------------------------------------------
# decomposition (Eq. 59-66)
# ----------------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class DecomposedCamera:
    """``rho M = K (R t)`` of Eq. 59, with the thesis's intrinsic parameters.

    Attributes
    ----------
    K : ndarray (3, 3)
        Intrinsic matrix (Eq. 50) in OpenCV layout, with skew ``K[0, 1] = -alpha cot(theta)`` (px).
    T_cam_world : ndarray (4, 4)
        Pose of the target (world) frame in the camera frame (``R``, ``t`` of Eq. 52; t in the unit of X).
    alpha, beta : float
        Magnifications of Eq. 65-66 (px); ``K[1, 1] = beta / sin(theta)``.
    theta : float
        Angle between the sensor axes (rad), pi/2 for no skew (Eq. 64).
    u0, v0 : float
        Principal point (px), Eq. 62-63.
    rho : float
        Scale factor of Eq. 60, with the sign epsilon that makes R a rotation.
    """

    K: np.ndarray
    T_cam_world: np.ndarray
    alpha: float
    beta: float
    theta: float
    u0: float
    v0: float
    rho: float

    @property
    def R_cam_world(self) -> np.ndarray:
        return self.T_cam_world[:3, :3]

    @property
    def t_cam_world(self) -> np.ndarray:
        return self.T_cam_world[:3, 3]


def intrinsic_matrix(alpha, beta, theta, u0, v0):
    """``K (3, 3)`` of Eq. 50 from the thesis's parameters (px, rad)."""
    return np.array([[alpha, -alpha / np.tan(theta), u0], [0.0, beta / np.sin(theta), v0], [0.0, 0.0, 1.0]])


def thesis_parameters(K):
    """Inverse of :func:`intrinsic_matrix`: ``(alpha, beta, theta, u0, v0)`` from an upper-triangular ``K``."""
    K = np.asarray(K, dtype=float)
    alpha = K[0, 0]
    theta = np.arctan2(alpha, -K[0, 1])  # cot(theta) = -K01 / alpha
    beta = K[1, 1] * np.sin(theta)
    return float(alpha), float(beta), float(theta), float(K[0, 2]), float(K[1, 2])


def decompose_projection(M, X=None) -> DecomposedCamera:
    """Intrinsic and extrinsic parameters from a projection matrix (Eq. 59-66).

    Parameters
    ----------
    M : array (3, 4)
        Any scale and sign (e.g. from :func:`dlt_projection_matrix`).
    X : array (N, 3), optional
        Object points; when given, checks that they lie in front of the camera (z > 0) and raises otherwise.

    Returns
    -------
    DecomposedCamera

    Notes
    -----
    Eq. 60 leaves the sign ``epsilon`` open. Only one sign admits ``K`` with positive ``alpha``, ``beta / sin(theta)``
    and a proper rotation: ``det(K) > 0`` and ``det(R) = 1`` force ``sign(rho^3 det(A)) > 0``, hence
    ``epsilon = sign(det(A))`` with ``A = M[:, :3]``. If the points then lie behind the camera, the correspondences are
    mirrored (a left-handed target frame): this is reported instead of returning a reflection.
    """
    M = np.asarray(M, dtype=float)
    if M.shape != (3, 4) or not np.all(np.isfinite(M)):
        raise ValueError(f"M: expected a finite (3, 4) projection matrix, got shape {M.shape}")
    A, b = M[:, :3], M[:, 3]
    a1, a2, a3 = A
    det = np.linalg.det(A)
    if abs(det) <= 1e-12 * np.linalg.norm(A) ** 3:
        raise ValueError("M: the left 3x3 block is singular (camera at infinity or degenerate estimate)")
    eps = 1.0 if det > 0 else -1.0
    rho = eps / np.linalg.norm(a3)  # Eq. 60
    r3 = rho * a3  # Eq. 61
    u0 = rho**2 * (a1 @ a3)  # Eq. 62
    v0 = rho**2 * (a2 @ a3)  # Eq. 63
    c13, c23 = np.cross(a1, a3), np.cross(a2, a3)
    n13, n23 = np.linalg.norm(c13), np.linalg.norm(c23)
    theta = np.arccos(np.clip(-(c13 @ c23) / (n13 * n23), -1.0, 1.0))  # Eq. 64
    alpha = rho**2 * n13 * np.sin(theta)  # Eq. 65
    beta = rho**2 * n23 * np.sin(theta)  # Eq. 66
    r1 = c23 / n23  # Forsyth & Ponce: r1 = rho^2 sin(theta) / beta (a2 x a3)
    r2 = np.cross(r3, r1)
    R = np.vstack([r1, r2, r3])
    K = intrinsic_matrix(alpha, beta, theta, u0, v0)
    t = rho * np.linalg.solve(K, b)  # Eq. 59: rho b = K t
    T = homogeneous(R, t)
    if X is not None:
        X = np.asarray(X, dtype=float)
        z = X @ r3 + t[2]
        if np.any(z <= 0):
            raise ValueError(f"X: {int(np.sum(z <= 0))} of {len(z)} points lie behind the camera for the only sign "
                             "that makes R a rotation (mirrored correspondences or a left-handed target frame)")
    return DecomposedCamera(K, T, float(alpha), float(beta), float(theta), float(u0), float(v0), float(rho))


def compose_projection(K, T_cam_world):
    """``M = K (R t)`` (Eq. 54), shape (3, 4)."""
    return np.asarray(K, dtype=float) @ np.asarray(T_cam_world, dtype=float)[:3, :]


# ----------------------------------------------------------------------------------------------------------------------
# planar targets (Zhang)
# ----------------------------------------------------------------------------------------------------------------------
def homography_dlt(xy, uv, normalize: bool = True):
    """Homography ``H (3, 3)`` with ``[u v 1]^T ~ H [x y 1]^T`` for points ``xy (N, 2)`` on the target plane.

    Normalised DLT (the planar analogue of Eq. 55-58), ``|H| = 1``, ``H[2, 2] >= 0``. Raises ``ValueError`` for fewer
    than 4 points, NaN, collinear points.
    """
    xy, uv = check_correspondences(xy, uv, "xy", "uv", dim=2, min_points=4)
    if point_set_rank(xy) < 2:
        raise ValueError("xy: the target points are collinear: no homography")
    if point_set_rank(uv) < 2:
        raise ValueError("uv: the image points are collinear: degenerate view")
    if normalize:
        Ta, Tb = normalization_matrix(xy), normalization_matrix(uv)
        xy = xy @ Ta[:2, :2].T + Ta[:2, 2]
        uv = uv @ Tb[:2, :2].T + Tb[:2, 2]
    n = len(xy)
    xh = np.hstack([xy, np.ones((n, 1))])
    L = np.zeros((2 * n, 9))
    L[0::2, 0:3] = xh
    L[0::2, 6:9] = -uv[:, :1] * xh
    L[1::2, 3:6] = xh
    L[1::2, 6:9] = -uv[:, 1:] * xh
    H = _null_vector(L, "svd", "xy").reshape(3, 3)
    if normalize:
        H = np.linalg.solve(Tb, H @ Ta)
    H = H / np.linalg.norm(H)
    return -H if H[2, 2] < 0 else H


def _v(H, i, j):
    h_i, h_j = H[:, i], H[:, j]
    return np.array([h_i[0] * h_j[0], h_i[0] * h_j[1] + h_i[1] * h_j[0], h_i[1] * h_j[1],
                     h_i[2] * h_j[0] + h_i[0] * h_j[2], h_i[2] * h_j[1] + h_i[1] * h_j[2], h_i[2] * h_j[2]])


def intrinsics_from_homographies(Hs, skew: bool = True, image_size=None):
    """Zhang's closed-form ``K (3, 3)`` from the homographies ``Hs (V, 3, 3)`` of V views of a plane.

    Parameters
    ----------
    Hs : array (V, 3, 3)
    skew : bool
        Estimate the skew (needs V >= 3); ``False`` adds the constraint of zero skew (V >= 2).
    image_size : (width, height), optional
        Used to condition the linear system (pixels scaled to about +-1). With V = 1, or V = 2 and ``skew=True``,
        the principal point is fixed at the image centre ``((w - 1) / 2, (h - 1) / 2)`` and zero skew assumed (V = 1
        also square pixels); without ``image_size`` such a call raises.

    Returns
    -------
    K : ndarray (3, 3)

    Raises
    ------
    ValueError
        Too few views, or views that do not constrain K (e.g. all parallel to the image plane): one line.
    """
    Hs = np.asarray(Hs, dtype=float)
    if Hs.ndim != 3 or Hs.shape[1:] != (3, 3) or not np.all(np.isfinite(Hs)):
        raise ValueError(f"Hs: expected finite (V, 3, 3) homographies, got shape {Hs.shape}")
    V = len(Hs)
    fix_pp = V == 1 or (V == 2 and skew)
    if image_size is not None:
        w, h = image_size
        c = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
        scale = 0.5 * max(w, h)
    elif fix_pp:
        raise ValueError(f"Hs: {V} view(s) of a plane do not determine K; give image_size to fix the principal "
                         "point at the image centre, or use more views")
    else:  # conditioning from the images of the target origins
        o = Hs[:, :2, 2] / Hs[:, 2:, 2]
        c = o.mean(axis=0)
        scale = max(float(np.mean(np.linalg.norm(o - c, axis=1))), float(np.linalg.norm(c)), 1.0)
    # pixels -> conditioned coordinates: x' = N x; K = N^-1 K'
    N = np.array([[1.0 / scale, 0.0, -c[0] / scale], [0.0, 1.0 / scale, -c[1] / scale], [0.0, 0.0, 1.0]])
    rows = []
    for H in np.einsum("ij,vjk->vik", N, Hs):
        H = H / np.linalg.norm(H)
        rows += [_v(H, 0, 1), _v(H, 0, 0) - _v(H, 1, 1)]
    Vm = np.array(rows)  # b = [B11, B12, B22, B13, B23, B33]
    if fix_pp:  # principal point at the (conditioned) origin, zero skew: b = [B11, 0, B22, 0, 0, B33]
        Vm = Vm[:, [0, 2, 5]]
        try:
            b11, b22, b33 = _null_vector(Vm, "svd", "Hs")
            ok = b11 / b33 < 0 and b22 / b33 < 0
        except ValueError:
            ok = False
        if not ok:  # a tilt about one image axis only leaves fx or fy free: add square pixels B11 = B22
            b11, b22, b33 = _null_vector(np.vstack([Vm, [1.0, -1.0, 0.0]]), "svd", "Hs")
        if not (b11 / b33 < 0 and b22 / b33 < 0):
            raise ValueError("Hs: the view(s) do not constrain the focal length (target parallel to the image?)")
        Kc = np.diag([np.sqrt(-b33 / b11), np.sqrt(-b33 / b22), 1.0])
        return np.linalg.solve(N, Kc)
    if not skew:
        Vm = np.vstack([Vm, [0.0, 1.0, 0.0, 0.0, 0.0, 0.0]])
    if V < 2 or (skew and V < 3):
        raise ValueError(f"Hs: {V} views are too few for the closed-form intrinsics")
    B11, B12, B22, B13, B23, B33 = _null_vector(Vm, "svd", "Hs")
    # Zhang (2000), Appendix B
    den = B11 * B22 - B12**2
    if B11 == 0 or den == 0:
        raise ValueError("Hs: degenerate image of the absolute conic")
    v0 = (B12 * B13 - B11 * B23) / den
    lam = B33 - (B13**2 + v0 * (B12 * B13 - B11 * B23)) / B11
    if not (lam / B11 > 0 and lam * B11 / den > 0):
        raise ValueError("Hs: the image of the absolute conic is not positive definite (degenerate views or noise)")
    fx = np.sqrt(lam / B11)
    fy = np.sqrt(lam * B11 / den)
    s_ = -B12 * fx**2 * fy / lam
    u0 = s_ * v0 / fy - B13 * fx**2 / lam
    Kc = np.array([[fx, s_, u0], [0.0, fy, v0], [0.0, 0.0, 1.0]])
    return np.linalg.solve(N, Kc)


def pose_from_homography(K, H):
    """Pose ``T_cam_plane (4, 4)`` of the target plane (z = 0) from ``K`` and its homography ``H`` (Zhang).

    ``[r1 r2 t] = lambda K^-1 H``, ``r3 = r1 x r2``, the rotation projected onto SO(3) (SVD); the sign such that the
    target lies in front of the camera (t_z > 0).
    """
    A = np.linalg.solve(np.asarray(K, dtype=float), np.asarray(H, dtype=float))
    lam = 2.0 / (np.linalg.norm(A[:, 0]) + np.linalg.norm(A[:, 1]))
    if A[2, 2] < 0:
        lam = -lam
    r1, r2, t = lam * A[:, 0], lam * A[:, 1], lam * A[:, 2]
    Q = np.column_stack([r1, r2, np.cross(r1, r2)])
    U, _, Wt = np.linalg.svd(Q)
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Wt)]) @ Wt
    return homogeneous(R, t)


def pose_from_projection(K, M):
    """Pose ``T_cam_world (4, 4)`` from ``K`` and a projection matrix ``M (3, 4)`` of a non-planar target.

    ``(R t) = lambda K^-1 M`` with ``det R > 0``, R projected onto SO(3).
    """
    A = np.linalg.solve(np.asarray(K, dtype=float), np.asarray(M, dtype=float))
    lam = 1.0 / np.cbrt(np.linalg.det(A[:, :3]))
    A = lam * A
    U, _, Wt = np.linalg.svd(A[:, :3])
    return homogeneous(U @ Wt, A[:, 3])
