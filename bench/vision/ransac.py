"""RANSAC on 3D-3D correspondences and error-ratio elimination (thesis section 3.8, Eq. 157-161).

:func:`ransac_absolute_orientation` finds ``T_1_2`` (``R 2p_i + t = 1p_i``, Eq. 124; see
:mod:`bench.vision.absolute_orientation` for the direction) from pairs contaminated by false matches:

1. Sampling (section 3.8 a-e): pick 3 distinct pairs ``1p*, 2p*``, estimate ``R`` from them with the chosen method
   (the thesis's Rodrigues/quaternion method or LMS [21]; Horn's as a third), translate both full sets by the
   sample means (Eq. 157-158) and count the pairs with ``d_r,i = |R 2p_i - 1p_i| < d_r`` (Eq. 159-160, translated
   coordinates). This is the same as ``|R 2p_i + t - 1p_i|`` with ``t`` from Eq. 125 on the sample.
   Collinear samples (condition number of the 3-point spread above ``max_condition``) count as iterations without a
   model. The best model has the most inliers; ties go to the smaller sum of squared inlier distances.
2. Iterations: a fixed count (thesis section 5.2.2: 100), or adaptive: after each new best model the required
   count becomes ``ceil(log(1 - confidence) / log(1 - w^3))`` with ``w`` the best inlier ratio (capped by
   ``max_iterations``), and sampling stops once it is reached.
3. Refit ("the model that includes the highest number of samples is used to generate the final rotation matrix"):
   the chosen method on the whole consensus set, translation by Eq. 125.
4. Error-ratio elimination (optional, ``r_lim``; thesis section 5.2.2: 0.1): with the refit model, every remaining
   pair gets ``r_e,i = d_r,i / |1p_i - 1p_bar|`` (its residual over its distance from the centre of the remaining
   ``1p``); the pair with the largest ratio is removed, the model re-estimated, and so on until every ratio is
   below ``r_lim`` (or only ``min_points`` pairs remain).

Misprint: Eq. 161 prints the ratio upside down, ``r_e,i = |1p_i - 1p_bar| / d_r,i``. As printed, removing the largest
ratio would remove the far-from-centre, well-fitting pairs, contradicting the text ("the samples that are close to
the center of the cluster ... are less important ... might even have a negative effect"), and the stopping rule
``r_e < r_lim = 0.1`` would require every residual to exceed ten times its distance from the centre - with RANSAC
inliers (``d_r,i < 20 mm``) only pairs within 2 mm of the centre could ever satisfy it. The inverted ratio matches
both the text and the parameter.

Distances are in metres (the thesis's ``d_r = 20 mm`` is ``0.02``); ``r_lim`` is dimensionless.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bench.geometry.transforms import homogeneous
from bench.vision.absolute_orientation import (
    MAX_CONDITION,
    METHODS,
    AbsoluteOrientationResult,
    _centre,
    _condition,
    _inertia,
    absolute_orientation,
    check_point_sets,
    fit_rotation,
)

#: Thesis section 5.2.2: 100 iterations, d_lim = 20 mm, r_lim = 0.1.
THESIS_ITERATIONS = 100
THESIS_DISTANCE = 0.02
THESIS_R_LIM = 0.1


@dataclass(frozen=True)
class EliminationStep:
    """One error-ratio elimination (Eq. 161): ``index`` (into the input arrays) removed with ratio ``ratio``; the
    re-estimated model then has ``rms`` (m) over ``n_remaining`` pairs and largest ratio ``max_ratio_after``."""

    index: int
    ratio: float
    rms: float
    n_remaining: int
    max_ratio_after: float


@dataclass
class RansacResult:
    """Outcome of :func:`ransac_absolute_orientation`.

    Attributes
    ----------
    success : bool
        False when no consensus of at least ``min_inliers`` pairs was found or the refit failed; then ``T`` is NaN.
    message : str
    T : ndarray (4, 4)
        ``T_1_2`` (``1p = T 2p``) from the final set of pairs.
    R : ndarray (3, 3)
    t : ndarray (3,)
        m.
    inliers : ndarray (N,) of bool
        Pairs kept at the end (RANSAC consensus minus the error-ratio eliminations).
    ransac_inliers : ndarray (N,) of bool
        The consensus set of the best RANSAC model.
    iterations : int
        Samples drawn (including degenerate ones).
    required_iterations : int
        Adaptive mode: the count required at the end; fixed mode: the fixed count.
    rms : float
        RMS of ``|1p_i - R 2p_i - t|`` over the final inliers (m).
    residuals : ndarray (N,)
        ``|1p_i - R 2p_i - t|`` for all pairs under the final model (m).
    history : list of EliminationStep
        The error-ratio eliminations in order (empty without ``r_lim``).
    elimination_converged : bool
        Every final ratio is below ``r_lim`` (True when no elimination was asked for).
    method : str
    orientation : AbsoluteOrientationResult or None
        The final fit (condition number, covariance, ...).
    """

    success: bool
    message: str
    T: np.ndarray
    R: np.ndarray
    t: np.ndarray
    inliers: np.ndarray
    ransac_inliers: np.ndarray
    iterations: int
    required_iterations: int
    rms: float
    residuals: np.ndarray = field(repr=False)
    history: list = field(default_factory=list)
    elimination_converged: bool = True
    method: str = "svd"
    orientation: AbsoluteOrientationResult | None = field(default=None, repr=False)


def adaptive_iterations(inlier_ratio, confidence=0.99, sample_size=3, max_iterations=10_000):
    """Standard RANSAC count ``ceil(log(1 - confidence) / log(1 - w^s))``, clipped to ``[1, max_iterations]``."""
    w = float(np.clip(inlier_ratio, 0.0, 1.0))
    good = w**sample_size
    if good >= 1.0:
        return 1
    if good <= 0.0:
        return int(max_iterations)
    n = np.log(1.0 - confidence) / np.log1p(-good)
    return int(np.clip(np.ceil(n), 1, max_iterations))


def _sample_triples(rng, n, size):
    """``size`` triples of distinct indices in ``[0, n)``, uniform over ordered triples."""
    a = rng.integers(0, n, size)
    b = rng.integers(0, n - 1, size)
    b = b + (b >= a)
    c = rng.integers(0, n - 2, size)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    c = c + (c >= lo)
    c = c + (c >= hi)
    return np.stack([a, b, c], axis=1)


def _failure(message, N, iterations, required, method, ransac_inliers=None):
    nan = np.full((4, 4), np.nan)
    return RansacResult(
        success=False, message=message, T=nan, R=nan[:3, :3].copy(), t=np.full(3, np.nan),
        inliers=np.zeros(N, dtype=bool),
        ransac_inliers=np.zeros(N, dtype=bool) if ransac_inliers is None else ransac_inliers,
        iterations=iterations, required_iterations=required, rms=np.nan, residuals=np.full(N, np.nan),
        elimination_converged=False, method=method,
    )


def error_ratios(p1, residuals):
    """Eq. 161 (corrected, see module docstring): ``d_r,i / |1p_i - 1p_bar|`` for pairs ``p1 (n, 3)``.

    A pair exactly at the centre has ratio ``inf`` (or 0 if its residual is 0 as well).
    """
    r = np.linalg.norm(p1 - p1.mean(axis=0), axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = residuals / r
    return np.where(r > 0.0, ratio, np.where(residuals > 0.0, np.inf, 0.0))


def ransac_absolute_orientation(p1, p2, *, d_r=THESIS_DISTANCE, iterations=THESIS_ITERATIONS, adaptive=False,
                                confidence=0.99, max_iterations=10_000, method="svd", refit_method=None,
                                r_lim=None, min_inliers=4, min_points=3, rng=None, batch=256,
                                max_condition=MAX_CONDITION):
    """RANSAC (section 3.8, Eq. 157-160) plus optional error-ratio elimination (Eq. 161) for ``T_1_2``.

    Parameters
    ----------
    p1, p2 : array_like (N, 3)
        Candidate corresponding points in frame 1 and frame 2 (m).
    d_r : float
        Inlier distance limit (m), Eq. 160 (thesis: 20 mm).
    iterations : int
        Fixed number of samples (thesis: 100); ignored when ``adaptive``.
    adaptive : bool
        Stop when ``adaptive_iterations(best inlier ratio, confidence)`` samples have been drawn.
    confidence : float
        Probability of drawing at least one all-inlier sample (adaptive mode).
    max_iterations : int
        Cap of the adaptive count.
    method : {"rodrigues", "svd", "horn"}
        Rotation estimator for the 3-point samples.
    refit_method : str, optional
        Estimator for the refit on the consensus set and the eliminations; defaults to ``method``.
    r_lim : float, optional
        Error-ratio limit (thesis: 0.1); None skips the elimination.
    min_inliers : int
        Smallest consensus accepted (a consensus of the 3 sampled pairs alone is no evidence).
    min_points : int
        The elimination never goes below this many pairs (>= 3).
    rng : numpy.random.Generator or int, optional
        Seeded generator (or seed) for the samples.
    batch : int
        Samples evaluated per vectorised batch (does not change the result).
    max_condition : float
        Samples and final sets with a larger spread condition number are treated as degenerate.

    Returns
    -------
    RansacResult
        ``success=False`` with the reason when there are fewer than 3 pairs, no consensus, or a degenerate
        consensus set. Malformed inputs raise a one-line ``ValueError``.
    """
    p1, p2, _ = check_point_sets(p1, p2)
    refit_method = method if refit_method is None else refit_method
    for name, m in (("method", method), ("refit_method", refit_method)):
        if m not in METHODS:
            raise ValueError(f"{name}: expected one of {METHODS}, got {m!r}")
    if not (np.isfinite(d_r) and d_r > 0):
        raise ValueError(f"d_r: must be a positive distance in m, got {d_r}")
    if r_lim is not None and not (np.isfinite(r_lim) and r_lim > 0):
        raise ValueError(f"r_lim: must be positive, got {r_lim}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence: must be in (0, 1), got {confidence}")
    if int(iterations) < 1 or int(max_iterations) < 1:
        raise ValueError("iterations, max_iterations: must be >= 1")
    if min_points < 3 or min_inliers < 3:
        raise ValueError("min_points, min_inliers: must be >= 3")
    rng = np.random.default_rng(rng)
    N = len(p1)
    limit = int(max_iterations) if adaptive else int(iterations)
    if N < 3:
        return _failure(f"RANSAC needs >= 3 pairs, got {N}", N, 0, limit, method)

    best_count, best_cost, best_mask = 0, np.inf, np.zeros(N, dtype=bool)
    required = limit
    done = 0
    ones3 = np.ones(3)
    while done < required:
        size = min(batch, required - done)
        idx = _sample_triples(rng, N, size)
        s1, s2 = p1[idx], p2[idx]  # (B, 3, 3)
        w = np.broadcast_to(ones3, (size, 3))
        _, c2 = _centre(s2, w)
        ok = _condition(_inertia(c2, w)) < max_condition
        R = fit_rotation(s1, s2, w, method)
        ok &= np.all(np.isfinite(R), axis=(-2, -1))
        R = np.where(ok[:, None, None], R, np.eye(3))
        m1, m2 = s1.mean(axis=1), s2.mean(axis=1)  # Eq. 157-158: sample means
        # Eq. 159-160: |R (2p_i - 2p*) - (1p_i - 1p*)| for all pairs, (B, N)
        d = np.linalg.norm(np.einsum("bij,nj->bni", R, p2) - np.einsum("bij,bj->bi", R, m2)[:, None, :]
                           - (p1[None] - m1[:, None, :]), axis=-1)
        inl = (d < d_r) & ok[:, None]
        counts = inl.sum(axis=1)
        costs = np.where(inl, d**2, 0.0).sum(axis=1)
        for k in range(size):  # sequential walk: identical to drawing one sample at a time
            done += 1
            if counts[k] > best_count or (counts[k] == best_count and counts[k] > 0 and costs[k] < best_cost):
                best_count, best_cost, best_mask = int(counts[k]), float(costs[k]), inl[k].copy()
                if adaptive:
                    required = max(done, adaptive_iterations(best_count / N, confidence, 3, max_iterations))
            if done >= required:
                break

    if best_count < min_inliers:
        return _failure(f"RANSAC found no consensus: best model has {best_count} pairs within d_r = {d_r:.4g} m "
                        f"(need {min_inliers}) after {done} samples", N, done, required, method)

    ransac_mask = best_mask
    keep = ransac_mask.copy()
    fit = absolute_orientation(p1[keep], p2[keep], method=refit_method, max_condition=max_condition)
    if not fit.success:
        return _failure(f"refit on the {best_count} RANSAC inliers failed: {fit.message}", N, done, required,
                        method, ransac_mask)

    history = []
    converged = True
    if r_lim is not None:
        while True:
            idx_keep = np.flatnonzero(keep)
            ratios = error_ratios(p1[idx_keep], fit.residuals)  # Eq. 161 (corrected)
            worst = int(np.argmax(ratios))
            if ratios[worst] < r_lim:
                break
            if len(idx_keep) <= min_points:
                converged = False
                break
            trial = keep.copy()
            trial[idx_keep[worst]] = False
            new_fit = absolute_orientation(p1[trial], p2[trial], method=refit_method, max_condition=max_condition)
            if not new_fit.success:
                converged = False
                break
            keep, fit = trial, new_fit
            after = error_ratios(p1[keep], fit.residuals)
            history.append(EliminationStep(index=int(idx_keep[worst]), ratio=float(ratios[worst]), rms=fit.rms,
                                           n_remaining=int(keep.sum()), max_ratio_after=float(after.max())))

    R, t = fit.R, fit.t
    residuals = np.linalg.norm(p1 - p2 @ R.T - t, axis=1)
    msg = f"{best_count} of {N} pairs in consensus after {done} samples"
    if r_lim is not None:
        msg += f"; {len(history)} removed by error ratio"
        if not converged:
            msg += f" (stopped before all ratios < r_lim = {r_lim:g}: {int(keep.sum())} pairs left)"
    if fit.message != "ok":
        msg += f"; {fit.message}"
    return RansacResult(
        success=True, message=msg, T=homogeneous(R, t), R=R, t=t, inliers=keep, ransac_inliers=ransac_mask,
        iterations=done, required_iterations=required, rms=fit.rms, residuals=residuals, history=history,
        elimination_converged=converged, method=refit_method, orientation=fit,
    )
