"""A printed calibration target's tolerances, and the error they leave in a calibration (a consider covariance).

A calibration's own covariance (``sigma^2 (J^T J)^-1``) describes the corner noise only. A printed target is not its
drawing: paper bows and cockles out of its plane, printers place lines unevenly and scale the page, a hand-built rig
is not exactly square. These errors are the *same in every view*, so they do not average out: they bias the
intrinsics and, through the target poses, the camera mount found by ``AX = XB``. Given the target's stated
tolerances (the ``tolerance`` mapping of ``target.yaml``, 1-sigma values), this module

* builds the covariance ``(3N, 3N)`` of the target's N corners (:func:`object_point_covariance`), and
* propagates it through the calibration (and the hand-eye step, by a callback) by Monte Carlo: the same detections
  calibrated against perturbed target geometries (:func:`consider_samples`); the spread of the results is the
  covariance a complete prior on the intrinsics and the mount must add (Schmidt's "consider" covariance: the
  parameters are not estimated, their uncertainty is carried).

``tolerance`` keys (all optional, default 0; lengths in mm)::

    flatness_rms_mm: 0.42          # out-of-plane waviness (cockle), a Gaussian field of this rms ...
    flatness_length_mm: [25, 17]   # ... and correlation lengths along the rows, across them
    bow_sagitta_mm: 0.6            # a cylindrical bow across each board (random sign), sagitta
    print_rms_mm: [0.05, 0.09]     # printed line positions: column lines (along x), row lines (along y)
    scale_rms_pct: 0.2             # printout scale
    fold_rms_deg: 0.2              # two-plane rig: second board turned about the fold

Frames: the target (board) frame of :class:`bench.camera.corners.BoardGeometry`; each plane's z points into its
board. Nothing here knows a simulation: the values are what the user states about the physical target.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import numpy as np
from pydantic import Field

from bench.camera.corners import BoardGeometry
from bench.config import Number, Section, parse
from bench.errors import ConfigError


def _at_most(limit):
    return Field(ge=0, le=limit)


class Tolerance(Section):
    """``target.yaml``'s ``tolerance`` mapping (1-sigma values; module docstring); a key left out is 0."""

    flatness_rms_mm: Annotated[float, _at_most(20)] = 0.0
    flatness_length_mm: Annotated[list[Annotated[Number, Field(gt=0, le=1e4)]], Field(min_length=2, max_length=2)] = \
        [25.0, 17.0]
    bow_sagitta_mm: Annotated[float, _at_most(50)] = 0.0
    print_rms_mm: Annotated[list[Annotated[Number, _at_most(20)]], Field(min_length=2, max_length=2)] = [0.0, 0.0]
    scale_rms_pct: Annotated[float, _at_most(10)] = 0.0
    fold_rms_deg: Annotated[float, _at_most(10)] = 0.0


@dataclass(frozen=True)
class TargetTolerance:
    """1-sigma tolerances of a printed target, SI (m, rad, fraction); see the module docstring."""

    flatness_rms: float = 0.0
    flatness_length: tuple = (0.025, 0.017)  # along the rows (plane x), across them (plane y)
    bow_sagitta: float = 0.0
    print_rms: tuple = (0.0, 0.0)  # column lines (x), row lines (y)
    scale_rms: float = 0.0
    fold_rms: float = 0.0

    @property
    def any(self) -> bool:
        return bool(self.flatness_rms or self.bow_sagitta or any(self.print_rms) or self.scale_rms or self.fold_rms)


def parse_tolerance(t, source) -> TargetTolerance:
    """A :class:`TargetTolerance` from the ``tolerance`` mapping (checked by :class:`Tolerance`); one-line
    :class:`ConfigError` naming ``source`` and ``tolerance.<key>`` for an unknown key, a wrong count, a negative,
    non-finite or implausible value."""
    v = parse(Tolerance, t, source, at="tolerance")
    mm, deg = 1e-3, np.pi / 180
    return TargetTolerance(v["flatness_rms_mm"] * mm, tuple(float(x) * mm for x in v["flatness_length_mm"]),
                           v["bow_sagitta_mm"] * mm, tuple(float(x) * mm for x in v["print_rms_mm"]),
                           v["scale_rms_pct"] * 1e-2, v["fold_rms_deg"] * deg)


