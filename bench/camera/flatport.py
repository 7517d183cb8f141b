"""Flat-port refraction, the pipeline's side: a camera in air behind a plane glass port, looking into water.

Geometry (camera frame, OpenCV axes, SI units). The port is a glass slab bounded by two parallel planes with unit
normal ``n = R_y(tilt_y) R_x(tilt_x) e_z`` (pointing into the water). The inner (air-side) surface contains the point
``(decentre_x, decentre_y, d0)``; its distance from the camera centre along the normal is
``h = n . (decentre_x, decentre_y, d0)`` (must be > 0), the outer surface lies ``t`` further. Inside the housing the
medium has index ``n_air``, the slab ``n_glass``, outside ``n_water`` (for a housing in air set ``n_water = n_air``).

Because the interfaces are infinite parallel planes, the system is rotationally symmetric about the *port axis* (the
line through the camera centre along ``n``): tilt matters, and a decentre matters only through ``h`` (sliding an
infinite plane within itself changes nothing; a finite port aperture, which would vignette, is not modelled).

* :func:`refract` - vector Snell's law ``n1 (d x n) = n2 (t x n)`` with a total-internal-reflection mask;
* :func:`trace_rays` - in-air rays from the camera centre through both interfaces: the ray's origin on the outer
  surface and its direction in water. For ``d0 > 0`` these water rays do *not* meet in one point (the camera is not
  a single-viewpoint camera); they touch a caustic on the port axis (:func:`axis_crossing`);
* :func:`project_flatport` - the forward projection of water points: by the symmetry the ray through a point lies
  in the plane spanned by the port axis and the point, so the problem is one-dimensional in the refraction invariant
  ``s = n_air sin(theta_air) = n_glass sin(theta_glass) = n_water sin(theta_water)``:
  ``h tan(theta_air) + t tan(theta_glass) + (z_p - h - t) tan(theta_water) = rho_p`` (the radial offset of the point
  from the port axis, ``z_p`` its distance along the axis), solved by safeguarded Newton iteration to 1e-12.

The simulator renders through the same functions (:class:`bench.sim.flatport.FlatPortStage`); the pipeline's
refractive camera (:mod:`bench.camera.refractive`) calibrates a port and projects through it. Pure numpy: nothing
here reads the simulator.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from bench.camera.model import CameraModel, check_K, to_pixels
from bench.errors import ConfigError
from bench.geometry.transforms import check_vectors, rot_x, rot_y

#: convergence tolerance of the forward projection (m, on the radial offset from the port axis)
PROJECT_TOL = 1e-12


# ----------------------------------------------------------------------------------------------------------------------
# the port
# ----------------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FlatPort:
    """A flat glass port in front of a camera (see the module docstring for the geometry).

    Attributes
    ----------
    d0 : float
        Camera centre (entrance pupil) to the inner glass surface along the optical axis (m), > 0.
    t : float
        Glass thickness (m), >= 0.
    n_air, n_glass, n_water : float
        Refractive indices inside the housing, of the glass and outside (>= 1).
    tilt : (2,) float
        Port tilt about the camera x then y axis (rad), each in (-pi/4, pi/4).
    decentre : (2,) float
        Lateral position (m) of the port's reference point ``(decentre_x, decentre_y, d0)``.
    source : str
        Name used in error messages.
    """

    d0: float = 0.02
    t: float = 0.01
    n_air: float = 1.0
    n_glass: float = 1.49
    n_water: float = 1.34
    tilt: np.ndarray = field(default_factory=lambda: np.zeros(2))
    decentre: np.ndarray = field(default_factory=lambda: np.zeros(2))
    source: str = "flat port"

    def __post_init__(self):
        for key in ("d0", "t", "n_air", "n_glass", "n_water"):
            val = getattr(self, key)
            if isinstance(val, bool) or not isinstance(val, (int, float, np.integer, np.floating)) \
                    or not np.isfinite(val):
                raise ConfigError(self.source, key, f"expected a finite number, got {val!r}")
            object.__setattr__(self, key, float(val))
        if self.d0 <= 0:
            raise ConfigError(self.source, "d0", f"lens-to-glass distance must be > 0 m, got {self.d0}")
        if self.t < 0:
            raise ConfigError(self.source, "t", f"glass thickness must be >= 0 m, got {self.t}")
        for key in ("n_air", "n_glass", "n_water"):
            if getattr(self, key) < 1.0:
                raise ConfigError(self.source, key, f"refractive index must be >= 1, got {getattr(self, key)}")
        for key, bound in (("tilt", np.pi / 4), ("decentre", 1.0)):
            arr = np.array(getattr(self, key), dtype=float)
            if arr.shape != (2,) or not np.all(np.isfinite(arr)):
                raise ConfigError(self.source, key, f"expected 2 finite numbers, got {getattr(self, key)!r}")
            if np.any(np.abs(arr) >= bound):
                raise ConfigError(self.source, key, f"each value must be below {bound:g} in magnitude, got "
                                  f"{arr.tolist()}")
            arr.flags.writeable = False
            object.__setattr__(self, key, arr)
        if self.h <= 0:
            raise ConfigError(self.source, "decentre", f"the port plane must lie in front of the camera centre "
                              f"(distance along the normal {self.h} m)")

    @property
    def R_cam_port(self) -> np.ndarray:
        """Rotation (3, 3) from the port frame (z along the port normal) to the camera frame."""
        return rot_y(self.tilt[1]) @ rot_x(self.tilt[0])

    @property
    def normal(self) -> np.ndarray:
        """Unit normal (3,) of the glass surfaces in the camera frame, pointing into the water."""
        return self.R_cam_port[:, 2]

    @property
    def h(self) -> float:
        """Distance (m) from the camera centre to the inner glass surface along the normal."""
        return float(self.normal @ np.array([self.decentre[0], self.decentre[1], self.d0]))

    @property
    def axial_d0(self) -> float:
        """Camera centre to the inner glass surface along the optical axis (m): ``h / n_z``, the ``d0`` of the centred
        port with the same glass plane (a decentre absorbed)."""
        return self.h / float(self.normal[2])

    def centred(self, d0_offset: float = 0.0, keep_tilt: bool = True) -> FlatPort:
        """The port without decentre at ``d0 = axial_d0 + d0_offset`` (m): with its tilt kept, the same glass plane;
        with the tilt dropped, the square port a housing's datasheet describes."""
        return replace(self, d0=self.axial_d0 + d0_offset, decentre=np.zeros(2),
                       tilt=self.tilt if keep_tilt else np.zeros(2))


