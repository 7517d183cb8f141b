"""Forward kinematics with the generalized error model (thesis Eq. 6-10), batched over configurations.

Frames: ``T_base_k`` for k = 0..n is frame k of the (possibly perturbed) arm in the base frame O0:
``T_base_k = E0 A1 E1 ... Ak Ek`` (Eq. 10); with all errors zero it is the nominal DH chain (Eq. 6).

The error vector ``eps`` has ``6 (n + 1)`` entries, frame-major, and inside a frame ``x, y, z, s, r, p``: translations
(m) along x, y, z and rotations (rad) about y (s), z (r) and x (p) (Eq. 9, Table 2 order).

Two forms of ``E_i``:

* ``"linear"`` - the thesis's linearised matrix of Eq. 9 (not exactly a rigid transform).
* ``"exact"`` - the rigid transform ``Trans(x, y, z) Rz(r) Ry(s) Rx(p)``, whose first-order expansion is Eq. 9.
"""

from __future__ import annotations

import numpy as np

from bench.geometry.transforms import homogeneous, rot_x, rot_y, rot_z, skew
from bench.robot.model import Robot

FORMS = ("exact", "linear")
#: Generators of rotations about x, y, z: ``[e_x]x, [e_y]x, [e_z]x`` (``d rot_x(a) / da = G_X rot_x(a)``).
_G_X, _G_Y, _G_Z = skew(np.eye(3))


def dh_transform(theta, d, a, alpha):
    """Standard DH link transform ``A_i = Rz(theta) Tz(d) Tx(a) Rx(alpha)`` (Eq. 7-8), ``theta.shape + (4, 4)``."""
    theta = np.asarray(theta, dtype=float)
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(alpha), np.sin(alpha)
    A = np.zeros(theta.shape + (4, 4))
    A[..., 0, 0], A[..., 0, 1], A[..., 0, 2], A[..., 0, 3] = ct, -st * ca, st * sa, a * ct
    A[..., 1, 0], A[..., 1, 1], A[..., 1, 2], A[..., 1, 3] = st, ct * ca, -ct * sa, a * st
    A[..., 2, 1], A[..., 2, 2], A[..., 2, 3] = sa, ca, d
    A[..., 3, 3] = 1.0
    return A


def joint_transforms(robot: Robot, q) -> list:
    """The DH matrices ``A_1 .. A_n`` at readings ``q (..., n)``, one contiguous ``(..., 4, 4)`` array per joint."""
    return [dh_transform(q[..., i] + robot.theta_offset[i], robot.d[i], robot.a[i], robot.alpha[i])
            for i in range(robot.n)]


def error_matrix(e6, form="exact"):
    """Generalized-error matrix ``E_i`` of one frame from ``e6 = (x, y, z, s, r, p)`` (Eq. 9 or its exact form)."""
    x, y, z, s, r, p = np.asarray(e6, dtype=float)
    if form == "linear":  # Eq. 9
        return np.array([[1.0, -r, s, x], [r, 1.0, -p, y], [-s, p, 1.0, z], [0.0, 0.0, 0.0, 1.0]])
    if form == "exact":
        return homogeneous(rot_z(r) @ rot_y(s) @ rot_x(p), [x, y, z])
    raise ValueError(f"form: expected one of {FORMS}, got {form!r}")


def error_matrix_derivatives(e6, form="exact"):
    """``dE/de_k`` for k over ``(x, y, z, s, r, p)``, shape (6, 4, 4)."""
    x, y, z, s, r, p = np.asarray(e6, dtype=float)
    D = np.zeros((6, 4, 4))
    D[0, 0, 3] = D[1, 1, 3] = D[2, 2, 3] = 1.0
    if form == "linear":
        D[3:, :3, :3] = _G_Y, _G_Z, _G_X  # s, r, p: about y, z, x
        return D
    if form != "exact":
        raise ValueError(f"form: expected one of {FORMS}, got {form!r}")
    Rz, Ry, Rx = rot_z(r), rot_y(s), rot_x(p)
    D[3, :3, :3] = Rz @ _G_Y @ Ry @ Rx
    D[4, :3, :3] = _G_Z @ Rz @ Ry @ Rx
    D[5, :3, :3] = Rz @ Ry @ _G_X @ Rx
    return D


def _check_eps(robot: Robot, eps):
    if eps is None:
        return np.zeros(robot.n_errors)
    eps = np.asarray(eps, dtype=float)
    if eps.shape != (robot.n_errors,):
        raise ValueError(f"eps: expected shape ({robot.n_errors},), got {eps.shape}")
    if not np.all(np.isfinite(eps)):
        raise ValueError("eps: contains NaN or inf")
    return eps


def link_frames(robot: Robot, q, eps=None, form="exact"):
    """Poses of frames 0..n in the base frame, ``T_base_k`` (Eq. 10).

    Parameters
    ----------
    robot : Robot
    q : array_like (..., n)
        Joint readings (rad).
    eps : array_like (6 (n + 1),), optional
        Generalized errors (m, rad); zero if omitted.
    form : {"exact", "linear"}

    Returns
    -------
    ndarray (..., n + 1, 4, 4)
    """
    q = robot.check_q(q)
    eps = _check_eps(robot, eps).reshape(robot.n + 1, 6)
    out = np.empty(q.shape[:-1] + (robot.n + 1, 4, 4))
    T = np.broadcast_to(error_matrix(eps[0], form), q.shape[:-1] + (4, 4))
    out[..., 0, :, :] = T
    for i, A in enumerate(joint_transforms(robot, q)):
        T = T @ A
        if np.any(eps[i + 1]):
            T = T @ error_matrix(eps[i + 1], form)
        out[..., i + 1, :, :] = T
    return out


def forward_kinematics(robot: Robot, q, eps=None, form="exact"):
    """End-effector frame ``T_base_ee`` (frame n), shape (..., 4, 4) (Eq. 6 / Eq. 10)."""
    return link_frames(robot, q, eps, form)[..., -1, :, :]


def ee_position(robot: Robot, q, eps=None, form="exact"):
    """Measured end-effector point ``p_base`` (m), shape (..., 3): the robot's ``p_ee`` carried by frame n."""
    T = forward_kinematics(robot, q, eps, form)
    return T[..., :3, :3] @ robot.p_ee + T[..., :3, 3]
