"""Least-squares plane and circle fits of measured 3D points (thesis section 2.9, Eq. 28-45).

The thesis finds each joint's rotation axis from the arc that a probe traces when that joint alone moves: a plane
through the arc (Eq. 28-31), the arc rotated into that plane (Eq. 32-35), an algebraic circle fit in the plane
(Eq. 36-44) and the circle's centre carried back to 3D (Eq. 45).

Numerical notes (where this module departs from the printed formulas, and why):

* Eq. 29 takes the eigenvector of ``C_a^T C_a`` with raw tracker coordinates. In metres far from the tracker origin
  the column of ones and the coordinate columns differ by orders of magnitude and forming ``C_a^T C_a`` squares the
  condition number, so ``fit_plane(method="normalized")`` (the default) applies the *same* eigenvector formulation to
  centred and scaled points (and takes the singular vector of ``C_a`` itself, which is the eigenvector of
  ``C_a^T C_a`` without forming it); ``method="thesis"`` is Eq. 28-31 verbatim. Both give the same plane on
  noise-free, well-conditioned data (tested). With noise they differ slightly (a small fraction of the fit's own
  spread, tested): Eq. 29 normalises the whole 4-vector ``|v| = 1``, an *algebraic* fit that equals the orthogonal
  (total least squares) plane only when the data are centred, as they are in the normalized method.
* Eq. 33, ``theta_z = atan(b/a)``, loses the quadrant: for ``a < 0`` the rotation of Eq. 34 maps ``z`` onto ``-n``
  mirrored in the xy-plane instead of onto ``n`` (and ``a = 0`` divides by zero). We use ``atan2(b, a)``. Eq. 32's
  ``acos(c)`` loses half the digits near ``c = +-1``; we use ``atan2(hypot(a, b), c)`` (the same angle).
  :func:`plane_rotation` keeps the printed form behind ``quadrant_safe=False`` for comparison.
* Eq. 31 calls ``d_p`` the distance of the plane from the tracker origin; the normal's sign is chosen so that
  ``d_p >= 0`` (the normal points from the plane towards the origin). Then the projected points of Eq. 35 all have
  ``z' = n . x = -d_p``, so Eq. 45's ``[x_r, y_r, d_p]`` is read as ``[x_r, y_r, z']`` with the points' own ``z'``.
* Eq. 39's first row is misprinted ``[2x, 2x, -1]``; it is ``[2x, 2y, -1]`` like the others. Eq. 41 is solved by
  an orthogonal least-squares solver instead of the normal equations (same solution, better conditioned).

All lengths in the unit of the input (metres in the pipeline).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from bench.geometry.transforms import rot_y, rot_z

#: Relative tolerance below which a point set counts as collinear (ratio of its second to its first singular value).
COLLINEAR_RTOL = 1e-9


@dataclass(frozen=True)
class Plane:
    """The plane ``normal . x + d = 0`` (Eq. 28, ``[a_p, b_p, c_p] = normal``, ``d_p = d``).

    Attributes
    ----------
    normal : ndarray (3,)
        Unit normal (Eq. 30), signed so that ``d >= 0``.
    d : float
        Distance of the plane from the origin (Eq. 31), >= 0.
    rms : float
        RMS of the fitted points' distances to the plane.
    """

    normal: np.ndarray
    d: float
    rms: float

    def signed_distance(self, points) -> np.ndarray:
        """Signed distances ``normal . x + d`` of ``points (..., 3)``."""
        return np.asarray(points, dtype=float) @ self.normal + self.d


class Circle2D(NamedTuple):
    """A circle in a plane: ``center (2,)``, ``radius`` and the fit's RMS radial residual ``rms``."""

    center: np.ndarray
    radius: float
    rms: float


@dataclass(frozen=True)
class Circle3D:
    """A circle in space (Eq. 45).

    Attributes
    ----------
    center : ndarray (3,)
        Centre ``c_r``.
    normal : ndarray (3,)
        Unit normal of the circle's plane (sign as in :class:`Plane`).
    radius : float
    rms : float
        RMS over the points of the 3D distance to the circle (out-of-plane and radial parts combined).
    """

    center: np.ndarray
    normal: np.ndarray
    radius: float
    rms: float


