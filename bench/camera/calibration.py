"""Camera calibration from views of a known target (thesis §3.3, Eq. 54-76, 195-196; Zhang; Heikkilä).

Pipeline of :func:`calibrate_camera`:

1. linear initialisation: per non-planar view the DLT (Eq. 55-58) and its decomposition (Eq. 59-66), the intrinsic
   matrices averaged over the views as the thesis does for Table 3; for planar views Zhang's closed form from the
   homographies (one plane is degenerate for the DLT), poses from ``K`` and ``H``;
2. radial distortion by alternation (Eq. 67-73): linear least squares for ``k1, k2`` given the pinhole model, then the
   pinhole model re-estimated from the corrected pixels, until the coefficients settle;
3. Levenberg-Marquardt over all views (Eq. 74) with the chosen model, analytic Jacobian: ``"heikkila"`` = radial +
   tangential (Eq. 75-76: ``k1, k2, p1, p2`` and optionally ``k3``), ``"radial"`` = ``k1, k2``, ``"pinhole"`` = none;
4. Heikkilä's implicit inverse model for undistortion (Eq. 77-86) is fitted to the result by
   :func:`bench.camera.heikkila.fit_implicit_inverse` (``result.camera``).

Conventions: OpenCV camera frame and distortion order ``(k1, k2, p1, p2[, k3])``; Eq. 75-76 are this model with
``fx = s_u f``, ``fy = f`` and no skew (Eq. 75 prints ``k2 v^5`` for ``k2 u^5`` and Eq. 76 ``k1 u^2 v^2`` for
``k1 u^2 v``: the radial terms are ``k r^2 u`` and ``k r^4 u``). Pixels ``u = fx x_d + s y_d + cx``,
``v = fy y_d + cy`` with ``s = -alpha cot(theta)`` (Eq. 50). The reprojection RMS is the thesis's chi (Eq. 196): the
root mean square over points of the pixel distance, which is also what ``cv2.calibrateCamera`` returns.

Uncertainty: ``cov = sigma^2 (J^T J)^-1`` at the optimum, ``sigma^2 = |r|^2 / (2N - P)`` (residual variance per
coordinate), the intrinsic block of the full inverse (i.e. marginalised over the poses).
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field, replace

import numpy as np

from bench.camera import dlt
from bench.camera.model import distort
from bench.geometry.quaternion import rotation_vector_to_matrix
from bench.geometry.transforms import homogeneous, invert, skew, transform_points

MODELS = ("heikkila", "radial", "pinhole")
#: each distortion coefficient's place in OpenCV's (k1, k2, p1, p2, k3)
_DIST_INDEX = {"k1": 0, "k2": 1, "p1": 2, "p2": 3, "k3": 4}
#: condition number of the column-scaled Jacobian above which the parameters count as undetermined
COND_LIMIT = 1e10


def distortion_names(model: str, k3: bool = False) -> list[str]:
    """Names of the estimated distortion coefficients of ``model`` (OpenCV order)."""
    if model == "heikkila":
        return ["k1", "k2", "p1", "p2"] + (["k3"] if k3 else [])
    if model == "radial":
        return ["k1", "k2"] + (["k3"] if k3 else [])
    if model == "pinhole":
        return []
    raise ValueError(f"model: expected one of {MODELS}, got {model!r}")


def _full_dist(model, d):
    """OpenCV 5-vector ``(k1, k2, p1, p2, k3)`` from the estimated coefficients ``d`` of ``model``."""
    out = np.zeros(5)
    if model == "heikkila":
        out[: len(d)] = d
    elif model == "radial":
        out[:2] = d[:2]
        if len(d) == 3:
            out[4] = d[2]
    return out


# ----------------------------------------------------------------------------------------------------------------------
# projection with analytic derivatives
# ----------------------------------------------------------------------------------------------------------------------
def _distortion_jacobians(x, y, dist5):
    """Partial derivatives of the OpenCV/Heikkilä distortion (Eq. 75-76) at normalised ``x, y (N,)``.

    Returns ``D_xy (N, 2, 2)`` (d(x_d, y_d)/d(x, y), from :func:`bench.camera.model.distortion_jacobian`) and
    ``D_k (N, 2, 5)`` (d(x_d, y_d)/d(k1, k2, p1, p2, k3)).
    """
    from bench.camera.model import distortion_jacobian

    D_xy = distortion_jacobian(np.column_stack([x, y]), dist5)
    r2 = x * x + y * y
    D_k = np.empty(x.shape + (2, 5))
    D_k[:, 0, 0], D_k[:, 1, 0] = x * r2, y * r2
    D_k[:, 0, 1], D_k[:, 1, 1] = x * r2**2, y * r2**2
    D_k[:, 0, 2], D_k[:, 1, 2] = 2 * x * y, r2 + 2 * y * y
    D_k[:, 0, 3], D_k[:, 1, 3] = r2 + 2 * x * x, 2 * x * y
    D_k[:, 0, 4], D_k[:, 1, 4] = x * r2**3, y * r2**3
    return D_xy, D_k


@dataclass
class _State:
    """Parameters of the bundle: intrinsics, estimated distortion, poses ``R (V, 3, 3)``, ``t (V, 3)``."""

    fx: float
    fy: float
    cx: float
    cy: float
    skew: float
    dist: np.ndarray
    R: np.ndarray
    t: np.ndarray

    def K(self):
        return np.array([[self.fx, self.skew, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def copy(self):
        return _State(self.fx, self.fy, self.cx, self.cy, self.skew, self.dist.copy(), self.R.copy(), self.t.copy())


class _Problem:
    """The stacked least-squares problem over all views (Eq. 74)."""

    def __init__(self, object_points, image_points, model, k3, fit_skew):
        self.X = object_points
        self.uv = image_points
        self.model, self.k3, self.fit_skew = model, k3, fit_skew
        self.dist_names = distortion_names(model, k3)
        self.intr_names = ["fx", "fy", "cx", "cy"] + (["skew"] if fit_skew else []) + self.dist_names
        self.n_intr = len(self.intr_names)
        self.n_views = len(object_points)
        self.offsets = np.concatenate([[0], np.cumsum([len(x) for x in object_points])])
        # columns of the 5-vector that are estimated
        self.dist_cols = [_DIST_INDEX[n] for n in self.dist_names]

    @property
    def n_params(self):
        return self.n_intr + 6 * self.n_views

    def residuals(self, s: _State, jacobian: bool = False):
        """Predicted minus observed pixels, stacked ``(2N,)`` as (u, v) per point; optionally ``J (2N, P)``."""
        dist5 = _full_dist(self.model, s.dist)
        N = self.offsets[-1]
        r = np.empty((N, 2))
        J = np.zeros((2 * N, self.n_params)) if jacobian else None
        for v in range(self.n_views):
            sl = slice(self.offsets[v], self.offsets[v + 1])
            RX = self.X[v] @ s.R[v].T
            Xc = RX + s.t[v]
            z = Xc[:, 2]
            x, y = Xc[:, 0] / z, Xc[:, 1] / z  # Eq. 46
            xd = distort(np.column_stack([x, y]), dist5)  # Eq. 75-76 (the one distortion implementation)
            u = s.fx * xd[:, 0] + s.skew * xd[:, 1] + s.cx  # Eq. 50
            w = s.fy * xd[:, 1] + s.cy
            r[sl] = np.column_stack([u, w]) - self.uv[v]
            if not jacobian:
                continue
            rows = np.arange(2 * self.offsets[v], 2 * self.offsets[v + 1])
            ru, rv = rows[0::2], rows[1::2]
            n = len(x)
            D_xy, D_k = _distortion_jacobians(x, y, dist5)
            A = np.array([[s.fx, s.skew], [0.0, s.fy]])  # d(u, v) / d(x_d, y_d)
            # intrinsics
            J[ru, 0] = xd[:, 0]
            J[rv, 1] = xd[:, 1]
            J[ru, 2] = 1.0
            J[rv, 3] = 1.0
            c = 4
            if self.fit_skew:
                J[ru, 4] = xd[:, 1]
                c = 5
            if self.dist_cols:
                Jk = np.einsum("ij,njk->nik", A, D_k[:, :, self.dist_cols])
                J[ru, c:c + len(self.dist_cols)] = Jk[:, 0]
                J[rv, c:c + len(self.dist_cols)] = Jk[:, 1]
            # pose: X_cam = exp(dw) R X + t  ->  d X_cam / d dw = -[R X]x, d X_cam / d t = I
            P = np.zeros((n, 2, 3))  # d(x, y) / d X_cam
            P[:, 0, 0] = 1.0 / z
            P[:, 0, 2] = -x / z
            P[:, 1, 1] = 1.0 / z
            P[:, 1, 2] = -y / z
            B = np.einsum("ij,njk,nkl->nil", A, D_xy, P)  # d(u, v) / d X_cam, (n, 2, 3)
            Jw = -np.einsum("nij,njk->nik", B, skew(RX))
            col = self.n_intr + 6 * v
            J[ru, col:col + 3] = Jw[:, 0]
            J[rv, col:col + 3] = Jw[:, 1]
            J[ru, col + 3:col + 6] = B[:, 0]
            J[rv, col + 3:col + 6] = B[:, 1]
        return (r.ravel(), J) if jacobian else r.ravel()

    def intrinsic_vector(self, s: _State):
        head = [s.fx, s.fy, s.cx, s.cy] + ([s.skew] if self.fit_skew else [])
        return np.concatenate([head, s.dist])

    def apply_step(self, s: _State, delta):
        n = s.copy()
        d = delta[: self.n_intr]
        n.fx, n.fy, n.cx, n.cy = s.fx + d[0], s.fy + d[1], s.cx + d[2], s.cy + d[3]
        c = 4
        if self.fit_skew:
            n.skew = s.skew + d[4]
            c = 5
        n.dist = s.dist + d[c:]
        dv = delta[self.n_intr:].reshape(self.n_views, 6)
        n.R = rotation_vector_to_matrix(dv[:, :3]) @ s.R
        n.t = s.t + dv[:, 3:]
        return n


#: converged when the Gauss-Newton step would lower the cost by less than this fraction of it (see
#: :func:`_levenberg_marquardt`)
GN_DECREASE_TOL = 1e-12
#: at most this many undamped Gauss-Newton steps polish the estimate once that holds
GN_POLISH_STEPS = 5
#: iterations after which an unconverged calibration goes on only if every point is in front of the camera
STALL_CHECK = 200
#: converged when the last CREEP_WINDOW iterations lowered the cost by less than CREEP_TOL / dof of it (a creep along
#: a flat valley, see :func:`_levenberg_marquardt`)
CREEP_WINDOW = 50
CREEP_TOL = 1e-4


def gauss_newton_step(J, r):
    """The undamped Gauss-Newton step ``-(J^T J)^+ J^T r`` and the cost decrease ``0.5 g^T (J^T J)^+ g`` it predicts
    (``g = J^T r``; the cost's unit, px^2); solved on the column-scaled normal matrix, pseudo-inverse for rank
    deficiency. Returns ``(step (p,), decrease)``."""
    g = J.T @ r
    D = np.sqrt(np.einsum("ij,ij->j", J, J))
    D[D == 0] = 1.0
    gs = g / D
    x = np.linalg.lstsq((J.T @ J) / np.outer(D, D), gs, rcond=None)[0]
    return -x / D, float(0.5 * gs @ x)


def _relative_step(problem: _Problem, s: _State, delta) -> float:
    """The largest step component relative to ``|parameter| + 1`` (poses: absolute)."""
    return float(np.max(np.abs(delta) / (np.abs(np.concatenate([problem.intrinsic_vector(s),
                                                                 np.zeros(6 * problem.n_views)])) + 1.0)))


def _levenberg_marquardt(problem: _Problem, s: _State, max_iterations: int, tol: float):
    """Levenberg-Marquardt with Marquardt's diagonal scaling; returns (state, iterations, converged, message).

    Converged when (a) the largest relative step is below ``tol``, (b) no damping lowers the cost, or (c) the
    Gauss-Newton step would lower the cost by less than :data:`GN_DECREASE_TOL` of it. (c) is statistical: the
    estimate is then within ``sqrt(dof * GN_DECREASE_TOL)`` (~1e-4 for a few thousand coordinates) standard
    deviations of the least-squares optimum (the cost decrease to the optimum is ``0.5 d^T H d`` and the covariance
    ``sigma^2 H^-1`` with ``sigma^2 = 2 cost / dof``). With noisy corners (realistic imaging) and a condition number
    ~1e6, (a) can stay unmet: the steps random-walk at rounding level at the optimum (seen on a seed of the webcam
    scenario: optimum in 28 iterations, still stepping ~1e-10 after 200). Under (c) up to :data:`GN_POLISH_STEPS`
    undamped Gauss-Newton steps follow while they do not raise the cost (in the quadratic region they converge
    quadratically: the estimate ends at the numerical optimum, not merely the statistical one). (d) is statistical
    too, for a flat, curved valley where LM creeps (every step lowers the cost as the Gauss-Newton model predicts,
    and the next one points elsewhere): the last :data:`CREEP_WINDOW` iterations lowered the cost by less than
    :data:`CREEP_TOL` ``/ dof`` of it, i.e. moved the estimate by < ``sqrt(CREEP_TOL)`` = 0.01 standard deviations
    (seen on seed 14 of the underwater x-y table's rig, OpenCV's corners: 4,493 iterations to (c), 55 s).
    """
    r, J = problem.residuals(s, jacobian=True)
    cost = 0.5 * r @ r
    lam = 1e-3
    dof = max(len(r) - problem.n_params, 1)
    history = [cost]
    for it in range(1, max_iterations + 1):
        delta, decrease = gauss_newton_step(J, r)
        if decrease <= GN_DECREASE_TOL * cost:  # the quadratic region: undamped steps polish to rounding level
            for _ in range(GN_POLISH_STEPS):
                trial = problem.apply_step(s, delta)
                r_t = problem.residuals(trial)
                if not (np.isfinite(r_t @ r_t) and 0.5 * r_t @ r_t <= cost * (1.0 + 1e-14)):
                    break
                s, cost = trial, 0.5 * r_t @ r_t
                if _relative_step(problem, s, delta) < tol:
                    break
                r, J = problem.residuals(s, jacobian=True)
                delta = gauss_newton_step(J, r)[0]
            return s, it, True, "converged (the Gauss-Newton step lowers the cost by < 1e-12 of it: at the optimum)"
        g = J.T @ r
        H = J.T @ J
        dH = np.diag(H).copy()
        dH[dH <= 0] = 1.0
        accepted = False
        while lam < 1e16:
            try:
                delta = -np.linalg.solve(H + lam * np.diag(dH), g)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            trial = problem.apply_step(s, delta)
            r_t = problem.residuals(trial)
            cost_t = 0.5 * r_t @ r_t
            # near the optimum the cost changes at rounding level: accept steps that do not increase it beyond that
            if np.isfinite(cost_t) and cost_t <= cost * (1.0 + 1e-14):
                accepted = True
                break
            lam *= 10.0
        if not accepted:
            return s, it, True, "converged (no further decrease possible)"
        s, cost = trial, cost_t
        lam = max(lam / 10.0, 1e-12)
        r, J = problem.residuals(s, jacobian=True)
        if _relative_step(problem, s, delta) < tol:
            return s, it, True, "converged"
        history.append(cost)
        if len(history) > CREEP_WINDOW and (history[-1 - CREEP_WINDOW] - cost) * dof < CREEP_TOL * cost:
            return s, it, True, (f"converged (the last {CREEP_WINDOW} iterations moved the estimate by < "
                                 f"{np.sqrt(CREEP_TOL):g} standard deviations)")
    return s, max_iterations, False, f"not converged after {max_iterations} iterations"


# ----------------------------------------------------------------------------------------------------------------------
# input checks and the linear initialisation
# ----------------------------------------------------------------------------------------------------------------------
def check_views(object_points, image_points, image_size):
    """Validate the per-view correspondences; returns lists of float arrays and ``(width, height)``."""
    if isinstance(object_points, np.ndarray) and object_points.ndim == 2:
        object_points, image_points = [object_points], [image_points]
    object_points, image_points = list(object_points), list(image_points)
    if len(object_points) == 0:
        raise ValueError("object_points: no views")
    if len(object_points) != len(image_points):
        raise ValueError(f"image_points: {len(image_points)} views for {len(object_points)} object-point views")
    Xs, uvs = [], []
    for i, (X, uv) in enumerate(zip(object_points, image_points, strict=True)):
        X, uv = np.asarray(X, dtype=float), np.asarray(uv, dtype=float)
        if X.ndim == 3 and X.shape[1] == 1:  # OpenCV's (N, 1, 3) / (N, 1, 2) layouts
            X = X[:, 0]
        if uv.ndim == 3 and uv.shape[1] == 1:
            uv = uv[:, 0]
        X, uv = dlt.check_correspondences(X, uv, f"object_points[{i}]", f"image_points[{i}]", min_points=4)
        Xs.append(X)
        uvs.append(uv)
    try:
        w, h = (int(image_size[0]), int(image_size[1]))
    except (TypeError, ValueError, IndexError):
        raise ValueError(f"image_size: expected (width, height) in px, got {image_size!r}") from None
    if w <= 0 or h <= 0:
        raise ValueError(f"image_size: expected positive (width, height) in px, got {image_size!r}")
    return Xs, uvs, (w, h)


def linear_calibration(object_points, image_points, image_size, fit_skew: bool = False):
    """Linear (pinhole) estimate of ``K`` and the per-view poses ``T_cam_target (V, 4, 4)``.

    Non-planar views: DLT + decomposition (Eq. 55-66), ``K`` averaged over these views (as for Table 3). Only planar
    views: Zhang's closed form. Poses of all views from the common ``K``. Raises ``ValueError`` naming the view for
    collinear points or views that do not determine ``K``.
    """
    Xs, uvs, size = check_views(object_points, image_points, image_size)
    ranks = [dlt.point_set_rank(X) for X in Xs]
    for i, rk in enumerate(ranks):
        if rk < 2:
            raise ValueError(f"object_points[{i}]: the points are collinear: the view does not constrain the camera")
    Ms, Ks = {}, []
    for i, rk in enumerate(ranks):
        if rk == 3:
            Ms[i] = dlt.dlt_projection_matrix(Xs[i], uvs[i])
            Ks.append(dlt.decompose_projection(Ms[i]).K)
    Hs, frames = {}, {}
    for i, rk in enumerate(ranks):
        if rk == 2:
            frames[i] = dlt.plane_frame(Xs[i])
            xy = transform_points(invert(frames[i]), Xs[i])[:, :2]
            Hs[i] = dlt.homography_dlt(xy, uvs[i])
    if Ks:
        K = np.mean(Ks, axis=0)
    else:
        H = np.array([Hs[i] for i in sorted(Hs)])
        try:
            K = dlt.intrinsics_from_homographies(H, skew=fit_skew and len(H) >= 3, image_size=size)
        except ValueError:
            # too few or too similar views for the full closed form: principal point at the image centre
            K = dlt.intrinsics_from_homographies(H[:1] if len(H) == 1 else H[:2], skew=True, image_size=size)
    if not fit_skew:
        K[0, 1] = 0.0
    T = np.array([dlt.pose_from_projection(K, Ms[i]) if i in Ms else dlt.pose_from_homography(K, Hs[i])
                  @ invert(frames[i]) for i in range(len(Xs))])
    return K, T


def _project_pinhole(K, T, X):
    Xc = transform_points(T, X)
    p = Xc @ K.T
    return p[:, :2] / p[:, 2:], Xc


def radial_alternation(object_points, image_points, image_size, fit_skew=False, max_rounds=20, tol=1e-6):
    """Radial distortion ``k1, k2`` by alternation (Eq. 67-73) with the linear pinhole calibration.

    Each round: ideal pixels ``u`` from the current pinhole model (Eq. 69), normalised ``u^`` (Eq. 70), the stacked
    system ``D_r k_r = d_r`` (Eq. 71-72) solved by least squares (Eq. 73), then the observed pixels corrected by the
    distortion and the pinhole model re-estimated (:func:`linear_calibration`), until ``k`` settles.

    Returns ``(K, T_cam_target (V, 4, 4), k (2,), rounds)``.
    """
    Xs, uvs, size = check_views(object_points, image_points, image_size)
    K, T = linear_calibration(Xs, uvs, size, fit_skew)
    k = np.zeros(2)
    rounds = 0
    while rounds < max_rounds:
        rounds += 1
        D, d, corrections = [], [], []
        for X, uv, Tv in zip(Xs, uvs, T, strict=True):
            u, Xc = _project_pinhole(K, Tv, X)  # Eq. 69
            xn = Xc[:, :2] / Xc[:, 2:]  # Eq. 70
            r2 = np.sum(xn * xn, axis=1)
            du = u - K[:2, 2]
            D.append(np.stack([du * r2[:, None], du * r2[:, None] ** 2], axis=-1).reshape(-1, 2))  # Eq. 72
            d.append((uv - u).reshape(-1))
            corrections.append((du, r2))
        k_new = np.linalg.lstsq(np.vstack(D), np.concatenate(d), rcond=None)[0]  # Eq. 73
        uv_corr = [uv - du * (k_new[0] * r2 + k_new[1] * r2**2)[:, None]
                   for uv, (du, r2) in zip(uvs, corrections, strict=True)]
        K, T = linear_calibration(Xs, uv_corr, size, fit_skew)
        change = np.max(np.abs(k_new - k))
        k = k_new
        if change <= tol * max(1.0, np.max(np.abs(k))):
            break
    return K, T, k, rounds


# ----------------------------------------------------------------------------------------------------------------------
# the calibration
# ----------------------------------------------------------------------------------------------------------------------
@dataclass
class CalibrationResult:
    """Outcome of :func:`calibrate_camera` (or :func:`opencv_reference`).

    Attributes
    ----------
    success : bool
    message : str
    model : str
        ``"heikkila"``, ``"radial"`` or ``"pinhole"``.
    K : ndarray (3, 3)
        Intrinsic matrix (px), skew at ``K[0, 1]`` (zero unless ``fit_skew``).
    dist : ndarray (5,)
        OpenCV order ``(k1, k2, p1, p2, k3)``; coefficients outside the model are zero.
    image_size : (int, int)
        ``(width, height)`` in px.
    T_cam_target : ndarray (V, 4, 4)
        Pose of the target in the camera frame for each view (target unit, e.g. m).
    rms_px : float
        Reprojection RMS over all points, the thesis's chi (Eq. 196), px.
    per_view_rms_px : ndarray (V,)
        chi of each view (Table 3's last row), px.
    residuals_px : list of ndarray (N_i, 2)
        Detected minus predicted pixels, ``p_e - p_p`` (Figures 44/53).
    parameter_names : list of str
        Names of the estimated intrinsic parameters (``fx, fy, cx, cy[, skew], k1, ...``).
    parameters : ndarray (p,)
    covariance : ndarray (p, p)
        ``sigma^2 (J^T J)^-1`` intrinsic block (px^2, unitless for the coefficients).
    sigma_px : float
        Residual standard deviation per image coordinate (px).
    iterations : int
    cost : float
        Half the sum of squared residuals (px^2).
    timings_s : dict
    """

    success: bool
    message: str
    model: str
    K: np.ndarray
    dist: np.ndarray
    image_size: tuple
    T_cam_target: np.ndarray
    rms_px: float
    per_view_rms_px: np.ndarray
    residuals_px: list
    parameter_names: list
    parameters: np.ndarray
    covariance: np.ndarray
    sigma_px: float
    iterations: int
    cost: float
    timings_s: dict = field(default_factory=dict)

    @property
    def std(self) -> np.ndarray:
        """Standard errors of ``parameters`` (same units)."""
        return np.sqrt(np.diag(self.covariance))

    @property
    def standard_errors(self) -> dict:
        """``{name: standard error}`` of the intrinsic parameters."""
        return dict(zip(self.parameter_names, self.std.tolist(), strict=True))

    @property
    def camera(self):
        """The calibrated :class:`bench.camera.model.CameraModel` (None when the calibration failed)."""
        from bench.camera.model import CameraModel

        if not self.success:
            return None
        return CameraModel(int(self.image_size[0]), int(self.image_size[1]), self.K, self.dist, name="calibrated",
                           model=self.model)

    def thesis_parameters(self) -> dict:
        """Eq. 50's ``alpha, beta (px), theta (deg), u0, v0 (px)``."""
        a, b, th, u0, v0 = dlt.thesis_parameters(self.K)
        return {"alpha_px": a, "beta_px": b, "theta_deg": float(np.degrees(th)), "u0_px": u0, "v0_px": v0}


def _failure(model, size, n_views, message, timings=None):
    nan3 = np.full((3, 3), np.nan)
    return CalibrationResult(False, message, model, nan3, np.full(5, np.nan), size,
                             np.full((n_views, 4, 4), np.nan), np.nan, np.full(n_views, np.nan), [], [],
                             np.array([]), np.zeros((0, 0)), np.nan, 0, np.nan, timings or {})


def _residual_summary(problem, s):
    r = problem.residuals(s).reshape(-1, 2)
    per_view = np.array([np.sqrt(np.mean(np.sum(r[a:b] ** 2, axis=1)))
                         for a, b in zip(problem.offsets[:-1], problem.offsets[1:], strict=True)])  # Eq. 196
    rms = float(np.sqrt(np.mean(np.sum(r * r, axis=1))))
    residuals = [-r[a:b] for a, b in zip(problem.offsets[:-1], problem.offsets[1:], strict=True)]
    return rms, per_view, residuals, r


def _check_initial(initial, n_views, model, k3, fit_skew):
    """``(K, T_cam_target, estimated coefficients)`` from an ``initial`` guess; one-line ValueError if malformed."""
    try:
        K, dist, T = (np.array(a, dtype=float) for a in initial)
    except (TypeError, ValueError):
        raise ValueError("initial: expected (K (3, 3), dist (5,), T_cam_target (V, 4, 4))") from None
    if K.shape != (3, 3) or dist.shape != (5,) or T.shape != (n_views, 4, 4):
        raise ValueError(f"initial: expected shapes (3, 3), (5,), ({n_views}, 4, 4), got {K.shape}, {dist.shape}, "
                         f"{T.shape}")
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(dist)) and np.all(np.isfinite(T))):
        raise ValueError("initial: contains NaN or inf")
    if not fit_skew:
        K[0, 1] = 0.0
    return K, T, np.array([dist[_DIST_INDEX[n]] for n in distortion_names(model, k3)])


