"""View planning for the link-5 camera: joint configurations that put the camera at an eye point, looking at a target.

Bench side: the planner stands in for the operator who jogs the arm to the views of a campaign. It works on whatever
model it is given (nominal, calibrated or true); the simulator then renders at the *true* joint angles and the
dataset carries the encoder *readings*.

Link 5 (Eq. 188) has five joints in front of it, so a camera on link 5 has five degrees of freedom: the eye point
(3) and the viewing direction (2) fix it, and the roll about the optical axis follows. Where two wrist branches give
the same eye and direction (rolls differing by 180 deg), the one whose image "down" (camera +y, OpenCV frame) is
closest to ``down_base`` (or to the seed view's) is taken, so that views of a campaign are upright and consistent.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from bench.geometry.transforms import homogeneous, rot_z
from bench.robot.model import Robot
from bench.robot.orientation import link5_frame


@dataclass(frozen=True)
class ViewSolution:
    """Outcome of :func:`look_at_configuration`; ``success`` False with a reason instead of an exception."""

    success: bool
    q: np.ndarray  # (6,) joint angles (rad) of the best solution found (q6 kept from the seed)
    position_error_m: float
    direction_error_rad: float
    message: str


def camera_frames(robot: Robot, q, T_link5_cam, eps=None):
    """``T_base_cam`` (..., 4, 4) of a camera mounted at ``T_link5_cam`` on link 5 (Eq. 188)."""
    return link5_frame(robot, q, eps) @ np.asarray(T_link5_cam, dtype=float)


def _check_point(p, name):
    p = np.asarray(p, dtype=float)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise ValueError(f"{name}: expected 3 finite coordinates (m), got {p!r}")
    return p


def look_at_configuration(robot: Robot, eye_base, target_base, T_link5_cam, eps=None, q_seed=None,
                          down_base=(0.0, 0.0, -1.0), rng: np.random.Generator | None = None, n_starts: int = 12,
                          tol_m: float = 1e-6, tol_rad: float = 1e-6) -> ViewSolution:
    """Joint angles that put the camera's centre at ``eye_base`` with its optical axis towards ``target_base``.

    Parameters
    ----------
    robot : Robot
    eye_base, target_base : array_like (3,)
        Camera centre and a point on the optical axis, base frame (m).
    T_link5_cam : array_like (4, 4)
        Camera mount: OpenCV optical frame (z forward, y down) in the link-5 frame.
    eps : array_like (42,), optional
        Generalized errors of the model to plan on (default nominal).
    q_seed : array_like (6,), optional
        Start (rad); its q6 is kept (joint 6 does not move link 5). Default: centre of the joint ranges.
    down_base : array_like (3,)
        Preferred image-down direction in the base frame (picks the upright wrist branch); with ``q_seed`` the seed
        camera's own down direction is preferred instead, so that neighbouring views keep their roll.
    rng : numpy.random.Generator, optional
        For the extra random starts (default: a fixed seed, so planning is deterministic).
    n_starts : int
        Random starts tried besides ``q_seed`` when it does not converge.

    Returns
    -------
    ViewSolution
    """
    eye = _check_point(eye_base, "eye_base")
    target = _check_point(target_base, "target_base")
    view = target - eye
    if np.linalg.norm(view) < 1e-6:
        raise ValueError("target_base: coincides with eye_base; no viewing direction")
    view /= np.linalg.norm(view)
    down = _check_point(down_base, "down_base")
    T_link5_cam = np.asarray(T_link5_cam, dtype=float)
    lo, hi = robot.q_min, robot.q_max
    q0 = 0.5 * (lo + hi) if q_seed is None else robot.check_q(q_seed, "q_seed").reshape(robot.n).copy()
    if q_seed is not None:  # keep the seed view's roll: matches between views must not turn by 180 deg (Eq. 106)
        down = camera_frames(robot, q0, T_link5_cam, eps)[:3, 1]
    rng = np.random.default_rng(0) if rng is None else rng

    def full(x):
        q = q0.copy()
        q[:5] = x
        return q

    def residual(x):
        T = camera_frames(robot, full(x), T_link5_cam, eps)
        return np.concatenate([T[:3, 3] - eye, T[:3, 2] - view])

    starts = [np.clip(q0[:5], lo[:5], hi[:5])]
    starts += list(rng.uniform(lo[:5], hi[:5], size=(n_starts, 5)))
    found = []
    for x0 in starts:
        sol = least_squares(residual, x0, bounds=(lo[:5], hi[:5]), xtol=1e-15, ftol=1e-15, gtol=1e-15,
                            max_nfev=200)
        r = residual(sol.x)
        ep, ed = float(np.linalg.norm(r[:3])), float(np.linalg.norm(r[3:]))
        found.append((sol.x, ep, ed))
        if sum(f[1] <= tol_m and f[2] <= tol_rad for f in found) >= 2:
            break
    converged = [f for f in found if f[1] <= tol_m and f[2] <= tol_rad]
    if converged:
        def uprightness(f):
            return -float(camera_frames(robot, full(f[0]), T_link5_cam, eps)[:3, 1] @ down)

        x, ep, ed = min(converged, key=lambda f: (round(uprightness(f), 6), np.sum((f[0] - q0[:5]) ** 2)))
        return ViewSolution(True, full(x), ep, ed, "view reached")
    x, ep, ed = min(found, key=lambda f: f[1] + f[2])
    return ViewSolution(False, full(x), ep, ed, f"view not reachable within the joint limits (best: position "
                                                f"{ep * 1e3:.1f} mm, direction {np.rad2deg(ed):.2f} deg off)")


def look_at(eye, target, down=(0.0, 0.0, -1.0)):
    """``T_frame_cam`` of an OpenCV camera at ``eye`` looking at ``target`` with image-down closest to ``down``."""
    eye, target, down = (np.asarray(v, dtype=float) for v in (eye, target, down))
    z = target - eye
    z /= np.linalg.norm(z)
    y = down - (down @ z) * z
    if np.linalg.norm(y) < 1e-9:
        raise ValueError("down: parallel to the viewing direction")
    y /= np.linalg.norm(y)
    return homogeneous(np.column_stack([np.cross(y, z), y, z]), eye)


def surrounding_eyes(T_base_ref_cam, offsets_m) -> np.ndarray:
    """Eye points around a reference view, in its image plane: ``offsets_m (k, 2)`` along camera x and y (m).

    Returns ``(k, 3)`` in the frame of ``T_base_ref_cam``'s parent (the base). Each surrounding view looks at the
    same target as the reference (the caller passes the target to :func:`look_at_configuration`), so the set forms
    the converging pattern of section 3.9 with baselines (intraocular distances, Eq. 199) equal to the offsets.
    """
    T = np.asarray(T_base_ref_cam, dtype=float)
    off = np.asarray(offsets_m, dtype=float).reshape(-1, 2)
    return T[:3, 3] + off[:, :1] * T[:3, 0] + off[:, 1:] * T[:3, 1]



def wrist_reach(robot: Robot, n_samples: int = 721):
    """The shell the wrist centre (link-5 origin) can occupy: its distance (m) from the shoulder (frame-1 origin,
    on the joint-2 axis) over the elbow's range, ``(r_min, r_max)``.

    Joints 2 and 3 move the wrist in the arm's plane; its distance from the shoulder depends on ``q3`` alone (the
    elbow): ``|a2 x + T_2_4(q3) origin|``, sampled over joint 3's limits.
    """
    from bench.robot.kinematics import link_frames

    q = np.tile(0.5 * (robot.q_min + robot.q_max), (n_samples, 1))
    q[:, 1] = 0.0 if robot.q_min[1] <= 0.0 <= robot.q_max[1] else robot.q_min[1]
    q[:, 2] = np.linspace(robot.q_min[2], robot.q_max[2], n_samples)
    F = link_frames(robot, q)
    d = np.linalg.norm(F[:, 4, :3, 3] - F[:, 1, :3, 3], axis=1)
    return float(d.min()), float(d.max())


def reach_diagnosis(robot: Robot, eye_base, target_base, T_link5_cam, n_roll: int = 72) -> dict:
    """Why a view may be out of reach, in numbers: where the wrist centre must be for the camera to sit at
    ``eye_base`` looking at ``target_base``, against the arm's shell (:func:`wrist_reach`) and joint 1's range.

    The roll about the optical axis is free (five joints in front of link 5), so the wrist centre lies on a circle
    around the optical axis; the circle's point that best fits the shell is reported.

    Returns
    -------
    dict
        ``wrist_dist_m`` (distance from the shoulder of the best wrist point), ``reach_min_m``, ``reach_max_m``,
        ``azimuth_deg`` (the wrist's azimuth about joint 1 from the base x axis), ``q1_min_deg``, ``q1_max_deg``,
        ``shortfall_m`` (how far the best point lies outside the shell; 0 inside), ``message``.
    """
    from bench.robot.kinematics import link_frames

    eye = _check_point(eye_base, "eye_base")
    view = _check_point(target_base, "target_base") - eye
    view /= np.linalg.norm(view)
    T_l5_cam = np.asarray(T_link5_cam, dtype=float)
    t_cam_l5 = -(T_l5_cam[:3, :3].T @ T_l5_cam[:3, 3])  # link-5 origin in the camera frame
    r_min, r_max = wrist_reach(robot)
    base = look_at(eye, eye + view)
    best = None
    for roll in np.linspace(0, 2 * np.pi, n_roll, endpoint=False):
        R = base[:3, :3] @ rot_z(roll)
        wrist = eye + R @ t_cam_l5
        az = float(np.arctan2(wrist[1], wrist[0]))
        q1 = np.clip(az, robot.q_min[0], robot.q_max[0])
        q = 0.5 * (robot.q_min + robot.q_max)
        q[0] = q1
        shoulder = link_frames(robot, q)[1, :3, 3]
        d = float(np.linalg.norm(wrist - shoulder))
        short = max(r_min - d, d - r_max, 0.0)
        az_out = float(max(robot.q_min[0] - az, az - robot.q_max[0], 0.0))
        key = (short + az_out * np.hypot(*wrist[:2]), short)
        if best is None or key < best[0]:
            best = (key, d, short, az)
    _, d, short, az = best
    out = {"wrist_dist_m": d, "reach_min_m": r_min, "reach_max_m": r_max, "azimuth_deg": float(np.rad2deg(az)),
           "q1_min_deg": float(np.rad2deg(robot.q_min[0])), "q1_max_deg": float(np.rad2deg(robot.q_max[0])),
           "shortfall_m": short}
    where = (f"the camera at {np.round(eye, 3).tolist()} m needs the wrist centre {d:.2f} m from the shoulder "
             f"(azimuth {np.rad2deg(az):.0f} deg); the arm's wrist reaches {r_min:.2f}-{r_max:.2f} m "
             f"(joint 1 {out['q1_min_deg']:.0f}..{out['q1_max_deg']:.0f} deg)")
    if short > 0:
        out["message"] = f"{where}: {short * 1e3:.0f} mm " + ("beyond its reach" if d > r_max else
                                                            "closer to the shoulder than the folded elbow allows")
    elif not robot.q_min[0] <= az <= robot.q_max[0]:
        out["message"] = f"{where}: outside joint 1's range"
    else:
        out["message"] = f"{where}: within the shell, so joints 2-5's limits (not the reach) exclude the view"
    return out
