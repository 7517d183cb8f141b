"""The robot base frame in laser-tracker coordinates from two probe arcs (thesis section 2.9, Eq. 28-45, 107-117).

Procedure (§2.9): a probe on the arm is measured by the tracker while joint 1 alone moves (arc 1) and while joint 2
alone moves (arc 2). Each arc's circle (:func:`bench.geometry.fits.fit_circle_3d`) gives that joint's rotation axis:
the line through the circle's centre along the circle's normal. Then

* **z0** is the joint-1 axis, oriented by the sense of rotation: increasing joint reading is counter-clockwise about
  +z (the DH ``Rz(theta)``). The sense is read from the arc itself: the points' angles on the fitted circle are
  regressed on the joint readings; the slope must be +-1 (else the arc is too short or too noisy to be trusted) and
  its sign orients the normal. z1 (joint 2) likewise from arc 2.
* **the origin** is "the coordinate on the rotation axis of joint 1 with the closest relative distance to the
  rotation axis of joint 2" (§2.9), found with the closest points between the two axes (Eq. 107-117), moved by
  ``-d1 z0`` for a DH chain with ``d1 != 0`` (in standard DH the foot of the common normal on z0 is ``O0 + d1 z0``;
  the TA-40 has ``d1 = 0``, so this is the thesis's definition exactly).
* **x0**: in standard DH, ``x1`` is the common normal of z0 and z1 and ``z1 = cos(alpha1) z0 - sin(alpha1) (z0 x x1)``,
  so ``x1 = (z0 x z1) / sin(alpha1)`` (normalised). For ``a1 > 0`` (TA-40: a1 = 115 mm, alpha1 = 90 deg) this is the
  common normal pointing from the joint-1 axis towards the joint-2 axis; the formula also holds for ``a1 = 0``.
  Frame 1 is frame 0 turned by ``theta1 = q1 + theta_offset1`` about z0, so ``x0 = Rot(z0, -theta1) x1`` with the
  joint-1 reading ``q1_during_arc2`` at which arc 2 was taken. ``y0 = z0 x x0``.

Assumptions: joints 1 and 2 are revolute and not parallel (``sin(alpha1) != 0``); the probe is off both axes; the
readings are the encoder values of the DH model (``theta = q + theta_offset``). The measured ``a1`` and ``alpha1``
(distance and angle between the fitted axes) are reported as a check of the model.

What the arcs define on an arm with errors (``T = E0 A1 E1 ...``, Eq. 10): the arcs see the *actual* joint axes.
With no errors in frames 0 and 1 the result is the nominal base exactly. A perturbed ``E0`` moves the joint-1 axis and
the whole construction with it: the arcs return ``T_tracker_base E0`` - the actual frame 0 - exactly, so the base
errors are absorbed into the measured base. Of ``E1`` (exact form ``Trans(x,y,z) Rz(r) Ry(s) Rx(p)``) only what moves
the joint-2 axis relative to frame 0 matters: for the TA-40 (alpha1 = 90 deg, y1 is parallel to z0) ``y1`` shifts the
origin along z0 by ``y1`` and ``s1`` turns x0 about z0 by ``s1`` (result ``T_tracker_base Tz(y1) Rz(s1)``), while
``x1``, ``z1``, ``r1`` and ``p1`` change only the measured a1/alpha1, not the frame - the same pairs that the
identifiability analysis merges (z0 into y1, r0 into s1, Eq. 21). Tested in ``tests/robot/test_base_from_arcs.py``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from bench.geometry.fits import Circle3D, check_points, fit_circle_3d, plane_rotation
from bench.geometry.lines import PARALLEL_TOL, Line, closest_points_between_lines
from bench.geometry.transforms import check_transform, homogeneous, transform_points
from bench.robot.kinematics import ee_position, link_frames
from bench.robot.model import Robot

_NAN_T = np.full((4, 4), np.nan)


@dataclass(frozen=True)
class BaseFrameResult:
    """Output of :func:`base_frame_from_arcs`.

    Attributes
    ----------
    success : bool
    message : str
        "ok" or the reason of failure.
    T_tracker_base : ndarray (4, 4)
        Base frame O0 in tracker coordinates (NaN if not successful).
    axis1, axis2 : Line or None
        Joint-1 and joint-2 rotation axes in tracker coordinates (point = circle centre, direction = +z0 / +z1).
    circle1, circle2 : Circle3D or None
        The fitted arcs.
    residual_rms_m : float
        RMS 3D distance of all arc points to their fitted circles (m).
    a1_measured_m : float
        Signed distance from the joint-1 axis to the joint-2 axis along x1 (m); compare with the model's a1.
    alpha1_measured_rad : float
        Angle from z0 to z1 about x1 (rad); compare with the model's alpha1.
    span1_rad, span2_rad : float
        Ranges of the joint readings along the arcs.
    """

    success: bool
    message: str
    T_tracker_base: np.ndarray = field(default_factory=lambda: _NAN_T.copy())
    axis1: Line | None = None
    axis2: Line | None = None
    circle1: Circle3D | None = None
    circle2: Circle3D | None = None
    residual_rms_m: float = float("nan")
    a1_measured_m: float = float("nan")
    alpha1_measured_rad: float = float("nan")
    span1_rad: float = float("nan")
    span2_rad: float = float("nan")


@dataclass(frozen=True)
class BaseFrameAccuracy:
    """Predicted accuracy of :func:`base_frame_from_arcs` (see :func:`base_frame_accuracy`).

    Attributes
    ----------
    covariance : ndarray (6, 6)
        Covariance of :func:`pose_deviation` ``[dt (m), dphi (rad)]``, both in tracker coordinates.
    pos_std_m : float
        ``sqrt(trace)`` of the position block: the predicted RMS of the 3D origin error (m).
    rot_std_rad : float
        ``sqrt(trace)`` of the rotation block: the predicted RMS rotation-error angle (rad).
    method : str
        ``"linear"`` or ``"monte_carlo"``.
    n_samples, n_failed : int
        Monte Carlo draws used and failed (0 for ``"linear"``).
    """

    covariance: np.ndarray
    pos_std_m: float
    rot_std_rad: float
    method: str
    n_samples: int = 0
    n_failed: int = 0


@dataclass(frozen=True)
class ArcMeasurements:
    """Tracker arcs and the joint readings at which they were measured (see :func:`simulate_arcs`).

    Attributes
    ----------
    arc1_tracker : ndarray (N1, 3)
        Probe points (tracker frame, m) while joint 1 moves alone.
    q1_arc1 : ndarray (N1,)
        Joint-1 readings along arc 1 (rad).
    arc2_tracker : ndarray (N2, 3)
        Probe points while joint 2 moves alone.
    q2_arc2 : ndarray (N2,)
        Joint-2 readings along arc 2 (rad).
    q1_during_arc2 : float
        Joint-1 reading (rad) held while arc 2 was measured.
    """

    arc1_tracker: np.ndarray
    q1_arc1: np.ndarray
    arc2_tracker: np.ndarray
    q2_arc2: np.ndarray
    q1_during_arc2: float


def _check_readings(q, n, name):
    try:
        q = np.asarray(q, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected numeric joint readings (rad)") from None
    if q.shape != (n,):
        raise ValueError(f"{name}: expected shape ({n},) (one reading per arc point), got {q.shape}")
    if not np.all(np.isfinite(q)):
        raise ValueError(f"{name}: contains NaN or inf")
    if np.any(np.abs(q) > 4 * np.pi):
        raise ValueError(f"{name}: |angle| > 4*pi rad; were degrees given where radians are expected?")
    return q


def _check_scalar_angle(v, name):
    try:
        v = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected one joint reading (rad)") from None
    if not np.isfinite(v):
        raise ValueError(f"{name}: must be finite")
    if abs(v) > 4 * np.pi:
        raise ValueError(f"{name}: |angle| > 4*pi rad; were degrees given where radians are expected?")
    return v


def _check_robot(robot):
    if not isinstance(robot, Robot) or robot.n < 2:
        raise ValueError("robot: expected a bench.robot.model.Robot with at least two joints")
    if abs(np.sin(robot.alpha[0])) < 1e-6:
        raise ValueError("robot: alpha1 = 0 or 180 deg: joint axes 1 and 2 are parallel; no base from arcs")
    return robot


def _oriented_axis(points, q, circle: Circle3D, max_slope_error):
    """Normal of ``circle`` signed by the rotation sense (Eq. 32-35 frame); returns (direction, slope)."""
    R_p = plane_rotation(circle.normal)
    local = (points - circle.center) @ R_p
    order = np.argsort(q, kind="stable")
    phi = np.unwrap(np.arctan2(local[order, 1], local[order, 0]))  # angles about +normal, in reading order
    qs = q[order]
    dq = qs - qs.mean()
    slope = float(dq @ (phi - phi.mean()) / (dq @ dq))
    if abs(abs(slope) - 1.0) > max_slope_error:
        return None, slope
    return circle.normal * np.sign(slope), slope


@dataclass(frozen=True)
class AxesFrame:
    """Output of :func:`base_frame_from_axes`."""

    T_tracker_base: np.ndarray
    a1_measured_m: float
    alpha1_measured_rad: float
    parallel: bool


def base_frame_from_axes(axis1: Line, axis2: Line, q1_during_arc2: float, robot: Robot,
                         parallel_tol: float = PARALLEL_TOL) -> AxesFrame:
    """Base frame from the oriented joint-1 and joint-2 axes (the construction of the module docstring).

    Parameters
    ----------
    axis1, axis2 : Line
        Joint axes (tracker frame, m); directions are +z0 and +z1 (any length).
    q1_during_arc2 : float
        Joint-1 reading (rad) at which ``axis2`` was observed.
    robot : Robot
        Supplies the DH ``d1``, ``alpha1`` and ``theta_offset1``.
    parallel_tol : float
        See :func:`bench.geometry.lines.closest_points_between_lines`.

    Returns
    -------
    AxesFrame
        ``T_tracker_base`` is NaN and ``parallel`` True if the axes are parallel.
    """
    robot = _check_robot(robot)
    z0, z1 = (np.asarray(axis.direction, dtype=float) for axis in (axis1, axis2))
    z0, z1 = z0 / np.linalg.norm(z0), z1 / np.linalg.norm(z1)
    cp = closest_points_between_lines(axis1.point, z0, axis2.point, z1, parallel_tol)  # Eq. 107-117
    if cp.parallel:
        return AxesFrame(_NAN_T.copy(), float(cp.distance), 0.0, True)
    n = np.cross(z0, z1)
    x1 = n / np.linalg.norm(n) * np.sign(np.sin(robot.alpha[0]))  # x1 = (z0 x z1) / sin(alpha1)
    a1 = float((cp.p2 - cp.p1) @ x1)  # DH a1: from z0 to z1 along x1
    alpha1 = float(np.arctan2(-(z1 @ np.cross(z0, x1)), z1 @ z0))  # z1 = cos(a) z0 - sin(a) (z0 x x1)
    theta1 = q1_during_arc2 + robot.theta_offset[0]
    x0 = np.cos(theta1) * x1 - np.sin(theta1) * np.cross(z0, x1)  # Rot(z0, -theta1) x1, x1 _|_ z0
    x0 /= np.linalg.norm(x0)
    y0 = np.cross(z0, x0)
    origin = cp.p1 - robot.d[0] * z0  # foot of the common normal on z0 is O0 + d1 z0
    return AxesFrame(homogeneous(np.column_stack([x0, y0, z0]), origin), a1, alpha1, False)


def base_frame_from_arcs(arc1_tracker, arc2_tracker, q1_during_arc2, q1_arc1, q2_arc2, robot: Robot, *,
                         min_span_deg: float = 2.0, max_slope_error: float = 0.1,
                         parallel_tol: float = PARALLEL_TOL) -> BaseFrameResult:
    """Robot base frame in tracker coordinates from the joint-1 and joint-2 arcs (§2.9).

    Parameters
    ----------
    arc1_tracker : array_like (N1, 3)
        Probe positions (tracker frame, m) measured while joint 1 alone moves; N1 >= 3.
    arc2_tracker : array_like (N2, 3)
        Probe positions while joint 2 alone moves; N2 >= 3.
    q1_during_arc2 : float
        Joint-1 reading (rad) held during arc 2.
    q1_arc1 : array_like (N1,)
        Joint-1 readings (rad) at the points of arc 1 (any order).
    q2_arc2 : array_like (N2,)
        Joint-2 readings (rad) at the points of arc 2.
    robot : Robot
        Nominal model: ``d1``, ``alpha1``, ``theta_offset1`` are used.
    min_span_deg : float
        Arcs whose readings span less are rejected (the centre of a short arc is ill-determined).
    max_slope_error : float
        Tolerance on ``|d(angle on circle)/d(reading)| = 1``: larger deviations mean the fitted circle does not
        follow the joint (arc too short or too noisy for its radius) and the result is rejected.
    parallel_tol : float
        See :func:`bench.geometry.lines.closest_points_between_lines`.

    Returns
    -------
    BaseFrameResult
        ``success=False`` with the reason for degenerate measurements (collinear or coincident points, too short
        an arc, angles not following the readings, parallel axes). Malformed input (shapes, NaN, readings in
        degrees) raises a one-line ``ValueError`` naming the argument.
    """
    robot = _check_robot(robot)
    arc1 = check_points(arc1_tracker, "arc1_tracker")
    arc2 = check_points(arc2_tracker, "arc2_tracker")
    q1 = _check_readings(q1_arc1, len(arc1), "q1_arc1")
    q2 = _check_readings(q2_arc2, len(arc2), "q2_arc2")
    q1_hold = _check_scalar_angle(q1_during_arc2, "q1_during_arc2")
    span1, span2 = float(np.ptp(q1)), float(np.ptp(q2))
    spans = {"span1_rad": span1, "span2_rad": span2}
    for name, span in (("q1_arc1", span1), ("q2_arc2", span2)):
        if span < np.deg2rad(min_span_deg):
            return BaseFrameResult(False, f"{name}: the arc spans {np.rad2deg(span):.3g} deg < min_span_deg = "
                                          f"{min_span_deg:g} deg", **spans)
    circles, axes = [], []
    for name, qname, pts, q in (("arc1_tracker", "q1_arc1", arc1, q1), ("arc2_tracker", "q2_arc2", arc2, q2)):
        try:
            circle = fit_circle_3d(pts, name)  # Eq. 28-45
        except ValueError as exc:
            return BaseFrameResult(False, str(exc), **spans)
        direction, slope = _oriented_axis(pts, q, circle, max_slope_error)
        if direction is None:
            return BaseFrameResult(False, f"{name}: angles on the fitted circle do not follow {qname} (slope "
                                          f"{slope:.3g}, expected +-1): arc too short or too noisy", **spans)
        circles.append(circle)
        axes.append(Line(circle.center, direction))
    frame = base_frame_from_axes(axes[0], axes[1], q1_hold, robot, parallel_tol)
    n1, n2 = len(arc1), len(arc2)
    rms = float(np.sqrt((n1 * circles[0].rms ** 2 + n2 * circles[1].rms ** 2) / (n1 + n2)))
    common = dict(axis1=axes[0], axis2=axes[1], circle1=circles[0], circle2=circles[1], residual_rms_m=rms, **spans)
    if frame.parallel:
        return BaseFrameResult(False, "arc1_tracker, arc2_tracker: the joint-1 and joint-2 axes are parallel",
                               **common)
    return BaseFrameResult(True, "ok", frame.T_tracker_base, a1_measured_m=frame.a1_measured_m,
                           alpha1_measured_rad=frame.alpha1_measured_rad, **common)


def pose_deviation(T_est, T_ref) -> np.ndarray:
    """``[t_est - t_ref (m), rotvec(R_est R_ref^T) (rad)]`` (6,), both in the common (tracker) frame."""
    dt = T_est[:3, 3] - T_ref[:3, 3]
    dphi = Rotation.from_matrix(T_est[:3, :3] @ T_ref[:3, :3].T).as_rotvec()
    return np.concatenate([dt, dphi])


def _accuracy_from_cov(cov, method, n_samples=0, n_failed=0):
    return BaseFrameAccuracy(cov, float(np.sqrt(np.trace(cov[:3, :3]))), float(np.sqrt(np.trace(cov[3:, 3:]))),
                             method, n_samples, n_failed)


def _ideal_arc(points, circle: Circle3D):
    """Nearest points on ``circle`` to ``points``: the noise-free arc implied by the fit."""
    v = points - circle.center
    v = v - np.outer(v @ circle.normal, circle.normal)
    return circle.center + circle.radius * v / np.linalg.norm(v, axis=1, keepdims=True)


def base_frame_accuracy(arc1_tracker, arc2_tracker, q1_during_arc2, q1_arc1, q2_arc2, robot: Robot, sigma_m: float,
                        *, sigma_q_rad: float = 0.0, method: str = "linear", n_samples: int = 200,
                        rng: np.random.Generator | None = None, step_m: float = 1e-6) -> BaseFrameAccuracy:
    """Predicted accuracy of :func:`base_frame_from_arcs` for these arcs and tracker noise.

    Parameters
    ----------
    arc1_tracker, arc2_tracker, q1_during_arc2, q1_arc1, q2_arc2, robot
        As for :func:`base_frame_from_arcs` (the measured arcs).
    sigma_m : float
        Tracker noise, standard deviation per axis (m), > 0.
    sigma_q_rad : float
        Standard deviation of the joint-1 reading ``q1_during_arc2`` (rad), >= 0.
    method : {"linear", "monte_carlo"}
        ``"linear"``: first-order propagation ``Sigma = J diag(sigma^2) J^T`` with the estimator's Jacobian taken by
        central differences (step ``step_m``) at the measured points. ``"monte_carlo"``: parametric bootstrap - the
        fitted (noise-free) arcs plus ``n_samples`` draws of noise, refitted; covariance about the noise-free estimate.
    n_samples : int
        Monte Carlo draws.
    rng : numpy.random.Generator
        Required for ``"monte_carlo"``.

    Returns
    -------
    BaseFrameAccuracy
    """
    if not (isinstance(sigma_m, (int, float)) and np.isfinite(sigma_m) and sigma_m > 0):
        raise ValueError(f"sigma_m: expected a tracker noise > 0 (m), got {sigma_m!r}")
    if not (isinstance(sigma_q_rad, (int, float)) and np.isfinite(sigma_q_rad) and sigma_q_rad >= 0):
        raise ValueError(f"sigma_q_rad: expected a reading noise >= 0 (rad), got {sigma_q_rad!r}")
    ref = base_frame_from_arcs(arc1_tracker, arc2_tracker, q1_during_arc2, q1_arc1, q2_arc2, robot)
    if not ref.success:
        raise ValueError(f"arc1_tracker, arc2_tracker: the base frame cannot be estimated ({ref.message})")
    arc1 = np.asarray(arc1_tracker, dtype=float)
    arc2 = np.asarray(arc2_tracker, dtype=float)
    n1 = len(arc1)

    def estimate(a1, a2, q1h):
        r = base_frame_from_arcs(a1, a2, q1h, q1_arc1, q2_arc2, robot)
        return r.T_tracker_base if r.success else None

    if method == "linear":
        x0 = np.concatenate([arc1.ravel(), arc2.ravel()])
        cols = []
        for k in range(len(x0)):
            devs = []
            for sgn in (1.0, -1.0):
                x = x0.copy()
                x[k] += sgn * step_m
                T = estimate(x[: 3 * n1].reshape(-1, 3), x[3 * n1:].reshape(-1, 3), q1_during_arc2)
                if T is None:
                    raise ValueError(f"step_m: perturbing the arcs by {step_m:g} m breaks the fit; use a smaller step")
                devs.append(pose_deviation(T, ref.T_tracker_base))
            cols.append((devs[0] - devs[1]) / (2 * step_m))
        J = np.array(cols).T  # (6, 3 (N1 + N2))
        cov = sigma_m**2 * J @ J.T
        if sigma_q_rad > 0:
            h = 1e-6
            dq = (pose_deviation(estimate(arc1, arc2, q1_during_arc2 + h), ref.T_tracker_base)
                  - pose_deviation(estimate(arc1, arc2, q1_during_arc2 - h), ref.T_tracker_base)) / (2 * h)
            cov = cov + sigma_q_rad**2 * np.outer(dq, dq)
        return _accuracy_from_cov(cov, "linear")
    if method == "monte_carlo":
        if rng is None:
            raise ValueError("rng: a numpy.random.Generator is required for method='monte_carlo'")
        if not (isinstance(n_samples, int) and n_samples >= 2):
            raise ValueError(f"n_samples: expected an int >= 2, got {n_samples!r}")
        ideal1, ideal2 = _ideal_arc(arc1, ref.circle1), _ideal_arc(arc2, ref.circle2)
        T0 = estimate(ideal1, ideal2, q1_during_arc2)
        if T0 is None:
            raise ValueError("arc1_tracker, arc2_tracker: the fitted noise-free arcs give no base frame")
        devs, failed = [], 0
        for _ in range(n_samples):
            T = estimate(ideal1 + rng.normal(scale=sigma_m, size=ideal1.shape),
                         ideal2 + rng.normal(scale=sigma_m, size=ideal2.shape),
                         q1_during_arc2 + (rng.normal(scale=sigma_q_rad) if sigma_q_rad > 0 else 0.0))
            if T is None:
                failed += 1
                continue
            devs.append(pose_deviation(T, T0))
        if len(devs) < 2:
            raise ValueError(f"sigma_m: {failed} of {n_samples} noisy draws failed; the arcs are too short for "
                             f"sigma_m = {sigma_m:g} m")
        D = np.array(devs)
        return _accuracy_from_cov(D.T @ D / len(D), "monte_carlo", n_samples, failed)
    raise ValueError(f"method: expected 'linear' or 'monte_carlo', got {method!r}")


def _circle_basis(normal):
    """Orthonormal in-plane axes ``(u, v)`` with ``u x v = normal``."""
    a = np.eye(3)[int(np.argmin(np.abs(normal)))]
    u = np.cross(normal, a)
    u /= np.linalg.norm(u)
    return u, np.cross(normal, u)


def _arc_points(theta, basis, phi):
    """Points of a circle: ``theta = (c (3), tilt (2), r, [phi0])``, tilt rotating the plane about u and v."""
    u0, v0, n0 = basis
    c, (a, b), r = theta[:3], theta[3:5], theta[5]
    R = Rotation.from_rotvec(a * u0 + b * v0).as_matrix()
    u, v = R @ u0, R @ v0
    ph = phi + (theta[6] if len(theta) > 6 else 0.0)
    return c + r * (np.cos(ph)[:, None] * u + np.sin(ph)[:, None] * v)


def base_frame_bound(arc1_tracker, arc2_tracker, q1_during_arc2, q1_arc1, q2_arc2, robot: Robot, sigma_m: float,
                     *, readings: bool = True, step: float = 1e-7) -> BaseFrameAccuracy:
    """Cramér-Rao bound of the base frame from two tracker arcs with noise ``sigma_m`` (m, per axis).

    Measurement model: the points of arc k lie on a circle (centre, plane tilt, radius: 6 parameters) at angles
    ``phi_i``; the base frame is a function of the two circles (the axes through their centres, Eq. 45 and 107-117,
    and the joint-1 reading for x0), so by the invariance of maximum likelihood its bound is ``G I^-1 G^T`` with
    ``I`` the circles' Fisher information (the angles eliminated as nuisance parameters) and ``G`` the derivative of
    :func:`base_frame_from_arcs` on exact arcs with respect to the circle parameters (central differences, ``step``).

    ``readings=True``: the joint readings along the arcs give every angle up to one unknown offset per arc (the
    information a simulation with exact encoders holds; the circle fit of section 2.9 does not use it);
    ``readings=False``: the angles are free (geometry alone - the information the circle fit uses). Evaluated at the
    fitted circles of the measured arcs (at the truth in a simulation: pass the noise-free arcs).

    Returns
    -------
    BaseFrameAccuracy
        ``method`` ``"cramer_rao"`` (readings) or ``"cramer_rao_geometry"``; covariance of
        :func:`pose_deviation` ``[dt, dphi]``.
    """
    if not (isinstance(sigma_m, (int, float)) and np.isfinite(sigma_m) and sigma_m > 0):
        raise ValueError(f"sigma_m: expected a tracker noise > 0 (m), got {sigma_m!r}")
    ref = base_frame_from_arcs(arc1_tracker, arc2_tracker, q1_during_arc2, q1_arc1, q2_arc2, robot)
    if not ref.success:
        raise ValueError(f"arc1_tracker, arc2_tracker: the base frame cannot be estimated ({ref.message})")
    thetas, bases, phis, infos = [], [], [], []
    for pts, circle, q in ((arc1_tracker, ref.circle1, q1_arc1), (arc2_tracker, ref.circle2, q2_arc2)):
        u, v = _circle_basis(circle.normal)
        basis = (u, v, circle.normal)
        d = np.asarray(pts, float) - circle.center
        phi = np.arctan2(d @ v, d @ u)
        if readings:  # angles = readings (sign as the arc turns) + one offset
            sgn = np.sign(np.polyfit(np.asarray(q, float), np.unwrap(phi), 1)[0]) or 1.0
            phi_fixed = sgn * (np.asarray(q, float) - q[0])
            offset = float(np.mean(np.unwrap(phi) - phi_fixed))
            theta = np.r_[circle.center, 0.0, 0.0, circle.radius, offset]
        else:
            phi_fixed, theta = np.unwrap(phi), np.r_[circle.center, 0.0, 0.0, circle.radius]
        # Fisher information of (theta, free angles): J^T J / sigma^2, then the angles' Schur complement
        n_th = len(theta)
        cols = []
        for k in range(n_th):
            e = np.zeros(n_th)
            e[k] = step
            cols.append(((_arc_points(theta + e, basis, phi_fixed) - _arc_points(theta - e, basis, phi_fixed))
                         / (2 * step)).ravel())
        J = np.array(cols).T
        if not readings:  # d p_i / d phi_i: tangent of the circle at each point, rows of point i only
            t = np.zeros((3 * len(phi_fixed), len(phi_fixed)))
            p_plus = _arc_points(theta, basis, phi_fixed + step)
            p_minus = _arc_points(theta, basis, phi_fixed - step)
            for i in range(len(phi_fixed)):
                t[3 * i:3 * i + 3, i] = (p_plus[i] - p_minus[i]) / (2 * step)
            J = np.hstack([J, t])
        info = J.T @ J / sigma_m**2
        A, B, C = info[:n_th, :n_th], info[:n_th, n_th:], info[n_th:, n_th:]
        infos.append(A - B @ np.linalg.solve(C, B.T) if B.shape[1] else A)
        thetas.append(theta)
        bases.append(basis)
        phis.append(phi_fixed)

    def frame(th1, th2):
        a1 = _arc_points(th1, bases[0], phis[0])
        a2 = _arc_points(th2, bases[1], phis[1])
        r = base_frame_from_arcs(a1, a2, q1_during_arc2, q1_arc1, q2_arc2, robot)
        if not r.success:
            raise ValueError(f"step: perturbing the circles by {step:g} breaks the fit ({r.message})")
        return r.T_tracker_base

    T0 = frame(*thetas)
    n1 = len(thetas[0])
    x0 = np.concatenate(thetas)
    G = np.empty((6, len(x0)))
    for k in range(len(x0)):
        devs = []
        for sgn in (1.0, -1.0):
            x = x0.copy()
            x[k] += sgn * step
            devs.append(pose_deviation(frame(x[:n1], x[n1:]), T0))
        G[:, k] = (devs[0] - devs[1]) / (2 * step)
    cov_theta = np.zeros((len(x0), len(x0)))
    cov_theta[:n1, :n1] = np.linalg.inv(infos[0])
    cov_theta[n1:, n1:] = np.linalg.inv(infos[1])
    cov = G @ cov_theta @ G.T
    return _accuracy_from_cov(0.5 * (cov + cov.T), "cramer_rao" if readings else "cramer_rao_geometry")


def true_axes(robot: Robot, eps, T_tracker_base, q1_during_arc2: float, form: str = "exact"):
    """The actual joint-1 and joint-2 axes of an arm with errors ``eps`` (Eq. 10), in tracker coordinates.

    Joint 1 turns about z of frame ``E0``; joint 2 about z of ``E0 A1 E1`` at the joint-1 reading
    ``q1_during_arc2``. For simulations: feed them to :func:`base_frame_from_axes` to get the frame the arcs define.

    Returns
    -------
    (Line, Line)
    """
    T = check_transform(T_tracker_base, "T_tracker_base")
    q = np.zeros(robot.n)
    q[0] = q1_during_arc2
    F = T @ link_frames(robot, q, eps, form)[:2]  # frames 0 and 1 in tracker coordinates
    return Line(F[0, :3, 3], F[0, :3, 2]), Line(F[1, :3, 3], F[1, :3, 2])


def simulate_arcs(robot: Robot, T_tracker_base, q_start, span1: float, span2: float, n_points: int, eps=None,
                  sigma_m: float = 0.0, rng: np.random.Generator | None = None, form: str = "exact") -> ArcMeasurements:
    """Tracker arcs of the measured point (``robot.p_ee``) on an arm with errors ``eps``, as a tracker sees them.

    Arc 1: joint 1 from ``q_start[0]`` to ``q_start[0] + span1`` with the other joints at ``q_start``. Arc 2: joint 2
    from ``q_start[1]`` to ``q_start[1] + span2`` with joint 1 at ``q_start[0]`` (= ``q1_during_arc2``). Both within the
    joint limits (else ``ValueError``). Noise: normal, ``sigma_m`` per axis (m), drawn from ``rng``.
    """
    q_start = robot.check_q(q_start, "q_start")
    T = check_transform(T_tracker_base, "T_tracker_base")
    if not (isinstance(n_points, (int, np.integer)) and n_points >= 3):
        raise ValueError(f"n_points: expected an int >= 3, got {n_points!r}")
    if sigma_m < 0 or (sigma_m > 0 and rng is None):
        raise ValueError("sigma_m: must be >= 0 (m), and an rng is needed when > 0")
    qs = []
    for j, span, name in ((0, span1, "span1"), (1, span2, "span2")):
        q = np.repeat(q_start[None], n_points, axis=0)
        q[:, j] = q_start[j] + np.linspace(0.0, span, n_points)
        if q[:, j].min() < robot.q_min[j] - 1e-12 or q[:, j].max() > robot.q_max[j] + 1e-12:
            raise ValueError(f"{name}: joint {j + 1} from {np.rad2deg(q_start[j]):.4g} deg over "
                             f"{np.rad2deg(span):.4g} deg leaves its limits [{np.rad2deg(robot.q_min[j]):.4g}, "
                             f"{np.rad2deg(robot.q_max[j]):.4g}] deg")
        qs.append(q)
    arcs = [transform_points(T, ee_position(robot, q, eps, form)) for q in qs]
    if sigma_m > 0:
        arcs = [a + rng.normal(scale=sigma_m, size=a.shape) for a in arcs]
    return ArcMeasurements(arcs[0], qs[0][:, 0].copy(), arcs[1], qs[1][:, 1].copy(), float(q_start[0]))
