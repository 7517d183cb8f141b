"""A refractive camera: a lens behind a flat glass port, and its calibration from rig views in water.

A camera behind a flat port is not a single-viewpoint camera (:mod:`bench.camera.flatport`): its water rays do not
meet in one point, so a central model (Heikkilä, Eq. 74-76) calibrated in water describes it only near the range it
was calibrated at (``scenarios/flatport_study.yaml`` measures how far). Treibitz et al. (2012), Agrawal et al. (2012)
and Jordt et al. (2016) model the port physically instead; this module does the same with the thesis's lens model
(Eq. 46, 75-76, 50) inside the housing:

``p_cam --Snell at both glass surfaces (project_flatport)--> x_n (in-air ray) --distort (Eq. 75-76)--> --K--> uv``

* :class:`RefractiveCamera` - projection (:meth:`~RefractiveCamera.project`), the water ray of a pixel
  (:meth:`~RefractiveCamera.rays`), and the pixel's *central coordinates at a depth*
  (:meth:`~RefractiveCamera.central_coordinates`): the normalised coordinates ``(x / z, y / z)``, seen from the
  lens centre, of the point on the pixel's water ray at lens-frame depth ``z``. With a depth from a first
  triangulation they are the coordinates of a pinhole camera at the lens centre, so every central algorithm
  downstream (triangulation, PnP, absolute orientation) sees the port exactly; an error ``dz`` in the depth moves
  them by about ``c dz / z^2``, ``c`` the ray's offset from the lens centre (mm), i.e. ~1e-5 for 5 mm at 0.5 m.
* :func:`calibrate_refractive` - the lens (fx fy cx cy, k1 k2 p1 p2) and the port (lens-to-glass distance ``d0``,
  tilt about x and y) with every view's rig pose, by least squares on the reprojection error
  (``scipy.optimize.least_squares``, the Jacobian by differences with its sparsity), from the rig's corners seen
  in water. The glass's thickness and index and the water's index are the housing's and the site's specification
  (fixed). Optional priors: the lens from an air calibration, ``d0`` from the housing drawing. It starts from a
  central calibration of the same views (the paraxial equivalent: focal lengths over ``n_water / n_air``, the poses
  moved from the paraxial virtual centre to the lens).

Units: m, rad, px. Pure numpy / SciPy: nothing here reads the simulator.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.optimize
from scipy.spatial.transform import Rotation

from bench.camera.flatport import FlatPort, axis_crossing, check_port, project_flatport, trace_rays
from bench.camera.model import CameraModel, distort, to_pixels, unproject_pinhole
from bench.geometry.transforms import homogeneous

#: names of the lens parameters estimated by :func:`calibrate_refractive`, in order
LENS_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")
#: forward-difference steps of the Jacobian: lens (px, unitless), port (m, rad), pose (rad, m); the projection is
#: exact to ~1e-9 px, so each step moves the pixels by >= ~1e-5 px (relative accuracy <= 1e-4)
FD_STEP_LENS = np.array([1e-4, 1e-4, 1e-4, 1e-4, 1e-7, 1e-7, 1e-8, 1e-8])
FD_STEP_PORT = np.array([1e-6, 1e-6, 1e-6])
FD_STEP_POSE = np.array([1e-7, 1e-7, 1e-7, 1e-7, 1e-7, 1e-7])
#: the lens-to-glass distance a calibration may reach (m) and the largest port tilt (rad): bounds of the solver
D0_RANGE_M = (1e-4, 0.5)
TILT_MAX = 0.7
#: solves at most to settle the pixels' sigma against the priors, and the smallest sigma they weigh with (px: exact
#: data's residuals are rounding errors)
PIXEL_SIGMA_ROUNDS = 4
SIGMA_FLOOR_PX = 1e-3
#: names of the port parameters estimated by :func:`calibrate_refractive`, in order (m, rad, rad)
PORT_NAMES = ("d0", "tilt_x", "tilt_y")


def paraxial_centre(port: FlatPort) -> np.ndarray:
    """The port's paraxial virtual centre (3,) in the lens frame (m): where near-axial water rays seem to start
    (the centre a central calibration in water finds, about ``(d0 + t) - (d0 + t n_air / n_glass) n_water / n_air``
    along the port normal)."""
    port = check_port(port)
    n = port.normal
    perp = np.cross(n, [0.0, 1.0, 0.0])
    d = n + 1e-4 * perp / np.linalg.norm(perp)
    return n * float(axis_crossing(d, port))


@dataclass(frozen=True)
class RefractiveCamera:
    """A lens (its intrinsics and distortion in air) behind a flat port.

    Attributes
    ----------
    lens : CameraModel
        The camera inside the housing (Eq. 46, 75-76, 50), as an air calibration gives it.
    port : FlatPort
        The port in the lens frame (:class:`bench.camera.flatport.FlatPort`).
    working_range_m : float
        The depth (m, lens frame) at which :meth:`normalised` places a pixel when no depth is known: e.g. the
        calibration views' median depth. A wrong value moves the coordinates by ~``c dz / z^2`` (module docstring).
    name : str
    """

    lens: CameraModel
    port: FlatPort
    working_range_m: float = 1.0
    name: str = "refractive camera"

    def __post_init__(self):
        if not isinstance(self.lens, CameraModel):
            raise ValueError(f"lens: expected a CameraModel, got {type(self.lens).__name__}")
        check_port(self.port)
        z = self.working_range_m
        if isinstance(z, bool) or not isinstance(z, (int, float, np.integer, np.floating)) or not (
                np.isfinite(z) and z > self.port.d0 + self.port.t):
            raise ValueError(f"working_range_m: expected a depth beyond the port (> {self.port.d0 + self.port.t:g} "
                             f"m), got {z!r}")
        object.__setattr__(self, "working_range_m", float(z))

    @property
    def size(self) -> tuple[int, int]:
        return self.lens.size

    @property
    def width(self) -> int:
        return self.lens.width

    @property
    def height(self) -> int:
        return self.lens.height

    @property
    def fx(self) -> float:
        """The paraxial focal length in water (px): the lens's times ``n_water / n_air`` - the scale between an
        angle in water and a pixel, for thresholds given in pixels."""
        return self.lens.fx * self.port.n_water / self.port.n_air

    def normalised(self, uv, depth=None) -> np.ndarray:
        """Pinhole coordinates ``(..., 2)`` from the lens centre of the pixels ``uv`` at ``depth`` (m, broadcast;
        default :attr:`working_range_m`): :meth:`central_coordinates`, the central algorithms' input."""
        return self.central_coordinates(uv, self.working_range_m if depth is None else depth)

    def virtual_camera(self) -> CameraModel:
        """The distortion-free pinhole at the lens centre with the paraxial focal lengths: ``K_v (x_n, 1)`` of
        :meth:`normalised` coordinates are pixels of about the real pixels' scale (for estimators that work in
        pixels, e.g. the joint bundle)."""
        return self.paraxial_camera()[0].replace(dist=np.zeros(5), model=None, name=f"{self.name} (virtual pinhole)")

    def project(self, p_cam) -> np.ndarray:
        """Pixels ``(..., 2)`` of lens-frame points ``p_cam (..., 3)`` (m) in water; NaN where a point cannot be
        imaged (inside the housing, behind the port)."""
        x_n = project_flatport(np.asarray(p_cam, dtype=float), self.port)
        return to_pixels(distort(x_n, self.lens.dist), self.lens.K)

    def rays(self, uv):
        """The water rays of pixels ``uv (..., 2)``: ``(origin (..., 3), direction (..., 3), ok (...))``, the origin
        on the outer glass surface (m, lens frame), the unit direction in water; NaN and ``ok`` False where the
        lens cannot be inverted or the ray misses the port."""
        uv = np.asarray(uv, dtype=float)
        bad = ~np.all(np.isfinite(uv), axis=-1)
        x = self.lens.undistort_pixels(np.where(bad[..., None], self.lens.K[:2, 2], uv))
        bad |= ~np.all(np.isfinite(x), axis=-1)  # where the lens's inverse does not converge
        d = unproject_pinhole(np.where(bad[..., None], 0.0, x))
        o, w, ok = trace_rays(d, self.port)
        ok = ok & ~bad
        return np.where(ok[..., None], o, np.nan), np.where(ok[..., None], w, np.nan), ok

    def central_coordinates(self, uv, depth) -> np.ndarray:
        """``(x / z, y / z)`` ``(..., 2)`` of the point on each pixel's water ray at lens-frame depth ``depth``
        (m, broadcast against ``uv``'s leading shape): the pixel as a pinhole camera at the lens centre would see
        a point at that depth (see the module docstring). NaN where the ray is invalid or does not reach the depth."""
        o, w, ok = self.rays(uv)
        z = np.broadcast_to(np.asarray(depth, dtype=float), o.shape[:-1])
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = (z - o[..., 2]) / w[..., 2]
            p = o + lam[..., None] * w
            x = p[..., :2] / p[..., 2:3]
        good = ok & np.isfinite(lam) & (lam > 0)
        return np.where(good[..., None], x, np.nan)

    def paraxial_camera(self) -> tuple[CameraModel, np.ndarray]:
        """``(central CameraModel, centre (3,))``: the central camera paraxially equivalent to lens + port - the
        lens's focal lengths (and skew) times ``n_water / n_air``, its principal point and distortion - and its
        centre in the lens frame (:func:`paraxial_centre`)."""
        K = self.lens.K.copy()
        K[:2, :2] *= self.port.n_water / self.port.n_air
        return self.lens.replace(K=K, name=f"{self.lens.name} (paraxial)"), paraxial_centre(self.port)