def object_point_covariance(geometry: BoardGeometry, tol: TargetTolerance) -> np.ndarray:
    """Covariance ``(3N, 3N)`` (m^2) of the target's corners ``geometry.object_points()`` (row-major x, y, z per
    corner) under ``tol``.

    Per plane (pattern of ``(nx + 1) x (ny + 1)`` squares of side ``s``, inner corner ``(i, j)`` at
    ``((i + 1) s, (j + 1) s)`` from the pattern's outer corner): along the plane normal the cockle
    ``rms^2 exp(-dx^2 / 2 Lx^2 - dy^2 / 2 Ly^2)`` plus the bow ``b^2 v v^T`` with ``v = 1 - (2 x / W - 1)^2``; in the
    plane, the corners of one column share its line's offset (``sigma_x^2``), those of one row their row's
    (``sigma_y^2``); the scale ``sigma_s^2 p p^T`` (``p`` the corners from each pattern's outer corner, one scale for
    the printout); the fold turns the second plane about the target's z axis (``sigma_f^2 w w^T``,
    ``w = e_z x X``).
    """
    X = geometry.object_points()
    N = len(X)
    C = np.zeros((3 * N, 3 * N))
    scale_dirs = np.zeros(3 * N)
    for k, (plane, sl) in enumerate(zip(geometry.planes, geometry.plane_slices(), strict=True)):
        R = plane.T_board_plane[:3, :3]
        nx, ny = plane.inner
        s = plane.square
        p = plane.points_plane()  # (n, 3), inner corners from the first inner corner
        x, y = p[:, 0] + s, p[:, 1] + s  # from the pattern's outer corner
        idx = np.arange(sl.start, sl.stop)
        rows3 = (3 * idx[:, None] + np.arange(3)).ravel()
        # the plane's covariance in its own frame, (n, 3, n, 3)
        Cp = np.zeros((len(p), 3, len(p), 3))
        lx, ly = tol.flatness_length
        Cp[:, 2, :, 2] += tol.flatness_rms ** 2 * np.exp(-0.5 * ((x[:, None] - x[None]) / lx) ** 2
                                                         - 0.5 * ((y[:, None] - y[None]) / ly) ** 2)
        v = 1 - (2 * x / ((nx + 1) * s) - 1) ** 2
        Cp[:, 2, :, 2] += tol.bow_sagitta ** 2 * np.outer(v, v)
        Cp[:, 0, :, 0] += tol.print_rms[0] ** 2 * (p[:, None, 0] == p[None, :, 0])
        Cp[:, 1, :, 1] += tol.print_rms[1] ** 2 * (p[:, None, 1] == p[None, :, 1])
        Cp = np.einsum("ab,ibjc,dc->iajd", R, Cp, R).reshape(3 * len(p), 3 * len(p))
        C[np.ix_(rows3, rows3)] += Cp
        scale_dirs[rows3] = (np.c_[x, y, np.zeros(len(p))] @ R.T).ravel()
        if k == 1 and tol.fold_rms:
            w = np.cross([0.0, 0.0, 1.0], X[sl]).ravel()
            full = np.zeros(3 * N)
            full[rows3] = w
            C += tol.fold_rms ** 2 * np.outer(full, full)
    C += tol.scale_rms ** 2 * np.outer(scale_dirs, scale_dirs)
    return C


def sample_factor(C: np.ndarray) -> np.ndarray:
    """``L`` with ``L L^T = C`` for a positive semi-definite ``C``: its symmetric square root ``V sqrt(W) V^T``.

    The corner covariances here are numerically singular (no Cholesky) and have eigenvalues equal to rounding (the
    rig's symmetric layout: the object_point_covariance of the in-situ rig, 216 x 216, has gaps of 1e-18 of the
    largest), so their eigenvectors are any basis of each such subspace: ``V sqrt(W)`` changed by 150 % under a
    1e-15 perturbation of ``C`` and with the number of BLAS threads, and the lab's priors with it (by 7-10 %: 46 or
    47 of 48 draws converged, on other draws). The square root is unique, whatever basis ``eigh`` returns (a
    draw moves by 1e-7 under the same perturbation)."""
    w, V = np.linalg.eigh(C)
    return (V * np.sqrt(np.clip(w, 0.0, None))) @ V.T