def calibrate_camera(object_points, image_points, image_size, model: str = "heikkila", *, k3: bool = False,
                     fit_skew: bool = False, max_iterations: int = 1000, tol: float = 1e-12,
                     initial=None) -> CalibrationResult:
    """Calibrate a camera from V views of a known target (thesis §3.3; Zhang; Heikkilä).

    Parameters
    ----------
    object_points : list of array (N_i, 3)
        Target points of each view in the target frame (any length unit; the poses come out in it). A view may be
        non-planar (the thesis's two-plane rig: one view suffices) or planar (a board: several views needed).
    image_points : list of array (N_i, 2)
        Detected pixels (px), same order.
    image_size : (width, height)
        px.
    model : {"heikkila", "radial", "pinhole"}
        Heikkilä = radial + tangential (k1, k2, p1, p2[, k3]); radial = k1, k2[, k3]; pinhole = no distortion.
    k3 : bool
        Also estimate the sixth-order radial coefficient.
    fit_skew : bool
        Estimate the skew (the thesis's theta); OpenCV's ``calibrateCamera`` keeps it zero.
    max_iterations, tol : int, float
        Levenberg-Marquardt limits: converged when the largest step, relative to ``|parameter| + 1``, is below ``tol``.
        Most calibrations converge in 5-40 iterations. Along a flat, curved valley LM creeps (the Jacobian checked
        against finite differences there): seed 9 of the webcam's Table 3 rig (realistic imaging) stops at 250
        iterations by :func:`_levenberg_marquardt`'s creep criterion (366 to the Gauss-Newton one), so the cap is
        1000, not 200. After :data:`STALL_CHECK` iterations LM goes on only while every point lies in front of the
        camera; a start that stalled with points behind it (a flat port over the whole image) restarts from the
        pinhole fit at once.
    initial : (K (3, 3), dist (5,), T_cam_target (V, 4, 4)), optional
        Start Levenberg-Marquardt here instead of the linear initialisation (DLT/Zhang and Eq. 67-73), e.g. from a
        calibration of more views (:func:`jackknife_views`); ``dist`` in OpenCV order, coefficients outside the model
        ignored, the skew ignored unless ``fit_skew``.

    Returns
    -------
    CalibrationResult
        ``success=False`` with the reason when the solver does not converge or the problem is degenerate.

    Raises
    ------
    ValueError
        Malformed input: NaN, wrong shapes, mismatched lengths, unknown model (one line, naming the field/view).
    """
    timings = {}
    t0 = time.perf_counter()
    distortion_names(model, k3)  # validates the model name
    Xs, uvs, size = check_views(object_points, image_points, image_size)
    V = len(Xs)
    n_points = sum(len(x) for x in Xs)
    if all(dlt.point_set_rank(X) == 2 for X in Xs) and V < (3 if fit_skew else 2):
        return _failure(model, size, V, f"{V} view(s) of a planar target do not determine the intrinsics (Zhang needs "
                        f">= {3 if fit_skew else 2} views; the DLT needs a non-planar target)", timings)
    start = None if initial is None else _check_initial(initial, V, model, k3, fit_skew)
    try:
        if start is not None:
            K, T, k = start
        elif model == "pinhole":
            K, T = linear_calibration(Xs, uvs, size, fit_skew)
            k = np.zeros(0)
        else:
            K, T, k_r, _ = radial_alternation(Xs, uvs, size, fit_skew)
            k = np.concatenate([k_r, np.zeros(len(distortion_names(model, k3)) - 2)])
    except ValueError as e:
        return _failure(model, size, V, f"initialisation failed: {e}", timings)
    timings["initialisation_s"] = time.perf_counter() - t0
    problem = _Problem(Xs, uvs, model, k3, fit_skew)
    if 2 * n_points <= problem.n_params:
        return _failure(model, size, V, f"too few points: {2 * n_points} coordinates for {problem.n_params} "
                        "parameters", timings)
    s = _State(K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1], k.astype(float), T[:, :3, :3].copy(),
               T[:, :3, 3].copy())
    t1 = time.perf_counter()
    s, iterations, converged, message = _levenberg_marquardt(problem, s, min(max_iterations, STALL_CHECK), tol)
    if not converged and iterations < max_iterations and _in_front(s, Xs):
        # a flat valley converges linearly (see ``max_iterations``): go on; a stalled start with points behind the
        # camera does not (it takes the pinhole restart below)
        s, more, converged, message = _levenberg_marquardt(problem, s, max_iterations - iterations, tol)
        iterations += more
        if not converged:
            message = f"not converged after {iterations} iterations"
    timings["levenberg_marquardt_s"] = time.perf_counter() - t1
    r, J = problem.residuals(s, jacobian=True)
    cost = 0.5 * float(r @ r)
    dof = 2 * n_points - problem.n_params
    sigma2 = 2.0 * cost / dof
    JtJ = J.T @ J
    col = np.sqrt(np.diag(JtJ))
    col[col == 0] = 1.0
    cond = float(np.linalg.cond(J / col))  # of the column-scaled Jacobian
    try:
        cov_full = sigma2 * np.linalg.inv(JtJ)
    except np.linalg.LinAlgError:
        cov_full = np.full_like(JtJ, np.nan)
    cov = cov_full[: problem.n_intr, : problem.n_intr]
    rms, per_view, residuals, _ = _residual_summary(problem, s)
    T_out = homogeneous(s.R, s.t)
    depth_ok = _in_front(s, Xs)
    success = converged and np.isfinite(rms) and depth_ok and cond < COND_LIMIT
    if not depth_ok:
        message += "; some points lie behind the camera"
    if cond >= COND_LIMIT:
        message += (f"; the views do not determine the parameters (condition number {cond:.1e} of the scaled "
                    "Jacobian)")
    timings["total_s"] = time.perf_counter() - t0
    result = CalibrationResult(bool(success), message, model, s.K(), _full_dist(model, s.dist), size, T_out, rms,
                               per_view, residuals, list(problem.intr_names), problem.intrinsic_vector(s), cov,
                               float(np.sqrt(sigma2)), iterations, cost, timings)
    if success or start is not None or model == "pinhole":
        return result
    # Eq. 67-73's start can be far off when strong distortion reaches the image corners (a flat port seen over the
    # whole image: LM then stalls with points behind the camera); restart from the pinhole fit, distortion zero
    pinhole = calibrate_camera(Xs, uvs, size, "pinhole", fit_skew=fit_skew, max_iterations=max_iterations, tol=tol)
    if not np.isfinite(pinhole.rms_px):
        return result
    retry = calibrate_camera(Xs, uvs, size, model, k3=k3, fit_skew=fit_skew, max_iterations=max_iterations, tol=tol,
                             initial=(pinhole.K, np.zeros(5), pinhole.T_cam_target))
    if not retry.success:
        return result
    retry.timings_s["total_s"] = time.perf_counter() - t0
    return replace(retry, message=f"{retry.message} (from the pinhole fit: the radial alternation's start gave "
                                  f"'{message}')")


