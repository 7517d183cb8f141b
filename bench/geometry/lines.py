"""Closest points between two 3D lines and their mid-point (thesis section 3.5, Eq. 107-117), batched.

Thesis notation: line 1 is ``P_1 = O_c1 + gamma1 p^`` (Eq. 107), line 2 is ``P_2 = O_c2 + gamma2 R p^'`` (Eq. 108);
here ``P_1 = p1 + gamma1 d1`` and ``P_2 = p2 + gamma2 d2``. The segment ``P_1 P_2`` is perpendicular to both lines
(Eq. 109-112); with the four points ``1 = p1``, ``2 = p1 + d1``, ``3 = p2``, ``4 = p2 + d2`` and
``d_mnop = (x_m - x_n)(x_o - x_p) + ...`` (Eq. 115) the solution is Eq. 116-117.

Numerics: Eq. 116's denominator ``d_2121 d_4343 - d_4321^2`` equals ``|d1 x d2|^2`` (Lagrange's identity) and its
numerator equals ``-((p2 - p1) x d2) . (d1 x d2)``; the cross-product forms used here avoid the cancellation of the
printed difference of products, which loses all digits for nearly parallel lines. ``gamma2`` follows from
``gamma1`` by Eq. 117's back-substitution (``P_2`` = the foot of ``P_1`` on line 2), which keeps the segment
perpendicular to both lines to rounding. :func:`closest_points_thesis` keeps the printed formulas for comparison.

Parallel lines: :func:`closest_points_between_lines` never raises for them. It returns a boolean mask ``parallel``
(the sine of the angle between the lines below ``parallel_tol``) and, for those entries, the finite fallback
``gamma1 = 0`` (``P_1 = p1``) and ``P_2`` = the foot of ``p1`` on line 2, so that ``distance`` is the true distance
between the two parallel lines. :func:`midpoint`, meant for single triangulations, raises ``ValueError`` instead.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from bench.geometry.transforms import check_vectors

#: Default threshold on ``sin(angle between the lines)`` under which two lines count as parallel.
PARALLEL_TOL = 1e-9


@dataclass(frozen=True)
class Line:
    """A line ``point + t direction`` in 3D (m), ``direction`` a unit vector (its sign may carry a meaning, e.g.
    the positive sense of a joint's rotation axis)."""

    point: np.ndarray
    direction: np.ndarray


class ClosestPoints(NamedTuple):
    """Result of :func:`closest_points_between_lines`, every field over the batch shape ``(...)``.

    Attributes
    ----------
    p1, p2 : ndarray (..., 3)
        Closest points on line 1 and line 2 (Eq. 107, 108).
    gamma1, gamma2 : ndarray (...)
        Line parameters (Eq. 116, 117), in units of the direction vectors as given.
    distance : ndarray (...)
        ``|p1 - p2|``, the lines' distance.
    parallel : ndarray (...) of bool
        True where the lines are (nearly) parallel; there ``gamma1 = 0`` (see the module notes).
    """

    p1: np.ndarray
    p2: np.ndarray
    gamma1: np.ndarray
    gamma2: np.ndarray
    distance: np.ndarray
    parallel: np.ndarray

    @property
    def midpoint(self) -> np.ndarray:
        """Mid-point of the closest points (the thesis's triangulated point), (..., 3)."""
        return 0.5 * (self.p1 + self.p2)


def _dot(a, b):
    return np.einsum("...i,...i->...", a, b)


def _cross(a, b):
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def closest_points_between_lines(p1, d1, p2, d2, parallel_tol: float = PARALLEL_TOL) -> ClosestPoints:
    """Closest points between lines ``p1 + gamma1 d1`` and ``p2 + gamma2 d2`` (Eq. 107-117), batched.

    Parameters
    ----------
    p1, d1 : array_like (..., 3)
        A point on line 1 (``O_c1``) and its direction (``p^``), any non-zero length.
    p2, d2 : array_like (..., 3)
        A point on line 2 (``O_c2``) and its direction (``R p^'``).
    parallel_tol : float
        Lines whose angle has ``sin < parallel_tol`` are flagged parallel.

    Returns
    -------
    ClosestPoints
        Broadcast over the leading shapes of the inputs.
    """
    p1, d1, p2, d2 = (check_vectors(v, n, 3) for v, n in ((p1, "p1"), (d1, "d1"), (p2, "p2"), (d2, "d2")))
    p1, d1, p2, d2 = np.broadcast_arrays(p1, d1, p2, d2)
    d2121 = _dot(d1, d1)  # |p^|^2 (Eq. 115 with points 1, 2)
    d4343 = _dot(d2, d2)  # |R p^'|^2
    if np.any(d2121 == 0.0):
        raise ValueError("d1: zero-length direction vector")
    if np.any(d4343 == 0.0):
        raise ValueError("d2: zero-length direction vector")
    w = p2 - p1  # = -(O_c1 - O_c2), the d_13.. vector of Eq. 115
    n = _cross(d1, d2)
    nn = _dot(n, n)  # = d2121 d4343 - d4321^2 (denominator of Eq. 116, Lagrange's identity)
    parallel = nn <= (parallel_tol * parallel_tol) * d2121 * d4343
    safe = np.where(parallel, 1.0, nn)
    gamma1 = np.where(parallel, 0.0, _dot(_cross(w, d2), n) / safe)  # Eq. 116
    c1 = p1 + gamma1[..., None] * d1  # Eq. 107
    # Eq. 117 by back-substitution: P_2 is the foot of P_1 on line 2 (parallel lines: the foot of p1). Unlike the
    # independent cross-product formula for gamma2, this keeps the segment perpendicular to both lines to the
    # rounding of the inputs (|P2 - P1| eps) however nearly parallel they are; the independent form was off by
    # |P2 - P1| eps / sin(angle) (found by tests/geometry/test_properties.py).
    gamma2 = _dot(c1 - p2, d2) / d4343
    c2 = p2 + gamma2[..., None] * d2  # Eq. 108
    dist = np.linalg.norm(c1 - c2, axis=-1)
    return ClosestPoints(c1, c2, gamma1, gamma2, dist, parallel)


def midpoint(p1, d1, p2, d2, parallel_tol: float = PARALLEL_TOL) -> np.ndarray:
    """The mid-point of the closest points of two lines (the thesis's triangulated point), (..., 3).

    Raises ``ValueError`` if any pair of lines is parallel (use :func:`closest_points_between_lines` and its
    ``parallel`` mask for batches that may contain some).
    """
    cp = closest_points_between_lines(p1, d1, p2, d2, parallel_tol)
    if np.any(cp.parallel):
        raise ValueError(f"d1, d2: {int(np.count_nonzero(cp.parallel))} pair(s) of lines are parallel; "
                         "the mid-point is undefined")
    return cp.midpoint


def closest_points_thesis(P1, P2, P3, P4):
    """Eq. 113-117 verbatim: line 1 through points 1 and 2, line 2 through points 3 and 4, all (..., 3).

    Returns ``(gamma1, gamma2)``. For reference and tests only: it divides by zero for parallel lines and loses
    precision for nearly parallel ones; use :func:`closest_points_between_lines`.
    """
    pts = {k: check_vectors(v, f"P{k}", 3) for k, v in zip((1, 2, 3, 4), (P1, P2, P3, P4), strict=True)}

    def dmnop(m, n, o, p):  # Eq. 115
        return _dot(pts[m] - pts[n], pts[o] - pts[p])

    d1321, d4321, d1343 = dmnop(1, 3, 2, 1), dmnop(4, 3, 2, 1), dmnop(1, 3, 4, 3)
    d2121, d4343 = dmnop(2, 1, 2, 1), dmnop(4, 3, 4, 3)
    gamma1 = (d1343 * d4321 - d1321 * d4343) / (d2121 * d4343 - d4321 * d4321)  # Eq. 116
    gamma2 = (d1343 + gamma1 * d4321) / d4343  # Eq. 117
    return gamma1, gamma2