def check_port(port) -> FlatPort:
    if not isinstance(port, FlatPort):
        raise ValueError(f"port: expected a FlatPort, got {type(port).__name__}")
    return port


# ----------------------------------------------------------------------------------------------------------------------
# Snell's law
# ----------------------------------------------------------------------------------------------------------------------
def refract(d, n, n1, n2):
    """Vector Snell's law at an interface with normal ``n`` from index ``n1`` into ``n2``.

    ``t = eta d + (cos_t - eta cos_i) n`` with ``eta = n1 / n2``, ``cos_i = d . n`` and
    ``cos_t = sqrt(1 - eta^2 (1 - cos_i^2))``; ``n`` is oriented along the propagation (flipped where ``d . n < 0``),
    so ``t`` lies in the plane of ``d`` and ``n`` and ``n1 |d x n| = n2 |t x n|``.

    Parameters
    ----------
    d : array_like (..., 3)
        Incident directions (normalised here).
    n : array_like (..., 3) or (3,)
        Surface normals (normalised here).
    n1, n2 : float or array_like (...)
        Refractive indices of the incident and the transmitting medium (>= 1).

    Returns
    -------
    t : ndarray (..., 3)
        Unit transmitted directions; NaN where the light is totally reflected.
    ok : ndarray (...) bool
        False where total internal reflection occurs (``eta^2 sin^2(theta_i) > 1``).
    """
    d = check_vectors(d, "d", 3)
    n = check_vectors(n, "n", 3)
    n1, n2 = np.asarray(n1, dtype=float), np.asarray(n2, dtype=float)
    if np.any(~np.isfinite(n1)) or np.any(~np.isfinite(n2)) or np.any(n1 < 1) or np.any(n2 < 1):
        raise ValueError("n1, n2: refractive indices must be finite and >= 1")
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    cos_i = np.sum(d * n, axis=-1)
    n = np.where((cos_i < 0)[..., None], -n, n)
    cos_i = np.abs(cos_i)
    eta = n1 / n2
    k = 1.0 - eta**2 * (1.0 - cos_i**2)
    ok = k >= 0
    cos_t = np.sqrt(np.where(ok, k, 0.0))
    t = eta[..., None] * d + (cos_t - eta * cos_i)[..., None] * n
    t = t / np.linalg.norm(t, axis=-1, keepdims=True)
    return np.where(ok[..., None], t, np.nan), ok


