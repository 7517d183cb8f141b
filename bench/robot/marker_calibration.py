"""Calibrate any serial arm from its URDF and measured marker points (``bench calibrate-robot --urdf ...``).

Measurement model. Marker ``j`` sits at an unknown offset ``u_j`` (m) on the tip link; a measurement system (motion
capture, laser tracker) reports it in its own frame ``meas``, whose pose relative to the robot base is unknown::

    m_ij = T_meas_base  T_base_tip(q_i; eps)  u_j          (T_base_tip: Eq. 10 in URDF form, bench.robot.chain)

Unknowns: ``T_meas_base`` (6), the offsets ``u_j`` (3 per marker) and the generalized errors ``eps`` (6 per joint
frame). Several markers on one plate also give the tip's orientation (their geometry ``u_j`` is estimated).

Steps
1. Closed-form start (:func:`closed_form_start`): with the nominal chain, ``m_ij = R (t_i + R_i u_j) + t`` is linear
   in ``R`` (9 entries), ``t`` and the products ``R_ab u_jc`` (27 per marker); a linear least squares, the nearest
   rotation to ``R`` and the offsets read from the products. No initial guess: it holds for any rotation.
2. Identifiability (:func:`identifiable_errors`): the stacked Jacobian at random configurations within the limits;
   the error columns that the measurement frame and marker offsets explain are projected out, and the remaining
   columns reduced to an independent set (:func:`bench.robot.identifiability.select_columns`, the numeric analysis
   of §2.5-2.7): the "kept" errors; the others are merged (fixed at zero).
3. Iterative identification (:func:`identify`): ``scipy.optimize.least_squares`` on the exact model with the
   analytic Jacobian, weighted per posture when standard deviations are given. ``model="reduced"`` estimates the
   kept errors (hard elimination, as the thesis and FIGAROH do); ``model="prior"`` estimates all ``6 (n + 1)``
   errors with a zero-mean Gaussian prior of the thesis's scale (+-2 mm, +-1 deg: standard deviations 2 mm and
   1 deg), which fixes the unidentifiable combinations at their smallest size instead of deleting columns.
4. Outliers: postures whose residual exceeds ``OUTLIER_K`` times the robust (median-based) residual scale are
   reported; with ``refuse_outliers`` they are removed, named, and the fit repeated.
"""

from __future__ import annotations

import csv
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.optimize

from bench.errors import BenchError, ConfigError
from bench.fileio import read_yaml
from bench.geometry.quaternion import rotation_vector_jacobian, rotation_vector_to_matrix
from bench.geometry.transforms import homogeneous, skew
from bench.robot.chain import SerialChain, gravity_torques, joint_jacobian, points_and_jacobian
from bench.robot.identifiability import select_columns
from bench.robot.model import error_names

#: Prior standard deviations of a generalized error (the thesis's simulated scale, §4.6): 2 mm and 1 deg.
PRIOR_TRANS_M = 2e-3
PRIOR_ROT_RAD = np.deg2rad(1.0)
#: A posture is an outlier when its residual exceeds this many robust residual scales (1.4826 MAD of the norms).
OUTLIER_K = 4.0
MODELS = ("reduced", "prior")
#: A calibration whose residual RMS exceeds this fraction of the arm's reach is refused (wrong units or links).
MAX_RMS_OF_REACH = 0.02
LENGTH_UNITS = {"m": 1.0, "mm": 1e-3}
LSQ_METHOD = "lm"  # MINPACK: the same minimum as "trf" here, ~2x faster on a loaded machine
ANGLE_UNITS = {"rad": 1.0, "deg": np.pi / 180}


# ------------------------------------------------------------------------------------------------ measurements


@dataclass
class Measurements:
    """Marker measurements in SI units.

    Attributes
    ----------
    q : ndarray (m, n)
        Joint readings (rad, m for prismatic).
    P : ndarray (m, k, 3)
        Marker points in the measurement frame (m).
    labels : list of str
        One per posture (the CSV's line numbers, ``line 2`` ...).
    markers : list of tuple of str
        The CSV columns of each marker.
    sigma : ndarray (m,) or None
        Per-posture standard deviation of a coordinate (m), from ``marker_std_mm`` when present.
    """

    q: np.ndarray
    P: np.ndarray
    labels: list
    markers: list
    sigma: np.ndarray | None = None

    def subset(self, idx) -> Measurements:
        idx = np.asarray(idx)
        return Measurements(self.q[idx], self.P[idx], [self.labels[i] for i in idx], self.markers,
                            None if self.sigma is None else self.sigma[idx])


