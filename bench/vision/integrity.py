"""Integrity of the in-situ localisation: does the answer hold, and how far from the truth can it be?

A localisation (:func:`bench.vision.insitu.locate`) trusts three things it cannot see: that each image was taken where
its joint readings put the camera, that the kinematic model (arm, mount, camera) still holds, and that the features
it matched are the scene it mapped. When one of them fails the least-squares answer can be confidently wrong (an image
swapped between views: ~0.8 m off with a millimetre covariance). :func:`assess` tests each assumption on the data the
robot gives - images, joint readings, the calibrated files; never the truth - and returns

* ``integrity`` - ``ok``, ``warning`` (usable with care: a soft test failed, or the protection radius exceeds the
  alert limit) or ``refused`` (an assumption is broken: the pose must not be used);
* ``reasons`` - one sentence per failed test, with its figures;
* a protection radius and angle - the pipeline's own bound on its base-pose error, exceeded with probability
  :data:`INTEGRITY_RISK` when every test passes.

The tests (each one's statistic is reported in ``tests``):

1. **Each view against the map given its joint readings.** Map points are projected into every view at the pose its
   readings predict (survey views: the kinematics relative to the reference; locate views: the solution and the
   kinematic relative pose ``T_a_b``); the number of matches within :data:`GATE_PX` is compared with the number a
   free single-view pose (PnP + RANSAC against the map) explains. An image taken elsewhere than its readings say
   (swapped, duplicated, a wrong or shifted joint log) is explained by a free pose but not by the predicted one:
   ``consensus`` = predicted / free falls (refused below :data:`CONSENSUS_REFUSE`).
2. **The two new views with each other and with the kinematics.** The free poses of the two locate views give their
   relative pose from the images alone; it must agree with the kinematic ``T_a_b`` (refused beyond
   :data:`RELATIVE_REFUSE_MM` / :data:`RELATIVE_REFUSE_DEG`; a warning beyond a third of it).
3. **Reprojection chi-square.** The locate views' residual RMS at the solution against the survey views' residual
   RMS at their kinematic poses (the keypoint noise of this scene, this water, this camera): the ratio inflates the
   covariance, and refuses beyond :data:`CHI2_RATIO_REFUSE`.
4. **Residual whiteness.** The correlation of each locate residual with its nearest image neighbour's: a model error
   (bent mount, wrong calibration) makes neighbouring residuals alike, noise does not. ``rho`` inflates the
   covariance by ``sqrt((1 + rho) / (1 - rho))`` (the variance of a mean of AR(1)-correlated samples).
5. **Support.** Inliers (at least :data:`MIN_INLIERS`), inlier fraction and the inliers' spread over image a (convex
   hull / image area).
6. **Conditioning** of the final least-squares problem.

Protection levels: the covariance of the base pose (position block, rotation block) is inflated by the chi-square and
whiteness factors, and by the disagreement of test 2 (a kinematic relative pose off by ``d`` moves the solution by
about ``d``); its largest standard deviation times ``k`` (``k^2`` the chi-square quantile of 3 degrees of freedom
at ``1 - INTEGRITY_RISK``), plus a floor for the model errors no test here resolves (:data:`FLOOR_MM`,
:data:`FLOOR_DEG`: the kinematic calibration's residual error, measured - see docs/integrity.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial import ConvexHull, QhullError, cKDTree
from scipy.stats import chi2

from bench.geometry.transforms import invert, rotation_angle, transform_points
from bench.vision.insitu import KeypointMap, MapConfig, ViewObservation, reference_matches

#: Probability that the true error exceeds the protection level when every test passes (the stated risk).
INTEGRITY_RISK = 1e-3
#: Reprojection gate (px) of the consensus counts (test 1); a match within it is "explained" by a pose.
GATE_PX = 3.0
#: Consensus (predicted / free inliers) below which a view is refused, and below which it is a warning.
CONSENSUS_REFUSE = 0.5
CONSENSUS_WARN = 0.8
#: A free pose needs this many inliers before its disagreement with the predicted one counts.
MIN_FREE_INLIERS = 12
#: Relative pose of the locate views, images vs kinematics (test 2): refused beyond these.
RELATIVE_REFUSE_MM = 30.0
RELATIVE_REFUSE_DEG = 1.5
#: Locate residual RMS / survey residual RMS (test 3) beyond which the solution is refused / warned.
CHI2_RATIO_REFUSE = 10.0
CHI2_RATIO_WARN = 3.0
#: Support (test 5).
MIN_INLIERS = 12
WARN_INLIERS = 30
WARN_INLIER_FRACTION = 0.3
WARN_SPREAD = 0.05
#: Conditioning (test 6): warning / refused beyond.
WARN_CONDITION = 1e4
REFUSE_CONDITION = 1e8
#: Optimism of the pose covariance (its standard deviations times this): see :func:`protection_levels`.
KAPPA = 1.0
#: Model floor of the protection levels (the residual kinematic calibration error, see the module docstring).
FLOOR_MM = 0.5
FLOOR_DEG = 0.01
#: Alert limits: a protection level above them makes an otherwise sound localisation a warning.
ALERT_MM = 3.0
ALERT_DEG = 0.15


@dataclass
class Integrity:
    """Outcome of :func:`assess`.

    Attributes
    ----------
    level : {"ok", "warning", "refused"}
    reasons : list of str
    protection_radius_m : float
        Bound on the base position error (m), exceeded with probability :data:`INTEGRITY_RISK` (inf when refused).
    protection_angle_rad : float
        Bound on the base rotation error (rad).
    tests : dict
        The statistic of every test (names carry units).
    """

    level: str
    reasons: list = field(default_factory=list)
    protection_radius_m: float = float("inf")
    protection_angle_rad: float = float("inf")
    tests: dict = field(default_factory=dict)

    def report(self) -> dict:
        """The locate.json entries (``integrity``, ``integrity_reasons``, ``protection_radius_mm``, ...)."""
        return {"integrity": self.level, "integrity_reasons": list(self.reasons),
                "protection_radius_mm": _finite(self.protection_radius_m * 1e3),
                "protection_angle_deg": _finite(np.rad2deg(self.protection_angle_rad)),
                "integrity_tests": {k: _finite(v) for k, v in self.tests.items()}}


def _finite(v):
    """JSON-safe number: NaN and inf become None (null)."""
    v = float(v)
    return v if np.isfinite(v) else None


def _project(T_view_ref, p_ref):
    """Normalized projections (N, 2) of reference-frame points in a view, and their depths (N,)."""
    X = transform_points(T_view_ref, p_ref)
    z = X[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        return X[:, :2] / z[:, None], z


def _residuals_px(kmap, view, idx_map, idx_view, T_ref_view, focal_px):
    """Reprojection errors (px, (N,)) and residual vectors (N, 2) of matched map points at a pose."""
    u, z = _project(invert(T_ref_view), kmap.p_ref[idx_map])
    r = (view.x_n[idx_view] - u) * focal_px
    e = np.linalg.norm(r, axis=1)
    e[~(z > 0)] = np.inf
    return e, r


def free_pose(kmap: KeypointMap, view: ViewObservation, idx_map, idx_view, focal_px: float, seed: int = 0):
    """Single-view pose of ``view`` from its map matches alone (PnP + RANSAC + LM, gate :data:`GATE_PX`).

    Returns ``(T_ref_view or None, inlier mask (N,) bool)``.
    """
    n = len(idx_map)
    if n < 6:
        return None, np.zeros(n, dtype=bool)
    obj = kmap.p_ref[idx_map].astype(np.float64)
    img = view.x_n[idx_view].astype(np.float64)
    cv2.setRNGSeed(seed)
    ok, rvec, tvec, inl = cv2.solvePnPRansac(obj, img, np.eye(3), None, reprojectionError=GATE_PX / focal_px,
                                             iterationsCount=500, confidence=0.999, flags=cv2.SOLVEPNP_EPNP)
    if not ok or inl is None or len(inl) < 6:
        return None, np.zeros(n, dtype=bool)
    inl = inl.ravel()
    rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], np.eye(3), None, rvec, tvec)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = cv2.Rodrigues(rvec)[0], tvec.ravel()
    T_ref_view = invert(T)
    e, _ = _residuals_px(kmap, view, idx_map, idx_view, T_ref_view, focal_px)
    return T_ref_view, e <= GATE_PX


def _whiteness(uv, r):
    """Correlation of each residual (N, 2) with its nearest image neighbour's (uv (N, 2) px); NaN below 8 points."""
    if len(uv) < 8:
        return float("nan")
    _, j = cKDTree(uv).query(uv, k=2)
    nb = r[j[:, 1]]
    rc = r - r.mean(axis=0)
    nbc = nb - r.mean(axis=0)
    den = float(np.sum(rc * rc))
    return float(np.sum(rc * nbc) / den) if den > 0 else float("nan")


