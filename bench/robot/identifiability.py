"""Which generalized errors can be identified, and what the others merge into (thesis §2.5-2.7, §4.4).

Two independent answers that must agree:

* :func:`closed_form_reduction` - the thesis's elimination rules: Eq. 16-17/21 (every revolute joint i makes
  ``z_(i-1)`` and ``r_(i-1)`` redundant and moves them into frame i), Eq. 23 (position-only measurement: the last
  frame's rotations are invisible), Eq. 24-27 in the form of Eq. 167 (the measured point on the last joint axis at
  ``h != 0`` from frame n-1: ``s_(n-1)`` merges into ``x_(n-1)`` and ``y_(n-1)`` into ``p_(n-1)``).
* :func:`numeric_identifiability` - rank and redundant columns of the stacked identification Jacobian at random
  poses (SVD for the rank, greedy column selection in a preferred order with pivoted QR as the default order), and
  the linear combination of kept columns that reproduces each dropped one. Works for any DH robot and point.

Both return the same object: the kept parameter indices and the 25x42 (in general p x 6(n+1)) map ``M`` with
``eps_dot = M eps`` (the reduced, identifiable errors, Eq. 20: ``J_e eps == G_e eps_dot``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from bench.robot.jacobian import identification_jacobian
from bench.robot.model import PARAM_KINDS, Robot, error_names

_IDX = {k: j for j, k in enumerate(PARAM_KINDS)}


def _col(frame: int, kind: str) -> int:
    return 6 * frame + _IDX[kind]


@dataclass
class Reduction:
    """An identifiable subset of the generalized errors and the map from the full vector to it.

    Attributes
    ----------
    kept : ndarray of int (p,)
        Indices of the identifiable errors in the full vector (ascending).
    M : ndarray (p, 6 (n + 1))
        ``eps_dot = M @ eps``: the reduced errors that reproduce the measurements of the full ``eps``
        (first order). Units mix m and rad as the entries they combine (coefficients such as ``a_i`` are in m).
    merged : dict
        For every eliminated error, ``{name: {kept_name: coefficient}}`` - where its value went.
    method : str
    rank : int
    singular_values : ndarray, optional
        Of the stacked (numeric) Jacobian.
    """

    kept: np.ndarray
    M: np.ndarray
    merged: dict = field(default_factory=dict)
    method: str = ""
    rank: int = 0
    singular_values: np.ndarray | None = None

    @property
    def names(self) -> list[str]:
        all_names = error_names(self.M.shape[1] // 6)
        return [all_names[k] for k in self.kept]

    def reduce(self, eps) -> np.ndarray:
        """Reduced errors ``eps_dot = M eps`` (Eq. 21, 167)."""
        return self.M @ np.asarray(eps, dtype=float)

    def expand(self, eps_dot) -> np.ndarray:
        """Full-length vector with ``eps_dot`` at the kept positions and zeros elsewhere (what the model uses)."""
        full = np.zeros(self.M.shape[1])
        full[self.kept] = eps_dot
        return full


def closed_form_reduction(robot: Robot, rows: str = "position", tol: float = 1e-12) -> Reduction:
    """The thesis's closed-form elimination of redundant errors for an all-revolute DH arm.

    Parameters
    ----------
    robot : Robot
        Its measured point ``p_ee`` decides Eq. 24-27/167: on the last joint axis (x = y = 0 after ``Rx(alpha_n)``)
        at height ``h = d_n + (Rx(alpha_n) p_ee)_z != 0`` they apply; off the axis only Eq. 16-17 and 23 do.
    rows : {"position", "pose"}
        What is measured. ``"pose"``: Eq. 16-17 only (6n parameters).

    Returns
    -------
    Reduction
        25 parameters for the TA-40 measured at O6.
    """
    n = robot.n
    p = 6 * (n + 1)
    M = np.eye(p)  # row k: current value of parameter k as a combination of the original errors
    removed: set[int] = set()
    for i in range(1, n + 1):  # Eq. 21, revolute joint i: z_(i-1), r_(i-1) go into frame i
        a, sa, ca = robot.a[i - 1], np.sin(robot.alpha[i - 1]), np.cos(robot.alpha[i - 1])
        z_prev, r_prev = M[_col(i - 1, "z")].copy(), M[_col(i - 1, "r")].copy()
        M[_col(i, "y")] += sa * z_prev + a * ca * r_prev
        M[_col(i, "z")] += ca * z_prev - a * sa * r_prev
        M[_col(i, "s")] += sa * r_prev
        M[_col(i, "r")] += ca * r_prev
        removed |= {_col(i - 1, "z"), _col(i - 1, "r")}
    if rows == "position":
        # Eq. 23, generalised to a point p_ee off frame n's origin: a rotation e of E_n moves the point by e x p_ee,
        # which the translations of E_n reproduce; at p_ee = 0 the rotations are simply invisible (Eq. 23).
        for kind, axis in (("s", (0.0, 1.0, 0.0)), ("r", (0.0, 0.0, 1.0)), ("p", (1.0, 0.0, 0.0))):
            c = np.cross(axis, robot.p_ee)
            for t, kt in enumerate("xyz"):
                M[_col(n, kt)] += c[t] * M[_col(n, kind)]
        removed |= {_col(n, "s"), _col(n, "r"), _col(n, "p")}
        ca, sa = np.cos(robot.alpha[-1]), np.sin(robot.alpha[-1])
        p_rot = np.array([robot.p_ee[0], ca * robot.p_ee[1] - sa * robot.p_ee[2],
                          sa * robot.p_ee[1] + ca * robot.p_ee[2]])
        h = robot.d[-1] + p_rot[2]
        on_axis = abs(robot.a[-1]) < tol and np.hypot(p_rot[0], p_rot[1]) < tol
        if on_axis and abs(h) < tol:
            raise ValueError("robot.p_ee: the measured point is at the origin of frame n-1; the recursive case of "
                             "Eq. 23-26 is not covered by the closed form - use numeric_identifiability()")
        if on_axis:  # Eq. 167: x* = x + s h, p* = p - y / h ; s_(n-1), y_(n-1) eliminated
            xs, ys = M[_col(n - 1, "s")].copy(), M[_col(n - 1, "y")].copy()
            M[_col(n - 1, "x")] += h * xs
            M[_col(n - 1, "p")] -= ys / h
            removed |= {_col(n - 1, "s"), _col(n - 1, "y")}
    elif rows != "pose":
        raise ValueError(f"rows: expected 'position' or 'pose', got {rows!r}")
    kept = np.array(sorted(set(range(p)) - removed))
    M = M[kept]
    return Reduction(kept, M, _merged_from_map(kept, M), "closed form (Eq. 21, 23, 167)", len(kept))


def _merged_from_map(kept, M, tol=1e-12) -> dict:
    names = error_names(M.shape[1] // 6)
    return {names[j]: {names[k]: float(M[r, j]) for r, k in enumerate(kept) if abs(M[r, j]) > tol}
            for j in np.setdiff1d(np.arange(M.shape[1]), kept)}


def select_columns(Js, preferred=None, rel_tol: float = 1e-9, n_poses: int | None = None):
    """Numerical rank of a (column-scaled) stacked Jacobian ``Js`` and a maximal set of independent columns.

    Columns are taken greedily in the ``preferred`` order (default: a column-pivoted QR's), each kept if it raises
    the rank (singular values above ``rel_tol * s_max * max(shape)``). Works for any stacked Jacobian: the DH arm's
    (:func:`numeric_identifiability`) or a URDF chain's with its nuisance parameters projected out.

    Returns
    -------
    kept : ndarray of int, ascending
    rank : int
    sv : ndarray
        Singular values of ``Js``.

    Raises
    ------
    ValueError
        When every row is independent (too few poses; ``n_poses`` names the count in the message).
    """
    sv = np.linalg.svd(Js, compute_uv=False)
    tol = rel_tol * sv[0] * max(Js.shape)
    rank = int(np.sum(sv > tol))
    if rank >= Js.shape[0]:
        n_poses = n_poses or Js.shape[0]
        per_pose = max(Js.shape[0] // n_poses, 1)
        raise ValueError(f"n_poses: {n_poses} poses give {Js.shape[0]} rows and all are independent, so the rank "
                         f"counts the rows, not the identifiable errors; use at least "
                         f"{Js.shape[1] // per_pose + 1} poses ({Js.shape[1]} parameters)")
    if preferred is None:
        _, _, piv = scipy.linalg.qr(Js, pivoting=True, mode="economic")
        order = list(piv)
    else:
        order = list(preferred) + [k for k in range(Js.shape[1]) if k not in set(preferred)]
    kept: list[int] = []
    for k in order:
        trial = Js[:, kept + [k]]
        s = np.linalg.svd(trial, compute_uv=False)
        if np.sum(s > tol) == len(kept) + 1:
            kept.append(k)
        if len(kept) == rank:
            break
    return np.array(sorted(kept), dtype=int), rank, sv


def numeric_identifiability(
    robot: Robot,
    rng: np.random.Generator,
    n_poses: int = 60,
    rows: str = "position",
    preferred: list[int] | np.ndarray | None = None,
    rel_tol: float = 1e-9,
) -> Reduction:
    """Rank and redundant columns of the stacked identification Jacobian ``J_t`` (Eq. 13) at random poses.

    Columns are chosen greedily in the ``preferred`` order (default: the order of a column-pivoted QR of ``J_t``),
    keeping a column if it raises the numerical rank. Each dropped column ``J_j`` is written as ``J_kept c_j`` by
    least squares; then ``eps_dot = eps_kept + sum_j c_j eps_j`` is the map ``M``. Rotation columns are scaled by
    the arm's reach so that the rank test compares like with like.

    Returns
    -------
    Reduction
        With ``singular_values`` of the scaled ``J_t``.

    Raises
    ------
    ValueError
        When every row of ``J_t`` is independent (too few poses: the rank then counts the rows, not the identifiable
        errors; 2 poses gave "rank 6" for the TA-40's 25).
    """
    if isinstance(n_poses, bool) or not isinstance(n_poses, (int, np.integer)) or n_poses < 1:
        raise ValueError(f"n_poses: expected a positive integer, got {n_poses!r}")
    q = robot.random_configurations(rng, n_poses)
    J = identification_jacobian(robot, q, rows=rows)
    J = J.reshape(-1, J.shape[-1])  # J_t of Eq. 13: the per-pose Jacobians stacked, (n_poses * rows, p)
    reach = max(float(np.sum(np.abs(robot.a)) + np.sum(np.abs(robot.d))), 1e-3)
    scale = np.tile([1.0, 1.0, 1.0, reach, reach, reach], robot.n + 1)
    Js = J / scale
    kept_arr, rank, sv = select_columns(Js, preferred, rel_tol, n_poses)
    dropped = np.setdiff1d(np.arange(J.shape[1]), kept_arr)
    C, *_ = np.linalg.lstsq(J[:, kept_arr], J[:, dropped], rcond=None)  # J_dropped = J_kept C
    M = np.zeros((len(kept_arr), J.shape[1]))
    M[:, kept_arr] = np.eye(len(kept_arr))
    M[:, dropped] = C
    residual = np.abs(J[:, kept_arr] @ C - J[:, dropped]).max(initial=0.0)
    if residual > 1e-8 * max(1.0, np.abs(J).max()):
        raise RuntimeError(f"dropped columns are not exact combinations of kept ones (residual {residual:.2e})")
    red = Reduction(kept_arr, M, {}, "numeric (SVD rank, greedy columns, least-squares merge)", rank, sv)
    red.merged = _merged_from_map(kept_arr, M, tol=1e-9)
    return red
