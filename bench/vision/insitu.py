"""Kinematic multi-view triangulation and base localisation (thesis section 3.9, Eq. 162-166).

The camera rides on link 5; the (calibrated) arm kinematics and the camera mount give every view's pose in the base
frame, ``T_base_cam = T_base_link5(q) T_link5_cam`` (Eq. 188). Two steps:

1. :func:`build_map` - the survey. A reference view and surrounding views taken without moving the base. Each
   reference keypoint is matched in every surrounding view (ratio test, orientation filter of Eq. 106) and
   triangulated against it by the mid-point method; matches whose rays pass farther apart than ``gap_max_m`` (thesis:
   5 mm) are dropped. The estimates of one keypoint, ``1p_i,j = 1gamma_i,j K^-1 p_i`` (Eq. 162-163, on the
   reference ray), are kept if they have a neighbour within ``neighbour_m`` (``d_n``) and averaged; the alternative
   estimate on the other rays, ``1p*_i`` (Eq. 164), must agree within ``cross_check_m``; keypoints seen in fewer than
   ``min_views`` views are dropped. The result is the map ``1p`` in the reference camera frame, plus the reference
   descriptors, and its pose in the survey base frame (the *site* frame, ``world`` below).
2. :func:`locate` - after the base has moved: two new views ``a, b`` (relative pose from the kinematics) are matched
   with the map and with each other, triangulated into ``2p`` in camera-a coordinates (Eq. 165-166), aligned to
   ``1p`` by RANSAC + absolute orientation + error-ratio elimination (section 3.8), which gives ``T_ref_a``; the base
   follows through link 5: ``T_world_base = T_world_ref T_ref_a (T_base_a)^-1``.
   :func:`locate_pnp` is the single-view alternative (PnP with RANSAC + LM refinement against ``1p``).

Frames: ``world`` = the base frame at survey time (the site frame in which the map is kept); ``ref`` = the reference
camera (OpenCV optical frame); ``a``, ``b`` = the camera at the two locate views. Image coordinates enter already
*normalized and undistorted* (``x_n``), so this module is independent of the camera model.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from bench.geometry.quaternion import matrix_to_rotation_vector, rotation_vector_to_matrix
from bench.geometry.transforms import homogeneous, invert, skew, transform_points
from bench.vision.features import (
    ORIENTATION_TOL_DEG,
    RATIO,
    Features,
    Matches,
    match_features,
)
from bench.vision.ransac import ransac_absolute_orientation
from bench.vision.triangulation import required_baseline, triangulate_midpoint

#: Baseline checks (Eq. 123 / 199, 1 px disparity error). A locate pair whose baseline is below
#: ``required_baseline(z, f, d_r)`` - a 1 px disparity error moves a triangulated 2p point by more than the RANSAC
#: distance d_r at the matches' median depth z - is used with a WARNING in the message: its 3D points are coarser than
#: the consensus test assumes, and the pose rests on the refinement (measured on synthetic data at 1.1 m, 0.3 px:
#: 50 mm -> 0.6 mm error, 5 mm -> 2 mm, 2 mm -> 26 mm with the refinement, 540 mm without). Below
#: ``BASELINE_FAIL_RATIO * z / f`` a 1 px disparity error is as large as the depth itself: no depth information, the
#: pair is refused. The survey gets the same warning against the map's neighbour distance d_n.
BASELINE_FAIL_RATIO = 1.0
#: Reference keypoints closer than this (px) are one detection (:func:`one_per_detection`): SIFT's second orientation
#: of a keypoint sits at the very same position and size (measured: every such pair within 1e-6 px; the next nearest
#: keypoints of a map lie 0.1-2 px apart).
TWIN_PX = 0.01
#: What a keypoint that SIFT's twins share is worth in the joint bundle, in measurements of a keypoint of its own
#: (``pipeline.twin_keypoints: weighted``). The twins' copies err as one (their true errors correlated 1.00 in every
#: other view, in air as under water), and a twin detection errs less than a single keypoint: against the panel's
#: true surface, the part of its error its point does not absorb (the deviation from the point's mean over its
#: views, what moves the pose) is 0.88 x (air) and 0.86 x (under water) a single keypoint's (RMS, eight runs each of
#: the default scenario; ``tools/keypoint_error_decomposition.py``'s ``twin_dev_rms_px`` / ``single_dev_rms_px``):
#: worth (1 / 0.87)^2 = 1.3. The joint bundle's own residuals say the same without the truth (a twin's robust
#: residual 0.87 x / 0.91 x a single keypoint's, six runs each). A constant of the estimator fitted on the
#: simulation, as :data:`bench.vision.integrity.KAPPA` is; docs/integrity.md, "Twin keypoints weighed as what they
#: are worth".
TWIN_WORTH = 1.3
#: ``pipeline.twin_keypoints``'s choices (:func:`twin_map_config`)
TWIN_CHOICES = ("both", "once", "weighted")
#: Condition number of the final pose problem above which the message carries a WARNING (both locate variants).
WARN_CONDITION = 1e4


@dataclass(frozen=True)
class ViewObservation:
    """One view as the pipeline sees it.

    Attributes
    ----------
    name : str
    features : Features
        Keypoints detected in the image as taken.
    x_n : ndarray (N, 2)
        The keypoints' normalized undistorted coordinates (the camera model's job).
    T_base_cam : ndarray (4, 4)
        Camera pose from the joint readings through the calibrated kinematics and mount.
    """

    name: str
    features: Features
    x_n: np.ndarray
    T_base_cam: np.ndarray


@dataclass(frozen=True)
class MapConfig:
    """Parameters of :func:`build_map` (thesis values where it gives them)."""

    ratio: float = RATIO
    orientation_tol_deg: float = ORIENTATION_TOL_DEG
    gap_max_m: float = 0.005  # closest-approach filter (section 5.2.2: 5 mm)
    neighbour_m: float = 0.01  # d_n of section 3.9
    cross_check_m: float = 0.005  # |1p - 1p*| (Eq. 163 vs Eq. 164)
    min_views: int = 2  # keep keypoints matched in at least this many surrounding views
    #: Reference keypoints closer than this (px) are one detection, of which the map keeps one (the copy matched in most
    #: views, observed wherever any copy was matched: :func:`_merge_twins`); 0 (the default, the thesis's map) keeps
    #: them all. SIFT gives a second keypoint, with its own orientation and descriptor, at the same position and scale
    #: wherever the orientation histogram has a second peak (Lowe 2004, section 5); each matches its twin in every
    #: view, so the thesis's map holds such a scene point twice and its covariance counts it as two measurements. Under
    #: water the copies' errors are one error (correlated 1.00 on the true surface) and merging makes the covariance
    #: honest; in air they are partly independent and merging costs accuracy (docs/integrity.md, "Twin keypoints in
    #: the covariance"); the bound counts each detection once (:func:`one_per_detection`).
    duplicate_px: float = 0.0
    #: Observations of one view whose keypoints lie closer than this (px) are one keypoint (SIFT's twins: both map
    #: points kept, as the thesis's map has them), weighed as :data:`TWIN_WORTH` measurements in the joint bundle
    #: (:func:`bench.vision.joint_bundle.detection_weights`); 0 (the default) weighs every observation as one.
    one_keypoint_px: float = 0.0


@dataclass
class KeypointMap:
    """The map ``1p``: reference keypoints with their 3D positions in the reference camera frame.

    Attributes
    ----------
    p_ref : ndarray (M, 3)
        Positions (m) in the reference camera frame (Eq. 162).
    p_ref_star : ndarray (M, 3)
        The alternative estimates on the surrounding rays (Eq. 164).
    features : Features
        The reference keypoints (descriptors, orientations) of the M map points.
    n_views : ndarray (M,)
        Surrounding views that contributed to each point.
    spread_m : ndarray (M,)
        RMS distance of the contributing estimates from their mean.
    T_world_ref : ndarray (4, 4)
        Pose of the reference camera in the site frame (the survey base frame).
    stats : dict
        Counts after each filter.
    x_ref : ndarray (M, 2)
        The map points' keypoints in the reference view (normalized, undistorted).
    T_ref_views : ndarray (K, 4, 4)
        Poses of the surrounding views in the reference camera frame (kinematics).
    observations : list of (ndarray (n_i,) int, ndarray (n_i, 2))
        Per map point: the surrounding views that contributed to it and its keypoint in each (normalized) - what
        :func:`bundle_refine` re-uses.
    ref_index : ndarray (M,) int
        Each map point's index among the reference view's keypoints (with the matches, its keypoint in every view).
    """

    p_ref: np.ndarray
    p_ref_star: np.ndarray
    features: Features
    n_views: np.ndarray
    spread_m: np.ndarray
    T_world_ref: np.ndarray
    stats: dict = field(default_factory=dict)
    x_ref: np.ndarray | None = None
    T_ref_views: np.ndarray | None = None
    observations: list | None = None
    ref_index: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.p_ref)


def view_matches(f1: Features, f2: Features, cfg: MapConfig) -> Matches:
    """The matches this module uses between two feature sets: ratio test and orientation filter of ``cfg``."""
    return match_features(f1, f2, cfg.ratio, cfg.orientation_tol_deg).matches


def reference_matches(reference: ViewObservation, views: list, config: MapConfig | None = None) -> list:
    """Ratio-test and orientation-filtered matches of the reference keypoints in each view (as :func:`build_map`)."""
    cfg = config or MapConfig()
    return [view_matches(reference.features, v.features, cfg) for v in views]


def build_map(reference: ViewObservation, surrounding: list, config: MapConfig | None = None,
              matches: list | None = None) -> KeypointMap:
    """Triangulate the reference keypoints against the surrounding views (section 3.9, Eq. 162-164).

    Parameters
    ----------
    reference : ViewObservation
    surrounding : list of ViewObservation
        Views around the reference, base not moved.
    config : MapConfig, optional
    matches : list of Matches, optional
        Reference -> surrounding-view matches, one per view, already ratio- and orientation-filtered (as
        :func:`reference_matches` gives them); computed here when omitted. Lets a caller that builds many maps from
        subsets of the same views (the x-y table experiments) match each view once.

    Returns
    -------
    KeypointMap
        Possibly empty (``len == 0``) when nothing survives the filters; ``stats`` says where points were lost.
    """
    cfg = config or MapConfig()
    if not surrounding:
        raise ValueError("surrounding: at least one surrounding view is needed to triangulate")
    n = len(reference.features)
    T_world_ref = np.asarray(reference.T_base_cam, dtype=float)
    stats = {"reference_keypoints": n, "matches": 0, "after_gap_filter": 0}
    if matches is not None and len(matches) != len(surrounding):
        raise ValueError(f"matches: {len(matches)} match sets for {len(surrounding)} surrounding views")
    T_ref_views = np.array([invert(T_world_ref) @ np.asarray(v.T_base_cam, float) for v in surrounding])
    matches = [view_matches(reference.features, v.features, cfg) for v in surrounding] if matches is None else matches
    matches, stats["duplicate_detections"] = _merge_twins(reference.features.uv, matches, cfg.duplicate_px)
    # every estimate of a reference keypoint: (its index, p on the reference ray, p on the other ray, view, keypoint)
    ests = [(np.empty(0, int), np.empty((0, 3)), np.empty((0, 3)), np.empty(0, int), np.empty((0, 2)))]
    for k, view in enumerate(surrounding):
        m = matches[k]
        stats["matches"] += len(m)
        if len(m) == 0:
            continue
        tri = triangulate_midpoint([np.eye(4), T_ref_views[k]], [reference.x_n[m.i1], view.x_n[m.i2]])
        ok = tri.valid & (tri.gap <= cfg.gap_max_m)
        stats["after_gap_filter"] += int(ok.sum())
        # Eq. 163 (on the reference ray) and Eq. 164 (on ray j)
        ests.append((m.i1[ok], tri.ray_points[0][ok], tri.ray_points[1][ok], np.full(int(ok.sum()), k),
                     view.x_n[m.i2[ok]]))
    i_all, p_all, ps_all, k_all, x_all = (np.concatenate(a) for a in zip(*ests, strict=True))
    # grouped by keypoint, each group's estimates in view order; groups padded to (G, L) slots
    order = np.argsort(i_all, kind="stable")
    i_all, p_all, ps_all, k_all, x_all = i_all[order], p_all[order], ps_all[order], k_all[order], x_all[order]
    keys, first, count = np.unique(i_all, return_index=True, return_counts=True)
    group = np.repeat(np.arange(len(keys)), count)
    slot = np.arange(len(i_all)) - first[group]
    L = int(count.max()) if len(count) else 0
    P = np.zeros((len(keys), L, 3))
    Ps = np.zeros((len(keys), L, 3))
    filled = np.zeros((len(keys), L), bool)
    P[group, slot], Ps[group, slot], filled[group, slot] = p_all, ps_all, True
    d = np.linalg.norm(P[:, :, None] - P[:, None], axis=-1)
    d[~(filled[:, :, None] & filled[:, None])] = np.inf
    d[:, np.arange(L), np.arange(L)] = np.inf
    nearest = d.min(axis=2) if L else np.zeros((0, 0))
    good = filled & ((nearest <= cfg.neighbour_m) | (count[:, None] == 1))  # neighbour filter d_n
    n_good = good.sum(axis=1)
    mean, mean_star = np.zeros((len(keys), 3)), np.zeros((len(keys), 3))
    for j in range(L):  # slot by slot, in view order: the same sums as each group's own mean
        mean += np.where(good[:, j, None], P[:, j], 0.0)
        mean_star += np.where(good[:, j, None], Ps[:, j], 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean, mean_star = mean / n_good[:, None], mean_star / n_good[:, None]  # Eq. 162, Eq. 164
    kept = (count >= cfg.min_views) & (n_good >= cfg.min_views)
    kept[kept] = np.linalg.norm(mean[kept] - mean_star[kept], axis=1) <= cfg.cross_check_m
    spread_sq = np.where(good, np.sum((P - mean[:, None]) ** 2, axis=2), 0.0).sum(axis=1)
    idx = keys[kept].astype(int)
    spread = np.sqrt(spread_sq[kept] / np.maximum(n_good[kept], 1))
    observations = [(k_all[first[g]:first[g] + count[g]][good[g, :count[g]]],
                     x_all[first[g]:first[g] + count[g]][good[g, :count[g]]].reshape(-1, 2))
                    for g in np.flatnonzero(kept)]
    stats["map_points"] = len(idx)
    # survey geometry for the baseline check (Eq. 199): the widest reference-to-view baseline and the map's depth
    stats["survey_baseline_m"] = float(max(np.linalg.norm(T[:3, 3]) for T in T_ref_views))
    stats["median_depth_m"] = float(np.median(mean[kept, 2])) if len(idx) else float("nan")
    return KeypointMap(mean[kept], mean_star[kept], reference.features.subset(idx), n_good[kept].astype(int), spread,
                       T_world_ref, stats, reference.x_n[idx], T_ref_views, observations, idx)


def twin_map_config(twin_keypoints: str = "both") -> MapConfig:
    """The map's settings for SIFT's twin keypoints: ``"both"`` copies (the thesis's map), one point per detection
    (``"once"``: :attr:`MapConfig.duplicate_px` = :data:`TWIN_PX`), or both copies with each view's shared keypoint
    weighed as what it is worth in the joint bundle (``"weighted"``: :attr:`MapConfig.one_keypoint_px` =
    :data:`TWIN_PX`, :data:`TWIN_WORTH` measurements)."""
    if twin_keypoints not in TWIN_CHOICES:
        raise ValueError(f"twin_keypoints: expected one of {', '.join(TWIN_CHOICES)}, got {twin_keypoints!r}")
    return MapConfig(duplicate_px=TWIN_PX if twin_keypoints == "once" else 0.0,
                     one_keypoint_px=TWIN_PX if twin_keypoints == "weighted" else 0.0)


def _merge_twins(uv, matches: list, tol_px: float) -> tuple:
    """The reference keypoints within ``tol_px`` of each other (SIFT's twins: one detection) made one: every match of
    a copy becomes a match of the group's representative - the copy matched in most views, then the first - so the
    map point is observed wherever any copy was matched; where several copies matched in one view, the
    representative's own match is kept (else the first). ``(matches, copies merged)``; ``tol_px`` 0 leaves them."""
    n_matched = np.zeros(len(uv), int)
    for m in matches:
        np.add.at(n_matched, m.i1, 1)
    rep = _twin_representatives(uv, n_matched, np.zeros(len(uv)), tol_px)
    copies = (rep != np.arange(len(uv))) & (n_matched > 0)
    if not copies.any():
        return list(matches), 0
    merged = []
    for m in matches:
        own = rep[m.i1] == m.i1
        pick = np.lexsort((np.arange(len(m)), ~own, rep[m.i1]))  # by representative, its own match first
        _, first = np.unique(rep[m.i1][pick], return_index=True)
        keep = np.sort(pick[first])
        merged.append(Matches(rep[m.i1][keep], m.i2[keep], m.distance[keep], m.ratio[keep]))
    return merged, int(copies.sum())


def one_per_detection(kmap: KeypointMap, tol_px: float = TWIN_PX) -> tuple:
    """The map points left when each detection counts once: of the points whose reference keypoints lie within
    ``tol_px`` of each other (SIFT's orientations of one keypoint), the one seen in most surrounding views.

    Returns
    -------
    one : ndarray (M',) int
        Increasing map indices of the points kept.
    merge : ndarray (M, M') bool
        ``merge[i, j]``: map point ``i`` is a copy of kept point ``j`` (or ``j`` itself). A detection is observed
        wherever any of its copies was: ``vis @ merge`` for a pattern ``vis (V, M)`` over the map points.
    """
    rep = _twin_representatives(kmap.features.uv, kmap.n_views, kmap.spread_m**2, tol_px)
    one = np.flatnonzero(rep == np.arange(len(rep)))
    return one, rep[:, None] == one[None]


def _twin_representatives(uv, n_views, spread_sq, tol_px: float) -> np.ndarray:
    """Each point's kept twin: the points whose keypoints are linked by distances within ``tol_px`` are one group of
    coincident detections, represented by its best point (the most surrounding views, then the smallest spread,
    then the first).

    Parameters
    ----------
    uv : ndarray (M, 2)
        The points' reference keypoints (px).
    n_views, spread_sq : ndarray (M,)
    tol_px : float

    Returns
    -------
    ndarray (M,) int
        The index of the point that represents each point's group (a point kept represents itself).
    """
    if not (np.isfinite(tol_px) and 0 <= tol_px <= 1):
        raise ValueError(f"duplicate_px: expected 0 (keep every keypoint) up to 1 px (SIFT's twins coincide to "
                         f"1e-6 px), got {tol_px!r}")
    rep = np.arange(len(uv))
    if tol_px == 0 or len(uv) < 2:
        return rep
    pairs = cKDTree(uv).query_pairs(float(tol_px), output_type="ndarray")
    if not len(pairs):
        return rep
    _, label = connected_components(coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                                               shape=(len(uv), len(uv))), directed=False)
    order = np.lexsort((rep, spread_sq, -np.asarray(n_views)))  # best first
    _, at = np.unique(label[order], return_index=True)  # the labels are 0 .. n-1: one best point per label
    return order[at][label]


@dataclass
class LocateResult:
    """Outcome of :func:`locate` / :func:`locate_pnp`; never raised for too few matches or no consensus.

    Attributes
    ----------
    success : bool
    message : str
    T_world_base : ndarray (4, 4)
        The base pose in the site frame (NaN on failure).
    T_ref_cam : ndarray (4, 4)
        Pose of locate view a (the camera) in the reference camera frame.
    covariance : ndarray (6, 6)
        First-order covariance of the base pose (rotation vector rad in the world frame, then translation m).
    condition : float
        Condition number of the final alignment (large = ill-conditioned; reported, and warned in ``message``).
    n_matches, n_inliers : int
    timings_s : dict
    pose_condition : float
        When the joint bundle refined the pose (``locate_dataset``, refine ``joints``): the condition of the pose it
        solved, where its points are (:func:`bench.vision.integrity.pose_condition`); NaN otherwise. ``condition``
        then stays the thesis estimate's that started it.
    field : dict or None
        With the covariance ``field`` (``locate_dataset``): the keypoint error field behind the covariance
        (:meth:`bench.vision.field_covariance.FieldCovariance.report`: the white noise and each degree's sd, px).
    """

    success: bool
    message: str
    T_world_base: np.ndarray
    T_ref_cam: np.ndarray
    covariance: np.ndarray
    condition: float
    n_matches: int
    n_inliers: int
    timings_s: dict = field(default_factory=dict)
    inliers: np.ndarray | None = None
    p1: np.ndarray | None = None  # matched map points (ref frame) used in the alignment
    p2: np.ndarray | None = None  # their 2p estimates (camera-a frame)
    #: the final solve's points: ``(map indices (N,), x_a (N, 2), x_b (N, 2))`` - which map points views a and b
    #: observed (normalized keypoints), after RANSAC and the reprojection gate; :func:`locate_pnp`: its inliers in
    #: view a, ``x_b`` None
    used: tuple | None = None
    pose_condition: float = float("nan")
    field: dict | None = None


def baseline_check(baseline_m: float, depth_m: float, focal_px: float, resolution_m: float) -> tuple:
    """Is a stereo baseline long enough at a depth (Eq. 123, 199, 1 px disparity error)?

    Returns ``(level, message)``: ``"ok"``; ``"warn"`` when ``baseline_m < required_baseline(depth_m, focal_px,
    resolution_m)``; ``"fail"`` when ``baseline_m < BASELINE_FAIL_RATIO * depth_m / focal_px`` (a 1 px disparity
    error is a depth error as large as the depth). ``message`` states the figures.
    """
    if not (np.isfinite(depth_m) and depth_m > 0 and focal_px > 0 and resolution_m > 0):
        return "ok", ""
    need = float(required_baseline(depth_m, focal_px, resolution_m))  # Eq. 199
    dz = depth_m**2 / (focal_px * max(baseline_m, 1e-300))  # Eq. 123, |dz| for ds = 1 px
    text = (f"baseline {baseline_m * 1e3:.3g} mm at depth {depth_m:.3g} m: 1 px of disparity is {dz * 1e3:.3g} mm "
            f"of depth (Eq. 123); Eq. 199 needs {need * 1e3:.3g} mm for {resolution_m * 1e3:.3g} mm")
    if baseline_m < BASELINE_FAIL_RATIO * depth_m / focal_px:
        return "fail", text
    return ("warn", text) if baseline_m < need else ("ok", text)


def _survey_warning(kmap: KeypointMap, focal_px: float, cfg: MapConfig) -> str:
    level, text = baseline_check(kmap.stats.get("survey_baseline_m", np.inf), kmap.stats.get("median_depth_m", np.nan),
                                 focal_px, cfg.neighbour_m)
    return "" if level == "ok" else f"; WARNING survey {text} (d_n): map depths are coarse"


def _failure(msg, n_matches=0, timings=None):
    nan = np.full((4, 4), np.nan)
    return LocateResult(False, msg, nan, nan, np.full((6, 6), np.nan), np.nan, n_matches, 0, timings or {})


def _base_covariance(cov_ref_a, T_world_ref, T_ref_a, T_base_a):
    """Propagate the covariance of ``T_ref_a`` (left rotation vector in the ref frame, then t) to ``T_world_base``.

    ``T_world_base = T_world_ref T_ref_a T_a_base``: a left perturbation ``exp(dphi) R, t + dt`` of ``T_ref_a``
    becomes, in the world frame, ``dphi_w = R_wr dphi`` and ``dt_w = R_wr (dt + dphi x (p - t_ref_a))`` for the base
    origin ``p`` expressed in the ref frame.
    """
    R_wr = T_world_ref[:3, :3]
    p = (T_ref_a @ invert(T_base_a))[:3, 3]
    d = p - T_ref_a[:3, 3]
    J = np.zeros((6, 6))
    J[:3, :3] = R_wr
    J[3:, :3] = -R_wr @ skew(d)
    J[3:, 3:] = R_wr
    return J @ cov_ref_a @ J.T


def locate(kmap: KeypointMap, view_a: ViewObservation, view_b: ViewObservation, config: MapConfig | None = None,
           method: str = "svd", d_r: float = 0.020, iterations: int = 100, adaptive: bool = False,
           r_lim: float | None = 0.1, rng=None, max_condition: float = 1e6, refine: bool = True,
           focal_px: float = 1000.0, matches: tuple | None = None) -> LocateResult:
    """Base pose from two new views (Eq. 165-166 + section 3.8 + link 5).

    Parameters
    ----------
    kmap : KeypointMap
    view_a, view_b : ViewObservation
        The two views after the base moved; ``T_base_cam`` from the kinematics in the *new* base frame.
    method : {"svd", "horn", "rodrigues"}
        Absolute-orientation estimator (LMS [21], Horn, or the thesis's quaternion method).
    d_r, iterations, adaptive, r_lim : RANSAC distance (m), iterations, adaptive count, error-ratio limit (thesis:
        20 mm, 100, fixed, 0.1).
    rng : numpy.random.Generator or int, optional
    refine : bool or {"none", "pose", "bundle"}
        After the thesis's alignment: ``"pose"`` (or True) minimises the reprojection error of the inlier map points
        in both views over the 6 pose parameters (:func:`refine_pose`, with its reprojection gate); ``"bundle"``
        then refines the map points and the pose together on every observation (:func:`bundle_refine`, the
        maximum-likelihood estimate given the kinematics). The reported covariance is that of the final
        least-squares problem; ``"none"`` (or False) reports the alignment's own first-order covariance.
    focal_px : float
        Focal length (px) of the camera: converts the 1 px disparity error of the baseline checks (Eq. 123, 199;
        see :data:`BASELINE_FAIL_RATIO`) to normalized units.
    matches : (Matches, Matches), optional
        The map -> a and a -> b matches, as :func:`match_features` gives them with ``config``'s ratio and
        orientation tolerance; computed here when omitted. Lets a caller that locates many pairs against the same
        maps (the x-y table experiments) match each combination once.

    Returns
    -------
    LocateResult
    """
    cfg = config or MapConfig()
    if refine not in (True, False, "none", "pose", "bundle"):
        raise ValueError(f"refine: expected True, False, 'none', 'pose' or 'bundle', got {refine!r}")
    refine = {True: "pose", False: "none"}.get(refine, refine)
    t0 = time.perf_counter()
    timings = {}
    if len(kmap) < 3:
        return _failure(f"the map has {len(kmap)} points; at least 3 are needed")
    if matches is None:
        matches = (view_matches(kmap.features, view_a.features, cfg),
                   view_matches(view_a.features, view_b.features, cfg))
    m_a, m_ab = matches  # map <-> a, a <-> b
    timings["match_s"] = time.perf_counter() - t0
    b_of_a = np.full(len(view_a.features), -1)
    b_of_a[m_ab.i1] = m_ab.i2
    sel = b_of_a[m_a.i2] >= 0
    i_map, i_a = m_a.i1[sel], m_a.i2[sel]
    i_b = b_of_a[i_a]
    if len(i_map) < 3:
        return _failure(f"only {len(i_map)} keypoints matched in the map and both views (need >= 3)", len(i_map),
                        timings)
    T_a_b = invert(np.asarray(view_a.T_base_cam, float)) @ np.asarray(view_b.T_base_cam, float)
    baseline = float(np.linalg.norm(T_a_b[:3, 3]))
    if baseline < 1e-4:
        return _failure(f"the two views are {baseline * 1e3:.3f} mm apart: no baseline to triangulate", len(i_map),
                        timings)
    tri = triangulate_midpoint([np.eye(4), T_a_b], [view_a.x_n[i_a], view_b.x_n[i_b]])  # Eq. 165 (a's ray) / 166
    ok = tri.valid & (tri.gap <= cfg.gap_max_m)
    p1, p2 = kmap.p_ref[i_map[ok]], tri.ray_points[0][ok]
    timings["triangulate_s"] = time.perf_counter() - t0 - timings["match_s"]
    if len(p1) < 3:
        return _failure(f"only {len(p1)} of {len(i_map)} matches triangulate within {cfg.gap_max_m * 1e3:g} mm",
                        len(i_map), timings)
    # depth: the matched map points' median depth in the reference view (a depth triangulated from a short pair is
    # itself unreliable); the locate views look at the same scene
    level, text = baseline_check(baseline, float(np.median(kmap.p_ref[i_map[ok], 2])), focal_px, d_r)  # Eq. 123, 199
    if level == "fail":
        return _failure(f"no depth from the locate pair: {text}", len(p1), timings)
    warning = f"; WARNING locate pair {text} (d_r): 2p is coarser than the RANSAC distance" if level == "warn" else ""
    warning += _survey_warning(kmap, focal_px, cfg)
    res = ransac_absolute_orientation(p1, p2, d_r=d_r, iterations=iterations, adaptive=adaptive, method=method,
                                      r_lim=r_lim, rng=rng, max_condition=max_condition)
    timings["align_s"] = time.perf_counter() - t0 - timings["match_s"] - timings["triangulate_s"]
    if not res.success:
        timings["total_s"] = time.perf_counter() - t0
        out = _failure(f"alignment failed: {res.message}", len(p1), timings)
        out.p1, out.p2 = p1, p2
        return out
    T_ref_a = res.T
    T_base_a = np.asarray(view_a.T_base_cam, float)
    orient = res.orientation
    cov_ref_a, cond = orient.covariance, float(orient.condition)
    msg = f"{int(res.inliers.sum())} of {len(p1)} 3D matches kept, rms {res.rms * 1e3:.2f} mm"
    used = np.flatnonzero(ok)[res.inliers]
    if refine != "none":
        sel_ok = used
        rp = refine_pose(kmap.p_ref[i_map[sel_ok]], view_a.x_n[i_a[sel_ok]], view_b.x_n[i_b[sel_ok]], T_a_b, T_ref_a)
        if rp.success:
            T_ref_a, cov_ref_a, cond = rp.T_ref_a, rp.covariance, rp.condition
            msg += f"; refined on reprojection: rms {rp.rms:.3g} (normalized), {rp.iterations} iterations"
            used = sel_ok[rp.kept]
            if not rp.kept.all():
                msg += f", {int((~rp.kept).sum())} points beyond the reprojection gate dropped"
            if refine == "bundle":
                bp = bundle_refine(kmap, i_map[used], view_a.x_n[i_a[used]], view_b.x_n[i_b[used]], T_a_b, T_ref_a)
                if bp.success:
                    T_ref_a, cov_ref_a, cond = bp.T_ref_a, bp.covariance, bp.condition
                    msg += f"; {bp.message[4:]}, rms {bp.rms:.3g}, {bp.iterations} iterations"
                else:
                    msg += f"; bundle skipped ({bp.message})"
        else:
            msg += f"; refinement skipped ({rp.message})"
        timings["refine_s"] = time.perf_counter() - t0 - sum(timings.values())
    timings["total_s"] = time.perf_counter() - t0
    T_world_base = kmap.T_world_ref @ T_ref_a @ invert(T_base_a)
    cov = _base_covariance(cov_ref_a, kmap.T_world_ref, T_ref_a, T_base_a)
    msg += warning
    if cond > WARN_CONDITION:
        msg += f"; WARNING ill-conditioned point spread (condition {cond:.3g})"
    return LocateResult(True, msg, T_world_base, T_ref_a, cov, cond, len(p1), int(res.inliers.sum()), timings,
                        res.inliers, p1, p2, (i_map[used], view_a.x_n[i_a[used]], view_b.x_n[i_b[used]]))


@dataclass(frozen=True)
class RefineResult:
    """Outcome of :func:`refine_pose`."""

    success: bool
    message: str
    T_ref_a: np.ndarray
    covariance: np.ndarray  # (6, 6): left rotation vector (rad) then translation (m) of T_ref_a, ref frame
    rms: float  # normalized units
    condition: float
    iterations: int
    kept: np.ndarray | None = None  # (N,) bool: points left after the reprojection gate (all True without one)


def _proj_jac(X):
    """Normalized projection of camera-frame points ``X (N, 3)`` and its Jacobian ``(N, 2, 3)``."""
    z = X[:, 2:3]
    x = X[:, :2] / z
    J = np.zeros((len(X), 2, 3))
    J[:, 0, 0] = J[:, 1, 1] = 1.0 / z[:, 0]
    J[:, :, 2] = -x / z
    return x, J


def _left_exp(delta):
    """``[[exp([w]x), v], [0, 1]]`` for ``delta = (w, v)``: the left perturbation ``T <- D T`` (:func:`refine_pose`)."""
    return homogeneous(rotation_vector_to_matrix(delta[:3]), delta[3:])


def pose_reprojection(T_a_ref, T_b_a, p_ref):
    """Projections of map points in views a and b and their derivative w.r.t. a left perturbation of ``T_a_ref``.

    Parameters
    ----------
    T_a_ref : ndarray (4, 4)
        Pose of the reference frame in camera a (the estimate).
    T_b_a : ndarray (4, 4)
        Camera a in camera b (fixed, from the kinematics).
    p_ref : ndarray (N, 3)
        Map points in the reference camera frame (m).

    Returns
    -------
    u : ndarray (2N, 2)
        Normalized projections, view a's N rows then view b's.
    J : ndarray (4N, 6)
        ``d u / d(w, v)`` for ``T_a_ref <- [[exp([w]x), v], [0, 1]] T_a_ref`` (rows as ``u.ravel()``).
    z_min : float
        The smallest depth of a point in either camera (m); ``<= 0`` means a point is behind a camera.
    """
    Xa, Xb, ua, ub, Ja, Jb, dX = _two_view(T_a_ref, T_b_a, p_ref)
    J = np.concatenate([Ja @ dX, Jb @ (T_b_a[:3, :3] @ dX)], axis=0).reshape(-1, 6)
    return np.concatenate([ua, ub], axis=0), J, float(min(Xa[:, 2].min(), Xb[:, 2].min()))


def _two_view(T_a_ref, T_b_a, p_ref):
    """Map points ``p_ref (N, 3)`` in views a and b: ``Xa, Xb`` (camera frames), normalized projections ``ua, ub``,
    their derivatives ``Ja, Jb (N, 2, 3)`` w.r.t. the camera-frame point, and ``dX (N, 3, 6)`` = d Xa / d(w, v) for a
    left perturbation of ``T_a_ref``."""
    n = len(p_ref)
    Xa = transform_points(T_a_ref, p_ref)
    Xb = transform_points(T_b_a, Xa)
    ua, Ja = _proj_jac(Xa)
    ub, Jb = _proj_jac(Xb)
    dX = np.concatenate([-skew(Xa), np.broadcast_to(np.eye(3), (n, 3, 3))], axis=2)
    return Xa, Xb, ua, ub, Ja, Jb, dX


def inverse_perturbation_jacobian(T_ref_a):
    """``M (6, 6)``: a left perturbation ``(w, v)`` of ``T_a_ref = T_ref_a^-1`` is the left perturbation ``M (w, v)``
    of ``T_ref_a`` (``(D T_a_ref)^-1 = Ad(T_ref_a) D^-1 T_ref_a``): ``w' = -R w``, ``v' = -R v - [t]x R w``."""
    R, t = T_ref_a[:3, :3], T_ref_a[:3, 3]
    M = np.zeros((6, 6))
    M[:3, :3] = -R
    M[3:, 3:] = -R
    M[3:, :3] = -skew(t) @ R
    return M


def _gauss_newton(p_ref, x_ab, T_b_a, T_a_ref, iterations):
    """Gauss-Newton on the two-view reprojection error; returns ``(T_a_ref, iterations, failure message or "")``."""
    it = 0
    for it in range(1, iterations + 1):
        u, J, z_min = pose_reprojection(T_a_ref, T_b_a, p_ref)
        if z_min <= 0:
            return T_a_ref, it, "points behind a camera"
        r = (x_ab - u).ravel()
        N = J.T @ J
        cond = float(np.linalg.cond(N))
        if not cond < 1e14:
            return T_a_ref, it, f"singular normal matrix (condition {cond:.3g})"
        delta = np.linalg.solve(N, J.T @ r)
        T_a_ref = _left_exp(delta) @ T_a_ref
        if np.abs(delta).max() < 1e-13:
            break
    return T_a_ref, it, ""


def refine_pose(p_ref, x_a, x_b, T_a_b, T_ref_a0, iterations: int = 20, gate: float | None = 3.0) -> RefineResult:
    """Minimise the reprojection error of map points in two views over the pose ``T_ref_a`` (Gauss-Newton).

    Estimated: ``T_ref_a`` (6 parameters, a left perturbation of ``T_a_ref``). Fixed: the map points ``p_ref (N, 3)``
    and the relative pose ``T_a_b`` of the two views (arm kinematics). Residuals: ``x_a - pi(T_a_ref p)`` and
    ``x_b - pi(T_b_a T_a_ref p)`` in normalized coordinates (:func:`pose_reprojection`). Covariance
    ``s^2 (J^T J)^-1`` with ``s^2`` from the residuals, mapped to a left rotation vector and translation of
    ``T_ref_a`` in the reference frame (:func:`inverse_perturbation_jacobian`).

    ``gate``: after each fit, points whose reprojection error (both views) exceeds ``gate`` times the robust scale
    ``1.4826 median`` of all points' errors are dropped and the pose is refitted, until none is dropped (at most
    five rounds, at least six points kept). RANSAC's 3D gate (d_r, 20 mm) cannot see a match that lands on a
    similar-looking feature a few millimetres away - repeated bolts, growth, stencils - but its reprojection error is
    many pixels; ``None`` keeps every point (plain least squares).
    """
    p_ref, x_a, x_b = (np.asarray(v, dtype=float) for v in (p_ref, x_a, x_b))
    n = len(p_ref)
    nan6 = np.full((6, 6), np.nan)
    if n < 3:
        return RefineResult(False, f"{n} points (need >= 3)", T_ref_a0, nan6, np.nan, np.inf, 0)
    T_b_a = invert(np.asarray(T_a_b, float))
    T_a_ref = invert(np.asarray(T_ref_a0, float))
    keep = np.ones(n, dtype=bool)
    total = 0
    for _ in range(5 if gate else 1):
        x_ab = np.concatenate([x_a[keep], x_b[keep]], axis=0)
        T_a_ref, it, fail = _gauss_newton(p_ref[keep], x_ab, T_b_a, T_a_ref, iterations)
        total += it
        if fail:
            return RefineResult(False, fail, T_ref_a0, nan6, np.nan, np.inf, total, keep)
        if not gate:
            break
        u, _, _ = pose_reprojection(T_a_ref, T_b_a, p_ref)
        e = np.hypot(np.linalg.norm(x_a - u[:n], axis=1), np.linalg.norm(x_b - u[n:], axis=1))
        scale = max(1.4826 * float(np.median(e[keep])), 1e-9)  # floor: ~1e-6 px, exact data keeps every point
        new = e <= gate * scale
        if np.array_equal(new, keep) or new.sum() < 6:
            break
        keep = new
    u, J, _ = pose_reprojection(T_a_ref, T_b_a, p_ref[keep])
    N = J.T @ J
    r = (np.concatenate([x_a[keep], x_b[keep]], axis=0) - u).ravel()
    s2 = float(r @ r) / max(len(r) - 6, 1)
    cov_a = s2 * np.linalg.inv(N)  # left perturbation of T_a_ref, in frame a
    T_ref_a = invert(T_a_ref)
    M = inverse_perturbation_jacobian(T_ref_a)
    msg = "ok" if keep.all() else f"ok; {int((~keep).sum())} of {n} points beyond {gate:g} x the robust scale dropped"
    return RefineResult(True, msg, T_ref_a, M @ cov_a @ M.T, float(np.sqrt(np.mean(r**2))), float(np.linalg.cond(N)),
                        total, keep)


def bundle_refine(kmap: KeypointMap, idx, x_a, x_b, T_a_b, T_ref_a0, iterations: int = 20) -> RefineResult:
    """The locate view's pose and the map points together, on every observation of them (maximum likelihood).

    The thesis fixes the map ¹p (averaged pairwise triangulations, Eq. 162) and aligns ²p to it; :func:`refine_pose`
    fixes the map and minimises the reprojection error in the two new views. Here the map points move too: estimated
    are ``T_ref_a`` (6 parameters, as in :func:`refine_pose`) and the 3D points ``p_ref[idx]``; fixed are the
    camera poses of the survey (reference = identity, surrounding views ``kmap.T_ref_views``) and ``T_a_b`` (all from
    the kinematics). Residuals (normalized coordinates): every point in the reference view, in each surrounding view
    that contributed to it (``kmap.observations``), and in views a and b (``x_a``, ``x_b``). Gauss-Newton with the
    points eliminated one by one (Schur complement); the covariance of the pose is ``s^2 S^-1`` of the reduced system
    (``s^2`` from the residuals), so it carries the map's uncertainty - which :func:`refine_pose`'s does not.

    Parameters
    ----------
    kmap : KeypointMap
        With ``x_ref``, ``T_ref_views`` and ``observations`` (as :func:`build_map` makes it).
    idx : array_like (N,) int
        The map points to use (e.g. the alignment's inliers), with ``x_a (N, 2)``, ``x_b (N, 2)`` their keypoints
        in views a and b.
    T_a_b, T_ref_a0 : ndarray (4, 4)
        View b in view a (kinematics); the starting pose of view a in the reference frame.
    """
    idx = np.asarray(idx, dtype=int)
    x_a, x_b = np.asarray(x_a, float), np.asarray(x_b, float)
    n = len(idx)
    nan6 = np.full((6, 6), np.nan)
    if kmap.observations is None or kmap.x_ref is None:
        return RefineResult(False, "the map carries no observations (built by an older build_map)", T_ref_a0, nan6,
                            np.nan, np.inf, 0)
    if n < 3:
        return RefineResult(False, f"{n} points (need >= 3)", T_ref_a0, nan6, np.nan, np.inf, 0)
    # fixed views: (point, R, t, x) rows - the reference and the surrounding views
    T_views = [invert(T) for T in kmap.T_ref_views]
    pts, Rs, ts, xs = [np.arange(n)], [np.broadcast_to(np.eye(3), (n, 3, 3))], [np.zeros((n, 3))], [kmap.x_ref[idx]]
    for j, i in enumerate(idx):
        views, x = kmap.observations[i]
        if len(views):
            pts.append(np.full(len(views), j))
            Rs.append(np.array([T_views[k][:3, :3] for k in views]))
            ts.append(np.array([T_views[k][:3, 3] for k in views]))
            xs.append(x)
    pts, Rs, ts, xs = (np.concatenate(v) for v in (pts, Rs, ts, xs))
    X = kmap.p_ref[idx].copy()
    T_b_a = invert(np.asarray(T_a_b, float))
    T_a_ref = invert(np.asarray(T_ref_a0, float))

    def linearise(T_a_ref, X):
        """Residuals and Jacobians: fixed rows (r, A), view rows (r, A, B); and whether every point is in front."""
        Xc = np.einsum("nij,nj->ni", Rs, X[pts]) + ts
        u, Jp = _proj_jac(Xc)
        fixed = (xs - u, Jp @ Rs)
        Xa, Xb, ua, ub, Ja, Jb, dX = _two_view(T_a_ref, T_b_a, X)
        Rba = T_b_a[:3, :3]
        views = (np.concatenate([x_a - ua, x_b - ub]), np.concatenate([Ja @ T_a_ref[:3, :3],
                                                                        Jb @ Rba @ T_a_ref[:3, :3]]),
                 np.concatenate([Ja @ dX, Jb @ (Rba @ dX)]))
        front = min(Xc[:, 2].min(), Xa[:, 2].min(), Xb[:, 2].min()) > 0
        return fixed, views, front

    def normal_equations(fixed, views):
        (rf, Af), (rv, Av, Bv) = fixed, views
        pv = np.concatenate([np.arange(n), np.arange(n)])
        V = np.zeros((n, 3, 3))
        np.add.at(V, pts, np.swapaxes(Af, 1, 2) @ Af)
        np.add.at(V, pv, np.swapaxes(Av, 1, 2) @ Av)
        ga = np.zeros((n, 3))
        np.add.at(ga, pts, np.einsum("nki,nk->ni", Af, rf))
        np.add.at(ga, pv, np.einsum("nki,nk->ni", Av, rv))
        W = np.zeros((n, 6, 3))
        np.add.at(W, pv, np.swapaxes(Bv, 1, 2) @ Av)
        U = np.einsum("nki,nkj->ij", Bv, Bv)
        gb = np.einsum("nki,nk->i", Bv, rv)
        Vinv = np.linalg.inv(V)
        WVi = W @ Vinv
        S = U - np.einsum("nij,nkj->ik", WVi, W)
        g = gb - np.einsum("nij,nj->i", WVi, ga)
        return S, g, ga, W, Vinv

    it, S = 0, None
    for it in range(1, iterations + 1):
        fixed, views, front = linearise(T_a_ref, X)
        if not front:
            return RefineResult(False, "points behind a camera", T_ref_a0, nan6, np.nan, np.inf, it)
        S, g, ga, W, Vinv = normal_equations(fixed, views)
        cond = float(np.linalg.cond(S))
        if not cond < 1e14:
            return RefineResult(False, f"singular reduced system (condition {cond:.3g})", T_ref_a0, nan6, np.nan,
                                cond, it)
        d_pose = np.linalg.solve(S, g)
        dX = np.einsum("nij,nj->ni", Vinv, ga - np.einsum("nji,j->ni", W, d_pose))
        T_a_ref = _left_exp(d_pose) @ T_a_ref
        X = X + dX
        if max(np.abs(d_pose).max(), np.abs(dX).max()) < 1e-13:
            break
    fixed, views, _ = linearise(T_a_ref, X)
    S, *_ = normal_equations(fixed, views)
    r = np.concatenate([fixed[0].ravel(), views[0].ravel()])
    s2 = float(r @ r) / max(len(r) - 6 - 3 * n, 1)
    T_ref_a = invert(T_a_ref)
    M = inverse_perturbation_jacobian(T_ref_a)
    return RefineResult(True, f"ok; bundle of {n} points, {len(r) // 2} observations", T_ref_a,
                        M @ (s2 * np.linalg.inv(S)) @ M.T, float(np.sqrt(np.mean(r**2))), float(np.linalg.cond(S)),
                        it, np.ones(n, dtype=bool))


def locate_pnp(kmap: KeypointMap, view_a: ViewObservation, config: MapConfig | None = None,
               reprojection_px: float = 2.0, focal_px: float = 1000.0, rng_seed: int = 0) -> LocateResult:
    """Single-view alternative: PnP against ``1p`` with RANSAC, then LM refinement on the inliers.

    ``focal_px`` converts the pixel threshold to normalized units (the coordinates are already undistorted and
    normalized, so PnP runs with ``K = I``).
    """
    cfg = config or MapConfig()
    t0 = time.perf_counter()
    m = view_matches(kmap.features, view_a.features, cfg)
    if len(m) < 4:
        return _failure(f"only {len(m)} map matches (PnP needs >= 4)", len(m))
    obj = kmap.p_ref[m.i1].astype(np.float64)
    img = view_a.x_n[m.i2].astype(np.float64)
    cv2.setRNGSeed(rng_seed)
    ok, rvec, tvec, inl = cv2.solvePnPRansac(obj, img, np.eye(3), None, reprojectionError=reprojection_px / focal_px,
                                             iterationsCount=1000, confidence=0.999, flags=cv2.SOLVEPNP_EPNP)
    if not ok or inl is None or len(inl) < 4:
        return _failure("PnP RANSAC found no consensus", len(m), {"total_s": time.perf_counter() - t0})
    inl = inl.ravel()
    rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], np.eye(3), None, rvec, tvec)
    R, _ = cv2.Rodrigues(rvec)
    T_a_ref = homogeneous(R, tvec.ravel())
    T_ref_a = invert(T_a_ref)
    T_base_a = np.asarray(view_a.T_base_cam, float)
    T_world_base = kmap.T_world_ref @ T_ref_a @ invert(T_base_a)
    # covariance: Gauss-Newton normal matrix of the reprojection residuals at the optimum, in (rvec, tvec) of T_a_ref,
    # carried to T_world_base by a numerical Jacobian of the (small) pose change (left rotation vector, translation)
    proj, J = cv2.projectPoints(obj[inl], rvec, tvec, np.eye(3), None)[:2]
    r = (img[inl] - proj.reshape(-1, 2)).ravel()
    Jp = J[:, :6]
    s2 = float(r @ r) / max(len(r) - 6, 1)
    N = Jp.T @ Jp
    cond = float(np.linalg.cond(N))
    cov_rt = s2 * np.linalg.pinv(N)

    def world_base(x):
        Ta = homogeneous(rotation_vector_to_matrix(x[:3]), x[3:])  # x = (OpenCV's rvec, tvec) of T_a_ref
        return kmap.T_world_ref @ invert(Ta) @ invert(T_base_a)

    x0 = np.concatenate([rvec.ravel(), tvec.ravel()])
    Jw = np.zeros((6, 6))
    for k in range(6):
        h = np.zeros(6)
        h[k] = 1e-7
        Tp, Tm = world_base(x0 + h), world_base(x0 - h)
        Jw[:3, k] = matrix_to_rotation_vector(Tp[:3, :3] @ Tm[:3, :3].T) / 2e-7
        Jw[3:, k] = (Tp[:3, 3] - Tm[:3, 3]) / 2e-7
    cov = Jw @ cov_rt @ Jw.T
    err = np.linalg.norm((img[inl] - proj.reshape(-1, 2)), axis=1)
    msg = f"PnP: {len(inl)} of {len(m)} matches kept, rms {np.sqrt(np.mean(err**2)) * focal_px:.2f} px"
    msg += _survey_warning(kmap, focal_px, cfg)
    if cond > WARN_CONDITION:
        msg += f"; WARNING ill-conditioned point spread (condition {cond:.3g})"
    return LocateResult(True, msg, T_world_base, T_ref_a, cov, cond, len(m), len(inl),
                        {"total_s": time.perf_counter() - t0}, None, obj[inl], transform_points(T_a_ref, obj[inl]),
                        (np.asarray(m.i1)[inl], img[inl], None))
