"""Identification Jacobian of the generalized error model (thesis Eq. 12-13), analytic and batched.

``J_e`` maps a change of the error vector ``eps`` to the change of the end-effector pose, ``dX = J_e d eps``
(Eq. 12). Position rows are the derivative of the measured point ``p_base`` (m); orientation rows are the base-frame
rotation vector ``w`` defined by ``dR R^T = [w]x``. With ``eps = 0`` this is the thesis's J_e of Appendix A; at other
``eps`` it is the exact Jacobian of the chosen form, used by the iterated (Gauss-Newton) identification.
"""

from __future__ import annotations

import numpy as np

from bench.geometry.transforms import vee
from bench.robot.kinematics import _check_eps, error_matrix, error_matrix_derivatives, joint_transforms
from bench.robot.model import Robot

ROWS = ("position", "pose")


def _cross_cols(w, r):
    """``w (..., 3, k) x r (..., 3)`` column by column -> (..., 3, k)."""
    rx, ry, rz = r[..., 0, None], r[..., 1, None], r[..., 2, None]
    return np.stack([w[..., 1, :] * rz - w[..., 2, :] * ry, w[..., 2, :] * rx - w[..., 0, :] * rz,
                     w[..., 0, :] * ry - w[..., 1, :] * rx], axis=-2)


def _jacobian_exact(robot: Robot, q, eps, rows, return_points):
    """Fast path for rigid error matrices: column k of frame i is ``R_B dt_k + (R_B w_k) x (p - o_i)`` where
    ``w_k = vee(dR_k R_E^T)`` is the local angular velocity of the error and ``o_i`` the origin of frame i."""
    lead = q.shape[:-1]
    A = joint_transforms(robot, q)
    E = [error_matrix(e, "exact") for e in eps]
    dE = [error_matrix_derivatives(e, "exact") for e in eps]
    RB, O = [], []
    T = np.broadcast_to(E[0], lead + (4, 4))
    RB.append(np.broadcast_to(np.eye(3), lead + (3, 3)))
    O.append(T[..., :3, 3])
    for i in range(1, robot.n + 1):
        B = T @ A[i - 1]
        T = B if not np.any(eps[i]) else B @ E[i]
        RB.append(B[..., :3, :3])
        O.append(T[..., :3, 3])
    p = (T[..., :3, :3] @ robot.p_ee) + T[..., :3, 3]
    n_rows = 3 if rows == "position" else 6
    J = np.empty(lead + (n_rows, robot.n_errors))
    for i in range(robot.n + 1):
        Rt = E[i][:3, :3].T
        W = vee(dE[i][:, :3, :3] @ Rt).T  # (3, 6) local angular velocities
        Dt = dE[i][:, :3, 3].T  # (3, 6)
        Wb = np.tensordot(RB[i], W, axes=([-1], [0]))  # R_B w_k, (..., 3, 6)
        Tb = np.tensordot(RB[i], Dt, axes=([-1], [0]))
        J[..., :3, 6 * i: 6 * i + 6] = Tb + _cross_cols(Wb, p - O[i])
        if rows == "pose":
            J[..., 3:, 6 * i: 6 * i + 6] = Wb
    return (J, p) if return_points else J


def identification_jacobian(robot: Robot, q, eps=None, form="exact", rows="position", return_points=False):
    """Identification Jacobian at configurations ``q``.

    Parameters
    ----------
    robot : Robot
    q : array_like (..., n)
        Joint readings (rad).
    eps : array_like (6 (n + 1),), optional
        Linearisation point (m, rad); zero (the thesis's J_e) if omitted.
    form : {"exact", "linear"}
    rows : {"position", "pose"}
        ``"position"``: 3 rows (dp, m per unit error); ``"pose"``: 6 rows, position then rotation vector (rad).

    return_points : bool
        Also return the measured points ``p_base (..., 3)`` (m) at ``eps`` (saves a forward pass).

    Returns
    -------
    J : ndarray (..., 3 or 6, 6 (n + 1))
    p : ndarray (..., 3), only with ``return_points``
    """
    if rows not in ROWS:
        raise ValueError(f"rows: expected one of {ROWS}, got {rows!r}")
    q = robot.check_q(q)
    eps = _check_eps(robot, eps).reshape(robot.n + 1, 6)
    if form == "exact" or not np.any(eps):  # both forms coincide at eps = 0
        return _jacobian_exact(robot, q, eps, rows, return_points)
    if form != "linear":
        raise ValueError(f"form: expected 'exact' or 'linear', got {form!r}")
    lead = q.shape[:-1]
    A = joint_transforms(robot, q)  # n arrays (..., 4, 4)
    E = [error_matrix(e, form) for e in eps]
    dE = [error_matrix_derivatives(e, form) for e in eps]

    # B[i]: frame i before its error matrix, B_0 = I, B_i = T_base_(i-1) A_i   (prefix of Eq. 10)
    identity = [not np.any(e) for e in eps]  # E_i = I: skip the product
    B = [np.broadcast_to(np.eye(4), lead + (4, 4))]
    T = np.broadcast_to(E[0], lead + (4, 4))
    for i in range(1, robot.n + 1):
        B.append(T @ A[i - 1])
        T = B[i] if identity[i] else B[i] @ E[i]
    # u[i]: the measured point in frame i after E_i (suffix of Eq. 10 applied to p_ee)
    u = [None] * robot.n + [np.broadcast_to(robot.p_ee, lead + (3,))]
    for i in range(robot.n, 0, -1):
        M = A[i - 1] if identity[i] else A[i - 1] @ E[i]
        u[i - 1] = (M[..., :3, :3] @ u[i][..., None])[..., 0] + M[..., :3, 3]

    n_rows = 3 if rows == "position" else 6
    J = np.empty(lead + (n_rows, robot.n_errors))
    for i in range(robot.n + 1):
        RB = B[i][..., :3, :3]
        # local derivative of the point: dR_k u + dt_k, shape (..., 3, 6)
        local = np.swapaxes(np.tensordot(u[i], dE[i][:, :3, :3], axes=([-1], [2])), -1, -2)
        local = local + dE[i][:, :3, 3].T
        J[..., :3, 6 * i: 6 * i + 6] = RB @ local
        if rows == "pose":
            RE_inv = np.linalg.inv(E[i][:3, :3])
            w_local = vee(dE[i][:, :3, :3] @ RE_inv).T  # (3, 6)
            J[..., 3:, 6 * i: 6 * i + 6] = RB @ w_local
    if return_points:
        return J, (T[..., :3, :3] @ robot.p_ee) + T[..., :3, 3]
    return J