def _in_front(s: _State, Xs) -> bool:
    """Every target point lies in front of the camera (positive depth) at the views' poses."""
    return all(np.all(Xs[v] @ s.R[v][2] + s.t[v][2] > 0) for v in range(len(Xs)))


def reprojection_residuals(result: CalibrationResult, object_points, image_points):
    """Detected minus predicted pixels ``(N_i, 2)`` per view for a calibration result (e.g. OpenCV's)."""
    Xs, uvs, _ = check_views(object_points, image_points, result.image_size)
    problem = _Problem(Xs, uvs, "heikkila", True, True)
    s = _State(result.K[0, 0], result.K[1, 1], result.K[0, 2], result.K[1, 2], result.K[0, 1], result.dist.copy(),
               result.T_cam_target[:, :3, :3].copy(), result.T_cam_target[:, :3, 3].copy())
    return _residual_summary(problem, s)[2]


def jackknife_views(object_points, image_points, image_size, model: str = "heikkila", *, k3: bool = False,
                    fit_skew: bool = False, result: CalibrationResult | None = None, **kwargs):
    """Leave-one-view-out (jackknife) standard errors of the intrinsic parameters.

    The formal standard errors of :func:`calibrate_camera` (``sigma^2 (J^T J)^-1``) treat every corner coordinate
    as an independent error. Corner errors that are correlated within a view - along a board line (aliasing of the
    rendered or printed edges, JPEG blocks, a warped board) - make them too small; the views themselves are
    independent, so the spread of the estimate over the calibrations that leave one view out measures the
    uncertainty without that assumption: ``var = (V - 1) / V sum_i (theta_(i) - mean)^2``.

    Parameters
    ----------
    object_points, image_points, image_size, model, k3, fit_skew, **kwargs
        As for :func:`calibrate_camera`; at least 2 views (a two-plane rig) or 3 (planar targets).
    result : CalibrationResult, optional
        The calibration of all views (computed if not given); each leave-one-out calibration starts from it.

    Returns
    -------
    std : ndarray (p,)
        Jackknife standard errors, order of ``CalibrationResult.parameter_names``; NaN when a leave-one-out
        calibration fails or there are too few views.
    estimates : ndarray (V, p)
        The leave-one-out estimates (NaN rows for failed ones).
    """
    Xs, uvs, size = check_views(object_points, image_points, image_size)
    V = len(Xs)
    n_par = 4 + int(fit_skew) + len(distortion_names(model, k3))
    est = np.full((V, n_par), np.nan)
    if V < 2:
        return np.full(n_par, np.nan), est
    if result is None:
        result = calibrate_camera(Xs, uvs, size, model, k3=k3, fit_skew=fit_skew, **kwargs)
    if not result.success:
        return np.full(n_par, np.nan), est
    for i in range(V):
        keep = [j for j in range(V) if j != i]
        r = calibrate_camera([Xs[j] for j in keep], [uvs[j] for j in keep], size, model, k3=k3, fit_skew=fit_skew,
                             initial=(result.K, result.dist, result.T_cam_target[keep]), **kwargs)
        if r.success:
            est[i] = r.parameters
    if not np.all(np.isfinite(est)):
        return np.full(n_par, np.nan), est
    return np.sqrt((V - 1) / V * np.sum((est - est.mean(axis=0)) ** 2, axis=0)), est