def consider_samples(geometry: BoardGeometry, tol: TargetTolerance, Xs, solve, draws: int = 48,
                     rng: np.random.Generator | None = None) -> np.ndarray:
    """Monte Carlo of a calibration over the target's tolerance: ``(draws, p)`` deviations of ``solve``'s result.

    Parameters
    ----------
    geometry : BoardGeometry
        The nominal target.
    tol : TargetTolerance
    Xs : list of ndarray (N_i, 3)
        Each view's object points (rows of ``geometry.object_points()``, m) as the calibration used them.
    solve : callable
        ``solve(Xs_perturbed) -> ndarray (p,)``: the calibration (and what follows it) re-run against a perturbed
        target, returning the parameters' deviation from the nominal result (e.g. ``fx, fy, cx, cy`` and the
        mount's right perturbation), or None when that run fails (the draw is dropped).
    draws : int
    rng : numpy.random.Generator, optional
        Default ``default_rng(0)``: the pipeline's result is reproducible.

    Returns
    -------
    ndarray (M, p)
        The deviations of the ``M <= draws`` runs that succeeded; their second moment about zero is the consider
        covariance.
    """
    rng = np.random.default_rng(0) if rng is None else rng
    X0 = geometry.object_points()
    idx = []
    for X in Xs:
        d = np.linalg.norm(np.asarray(X, float)[:, None] - X0[None], axis=2)
        if np.any(d.min(1) > 1e-9):
            raise ValueError("object points that are not the target's corners")
        idx.append(d.argmin(1))
    L = sample_factor(object_point_covariance(geometry, tol))
    out = []
    for _ in range(draws):
        dX = (L @ rng.standard_normal(L.shape[1])).reshape(-1, 3)
        r = solve([np.asarray(X, float) + dX[i] for X, i in zip(Xs, idx, strict=True)])
        if r is not None:
            out.append(np.asarray(r, float))
    return np.array(out)


#: fewest successful calibrations against the toleranced target for a consider covariance
MIN_CONSIDER_DRAWS = 10


def consider_covariance(geometry: BoardGeometry, tol: TargetTolerance, Xs, solve, draws: int = 48,
                        source="target.yaml") -> tuple:
    """The consider covariance ``(p, p)``: the second moment about zero of :func:`consider_samples`' deviations (the
    nominal result is the centre), and the number of runs behind it. One-line :class:`ConfigError` naming
    ``source`` when fewer than :data:`MIN_CONSIDER_DRAWS` runs succeed (the stated tolerances are implausible)."""
    d = consider_samples(geometry, tol, Xs, solve, draws)
    if len(d) < MIN_CONSIDER_DRAWS:
        raise ConfigError(source, "tolerance", f"only {len(d)} of {draws} calibrations against the toleranced rig "
                                               "converged: the tolerances are implausible")
    return d.T @ d / len(d), len(d)


def calibration_with_tolerance(cal, geometry: BoardGeometry, tol: TargetTolerance, Xs, uvs, draws: int = 48,
                               source="target.yaml") -> tuple:
    """A camera calibration whose covariance carries the target's stated tolerances, not only the pixel noise.

    The calibration's formal covariance (``sigma^2 (J^T J)^-1``) treats the target as exact; a printed rig's errors
    bias every parameter (a paper rig's cockle moves the focal length by percents and the principal point by tens of
    pixels, while the formal standard errors are pixels). This adds the consider covariance of the parameters
    (:func:`consider_covariance`: the same detections calibrated again against targets drawn from ``tol``, each as
    the nominal calibration was, from its own linear initialisation, or from the nominal optimum where that fails).
    ValueError for a failed nominal calibration or fewer than :data:`MIN_CONSIDER_DRAWS` draws.

    Parameters
    ----------
    cal : CalibrationResult
        The calibration (:func:`bench.camera.calibration.calibrate_camera`) of ``Xs``, ``uvs``.
    geometry, tol, Xs, draws, source
        As for :func:`consider_covariance`; ``uvs`` the detections (list of ``(N_i, 2)`` px).

    Returns
    -------
    (CalibrationResult, ndarray (p, p), int)
        The calibration with ``covariance`` = formal + consider (its ``std`` follows), the consider covariance
        alone, and the number of draws behind it.
    """
    from dataclasses import replace

    from bench.camera.calibration import calibrate_camera

    if not cal.success:
        raise ValueError(f"calibration_with_tolerance: the nominal calibration failed ({cal.message})")
    if draws < MIN_CONSIDER_DRAWS:
        raise ValueError(f"draws: expected at least {MIN_CONSIDER_DRAWS} Monte Carlo draws, got {draws}")
    k3, skew = "k3" in cal.parameter_names, "skew" in cal.parameter_names

    def solve(Xs_m):  # each draw calibrated as the nominal one was (its own initialisation and restarts); where
        # that fails - a planar board drawn out of its plane, which the planar initialisation refuses - from the
        # nominal optimum
        c = None
        for initial in (None, (cal.K, cal.dist, cal.T_cam_target)):
            c = calibrate_camera(Xs_m, uvs, cal.image_size, model=cal.model, k3=k3, fit_skew=skew, initial=initial)
            if c.success and list(c.parameter_names) == list(cal.parameter_names):
                return c.parameters - cal.parameters
        return None

    C, n = consider_covariance(geometry, tol, Xs, solve, draws, source)
    cov = cal.covariance + C
    return replace(cal, covariance=0.5 * (cov + cov.T)), C, n
