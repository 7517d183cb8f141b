"""Inverse kinematics of the TA-40 (thesis section 4.5, Eq. 168-187), nominal and calibrated.

* :func:`analytic_ik` - all closed-form solutions of the *nominal* DH model (Eq. 8) for a target ``T_base_ee``
  (pose of frame 6 in the base frame O0): up to 8 branches, shoulder ``theta1 / theta1 + pi`` x elbow (two signs of
  the law-of-cosines angle) x wrist flip ``(theta4, theta5, theta6) / (theta4 + pi, -theta5, theta6 + pi)``.
* :func:`select_solution` - the in-limit branch closest to the current joint readings.
* :func:`compensated_ik` - the joint readings that reach the target on the *calibrated* (generalized-error) model
  of Eq. 10: analytic nominal IK gives the seeds, damped Newton (Levenberg-Marquardt) on
  :func:`~bench.robot.kinematics.forward_kinematics` finishes, within the joint limits.
* :func:`geometric_jacobian` - the ordinary joint-space Jacobian ``d pose / d q`` (6 x n) of the error model.

Everything is SI (m, rad). Joint readings ``q`` relate to DH angles by ``theta_i = q_i + theta_offset_i``.

Derivation (standard DH, Eq. 8, TA-40 structure alpha = 90/0/90/-90/90/0 deg, a4 = a5 = a6 = d5 = 0)
-------------------------------------------------------------------------------------------------------
The wrist is spherical (O4 = O5), so the wrist centre is ``p_w = p - d6 b`` (``b`` = z-axis of frame 6 = approach
vector, ``p`` = origin O6). In frame 1 (Eq. 169, 172)::

    x' = x c1 + y s1 - a1          = a2 c2 + a3 c23 + d4 s23
    y' = z - d1                    = a2 s2 + a3 s23 - d4 c23
    z' = x s1 - y c1               = d2 + d3            (= 0 for the TA-40)

with (x, y, z) = p_w. Hence ``theta1 = atan2(y, x) + asin((d2 + d3) / r)`` or ``atan2(y, x) + pi - asin(...)``
(``r = hypot(x, y)``; for the TA-40, Eq. 173 corrected: ``atan2(y, x) + k pi``). Joints 2-3 form a planar two-link
arm with links ``a2`` and ``k = hypot(a3, d4)`` (Eq. 175): ``a3 c23 + d4 s23 = k cos(theta23 - beta)``,
``a3 s23 - d4 c23 = k sin(theta23 - beta)``, ``beta = atan2(d4, a3)``. With ``gamma = theta3 - beta``,
``cos(gamma) = (x'^2 + y'^2 - a2^2 - k^2) / (2 a2 k)``, ``theta3 = beta + gamma`` and
``theta2 = atan2(y', x') - atan2(k sin(gamma), a2 + k cos(gamma))``.
The wrist: ``M = R_3_6 = R_0_3^T R`` has third column ``(c4 s5, s4 s5, c5)`` (Eq. 178), so
``theta4 = atan2(M12, M02) (+ pi)``; then ``N = R_4_6 = Rz(theta4)Rx(-90)^T M = Rz(theta5) Rx(90) Rz(theta6)`` gives
``theta5 = atan2(N02, -N12)`` and ``theta6 = atan2(N20, N21)``. Taking theta5 and theta6 from ``N`` given theta4
(instead of Eq. 182-187) reproduces the target rotation exactly for *any* theta4, which is what makes the wrist
singularity harmless: if ``sin(theta5) < wrist_tol`` theta4 is fixed at ``q4_hint`` (thesis: "joint 4 then has to be
fixed in an arbitrary position") and the whole wrist roll goes into theta6; that arm branch then has a single wrist
branch.

Misprints in the thesis
-----------------------
Checked numerically against the DH chain of Table 1 (``models/ta40.yaml``):

1. Eq. 170, 172, 174, 175 - the second component of O4 in frame 1 is ``a2 s2 + a3 s23 - d4 c23``, not ``+ d4 c23``
   (the z-axis of frame 3 in frame 1 is ``(s23, -c23, 0)``); ``a_s`` there is ``a3``.
2. Eq. 171-173 - the wrist-centre offset is ``b_i d6``, not ``b_i a6`` (a6 = 0 in Table 1; d6 = 360 mm), and the
   second row of Eq. 171-172 is ``z - d1 - b3 d6`` (d1 = 0 for the TA-40, harmless). Eq. 171 should read
   ``(A_1^0)^-1 T_6^0 (A_6^5)^-1``, not ``... P_5^1 ...``; the text after Eq. 169 cites "Equation (162)" for (169).
3. Eq. 173 - ``z - b1 a6`` in the denominator must be ``x - b1 d6``; the quadrant matters, so ``atan2``.
4. Eq. 176 - the trailing ``+ phi`` is spurious: ``theta2 = atan2(y', x') + acos((x'^2 + y'^2 + a2^2 - k^2) /
   (2 a2 sqrt(x'^2 + y'^2)))``, which is the elbow branch of Eq. 177's ``-acos`` (Eq. 177 itself is right).
5. Eq. 181 - the expanded ``x''`` and ``z''`` rows are garbled (e.g. ``x c1 (c23 - s23)``, ``a1 (c23 + s23)``,
   ``z (s23 - c23)``); Eq. 180, which they should restate, is correct.
6. Eq. 184 - first row, second column ``p_z`` should be ``p_x`` (the ``o``/``p`` column).
7. Eq. 185 - the vector is ``(n_x, n_y, n_z)`` not ``(n_z, n_y, n_x)``, and its second row has two sign errors:
   ``n_y = [(s1 c23 c4 - c1 s4) c5 - s1 s23 s5] c6 + (-s1 c23 s4 - c1 c4) s6``; so ``mu3`` and ``mu4`` must read
   ``(s1 c23 c4 - c1 s4) c5 - s1 s23 s5`` and ``-s1 c23 s4 - c1 c4``.
8. Text after Eq. 183: "Joint six only changes the *position*" - it changes only the orientation.

Not misprints but numerical weaknesses of the printed method, avoided here: Eq. 183 divides by ``s4`` (fails at
theta4 = 0; ``x'' c4 + y'' s4 = d6 s5`` does not); the determinant of Eq. 186, ``mu1 mu4 - mu2 mu3``, equals
``b_z`` (z-component of the approach vector), so Eq. 186 is singular whenever the tool axis is horizontal. And
"joint 2 only can attain positive angles eliminates this ambiguity" is not true in general: for 86 % of uniformly
drawn in-limit configurations both elbow branches have theta2 >= 0, for 52 % both are entirely within the limits
(with the wrist flip, 4 in-limit branches instead of 2), hence :func:`select_solution`.

Compensated IK, position-only mode
----------------------------------
The calibration identifies only the 25 position-relevant errors (Eq. 167); the orientation of the calibrated
model is biased (section 4.6). With ``position_only=True`` success depends on the measured point alone
(``robot.p_ee`` carried by frame 6, target point ``T_target @ robot.p_ee``), and the orientation is a *secondary*
objective handled by stages, not by a null-space projection: Newton first solves the full pose (6 equations, 6
joints: generically the full pose is reachable, and then the orientation is exact too); only if that stops short
(a joint limit, or the orientation unattainable) does a second Newton run on the 3 position equations alone, with
minimum-norm damped steps from the best full-pose iterate, so the position becomes exact and the orientation stays
as close as the first stage got. The alternative "orientation only as the analytic seed" (3 equations from the
nominal seed) was measured and rejected: with +-2 mm / +-1 deg errors its minimum-norm correction left the
orientation up to ~15 deg off target, and worse from poor seeds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.geometry.transforms import check_transform, rotation_angle, skew, vee
from bench.robot.kinematics import FORMS, _check_eps, dh_transform, error_matrix, forward_kinematics, link_frames
from bench.robot.model import Robot

__all__ = ["IKResult", "analytic_ik", "check_ik_structure", "compensated_ik", "geometric_jacobian",
           "select_solution"]

#: DH twists (rad) of the supported structure (TA-40, thesis Table 1).
_ALPHA = np.deg2rad([90.0, 0.0, 90.0, -90.0, 90.0, 0.0])
#: Joint readings within this distance (rad) of a limit count as within the limits.
LIMIT_TOL = 1e-9
_GZ = skew([0.0, 0.0, 1.0])  # [e_z]x


@dataclass(frozen=True)
class IKResult:
    """Outcome of an IK call. Never raised for unreachable targets: ``success`` is False and ``message`` says why.

    Attributes
    ----------
    success : bool
        Analytic: at least one branch reproduces the pose and is within the joint limits. Compensated: converged
        to ``tol`` (position, and orientation unless position-only) within the limits.
    solutions : ndarray (k, 6)
        Joint readings (rad), each mapped to the 2 pi-equivalent inside the limits where one exists.
    within_limits : ndarray (k,) of bool
    message : str
    iterations : int
        Newton iterations (0 for the analytic solver).
    position_error_m, orientation_error_rad : float
        Worst residual over ``solutions`` (analytic, on the nominal model) or of the returned solution
        (compensated, on the error model); NaN if there is no solution.
    wrist_singular : bool
        sin(theta5) below the wrist tolerance: theta4 was fixed at ``q4_hint``.
    at_limit : ndarray (k, 6) of bool or None
        Compensated only: joints held (clipped) at a limit.
    """

    success: bool
    solutions: np.ndarray
    within_limits: np.ndarray
    message: str
    iterations: int = 0
    position_error_m: float = float("nan")
    orientation_error_rad: float = float("nan")
    wrist_singular: bool = False
    at_limit: np.ndarray | None = None


# ----------------------------------------------------------------------------------------------- helpers


def _wrap(x):
    """Angles wrapped to [-pi, pi)."""
    return (np.asarray(x, dtype=float) + np.pi) % (2 * np.pi) - np.pi


def _in_limits(robot: Robot, q, tol=LIMIT_TOL):
    q = np.asarray(q, dtype=float)
    return np.all((q >= robot.q_min - tol) & (q <= robot.q_max + tol), axis=-1)


def _into_limits(robot: Robot, q):
    """Each angle wrapped to [-pi, pi), then shifted by +-2 pi if that brings it inside its joint range."""
    q = _wrap(q)
    out = q.copy()
    for shift in (2 * np.pi, -2 * np.pi):
        cand = q + shift
        ok_now = (out >= robot.q_min - LIMIT_TOL) & (out <= robot.q_max + LIMIT_TOL)
        ok_cand = (cand >= robot.q_min - LIMIT_TOL) & (cand <= robot.q_max + LIMIT_TOL)
        out = np.where(~ok_now & ok_cand, cand, out)
    return out


def _centre(robot: Robot):
    return 0.5 * (robot.q_min + robot.q_max)


def _check_target(T, name):
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4):
        raise ValueError(f"{name}: expected shape (4, 4), got {T.shape}")
    return check_transform(T, name)


def _check_angle(value, name):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number (rad), got {value!r}") from None
    if not np.isfinite(v):
        raise ValueError(f"{name}: must be finite")
    return v


def _pose_errors(T, T_target):
    """Position (m) and orientation (rad) distance between poses ``T (..., 4, 4)`` and one target."""
    dp = np.linalg.norm(T[..., :3, 3] - T_target[:3, 3], axis=-1)
    dr = rotation_angle(np.swapaxes(T_target[:3, :3], -1, -2) @ T[..., :3, :3])
    return dp, dr


def check_ik_structure(robot: Robot) -> None:
    """Raise a one-line ``ValueError`` unless ``robot`` has the TA-40 structure :func:`analytic_ik` solves.

    Required: 6 revolute joints, twists alpha = (90, 0, 90, -90, 90, 0) deg, a4 = a5 = a6 = 0 and d5 = 0 (spherical
    wrist at O4 = O5), a2 > 0 and hypot(a3, d4) > 0. a1, a3, d1, d4, d6, the lateral offset d2 + d3 and the joint
    offsets are free.
    """
    if robot.n != 6:
        raise ValueError(f"robot: analytic IK needs the 6-joint TA-40 structure, got {robot.n} joints")
    if np.abs(_wrap(robot.alpha - _ALPHA)).max() > 1e-9:
        got = ", ".join(f"{v:g}" for v in np.round(np.rad2deg(robot.alpha), 6))
        raise ValueError(f"robot: analytic IK needs twists alpha = 90/0/90/-90/90/0 deg, got {got}")
    bad = [f"{n}={v * 1e3:g} mm" for n, v in (("a4", robot.a[3]), ("a5", robot.a[4]), ("a6", robot.a[5]),
                                              ("d5", robot.d[4])) if abs(v) > 1e-12]
    if bad:
        raise ValueError(f"robot: analytic IK needs a spherical wrist (a4 = a5 = a6 = d5 = 0), got {', '.join(bad)}")
    if robot.a[1] <= 0 or np.hypot(robot.a[2], robot.d[3]) <= 0:
        raise ValueError("robot: analytic IK needs a2 > 0 and hypot(a3, d4) > 0")


# ----------------------------------------------------------------------------------------------- analytic IK


def analytic_ik(robot: Robot, T_base_ee, q4_hint: float = 0.0, q1_hint: float = 0.0,
                wrist_tol: float = 1e-12, reach_tol: float = 1e-10) -> IKResult:
    """All closed-form IK solutions of the nominal model (thesis section 4.5, corrected; see module docstring).

    Parameters
    ----------
    robot : Robot
        Must have the TA-40 structure (:func:`check_ik_structure`); only its nominal DH parameters are used.
    T_base_ee : array_like (4, 4)
        Target pose of frame 6 (origin O6 and orientation) in the base frame, m. ``robot.p_ee`` is not used.
    q4_hint : float
        Joint-4 reading (rad) to hold at the wrist singularity (sin(theta5) < ``wrist_tol``), e.g. the current one.
    q1_hint : float
        Joint-1 reading (rad) at the shoulder singularity (wrist centre on the joint-1 axis; then q1_hint + pi too).
    wrist_tol : float
        Below this sin(theta5) the wrist counts as singular. Above it theta4 comes from atan2 and may carry noise
        ~1e-16 / sin(theta5) rad, but the returned pose stays exact because theta5, theta6 are solved given theta4.
    reach_tol : float
        Tolerance on the law-of-cosines argument at the workspace boundary (for the TA-40, targets up to about
        0.4 reach_tol m beyond full stretch are clipped to it).

    Returns
    -------
    IKResult
        ``solutions`` (k, 6): k = 8 in general; an arm branch with a singular wrist contributes one wrist branch
        instead of two; fewer where branches coincide (full stretch) or are out of reach - for the TA-40 the
        shoulder branch theta1 + pi is out of reach for about half of the workspace, giving k = 4. All reproduce the
        pose;
        ``within_limits`` marks those inside the joint limits; ``success`` is True iff at least one is.
        Out-of-reach targets give k = 0 and success False.
    """
    check_ik_structure(robot)
    T = _check_target(T_base_ee, "T_base_ee")
    q4_hint = _check_angle(q4_hint, "q4_hint")
    q1_hint = _check_angle(q1_hint, "q1_hint")
    thetas, singular, fail = _branches(robot, T, q4_hint, q1_hint, wrist_tol, reach_tol)
    if fail:
        return IKResult(False, np.empty((0, 6)), np.zeros(0, bool), fail)
    q = _into_limits(robot, thetas - robot.theta_offset)
    keep = []  # drop coincident branches (full stretch, fold-back)
    for i in range(len(q)):
        if all(np.abs(_wrap(q[i] - q[j])).max() > 1e-9 for j in keep):
            keep.append(i)
    q = q[keep]
    inside = _in_limits(robot, q)
    dp, dr = _pose_errors(forward_kinematics(robot, q), T)
    tag = " (wrist singular: theta4 held at q4_hint, wrist roll in theta6)" if singular else ""
    if inside.any():
        msg = f"{len(q)} branches, {int(inside.sum())} within the joint limits{tag}"
    else:
        msg = f"none of the {len(q)} branches is within the joint limits ({_worst_violation(robot, q)}){tag}"
    return IKResult(bool(inside.any()), q, inside, msg, 0, float(dp.max()), float(dr.max()), singular)


def _branches(robot: Robot, T, q4_hint, q1_hint, wrist_tol, reach_tol, clamp=None, theta1=None):
    """DH angles of all branches, ``(thetas (k, 6), wrist_singular, failure message or "")``.

    Newton seeds only: ``clamp`` - instead of failing out of reach, clip the law-of-cosines argument to
    ``[-1 + clamp, 1 - clamp]`` (a slightly bent arm pointing at the target) and the lateral-offset sine to +-1;
    ``theta1`` - impose these DH angles of joint 1 (the wrist centre is then projected into the arm plane).
    """
    a1, a2, a3 = robot.a[:3]
    d1, d4, d6 = robot.d[0], robot.d[3], robot.d[5]
    d_lat = robot.d[1] + robot.d[2]
    off = robot.theta_offset
    R, p = T[:3, :3], T[:3, 3]
    x, y, z = p - d6 * R[:, 2]  # wrist centre O4 = O5
    r = np.hypot(x, y)
    k = np.hypot(a3, d4)
    beta = np.arctan2(d4, a3)

    if r < abs(d_lat) - reach_tol and clamp is None:
        return None, False, (f"out of reach: wrist centre is {r:.6g} m from the joint-1 axis, less than the lateral "
                             f"offset |d2 + d3| = {abs(d_lat):.6g} m")
    if theta1 is not None:
        pass
    elif r < 1e-12 and abs(d_lat) < 1e-12:  # shoulder singularity: theta1 free
        theta1 = [q1_hint + off[0], q1_hint + off[0] + np.pi]
    else:
        phi = np.arctan2(y, x)
        asn = np.arcsin(np.clip(d_lat / max(r, 1e-300), -1.0, 1.0))
        theta1 = [phi + asn, phi + np.pi - asn]

    thetas, singular, reach = [], False, []
    for t1 in theta1:
        c1, s1 = np.cos(t1), np.sin(t1)
        xp, yp = x * c1 + y * s1 - a1, z - d1
        rho = np.hypot(xp, yp)
        cg = (rho**2 - a2**2 - k**2) / (2 * a2 * k)
        if clamp is not None:
            cg = np.clip(cg, -1.0 + clamp, 1.0 - clamp)
        elif abs(cg) > 1 + reach_tol:
            reach.append(f"{rho:.6g} m")
            continue
        g0 = np.arccos(np.clip(cg, -1.0, 1.0))
        for g in (-g0, g0):  # Eq. 177's "-acos" branch first
            t3 = beta + g
            t2 = np.arctan2(yp, xp) - np.arctan2(k * np.sin(g), a2 + k * np.cos(g))
            A = dh_transform(np.array([t1, t2, t3]), robot.d[:3], robot.a[:3], robot.alpha[:3])
            M = (A[0] @ A[1] @ A[2])[:3, :3].T @ R  # R_3_6
            s5 = np.hypot(M[0, 2], M[1, 2])
            if s5 < wrist_tol:
                singular = True
                t4s = [q4_hint + off[3]]
            else:
                t4 = np.arctan2(M[1, 2], M[0, 2])
                t4s = [t4, t4 + np.pi]
            for t4 in t4s:
                N = dh_transform(t4, 0.0, 0.0, robot.alpha[3])[:3, :3].T @ M  # R_4_6 = Rz(t5) Rx(90) Rz(t6)
                t5 = np.arctan2(N[0, 2], -N[1, 2])
                t6 = np.arctan2(N[2, 0], N[2, 1])
                thetas.append([t1, t2, t3, t4, t5, t6])
    if not thetas:
        return None, False, (f"out of reach: wrist centre is {' / '.join(reach)} from the joint-2 axis for the two "
                             f"shoulder branches; reachable distances are [{abs(a2 - k):.6g}, {a2 + k:.6g}] m")
    return np.array(thetas), singular, ""


def _worst_violation(robot: Robot, q):
    """Describe the smallest limit violation over branches ``q (k, n)``: the branch that is nearest to feasible."""
    viol = np.maximum(robot.q_min - q, q - robot.q_max).clip(min=0.0)
    b = int(np.argmin(viol.max(axis=1)))
    j = int(np.argmax(viol[b]))
    return (f"nearest branch: joint{j + 1} = {np.rad2deg(q[b, j]):.3f} deg outside "
            f"[{np.rad2deg(robot.q_min[j]):g}, {np.rad2deg(robot.q_max[j]):g}] deg")


def select_solution(robot: Robot, solutions, q_current=None, wrapped: bool = True):
    """The branch within the joint limits closest to ``q_current``; None if no branch is within the limits.

    Parameters
    ----------
    robot : Robot
    solutions : IKResult or array_like (k, n)
        Joint readings (rad).
    q_current : array_like (n,), optional
        Current joint readings (rad); the centre of the joint ranges if omitted.
    wrapped : bool
        Distance on angle differences wrapped to [-pi, pi) (default). Joints with hard stops cannot actually pass
        through +-180 deg, so ``wrapped=False`` (plain differences) is the physically travelled distance.

    Returns
    -------
    ndarray (n,) or None
    """
    sols = solutions.solutions if isinstance(solutions, IKResult) else solutions
    sols = np.asarray(sols, dtype=float)
    if sols.ndim != 2 or sols.shape[1] != robot.n:
        raise ValueError(f"solutions: expected shape (k, {robot.n}), got {sols.shape}")
    if not np.all(np.isfinite(sols)):
        raise ValueError("solutions: contains NaN or inf")
    ref = _centre(robot) if q_current is None else robot.check_q(q_current, "q_current")
    if ref.shape != (robot.n,):
        raise ValueError(f"q_current: expected shape ({robot.n},), got {ref.shape}")
    if len(sols) == 0:
        return None
    inside = _in_limits(robot, sols)
    if not inside.any():
        return None
    diff = sols - ref
    if wrapped:
        diff = _wrap(diff)
    dist = np.where(inside, np.sum(diff**2, axis=1), np.inf)
    return sols[int(np.argmin(dist))].copy()


# ----------------------------------------------------------------------------------------------- Jacobian


def geometric_jacobian(robot: Robot, q, eps=None, form: str = "exact", point=None):
    """Joint-space Jacobian of the (error) model: ``[dp; w] = J dq``, shape (..., 6, n).

    Rows 0-2: velocity of ``point`` (in frame n, m; default the origin of frame n); rows 3-5: base-frame angular
    velocity ``w`` with ``dR R^-1 = [w]x``. Joint i turns about the z-axis of frame i-1 *after* its error matrix
    (``link_frames[i-1]``, Eq. 10), so for the exact form column i is ``[z_(i-1) x (p - o_(i-1)); z_(i-1)]``.
    For the linearised form (Eq. 9) the frames are affine, not rigid; then the exact column is
    ``dp = R_(i-1) (e_z x u)`` with ``u`` the point in frame i-1 coordinates, and ``w = vee(R_(i-1) [e_z]x
    R_(i-1)^-1)`` (the skew part; ``R`` is orthonormal only to first order there).
    """
    if form not in FORMS:
        raise ValueError(f"form: expected one of {FORMS}, got {form!r}")
    return _jacobian_from_frames(link_frames(robot, q, eps, form), form, point)


def _jacobian_from_frames(F, form, point=None):
    """:func:`geometric_jacobian` from the frames ``F (..., n + 1, 4, 4)`` of :func:`link_frames`."""
    pt = np.zeros(3) if point is None else np.asarray(point, dtype=float).reshape(3)
    T = F[..., -1, :, :]
    p = T[..., :3, :3] @ pt + T[..., :3, 3]  # (..., 3)
    P = F[..., :-1, :, :]  # frame i-1 for joint i, (..., n, 4, 4)
    J = np.empty(F.shape[:-3] + (6, P.shape[-3]))
    if form == "exact":
        z, o = P[..., :3, 2], P[..., :3, 3]  # (..., n, 3)
        J[..., :3, :] = np.swapaxes(np.cross(z, p[..., None, :] - o), -1, -2)
        J[..., 3:, :] = np.swapaxes(z, -1, -2)
    else:
        Pinv = np.linalg.inv(P)
        u = np.einsum("...ij,...j->...i", Pinv[..., :3, :3], p[..., None, :]) + Pinv[..., :3, 3]
        J[..., :3, :] = np.swapaxes(np.einsum("...ij,...j->...i", P[..., :3, :3], u @ _GZ.T), -1, -2)
        W = P[..., :3, :3] @ _GZ @ np.linalg.inv(P[..., :3, :3])
        J[..., 3:, :] = np.swapaxes(vee(W), -1, -2)
    return J


def _frames_fn(robot: Robot, eps, form):
    """Fast single-configuration :func:`link_frames` for Newton: the error matrices are built once.

    Same chain, ``T_base_k = E0 A1 E1 ... Ak Ek`` (Eq. 10); the results are re-checked with
    :func:`~bench.robot.kinematics.forward_kinematics` before being reported.
    """
    E = [error_matrix(e, form) for e in np.asarray(eps, dtype=float).reshape(robot.n + 1, 6)]

    def frames(q):
        A = dh_transform(q + robot.theta_offset, robot.d, robot.a, robot.alpha)
        F = np.empty((robot.n + 1, 4, 4))
        F[0] = T = E[0]
        for i in range(robot.n):
            F[i + 1] = T = T @ A[i] @ E[i + 1]
        return F

    return frames


# ----------------------------------------------------------------------------------------------- compensated IK


def compensated_ik(robot: Robot, eps, T_target, q_seed=None, form: str = "exact", position_only: bool = False,
                   tol: float = 1e-10, max_iter: int = 50) -> IKResult:
    """Joint readings that put the *calibrated* arm (Eq. 10 with errors ``eps``) at ``T_target``.

    The analytic nominal IK (:func:`analytic_ik`) gives the seeds - its in-limit branches, plus ``q_seed``; then
    damped Newton / Levenberg-Marquardt steps ``dq = J^T (J J^T + lam I)^-1 r`` on the error model's
    :func:`~bench.robot.kinematics.forward_kinematics` with :func:`geometric_jacobian`, joints clipped to their
    limits (a joint at a limit whose step points outwards is frozen for that step), until the error is below
    ``tol``. Of the solutions reached, the one closest to ``q_seed`` (wrapped distance; default the centre of the
    joint ranges) is returned: near the shoulder and wrist singularities the calibrated solution can be tens of
    degrees away from its nominal branch. If no such seed converges (a fold of the stretched arm, a limit, a local
    minimum), fallbacks are tried until one does: a slightly bent arm aimed at the target, clipped nominal
    branches, a sweep of joint 1 (see ``_seeds``).

    Orientation error: ``atan2(|vee(E)|, (tr E - 1) / 2)`` with ``E = R_target^T R`` - the rotation angle for the
    exact form; for the linear form (whose ``R`` is orthonormal to first order only) it vanishes exactly when the
    rotation (polar) factor of ``R`` equals ``R_target``.

    Parameters
    ----------
    robot : Robot
        TA-40 structure (the analytic seed needs it).
    eps : array_like (42,) or None
        Generalized errors (m, rad), order of Table 2; None = nominal.
    T_target : array_like (4, 4)
        Target pose of frame 6 in the base frame (m).
    q_seed : array_like (6,), optional
        Current joint readings (rad): selects the analytic branch and supplies q1/q4 at singularities.
    form : {"exact", "linear"}
    position_only : bool
        Success on the measured point ``T_target @ robot.p_ee`` only; the orientation is a secondary objective
        (see the module docstring) and is reported in ``orientation_error_rad``.
    tol : float
        Convergence threshold on the position error (m) and, unless ``position_only``, the orientation error (rad).
    max_iter : int
        Newton iterations per seed (and per stage).

    Returns
    -------
    IKResult
        One solution (1, 6); ``success`` False (with the reason) if not converged, e.g. target out of reach or
        only reachable beyond a joint limit (``at_limit`` shows the clipped joints); then the best iterate found.
    """
    T_t = _check_target(T_target, "T_target")
    eps = _check_eps(robot, eps)
    if form not in FORMS:
        raise ValueError(f"form: expected one of {FORMS}, got {form!r}")
    if not (np.isfinite(tol) and tol > 0):
        raise ValueError(f"tol: must be a positive number, got {tol!r}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise ValueError(f"max_iter: must be a positive integer, got {max_iter!r}")
    if q_seed is not None:
        q_seed = robot.check_q(q_seed, "q_seed")
        if q_seed.shape != (robot.n,):
            raise ValueError(f"q_seed: expected shape ({robot.n},), got {q_seed.shape}")

    hint = np.zeros(robot.n) if q_seed is None else q_seed
    nominal = analytic_ik(robot, T_t, q4_hint=hint[3], q1_hint=hint[0])
    point = robot.p_ee if position_only else np.zeros(3)
    p_t = T_t[:3, :3] @ point + T_t[:3, 3]
    R_t = T_t[:3, :3]

    frames = _frames_fn(robot, eps, form)

    def residual(q, n_rows):
        """``(r, position error, orientation error, frames)`` at ``q``."""
        F = frames(q)
        T = F[-1]
        rp = p_t - (T[:3, :3] @ point + T[:3, 3])
        # orientation: skew part of R_t^T R (zero iff the rotation (polar) factor of R equals R_t; R is orthonormal
        # only to first order for the linear form), as a base-frame rotation vector from current to target
        E = R_t.T @ T[:3, :3]
        v = vee(E)
        s = np.linalg.norm(v)
        ang = float(np.arctan2(s, 0.5 * (np.trace(E) - 1.0)))
        ro = -R_t @ v * (ang / s if s > 1e-300 else 1.0)
        return np.concatenate([rp, ro])[:n_rows], float(np.linalg.norm(rp)), ang, F

    def newton(q, n_rows):
        """Damped Newton from ``q`` on the first ``n_rows`` residuals; returns ``(q, ep, eo, iterations)``."""
        r, ep, eo, F = residual(q, n_rows)
        lam, it, hist = 1e-8, 0, []
        while not (ep <= tol and (n_rows == 3 or eo <= tol)) and it < max_iter:
            it += 1
            hist.append(np.linalg.norm(r))
            if it > 10 and hist[-1] > 0.1 * hist[-6]:  # slow progress (fold, limit, local minimum): next seed
                break
            J = _jacobian_from_frames(F, form, point)[:n_rows]
            free = np.ones(robot.n, bool)
            for _ in range(robot.n):
                dq = np.zeros(robot.n)
                Jf = J[:, free]
                dq[free] = Jf.T @ np.linalg.solve(Jf @ Jf.T + lam * np.eye(n_rows), r)
                outward = ((q >= robot.q_max) & (dq > 0)) | ((q <= robot.q_min) & (dq < 0))
                if not (outward & free).any():
                    break
                free &= ~outward
            q_new = np.clip(q + dq, robot.q_min, robot.q_max)
            r_new, ep_new, eo_new, F_new = residual(q_new, n_rows)
            if np.linalg.norm(r_new) < np.linalg.norm(r):
                q, r, ep, eo, F = q_new, r_new, ep_new, eo_new, F_new
                lam = max(lam * 0.1, 1e-15)
            else:
                lam *= 10.0
                if lam > 1e4:
                    break
        return q, ep, eo, it

    def reached(run):
        return run[1] <= tol and run[2] <= tol

    ref = _centre(robot) if q_seed is None else q_seed
    runs = []  # full-pose Newton end points (q, ep, eo, iterations, note), one per seed tried
    for q0, note, primary in _seeds(robot, T_t, nominal, q_seed):
        if not primary and any(reached(run) for run in runs):
            break
        runs.append((*newton(np.clip(q0, robot.q_min, robot.q_max), 6), note))
        if not primary and reached(runs[-1]):
            break
    if any(reached(run) for run in runs):  # the solution closest to q_seed (or the range centre)
        best = min((run for run in runs if reached(run)), key=lambda run: np.sum(_wrap(run[0] - ref) ** 2))
    else:
        best = min(runs, key=lambda run: run[1] + run[2])
    if position_only and best[1] > tol:  # full pose reached from no seed: keep the position, let the orientation give
        stage2 = []
        for q1, _, _, it1, note in sorted(runs, key=lambda run: run[1] + run[2]):
            q, ep, eo, it = newton(q1, 3)
            stage2.append((q, ep, eo, it1 + it, f"{note}, full pose not reachable, position-only refinement"))
            if ep <= tol:
                break
        best = min(stage2, key=lambda run: (run[1] > tol, run[1], run[2]))
    q, _, _, it, note = best
    T = forward_kinematics(robot, q, eps, form)  # report with the reference FK, not the Newton-internal chain
    ep = float(np.linalg.norm(T[:3, :3] @ point + T[:3, 3] - p_t))
    E = R_t.T @ T[:3, :3]
    eo = float(np.arctan2(np.linalg.norm(vee(E)), 0.5 * (np.trace(E) - 1.0)))
    at_limit = (q <= robot.q_min) | (q >= robot.q_max)
    ok = ep <= tol and (position_only or eo <= tol)
    what = "position" if position_only else "pose"
    errs = f"position error {ep:.2e} m, orientation error {eo:.2e} rad"
    if ok:
        msg = f"{what} reached on the error model in {it} iterations: {errs}; {note} ({len(runs)} tried)"
    else:
        lim = ", ".join(f"joint{j + 1}" for j in np.flatnonzero(at_limit))
        if nominal.message.startswith("out of reach"):
            why = "target out of reach"
        elif lim:
            why = f"best iterate has {lim} at its limit: target likely reachable only beyond it"
        else:
            why = "no convergence from any seed"
        msg = f"{what} not reached to tol {tol:g} ({why}): {errs}; {note}; nominal IK: {nominal.message}"
    return IKResult(ok, q[None, :], _in_limits(robot, q)[None], msg, it, ep, eo, nominal.wrist_singular,
                    at_limit[None, :])


def _seeds(robot: Robot, T, nominal: IKResult, q_seed):
    """Newton seeds ``(q0, note, primary)`` (a generator, best first).

    Primary seeds are all tried, and the converged solution closest to ``q_seed`` wins; the fallbacks are tried in
    order only if no primary seed converged, until one does.

    1. primary: the in-limit nominal branches, by distance to ``q_seed`` (or the range centre), and ``q_seed``;
    2. the in-limit branches of a slightly bent arm aimed at the target (both elbow signs: near full stretch Newton
       cannot cross the fold to the other elbow sign);
    3. the two nominal branches nearest to the limits, clipped;
    4. a sweep of joint 1 over its range (in-limit branches of each, wrist centre projected into the arm plane):
       with the wrist centre near the joint-1 axis the nominal theta1 can be tens of degrees off the calibrated one;
    5. the centre of the joint ranges.
    """
    ref = _centre(robot) if q_seed is None else q_seed
    hint = np.zeros(robot.n) if q_seed is None else q_seed

    def by_distance(cands, n=None):
        cands = cands[_in_limits(robot, cands)]
        return cands[np.argsort(np.sum(_wrap(cands - ref) ** 2, axis=1), kind="stable")][:n]

    def bent(theta1=None):
        thetas, _, _ = _branches(robot, T, hint[3], hint[0], 1e-12, 0.0, clamp=1e-2, theta1=theta1)
        return _into_limits(robot, thetas - robot.theta_offset)

    sols = nominal.solutions
    for c in by_distance(sols):
        yield c, "seed: analytic nominal branch", True
    if q_seed is not None:
        yield q_seed, "seed: q_seed", True
    for c in by_distance(bent()):
        yield c, "seed: bent-arm branch aimed at the target", False
    outside = sols[~nominal.within_limits]
    if len(outside):
        viol = np.maximum(robot.q_min - outside, outside - robot.q_max).clip(min=0.0).max(axis=1)
        for c in outside[np.argsort(viol, kind="stable")][:2]:
            yield np.clip(c, robot.q_min, robot.q_max), "seed: nominal branch clipped to the joint limits", False
    for q1 in np.linspace(robot.q_min[0], robot.q_max[0], 7):
        for c in by_distance(bent([q1 + robot.theta_offset[0]])):
            yield c, "seed: joint-1 sweep", False
    yield _centre(robot), "seed: centre of the joint ranges", False
