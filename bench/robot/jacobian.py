"""Identification Jacobian of the generalized error model (thesis Eq. 12-13), analytic and batched.

``J_e`` maps a change of the error vector ``eps`` to the change of the end-effector pose, ``dX = J_e d eps``
(Eq. 12). Position rows are the derivative of the measured point ``p_base`` (m); orientation rows are the base-frame
rotation vector ``w`` defined by ``dR R^T = [w]x``. With ``eps = 0`` this is the thesis's J_e of Appendix A; at other
``eps`` it is the exact Jacobian of the chosen form, used by the iterated (Gauss-Newton) identification.
"""

from __future__ import annotations

import numpy as np

from bench.geometry.transforms import vee
from bench.robot.kinematics import _check_eps, dh_transform, error_matrix, error_matrix_derivatives
from bench.robot.model import Robot

ROWS = ("position", "pose")


def identification_jacobian(robot: Robot, q, eps=None, form="exact", rows="position"):
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

    Returns
    -------
    ndarray (..., 3 or 6, 6 (n + 1))
    """
    if rows not in ROWS:
        raise ValueError(f"rows: expected one of {ROWS}, got {rows!r}")
    q = robot.check_q(q)
    eps = _check_eps(robot, eps).reshape(robot.n + 1, 6)
    lead = q.shape[:-1]
    A = dh_transform(q + robot.theta_offset, robot.d, robot.a, robot.alpha)  # (..., n, 4, 4)
    E = [error_matrix(e, form) for e in eps]
    dE = [error_matrix_derivatives(e, form) for e in eps]

    # B[i]: frame i before its error matrix, B_0 = I, B_i = T_base_(i-1) A_i   (prefix of Eq. 10)
    B = np.empty(lead + (robot.n + 1, 4, 4))
    B[..., 0, :, :] = np.eye(4)
    T = np.broadcast_to(E[0], lead + (4, 4))
    for i in range(1, robot.n + 1):
        B[..., i, :, :] = T @ A[..., i - 1, :, :]
        T = B[..., i, :, :] @ E[i]
    # u[i]: the measured point in frame i after E_i (suffix of Eq. 10 applied to p_ee)
    u = np.empty(lead + (robot.n + 1, 3))
    u[..., robot.n, :] = robot.p_ee
    for i in range(robot.n, 0, -1):
        M = A[..., i - 1, :, :] @ E[i]
        u[..., i - 1, :] = np.einsum("...ij,...j->...i", M[..., :3, :3], u[..., i, :]) + M[..., :3, 3]

    n_rows = 3 if rows == "position" else 6
    J = np.empty(lead + (n_rows, robot.n_errors))
    for i in range(robot.n + 1):
        RB = B[..., i, :3, :3]
        # local derivative of the point: dR_k u + dt_k, shape (..., 3, 6)
        local = np.einsum("kab,...b->...ak", dE[i][:, :3, :3], u[..., i, :]) + dE[i][:, :3, 3].T
        J[..., :3, 6 * i: 6 * i + 6] = RB @ local
        if rows == "pose":
            RE_inv = np.linalg.inv(E[i][:3, :3])
            w_local = vee(dE[i][:, :3, :3] @ RE_inv).T  # (3, 6)
            J[..., 3:, 6 * i: 6 * i + 6] = RB @ w_local
    return J


def stacked_jacobian(robot: Robot, q, eps=None, form="exact", rows="position", columns=None):
    """Total identification matrix ``J_t`` of Eq. 13: the per-pose Jacobians of ``q (m, n)`` stacked, (m*rows, p).

    ``columns`` (indices into the error vector) selects a reduced set (the thesis's ``G_e``).
    """
    J = identification_jacobian(robot, q, eps, form, rows)
    J = J.reshape(-1, J.shape[-1])
    return J if columns is None else J[:, columns]