# ------------------------------------------------------------------------------------------------ calibration


@dataclass(frozen=True)
class RefractiveCalibration:
    """Outcome of :func:`calibrate_refractive`.

    Attributes
    ----------
    success : bool
        ``least_squares`` stopped on one of its tolerances (status > 0) and every residual is finite.
    message : str
    camera : RefractiveCamera
    T_cam_target : ndarray (V, 4, 4)
        Each view's target pose in the lens frame (m).
    rms_px : float
        Reprojection RMS over all points (px).
    sigma_px : float
        Residual standard deviation per image coordinate (px): ``sqrt(2 cost / (2N - p))``.
    parameter_names : tuple of str
        The estimated lens and port parameters (:data:`LENS_NAMES`, :data:`PORT_NAMES`; those held fixed left out).
    parameters : ndarray (p,)
    covariance : ndarray (p, p)
        ``sigma^2 (J^T J)^-1`` of those parameters, the views' poses marginalised (px^2, unitless, m^2, rad^2).
    iterations : int
        Function evaluations of ``least_squares``.
    cost : float
        Half the sum of squared reprojection residuals (px^2), priors excluded.
    """

    success: bool
    message: str
    camera: RefractiveCamera
    T_cam_target: np.ndarray
    rms_px: float
    sigma_px: float
    parameter_names: tuple
    parameters: np.ndarray
    covariance: np.ndarray
    iterations: int
    cost: float

    def std(self, name: str) -> float:
        """Standard deviation of one estimated parameter (its unit)."""
        i = self.parameter_names.index(name)
        return float(np.sqrt(self.covariance[i, i]))