def check_points(points, name="points", dim=3, min_points=3) -> np.ndarray:
    """Validate a finite ``(N, dim)`` array with ``N >= min_points``; one-line ``ValueError`` naming ``name``."""
    try:
        p = np.asarray(points, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a numeric (N, {dim}) array") from None
    if p.ndim != 2 or p.shape[1] != dim:
        raise ValueError(f"{name}: expected shape (N, {dim}), got {p.shape}")
    if p.shape[0] < min_points:
        raise ValueError(f"{name}: needs at least {min_points} points, got {p.shape[0]}")
    if not np.all(np.isfinite(p)):
        raise ValueError(f"{name}: contains NaN or inf")
    return p


def _centre_and_scale(p, name):
    """Centroid, RMS distance to it, and the singular values of the centred points; rejects degenerate sets."""
    c = p.mean(axis=0)
    q = p - c
    scale = float(np.sqrt(np.mean(np.sum(q * q, axis=1))))
    if scale == 0.0 or scale <= 1e-14 * max(1.0, float(np.abs(c).max())):
        raise ValueError(f"{name}: all points coincide")
    sv = np.linalg.svd(q / scale, compute_uv=False)
    if sv[1] <= COLLINEAR_RTOL * sv[0]:
        raise ValueError(f"{name}: points are collinear (singular value ratio {sv[1] / sv[0]:.1e})")
    return c, scale


def fit_plane(points, method="normalized", name="points") -> Plane:
    """Least-squares plane through 3D points (Eq. 28-31).

    Parameters
    ----------
    points : array_like (N, 3)
        Measured points, N >= 3, not collinear.
    method : {"normalized", "thesis"}
        ``"thesis"``: the smallest eigenvector of ``C_a^T C_a`` with ``C_a = [x y z 1]`` (Eq. 28-29) on the raw
        coordinates; ``"normalized"``: the same formulation on centred, scaled coordinates (well conditioned).
    name : str
        Argument name used in error messages.

    Returns
    -------
    Plane
    """
    p = check_points(points, name)
    c, scale = _centre_and_scale(p, name)
    if method == "thesis":
        C_a = np.hstack([p, np.ones((len(p), 1))])  # Eq. 28
        _, V = np.linalg.eigh(C_a.T @ C_a)  # Eq. 29: ascending eigenvalues
        v = V[:, 0]
        norm = np.linalg.norm(v[:3])
        normal, d = v[:3] / norm, v[3] / norm  # Eq. 30, 31
    elif method == "normalized":
        C_a = np.hstack([(p - c) / scale, np.ones((len(p), 1))])  # Eq. 28 on centred, scaled points
        v = np.linalg.svd(C_a)[2][-1]  # smallest eigenvector of C_a^T C_a (Eq. 29); full V also for N = 3 < 4
        norm = np.linalg.norm(v[:3])
        normal = v[:3] / norm  # Eq. 30
        d = scale * v[3] / norm - normal @ c  # Eq. 31, mapped back: n.(x - c)/s + d' = 0
    else:
        raise ValueError(f"method: expected 'normalized' or 'thesis', got {method!r}")
    if d < 0:  # Eq. 31 calls d_p a distance: sign the normal so that d_p >= 0
        normal, d = -normal, -d
    rms = float(np.sqrt(np.mean((p @ normal + d) ** 2)))
    return Plane(normal, float(d), rms)


def plane_rotation(normal, quadrant_safe=True) -> np.ndarray:
    """Rotation ``R_p = Rz(theta_z) Ry(theta_y)`` whose third column is the plane normal (Eq. 32-34).

    Parameters
    ----------
    normal : array_like (3,)
        Unit normal ``[a_p, b_p, c_p]``.
    quadrant_safe : bool
        True (default): ``theta_y = atan2(hypot(a, b), c)``, ``theta_z = atan2(b, a)``. False: Eq. 32-33 as printed,
        ``acos(c)`` and ``atan(b / a)``, which for ``a < 0`` yields a rotation whose z-axis is *not* the normal.

    Returns
    -------
    ndarray (3, 3)
    """
    a, b, c = np.asarray(normal, dtype=float).reshape(3)
    if quadrant_safe:
        theta_y = np.arctan2(np.hypot(a, b), c)  # Eq. 32, full precision near c = +-1
        theta_z = np.arctan2(b, a)  # Eq. 33 with the quadrant kept
    else:
        theta_y = np.arccos(np.clip(c, -1.0, 1.0))  # Eq. 32 as printed
        with np.errstate(divide="ignore", invalid="ignore"):
            theta_z = np.arctan(b / a)  # Eq. 33 as printed
    return rot_z(theta_z) @ rot_y(theta_y)  # Eq. 34


def project_to_plane(points, plane: Plane):
    """Coordinates of ``points (N, 3)`` in the plane's frame ``R_p`` (Eq. 35).

    Returns
    -------
    xy : ndarray (N, 2)
        In-plane coordinates.
    z : ndarray (N,)
        Out-of-plane coordinate ``n . x``; equal to ``-plane.d`` for points on the plane.
    R_p : ndarray (3, 3)
        The rotation of Eq. 34 (``x = R_p [x', y', z']``).
    """
    R_p = plane_rotation(plane.normal)
    local = np.asarray(points, dtype=float) @ R_p  # Eq. 35: (R_p^T C_a^T)^T
    return local[:, :2], local[:, 2], R_p


def fit_circle_2d(xy, name="xy") -> Circle2D:
    """Algebraic least-squares circle through 2D points (Eq. 36-44).

    Parameters
    ----------
    xy : array_like (N, 2)
        N >= 3 points, not collinear.
    name : str
        Argument name used in error messages.

    Returns
    -------
    Circle2D
        ``(center (2,), radius, rms)``; ``rms`` is the RMS radial residual.
    """
    p = check_points(xy, name, dim=2)
    mean, scale = _centre_and_scale(p, name)  # Eq. 36
    t = (p - mean) / scale  # Eq. 37-38 (plus a scale for conditioning)
    C_t = np.column_stack([2 * t[:, 0], 2 * t[:, 1], -np.ones(len(t))])  # Eq. 39
    b_t = np.sum(t * t, axis=1)  # Eq. 40
    u, _, rank, _ = np.linalg.lstsq(C_t, b_t, rcond=None)  # Eq. 41
    if rank < 3:
        raise ValueError(f"{name}: points are collinear; no circle")
    r2 = u[0] ** 2 + u[1] ** 2 - u[2]  # Eq. 44 squared
    if not r2 > 0:
        raise ValueError(f"{name}: degenerate circle fit (radius^2 = {r2:.3g})")
    center = mean + scale * u[:2]  # Eq. 42-43, translated and scaled back
    radius = float(scale * np.sqrt(r2))  # Eq. 44
    rms = float(np.sqrt(np.mean((np.linalg.norm(p - center, axis=1) - radius) ** 2)))
    return Circle2D(center, radius, rms)


def fit_circle_3d(points, name="points", plane_method="normalized") -> Circle3D:
    """Circle through 3D points: plane (Eq. 28-31), projection (Eq. 32-35), 2D circle (Eq. 36-44), Eq. 45.

    Parameters
    ----------
    points : array_like (N, 3)
        N >= 3 points of an arc, not collinear.
    name : str
        Argument name used in error messages.
    plane_method : {"normalized", "thesis"}
        See :func:`fit_plane`.

    Returns
    -------
    Circle3D
    """
    p = check_points(points, name)
    plane = fit_plane(p, plane_method, name)
    xy, z, R_p = project_to_plane(p, plane)
    c2 = fit_circle_2d(xy, name)
    center = R_p @ np.array([c2.center[0], c2.center[1], z.mean()])  # Eq. 45 (z' = n.x = -d_p, see module notes)
    radial = np.linalg.norm(xy - c2.center, axis=1) - c2.radius
    rms = float(np.sqrt(np.mean(radial**2 + (z - z.mean()) ** 2)))
    return Circle3D(center, plane.normal.copy(), c2.radius, rms)