def _hull_fraction(uv, size):
    if len(uv) < 3:
        return 0.0
    try:
        return float(ConvexHull(uv).volume / (size[0] * size[1]))
    except QhullError:
        return 0.0


def _view_consensus(kmap, view, T_ref_view, focal_px, cfg, seed):
    """Test 1 for one view: matches, inliers at the predicted pose, inliers of a free pose, the free pose."""
    m = reference_matches(ViewObservation("map", kmap.features, kmap.x_ref, np.eye(4)), [view], cfg)[0]
    e, r = _residuals_px(kmap, view, m.i1, m.i2, T_ref_view, focal_px)
    pred = e <= GATE_PX
    T_free, free = free_pose(kmap, view, m.i1, m.i2, focal_px, seed)
    return {"matches": len(m), "predicted": int(pred.sum()), "free": int(free.sum()), "T_free": T_free,
            "residual_px": e[pred], "residual_vec": r[pred], "uv": view.features.uv[m.i2[pred]]}


def _robust_rms(e):
    e = np.asarray(e, float)
    return float(np.sqrt(np.mean(e**2))) if len(e) else float("nan")


def protection_levels(covariance, tests: dict, kappa: float | None = None, floor_mm: float | None = None,
                      floor_deg: float | None = None):
    """Protection radius (m) and angle (rad) from the pose covariance and the integrity tests' statistics.

    ``k * kappa * f_chi * f_white * sigma_max + floor`` per block (position, rotation), with ``sigma_max`` the
    largest standard deviation of the block, ``k^2`` the chi-square quantile of 3 degrees of freedom at
    ``1 - INTEGRITY_RISK``, ``f_chi`` / ``f_white`` the test-3 / test-4 inflations in ``tests``
    (``inflation_chi2``, ``inflation_whiteness``), and ``kappa`` (default :data:`KAPPA`) the covariance's measured
    optimism (docs/integrity.md: fitted on clean envelope runs so that the covariance's 95 % region holds 95 % of
    their errors). The disagreement of test 2 (``relative_pose_mm`` / ``_deg``) is added in quadrature, a third of
    it. Also records ``k_factor`` and ``kappa`` into ``tests``.

    Parameters
    ----------
    covariance : array_like (6, 6)
        Rotation vector (rad) then translation (m) of the base pose.
    tests : dict
        The statistics :func:`assess` computed (names carry units).
    """
    kappa = KAPPA if kappa is None else float(kappa)
    floor_mm = FLOOR_MM if floor_mm is None else float(floor_mm)
    floor_deg = FLOOR_DEG if floor_deg is None else float(floor_deg)
    cov = np.asarray(covariance, float)
    sig_rot = float(np.sqrt(max(np.linalg.eigvalsh(cov[:3, :3]).max(), 0.0)))
    sig_pos = float(np.sqrt(max(np.linalg.eigvalsh(cov[3:, 3:]).max(), 0.0)))
    k = float(np.sqrt(chi2.ppf(1 - INTEGRITY_RISK, 3)))
    f = kappa * float(tests.get("inflation_chi2", 1.0)) * float(tests.get("inflation_whiteness", 1.0))
    tests.update(k_factor=k, kappa=kappa)
    pr = k * f * sig_pos + floor_mm * 1e-3
    pa = k * f * sig_rot + np.deg2rad(floor_deg)
    d_t = tests.get("relative_pose_mm")
    if d_t is not None and np.isfinite(d_t):  # a kinematic relative pose off by d moves the solution by about d
        pr = float(np.hypot(pr, d_t * 1e-3 / 3))
        pa = float(np.hypot(pa, np.deg2rad(tests["relative_pose_deg"]) / 3))
    return float(pr), float(pa)