def per_view_pinhole(object_points, image_points) -> list[dict]:
    """Table 3: each non-planar view calibrated alone by the DLT (Eq. 55-66) and its chi (Eq. 195-196).

    Returns one dict per view: ``alpha_px, beta_px, theta_deg, u0_px, v0_px, chi_px`` (NaN and a ``note`` for planar
    views, which the DLT cannot calibrate alone).
    """
    out = []
    for i, (X, uv) in enumerate(zip(object_points, image_points, strict=True)):
        X, uv = dlt.check_correspondences(X, uv, f"object_points[{i}]", f"image_points[{i}]")
        try:
            M = dlt.dlt_projection_matrix(X, uv)
        except ValueError as e:
            out.append({"view": i, "alpha_px": np.nan, "beta_px": np.nan, "theta_deg": np.nan, "u0_px": np.nan,
                        "v0_px": np.nan, "chi_px": np.nan, "note": str(e)})
            continue
        d = dlt.decompose_projection(M, X)
        out.append({"view": i, "alpha_px": d.alpha, "beta_px": d.beta, "theta_deg": float(np.degrees(d.theta)),
                    "u0_px": d.u0, "v0_px": d.v0, "chi_px": dlt.reprojection_rms(M, X, uv), "note": ""})
    return out


def opencv_flags(model: str, k3: bool = False) -> int:
    """``cv2.calibrateCamera`` flags estimating exactly the coefficients of ``model`` (skew is always zero there)."""
    import cv2

    distortion_names(model, k3)
    flags = 0 if k3 else cv2.CALIB_FIX_K3
    if model in ("radial", "pinhole"):
        flags |= cv2.CALIB_ZERO_TANGENT_DIST
    if model == "pinhole":
        flags |= cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3
    return flags