def parse_points(specs) -> list:
    """``["x1,y1,z1", ...]`` -> ``[("x1", "y1", "z1"), ...]``; one-line error for a malformed ``--points``."""
    out = []
    for s in specs:
        cols = tuple(c.strip() for c in str(s).split(","))
        if len(cols) != 3 or not all(cols):
            raise BenchError(f"--points {s!r}: expected three column names x,y,z (e.g. x1,y1,z1)")
        out.append(cols)
    if not out:
        raise BenchError("--points: give at least one marker (three column names x,y,z)")
    if len({c for m in out for c in m}) != 3 * len(out):
        raise BenchError(f"--points: a column is named twice in {specs}")
    return out


def read_measurements(path, chain: SerialChain, markers, units: str = "m", joint_units: str = "rad",
                      std_column: str | None = "marker_std_mm") -> Measurements:
    """Read a measurement CSV: one row per posture, the joint readings under the URDF's joint names, the markers'
    coordinates under the ``markers`` columns; other columns are ignored.

    ``units`` is the unit of the marker coordinates and of prismatic readings; ``joint_units`` of revolute ones.
    ``std_column`` (mm) gives per-posture weights when present. Every problem is a one-line :class:`ConfigError`
    naming the file, the column or line and the value.
    """
    path = Path(path)
    if units not in LENGTH_UNITS:
        raise BenchError(f"--units: expected one of {tuple(LENGTH_UNITS)}, got {units!r}")
    if joint_units not in ANGLE_UNITS:
        raise BenchError(f"--joint-units: expected one of {tuple(ANGLE_UNITS)}, got {joint_units!r}")
    if not path.is_file():
        raise ConfigError(path, "<file>", "not found")
    try:
        lines = [ln for ln in path.read_text().splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    except UnicodeDecodeError:
        raise ConfigError(path, "<file>", "not a text CSV file") from None
    if not lines:
        raise ConfigError(path, "<file>", "empty")
    reader = csv.reader(lines)
    header = [h.strip() for h in next(reader)]
    missing = [j for j in chain.joint_names if j not in header]
    if missing:
        raise ConfigError(path, "<header>", f"no column for joint{'s' if len(missing) > 1 else ''} "
                                            f"{', '.join(missing)} (the URDF's joint names between "
                                            f"{chain.base_link} and {chain.tip_link})")
    missing = [c for m in markers for c in m if c not in header]
    if missing:
        raise ConfigError(path, "<header>", f"no column {', '.join(missing)} (given by --points)")
    jcol = [header.index(j) for j in chain.joint_names]
    pcol = [[header.index(c) for c in m] for m in markers]
    scol = header.index(std_column) if std_column and std_column in header else None
    q, P, labels, sig = [], [], [], []
    for lineno, row in enumerate(reader, start=2):
        if len(row) != len(header):
            raise ConfigError(path, f"line {lineno}", f"{len(row)} values for the {len(header)} columns of the header")

        def num(c, lineno=lineno, row=row):
            try:
                v = float(row[c])
            except ValueError:
                raise ConfigError(path, f"line {lineno}, column {header[c]}", f"not a number: {row[c]!r}") from None
            if not np.isfinite(v):
                raise ConfigError(path, f"line {lineno}, column {header[c]}", f"not finite: {row[c]!r}")
            return v

        q.append([num(c) for c in jcol])
        P.append([[num(c) for c in m] for m in pcol])
        labels.append(f"line {lineno}")
        if scol is not None:
            sig.append(num(scol))
    if not q:
        raise ConfigError(path, "<file>", "no data rows")
    q = np.array(q)
    P = np.array(P) * LENGTH_UNITS[units]
    for k, t in enumerate(chain.joint_types):
        q[:, k] *= LENGTH_UNITS[units] if t == "prismatic" else ANGLE_UNITS[joint_units]
    _check_units(path, chain, q, P, units, joint_units)
    sigma = None
    if scol is not None:
        sigma = np.array(sig) * 1e-3
        if np.any(sigma <= 0):
            bad = int(np.argmin(sigma))
            raise ConfigError(path, f"{labels[bad]}, column {std_column}", f"must be > 0 mm, got {sig[bad]}")
    return Measurements(q, P, labels, [tuple(m) for m in markers], sigma)


def _check_units(path, chain, q, P, units, joint_units) -> None:
    """Plausibility of the declared units against the chain (one-line :class:`ConfigError` with the likely cause)."""
    reach = chain.reach
    spread = float(np.sqrt(np.mean(np.sum((P - P.mean(axis=0)) ** 2, axis=-1))))
    if spread > 20 * reach:
        raise ConfigError(path, "--units", f"the markers spread over {spread:.4g} m for an arm reaching {reach:.3g} m "
                                           f"(--units {units}): mm given as m?")
    if spread < reach / 200:
        raise ConfigError(path, "--units", f"the markers spread over {spread:.3g} m for an arm reaching {reach:.3g} m "
                                           f"(--units {units}): m given as mm, or the arm did not move?")
    rev = [k for k, t in enumerate(chain.joint_types) if t == "revolute"]
    if joint_units == "deg" and rev and np.abs(q[:, rev]).max() < np.deg2rad(2 * np.pi) and \
            max(chain.q_max[k] - chain.q_min[k] for k in rev) > np.deg2rad(30):
        raise ConfigError(path, "--joint-units", f"every revolute reading lies within +-{2 * np.pi:.3g} deg for "
                                                 "joints that move much further: radians given as degrees?")
    for k, t in enumerate(chain.joint_types):
        lo, hi = chain.q_min[k], chain.q_max[k]
        width = hi - lo
        out = (q[:, k] < lo - 0.1 * width - 1e-3) | (q[:, k] > hi + 0.1 * width + 1e-3)
        if np.any(out):
            i = int(np.argmax(out))
            u = units if t == "prismatic" else joint_units
            scale = LENGTH_UNITS[units] if t == "prismatic" else ANGLE_UNITS[joint_units]
            raise ConfigError(path, f"line {i + 2}, column {chain.joint_names[k]}",
                              f"{q[i, k] / scale:.6g} {u} is outside the joint's limits [{lo / scale:.4g}, "
                              f"{hi / scale:.4g}] {u}: wrong {'--units' if t == 'prismatic' else '--joint-units'}?")


# ------------------------------------------------------------------------------------------------ model


def compliant_q(chain, q, compliance=None):
    """Joint positions under gravity: ``q + c_j tau_j(q)`` for the joints of ``compliance = {name: c}`` (rad per
    N m, m per N; ``tau``: :func:`bench.robot.chain.gravity_torques`)."""
    if not compliance:
        return q
    idx = [chain.joint_names.index(n) for n in compliance]
    q = np.array(q, dtype=float)
    q[..., idx] += gravity_torques(chain, q)[..., idx] * np.array(list(compliance.values()))
    return q


def predict(chain, q, eps, T_meas_base, U, compliance=None):
    """Marker points in the measurement frame, (m, k, 3) (m); ``compliance`` as :func:`compliant_q`."""
    p, _, _ = points_and_jacobian(chain, compliant_q(chain, q, compliance), U, eps)
    return p @ T_meas_base[:3, :3].T + T_meas_base[:3, 3]


def closed_form_start(chain: SerialChain, q, P):
    """``(T_meas_base, U)`` from the nominal chain by the linear method of the module docstring (any rotation).

    ``P (m, k, 3)``; needs ``3 m k >= 12 + 27 k`` equations. The nonlinear fit refines the result.
    """
    m, k, _ = P.shape
    if 3 * m * k < 12 + 27 * k + 3:
        raise BenchError(f"{m} postures are too few for the closed-form start with {k} marker(s): need at least "
                         f"{int(np.ceil((15 + 27 * k) / (3 * k)))}")
    T = points_and_jacobian(chain, q, np.zeros((1, 3)))[2]
    Rt, tt = T[:, :3, :3], T[:, :3, 3]
    scale = max(float(np.abs(tt).max()), 1e-3)
    n_unk = 12 + 27 * k
    A = np.zeros((m, k, 3, n_unk))
    for a in range(3):
        A[:, :, a, 3 * a: 3 * a + 3] = tt[:, None, :] / scale  # R[a, :] . t_i   (scaled)
        A[:, :, a, 9 + a] = 1.0 / scale  # t[a]
        for j in range(k):
            # (R R_i u_j)_a = sum_bc R_ab (R_i)_bc u_jc = sum_bc (R_i)_bc Y_jabc
            A[:, j, a, 12 + 27 * j + 9 * a: 12 + 27 * j + 9 * a + 9] = Rt.reshape(m, 9) / scale
    x, *_ = np.linalg.lstsq(A.reshape(-1, n_unk), (P / scale).reshape(-1), rcond=None)
    Rraw = x[:9].reshape(3, 3)
    Uu, _, Vt = np.linalg.svd(Rraw)
    R = Uu @ np.diag([1.0, 1.0, np.linalg.det(Uu @ Vt)]) @ Vt
    t = x[9:12]  # the columns of t were divided by scale, so x holds t itself
    U = np.empty((k, 3))
    for j in range(k):
        Y = x[12 + 27 * j: 12 + 27 * (j + 1)].reshape(3, 3, 3)  # Y[a, b, c] = R_ab u_c
        U[j] = np.einsum("ab,abc->c", R, Y) / 3.0  # sum_ab R_ab R_ab u_c = 3 u_c
    # the start is refined with the nominal chain (frame and offsets only): robust to the linear step's noise
    T0 = homogeneous(R, t)
    T0, U, _ = _solve(chain, q, P, None, T0, U, np.zeros(0, dtype=int), None, prior=None)[:3]
    return T0, U


def _solve(chain, q, P, w, T0, U0, kept, eps0, prior, max_nfev=200, tau=None, c0=None):
    """least_squares over (frame, offsets, eps[kept], compliances); ``prior`` = per-parameter prior std (len
    n_errors) or None; ``tau (m, n_c)`` the gravity loads of the compliant joints (columns of ``c0``'s joints)."""
    m, k, _ = P.shape
    comp = None if tau is None else np.asarray(c0[0], dtype=int)
    n_c = 0 if comp is None else len(comp)
    n_e = chain.n_errors
    cols = np.asarray(kept, dtype=int)
    w = np.ones(m) if w is None else np.asarray(w, dtype=float)
    R0 = T0[:3, :3]
    eps_base = np.zeros(n_e) if eps0 is None else np.asarray(eps0, dtype=float).copy()

    n_x = 6 + 3 * k + len(cols)

    def unpack(x):
        R, Jl = rotation_vector_to_matrix(x[:3]), rotation_vector_jacobian(x[:3])  # d(R v) = -[R v]x Jl dphi
        eps = eps_base.copy()
        eps[cols] = x[6 + 3 * k: n_x]
        return R @ R0, x[3:6], x[6: 6 + 3 * k].reshape(k, 3), eps, Jl

    def q_eff(x):
        if comp is None:
            return q
        qe = q.copy()
        qe[:, comp] += tau * x[n_x:]
        return qe

    def fun_jac(x):
        R, t, U, eps, Jl = unpack(x)
        qe = q_eff(x)
        p, Je, T = points_and_jacobian(chain, qe, U, eps)
        pm = p @ R.T + t
        r = ((pm - P) * w[:, None, None]).reshape(-1)
        J = np.zeros((m, k, 3, n_x + n_c))
        J[..., :3] = -skew(pm - t) @ Jl  # d(Exp(phi) R0 p)/dphi
        J[..., 3:6] = np.eye(3)
        RRt = R @ T[:, :3, :3]  # (m, 3, 3)
        for j in range(k):
            J[:, j, :, 6 + 3 * j: 9 + 3 * j] = RRt
        J[..., 6 + 3 * k: n_x] = np.einsum("ab,mkbc->mkac", R, Je[..., cols])
        if comp is not None:
            Jq = joint_jacobian(chain, qe, U, eps)[..., comp] * tau[:, None, None, :]
            J[..., n_x:] = np.einsum("ab,mkbc->mkac", R, Jq)
        J = (J * w[:, None, None, None]).reshape(-1, J.shape[-1])
        if prior is not None:
            pr = 1.0 / prior[cols]
            r = np.concatenate([r, eps[cols] * pr])
            Jp = np.zeros((len(cols), J.shape[1]))
            Jp[np.arange(len(cols)), 6 + 3 * k + np.arange(len(cols))] = pr
            J = np.vstack([J, Jp])
        return r, J

    cache = {}

    def fun(x):
        cache["x"] = x.copy()
        cache["rj"] = fun_jac(x)
        return cache["rj"][0]

    def jac(x):
        if "x" not in cache or not np.array_equal(cache["x"], x):
            fun(x)
        return cache["rj"][1]

    x0 = np.concatenate([np.zeros(3), T0[:3, 3], np.asarray(U0, float).reshape(-1), eps_base[cols],
                         np.zeros(n_c) if comp is None else np.asarray(c0[1], float)])
    res = scipy.optimize.least_squares(fun, x0, jac=jac, method=LSQ_METHOD, x_scale="jac", xtol=1e-15, ftol=1e-15,
                                       gtol=1e-15, max_nfev=max_nfev)
    R, t, U, eps, _ = unpack(res.x)
    _, J = fun_jac(res.x)
    res.compliance = res.x[n_x:]
    return homogeneous(R, t), U, eps, res, J


def _prior_std(chain: SerialChain) -> np.ndarray:
    return np.tile([PRIOR_TRANS_M] * 3 + [PRIOR_ROT_RAD] * 3, chain.n + 1)


def identifiable_errors(chain: SerialChain, U, T_meas_base=None, rng=None, n_poses: int = 80,
                        rel_tol: float = 1e-9):
    """Kept (identifiable) error indices and the merge map for points ``U (k, 3)`` on the tip, with the measurement
    frame and the offsets estimated alongside (their columns projected out first).

    Returns ``(kept, merged)``: ``merged`` maps every eliminated error name to ``{kept name: coefficient}`` plus
    ``"frame/markers"`` when the measurement frame or the offsets absorb it (first order).
    """
    rng = np.random.default_rng(0) if rng is None else rng
    q = chain.random_configurations(rng, n_poses)
    U = np.asarray(U, float).reshape(-1, 3)
    p, Je, T = points_and_jacobian(chain, q, U)
    k = len(U)
    Jn = np.zeros((n_poses, k, 3, 6 + 3 * k))
    Jn[..., :3] = -skew(p)
    Jn[..., 3:6] = np.eye(3)
    for j in range(k):
        Jn[:, j, :, 6 + 3 * j: 9 + 3 * j] = T[:, :3, :3]
    Jn = Jn.reshape(-1, 6 + 3 * k)
    Je = Je.reshape(-1, chain.n_errors)
    reach = max(chain.reach, 1e-3)
    scale = np.tile([1.0, 1.0, 1.0, reach, reach, reach], chain.n + 1)
    Qn, _ = np.linalg.qr(Jn)
    Jp = Je - Qn @ (Qn.T @ Je)  # what the frame and the offsets cannot explain
    Js = Jp / scale
    smax = np.linalg.svd(Je / scale, compute_uv=False)[0]
    Js[:, np.linalg.norm(Js, axis=0) < 1e-9 * smax * np.sqrt(Js.shape[0])] = 0.0
    kept, _, _ = select_columns(Js, None, rel_tol, n_poses)
    names = error_names(chain.n + 1)
    dropped = np.setdiff1d(np.arange(chain.n_errors), kept)
    C, *_ = np.linalg.lstsq(Jp[:, kept], Jp[:, dropped], rcond=None)
    merged = {}
    for c, j in enumerate(dropped):
        coef = {names[kk]: float(C[r, c]) for r, kk in enumerate(kept) if abs(C[r, c]) > 1e-9}
        if np.linalg.norm(Je[:, j] - Jp[:, j]) > 1e-9 * np.linalg.norm(Je[:, j]):
            coef["frame/markers"] = 1.0
        merged[names[j]] = coef
    return kept, merged


@dataclass
class MarkerCalibration:
    """Result of :func:`identify` (SI units)."""

    chain: SerialChain
    markers: list
    model: str
    eps: np.ndarray
    T_meas_base: np.ndarray
    U: np.ndarray
    kept: np.ndarray
    merged: dict
    covariance: np.ndarray
    residuals: np.ndarray  # (m, k) norms, m
    labels: list
    outliers: list = field(default_factory=list)
    refused: list = field(default_factory=list)
    nominal_residuals: np.ndarray | None = None
    message: str = ""
    timings_s: dict = field(default_factory=dict)
    cost: float = float("nan")
    refused_errors: dict = field(default_factory=dict)  # label -> RMS residual (m) of a refused posture
    compliance: dict = field(default_factory=dict)  # joint name -> rad per N m (m per N if prismatic)

    @property
    def rms_m(self) -> float:
        return float(np.sqrt(np.mean(self.residuals**2)))

    def predicted_error(self, q) -> np.ndarray:
        """Standard deviation (m, 3D) of the predicted marker positions at ``q (h, n)`` from the estimate's
        covariance (frame, offsets and errors): the bound a held-out check should meet."""
        k = len(self.U)
        if self.compliance:
            raise ValueError("predicted_error: not available with compliance (a non-geometric model)")
        p, Je, T = points_and_jacobian(self.chain, q, self.U, self.eps)
        R = self.T_meas_base[:3, :3]
        pm = p @ R.T + self.T_meas_base[:3, 3]
        cols = self.kept if self.model == "reduced" else np.arange(self.chain.n_errors)
        J = np.zeros(p.shape[:2] + (3, 6 + 3 * k + len(cols)))
        J[..., :3] = -skew(pm - self.T_meas_base[:3, 3])
        J[..., 3:6] = np.eye(3)
        for j in range(k):
            J[:, j, :, 6 + 3 * j: 9 + 3 * j] = R @ T[:, :3, :3]
        J[..., 6 + 3 * k:] = np.einsum("ab,mkbc->mkac", R, Je[..., cols])
        var = np.einsum("mkai,ij,mkaj->mk", J, self.covariance, J)
        return np.sqrt(var)


def identify(chain: SerialChain, meas: Measurements, model: str = "reduced", weights: str = "auto",
             sigma_m: float | None = None, refuse_outliers: bool = False, rng=None,
             prior_scale: float = 1.0, compliance: bool = False, nominal_offsets=None) -> MarkerCalibration:
    """Closed-form start, identifiability, iterative identification and outlier screening (module docstring).

    Parameters
    ----------
    model : {"reduced", "prior"}
    weights : {"auto", "none"}
        ``auto``: per-posture weights ``1 / sigma_i`` from the file's standard deviations when given; ``none``: equal.
    sigma_m : float, optional
        Standard deviation of a coordinate (m) for the covariance; default the residuals' (a-posteriori).
    prior_scale : float
        Multiplies the prior's standard deviations (``model="prior"``).
    nominal_offsets : ndarray (k, 3), optional
        Marker offsets (m) known by design, at which the identifiability is analysed (default: the closed-form
        start's estimate). A point by design on a joint axis (the TA-40's O6) has fewer identifiable errors than
        one a millimetre off it; the design decides, not the estimate.
    compliance : bool
        Also estimate a compliance per revolute joint that gravity loads (``q + c tau(q)``; the loads from the URDF's
        inertials, the base z-up): joint elasticity, the largest non-geometric error of light arms.
    """
    if model not in MODELS:
        raise BenchError(f"--model: expected one of {MODELS}, got {model!r}")
    t0 = time.perf_counter()
    q, P = meas.q, meas.P
    m, k, _ = P.shape
    T0, U0 = closed_form_start(chain, q, P)
    t_start = time.perf_counter() - t0
    kept, merged = identifiable_errors(chain, U0 if nominal_offsets is None else nominal_offsets, T0, rng)
    cols = kept if model == "reduced" else np.arange(chain.n_errors)
    n_par = 6 + 3 * k + len(kept)
    if 3 * m * k <= n_par:
        raise BenchError(f"{m} postures give {3 * m * k} equations for {n_par} unknowns (frame 6, offsets {3 * k}, "
                         f"errors {len(kept)}): measure more postures")
    w = None
    if weights == "auto" and meas.sigma is not None:
        w = np.median(meas.sigma) / meas.sigma
    elif weights not in ("auto", "none"):
        raise BenchError(f"--weights: expected auto or none, got {weights!r}")
    prior = _prior_std(chain) if model == "prior" else None
    comp_idx = np.zeros(0, dtype=int)
    if compliance:
        if chain.body_mass is None:
            raise BenchError("--compliance: the URDF has no <inertial> masses on the chain (no gravity loads)")
        tau_all = gravity_torques(chain, q)
        rms_tau = np.sqrt(np.mean(tau_all**2, axis=0))
        rev = np.array([t == "revolute" for t in chain.joint_types])
        comp_idx = np.flatnonzero(rev & (rms_tau > 1e-2 * rms_tau[rev].max()))
        n_par += len(comp_idx)
    labels = list(meas.labels)
    idx = np.arange(m)
    refused, outliers = [], []
    nominal = np.linalg.norm(predict(chain, q, None, T0, U0) - P, axis=-1)
    for _ in range(3):
        ww = None if w is None else w[idx]
        extra = {"tau": tau_all[idx][:, comp_idx], "c0": (comp_idx, np.zeros(len(comp_idx)))} if len(comp_idx) else {}
        scale_prior = None
        if prior is not None:  # the prior is relative to the data's noise: sigma from a first unregularised pass
            T1, U1, e1, r1, _ = _solve(chain, q[idx], P[idx], ww, T0, U0, kept, None, None, **extra)
            s_hat = np.sqrt(2 * r1.cost / max(r1.fun.size - n_par, 1))
            scale_prior = prior_scale * prior / s_hat
        T, U, eps, res, J = _solve(chain, q[idx], P[idx], ww, T0, U0, cols, None, scale_prior, **extra)
        comp = {chain.joint_names[j]: float(c) for j, c in zip(comp_idx, res.compliance, strict=True)}
        resid = np.linalg.norm(predict(chain, q[idx], eps, T, U, comp) - P[idx], axis=-1)
        per = np.sqrt(np.mean(resid**2, axis=1))
        robust = 1.4826 * np.median(np.abs(per - np.median(per))) + np.median(per)
        bad = per > OUTLIER_K * robust
        outliers = [labels[i] for i in idx[bad]]
        if not (refuse_outliers and bad.any()):
            break
        refused += outliers
        idx = idx[~bad]
    dof = res.fun.size - n_par if prior is None else 3 * len(idx) * k - n_par
    s2 = sigma_m**2 if sigma_m is not None else 2 * res.cost / max(dof, 1)
    cov = np.linalg.pinv(J.T @ J) * s2
    # with weights (median 1) s2 is the variance of a coordinate at the median posture's standard deviation
    if np.sqrt(np.mean(resid**2)) > MAX_RMS_OF_REACH * chain.reach:
        raise BenchError(f"the calibrated model misses the markers by {np.sqrt(np.mean(resid**2)) * 1e3:.4g} mm RMS "
                         f"(the arm reaches {chain.reach:.3g} m): wrong --units / --joint-units, wrong "
                         "--base-link / --tip-link, or markers not on the tip link?")
    full_resid = np.linalg.norm(predict(chain, q, eps, T, U, comp) - P, axis=-1)
    msg = f"least squares ({model}): {res.message}"
    refused_err = {lbl: float(np.sqrt(np.mean(full_resid[i] ** 2))) for i, lbl in enumerate(labels) if lbl in refused}
    return MarkerCalibration(chain, list(meas.markers), model, eps, T, U, kept, merged, cov, full_resid[idx],
                             [labels[i] for i in idx], outliers, refused, nominal[idx], msg,
                             {"closed_form_start_s": t_start, "calibration_s": time.perf_counter() - t0},
                             float(res.cost), refused_err, comp)


# ------------------------------------------------------------------------------------------------ files

FORMAT = "bench-urdf-calibration/1"


def _err_key(name: str) -> str:
    return f"{name}_mm" if name[0] in "xyz" else f"{name}_rad"


def write_calibration(out, cal: MarkerCalibration, urdf_path, units: str, joint_units: str,
                      measurements_path) -> tuple:
    """Write ``out/robot.yaml`` (the nominal chain, the identified errors, the measurement frame, the marker offsets)
    and ``out/calibration.json``; returns both paths."""
    import hashlib
    import json

    import yaml

    from bench.fileio import atomic_write_text
    from bench.geometry.quaternion import matrix_to_quaternion
    from bench.robot.chain import chain_to_dict

    out = Path(out)
    names = error_names(cal.chain.n + 1)
    urdf_path = Path(urdf_path)
    robot = {
        "format": FORMAT,
        "name": cal.chain.name,
        "source": {"urdf": str(urdf_path.resolve()), "urdf_sha256": hashlib.sha256(urdf_path.read_bytes()).hexdigest()},
        "frames": {"note": "error frame k sits in joint k+1's frame before its motion; the last one on the tip link",
                   "joints": list(cal.chain.joint_names)},
        "chain": chain_to_dict(cal.chain),
        "calibration": {
            "model": cal.model,
            "errors": {_err_key(n): float(v * (1e3 if n[0] in "xyz" else 1.0))
                       for n, v in zip(names, cal.eps, strict=True)},
            "T_meas_base": {"translation_mm": [float(v) for v in cal.T_meas_base[:3, 3] * 1e3],
                            "quaternion_wxyz": [float(v) for v in matrix_to_quaternion(cal.T_meas_base[:3, :3])]},
            "markers": [{"columns": list(c), "offset_mm": [float(v) for v in u * 1e3]}
                        for c, u in zip(cal.markers, cal.U, strict=True)],
            "units": {"points": units, "joints": joint_units},
        },
    }
    if cal.compliance:  # q + c tau(q): tau from the chain's body masses, gravity -z of the base (URDF z-up)
        robot["calibration"]["compliance"] = {
            n: {("m_per_n" if cal.chain.joint_types[cal.chain.joint_names.index(n)] == "prismatic"
                 else "rad_per_nm"): float(c)} for n, c in cal.compliance.items()}
    atomic_write_text(out / "robot.yaml", yaml.safe_dump(robot, sort_keys=False))
    k = len(cal.U)
    cols = cal.kept if cal.model == "reduced" else np.arange(cal.chain.n_errors)
    par_names = ([f"T_meas_base.rot_{a}_rad" for a in "xyz"] + [f"T_meas_base.{a}_mm" for a in "xyz"]
                 + [f"marker{j + 1}.{a}_mm" for j in range(k) for a in "xyz"] + [_err_key(names[c]) for c in cols]
                 + [f"compliance.{n}_rad_per_nm" for n in cal.compliance])
    std = np.sqrt(np.diag(cal.covariance))
    n_e = 6 + 3 * k + len(cols)
    std_u = np.concatenate([std[:3], std[3:6] * 1e3, std[6: 6 + 3 * k] * 1e3,
                            [s * (1e3 if names[c][0] in "xyz" else 1.0) for s, c in zip(std[6 + 3 * k: n_e], cols,
                                                                                     strict=True)], std[n_e:]])
    per = np.sqrt(np.mean(cal.residuals**2, axis=1))
    report = {
        "method": ("closed-form start (linear in R, t and R u) + least squares on the exact model (Eq. 10, URDF "
                   f"form); model {cal.model!r}: " + ("the numerically identifiable errors" if cal.model == "reduced"
                                                      else "all errors with a 2 mm / 1 deg Gaussian prior")
                   + ("; joint compliance under gravity" if cal.compliance else "")),
        "urdf": str(urdf_path), "measurements": str(measurements_path), "message": cal.message,
        "rms_mm": cal.rms_m * 1e3, "max_mm": float(cal.residuals.max() * 1e3),
        "rms_first_marker_mm": float(np.sqrt(np.mean(cal.residuals[:, 0] ** 2)) * 1e3),
        "rms_nominal_mm": float(np.sqrt(np.mean(cal.nominal_residuals**2)) * 1e3),
        "n_postures": int(len(cal.residuals)), "n_markers": int(k),
        "n_parameters": int(len(par_names)), "n_error_parameters": int(len(cols)),
        "kept": [names[c] for c in cal.kept], "merged": cal.merged,
        "parameters": [{"name": n, "std": float(s)} for n, s in zip(par_names, std_u, strict=True)],
        "covariance_parameters": par_names,
        "covariance_units": "SI: rad for rotations, m for translations (the names' mm are for the std only)",
        "covariance": cal.covariance.tolist(),
        "compliance_rad_per_nm": cal.compliance,
        "outliers": cal.outliers, "outliers_refused": cal.refused,
        "refused_errors_mm": {k_: v * 1e3 for k_, v in cal.refused_errors.items()},
        "per_posture": [{"posture": lbl, "error_mm": float(e * 1e3)} for lbl, e in zip(cal.labels, per,
                                                                                         strict=True)],
        "timings_s": cal.timings_s,
    }
    atomic_write_text(out / "calibration.json", json.dumps(report, indent=2) + "\n")
    return out / "robot.yaml", out / "calibration.json"


def load_calibration(path):
    """``(chain, eps, T_meas_base, U, markers, units, compliance)`` from a ``robot.yaml`` written by
    :func:`write_calibration`."""

    from bench.geometry.quaternion import quaternion_to_matrix
    from bench.robot.chain import chain_from_dict

    path = Path(path)
    data = read_yaml(path)
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ConfigError(path, "format", f"expected {FORMAT!r} (a robot.yaml written by bench calibrate-robot "
                                          "--urdf), got {!r}".format(data.get("format") if isinstance(data, dict)
                                                                     else None))
    chain = chain_from_dict(data.get("chain"), str(path))
    cal = data.get("calibration")
    if not isinstance(cal, dict):
        raise ConfigError(path, "calibration", "missing")
    names = error_names(chain.n + 1)
    errs = cal.get("errors") or {}
    eps = np.zeros(chain.n_errors)
    for i, n in enumerate(names):
        v = errs.get(_err_key(n), 0.0)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
            raise ConfigError(path, f"calibration.errors.{_err_key(n)}", f"expected a finite number, got {v!r}")
        eps[i] = v * (1e-3 if n[0] in "xyz" else 1.0)
    try:
        fr = cal["T_meas_base"]
        t = np.array(fr["translation_mm"], dtype=float).reshape(3) * 1e-3
        qw = np.array(fr["quaternion_wxyz"], dtype=float).reshape(4)
        markers = [tuple(str(c) for c in mk["columns"]) for mk in cal["markers"]]
        U = np.array([mk["offset_mm"] for mk in cal["markers"]], dtype=float).reshape(-1, 3) * 1e-3
        units = cal["units"]
    except (KeyError, TypeError, ValueError):
        raise ConfigError(path, "calibration", "expected T_meas_base {translation_mm, quaternion_wxyz}, markers "
                                               "[{columns, offset_mm}] and units") from None
    if abs(np.linalg.norm(qw) - 1.0) > 1e-6 or any(len(m) != 3 for m in markers):
        raise ConfigError(path, "calibration.T_meas_base.quaternion_wxyz", "must be a unit quaternion")
    compliance = {}
    for name, entry in (cal.get("compliance") or {}).items():
        v = list(entry.values())[0] if isinstance(entry, dict) and len(entry) == 1 else None
        if name not in chain.joint_names or isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ConfigError(path, f"calibration.compliance.{name}", "expected a chain joint with {rad_per_nm: c}")
        compliance[name] = float(v)
    if compliance and chain.body_mass is None:
        raise ConfigError(path, "calibration.compliance", "needs the chain's body_mass_kg / body_com_mm")
    return chain, eps, homogeneous(quaternion_to_matrix(qw), t), U, markers, units, compliance


def check(robot_yaml, measurements, points=None, units=None, joint_units=None) -> dict:
    """Score a calibrated robot file on (held-out) postures with everything frozen: per-posture 3D errors (mm).

    ``points`` default to the calibrated markers' columns; given, they either name some of the calibrated markers
    (by their columns: those are scored) or as many markers as were calibrated (renamed columns, in the same order).
    ``units`` / ``joint_units`` default to the calibration's.
    """
    chain, eps, T, U, markers, cal_units, compliance = load_calibration(robot_yaml)
    cols = markers if points is None else parse_points(points)
    if all(c in markers for c in cols):  # calibrated markers chosen by their columns (e.g. marker 1 of a plate)
        U = U[[markers.index(c) for c in cols]]
        markers = cols
    elif len(cols) != len(markers):
        raise BenchError(f"--points: {len(cols)} marker(s) given, neither the calibration's columns nor as many "
                         f"markers as it has ({len(markers)}: {'; '.join(','.join(m) for m in markers)})")
    meas = read_measurements(measurements, chain, cols, units or cal_units["points"],
                             joint_units or cal_units["joints"])
    err = np.linalg.norm(predict(chain, meas.q, eps, T, U, compliance) - meas.P, axis=-1)  # (m, k)
    per = np.sqrt(np.mean(err**2, axis=1))
    return {"robot": str(robot_yaml), "measurements": str(measurements),
            "rms_mm": float(np.sqrt(np.mean(err**2)) * 1e3), "max_mm": float(err.max() * 1e3),
            "rms_first_marker_mm": float(np.sqrt(np.mean(err[:, 0] ** 2)) * 1e3),
            "n_postures": int(len(err)), "n_markers": int(len(markers)),
            "per_posture": [{"posture": lbl, "error_mm": float(e * 1e3),
                             "marker_errors_mm": [float(v * 1e3) for v in row]}
                            for lbl, e, row in zip(meas.labels, per, err, strict=True)]}
