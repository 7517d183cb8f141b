"""Physically based flat-port refraction: a camera in air behind a plane glass port, looking into water.

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
  from the port axis, ``z_p`` its distance along the axis), solved by safeguarded Newton iteration to 1e-12;
* :class:`FlatPortStage` - the image of a pinhole render (RGB + z-depth from the same camera centre) through the
  port, by per-pixel ray tracing (see the class docstring).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field

import cv2
import numpy as np

from bench.camera.model import CameraModel, check_K, from_pixels, to_pixels, unproject_pinhole
from bench.errors import ConfigError
from bench.geometry.transforms import rot_x, rot_y
from bench.sim.distortion import RenderSpec, check_supersample, subsample_coordinates
from bench.sim.parallel import band_edges, map_bands

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


def _as_port(port) -> FlatPort:
    if not isinstance(port, FlatPort):
        raise ValueError(f"port: expected a FlatPort, got {type(port).__name__}")
    return port


def _check_vectors(v, name) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    if v.ndim < 1 or v.shape[-1] != 3:
        raise ValueError(f"{name}: expected shape (..., 3), got {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{name}: contains NaN or inf")
    return v


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
    d = _check_vectors(d, "d")
    n = _check_vectors(n, "n")
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
    port = _as_port(port)
    d = _check_vectors(dirs_cam, "dirs_cam")
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
    port = _as_port(port)
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
    port = _as_port(port)
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
    s = np.zeros_like(rho_t)
    # start from the thin-port solution in water (rho_p / z_p = tan(theta_water))
    s = np.clip(port.n_water * rho_t / np.hypot(rho_t, q[valid][:, 2]), 0.0, n_min * (1 - 1e-12))
    done = rho_t == 0
    s[done] = 0.0
    it = 0
    res = np.zeros_like(rho_t)
    for it in range(1, max_iterations + 1):
        act = ~done
        if not np.any(act):
            it -= 1
            break
        La = tuple(Lk if np.ndim(Lk) == 0 else Lk[act] for Lk in L)
        rho, drho = _radial_offset(s[act], La, n_k)
        f = rho - rho_t[act]
        res[act] = f
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


# ----------------------------------------------------------------------------------------------------------------------
# the image stage
# ----------------------------------------------------------------------------------------------------------------------
_CACHE_SIZE = 4
_TRACE_CACHE: OrderedDict = OrderedDict()


@dataclass(frozen=True)
class FlatPortImage:
    """Output of :meth:`FlatPortStage.apply`.

    Attributes
    ----------
    image : ndarray (H, W[, C])
        The image through the port (dtype of the render).
    depth : ndarray (H, W) float
        z (m, camera frame) of the point seen by each pixel centre's ray; inf where it sees the background.
    water_path : ndarray (H, W) float
        Path length (m) in water of each pixel centre's ray, from the outer glass surface to the point; inf for the
        background (the water path the medium stage needs).
    converged_fraction : float
        Fraction of the finite-depth sub-samples whose depth iteration converged.
    unresolved : ndarray (H, W) int
        Sub-samples per pixel that did not converge (occlusion boundaries) and took the background.
    """

    image: np.ndarray
    depth: np.ndarray
    water_path: np.ndarray
    converged_fraction: float
    unresolved: np.ndarray


class FlatPortStage:
    """The image of a pinhole render seen through a flat port (per-pixel ray tracing).

    For every output pixel ``s x s`` sub-rays (same sub-sample positions and box filter as
    :class:`bench.sim.distortion.DistortionStage`) leave the camera centre in air - through ``K_out^-1`` (Eq. 51), or
    through ``lens.unproject`` when a lens :class:`CameraModel` (the housing's inner camera with its distortion,
    Eq. 75-76) is given - and are traced through both glass surfaces into water (:func:`trace_rays`, cached). The
    point a water ray ``o + lambda w`` hits is found with the depth buffer of the pinhole render, rendered from the
    same camera centre: starting from the render depth in the ray's far direction ``w``, the fixed-point iteration
    ``lambda <- (z_r(K_render pi(o + lambda w)) - o_z) / w_z`` makes the point's z equal to the render depth where
    the point projects. It contracts fast because the origins ``o`` are a few cm off the centre (the parallax per
    metre of ``lambda`` is small); it stops at ``|d lambda| <= tol_rel lambda`` or, for the sub-rays that only
    sample the colour, when the sample point moves by less than ``tol_px`` render px (0.001 px by default, 30 times
    below the 1/32 px resolution of ``cv2.remap``'s weights). The RGB is then sampled bilinearly
    at the converged render pixel and the ``s x s`` samples are averaged.

    Residual approximations (documented, measured in the tests): the depth buffer is interpolated bilinearly in z
    (exact for fronto-parallel planes, second order for slanted ones), sampled by ``cv2.remap`` (bilinear weights
    quantised to 1/32 render px); a surface hidden from the pinhole centre but visible from the shifted origin ``o``
    (dis-occlusion, a few render px wide at depth edges) cannot be seen in a single-centre render: such rays converge
    onto the occluder or oscillate. Sub-rays that do not converge take ``background`` (default: the render sampled in
    the ray's direction at infinity); rays whose render depth is infinite see the background at infinity, which is
    exact (no parallax at infinity). The test with a near half-plane (0.4 m) in front of a wall (1.0 m), edge 6 cm
    off the axis, ``f = 160`` px: the stage differs from an exact ray trace only in a 1-2 px band next to the edge
    (predicted analytically as the wall points the shifted rays see but the centre does not) and by <= 0.3 DN
    elsewhere.

    Parameters
    ----------
    K_out : array_like (3, 3)
        Intrinsics of the output image (px); ignored in favour of ``lens.K`` when ``lens`` is given (must match).
    size_out : (int, int)
        ``(width, height)`` of the output (px).
    port : FlatPort
    supersample : int
        Sub-rays per output pixel along each axis (1..16).
    lens : CameraModel, optional
        The inner camera (lens distortion applied in ray space, before the port).
    background : sequence of float, optional
        Colour of non-converged sub-rays; ``None`` samples the render at the ray's direction at infinity.
    """

    def __init__(self, K_out, size_out, port: FlatPort, supersample: int, lens: CameraModel | None = None,
                 background=None):
        self.port = _as_port(port)
        self.supersample = check_supersample(supersample)
        K = check_K(K_out, "K_out")
        try:
            W, H = (int(v) for v in size_out)
        except (TypeError, ValueError):
            raise ValueError(f"size_out: expected (width, height), got {size_out!r}") from None
        if W < 1 or H < 1:
            raise ValueError(f"size_out: expected positive (width, height), got {size_out!r}")
        if lens is not None:
            if not isinstance(lens, CameraModel):
                raise ValueError(f"lens: expected a CameraModel, got {type(lens).__name__}")
            if lens.size != (W, H) or not np.allclose(lens.K, K):
                raise ValueError(f"lens: its K and size {lens.size} must equal K_out and size_out {(W, H)}")
        self.K_out, self.width, self.height, self.lens = K, W, H, lens
        self.background = None if background is None else np.asarray(background, dtype=np.float32).ravel()

    # --- rays ---------------------------------------------------------------------------------------------------------
    def _key(self, which):
        lens = None if self.lens is None else (self.lens.K.tobytes(), self.lens.dist.tobytes())
        p = self.port
        return (which, self.K_out.tobytes(), self.width, self.height, self.supersample, lens,
                (p.d0, p.t, p.n_air, p.n_glass, p.n_water, p.tilt.tobytes(), p.decentre.tobytes()))

    def _air_rays(self, uv):
        if self.lens is not None:
            return self.lens.unproject(uv)
        return unproject_pinhole(from_pixels(uv, self.K_out))

    def rays(self, which: str = "sub"):
        """Cached ``(origin, direction, ok)`` in water for the sub-samples (``"sub"``, ``(H s, W s)``) or the pixel
        centres (``"centre"``, ``(H, W)``)."""
        key = self._key(which)
        if key in _TRACE_CACHE:
            _TRACE_CACHE.move_to_end(key)
            return _TRACE_CACHE[key]
        s = self.supersample if which == "sub" else 1
        uu, vv = np.meshgrid(subsample_coordinates(self.width, s), subsample_coordinates(self.height, s))
        o, w, ok = trace_rays(self._air_rays(np.stack([uu, vv], -1)), self.port)
        if not np.all(ok):
            raise ValueError(f"port: {np.count_nonzero(~ok)} ray(s) of the image are totally reflected or miss the "
                             "port (tilt too large for the field of view)")
        _TRACE_CACHE[key] = (o, w, ok)
        while len(_TRACE_CACHE) > _CACHE_SIZE:
            _TRACE_CACHE.popitem(last=False)
        return o, w, ok

    def render_spec(self, z_min: float, margin: int = 2) -> RenderSpec:
        """A pinhole render (intrinsics, size) that covers every point the output sees at depths ``z >= z_min`` (m).

        Points on a water ray at ``z >= z_min`` project between the ray's point at ``z_min`` and its direction at
        infinity; the render's focal lengths are ``s n_water / n_air`` times the output's (the port magnifies).
        """
        if not np.isfinite(z_min) or z_min <= self.port.h + self.port.t:
            raise ValueError(f"z_min: must exceed the outer glass surface ({self.port.h + self.port.t} m), got "
                             f"{z_min}")
        o, w, _ = self.rays("sub")
        border = np.concatenate([o[0], o[-1], o[:, 0], o[:, -1]]), np.concatenate([w[0], w[-1], w[:, 0], w[:, -1]])
        ob, wb = border
        lam = (z_min - ob[:, 2]) / wb[:, 2]
        pts = ob + lam[:, None] * wb
        x_n = np.concatenate([pts[:, :2] / pts[:, 2:], wb[:, :2] / wb[:, 2:]])
        lo, hi = x_n.min(axis=0), x_n.max(axis=0)
        mag = self.supersample * self.port.n_water / self.port.n_air
        f_r = mag * np.array([self.K_out[0, 0], self.K_out[1, 1]])
        size = np.ceil((hi - lo) * f_r).astype(int) + 1 + 2 * margin
        c_r = margin - f_r * lo
        K = np.array([[f_r[0], 0.0, c_r[0]], [0.0, f_r[1], c_r[1]], [0.0, 0.0, 1.0]])
        return RenderSpec(K, int(size[0]), int(size[1]), self.supersample)

    # --- the depth iteration ------------------------------------------------------------------------------------------
    def projection(self, which: str, K_render) -> _RayProjection:
        """Cached :class:`_RayProjection` of the ``which`` rays (see :meth:`rays`) into a render with ``K_render``."""
        K_r = check_K(K_render, "K_render")
        key = self._key(which) + (K_r.tobytes(),)
        if key in _PROJ_CACHE:
            _PROJ_CACHE.move_to_end(key)
            return _PROJ_CACHE[key]
        o, w, _ = self.rays(which)
        proj = _RayProjection.build(o, w, K_r)
        _PROJ_CACHE[key] = proj
        while len(_PROJ_CACHE) > _CACHE_SIZE:
            _PROJ_CACHE.popitem(last=False)
        return proj

    @staticmethod
    def _solve(o, w, depth32, K_r, max_iterations, tol_rel):
        """Fixed point of the ray parameter for arrays ``o, w (..., 3)``: returns ``(lam, uv, status)`` (flat).

        status: 0 converged on a finite surface, 1 background (infinite depth), 2 not converged.
        """
        proj = _RayProjection.build(np.asarray(o, float).reshape(1, -1, 3), np.asarray(w, float).reshape(1, -1, 3),
                                    check_K(K_r, "K_render"))
        lam, u, v, status = _depth_fixed_point(proj, np.asarray(depth32, np.float32), max_iterations, tol_rel)
        return lam.ravel(), np.stack([u.ravel(), v.ravel()], -1).astype(float), status.ravel()

    def apply(self, image, depth, K_render, *, max_iterations: int = 12, tol_rel: float = 1e-6,
              tol_px: float = 1e-3) -> FlatPortImage:
        """The image through the port of a pinhole render ``image (H_r, W_r[, C])`` with z-depth ``depth (H_r, W_r)``
        (m, inf = background) and intrinsics ``K_render`` (no skew).

        The output's row bands are traced in parallel threads (:mod:`bench.sim.parallel`; every ray is independent,
        so the result does not depend on the split). Raises a one-line ``ValueError`` when a converged hit point lies
        outside the render (see :meth:`render_spec`).
        """
        img = np.asarray(image)
        if img.ndim not in (2, 3) or img.shape[0] < 2 or img.shape[1] < 2:
            raise ValueError(f"image: expected (H, W) or (H, W, C), got shape {img.shape}")
        if img.dtype.kind == "f" and not np.all(np.isfinite(img)):
            raise ValueError("image: contains NaN or inf")
        d = np.asarray(depth)
        if d.shape != img.shape[:2]:
            raise ValueError(f"depth: expected shape {img.shape[:2]} (the image's), got {d.shape}")
        if d.dtype.kind not in "fiu" or np.isnan(d).any() or (d <= 0).any():
            raise ValueError("depth: must be > 0 (m) or inf, no NaN")
        K_r = check_K(K_render, "K_render")
        if K_r[0, 1] != 0:
            raise ValueError("K_render: the render must have no skew")
        Hr, Wr = d.shape
        d32 = np.ascontiguousarray(d, dtype=np.float32)
        s, W, H = self.supersample, self.width, self.height
        if self.background is not None and img.ndim == 3 and self.background.size not in (1, img.shape[2]):
            raise ValueError(f"background: expected 1 or {img.shape[2]} values, got {self.background.size}")
        src = img.astype(np.float32)
        chans = [src] if src.ndim == 2 or src.shape[2] <= 4 else [src[..., i] for i in range(src.shape[2])]
        p_sub, p_ctr = self.projection("sub", K_r), self.projection("centre", K_r)

        def band(r0, r1):
            """Output rows r0..r1: the box-filtered colour, the centre rays' (lam, z) and the sub-ray status."""
            ps = p_sub.rows(r0 * s, r1 * s)
            _, u, v, status = _depth_fixed_point(ps, d32, max_iterations, tol_rel, tol_px)
            hit = status == 0
            if hit.any():
                # the whole band's maps inside the render imply the hits are; otherwise check the hits alone
                if u.min() < -0.5 or v.min() < -0.5 or u.max() > Wr - 0.5 or v.max() > Hr - 0.5:
                    u_hit, v_hit = u[hit], v[hit]
                    if u_hit.min() < -0.5 or v_hit.min() < -0.5 or u_hit.max() > Wr - 0.5 or v_hit.max() > Hr - 0.5:
                        raise ValueError(f"K_render: a {Wr}x{Hr} render does not cover the points the port image "
                                         "sees; use FlatPortStage.render_spec(z_min)")
            m1, m2 = cv2.convertMaps(u, v, cv2.CV_16SC2)
            parts = [cv2.remap(c, m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE) for c in chans]
            sub = parts[0] if len(parts) == 1 else np.stack(parts, axis=-1)
            unresolved = status == 2
            if self.background is not None and unresolved.any():
                bg = self.background if sub.ndim == 3 else self.background[:1]
                sub[unresolved] = bg if sub.ndim == 3 else bg[0]
            if s == 1:
                out = sub
            elif sub.ndim == 2 or sub.shape[2] <= 4:  # INTER_AREA at an integer factor: the exact block mean
                out = cv2.resize(sub, (W, r1 - r0), interpolation=cv2.INTER_AREA)
            else:
                out = sub.reshape(r1 - r0, s, W, s, sub.shape[2]).mean(axis=(1, 3), dtype=np.float32)
            pc = p_ctr.rows(r0, r1)
            lam_c, _, _, st_c = _depth_fixed_point(pc, d32, max_iterations, tol_rel)
            lam_c = np.where(st_c == 0, lam_c, np.inf)
            z_c = np.where(np.isfinite(lam_c), pc.o_z + np.where(np.isfinite(lam_c), lam_c, 0) * pc.w_z, np.inf)
            unres = unresolved.reshape(r1 - r0, s, W, s).sum(axis=(1, 3)).astype(np.int32)
            return out, lam_c, z_c, unres, int(np.count_nonzero(hit)), int(np.count_nonzero(status != 1))

        res = map_bands(band, band_edges(H))
        out = np.concatenate([r[0] for r in res]) if len(res) > 1 else res[0][0]
        if img.dtype.kind in "ui":
            info = np.iinfo(img.dtype)
            out = np.clip(np.rint(out), info.min, info.max).astype(img.dtype)
        lam_c, z_c, unres = (np.concatenate([r[k] for r in res]) for k in (1, 2, 3))
        frac = float(sum(r[4] for r in res) / max(1, sum(r[5] for r in res)))
        return FlatPortImage(out, z_c, lam_c, frac, unres)


# ----------------------------------------------------------------------------------------------------------------------
# the depth fixed point, vectorised
# ----------------------------------------------------------------------------------------------------------------------
_PROJ_CACHE: OrderedDict = OrderedDict()
#: the fixed point runs over the whole ray grid while more than this fraction of rays is active, then on the
#: compacted active rays only (gathering costs more than sampling a few converged rays again)
_DENSE_FRACTION = 0.2


@dataclass(frozen=True)
class _RayProjection:
    """Where the points of a grid of water rays ``o + lambda w`` project in a pinhole render ``K_r`` (no skew).

    With ``z`` the point's z-coordinate (camera frame), ``lambda = (z - o_z) / w_z`` and the point's normalised image
    coordinate is ``x = w_x / w_z + (o_x - o_z w_x / w_z) / z`` (exact), so its render pixel is

        ``u(z) = u_inf + a_u / z``,  ``v(z) = v_inf + a_v / z``,

    ``(u_inf, v_inf)`` the pixel of the ray's direction at infinity and ``a = f_r (o_xy - o_z w_xy / w_z)`` (px m).
    The four fields are computed once per (rays, ``K_r``) in float64 and kept in float32 for the iteration (their
    rounding, < 1e-4 render px, is far below the 1/32 px bilinear weight quantisation of ``cv2.remap``).
    """

    u_inf: np.ndarray  # (R, C) float64
    v_inf: np.ndarray
    a_u: np.ndarray
    a_v: np.ndarray
    o_z: np.ndarray  # (R, C) float64
    w_z: np.ndarray
    f32: tuple  # float32 copies of (u_inf, v_inf, a_u, a_v, o_z) and max(|a_u|, |a_v|)

    def rows(self, r0: int, r1: int) -> _RayProjection:
        """The rays of grid rows ``r0..r1`` (views)."""
        return _RayProjection(*(a[r0:r1] for a in (self.u_inf, self.v_inf, self.a_u, self.a_v, self.o_z, self.w_z)),
                              tuple(a[r0:r1] for a in self.f32))

    @classmethod
    def build(cls, o, w, K_r) -> _RayProjection:
        rx, ry = w[..., 0] / w[..., 2], w[..., 1] / w[..., 2]
        u_inf = K_r[0, 0] * rx + K_r[0, 2]
        v_inf = K_r[1, 1] * ry + K_r[1, 2]
        a_u = K_r[0, 0] * (o[..., 0] - o[..., 2] * rx)
        a_v = K_r[1, 1] * (o[..., 1] - o[..., 2] * ry)
        o_z, w_z = np.ascontiguousarray(o[..., 2]), np.ascontiguousarray(w[..., 2])
        f32 = tuple(np.ascontiguousarray(a, dtype=np.float32)
                    for a in (u_inf, v_inf, a_u, a_v, o_z, np.maximum(np.abs(a_u), np.abs(a_v))))
        return cls(u_inf, v_inf, a_u, a_v, o_z, w_z, f32)


def _converged(z, z_new, o_z, a_max, tol_rel, tol_px):
    """``|dz| <= tol_rel |z - o_z|``, or the sample point moved by at most ``tol_px`` render px (when > 0)."""
    dz = np.abs(z_new - z)
    conv = dz <= np.float32(tol_rel) * np.abs(z - o_z)
    if tol_px > 0:  # |du| = |a_u| |1/z_new - 1/z| = |a_u| |dz| / (z z_new)
        conv |= a_max * dz <= np.float32(tol_px) * z * z_new
    return conv


def _remap_points(src, u, v):
    """Bilinear ``cv2.remap`` of a single-channel float32 image at the points ``(u, v)`` (flat float32 arrays)."""
    n = u.size
    cols = 1024
    rows = -(-n // cols)
    mu = np.zeros(rows * cols, np.float32)
    mv = np.zeros(rows * cols, np.float32)
    mu[:n], mv[:n] = u, v
    out = cv2.remap(src, mu.reshape(rows, cols), mv.reshape(rows, cols), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1)[:n]


def _depth_fixed_point(proj: _RayProjection, depth32, max_iterations: int, tol_rel: float, tol_px: float = 0.0):
    """The depth fixed point of :class:`FlatPortStage` for a grid of rays: ``(lam, u, v, status)``, each ``(R, C)``.

    In the point's z (see :class:`_RayProjection`) the iteration ``lambda <- (z_r(K_r pi(o + lambda w)) - o_z) /
    w_z`` reads ``z <- z_r(u(z), v(z))``, started from the render depth in the ray's far direction; a ray has
    converged when ``|dz| <= tol_rel (z - o_z)`` (i.e. ``|d lambda| <= tol_rel lambda``) or, with ``tol_px > 0``,
    when its sample point moves by at most ``tol_px`` render px (``max(|a_u|, |a_v|) |d(1/z)| <= tol_px``). Each
    step samples the depth buffer (bilinear, ``cv2.remap``) for the whole grid while many rays are active, then for
    the remaining rays only. status: 0 converged on a finite surface, 1 background (infinite depth in the far
    direction), 2 not converged (an occlusion edge) or stepped onto the background. ``(u, v)`` (render px, float32:
    the maps of ``cv2.remap``, whose rounding, < 1e-4 px, is far below its 1/32 px weight quantisation) is the
    converged point's pixel for status 0 and the direction at infinity otherwise; ``lam`` (float64) is inf unless
    status is 0.
    """
    u_inf, v_inf, a_u, a_v, o_z, a_max = proj.f32
    shape = u_inf.shape
    z = cv2.remap(depth32, u_inf, v_inf, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    status = np.full(shape, 2, dtype=np.int8)
    active = np.isfinite(z)
    status[~active] = 1
    n_total = z.size
    it = 0
    while it < max_iterations and np.count_nonzero(active) > _DENSE_FRACTION * n_total:  # dense steps
        it += 1
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = np.float32(1.0) / z
            z_new = cv2.remap(depth32, u_inf + a_u * inv, v_inf + a_v * inv, cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_REPLICATE)
            fin = np.isfinite(z_new)
            conv = active & fin & _converged(z, z_new, o_z, a_max, tol_rel, tol_px)
        np.copyto(z, z_new, where=active & fin)
        status[conv] = 0
        active &= fin & ~conv
    idx = np.flatnonzero(active)
    zf, sf = z.reshape(-1), status.reshape(-1)
    if idx.size and it < max_iterations:  # sparse steps on the remaining rays
        ui, vi, aui, avi, ozi, ami = (a.reshape(-1)[idx] for a in (u_inf, v_inf, a_u, a_v, o_z, a_max))
        zi = zf[idx]
        for _ in range(it, max_iterations):
            inv = np.float32(1.0) / zi
            z_new = _remap_points(depth32, ui + aui * inv, vi + avi * inv)
            fin = np.isfinite(z_new)
            conv = fin & _converged(zi, z_new, ozi, ami, tol_rel, tol_px)
            zi = np.where(fin, z_new, zi)
            sf[idx[conv]] = 0
            keep = fin & ~conv
            zf[idx] = zi
            idx, zi, ui, vi, aui, avi, ozi, ami = (a[keep] for a in (idx, zi, ui, vi, aui, avi, ozi, ami))
            if idx.size == 0:
                break
    hit = status == 0
    inv = np.where(hit, np.float32(1.0) / z, np.float32(0.0))
    u, v = u_inf + a_u * inv, v_inf + a_v * inv
    lam = np.where(hit, (z.astype(np.float64) - proj.o_z) / proj.w_z, np.inf)
    return lam, u, v, status