def _poses_to_vector(T):
    T = np.asarray(T, dtype=float)
    return np.concatenate([Rotation.from_matrix(T[:, :3, :3]).as_rotvec(), T[:, :3, 3]], axis=1).ravel()


def _vector_to_poses(v):
    v = v.reshape(-1, 6)
    return homogeneous(Rotation.from_rotvec(v[:, :3]).as_matrix(), v[:, 3:])


def virtual_scale(port: FlatPort) -> np.ndarray:
    """``(8,)``: how :data:`LENS_NAMES` (fx fy cx cy k1 k2 p1 p2) scale into the virtual pinhole's equivalents,
    paraxially, ``m = n_water / n_air``: ``m, m, 1, 1, m^2, m^4, m, m`` (the lens's distortion acts on in-air
    coordinates, ``m`` times the water ones: ``k1 r_a^2 = k1 m^2 r_w^2`` etc.) - the terms a refractive camera's lab
    priors are written in."""
    m = port.n_water / port.n_air
    return np.array([m, m, 1.0, 1.0, m**2, m**4, m, m])


def lens_parameters(lens: CameraModel) -> np.ndarray:
    """The lens's :data:`LENS_NAMES` values (8,): ``fx fy cx cy`` (px), ``k1 k2 p1 p2``."""
    return np.array([lens.fx, lens.fy, lens.cx, lens.cy, *lens.dist[:4]])


