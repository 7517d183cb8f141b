"""Camera positioning on the x-y table (thesis section 5.2.2 and 5.4): the accuracy experiment of Tables 5-8, 11-14.

A camera rides on the rotary stage of an x-y table and photographs a reference object from the poses of Table 4
(21 views, web camera on the rotation axis) or Table 10 (17 views, underwater camera 100 mm off the axis). The table's
readings give every view's pose; the vision pipeline of section 3.9 then estimates, for every pair of views at a given
intraocular distance, the position of one of them relative to the reference view - by vision alone - and the
experiment compares it with the table's readings (the thesis) or the truth (the bench's evaluator).

Frames (SI inside, ``T_a_b`` maps ``b`` to ``a``): ``table`` - the table's axes (x and z along the slides, y down the
rotary axis, origin on the axis at the camera height with both slides centred; the thesis's reference frame is this
frame moved to the reference camera's centre); ``stage`` - the rotary stage (origin on the axis, turning about y);
``cam`` - the camera's optical frame (x right, y down, z forward).

Nominal kinematics (what the pipeline knows; the table's positioning errors are not modelled)::

    T_table_stage(x, z, theta) = Trans(x, 0, z) Ry(theta)
    T_stage_cam = [R0 | o]                 (o: the camera centre on the stage, table.yaml; R0: Eq. 197)
    T_table_cam = T_table_stage T_stage_cam

``R0 = Ry(theta_y0) Rx(theta_x0) Rz(theta_z0)`` is the camera's unknown orientation on its support (Eq. 197, factors
applied as labelled: :func:`bench.vision.handeye.mount_rotation`). The thesis writes the view's rotation as
``R_i = R0 R_table,i`` (Eq. 198, the bias applied in the table frame); a camera bolted to the rotary stage turns with
it, so the bias is applied in the stage frame (``R_table,i R0``), as :func:`~bench.vision.handeye.search_mount_rotation`
does. ``R0`` is found by the thesis's search (Eq. 197-198): ``theta_y0`` equalises the mean depth of the points
triangulated against the two extreme views, ``theta_z0`` maximises the rays that coincide within 1 mm,
``theta_x0 = 0`` (no motion along y makes it unobservable).

The experiment (:func:`estimate_positions`), per intraocular distance ``d_o`` (the x-slide travel between the two
views of a pair) and per pair ``(a, b)`` with neither being the reference:

1. ``1p`` - the map (:func:`bench.vision.insitu.build_map`, Eq. 162-164) from the reference and the surrounding views
   at least ``map_min_baseline_m`` from it (Eq. 199: 49 mm for 1 px at 700 mm and 10 mm depth resolution), minus the
   pair and any excluded views; orientation filter 20 deg, coincidence (ray gap) 5 mm;
2. ``2p`` - the pair triangulated (Eq. 165-166) and matched with ``1p`` (:func:`bench.vision.insitu.locate`);
3. ``T_ref_a`` by RANSAC (100 iterations, ``d_r`` = 20 mm) with the quaternion (Rodrigues, section 3.7.2) or the
   LMS [21] (SVD) rotation, without and with error-ratio elimination (``r_lim`` = 0.1): the four methods of
   Tables 5-8 / 11-14;
4. the position of camera ``a`` relative to the reference camera in the table's axes:
   ``p = R_table_ref t_ref_a`` with the estimated ``R0``;
5. beside the thesis's four, optionally (method ``bundle``, at the distances ``bundle_intraocular_mm``): the
   maximum-likelihood estimate from the pixels of every view the estimate uses, started from LMS + error ratio's -
   the pair's displacement, ``R0``, the intrinsics and the distortion under their priors, the points
   (:func:`bench.vision.xy_table_bundle.pair_bundle`).

Features: SIFT keypoints with the thesis's thresholds (:func:`~bench.vision.features.detect_sift`) or, for the
calibration rig of section 5.4, the corners of the rig with their ids (:func:`corner_features`: each corner id becomes
a one-hot descriptor, so the same matching code pairs corners by id - the thesis's "72 correct matches").

The module is pipeline code: it reads the public part of a dataset only (:func:`position_dataset`).
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from bench.dataset import load_dataset
from bench.errors import ConfigError
from bench.fileio import read_yaml
from bench.geometry.transforms import homogeneous, rot_y, transform_points
from bench.vision.absolute_orientation import absolute_orientation
from bench.vision.features import Features, detect_sift
from bench.vision.handeye import mount_rotation, search_mount_rotation
from bench.vision.insitu import MapConfig, ViewObservation, build_map, locate, reference_matches, view_matches
from bench.vision.ransac import ransac_absolute_orientation

#: the four methods of Tables 5-8 (11-14): name -> (rotation estimator, error-ratio elimination)
METHODS = {"quaternion": ("rodrigues", False), "lms": ("svd", False), "quaternion_ratio": ("rodrigues", True),
           "lms_ratio": ("svd", True)}
#: the maximum-likelihood estimate beside them (:mod:`bench.vision.xy_table_bundle`, started from ``lms_ratio``'s)
BUNDLE = "bundle"
#: the bundle's loose prior (deg, per axis) on the camera's rotation on its support: the search's estimate is ~2 deg
#: off; it holds only the rotation about the line of camera centres, which no view of a straight campaign observes
R0_PRIOR_DEG = 10.0
TABLE_SPEC_KEYS = {"camera_offset_mm", "camera_offset_tolerance_mm", "travel_mm", "resolution_mm", "resolution_deg",
                   "notes"}
DESCRIPTOR_SIZE = 128


# ------------------------------------------------------------------------------------------------ the table


@dataclass(frozen=True)
class TableSpec:
    """The x-y table's nominal specification (``table.yaml``; SI).

    Attributes
    ----------
    camera_offset_m : ndarray (3,)
        Camera centre in the stage frame (m): 0 on the axis (section 5.2.2), (-0.1, 0, 0) for the underwater
        camera's support (section 5.4).
    travel_m : float
        Travel of each slide, centred (section 5.2: 200 mm).
    resolution_m, resolution_rad : float
        Slide and rotary resolutions (0.1 mm, 0.1 deg).
    camera_offset_sigma_m : ndarray (3,) or None
        The stated tolerance (1 sigma per axis, m) of the camera centre on the stage (``camera_offset_tolerance_mm``):
        the bundle refines the centre under it; None: the centre is taken as exact.
    """

    camera_offset_m: np.ndarray
    travel_m: float = 0.2
    resolution_m: float = 1e-4
    resolution_rad: float = float(np.deg2rad(0.1))
    camera_offset_sigma_m: np.ndarray | None = None


def load_table_spec(path) -> TableSpec:
    """Read ``table.yaml`` (mm and degrees in the keys); one-line :class:`ConfigError` naming the file and field."""
    path = Path(path)
    doc = read_yaml(path, "not found (an x-y table dataset must describe its table)")
    if not isinstance(doc, dict):
        raise ConfigError(path, "<top>", "expected a mapping")
    bad = sorted(set(doc) - TABLE_SPEC_KEYS)
    if bad:
        raise ConfigError(path, bad[0], f"unknown key (allowed: {', '.join(sorted(TABLE_SPEC_KEYS))})")
    off = doc.get("camera_offset_mm")
    if not (isinstance(off, list) and len(off) == 3 and all(_is_number(v) for v in off)):
        raise ConfigError(path, "camera_offset_mm", f"expected 3 numbers (mm), got {off!r}")
    vals = {}
    for key, default in (("travel_mm", 200.0), ("resolution_mm", 0.1), ("resolution_deg", 0.1)):
        v = doc.get(key, default)
        if not _is_number(v) or v <= 0:
            raise ConfigError(path, key, f"expected a positive number, got {v!r}")
        vals[key] = float(v)
    tol = doc.get("camera_offset_tolerance_mm")
    if tol is not None:
        tol = [tol] * 3 if _is_number(tol) else tol
        if not (isinstance(tol, list) and len(tol) == 3 and all(_is_number(v) and v > 0 for v in tol)):
            raise ConfigError(path, "camera_offset_tolerance_mm", f"expected one or 3 positive numbers (mm, 1 sigma), "
                                                                  f"got {doc['camera_offset_tolerance_mm']!r}")
        tol = np.array(tol, float) * 1e-3
    return TableSpec(np.array(off, float) * 1e-3, vals["travel_mm"] * 1e-3, vals["resolution_mm"] * 1e-3,
                     float(np.deg2rad(vals["resolution_deg"])), tol)


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and bool(np.isfinite(v))


def check_readings(readings, spec: TableSpec, names=None, source="table.csv") -> np.ndarray:
    """Validate table readings ``(N, 3)`` ``[x_m, z_m, rot_rad]``: finite, slides within the travel (give or take
    one resolution step: a table that reads its carriage's true position - a linear scale - reports its scale error
    at the ends of the travel)."""
    r = np.atleast_2d(np.asarray(readings, dtype=float))
    names = list(names) if names is not None else [str(i + 1) for i in range(len(r))]
    if r.ndim != 2 or r.shape[1] != 3:
        raise ConfigError(source, "readings", f"expected (N, 3) [x, z, rot], got shape {np.shape(readings)}")
    half, tol = spec.travel_m / 2, spec.resolution_m
    for name, (x, z, rot) in zip(names, r, strict=True):
        if not np.all(np.isfinite((x, z, rot))):
            raise ConfigError(source, name, "reading is NaN or inf")
        if abs(x) > half + tol or abs(z) > half + tol:
            raise ConfigError(source, name, f"x = {x * 1e3:.1f} mm, z = {z * 1e3:.1f} mm outside the travel of "
                                            f"+-{half * 1e3:.0f} mm")
        if abs(rot) > np.pi:
            raise ConfigError(source, name, f"rot = {np.rad2deg(rot):.1f} deg outside +-180 deg")
    return r


def stage_poses(readings) -> np.ndarray:
    """Nominal ``T_table_stage (..., N, 4, 4)`` of readings ``(..., N, 3)`` ``[x_m, z_m, rot_rad]``: Trans(x, 0, z)
    Ry(rot)."""
    r = np.atleast_2d(np.asarray(readings, dtype=float))
    return homogeneous(rot_y(r[..., 2]), np.stack([r[..., 0], np.zeros(r.shape[:-1]), r[..., 1]], -1))


def stage_camera(R0, camera_offset_m) -> np.ndarray:
    """``T_stage_cam = [R0 | o]``: the camera on its support (Eq. 197's rotation, the centre from ``table.yaml``)."""
    return homogeneous(np.asarray(R0, float), np.asarray(camera_offset_m, float))


# ------------------------------------------------------------------------------------------------ features


def corner_features(uv, ids, n_ids: int) -> Features:
    """Features of target corners: the pixels ``uv (N, 2)`` with their ``ids (N,)`` (< ``n_ids``) as descriptors.

    Each id becomes a one-hot descriptor (``n_ids`` <= 128), so that :func:`~bench.vision.features.match_descriptors`
    pairs corners by id (distance 0 to the same id, sqrt(2) to any other: ratio 0) and the orientation filter keeps
    them all (orientation 0). This is how the corner extractor's labelling provides the matching of section 5.4.
    """
    uv = np.asarray(uv, dtype=float).reshape(-1, 2)
    ids = np.asarray(ids, dtype=int).reshape(-1)
    if len(ids) != len(uv):
        raise ValueError(f"corner_features: {len(uv)} corners but {len(ids)} ids")
    if not 0 < n_ids <= DESCRIPTOR_SIZE or (len(ids) and (ids.min() < 0 or ids.max() >= n_ids)):
        raise ValueError(f"corner_features: ids must lie in [0, {n_ids}) with n_ids <= {DESCRIPTOR_SIZE}")
    if len(np.unique(ids)) != len(ids):
        raise ValueError("corner_features: duplicate corner ids")
    desc = np.zeros((len(ids), DESCRIPTOR_SIZE), np.float32)
    desc[np.arange(len(ids)), ids] = 1.0
    n = len(ids)
    return Features(uv, np.zeros(n), np.full(n, 4.0), np.ones(n), desc)


def rig_corner_features(image, geometry, extractor: str = "opencv"):
    """``(Features or None, message)``: the target's corners in ``image`` by ``extractor``
    (:data:`bench.camera.corners.EXTRACTORS`) as :func:`corner_features`; None with the extractor's message when the
    target is not found. Section 5.4 extracted the rig's corners with "the semi automatic algorithm used in the camera
    calibration" (the thesis's extractor)."""
    from bench.camera.corners import extract_corners

    res = extract_corners(image, geometry, extractor)
    if not res.success:
        return None, res.message
    return corner_features(res.uv, res.ids, geometry.n_corners), ""


# ------------------------------------------------------------------------------------------------ the experiment


@dataclass(frozen=True)
class PositioningConfig:
    """Parameters of the x-y table experiment (thesis values as defaults, section 5.2.2).

    Attributes
    ----------
    reference : str
        Name of the reference view (image 11 of Table 4, image 9 of Table 10).
    intraocular_mm : tuple of float
        Intraocular distances ``d_o`` (x-slide travel between the two views of a pair, mm).
    map_min_baseline_m : float
        Views closer than this to the reference are not used for ``1p`` (Eq. 199: 49 mm); 0 disables the rule.
    map_exclude : tuple of str
        Views never used for ``1p`` (section 5.4: images 7, 8, 10, 11).
    map : MapConfig
        Matching and triangulation filters (ratio 0.8, orientation 20 deg, gap 5 mm, ...).
    ransac_iterations, d_r_m, r_lim : int, float, float
        RANSAC samples (100), inlier distance (20 mm), error-ratio limit (0.1).
    methods : tuple of str
        Keys of :data:`METHODS` (the thesis's estimators) and :data:`BUNDLE` (the bundle over the estimate's views,
        :func:`~bench.vision.xy_table_bundle.pair_bundle`, started from ``lms_ratio``'s estimate).
    bundle_R0_prior_deg : float
        The bundle's prior (deg per axis) on the correction of the searched ``R0``.
    bundle_intraocular_mm : tuple of float or None
        The intraocular distances at which the bundle runs (~0.3 s per estimate); None: all.
    bundle_centre : bool
        The bundle refines the camera centre on the stage under ``table.yaml``'s stated tolerance
        (``camera_offset_tolerance_mm``). Off by default: under realistic imaging the centre's lateral coordinate,
        the principal point and ``R0`` absorb the lens's unmodelled warp together (seed 1 of ``xy_table_webcam``:
        the centre moves 16 mm, against a 1 mm tolerance, and z errs by 0.9 mm instead of 0.07 mm).
    bundle_readings : bool
        The bundle refines every view's table reading under a prior of one resolution step (``table.yaml``'s
        ``resolution_mm`` / ``resolution_deg``, a uniform quantisation: step / sqrt(12)); False: readings exact.
    bias_grid_y_deg, bias_grid_z_deg : (start, stop, step)
        Search grids of ``theta_y0`` (thesis steps of 0.5 deg) and ``theta_z0`` (0.1 deg), inclusive.
    bias_refine : bool
        After the thesis's search, search ``theta_y0`` again with the ``theta_z0`` found (the thesis searched it with
        ``theta_z0 = 0``), then both on grids ten times finer around the optimum.
    bias_depth_statistic : {"median", "mean"}
        ``theta_y0`` criterion: the median of the per-point depth differences (robust to the few false matches that
        pass the gap filter) or the thesis's difference of mean depths (it used six hand-verified matches).
    coincide_m : float
        The ``theta_z0`` criterion's coincidence distance (thesis: 1 mm).
    pair_tolerance_m : float
        A pair belongs to ``d_o`` when its x-slide travel is within this of it.
    seed : int
        RANSAC samples are drawn from ``numpy.random.default_rng((seed, k))`` for the k-th combination.
    """

    reference: str
    intraocular_mm: tuple = (20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0, 100.0, 110.0)
    map_min_baseline_m: float = 0.049
    map_exclude: tuple = ()
    map: MapConfig = field(default_factory=MapConfig)
    ransac_iterations: int = 100
    d_r_m: float = 0.020
    r_lim: float = 0.1
    methods: tuple = ("quaternion", "lms", "quaternion_ratio", "lms_ratio")
    bundle_R0_prior_deg: float = R0_PRIOR_DEG
    bundle_intraocular_mm: tuple | None = None
    bundle_centre: bool = False
    bundle_readings: bool = False
    bias_grid_y_deg: tuple = (-12.0, 12.0, 0.5)
    bias_grid_z_deg: tuple = (-5.0, 5.0, 0.1)
    bias_refine: bool = False
    bias_depth_statistic: str = "median"
    coincide_m: float = 0.001
    pair_tolerance_m: float = 0.001
    seed: int = 0


@dataclass(frozen=True)
class Combination:
    """One estimate: camera ``a`` of pair ``(a, b)`` at intraocular distance ``d_m`` by ``method``.

    ``p_table`` is the estimated position of camera ``a`` relative to the reference camera, in the table's axes (m;
    NaN on failure); ``map_points``, ``pairs_3d``, ``ransac_inliers``, ``inliers`` count the map ``1p``, the
    triangulated ``1p <-> 2p`` correspondences, RANSAC's consensus and what is left after the error-ratio elimination
    (the bundle: the pixel observations its gate kept); ``cov_p`` (3, 3) the bundle's first-order covariance of
    ``p_table`` (m^2; None for the thesis's estimators).
    """

    d_m: float
    a: str
    b: str
    method: str
    success: bool
    message: str
    p_table: np.ndarray
    map_points: int
    pairs_3d: int
    ransac_inliers: int
    inliers: int
    cov_p: np.ndarray | None = None


@dataclass
class PositioningResult:
    """Outcome of :func:`estimate_positions`.

    Attributes
    ----------
    success : bool
        False only when nothing could be estimated (the reason in ``message``); single failed combinations are
        reported in ``combinations``.
    R0 : ndarray (3, 3)
        The camera rotation on its support used (estimated, or given).
    bias_deg : ndarray (3,)
        ``theta_x0, theta_y0, theta_z0`` (deg) when searched, NaN when ``R0`` was given.
    search : MountSearchResult or None
    combinations : list of Combination
    pairs : dict {d_mm: [(a, b), ...]}
    T_table_cam : dict {name: (4, 4)}
        Every view's pose from the readings and ``R0``.
    keypoints : dict {name: int}
    timings_s : dict
    observations : dict {name: ViewObservation}
        Every view as the experiment used it (keypoints, undistorted coordinates, pose from the readings and R0).
    reference_matches : dict {name: Matches}
        The reference keypoints' matches in every other view (ratio test and orientation filter).
    """

    success: bool
    message: str
    R0: np.ndarray
    bias_deg: np.ndarray
    search: object
    combinations: list
    pairs: dict
    T_table_cam: dict
    keypoints: dict
    timings_s: dict = field(default_factory=dict)
    observations: dict = field(default_factory=dict)
    reference_matches: dict = field(default_factory=dict)


def intraocular_pairs(names, readings, reference: str, intraocular_mm, tolerance_m: float = 1e-3) -> dict:
    """All pairs ``(a, b)`` of views whose x-slide readings differ by ``d_o`` (within ``tolerance_m``), per ``d_o``.

    Neither view may be the reference (it defines ``1p``'s frame). ``a`` is the view with the smaller x reading; pairs
    are listed by increasing x of ``a``. Returns ``{d_mm: [(a, b), ...]}`` (possibly empty lists).
    """
    names = list(names)
    x = np.asarray(readings, float)[:, 0]
    order = np.argsort(x, kind="stable")
    return {float(d): [(names[i], names[j]) for i in order for j in order
                       if reference not in (names[i], names[j]) and x[j] > x[i]
                       and abs((x[j] - x[i]) - d * 1e-3) <= tolerance_m]
            for d in intraocular_mm}


def map_view_names(names, centres, reference: str, pair, min_baseline_m: float, exclude=()) -> list:
    """Views used for ``1p``: all but the reference, the pair, ``exclude`` and those closer than ``min_baseline_m``.

    ``centres`` (N, 3): the camera centres from the readings (m), in the order of ``names``.
    """
    names = list(names)
    c = np.asarray(centres, float)
    c_ref = c[names.index(reference)]
    skip = {reference, *pair, *exclude}
    return [n for n, p in zip(names, c, strict=True)
            if n not in skip and np.linalg.norm(p - c_ref) >= min_baseline_m - 1e-9]


def _grid(spec, name):
    start, stop, step = (float(v) for v in spec)
    if not (step > 0 and stop >= start):
        raise ValueError(f"{name}: expected (start, stop, step > 0) with stop >= start, got {spec!r}")
    n = int(np.floor((stop - start) / step + 1e-9)) + 1
    return start + step * np.arange(n)


def _search_bias(obs, T_table_stage, names, ref, offset, cfg: PositioningConfig, x_read):
    """The thesis's search for R0 (Eq. 197-198) between the two extreme views (by x reading)."""
    others = [n for n in names if n != ref]
    xs = np.array([x_read[names.index(n)] for n in others])
    left, right = int(np.argmin(xs)), int(np.argmax(xs))
    T_st = np.stack([T_table_stage[names.index(n)] for n in others])
    T_ref = T_table_stage[names.index(ref)]
    views = [obs[n] for n in others]
    gy, gz = np.deg2rad(_grid(cfg.bias_grid_y_deg, "bias_grid_y_deg")), \
        np.deg2rad(_grid(cfg.bias_grid_z_deg, "bias_grid_z_deg"))
    kw = dict(left=left, right=right, coincide_m=cfg.coincide_m, gap_max_m=cfg.map.gap_max_m, ratio=cfg.map.ratio,
              orientation_tol_deg=cfg.map.orientation_tol_deg, depth_statistic=cfg.bias_depth_statistic)
    res = search_mount_rotation(obs[ref], views, T_ref, T_st, offset, gy, gz, **kw)
    if cfg.bias_refine:  # theta_y0 again with the theta_z0 found, then both on grids ten times finer
        sy, sz = gy[1] - gy[0] if len(gy) > 1 else 0.0, gz[1] - gz[0] if len(gz) > 1 else 0.0
        res = search_mount_rotation(obs[ref], views, T_ref, T_st, offset, gy, [res.theta_z0], **kw,
                                    theta_z0_during_y=res.theta_z0)
        fy = res.theta_y0 + np.linspace(-sy, sy, 21)
        fz = res.theta_z0 + np.linspace(-sz, sz, 21)
        res = search_mount_rotation(obs[ref], views, T_ref, T_st, offset, fy, fz, **kw,
                                    theta_z0_during_y=res.theta_z0)
    return res


def _align(p1, p2, cfg: PositioningConfig, seed) -> dict:
    """``T_ref_a`` by each requested method: ``{method: (T, success, message, ransac inliers, final inliers)}``.

    One RANSAC per rotation estimator (samples from ``default_rng((*seed, estimator index))``) serves both of its
    methods: without elimination the model is the refit on RANSAC's consensus set, which is exactly what
    :func:`~bench.vision.ransac.ransac_absolute_orientation` returns for ``r_lim=None`` with the same samples.
    """
    out = {}
    for ei, est in enumerate(("rodrigues", "svd", "horn")):
        wanted = [m for m in cfg.methods if METHODS[m][0] == est]
        if not wanted:
            continue
        ratio = any(METHODS[m][1] for m in wanted)
        res = ransac_absolute_orientation(p1, p2, d_r=cfg.d_r_m, iterations=cfg.ransac_iterations, method=est,
                                          r_lim=cfg.r_lim if ratio else None, rng=np.random.default_rng((*seed, ei)))
        for m in wanted:
            if not res.success:
                out[m] = (np.full((4, 4), np.nan), False, res.message, 0, 0)
            elif METHODS[m][1] or not ratio:
                out[m] = (res.T, True, res.message, int(res.ransac_inliers.sum()), int(res.inliers.sum()))
            else:  # the consensus refit, before the eliminations
                keep = res.ransac_inliers
                fit = absolute_orientation(p1[keep], p2[keep], method=est)
                n = int(keep.sum())
                out[m] = (fit.T, fit.success, f"{n} of {len(p1)} pairs in consensus; {fit.message}", n, n)
    return {m: out[m] for m in cfg.methods}


def _bundle_estimate(d_mm, a, b, kmap, used, start, obs, features, matches, read, names, R0, spec, camera, cov_K,
                     cov_dist, n_pairs_3d, cfg) -> Combination:
    """The bundle's estimate of camera ``a`` (:func:`bench.vision.xy_table_bundle.pair_bundle`), started from the
    LMS + error-ratio estimate ``start`` (its ``_align`` tuple)."""
    from bench.vision.xy_table_bundle import pair_bundle, pair_observations  # it builds on this module

    T, ok, msg, n_ransac, _ = start
    nan3 = np.full(3, np.nan)
    if not ok:
        return Combination(d_mm * 1e-3, a, b, BUNDLE, False, f"no start (LMS + error ratio: {msg})", nan3, len(kmap),
                           n_pairs_3d, n_ransac, 0)
    views = [cfg.reference, *used, a, b]
    view, point, uv, points = pair_observations(kmap, views, matches, features, (a, b))
    T_table_ref = obs[cfg.reference].T_base_cam
    X = transform_points(T_table_ref, kmap.p_ref[points])
    in_pair = np.zeros(len(views), bool)
    in_pair[-2:] = True
    sigma = np.array([spec.resolution_m, spec.resolution_m, spec.resolution_rad]) / np.sqrt(12)  # one step
    res = pair_bundle(read[[names.index(n) for n in views]], in_pair, T_table_ref @ T, R0, spec.camera_offset_m,
                      camera.K, camera.dist, view, point, uv, X, cov_K, sigma if cfg.bundle_readings else None,
                      cov_dist, spec.camera_offset_sigma_m if cfg.bundle_centre else None, cfg.bundle_R0_prior_deg)
    return Combination(d_mm * 1e-3, a, b, BUNDLE, res.success, res.message, res.p_table, len(kmap), n_pairs_3d,
                       n_ransac, res.observations, res.cov_p)


def estimate_positions(features: dict, readings: dict, camera, spec: TableSpec, config: PositioningConfig,
                       R0=None, verbose: bool = False, cov_K=None, cov_dist=None) -> PositioningResult:
    """The x-y table experiment on already detected features (module docstring, steps 1-4).

    Parameters
    ----------
    features : dict {name: Features}
        Keypoints (or corner features) of every table view, pixels as detected.
    readings : dict {name: (3,)}
        Table readings ``[x_m, z_m, rot_rad]`` of the same views.
    camera : CameraModel
        The pipeline's camera (calibrated or nominal): undistorts the keypoints.
    spec : TableSpec
    config : PositioningConfig
    R0 : (3, 3), optional
        The camera's rotation on its support; None: the thesis's search (Eq. 197-198).
    verbose : bool
        Progress on stderr.
    cov_K : (4, 4), optional
        Covariance (px^2) of the camera's ``fx, fy, cx, cy`` (its calibration's): the bundle method refines them
        under it; None: the bundle takes them as exact.
    cov_dist : (4, 4), optional
        Covariance of the distortion's ``k1, k2, p1, p2`` about the camera's: the bundle refines them under it (a
        loose prior about zero for a pin-hole calibration); None: exact.

    Returns
    -------
    PositioningResult
    """
    t0 = time.perf_counter()
    cfg = config
    names = list(features)
    if set(names) != set(readings):
        missing = sorted(set(names) ^ set(readings))
        raise ConfigError("table.csv", missing[0], "a table view needs both an image and a reading")
    if cfg.reference not in features:
        raise ConfigError("pipeline", "reference", f"no table view named {cfg.reference!r}")
    for m in cfg.methods:
        if m not in METHODS and m != BUNDLE:
            raise ValueError(f"methods: unknown {m!r} (known: {', '.join([*METHODS, BUNDLE])})")
    thesis_methods = tuple(m for m in cfg.methods if m in METHODS)
    if BUNDLE in cfg.methods and "lms_ratio" not in thesis_methods:
        thesis_methods += ("lms_ratio",)  # the bundle starts from it
    align_cfg = replace(cfg, methods=thesis_methods)

    def methods_at(d_mm):  # the bundle runs at its own distances only
        return [m for m in cfg.methods if m != BUNDLE or cfg.bundle_intraocular_mm is None
                or any(abs(d_mm - d) < 1e-9 for d in cfg.bundle_intraocular_mm)]

    if BUNDLE in cfg.methods and cfg.bundle_centre and spec.camera_offset_sigma_m is None:
        raise ConfigError("table.yaml", "camera_offset_tolerance_mm",
                          "the bundle's camera centre (bundle_centre) needs the centre's stated tolerance")
    read = check_readings(np.stack([readings[n] for n in names]), spec, names)
    T_table_stage = stage_poses(read)
    obs = {}
    for n in names:
        f = features[n]
        x_n = camera.undistort_pixels(f.uv) if len(f) else np.empty((0, 2))
        obs[n] = ViewObservation(n, f, x_n, np.eye(4))
    timings = {"undistort_s": time.perf_counter() - t0}

    search = None
    if R0 is None:
        t1 = time.perf_counter()
        search = _search_bias(obs, T_table_stage, names, cfg.reference, spec.camera_offset_m, cfg, read[:, 0])
        R0 = mount_rotation(search.theta_x0, search.theta_y0, search.theta_z0)
        bias = np.rad2deg([search.theta_x0, search.theta_y0, search.theta_z0])
        timings["bias_search_s"] = time.perf_counter() - t1
        if verbose:
            print(f"mount rotation: {search.message}", file=sys.stderr)
    else:
        R0 = np.asarray(R0, float)
        bias = np.full(3, np.nan)
    X = stage_camera(R0, spec.camera_offset_m)
    T_table_cam = {n: T_table_stage[i] @ X for i, n in enumerate(names)}
    obs = {n: ViewObservation(n, o.features, o.x_n, T_table_cam[n]) for n, o in obs.items()}
    centres = np.stack([T_table_cam[n][:3, 3] for n in names])
    ref = obs[cfg.reference]
    R_table_ref = T_table_cam[cfg.reference][:3, :3]

    t1 = time.perf_counter()
    others = [n for n in names if n != cfg.reference]
    ref_matches = dict(zip(others, reference_matches(ref, [obs[n] for n in others], cfg.map), strict=True))
    timings["match_reference_s"] = time.perf_counter() - t1
    pairs = intraocular_pairs(names, read, cfg.reference, cfg.intraocular_mm, cfg.pair_tolerance_m)
    maps, matched = {}, {}
    combos = []
    t_map = t_locate = t_align = t_bundle = 0.0
    k = 0
    n_pairs = sum(len(p) for p in pairs.values())
    for d_mm, plist in pairs.items():
        for a, b in plist:
            k += 1
            if verbose:
                print(f"\r  positioning: d_o = {d_mm:g} mm, pair {a}-{b} ({k}/{n_pairs})", end="", file=sys.stderr)
            used = tuple(map_view_names(names, centres, cfg.reference, (a, b), cfg.map_min_baseline_m,
                                        cfg.map_exclude))
            t2 = time.perf_counter()
            if used not in maps:
                maps[used] = build_map(ref, [obs[n] for n in used], cfg.map, [ref_matches[n] for n in used]) \
                    if used else None
            kmap = maps[used]
            t3 = time.perf_counter()
            t_map += t3 - t2
            n_map = 0 if kmap is None else len(kmap)
            if kmap is None or n_map < 3:
                msg = "no views left for 1p" if kmap is None else f"the map has {n_map} points (need >= 3)"
                combos += [Combination(d_mm * 1e-3, a, b, m, False, msg, np.full(3, np.nan), n_map, 0, 0, 0)
                           for m in methods_at(d_mm)]
                continue
            # the 1p <-> 2p correspondences (Eq. 165-166) come from locate(); the alignment is redone per method.
            # A map and a view, or two views, recur across pairs: each combination is matched once
            for key, f1, f2 in (((used, a), kmap.features, obs[a].features),
                                ((a, b), obs[a].features, obs[b].features)):
                if key not in matched:
                    matched[key] = view_matches(f1, f2, cfg.map)
            loc = locate(kmap, obs[a], obs[b], cfg.map, method="svd", d_r=cfg.d_r_m, iterations=cfg.ransac_iterations,
                         r_lim=None, rng=np.random.default_rng((cfg.seed, k)), refine=False,
                         matches=(matched[used, a], matched[a, b]))
            t4 = time.perf_counter()
            t_locate += t4 - t3
            if loc.p1 is None or len(loc.p1) < 3:
                combos += [Combination(d_mm * 1e-3, a, b, m, False, loc.message, np.full(3, np.nan), n_map,
                                       0 if loc.p1 is None else len(loc.p1), 0, 0) for m in methods_at(d_mm)]
                continue
            aligned = _align(loc.p1, loc.p2, align_cfg, (cfg.seed, k))
            for m, (T, ok, msg, n_ransac, n_kept) in aligned.items():
                if m not in cfg.methods:
                    continue
                p = R_table_ref @ T[:3, 3]  # camera a's centre relative to the reference, table axes
                combos.append(Combination(d_mm * 1e-3, a, b, m, ok, msg, p, n_map, len(loc.p1), n_ransac, n_kept))
            t5 = time.perf_counter()
            t_align += t5 - t4
            if BUNDLE in methods_at(d_mm):
                combos.append(_bundle_estimate(d_mm, a, b, kmap, used, aligned["lms_ratio"], obs, features,
                                               ref_matches, read, names, R0, spec, camera, cov_K, cov_dist,
                                               len(loc.p1), cfg))
                t_bundle += time.perf_counter() - t5
    if verbose and n_pairs:
        print(file=sys.stderr)
    timings.update({"maps_s": t_map, "locate_s": t_locate, "align_s": t_align, "bundle_s": t_bundle,
                    "positioning_total_s": time.perf_counter() - t0})
    ok = sum(c.success for c in combos)
    msg = f"{ok} of {len(combos)} estimates over {n_pairs} pairs, {len(maps)} distinct maps"
    return PositioningResult(ok > 0, msg if ok else "no estimate succeeded: " + msg, R0, bias, search, combos, pairs,
                             T_table_cam, {n: len(f) for n, f in features.items()}, timings, obs, ref_matches)


# ------------------------------------------------------------------------------------------------ a dataset


def table_views(ds, role: str = "table") -> list:
    """The dataset's views of ``role`` with their table readings; one-line error when a reading is missing."""
    views = [v for v in ds.views if v.role == role]
    if not views:
        raise ConfigError(ds.root / "manifest.yaml", "views", f"no view with role {role!r}")
    for v in views:
        if v.table is None:
            src = ds.root / "table.csv"
            raise ConfigError(src, v.name, "no table reading for this view" if src.is_file() else
                              "table.csv not found (an x-y table dataset needs the table readings)")
    return views


def position_dataset(root, config: PositioningConfig, camera=None, features: str = "sift", geometry=None,
                     verbose: bool = False, corner_extractor: str = "opencv") -> PositioningResult:
    """The experiment on a dataset folder (public part only): views of role ``table``, ``table.csv``, ``table.yaml``.

    ``camera`` replaces the dataset's ``camera.yaml`` (e.g. a calibration result); ``features`` is ``"sift"`` or
    ``"corners"`` (then ``geometry`` is the target, e.g. from ``target.yaml``, and ``corner_extractor``
    (:func:`rig_corner_features`) labels the corners; views where the target is not found are left out, the
    reference must have it).
    """
    t0 = time.perf_counter()
    ds = load_dataset(root)
    spec = load_table_spec(ds.root / "table.yaml")
    cam = camera if camera is not None else ds.camera()
    views = table_views(ds)
    feats, skipped = {}, []
    for v in views:
        img = v.image(expected_size=cam.size)
        if features == "sift":
            feats[v.name] = detect_sift(img, channel_order="rgb")  # View.image: RGB (or grey)
        elif features == "corners":
            if geometry is None:
                raise ValueError("features='corners' needs the target geometry")
            f, msg = rig_corner_features(img, geometry, corner_extractor)
            if f is None:
                skipped.append(f"{v.name}: {msg}")
                continue
            feats[v.name] = f
        else:
            raise ValueError(f"features: expected 'sift' or 'corners', got {features!r}")
    if config.reference not in feats:
        raise ConfigError(ds.root, config.reference, "no features in the reference view: " + "; ".join(skipped))
    t_feat = time.perf_counter() - t0
    res = estimate_positions(feats, {n: ds.view(n).table for n in feats}, cam, spec, config, verbose=verbose)
    res.timings_s["features_s"] = t_feat
    if skipped:
        res.message += f"; left out: {'; '.join(skipped)}"
    return res
