"""The thesis's Heikkilä camera parameters (Eq. 74-86, Tables 9 and 15) and their one mapping to OpenCV's ``K, dist``.

Heikkilä's model [17] (the Matlab toolbox the thesis used, §5.3) works on the image plane in length units:
``x = f X/Z``, ``y = f Y/Z`` (f the effective focal length, a length), distortion there
``x_d = x (1 + k1 r^2 + k2 r^4) + 2 p1 x y + p2 (r^2 + 2 x^2)``, ``y_d = y (...) + p1 (r^2 + 2 y^2) + 2 p2 x y``
(``r^2 = x^2 + y^2``), then pixels ``u = D s_u x_d + u0``, ``v = D y_d + v0`` with ``D = 1 / pixel_pitch``
(the sensor's pixel density) and ``s_u`` the aspect ratio. The thesis prints the same model with ``f`` in pixels
(Eq. 75-76, ``s_u f (...)``) and gives the pixel density it entered into the toolbox: a 6.4 x 4.8 mm sensor for
640 x 480 px, "giving 100 pixels/mm" (§5.3). Tables 9 and 15 therefore hold ``k1`` in mm^-2, ``k2`` in mm^-4 and
``T1 = p1``, ``T2 = p2`` in mm^-1 (the toolbox's units); this module keeps them in SI (m^-2, m^-4, m^-1, and ``f``,
the pitch in m). The literal reading of Eq. 75 (distortion on normalised coordinates, the printed numbers used as
unitless OpenCV coefficients) would move the corners of the Table 9 image by 2.5-4 px instead of 70-94 px, at
odds with the "highly distorted" images of §5.3; the presets use the toolbox's units.

The mapping, written down once (:func:`heikkila_to_opencv`, :func:`opencv_to_heikkila`)::

    fx = s_u f / pitch,  fy = f / pitch,  cx = u0,  cy = v0,  skew = 0,
    k1_cv = k1 f^2,  k2_cv = k2 f^4,  p1_cv = p1 f,  p2_cv = p2 f,  k3_cv = 0.

It follows from ``x = f x_n``: ``x_d = f distort_cv(x_n; k1 f^2, k2 f^4, p1 f, p2 f)``. Heikkilä's model has no skew
and no ``k3``; an OpenCV camera with either has no Heikkilä form (one-line ``ValueError``).

Also here: the forward model written independently in the toolbox's own form (:func:`heikkila_project`, for the
cross-check), Eq. 75-76 exactly as printed (:func:`eq75_as_printed`, with its two misprints), and Heikkilä's
implicit inverse model (Eq. 77-86, :func:`fit_implicit_inverse`), as printed and corrected.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.camera.model import CameraModel, check_dist, check_K, distort, from_pixels
from bench.geometry.transforms import check_vectors

#: the thesis's pixel pitch (§5.3: 100 pixels/mm), m
THESIS_PIXEL_PITCH = 1e-5


@dataclass(frozen=True)
class HeikkilaParameters:
    """Heikkilä's intrinsic parameters (Eq. 75-76, Tables 9 and 15) in SI units.

    Attributes
    ----------
    s_u : float
        Aspect ratio (unitless), multiplies the horizontal scale.
    f : float
        Effective focal length (m); ``f / pixel_pitch`` is the thesis's ``f [pix]``.
    u0, v0 : float
        Principal point (px).
    k1 : float
        Radial coefficient (m^-2).
    k2 : float
        Radial coefficient (m^-4).
    p1, p2 : float
        Tangential coefficients (m^-1), the thesis's ``T1``, ``T2``.
    pixel_pitch : float
        Sensor pixel size (m); the thesis's 100 px/mm is ``1e-5``.
    """

    s_u: float
    f: float
    u0: float
    v0: float
    k1: float
    k2: float
    p1: float
    p2: float
    pixel_pitch: float = THESIS_PIXEL_PITCH

    def __post_init__(self):
        for key in ("s_u", "f", "u0", "v0", "k1", "k2", "p1", "p2", "pixel_pitch"):
            val = getattr(self, key)
            try:
                val = float(val)
            except (TypeError, ValueError):
                raise ValueError(f"{key}: expected a number, got {val!r}") from None
            if not np.isfinite(val):
                raise ValueError(f"{key}: must be finite, got {val}")
            object.__setattr__(self, key, val)
        if self.s_u <= 0:
            raise ValueError(f"s_u: aspect ratio must be > 0, got {self.s_u}")
        if self.f <= 0:
            raise ValueError(f"f: focal length must be > 0 (m), got {self.f}")
        if not 0 < self.pixel_pitch < 1e-3:
            raise ValueError(f"pixel_pitch: expected a pixel size in m in (0, 1e-3), got {self.pixel_pitch}")

    @property
    def f_px(self) -> float:
        """Focal length in pixels (the thesis's ``f [pix]``)."""
        return self.f / self.pixel_pitch


def heikkila_to_opencv(params: HeikkilaParameters) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV ``K (3, 3)`` and ``dist (5,)`` of Heikkilä parameters (the mapping of the module docstring)."""
    f, D = params.f, 1.0 / params.pixel_pitch
    K = np.array([[D * params.s_u * f, 0.0, params.u0], [0.0, D * f, params.v0], [0.0, 0.0, 1.0]])
    dist = np.array([params.k1 * f**2, params.k2 * f**4, params.p1 * f, params.p2 * f, 0.0])
    return K, dist


def opencv_to_heikkila(K, dist, pixel_pitch: float = THESIS_PIXEL_PITCH) -> HeikkilaParameters:
    """Heikkilä parameters of an OpenCV camera (inverse of :func:`heikkila_to_opencv`); needs zero skew and k3."""
    K = check_K(K)
    d = check_dist(dist)
    if K[0, 1] != 0:
        raise ValueError(f"K: skew {K[0, 1]} px has no Heikkilä form (the model has none)")
    if d[4] != 0:
        raise ValueError(f"dist: k3 = {d[4]} has no Heikkilä form (the model stops at k2)")
    pitch = float(pixel_pitch)
    if not (np.isfinite(pitch) and 0 < pitch < 1e-3):
        raise ValueError(f"pixel_pitch: expected a pixel size in m in (0, 1e-3), got {pixel_pitch!r}")
    f = K[1, 1] * pitch
    return HeikkilaParameters(s_u=K[0, 0] / K[1, 1], f=f, u0=K[0, 2], v0=K[1, 2], k1=d[0] / f**2, k2=d[1] / f**4,
                              p1=d[2] / f, p2=d[3] / f, pixel_pitch=pitch)


#: order of the parameters in :func:`heikkila_covariance` (that of :class:`HeikkilaParameters`)
HEIKKILA_NAMES = ("s_u", "f", "u0", "v0", "k1", "k2", "p1", "p2")
#: order of the OpenCV parameters it takes (``CalibrationResult.parameter_names`` of the ``"heikkila"`` model)
OPENCV_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")


def heikkila_jacobian(K, dist, pixel_pitch: float = THESIS_PIXEL_PITCH) -> np.ndarray:
    """Derivative ``(8, 8)`` of the Heikkilä parameters (:data:`HEIKKILA_NAMES`, SI) with respect to OpenCV's
    ``fx, fy, cx, cy, k1, k2, p1, p2`` (:data:`OPENCV_NAMES`) at ``K, dist`` (the map of :func:`opencv_to_heikkila`).

    With ``f = fy pitch``: ``s_u = fx / fy``, ``k1 = k1_cv / f^2``, ``k2 = k2_cv / f^4``, ``p = p_cv / f``.
    """
    h = opencv_to_heikkila(K, dist, pixel_pitch)
    fx, fy = float(K[0][0]), float(K[1][1])
    f = h.f
    J = np.zeros((8, 8))
    J[0, 0], J[0, 1] = 1.0 / fy, -fx / fy**2  # s_u
    J[1, 1] = h.pixel_pitch  # f (m)
    J[2, 2] = J[3, 3] = 1.0  # u0, v0
    J[4, 4], J[4, 1] = 1.0 / f**2, -2.0 * h.k1 / fy  # k1 = k1_cv / (fy pitch)^2
    J[5, 5], J[5, 1] = 1.0 / f**4, -4.0 * h.k2 / fy
    J[6, 6], J[6, 1] = 1.0 / f, -h.p1 / fy
    J[7, 7], J[7, 1] = 1.0 / f, -h.p2 / fy
    return J


def heikkila_covariance(K, dist, cov_opencv, pixel_pitch: float = THESIS_PIXEL_PITCH) -> np.ndarray:
    """Covariance ``(8, 8)`` of the Heikkilä parameters (:data:`HEIKKILA_NAMES`; SI: m, m^-2, m^-4, m^-1) from the
    covariance of OpenCV's ``fx, fy, cx, cy, k1, k2, p1, p2`` (``CalibrationResult.covariance`` of the ``"heikkila"``
    model), by first-order propagation ``J C J^T`` (:func:`heikkila_jacobian`)."""
    C = np.asarray(cov_opencv, dtype=float)
    if C.shape != (8, 8) or not np.all(np.isfinite(C)):
        raise ValueError(f"cov_opencv: expected a finite (8, 8) covariance of {OPENCV_NAMES}, got shape {C.shape}")
    J = heikkila_jacobian(K, dist, pixel_pitch)
    return J @ C @ J.T


def camera_from_heikkila(params: HeikkilaParameters, width: int, height: int, name: str = "camera") -> CameraModel:
    """The :class:`CameraModel` (model ``"heikkila"``, with the pixel pitch) of Heikkilä parameters."""
    K, dist = heikkila_to_opencv(params)
    return CameraModel(width, height, K, dist, name=name, model="heikkila", pixel_pitch=params.pixel_pitch)


def heikkila_of(camera: CameraModel) -> HeikkilaParameters:
    """Heikkilä parameters of a camera; needs its ``pixel_pitch`` (one-line ``ValueError`` otherwise)."""
    if camera.pixel_pitch is None:
        raise ValueError(f"camera {camera.name!r}: pixel_pitch: needed for the Heikkilä parameters, not set")
    return opencv_to_heikkila(camera.K, camera.dist, camera.pixel_pitch)


def heikkila_project(params: HeikkilaParameters, p_cam) -> np.ndarray:
    """Pixels ``(..., 2)`` of camera-frame points ``(..., 3)`` (m) computed in the toolbox's own form (Eq. 75-76).

    Written independently of :mod:`bench.camera.model` (on the image plane in m, then to pixels) so that the two
    can be compared; NaN for ``z <= 0``.
    """
    p = check_vectors(p_cam, "p_cam", 3)
    z = np.where(p[..., 2] > 0, p[..., 2], np.nan)
    x = params.f * p[..., 0] / z  # image-plane coordinates (m)
    y = params.f * p[..., 1] / z
    r2 = x * x + y * y
    delta = params.k1 * r2 + params.k2 * r2 * r2
    xd = x * (1 + delta) + 2 * params.p1 * x * y + params.p2 * (r2 + 2 * x * x)
    yd = y * (1 + delta) + params.p1 * (r2 + 2 * y * y) + 2 * params.p2 * x * y
    D = 1.0 / params.pixel_pitch
    return np.stack([D * params.s_u * xd + params.u0, D * yd + params.v0], axis=-1)


def eq75_as_printed(params: HeikkilaParameters, x_n) -> np.ndarray:
    """Eq. 75-76 exactly as printed, on normalised ``x_n (..., 2)`` with the coefficients in normalised units.

    The printed equations differ from the consistent model (:func:`heikkila_project`, OpenCV) by two misprints:
    Eq. 75 has ``k2 v^5`` where the radial term needs ``k2 u^5``, and Eq. 76 ``k1 u^2 v^2`` where it needs
    ``k1 u^2 v``. Kept for the record; the tests pin the difference to exactly these terms.
    """
    x_n = check_vectors(x_n, "x_n", 2)
    _, d = heikkila_to_opencv(params)
    k1, k2, p1, p2 = d[:4]
    u, v = x_n[..., 0], x_n[..., 1]
    fx, fy = params.s_u * params.f_px, params.f_px
    uu = fx * (k2 * v**5 + 2 * k2 * u**3 * v**2 + k2 * u * v**4 + k1 * u**3 + k1 * u * v**2 + 3 * p2 * u**2
               + 2 * p1 * u * v + p2 * v**2 + u) + params.u0  # Eq. 75 as printed
    vv = fy * (k2 * v**5 + 2 * k2 * u**2 * v**3 + k2 * u**4 * v + k1 * u**2 * v**2 + k1 * v**3 + p1 * u**2
               + 2 * p2 * u * v + 3 * p1 * v**2 + v) + params.v0  # Eq. 76 as printed
    return np.stack([uu, vv], axis=-1)


# ----------------------------------------------------------------------------------------------------------------------
# the implicit inverse model (Eq. 77-86)
# ----------------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ImplicitInverse:
    """Heikkilä's implicit inverse model, Eq. 77-78, fitted by Eq. 81-86.

    Attributes
    ----------
    g : ndarray (8,)
        ``g1 .. g8`` (on normalised coordinates).
    as_printed : bool
        Fitted with the observation rows of Eq. 81-82 as printed (True) or corrected (False).
    rms_px, max_px : float
        Error of the model on its fitting grid in ideal pixels (``fx`` times the normalised error).
    """

    g: np.ndarray
    as_printed: bool
    rms_px: float
    max_px: float

    def apply(self, x_d) -> np.ndarray:
        """Approximate ideal normalised coordinates ``(..., 2)`` of distorted ones ``x_d (..., 2)`` (Eq. 77-78)."""
        x_d = check_vectors(x_d, "x_d", 2)
        g = self.g
        us, vs = x_d[..., 0], x_d[..., 1]
        r2 = us * us + vs * vs
        G = (g[4] * r2 + g[5] * us + g[6] * vs + g[7]) * r2 + 1.0  # Eq. 78
        u = us + us * (g[0] * r2 + g[1] * r2**2) + 2 * g[2] * us * vs + g[3] * (r2 + 2 * us * us)  # Eq. 77
        v = vs + vs * (g[0] * r2 + g[1] * r2**2) + g[2] * (r2 + 2 * vs * vs) + 2 * g[3] * us * vs
        return np.stack([u, v], axis=-1) / G[..., None]


def fit_implicit_inverse(camera: CameraModel, grid: int = 40, as_printed: bool = False) -> ImplicitInverse:
    """Fit the implicit inverse model (Eq. 77-86) to ``camera`` on a ``grid x grid`` lattice of ideal points.

    The ideal points ``(u^, v^)`` span the image (``K^-1`` of pixels, Eq. 87); the forward model (Eq. 75-76) gives
    their distorted ``(u*, v*)`` (Eq. 79-80 in normalised form); ``g`` is the least-squares solution of ``e = T g``
    (Eq. 83-85; Eq. 86 is read ``(T^T T)^-1 T^T e``, the printed ``T^-1`` being a misprint). With
    ``as_printed=True`` the rows of Eq. 81-82 are used as printed: first entry ``-u*^2 r^2`` and fifth ``u* r^4``;
    the derivation from Eq. 77-78 (multiply by ``G`` and collect) gives ``-u* r^2`` and ``u^ r^4`` (and likewise in
    ``V_i``), which is the default.
    """
    if grid < 3:
        raise ValueError(f"grid: expected >= 3 points per side, got {grid}")
    pu, pv = np.meshgrid(np.linspace(-0.5, camera.width - 0.5, grid), np.linspace(-0.5, camera.height - 0.5, grid))
    ideal = from_pixels(np.stack([pu.ravel(), pv.ravel()], axis=-1), camera.K)  # Eq. 87
    uh, vh = ideal[:, 0], ideal[:, 1]
    xd = distort(ideal, camera.dist)  # Eq. 75-76
    us, vs = xd[:, 0], xd[:, 1]
    r2 = us * us + vs * vs
    if as_printed:
        U = np.column_stack([-us**2 * r2, -us * r2**2, -2 * us * vs, -(r2 + 2 * us * us), us * r2**2, uh * us * r2,
                             uh * vs * r2, uh * r2])  # Eq. 81 as printed
        V = np.column_stack([-vs**2 * r2, -vs * r2**2, -(r2 + 2 * vs * vs), -2 * us * vs, vs * r2**2, vh * us * r2,
                             vh * vs * r2, vh * r2])  # Eq. 82 as printed
    else:
        U = np.column_stack([-us * r2, -us * r2**2, -2 * us * vs, -(r2 + 2 * us * us), uh * r2**2, uh * us * r2,
                             uh * vs * r2, uh * r2])  # Eq. 81 corrected
        V = np.column_stack([-vs * r2, -vs * r2**2, -(r2 + 2 * vs * vs), -2 * us * vs, vh * r2**2, vh * us * r2,
                             vh * vs * r2, vh * r2])  # Eq. 82 corrected
    T = np.empty((2 * len(us), 8))
    T[0::2], T[1::2] = U, V  # Eq. 83
    e = np.empty(2 * len(us))
    e[0::2], e[1::2] = us - uh, vs - vh  # Eq. 84
    scale = np.linalg.norm(T, axis=0)
    scale[scale == 0] = 1.0
    g = np.linalg.lstsq(T / scale, e, rcond=None)[0] / scale  # Eq. 85-86
    model = ImplicitInverse(g, as_printed, 0.0, 0.0)
    err = (model.apply(xd) - ideal) * [camera.fx, camera.fy]
    norm = np.linalg.norm(err, axis=1)
    return ImplicitInverse(g, as_printed, float(np.sqrt(np.mean(norm**2))), float(norm.max()))