def with_lens_parameters(template: CameraModel, theta) -> CameraModel:
    """``template`` with :data:`LENS_NAMES` = ``theta`` (8,); its skew and k3 kept."""
    fx, fy, cx, cy, k1, k2, p1, p2 = theta
    K = np.array([[fx, template.skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return template.replace(K=K, dist=np.array([k1, k2, p1, p2, template.dist[4]]), model=None)


def _port_of(theta, template: FlatPort) -> FlatPort:
    return FlatPort(d0=float(theta[0]), t=template.t, n_air=template.n_air, n_glass=template.n_glass,
                    n_water=template.n_water, tilt=np.array(theta[1:3]), decentre=np.zeros(2),
                    source=template.source)


def _check_views(object_points, image_points):
    if len(object_points) != len(image_points) or len(object_points) < 2:
        raise ValueError(f"views: expected >= 2 views with object and image points each, got "
                         f"{len(object_points)} and {len(image_points)}")
    Xs, uvs = [], []
    for k, (X, uv) in enumerate(zip(object_points, image_points, strict=True)):
        X, uv = np.asarray(X, dtype=float), np.asarray(uv, dtype=float)
        if X.ndim != 2 or X.shape[1] != 3 or uv.shape != (len(X), 2) or len(X) < 6:
            raise ValueError(f"view {k + 1}: expected (N, 3) object and (N, 2) image points, N >= 6, got "
                             f"{X.shape} and {uv.shape}")
        if not (np.all(np.isfinite(X)) and np.all(np.isfinite(uv))):
            raise ValueError(f"view {k + 1}: contains NaN or inf")
        Xs.append(X)
        uvs.append(uv)
    return Xs, uvs


def calibrate_refractive(object_points, image_points, lens0: CameraModel, port0: FlatPort, T_cam_target0, *,
                         lens_prior=None, d0_sigma_m: float | None = None, tilt_sigma_rad: float | None = None,
                         fix_lens: bool = False, fix_tilt: bool = False, fix_port: bool = False,
                         pixel_sigma_px: float | None = None, max_nfev: int = 200) -> RefractiveCalibration:
    """Calibrate a lens behind a flat port from views of a known target in water (see the module docstring).

    Parameters
    ----------
    object_points : sequence of V ndarray (N_k, 3)
        The target's points in its frame (m).
    image_points : sequence of V ndarray (N_k, 2)
        Their detected pixels (px).
    lens0 : CameraModel
        The lens's start (or, with ``fix_lens``, its value): e.g. :meth:`RefractiveCamera.paraxial_camera`'s inverse
        of a central calibration, or an air calibration. Its skew and k3 are held fixed.
    port0 : FlatPort
        The port's start and its fixed part: thickness ``t`` and the indices (the housing's specification and the
        water's); ``d0`` and the tilt are estimated, the decentre is absorbed into ``d0`` (only the port plane's
        distance along its normal matters).
    T_cam_target0 : ndarray (V, 4, 4)
        The views' start poses in the lens frame (m).
    lens_prior : tuple (mean (8,), covariance (8, 8)), optional
        A prior on :data:`LENS_NAMES` (px, unitless), e.g. from a calibration of the lens in air.
    d0_sigma_m : float, optional
        A prior on ``d0`` around ``port0``'s (its plane's distance along its normal over the normal's z: a decentre
        absorbed) with this standard deviation (m), e.g. the housing drawing's tolerance.
    tilt_sigma_rad : float, optional
        A prior on each tilt angle around ``port0.tilt`` (rad), e.g. how square the housing holds the lens.
    fix_lens, fix_tilt, fix_port : bool
        Hold the lens (at ``lens0``), the tilt or the whole port (at ``port0``'s) fixed: e.g. the port in air, where
        a slab's distance from the lens does not matter.
    pixel_sigma_px : float, optional
        The pixels' noise (px), which weighs them against the priors; default: estimated from the residuals (a
        solve at 1 px, then again at the residuals' sigma until it changes by < 5 %, at most
        :data:`PIXEL_SIGMA_ROUNDS` solves).
    max_nfev : int
        Evaluation budget of ``least_squares`` (per solve).

    Returns
    -------
    RefractiveCalibration
        ``success`` False (with the reason) when the solver did not converge; never raises on non-convergence.
    """
    Xs, uvs = _check_views(object_points, image_points)
    port0 = check_port(port0)
    T0 = np.asarray(T_cam_target0, dtype=float)
    if T0.shape != (len(Xs), 4, 4) or not np.all(np.isfinite(T0)):
        raise ValueError(f"T_cam_target0: expected ({len(Xs)}, 4, 4) finite poses, got {T0.shape}")
    if d0_sigma_m is not None and not (np.isfinite(d0_sigma_m) and d0_sigma_m > 0):
        raise ValueError(f"d0_sigma_m: expected a standard deviation > 0 m, got {d0_sigma_m!r}")
    if tilt_sigma_rad is not None and not (np.isfinite(tilt_sigma_rad) and tilt_sigma_rad > 0):
        raise ValueError(f"tilt_sigma_rad: expected a standard deviation > 0 rad, got {tilt_sigma_rad!r}")
    lens_theta0 = lens_parameters(lens0)
    L_prior = None
    if lens_prior is not None:
        mean, cov = (np.asarray(a, dtype=float) for a in lens_prior)
        if mean.shape != (8,) or cov.shape != (8, 8) or not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
            raise ValueError(f"lens_prior: expected a mean (8,) and a covariance (8, 8), got {mean.shape}, "
                             f"{cov.shape}")
        try:
            L_prior = (mean, np.linalg.cholesky(np.linalg.inv(cov)).T)  # whitening: L^T L = cov^-1
        except np.linalg.LinAlgError:
            raise ValueError("lens_prior: the covariance is not positive definite") from None
    free_lens = not fix_lens
    if fix_lens and fix_port:
        raise ValueError("fix_lens, fix_port: nothing left to calibrate")
    if fix_lens and lens_prior is not None:
        raise ValueError("lens_prior: given with fix_lens (a held lens takes no prior)")
    if pixel_sigma_px is not None and not (np.isfinite(pixel_sigma_px) and pixel_sigma_px > 0):
        raise ValueError(f"pixel_sigma_px: expected a standard deviation > 0 px, got {pixel_sigma_px!r}")
    port_free = np.array([not fix_port, not (fix_tilt or fix_port), not (fix_tilt or fix_port)])
    d0_start = port0.axial_d0  # the same port plane with the decentre absorbed
    port_theta0 = np.array([d0_start, *port0.tilt])
    n_lens = 8 if free_lens else 0
    n_port = int(port_free.sum())
    counts = np.array([len(x) for x in Xs])
    view_of = np.repeat(np.arange(len(Xs)), counts)
    X_all, uv_all = np.vstack(Xs), np.vstack(uvs).ravel()
    x0 = np.concatenate([lens_theta0 if free_lens else [], port_theta0[port_free], _poses_to_vector(T0)])
    n_pix = uv_all.size

    def unpack(x):
        lens_t = x[:n_lens] if free_lens else lens_theta0
        port_t = port_theta0.copy()
        port_t[port_free] = x[n_lens:n_lens + n_port]
        return lens_t, port_t, x[n_lens + n_port:]

    def residuals(x):
        lens_t, port_t, poses = unpack(x)
        v = poses.reshape(-1, 6)
        R = Rotation.from_rotvec(v[view_of, :3]).as_matrix()
        p = np.einsum("nij,nj->ni", R, X_all) + v[view_of, 3:]
        x_n = project_flatport(p, _port_of(port_t, port0))
        lens = with_lens_parameters(lens0, lens_t)
        r = to_pixels(distort(x_n, lens.dist), lens.K).ravel() - uv_all
        r = np.where(np.isfinite(r), r, 1e6) / scale[0]  # unimageable: a large, finite penalty; whitened (sigma)
        extra = []
        if L_prior is not None and free_lens:
            extra.append(L_prior[1] @ (lens_t - L_prior[0]))
        if d0_sigma_m is not None and port_free[0]:
            extra.append(np.array([(port_t[0] - d0_start) / d0_sigma_m]))
        if tilt_sigma_rad is not None and port_free[1]:
            extra.append((port_t[1:] - port_theta0[1:]) / tilt_sigma_rad)
        return np.concatenate([r, *extra]) if extra else r

    n_glob = n_lens + n_port
    n_views = len(Xs)
    step = np.concatenate([FD_STEP_LENS if free_lens else [], FD_STEP_PORT[port_free], np.tile(FD_STEP_POSE, n_views)])

    def jacobian(x):
        """Forward differences, grouped: each lens and port parameter alone, each pose coordinate of every view at
        once (the views share no residual). Dense, for the trust region's exact solver."""
        r0 = residuals(x)
        J = np.zeros((r0.size, x.size))
        cols = [[j] for j in range(n_glob)] + [[n_glob + 6 * k + c for k in range(n_views)] for c in range(6)]
        owner = np.full(x.size, -1)
        owner[n_glob:] = np.repeat(np.arange(n_views), 6)
        row_view = np.concatenate([np.repeat(view_of, 2), np.full(r0.size - n_pix, -1)])
        for group in cols:
            h = step[group]
            xp = x.copy()
            xp[group] += h
            dr = residuals(xp) - r0
            if len(group) == 1 and group[0] < n_glob:
                J[:, group[0]] = dr / h[0]
            else:
                for j, hj in zip(group, h, strict=True):
                    rows = row_view == owner[j]
                    J[rows, j] = dr[rows] / hj
        return J

    lo, hi = np.full(x0.size, -np.inf), np.full(x0.size, np.inf)  # the port in front of the lens, tilt < 45 deg
    port_lo, port_hi = np.array([D0_RANGE_M[0], -TILT_MAX, -TILT_MAX]), np.array([D0_RANGE_M[1], TILT_MAX, TILT_MAX])
    lo[n_lens:n_glob], hi[n_lens:n_glob] = port_lo[port_free], port_hi[port_free]
    x0[n_lens:n_glob] = np.clip(x0[n_lens:n_glob], lo[n_lens:n_glob] + 1e-9, hi[n_lens:n_glob] - 1e-9)
    # the pixels weigh against the (whitened) priors with their noise: a first solve at 1 px (or the given sigma),
    # then again at the residuals' own sigma until it settles (without priors the weight does not matter)
    dof = max(n_pix - x0.size, 1)
    priors = (L_prior is not None and free_lens) or (d0_sigma_m is not None and port_free[0]) or (
        tilt_sigma_rad is not None and port_free[1])
    scale = [pixel_sigma_px if pixel_sigma_px is not None else 1.0]
    nfev = 0
    for _ in range(PIXEL_SIGMA_ROUNDS if priors and pixel_sigma_px is None else 1):
        sol = scipy.optimize.least_squares(residuals, x0, jac=jacobian, bounds=(lo, hi), method="trf",
                                           tr_solver="exact", x_scale="jac", xtol=1e-10, ftol=1e-10, gtol=1e-8,
                                           max_nfev=max_nfev)
        nfev += sol.nfev
        r_px = sol.fun[:n_pix] * scale[0]
        sigma_hat = max(float(np.sqrt((r_px @ r_px) / dof)), SIGMA_FLOOR_PX)
        if not (priors and pixel_sigma_px is None) or abs(sigma_hat / scale[0] - 1) < 0.05 or sol.status <= 0:
            break
        scale[0], x0 = sigma_hat, sol.x
    lens_t, port_t, poses = unpack(sol.x)
    r = sol.fun[:n_pix] * scale[0]
    finite = bool(np.all(np.abs(r) < 1e5))
    cam = RefractiveCamera(with_lens_parameters(lens0, lens_t), _port_of(port_t, port0))
    cost = 0.5 * float(r @ r)
    sigma = float(np.sqrt(2 * cost / dof))
    J = np.asarray(sol.jac)
    names = (LENS_NAMES if free_lens else ()) + tuple(n for n, f in zip(PORT_NAMES, port_free, strict=True) if f)
    try:
        # the pixel rows (whitened by the sigma they were solved with) weigh with the residuals' sigma, the priors
        # are whitened already
        W = np.ones(J.shape[0])
        W[:n_pix] = (scale[0] / max(sigma, SIGMA_FLOOR_PX)) ** 2
        cov = np.linalg.pinv((J.T * W) @ J, rcond=1e-15, hermitian=True)[:n_glob, :n_glob]
        cov = 0.5 * (cov + cov.T)
    except np.linalg.LinAlgError:
        cov = np.full((n_glob, n_glob), np.nan)
    success = sol.status > 0 and finite
    msg = sol.message if success else (f"least_squares stopped (status {sol.status}): {sol.message}" if finite else
                                       "some rig points cannot be imaged through the fitted port")
    return RefractiveCalibration(success, msg, cam, _vector_to_poses(poses), float(np.sqrt(np.mean(np.sum(
        r.reshape(-1, 2) ** 2, axis=1)))), sigma, names, sol.x[:n_glob].copy(), cov, int(nfev), cost)


def refractive_start(central: CameraModel, T_central_target, port_nominal: FlatPort):
    """``(lens0, T_lens_target0)``: the start of :func:`calibrate_refractive` from a central calibration in water.

    The lens's focal lengths (and skew) are the central camera's over ``n_water / n_air`` (the port's paraxial
    magnification), its principal point and k1 k2 p1 p2 the central camera's, its k3 zero (a central fit's k3 is
    mostly the port's high orders, and :func:`calibrate_refractive` holds k3); the target poses move from the central
    camera's centre - the paraxial virtual centre of ``port_nominal`` - to the lens centre.
    """
    port = check_port(port_nominal)
    K = central.K.copy()
    K[:2, :2] /= port.n_water / port.n_air
    c = paraxial_centre(port)
    T = np.asarray(T_central_target, dtype=float)
    dist = np.r_[central.dist[:4], 0.0]
    return central.replace(K=K, dist=dist, model=None, name=f"{central.name} (lens)"), homogeneous(np.eye(3), c) @ T