@contextlib.contextmanager
def opencv_one_thread():
    """OpenCV on one thread inside the block (its thread count restored after): ``cv2.calibrateCamera`` sums over
    views in parallel, so with two threads the same detections gave intrinsics differing by ~1e-6 px from call to
    call; on one thread it is the same to the last bit."""
    import cv2

    n = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        cv2.setNumThreads(n)


def opencv_reference(object_points, image_points, image_size, model: str = "heikkila", *, k3: bool = False,
                     K_init=None, max_iterations: int = 500, one_thread: bool = True) -> CalibrationResult:
    """``cv2.calibrateCamera`` on the same detections with flags matching ``model`` (zero skew).

    ``one_thread`` (default): OpenCV on one thread (:func:`opencv_one_thread`), the same result to the last bit from
    call to call; ``False`` runs it on OpenCV's own thread count (``make benchmark`` times the peer so).

    Non-planar targets need an initial ``K`` (OpenCV's own initialisation is planar only): ``K_init`` or, if None, the
    linear calibration of this module. OpenCV takes the points as float32 (it refuses float64): compare on detections
    that are float32 already (as ``findChessboardCornersSB`` returns them), or the rounding (~1e-5 px) shows. The RMS is
    recomputed by Eq. 196 on the float64 points given (it equals OpenCV's return value for float32 input).
    """
    import cv2

    t0 = time.perf_counter()
    Xs, uvs, size = check_views(object_points, image_points, image_size)
    flags = opencv_flags(model, k3)
    planar = all(dlt.point_set_rank(X) <= 2 and np.allclose(X[:, 2], 0.0) for X in Xs)
    if K_init is None and not planar:
        K_init = linear_calibration(Xs, uvs, size)[0]
    if K_init is not None:
        flags |= cv2.CALIB_USE_INTRINSIC_GUESS
        K0 = np.array(K_init, dtype=float)
        K0[0, 1] = 0.0
    else:
        K0 = np.eye(3)
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, max_iterations, np.finfo(float).eps)
    try:
        with opencv_one_thread() if one_thread else contextlib.nullcontext():
            rms_cv, K, dist, rvecs, tvecs = cv2.calibrateCamera(
                [X.astype(np.float32) for X in Xs], [uv.astype(np.float32) for uv in uvs], size, K0, np.zeros(5),
                flags=flags, criteria=criteria)
    except cv2.error as e:
        first = str(e).strip().splitlines()
        return _failure(model, size, len(Xs), f"cv2.calibrateCamera failed: {first[-1] if first else e}")
    dist5 = np.zeros(5)
    dist5[: min(5, dist.size)] = dist.ravel()[:5]
    T = np.array([homogeneous(rotation_vector_to_matrix(np.ravel(rv)), np.ravel(tv))
                  for rv, tv in zip(rvecs, tvecs, strict=True)])
    result = CalibrationResult(True, f"cv2.calibrateCamera (flags {flags})", model, K, dist5, size, T, float(rms_cv),
                               np.zeros(len(Xs)), [], [], np.array([]), np.zeros((0, 0)), np.nan, 0, np.nan,
                               {"total_s": time.perf_counter() - t0})
    residuals = reprojection_residuals(result, Xs, uvs)
    result.residuals_px = residuals
    allr = np.vstack(residuals)
    result.rms_px = float(np.sqrt(np.mean(np.sum(allr**2, axis=1))))
    result.per_view_rms_px = np.array([np.sqrt(np.mean(np.sum(r**2, axis=1))) for r in residuals])
    result.cost = 0.5 * float(np.sum(allr**2))
    return result
