"""Observability indices of a calibration pose set and pose selection that maximises one of them.

For the column-scaled stacked reduced Jacobian with singular values ``s_1 >= ... >= s_L`` over ``m`` poses
(Sun & Hollerbach, "Observability index selection for robot calibration", ICRA 2008):

* ``O1 = (s_1 ... s_L)^(1/L) / sqrt(m)`` - Borm & Menq (volume of the error ellipsoid's inverse),
* ``O2 = s_L / s_1`` - inverse condition number (Driels & Pathre),
* ``O3 = s_L`` - minimum singular value (Nahvi, Hollerbach & Hayward),
* ``O4 = s_L^2 / s_1`` - noise amplification index (Nahvi & Hollerbach),
* ``O5 = 1 / (1/s_1 + ... + 1/s_L)`` - Sun & Hollerbach (related to A-optimality).

Larger is better for all five.
"""

from __future__ import annotations

import numpy as np

from bench.robot.jacobian import identification_jacobian
from bench.robot.model import Robot

INDICES = ("O1", "O2", "O3", "O4", "O5")


def _indices_from_sv(sv, m):
    """``sv (..., L)`` descending -> dict of the five indices (arrays of shape ``...``)."""
    sv = np.clip(sv, 0.0, None)
    L = sv.shape[-1]
    with np.errstate(divide="ignore"):
        logs = np.log(sv)
        o1 = np.exp(np.sum(logs, -1) / L) / np.sqrt(m)
        o5 = 1.0 / np.sum(1.0 / sv, -1)
    return {"O1": o1, "O2": sv[..., -1] / sv[..., 0], "O3": sv[..., -1], "O4": sv[..., -1] ** 2 / sv[..., 0],
            "O5": o5}


def _column_scale(robot: Robot, columns) -> np.ndarray:
    """Rotation columns are scaled by the arm's reach so indices compare metres with metres."""
    reach = float(np.sum(np.abs(robot.a)) + np.sum(np.abs(robot.d)))
    s = np.tile([1.0, 1.0, 1.0, reach, reach, reach], robot.n + 1)
    return s[np.asarray(columns)]


def observability_indices(robot: Robot, q, columns) -> dict:
    """The five indices for poses ``q (m, n)`` and identified ``columns`` (e.g. ``reduction.kept``)."""
    J = identification_jacobian(robot, q)[..., columns].reshape(-1, len(columns)) / _column_scale(robot, columns)
    sv = np.linalg.svd(J, compute_uv=False)
    return {k: float(v) for k, v in _indices_from_sv(sv, len(q)).items()}


def select_poses(robot: Robot, columns, n_poses: int, rng: np.random.Generator, index: str = "O1",
                 n_candidates: int = 2000, exchange_passes: int = 2):
    """Choose ``n_poses`` configurations within joint limits that maximise an observability index.

    Greedy addition from ``n_candidates`` random in-limit configurations (each step adds the candidate that most
    increases the index of the information matrix ``G^T G``), followed by ``exchange_passes`` of single-pose
    exchanges (DETMAX-style) that keep any swap improving the index.

    Returns
    -------
    q : ndarray (n_poses, n)
    value : float
        The index of the selected set.
    """
    if index not in INDICES:
        raise ValueError(f"index: expected one of {INDICES}, got {index!r}")
    L = len(columns)
    if n_poses * 3 < L:
        raise ValueError(f"n_poses: {n_poses} poses give {3 * n_poses} equations for {L} unknowns")
    cand = robot.random_configurations(rng, n_candidates)
    G = identification_jacobian(robot, cand)[..., columns] / _column_scale(robot, columns)  # (c, 3, L)
    info = np.einsum("cal,cak->clk", G, G)  # per-candidate information G_i^T G_i

    def score(mats, m):
        ev = np.linalg.eigvalsh(mats)[..., ::-1]
        return _indices_from_sv(np.sqrt(np.clip(ev, 0.0, None)), m)[index]

    chosen: list[int] = []
    S = np.eye(L) * 1e-12  # tiny ridge so early, rank-deficient sets can be ranked
    for k in range(n_poses):
        vals = score(S + info, k + 1)
        vals[chosen] = -np.inf
        best = int(np.argmax(vals))
        chosen.append(best)
        S = S + info[best]
    current = score(S, n_poses)
    for _ in range(exchange_passes):
        improved = False
        for pos in range(n_poses):
            base = S - info[chosen[pos]]
            vals = score(base + info, n_poses)
            vals[chosen] = -np.inf
            best = int(np.argmax(vals))
            if vals[best] > current * (1 + 1e-12):
                S = base + info[best]
                chosen[pos] = best
                current = vals[best]
                improved = True
        if not improved:
            break
    q = cand[chosen]
    return q, observability_indices(robot, q, columns)[index]