# ----------------------------------------------------------------------------------------------------------------------
# tracing and projection
# ----------------------------------------------------------------------------------------------------------------------
def trace_rays(dirs_cam, port: FlatPort):
    """Trace in-air rays from the camera centre through the port into the water.

    Parameters
    ----------
    dirs_cam : array_like (..., 3)
        Ray directions in the camera frame (any length; must not be zero).
    port : FlatPort

    Returns
    -------
    origin : ndarray (..., 3)
        Where each ray leaves the outer glass surface (m, camera frame).
    direction : ndarray (..., 3)
        Unit direction in water (camera frame).
    ok : ndarray (...) bool
        False for rays that miss the port (``d . n <= 0``) or are totally reflected; their outputs are NaN.
    """
    port = check_port(port)
    d = check_vectors(dirs_cam, "dirs_cam", 3)
    norm = np.linalg.norm(d, axis=-1, keepdims=True)
    if np.any(norm == 0):
        raise ValueError("dirs_cam: contains a zero vector")
    d = d / norm
    n = port.normal
    c1 = d @ n
    ok = c1 > 1e-12
    with np.errstate(divide="ignore", invalid="ignore"):
        p1 = d * (port.h / np.where(ok, c1, np.nan))[..., None]  # inner surface
        d2, ok2 = refract(d, n, port.n_air, port.n_glass)
        p2 = p1 + d2 * (port.t / (d2 @ n))[..., None]  # outer surface
        d3, ok3 = refract(np.where(ok2[..., None], d2, n), n, port.n_glass, port.n_water)
    ok = ok & ok2 & ok3
    nan = np.full(d.shape, np.nan)
    return np.where(ok[..., None], p2, nan), np.where(ok[..., None], d3, nan), ok