def assess(kmap: KeypointMap, surround: list, view_a: ViewObservation, view_b: ViewObservation, result,
           focal_px: float, image_size, config: MapConfig | None = None, seed: int = 0) -> Integrity:
    """Integrity tests and protection levels of a two-view localisation (see the module docstring).

    Parameters
    ----------
    kmap : KeypointMap
        The survey map (reference frame).
    surround : list of ViewObservation
        The survey's surrounding views, in the order :func:`~bench.vision.insitu.build_map` took them
        (``kmap.T_ref_views``).
    view_a, view_b : ViewObservation
        The two locate views (poses from their joint readings in the new base frame); ``view_b`` None for a
        single-view (PnP) localisation, which is then at best a warning.
    result : LocateResult
        The localisation (its ``T_ref_cam``, ``covariance``, ``condition``, ``n_matches``, ``n_inliers``).
    focal_px : float
        The calibrated focal length (px): normalized residuals to pixels.
    image_size : (int, int)
        Width, height (px).

    Returns
    -------
    Integrity
    """
    cfg = config or MapConfig()
    refuse, warn, tests = [], [], {}
    if not result.success:
        return Integrity("refused", [f"no localisation: {result.message}"])
    if view_b is None:
        warn.append("single-view (PnP) localisation: the cross-check of two views with the kinematics is missing")
        T_a_b = np.eye(4)
    else:
        T_a_b = invert(np.asarray(view_a.T_base_cam, float)) @ np.asarray(view_b.T_base_cam, float)
    T_ref_a = np.asarray(result.T_ref_cam, float)

    # --- test 1: every view against the map, at the pose its joint readings predict --------------------------------
    survey_res = []
    for k, v in enumerate(surround):
        c = _view_consensus(kmap, v, kmap.T_ref_views[k], focal_px, cfg, seed)
        survey_res.append(c["residual_px"])
        frac = c["predicted"] / max(c["free"], 1)
        tests[f"consensus_{v.name}"] = frac
        if c["free"] >= MIN_FREE_INLIERS and frac < CONSENSUS_REFUSE:
            refuse.append(f"survey view {v.name}: its image is not where its joint readings put the camera "
                          f"({c['predicted']} map matches within {GATE_PX:g} px there, {c['free']} at a free pose)")
        elif c["free"] >= MIN_FREE_INLIERS and frac < CONSENSUS_WARN:
            warn.append(f"survey view {v.name}: consensus {frac:.2f} at its kinematic pose")
    loc = {}
    pairs = [("a", view_a, T_ref_a)] + ([("b", view_b, T_ref_a @ T_a_b)] if view_b is not None else [])
    for name, v, T in pairs:
        c = _view_consensus(kmap, v, T, focal_px, cfg, seed)
        loc[name] = c
        frac = c["predicted"] / max(c["free"], 1)
        tests[f"consensus_locate_{name}"] = frac
        tests[f"free_inliers_locate_{name}"] = float(c["free"])
        if c["free"] < MIN_FREE_INLIERS:
            refuse.append(f"locate view {v.name}: only {c['free']} of {c['matches']} map matches agree with any "
                          f"single pose (need {MIN_FREE_INLIERS})")
        elif frac < CONSENSUS_REFUSE:
            refuse.append(f"locate view {v.name}: {c['predicted']} map matches within {GATE_PX:g} px at the solution "
                          f"and its joint readings, {c['free']} at a free pose (consensus {frac:.2f})")
        elif frac < CONSENSUS_WARN:
            warn.append(f"locate view {v.name}: consensus {frac:.2f} at the solution")

    # --- test 2: the two new views' relative pose, images vs kinematics -------------------------------------------
    d_t = d_r = float("nan")
    if "b" in loc and loc["a"]["T_free"] is not None and loc["b"]["T_free"] is not None:
        T_ab_img = invert(loc["a"]["T_free"]) @ loc["b"]["T_free"]
        D = invert(T_a_b) @ T_ab_img
        d_t, d_r = float(np.linalg.norm(D[:3, 3])), float(rotation_angle(D[:3, :3]))
        tests["relative_pose_mm"], tests["relative_pose_deg"] = d_t * 1e3, np.rad2deg(d_r)
        if d_t * 1e3 > RELATIVE_REFUSE_MM or np.rad2deg(d_r) > RELATIVE_REFUSE_DEG:
            refuse.append(f"the locate views' relative pose from the images differs from the joint readings' by "
                          f"{d_t * 1e3:.1f} mm and {np.rad2deg(d_r):.2f} deg (limits {RELATIVE_REFUSE_MM:g} mm, "
                          f"{RELATIVE_REFUSE_DEG:g} deg)")
        elif d_t * 1e3 > RELATIVE_REFUSE_MM / 3 or np.rad2deg(d_r) > RELATIVE_REFUSE_DEG / 3:
            warn.append(f"the locate views' relative pose from the images differs from the joint readings' by "
                        f"{d_t * 1e3:.1f} mm and {np.rad2deg(d_r):.2f} deg")

    # --- test 3: reprojection chi-square, locate views vs the survey's own noise -----------------------------------
    sigma_survey = _robust_rms(np.concatenate(survey_res)) if survey_res else float("nan")
    res_loc = np.concatenate([c["residual_px"] for c in loc.values()])
    rms_loc = _robust_rms(res_loc)
    ratio = rms_loc / sigma_survey if sigma_survey > 0 else float("nan")
    tests.update(survey_rms_px=sigma_survey, locate_rms_px=rms_loc, chi2_ratio=ratio)
    if np.isfinite(ratio) and ratio > CHI2_RATIO_REFUSE:
        refuse.append(f"reprojection RMS {rms_loc:.2f} px at the solution, {ratio:.1f} x the survey's "
                      f"{sigma_survey:.2f} px (limit {CHI2_RATIO_REFUSE:g} x)")
    elif np.isfinite(ratio) and ratio > CHI2_RATIO_WARN:
        warn.append(f"reprojection RMS {rms_loc:.2f} px, {ratio:.1f} x the survey's")

    # --- test 4: whiteness ------------------------------------------------------------------------------------------
    rho = _whiteness(loc["a"]["uv"], loc["a"]["residual_vec"])
    tests["whiteness_rho"] = rho
    rho_c = float(np.clip(rho, 0.0, 0.95)) if np.isfinite(rho) else 0.0
    f_white = float(np.sqrt((1 + rho_c) / (1 - rho_c)))

    # --- test 5: support --------------------------------------------------------------------------------------------
    frac_in = result.n_inliers / max(result.n_matches, 1)
    spread = _hull_fraction(loc["a"]["uv"], image_size)
    tests.update(inliers=float(result.n_inliers), inlier_fraction=frac_in, spread_fraction=spread)
    if result.n_inliers < MIN_INLIERS:
        refuse.append(f"{result.n_inliers} inliers (need {MIN_INLIERS})")
    elif result.n_inliers < WARN_INLIERS:
        warn.append(f"only {result.n_inliers} inliers")
    if frac_in < WARN_INLIER_FRACTION:
        warn.append(f"inlier fraction {frac_in:.2f} of {result.n_matches} matches")
    if spread < WARN_SPREAD:
        warn.append(f"inliers cover {spread * 100:.1f} % of image a")

    # --- test 6: conditioning ---------------------------------------------------------------------------------------
    tests["condition"] = float(result.condition)
    if not result.condition < REFUSE_CONDITION:
        refuse.append(f"ill-conditioned pose problem (condition {result.condition:.3g})")
    elif result.condition > WARN_CONDITION:
        warn.append(f"ill-conditioned pose problem (condition {result.condition:.3g})")

    # --- protection levels -------------------------------------------------------------------------------------------
    tests.update(inflation_chi2=max(1.0, ratio) if np.isfinite(ratio) else 1.0, inflation_whiteness=f_white)
    pr, pa = protection_levels(result.covariance, tests)
    if refuse:
        return Integrity("refused", refuse + warn, float("inf"), float("inf"), tests)
    if pr * 1e3 > ALERT_MM or np.rad2deg(pa) > ALERT_DEG:
        warn.append(f"protection radius {pr * 1e3:.2f} mm / {np.rad2deg(pa):.3f} deg exceeds the alert limit "
                    f"{ALERT_MM:g} mm / {ALERT_DEG:g} deg")
    return Integrity("warning" if warn else "ok", warn, pr, pa, tests)
