"""The camera model shared by the pipeline and the simulator (thesis §3.2-3.3, Eq. 46-51, 67-68, 75-76).

A chain of stages, each with its inverse, batched over leading axes (``(..., 3)`` points, ``(..., 2)`` coordinates):

``p_cam --project_pinhole (Eq. 46)--> x_n --distort (Eq. 75-76)--> x_d --to_pixels (Eq. 50)--> uv``

and back: :func:`from_pixels` (Eq. 51), :func:`undistort` (Newton iteration of the implicit model to 1e-12),
:func:`unproject_pinhole` (a ray).

Conventions (``../shared/design.md``): OpenCV camera frame (x right, y down, z forward); pixel ``(0, 0)`` is the
centre of the top-left pixel; distortion coefficients in OpenCV order ``(k1, k2, p1, p2[, k3])`` acting on normalised
coordinates. Eq. 75-76 (Heikkilä) are this model with ``fx = s_u f``, ``fy = f``, no skew and ``k3 = 0`` once the
printed misprints are corrected (Eq. 75 prints ``k2 v^5`` for ``k2 u^5``, Eq. 76 ``k1 u^2 v^2`` for ``k1 u^2 v``; see
:func:`bench.camera.heikkila.eq75_as_printed`); the unit of the thesis's coefficients is handled in
:mod:`bench.camera.heikkila`. The intrinsic matrix is Eq. 50 in OpenCV layout, ``K = [[alpha, -alpha cot(theta), u0],
[0, beta / sin(theta), v0], [0, 0, 1]]``, i.e. ``fx = K[0, 0]``, ``skew = K[0, 1]``, ``fy = K[1, 1]``.

Units: points in m, normalised coordinates unitless, pixels in px.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from bench.geometry.transforms import check_vectors

#: distortion model names: no distortion, radial only (Eq. 67-68), radial + tangential (Eq. 75-76)
MODELS = ("pinhole", "radial", "heikkila")
#: convergence tolerance of :func:`undistort` on the distortion residual (normalised units)
UNDISTORT_TOL = 1e-12
_CHUNK = 1 << 15


# ----------------------------------------------------------------------------------------------------------------------
# validation
# ----------------------------------------------------------------------------------------------------------------------
def check_K(K, name: str = "K") -> np.ndarray:
    """Validate an intrinsic matrix (Eq. 50): finite, upper triangular, ``fx, fy > 0``, last row ``(0, 0, 1)``.

    Returns
    -------
    K : ndarray (3, 3), float
    """
    K = np.asarray(K, dtype=float)
    if K.shape != (3, 3):
        raise ValueError(f"{name}: expected a (3, 3) intrinsic matrix, got shape {K.shape}")
    if not np.all(np.isfinite(K)):
        raise ValueError(f"{name}: contains NaN or inf")
    if K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
        raise ValueError(f"{name}: expected upper triangular with last row (0, 0, 1), got {K.tolist()}")
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise ValueError(f"{name}: focal lengths fx = {K[0, 0]}, fy = {K[1, 1]} must be > 0 (px)")
    return K


def check_dist(dist, name: str = "dist") -> np.ndarray:
    """Validate OpenCV distortion coefficients ``(k1, k2, p1, p2[, k3])``; 0, 4 or 5 finite values.

    Returns
    -------
    dist : ndarray (5,)
        Padded with ``k3 = 0`` when 4 (or all zeros when 0) are given.
    """
    d = np.asarray(dist if dist is not None else [], dtype=float).ravel()
    if d.size not in (0, 4, 5):
        raise ValueError(f"{name}: expected 4 or 5 coefficients (k1, k2, p1, p2[, k3]), got {d.size}")
    if not np.all(np.isfinite(d)):
        raise ValueError(f"{name}: contains NaN or inf")
    out = np.zeros(5)
    out[: d.size] = d
    return out


def model_of(dist) -> str:
    """The smallest model in :data:`MODELS` that holds ``dist``: pinhole, radial (p1 = p2 = 0) or heikkila."""
    d = check_dist(dist)
    if not np.any(d):
        return "pinhole"
    if d[2] == 0 and d[3] == 0:
        return "radial"
    return "heikkila"


# ----------------------------------------------------------------------------------------------------------------------
# the stages
# ----------------------------------------------------------------------------------------------------------------------
def project_pinhole(p_cam) -> np.ndarray:
    """Normalised image coordinates ``(x/z, y/z)`` of camera-frame points (Eq. 46).

    Parameters
    ----------
    p_cam : array_like (..., 3)
        Points in the camera frame (m), OpenCV axes.

    Returns
    -------
    x_n : ndarray (..., 2)
        Normalised coordinates; NaN for points with ``z <= 0`` (behind the camera or in its centre plane).
    """
    p = check_vectors(p_cam, "p_cam", 3)
    z = p[..., 2:3]
    with np.errstate(divide="ignore", invalid="ignore"):
        x_n = p[..., :2] / z
    return np.where(z > 0, x_n, np.nan)


def unproject_pinhole(x_n, normalize: bool = True) -> np.ndarray:
    """Rays of normalised coordinates (inverse of Eq. 46): ``(x, y, 1)``, unit length if ``normalize``.

    Returns
    -------
    rays_cam : ndarray (..., 3)
    """
    x_n = check_vectors(x_n, "x_n", 2)
    rays = np.concatenate([x_n, np.ones(x_n.shape[:-1] + (1,))], axis=-1)
    if normalize:
        rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    return rays


def distort(x_n, dist) -> np.ndarray:
    """Distorted normalised coordinates (Eq. 75-76 in normalised form, OpenCV's model).

    ``x_d = x g + 2 p1 x y + p2 (r^2 + 2 x^2)``, ``y_d = y g + p1 (r^2 + 2 y^2) + 2 p2 x y`` with
    ``g = 1 + k1 r^2 + k2 r^4 + k3 r^6``, ``r^2 = x^2 + y^2``.

    Parameters
    ----------
    x_n : array_like (..., 2)
        Ideal normalised coordinates.
    dist : array_like (4,) or (5,)
        ``(k1, k2, p1, p2[, k3])``.

    Returns
    -------
    x_d : ndarray (..., 2)
    """
    x_n = np.asarray(x_n, dtype=float)
    if x_n.ndim < 1 or x_n.shape[-1] != 2:
        raise ValueError(f"x_n: expected shape (..., 2), got {x_n.shape}")
    k1, k2, p1, p2, k3 = check_dist(dist)
    x, y = x_n[..., 0], x_n[..., 1]
    r2 = x * x + y * y
    g = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))  # radial factor, Eq. 67-68 / 75-76
    xy2 = 2.0 * x * y
    out = np.empty(x_n.shape)
    out[..., 0] = x * g + p1 * xy2 + p2 * (r2 + 2.0 * x * x)  # Eq. 75 (corrected)
    out[..., 1] = y * g + p1 * (r2 + 2.0 * y * y) + p2 * xy2  # Eq. 76 (corrected)
    return out


def distortion_jacobian(x_n, dist) -> np.ndarray:
    """``d x_d / d x_n`` of :func:`distort`, shape ``(..., 2, 2)``."""
    x_n = np.asarray(x_n, dtype=float)
    k1, k2, p1, p2, k3 = check_dist(dist)
    x, y = x_n[..., 0], x_n[..., 1]
    r2 = x * x + y * y
    g = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dg = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # dg / d(r^2)
    J = np.empty(x_n.shape[:-1] + (2, 2))
    off = 2.0 * x * y * dg + 2.0 * p1 * x + 2.0 * p2 * y
    J[..., 0, 0] = g + 2.0 * x * x * dg + 2.0 * p1 * y + 6.0 * p2 * x
    J[..., 0, 1] = off
    J[..., 1, 0] = off
    J[..., 1, 1] = g + 2.0 * y * y * dg + 6.0 * p1 * y + 2.0 * p2 * x
    return J


def distortion_parameter_jacobian(x_n) -> np.ndarray:
    """``d distort(x_n) / d (k1, k2, p1, p2)`` (N, 2, 4) (:func:`distort` is linear in them; Eq. 75-76)."""
    x, y = x_n[:, 0], x_n[:, 1]
    r2 = x * x + y * y
    J = np.empty((len(x_n), 2, 4))
    J[:, 0, 0], J[:, 1, 0] = x * r2, y * r2
    J[:, 0, 1], J[:, 1, 1] = x * r2 * r2, y * r2 * r2
    J[:, 0, 2], J[:, 1, 2] = 2 * x * y, r2 + 2 * y * y
    J[:, 0, 3], J[:, 1, 3] = r2 + 2 * x * x, 2 * x * y
    return J


def thin_prism(x_n, s) -> np.ndarray:
    """The thin-prism displacement ``(s1 r^2 + s2 r^4, s3 r^2 + s4 r^4)`` (N, 2) of normalized points ``x_n`` (N, 2):
    a lens element tilted or decentred (Weng, Cohen & Herniou, PAMI 14(10) 1992; OpenCV's thin-prism terms). Added
    to :func:`distort`'s output where a model carries it (the x-y table's bundle)."""
    x_n, s = np.asarray(x_n, float), np.asarray(s, float)
    r2 = np.sum(x_n**2, axis=-1)
    return np.stack([s[0] * r2 + s[1] * r2**2, s[2] * r2 + s[3] * r2**2], -1)


def thin_prism_jacobian(x_n, s) -> np.ndarray:
    """``d thin_prism(x_n) / d x_n`` (N, 2, 2)."""
    x_n, s = np.asarray(x_n, float), np.asarray(s, float)
    r2 = np.sum(x_n**2, axis=-1)
    gx, gy = s[0] + 2 * s[1] * r2, s[2] + 2 * s[3] * r2  # d(.)/d(r^2)
    return 2 * np.stack([gx[:, None] * x_n, gy[:, None] * x_n], -2)


def thin_prism_parameter_jacobian(x_n) -> np.ndarray:
    """``d thin_prism(x_n) / d (s1, s2, s3, s4)`` (N, 2, 4) (linear in them)."""
    r2 = np.sum(np.asarray(x_n, float) ** 2, axis=-1)
    J = np.zeros((len(r2), 2, 4))
    J[:, 0, 0], J[:, 0, 1], J[:, 1, 2], J[:, 1, 3] = r2, r2**2, r2, r2**2
    return J


@dataclass(frozen=True)
class UndistortResult:
    """Outcome of :func:`undistort` with ``full_output=True``.

    Attributes
    ----------
    x_n : ndarray (..., 2)
        Ideal normalised coordinates; NaN where the iteration did not converge.
    converged : ndarray (...,) of bool
    iterations : int
        Newton iterations used by the slowest point.
    max_residual : float
        Largest ``|distort(x_n) - x_d|`` (inf norm, normalised units) over the converged points.
    success : bool
        All points converged.
    message : str
    """

    x_n: np.ndarray
    converged: np.ndarray
    iterations: int
    max_residual: float
    success: bool
    message: str


def undistort(x_d, dist, *, tol: float = UNDISTORT_TOL, max_iterations: int = 50, full_output: bool = False,
              x0=None):
    """Ideal normalised coordinates of distorted ones: the inverse of :func:`distort` (Eq. 75-76).

    The forward model has no closed-form inverse (the thesis's Eq. 77-86 fit an approximate implicit inverse, see
    :func:`bench.camera.heikkila.fit_implicit_inverse`); here it is solved per point by damped Newton iteration on
    ``distort(x) - x_d = 0`` with the analytic Jacobian, started at ``x0`` (default ``x_d``), until the residual is
    ``<= tol``; a step that does not reduce the residual is halved (backtracking).

    Parameters
    ----------
    x_d : array_like (..., 2)
        Distorted normalised coordinates.
    dist : array_like (4,) or (5,)
    tol : float
        Convergence threshold on ``|distort(x) - x_d|_inf`` (normalised units; ``1e-12`` is ~1e-9 px).
    max_iterations : int
    full_output : bool
        Return an :class:`UndistortResult` instead of the array.
    x0 : array_like (..., 2), optional
        Starting point (e.g. interpolated from a coarser solution); only changes the number of iterations.

    Returns
    -------
    x_n : ndarray (..., 2)
        NaN for points where the iteration did not converge (outside the region where the distortion is
        invertible); or an :class:`UndistortResult`.
    """
    x_d = check_vectors(x_d, "x_d", 2)
    dist5 = check_dist(dist)
    shape = x_d.shape
    target = x_d.reshape(-1, 2)
    if x0 is None:
        x = target.copy()
    else:
        x0 = check_vectors(x0, "x0", 2)
        if x0.shape != shape:
            raise ValueError(f"x0: expected the shape of x_d {shape}, got {x0.shape}")
        x = x0.reshape(-1, 2).copy()
    converged = np.zeros(len(x), dtype=bool)
    if not np.any(dist5):
        x = target.copy()
        converged[:] = True
        result = UndistortResult(x.reshape(shape), converged.reshape(shape[:-1]), 0, 0.0, True, "no distortion")
        return result if full_output else result.x_n
    res = np.empty_like(x)
    iterations = 0
    for i in range(0, len(x), _CHUNK):  # chunks keep the temporaries in cache (several times faster on 1e6 points)
        sl = slice(i, i + _CHUNK)
        x[sl], res[sl], converged[sl], it = _newton(target[sl], x[sl], dist5, tol, max_iterations)
        iterations = max(iterations, it)
    x[~converged] = np.nan
    max_res = float(np.max(np.abs(res[converged]))) if np.any(converged) else float("nan")
    ok = bool(np.all(converged))
    msg = "converged" if ok else f"{int(np.sum(~converged))} of {len(x)} points did not converge in {max_iterations} " \
                                 f"iterations to a root where the distortion is one-to-one"
    result = UndistortResult(x.reshape(shape), converged.reshape(shape[:-1]), iterations, max_res, ok, msg)
    return result if full_output else result.x_n


def _newton(target, x, dist5, tol, max_iterations):
    """Damped Newton on ``distort(x) = target`` for ``(N, 2)`` arrays; returns ``x, residual, converged, its``."""
    converged = np.zeros(len(x), dtype=bool)
    active = np.arange(len(x))
    res = distort(x, dist5) - target
    iterations = 0
    while True:
        done = np.max(np.abs(res[active]), axis=1) <= tol
        converged[active[done]] = True
        active = active[~done]
        if active.size == 0 or iterations == max_iterations:
            break
        iterations += 1
        xa, ra = x[active], res[active]
        J = distortion_jacobian(xa, dist5)
        det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.stack([(J[:, 1, 1] * ra[:, 0] - J[:, 0, 1] * ra[:, 1]) / det,
                             (J[:, 0, 0] * ra[:, 1] - J[:, 1, 0] * ra[:, 0]) / det], axis=1)
        step[~np.isfinite(step)] = 0.0
        norm0 = np.sum(ra * ra, axis=1)
        lam = np.ones(len(active))
        x_new = xa - step
        r_new = distort(x_new, dist5) - target[active]
        for _ in range(30):  # backtracking where the full Newton step does not reduce the residual
            worse = (np.sum(r_new * r_new, axis=1) > norm0) & (lam > 1e-9)
            if not np.any(worse):
                break
            lam[worse] *= 0.5
            x_new[worse] = xa[worse] - lam[worse, None] * step[worse]
            r_new[worse] = distort(x_new[worse], dist5) - target[active[worse]]
        x[active] = x_new
        res[active] = r_new
    # a root on the physical branch: both eigenvalues of the Jacobian positive (det > 0 and trace > 0); beyond a
    # fold (e.g. g = 1 + k1 r^2 < 0) the equation has other roots, which are rejected
    ok = np.flatnonzero(converged)
    J = distortion_jacobian(x[ok], dist5)
    det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
    converged[ok[(det <= 0) | (J[:, 0, 0] + J[:, 1, 1] <= 0)]] = False
    return x, res, converged, iterations


def to_pixels(x, K) -> np.ndarray:
    """Pixels of (distorted) normalised coordinates: ``(u, v, 1) = K (x, y, 1)`` (Eq. 50, with skew).

    Parameters
    ----------
    x : array_like (..., 2)
    K : array_like (3, 3)

    Returns
    -------
    uv : ndarray (..., 2)
        px, OpenCV convention ((0, 0) is the centre of the top-left pixel).
    """
    x = np.asarray(x, dtype=float)
    if x.ndim < 1 or x.shape[-1] != 2:
        raise ValueError(f"x: expected shape (..., 2), got {x.shape}")
    K = check_K(K)
    uv = np.empty(x.shape)
    uv[..., 0] = K[0, 0] * x[..., 0] + K[0, 1] * x[..., 1] + K[0, 2]
    uv[..., 1] = K[1, 1] * x[..., 1] + K[1, 2]
    return uv


def from_pixels(uv, K) -> np.ndarray:
    """Normalised coordinates of pixels: ``(x, y, 1) = K^-1 (u, v, 1)`` (Eq. 51), the inverse of :func:`to_pixels`."""
    uv = check_vectors(uv, "uv", 2)
    K = check_K(K)
    x = np.empty(uv.shape)
    x[..., 1] = (uv[..., 1] - K[1, 2]) / K[1, 1]
    x[..., 0] = (uv[..., 0] - K[0, 2] - K[0, 1] * x[..., 1]) / K[0, 0]
    return x


def radial_eq67(uv_ideal, K, k1: float, k2: float) -> np.ndarray:
    """Distorted pixels of ideal pixels by the radial model as printed in Eq. 67-68.

    ``u_d = u + (u - u0)(k1 r^2 + k2 r^4)``, ``v_d = v + (v - v0)(k1 r^2 + k2 r^4)``, ``r`` from the ideal normalised
    coordinates (Eq. 70). Because the radial factor scales ``(x, y)`` and ``K`` is linear in them, this equals
    ``to_pixels(distort(x_n, (k1, k2, 0, 0)), K)`` exactly, skew included.
    """
    uv = check_vectors(uv_ideal, "uv_ideal", 2)
    K = check_K(K)
    x_n = from_pixels(uv, K)  # Eq. 70
    r2 = np.sum(x_n * x_n, axis=-1, keepdims=True)
    return uv + (uv - K[:2, 2]) * (k1 * r2 + k2 * r2 * r2)  # Eq. 67-68


# ----------------------------------------------------------------------------------------------------------------------
# the camera
# ----------------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CameraModel:
    """A calibrated (or specified) camera: resolution, intrinsics (Eq. 50) and distortion (Eq. 75-76).

    Attributes
    ----------
    width, height : int
        Image size (px).
    K : ndarray (3, 3)
        Intrinsic matrix, OpenCV layout with skew ``K[0, 1]`` (px).
    dist : ndarray (5,)
        ``(k1, k2, p1, p2, k3)`` on normalised coordinates (unitless); given as 0, 4 or 5 values.
    name : str
    model : str
        One of :data:`MODELS`; derived from ``dist`` when not given (:func:`model_of`). A model that cannot hold
        ``dist`` (e.g. ``"radial"`` with ``p1 != 0``) is an error.
    pixel_pitch : float or None
        Size of a sensor pixel (m), needed only for the thesis's Heikkilä parameters (§5.3: 100 px/mm, i.e. 1e-5 m).
    """

    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    name: str = "camera"
    model: str | None = None
    pixel_pitch: float | None = None

    def __post_init__(self):
        for key in ("width", "height"):
            val = getattr(self, key)
            if isinstance(val, bool) or not isinstance(val, (int, np.integer)) or val <= 0:
                raise ValueError(f"{key}: expected a positive integer number of pixels, got {val!r}")
            object.__setattr__(self, key, int(val))
        K = check_K(self.K).copy()
        dist = check_dist(self.dist)
        K.flags.writeable = False
        dist.flags.writeable = False
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", dist)
        derived = model_of(dist)
        model = derived if self.model is None else self.model
        if model not in MODELS:
            raise ValueError(f"model: expected one of {MODELS}, got {model!r}")
        if MODELS.index(model) < MODELS.index(derived):
            raise ValueError(f"model: {model!r} cannot hold dist = {dist.tolist()} (needs {derived!r})")
        object.__setattr__(self, "model", model)
        if self.pixel_pitch is not None:
            pitch = float(self.pixel_pitch)
            if not (np.isfinite(pitch) and 0 < pitch < 1e-3):
                raise ValueError(f"pixel_pitch: expected a pixel size in m in (0, 1e-3), got {self.pixel_pitch!r}")
            object.__setattr__(self, "pixel_pitch", pitch)

    # --- parameters ---------------------------------------------------------------------------------------------------
    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def skew(self) -> float:
        return float(self.K[0, 1])

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)`` in px, OpenCV's ``image_size``."""
        return self.width, self.height

    def replace(self, **changes) -> CameraModel:
        """A copy with some fields changed (validated again)."""
        return replace(self, **changes)

    # --- the chain ----------------------------------------------------------------------------------------------------
    def project(self, p_cam) -> np.ndarray:
        """Pixels ``(..., 2)`` of camera-frame points ``p_cam (..., 3)`` (m); NaN for points with ``z <= 0``.

        Equal to ``cv2.projectPoints`` with ``rvec = tvec = 0`` (Eq. 46, 75-76, 50).
        """
        return to_pixels(distort(project_pinhole(p_cam), self.dist), self.K)

    def undistort_pixels(self, uv, **kwargs) -> np.ndarray:
        """Ideal normalised coordinates ``(..., 2)`` of pixels ``uv (..., 2)`` (Eq. 51 then the inverse of 75-76)."""
        return undistort(from_pixels(uv, self.K), self.dist, **kwargs)

    def unproject(self, uv, normalize: bool = True) -> np.ndarray:
        """Rays ``(..., 3)`` in the camera frame through pixels ``uv (..., 2)``; unit length, or ``z = 1``."""
        return unproject_pinhole(self.undistort_pixels(uv), normalize=normalize)

    def in_image(self, uv, border: float = 0.0) -> np.ndarray:
        """Mask ``(...,)``: pixel centres inside the image footprint ``[-0.5, W - 0.5] x [-0.5, H - 0.5]``."""
        uv = np.asarray(uv, dtype=float)
        with np.errstate(invalid="ignore"):
            return ((uv[..., 0] >= -0.5 + border) & (uv[..., 0] <= self.width - 0.5 - border)
                    & (uv[..., 1] >= -0.5 + border) & (uv[..., 1] <= self.height - 0.5 - border))

    def check_invertible(self, samples: int = 64) -> float:
        """Check that the distortion is one-to-one over the image; returns the smallest Jacobian determinant found.

        The image border (``samples`` points per side) and an interior grid are undistorted, and the Jacobian of the
        forward model is evaluated there; a non-converging point or a determinant ``<= 0`` (the distortion folds
        over) is a one-line ``ValueError`` naming the camera.
        """
        u = np.linspace(-0.5, self.width - 0.5, samples)
        v = np.linspace(-0.5, self.height - 0.5, samples)
        uu, vv = np.meshgrid(u, v)
        res = undistort(from_pixels(np.stack([uu, vv], axis=-1), self.K), self.dist, full_output=True)
        if not res.success:
            raise ValueError(f"camera {self.name!r}: dist: distortion not invertible over the image ({res.message})")
        J = distortion_jacobian(res.x_n, self.dist)
        det = float(np.min(np.linalg.det(J)))
        if det <= 0:
            raise ValueError(f"camera {self.name!r}: dist: distortion folds over inside the image (det {det:.3g})")
        return det


def random_camera_model(rng: np.random.Generator, width: int = 640, height: int = 480, model: str = "heikkila",
                        skew: bool = True, k3: bool = False, name: str = "random") -> CameraModel:
    """A plausible random camera for tests: ``f`` 400-1000 px, principal point near the centre, small skew and
    distortion of the given model (``|k1| <= 0.3``, ``|k2| <= 0.1``, ``|p| <= 2e-3``, ``|k3| <= 0.05``)."""
    f = rng.uniform(400, 1000)
    K = np.array([[f * rng.uniform(0.95, 1.05), rng.uniform(-2, 2) if skew else 0.0,
                   width / 2 + rng.uniform(-20, 20)],
                  [0.0, f, height / 2 + rng.uniform(-20, 20)], [0.0, 0.0, 1.0]])
    for _ in range(100):  # redraw until the distortion is one-to-one over the image
        dist = np.zeros(5)
        if model in ("radial", "heikkila"):
            dist[0], dist[1] = rng.uniform(-0.3, 0.3), rng.uniform(-0.1, 0.1)
            if k3:
                dist[4] = rng.uniform(-0.05, 0.05)
        if model == "heikkila":
            dist[2:4] = rng.uniform(-2e-3, 2e-3, 2)
        camera = CameraModel(width, height, K, dist, name=name, model=model)
        try:
            camera.check_invertible(samples=16)
        except ValueError:
            continue
        return camera
    raise RuntimeError("random_camera_model: no invertible distortion drawn in 100 tries")
