"""Pose error of the end effector and of link 5 after calibration with the reduced errors (thesis §4.6).

Link 5's frame is Eq. 188, ``T_5^0 = E0 A1 E1 ... A4 E4 A5`` (the body that carries the camera, up to and
including joint 5's rotation). The deviation between the true and the calibrated model is Eq. 189,
``dT = T(q, eps_dot)^-1 T(q, eps)``, expressed in the calibrated frame. Its rotation is decomposed as
``dR = Ry(dy) Rx(dx) Rz(dz)`` (Eq. 190 with the axis labels of its middle and last factors corrected - the printed
middle factor is a z-rotation labelled x); Eq. 191-194 as printed correspond to all three angles negated, and the
angles here are extracted from the matrix consistently with the product above.
"""

from __future__ import annotations

import numpy as np

from bench.geometry.transforms import invert
from bench.robot.kinematics import dh_transform, link_frames
from bench.robot.model import Robot


def link5_frame(robot: Robot, q, eps=None, form="exact"):
    """``T_base_link5`` of Eq. 188 (frame 4 of Eq. 10 times ``A_5``), shape (..., 4, 4)."""
    F = link_frames(robot, q, eps, form)
    q = np.asarray(q, dtype=float)
    A5 = dh_transform(q[..., 4] + robot.theta_offset[4], robot.d[4], robot.a[4], robot.alpha[4])
    return F[..., 4, :, :] @ A5


def yxz_angles(dR):
    """Angles ``(dx, dy, dz)`` (rad) with ``dR = Ry(dy) Rx(dx) Rz(dz)`` (Eq. 190-194, see module note)."""
    dx = -np.arcsin(np.clip(dR[..., 1, 2], -1.0, 1.0))
    dy = np.arctan2(dR[..., 0, 2], dR[..., 2, 2])
    dz = np.arctan2(dR[..., 1, 0], dR[..., 1, 1])
    return np.stack([dx, dy, dz], -1)


def pose_deviation(T_est, T_true):
    """Eq. 189: position deviation (m, in the estimated frame) and YXZ angles (rad), each (..., 3)."""
    dT = invert(T_est) @ T_true
    return dT[..., :3, 3], yxz_angles(dT[..., :3, :3])


def orientation_analysis(robot: Robot, q, eps_true, eps_est, form="exact") -> dict:
    """End-effector and link-5 deviations between the true and the calibrated model over configurations ``q``.

    Returns
    -------
    dict of ndarray (m, 3)
        ``ee_pos_m``, ``ee_rot_rad``, ``link5_pos_m``, ``link5_rot_rad``: Eq. 189 for frame 6 and for link 5.
    """
    ee_t = link_frames(robot, q, eps_true, form)[..., -1, :, :]
    ee_e = link_frames(robot, q, eps_est, form)[..., -1, :, :]
    l5_t, l5_e = link5_frame(robot, q, eps_true, form), link5_frame(robot, q, eps_est, form)
    ee_p, ee_r = pose_deviation(ee_e, ee_t)
    # position error of the measured point itself, in the base frame (what the calibration makes small)
    p_true = ee_t[..., :3, :3] @ robot.p_ee + ee_t[..., :3, 3]
    p_est = ee_e[..., :3, :3] @ robot.p_ee + ee_e[..., :3, 3]
    l5_p, l5_r = pose_deviation(l5_e, l5_t)
    return {"ee_pos_m": p_true - p_est, "ee_rot_rad": ee_r, "link5_pos_m": l5_p, "link5_rot_rad": l5_r,
            "ee_frame_pos_m": ee_p}