def axis_crossing(dirs_cam, port: FlatPort) -> np.ndarray:
    """Where the water rays, extended backwards, cross the port axis: distance (m) from the camera centre along it.

    A single-viewpoint camera has one value for all rays; a flat port with ``d0 > 0`` spreads them along the axis
    (the caustic): ``z = h + t - (h tan(a) + t tan(g)) / tan(w)`` with the ray's angles to the axis in air, glass
    and water; its paraxial limit is ``h + t - (h n_water / n_air + t n_water / n_glass)``. Rays along the axis have
    no crossing (NaN).
    """
    port = check_port(port)
    o, w, ok = trace_rays(dirs_cam, port)
    R = port.R_cam_port
    o_p, w_p = o @ R, w @ R
    rho_o = np.hypot(o_p[..., 0], o_p[..., 1])
    rho_w = np.hypot(w_p[..., 0], w_p[..., 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        z = o_p[..., 2] - rho_o * w_p[..., 2] / rho_w
    return np.where(ok & (rho_w > 1e-15), z, np.nan)


@dataclass(frozen=True)
class FlatPortProjection:
    """Result of :func:`project_flatport` with ``full_output=True``.

    Attributes
    ----------
    x_n : ndarray (..., 2)
        Pinhole coordinates of the in-air rays (NaN where not converged or no solution).
    converged : ndarray (...) bool
    iterations : int
    max_residual : float
        Largest ``|rho(s) - rho_p|`` (m) over the converged points.
    success : bool
    message : str
    """

    x_n: np.ndarray
    converged: np.ndarray
    iterations: int
    max_residual: float
    success: bool
    message: str


def _radial_offset(s, L, n_k):
    """rho(s) = sum_k L_k s / sqrt(n_k^2 - s^2) and its derivative (Snell's invariant s)."""
    rho = np.zeros_like(s)
    drho = np.zeros_like(s)
    for Lk, nk in zip(L, n_k, strict=True):
        if np.all(Lk == 0):
            continue
        c = np.sqrt(nk * nk - s * s)
        rho += Lk * s / c
        drho += Lk * nk * nk / c**3
    return rho, drho


def lens_port_projector(camera: CameraModel, port: FlatPort | None = None):
    """``project(p_cam (..., 3)) -> uv (..., 2)`` (px) through the lens ``camera`` and, if given, the flat ``port``
    (:func:`project_flatport`, then the lens's distortion and K); NaN where a point cannot be imaged."""
    if port is None:
        return camera.project

    def project(p_cam):
        x_n = project_flatport(np.asarray(p_cam, dtype=float), port)
        return camera.project(np.concatenate([x_n, np.ones(x_n.shape[:-1] + (1,))], axis=-1))

    return project


def project_flatport(p_cam, port: FlatPort, K=None, *, tol: float = PROJECT_TOL, max_iterations: int = 100,
                     full_output: bool = False):
    """Forward projection of water points through the flat port: the image point of the in-air ray.

    Solves ``rho(s) = h s / c_a + t s / c_g + (z_p - h - t) s / c_w = rho_p`` with ``c_k = sqrt(n_k^2 - s^2)`` for the
    refraction invariant ``s in [0, min n)``: ``rho`` is increasing and convex, Newton steps are kept inside a
    shrinking bisection bracket, stop when ``|rho(s) - rho_p| <= tol`` (m) or the step is below float resolution.

    Parameters
    ----------
    p_cam : array_like (..., 3)
        Points in the camera frame (m); they must lie beyond the outer glass surface.
    port : FlatPort
    K : array_like (3, 3), optional
        Intrinsics of the (distortion-free) camera inside the housing (px, Eq. 50, skew allowed): when given, the
        result is in pixels ``uv = K (x_n, 1)``; with a distorted lens use ``lens.project`` on ``(x_n, 1)`` instead.
    tol : float
        Convergence tolerance on the radial residual (m).
    max_iterations : int
    full_output : bool
        Return a :class:`FlatPortProjection` instead of ``x_n``.

    Returns
    -------
    x_n : ndarray (..., 2)
        ``(x/z, y/z)`` of the in-air ray direction (the inner camera's ideal normalised coordinate, Eq. 46), or the
        pixels ``uv`` (px, OpenCV convention) when ``K`` is given; NaN for points inside the housing or on the wrong
        side, and for non-converged points. With ``full_output`` a :class:`FlatPortProjection` (its ``x_n`` holds
        the pixels when ``K`` is given).
    """
    port = check_port(port)
    K = None if K is None else check_K(K, "K")
    p = np.asarray(p_cam, dtype=float)
    if p.ndim < 1 or p.shape[-1] != 3:
        raise ValueError(f"p_cam: expected shape (..., 3), got {p.shape}")
    R = port.R_cam_port
    q = p @ R  # port frame
    rho_p = np.hypot(q[..., 0], q[..., 1])
    Lw = q[..., 2] - port.h - port.t
    valid = np.isfinite(rho_p) & np.isfinite(Lw) & (Lw > 0)
    rho_t, Lw_v = rho_p[valid], Lw[valid]
    n_k = (port.n_air, port.n_glass, port.n_water)
    L = (port.h, port.t, Lw_v)
    n_min = min(n_k)
    lo = np.zeros_like(rho_t)
    hi = np.full_like(rho_t, n_min)
    # start from the thin-port solution in water (rho_p / z_p = tan(theta_water))
    s = np.clip(port.n_water * rho_t / np.hypot(rho_t, q[valid][:, 2]), 0.0, n_min * (1 - 1e-12))
    done = rho_t == 0
    s[done] = 0.0
    it = 0
    for it in range(1, max_iterations + 1):
        act = ~done
        if not np.any(act):
            it -= 1
            break
        La = tuple(Lk if np.ndim(Lk) == 0 else Lk[act] for Lk in L)
        rho, drho = _radial_offset(s[act], La, n_k)
        f = rho - rho_t[act]
        conv = np.abs(f) <= 1e-3 * tol  # iterate to float resolution; success is judged against tol
        lo_a, hi_a = lo[act], hi[act]
        lo_a = np.where(f < 0, s[act], lo_a)  # rho increasing: f < 0 -> root above s
        hi_a = np.where(f > 0, s[act], hi_a)
        step = s[act] - f / drho
        bad = ~((step > lo_a) & (step < hi_a)) | ~np.isfinite(step)
        step = np.where(bad, 0.5 * (lo_a + hi_a), step)
        small = np.abs(step - s[act]) <= 4 * np.finfo(float).eps * np.maximum(s[act], 1e-300)
        new_s = np.where(conv, s[act], step)
        idx = np.flatnonzero(act)
        s[idx], lo[idx], hi[idx] = new_s, lo_a, hi_a
        done[idx[conv | small]] = True
    # final residual and convergence
    rho, _ = _radial_offset(s, L, n_k)
    res = np.abs(rho - rho_t)
    conv_v = res <= tol + 8 * np.finfo(float).eps * np.maximum(rho_t, 1.0)
    sin_a = s / port.n_air
    cos_a = np.sqrt(1.0 - sin_a**2)
    qv = q[valid]
    with np.errstate(divide="ignore", invalid="ignore"):
        radial = np.where(rho_t[:, None] > 0, qv[:, :2] / rho_t[:, None], 0.0)
    dir_port = np.concatenate([sin_a[:, None] * radial, cos_a[:, None]], axis=-1)
    dir_cam = dir_port @ R.T
    x_n = np.full(p.shape[:-1] + (2,), np.nan)
    ok_v = conv_v & (dir_cam[:, 2] > 0)
    vals = np.where(ok_v[:, None], dir_cam[:, :2] / dir_cam[:, 2:3], np.nan)
    x_n[valid] = vals
    if K is not None:
        x_n = to_pixels(x_n, K)  # Eq. 50
    if not full_output:
        return x_n
    converged = np.zeros(p.shape[:-1], dtype=bool)
    converged[valid] = ok_v
    max_res = float(res[ok_v].max()) if np.any(ok_v) else 0.0
    n_bad = int(np.count_nonzero(~converged))
    msg = "converged" if n_bad == 0 else f"{n_bad} point(s) not projected (inside the housing, behind, or no root)"
    return FlatPortProjection(x_n, converged, it, max_res, n_bad == 0, msg)
