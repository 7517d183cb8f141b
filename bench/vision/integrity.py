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
   relative pose from the images alone; it must agree with the kinematic ``T_a_b``: refused beyond
   :data:`RELATIVE_REFUSE_MM` / :data:`RELATIVE_REFUSE_DEG` when its Mahalanobis square
   (:func:`relative_pose_disagreement`: the keypoints' noise, the map's depth errors and, given the lab's
   covariances (:class:`LabPrior`), the intrinsics', the lens's and the mount's errors) also exceeds
   :data:`RELATIVE_Q_REFUSE` times the overdispersion of clean runs; a warning when the part of it beyond a clean
   run's (:func:`relative_pose_excess`) exceeds a third of those limits, or the square :data:`RELATIVE_Q_WARN` times
   it.
3. **Reprojection chi-square.** The locate views' residual RMS at the solution against the survey views' residual
   RMS at their kinematic poses (the keypoint noise of this scene, this water, this camera): the ratio inflates the
   covariance, and refuses beyond :data:`CHI2_RATIO_REFUSE`.
4. **Residual whiteness.** The correlation of each locate residual with its nearest image neighbour's: a model error
   (bent mount, wrong calibration) makes neighbouring residuals alike, noise does not - but so does realistic
   imaging on a clean run, so ``rho`` is reported, not applied (see below).
5. **Support.** Inliers (at least :data:`MIN_INLIERS`), inlier fraction and the inliers' spread over image a (convex
   hull / image area).
6. **Conditioning** of the final least-squares problem (``LocateResult.condition``: the thesis estimator's alignment
   or reprojection system; for the joint bundle :func:`pose_condition`, the geometry of the pose it solved); a pose
   covariance that is not positive definite is refused.
7. **The base's tilt against the vehicle's INS** (:mod:`bench.vision.tilt`, when the dataset has ``vehicle.yaml``;
   applied by ``locate_dataset`` after the others): gravity's direction at the two parkings, carried by the located
   rotation, against the covariance; refused beyond its chi-square quantile. The one test that sees the camera
   turned on its mount between the survey and the localisation (about a horizontal axis).

Protection levels: the base-pose covariance (position block, rotation block; ``locate_dataset`` has calibrated it
by the estimator's measured optimism :data:`KAPPA`), inflated by the chi-square factor of test 3, gives the
``1 - INTEGRITY_RISK`` quantile of the error's norm (:func:`norm_quantile`: the exact quantile of a Gaussian's norm,
not ``k`` times its largest standard deviation); the part of test 2's disagreement beyond a clean run's (a
kinematic relative pose off by ``d`` moves the solution by about ``d``; a third of it) and a floor for the model
errors no test here resolves (:data:`FLOOR_MM`, :data:`FLOOR_DEG`) are added in quadrature. Residual whiteness
(test 4) is reported, not applied: over 20 clean seeds it did not predict the covariance's misfit
(docs/integrity.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import numpy as np
from scipy.spatial import ConvexHull, QhullError, cKDTree

from bench.camera.model import distort, distortion_jacobian, distortion_parameter_jacobian
from bench.camera.refractive import RefractiveCamera, lens_parameters, virtual_scale, with_lens_parameters
from bench.geometry.quaternion import matrix_to_rotation_vector
from bench.geometry.transforms import homogeneous, invert, skew, transform_points
from bench.vision.insitu import KeypointMap, MapConfig, ViewObservation, _left_exp, _proj_jac, reference_matches
from bench.vision.triangulation import triangulate_midpoint

#: Probability that the true error exceeds the protection level when every test passes (the stated risk).
INTEGRITY_RISK = 1e-3
#: Reprojection gate (px) of the consensus counts (test 1); a match within it is "explained" by a pose.
GATE_PX = 3.0
#: Consensus (predicted / free inliers) below which a view is refused, and below which it is a warning.
CONSENSUS_REFUSE = 0.5
CONSENSUS_WARN = 0.8
#: A free pose needs this many inliers before its disagreement with the predicted one counts.
MIN_FREE_INLIERS = 12
#: Relative pose of the locate views, images vs kinematics (test 2): refused beyond these (a warning beyond a third)
#: when its Mahalanobis square (:func:`relative_pose_disagreement`) also exceeds :data:`RELATIVE_Q_REFUSE` times
#: the overdispersion.
RELATIVE_REFUSE_MM = 30.0
RELATIVE_REFUSE_DEG = 1.5
#: The Mahalanobis square's overdispersion on clean runs, with the lab calibrations' covariances in it
#: (:class:`LabPrior`): its median over ta40_in_situ_manifold seeds 1-20 is 3.18 underwater and 3.15 in air
#: (realistic imaging), against chi2_6's 5.35 - below 1, as the map's spread and the poses' residuals also hold the
#: lab's errors that its term counts again (a Monte Carlo in tests/vision/test_protection_levels.py). Thresholds: that
#: factor times chi2_6 at 1 - 1e-3 (refused, with the raw limits) and at 0.99 (a warning).
RELATIVE_OVERDISPERSION = 0.59
#: The same without them (the keypoints' noise and the map's depth errors only): the lab's errors are then the
#: unmodelled part - median 80 underwater (this factor, fitted there), 197 in air, where the keypoints are sharper
#: and the same lab errors weigh more (docs/integrity.md, "Test 2 and the lab's errors").
RELATIVE_OVERDISPERSION_FEATURES = 15.0
#: chi2_6 at 1 - 1e-3 and at 0.99: test 2's refusal and warning quantiles, times the overdispersion that applies.
RELATIVE_Q_REFUSE = 22.458
RELATIVE_Q_WARN = 16.812
#: Degrees of freedom of test 2's disagreement (a rotation vector and a translation).
RELATIVE_DOF = 6
#: Locate residual RMS / survey residual RMS (test 3) beyond which the solution is refused / warned.
CHI2_RATIO_REFUSE = 10.0
#: the smallest survey noise test 3 divides by (px): exact data's residuals are rounding errors, not noise
NOISE_FLOOR_PX = 0.01
CHI2_RATIO_WARN = 3.0
#: Support (test 5).
MIN_INLIERS = 12
WARN_INLIERS = 30
WARN_INLIER_FRACTION = 0.3
WARN_SPREAD = 0.05
#: Conditioning (test 6): warning / refused beyond - the thesis estimator's condition number, or the joint bundle's
#: :func:`pose_condition` (15-633 over 263 clean localisations: one region and four, 0.5-1.0 m; docs/integrity.md,
#: "The conditioning test of the joint bundle"; it grows as (depth / spread)^2, so 1e4 is a point spread ~4x
#: narrower than any of theirs)
WARN_CONDITION = 1e4
REFUSE_CONDITION = 1e8
#: Optimism of each estimator's first-order covariance (``refine`` mode: its standard deviations times this), fitted
#: as ``sqrt(q95(NEES_pos) / chi2_3(0.95))`` on clean runs so that the covariance's 95 % region holds 95 % of the
#: errors (docs/integrity.md, "An honest covariance"): ``joints`` on ta40_in_situ_manifold seeds 1-20 (realistic
#: imaging; every map point in the joint bundle, pipeline.map_points: all; the thesis's map, SIFT's twins kept - with
#: one point per detection, pipeline.twin_keypoints: once, the same value covers 90 % of those seeds' errors:
#: docs/integrity.md, "Twin keypoints in the covariance"), ``bundle`` on the 84-run envelope of
#: docs/integrity.md; ``joints_regions`` - the joint bundle over several regions of the scene, whose keypoints are
#: independent but whose feature errors are not (docs/integrity.md, "The covariance with several regions") - on the
#: 40 four-region runs of the availability cells (clear and coastal water, 0.5-1.0 m, 2x renders): 1.32 x 1.26, the
#: further factor two-fold cross-validated at 1.20 / 1.27; ``pose`` / ``none`` / ``pnp`` were not measured and take
#: the largest measured value. On aligned keypoints (``pipeline.keypoints: aligned``,
#: :mod:`bench.vision.patch_align`) the joint bundle's pixel noise halves but its error does not, so the same
#: estimators have their own (docs/integrity.md, "Aligned keypoints"): ``joints_aligned`` on the same 20 seeds,
#: ``joints_regions_aligned`` on the same 40 runs. With the covariance of each view's keypoint error field
#: (``pipeline.covariance: field``, :mod:`bench.vision.field_covariance`): ``joints_field`` on the same 20 seeds
#: (localised again at kappa 1; docs/integrity.md, "The covariance with each view's keypoint field"). With SIFT's
#: twins weighed as what they are worth (``pipeline.twin_keypoints: weighted``): ``joints_weighted`` on seeds 1-40
#: (1.32 x 1.17; docs/integrity.md, "Twin keypoints weighed as what they are worth" - seeds 21-40, held out from the
#: fit of ``joints``, ask 1.33 more of it with the thesis's map).
KAPPA = {"joints": 1.32, "joints_regions": 1.66, "bundle": 2.89, "joints_aligned": 1.81,
         "joints_regions_aligned": 2.14, "joints_field": 1.19, "joints_weighted": 1.55}
KAPPA_UNMEASURED = max(KAPPA.values())
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
    regions, region_reasons : dict
        A localisation over several regions of the scene (:func:`assess_regions`): each region's own level and
        reasons (empty for one region).
    """

    level: str
    reasons: list = field(default_factory=list)
    protection_radius_m: float = float("inf")
    protection_angle_rad: float = float("inf")
    tests: dict = field(default_factory=dict)
    regions: dict = field(default_factory=dict)
    region_reasons: dict = field(default_factory=dict)

    def report(self) -> dict:
        """The locate.json entries (``integrity``, ``integrity_reasons``, ``protection_radius_mm``, ...; with
        several regions ``integrity_regions``, each region's level)."""
        out = {"integrity": self.level, "integrity_reasons": list(self.reasons),
               "protection_radius_mm": _finite(self.protection_radius_m * 1e3),
               "protection_angle_deg": _finite(np.rad2deg(self.protection_angle_rad)),
               "integrity_tests": {k: _finite(v) for k, v in self.tests.items()}}
        if self.regions:
            out["integrity_regions"] = dict(self.regions)
        return out


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


def map_point_sigma(kmap: KeypointMap) -> np.ndarray:
    """Standard deviation (M,) m of each map point along its reference ray (where Eq. 162 puts it).

    A point is the mean of ``n_i`` pairwise estimates on the reference ray whose RMS spread is ``spread_i``; its
    variance ``spread_i^2 / (n_i - 1)`` is pooled over the map as ``c^2 z_i^4 / n_i`` (triangulation depth error grows
    as depth^2), since one point's two or three estimates say little about its own spread.
    """
    z = np.maximum(kmap.p_ref[:, 2], 1e-6)
    n = np.maximum(np.asarray(kmap.n_views, float), 2.0)
    c2 = float(np.mean(np.asarray(kmap.spread_m, float) ** 2 * n / (n - 1) / z**4)) if len(z) else 0.0
    return np.sqrt(c2 * z**4 / n)


def _view_jacobians(p_ref, T_ref_view):
    """Per match: the normalized projection's Jacobians (N, 2, 6) w.r.t. the left perturbation ``[w, v]`` of
    ``T_view_ref`` and (N, 2, 3) w.r.t. the map point (reference frame); and the projections (N, 2)."""
    T_view_ref = invert(T_ref_view)
    X = transform_points(T_view_ref, np.asarray(p_ref, float))
    u, P = _proj_jac(X)
    dX = np.concatenate([-skew(X), np.broadcast_to(np.eye(3), (len(X), 3, 3))], axis=2)  # d(exp(w) X + v)/d(w, v)
    return P @ dX, P @ T_view_ref[:3, :3], u


@dataclass(frozen=True)
class LabPrior:
    """What the lab calibrations leave uncertain in test 2: the covariance ``cov`` of the intrinsics ``fx fy cx cy``
    (px), the lens's ``k1 k2 p1 p2`` (and ``k3``) when their block is known, and the camera mount (a right
    perturbation ``[w, v]`` of ``T_link5_cam``: rad, then m) - (10, 10), (14, 14) or (15, 15), the joint bundle's prior
    (:func:`bench.vision.joint_bundle.lab_prior` of ``calibration_priors.yaml``'s blocks, in its order) - with the
    calibrated intrinsics ``K`` (3, 3) and lens ``dist`` (5,) at which a change of them moves the normalized
    keypoints. A refractive camera's priors are written in its virtual pinhole's terms (``K``, no lens; the lens's
    covariance scaled by the port's paraxial magnification, ``bench.scenario.in_situ_lab``); give the camera as
    ``refractive`` and the keypoints move through the lens and the port themselves (:meth:`keypoint_jacobian`),
    not through that paraxial view, whose lens block is 15-50 % low at the image corners."""

    cov: np.ndarray
    K: np.ndarray
    dist: np.ndarray
    refractive: RefractiveCamera | None = None

    def keypoint_jacobian(self, x_n) -> np.ndarray:
        """``d x_n / d (fx fy cx cy [k1 k2 p1 p2 [k3]])`` (N, 2, 4, 8 or 9) of normalized undistorted keypoints ``x_n``
        (N, 2): the pixel ``u = K distort(x_n)`` held, ``x_d = (u - c) / f`` and ``distort(x_n) = x_d`` moved; for a
        ``refractive`` camera by central differences of :meth:`~bench.camera.refractive.RefractiveCamera.
        central_coordinates` at its working range."""
        x_n = np.asarray(x_n, float).reshape(-1, 2)
        if self.refractive is not None:
            return self._refractive_jacobian(x_n)
        f = np.array([self.K[0, 0], self.K[1, 1]])
        x_d = distort(x_n, self.dist)
        dxd = np.zeros((len(x_n), 2, 4))  # d x_d / d (fx fy cx cy); the skew stays
        dxd[:, 0, 0], dxd[:, 1, 1] = -x_d[:, 0] / f[0], -x_d[:, 1] / f[1]
        dxd[:, 0, 2], dxd[:, 1, 3] = -1.0 / f[0], -1.0 / f[1]
        if len(self.cov) >= 14:  # the lens's k1 k2 p1 p2 (and k3 with the lab's own: 15)
            dxd = np.concatenate([dxd, -distortion_parameter_jacobian(x_n)], axis=2)
        if len(self.cov) == 15:  # d distort / d k3 = x_n r^6
            dxd = np.concatenate([dxd, -(x_n * np.sum(x_n**2, axis=1)[:, None] ** 3)[:, :, None]], axis=2)
        return np.linalg.solve(distortion_jacobian(x_n, self.dist), dxd)

    def _refractive_jacobian(self, x_n) -> np.ndarray:
        """The refractive camera's :meth:`keypoint_jacobian`: each keypoint's pixel through lens and port (at the
        working range ``z``), held while one lens parameter moves by a step of the prior's (virtual pinhole's)
        parameter, scaled back by :func:`~bench.camera.refractive.virtual_scale` (the scaling the prior was written
        with) - and its coordinates at ``z`` again."""
        cam = self.refractive
        z = cam.working_range_m
        uv = cam.project(np.c_[x_n * z, np.full(len(x_n), z)])
        n = 8 if len(self.cov) == 14 else 4
        per_step = 1.0 / virtual_scale(cam.port)[:n]
        steps = np.array([1e-2, 1e-2, 1e-2, 1e-2, 1e-5, 1e-5, 1e-6, 1e-6])[:n]  # px, then unitless
        theta0, J = lens_parameters(cam.lens), np.empty((len(x_n), 2, n))
        for i in range(n):
            x = []
            for sign in (1.0, -1.0):
                theta = theta0.copy()
                theta[i] += sign * steps[i] * per_step[i]
                moved = replace(cam, lens=with_lens_parameters(cam.lens, theta))
                x.append(moved.central_coordinates(uv, z))
            J[:, :, i] = (x[0] - x[1]) / (2.0 * steps[i])
        bad = ~np.all(np.isfinite(J), axis=(1, 2))  # a keypoint the port does not image at z: the paraxial view
        if bad.any():
            J[bad] = replace(self, refractive=None).keypoint_jacobian(x_n[bad])
        return J


def _log(T):
    """``[w, v]`` (6,) of a small transform (4, 4): its rotation vector and translation."""
    return np.r_[matrix_to_rotation_vector(T[:3, :3]), T[:3, 3]]


def _map_points(kmap: KeypointMap, x_ref, x_obs, T_ref_views) -> np.ndarray:
    """Eq. 162 again: every map point (M, 3) as the mean of its mid-point estimates on the reference ray, from the
    reference keypoints ``x_ref`` (M, 2), the surrounding observations ``x_obs`` (in ``kmap.observations``' order,
    concatenated) and the surrounding poses ``T_ref_views`` (K, 4, 4)."""
    views = np.concatenate([np.asarray(o[0], int) for o in kmap.observations])
    point = np.repeat(np.arange(len(kmap)), [len(o[0]) for o in kmap.observations])
    p, n = np.zeros((len(kmap), 3)), np.zeros(len(kmap))
    for k in np.unique(views):
        s = views == k
        tri = triangulate_midpoint([np.eye(4), T_ref_views[k]], [x_ref[point[s]], x_obs[s]])
        np.add.at(p, point[s], tri.ray_points[0])
        np.add.at(n, point[s], 1.0)
    return p / n[:, None]


def _lab_jacobian(kmap: KeypointMap, frees: list, T_a_b, lab: LabPrior, gains: list) -> np.ndarray:
    """Test 2's disagreement's first-order response (6, n) to the lab's intrinsics, lens and mount (:class:`LabPrior`'s
    order), by central differences of the whole chain: the normalized keypoints (the map's reference and surrounding
    ones and both free views': :meth:`LabPrior.keypoint_jacobian`), the surrounding poses the map is triangulated from
    and the kinematic ``T_a_b`` (a mount error ``M`` conjugates both: ``M^-1 T M``), the map again
    (:func:`_map_points`) and each free pose's Gauss-Newton response ``gains`` (6, 2N) to its new residuals."""
    if kmap.observations is None or kmap.x_ref is None or kmap.T_ref_views is None:
        raise ValueError("kmap: test 2's lab term needs the map's survey (observations, x_ref, T_ref_views), as "
                         "build_map gives it")
    x_obs = np.concatenate([np.asarray(o[1], float).reshape(-1, 2) for o in kmap.observations])
    p0 = _map_points(kmap, kmap.x_ref, x_obs, kmap.T_ref_views)
    x_free = [np.asarray(fr["x_n"], float).reshape(-1, 2) for fr in frees]
    D_all = lab.keypoint_jacobian(np.concatenate([kmap.x_ref, x_obs, *x_free]))  # one call: refractive ones cost
    D_ref, D_obs, *D_free = np.split(D_all, np.cumsum([len(kmap.x_ref), len(x_obs), *map(len, x_free)])[:-1])
    views = []
    for fr, G, D in zip(frees, gains, D_free, strict=True):
        T_view_ref, idx = invert(fr["T_free"]), np.asarray(fr["map_idx"], int)
        u0 = _proj_jac(transform_points(T_view_ref, kmap.p_ref[idx]))[0]  # the projections at theta = 0
        views.append((T_view_ref, idx, u0, D, G))
    n = len(lab.cov)

    def d_of(th):
        M = _left_exp(th[n - 6:])
        Mi = invert(M)
        p = kmap.p_ref + _map_points(kmap, kmap.x_ref + D_ref @ th[:n - 6], x_obs + D_obs @ th[:n - 6],
                                     Mi @ kmap.T_ref_views @ M) - p0
        poses = []
        for T_view_ref, idx, u0, D, G in views:
            r = _proj_jac(transform_points(T_view_ref, p[idx]))[0] - u0 - D @ th[:n - 6]
            poses.append(_left_exp(-G @ r.ravel()) @ T_view_ref)
        return _log(invert(Mi @ T_a_b @ M) @ poses[0] @ invert(poses[1]))

    # 0.1 px, 1e-4 of a lens coefficient, 10 urad, 10 um: linear for the priors' 1-30 px, 1e-3-1, mrad and mm
    h = np.r_[np.full(4, 0.1), np.full(n - 10, 1e-4), np.full(6, 1e-5)]
    return np.array([(d_of(hi * e) - d_of(-hi * e)) / (2 * hi) for hi, e in zip(h, np.eye(n), strict=True)]).T


def relative_pose_disagreement(kmap: KeypointMap, free_a: dict, free_b: dict, T_a_b,
                               lab: LabPrior | None = None) -> tuple:
    """Test 2: the relative pose of two free single-view poses against the kinematic ``T_a_b``.

    ``free_a`` / ``free_b``: ``T_free`` (T_ref_view), ``map_idx`` (N,) map points and ``x_n`` (N, 2) their
    normalized keypoints (the free pose's inliers). Returns ``(d, chi2)``: ``d`` (6,) the rotation vector (rad) and
    translation (m) of ``T_a_b^-1 T_ab_images``, and its Mahalanobis square ``d^T C^-1 d``. ``C`` propagates
    through both least-squares poses (``(J^T J)^-1 J^T`` each; ``d`` by finite differences): the keypoint noise
    (each view's residual variance at its pose, which also holds the map's error as that view sees it) and the map
    points' depth errors (:func:`map_point_sigma`), shared by the two views - a map error moves both poses alike
    and mostly cancels in their relative pose. A PnP pose of a panel is poorly determined along the
    tilt-translation mode (1.8 deg of tilt and 22 mm of translation look alike at 0.7 m): a raw disagreement along
    it means little, the Mahalanobis square weighs it.

    Given ``lab`` (:class:`LabPrior`), ``C`` also holds the lab calibrations' errors (:func:`_lab_jacobian`): a
    mount or focal length a little off moves the kinematic ``T_a_b``, the map and both free poses, and on clean runs
    it is most of the disagreement (docs/integrity.md, "Test 2 and the lab's errors"). Without it that part is the
    overdispersion :data:`RELATIVE_OVERDISPERSION_FEATURES` the thresholds carry; on exact keypoints (an evaluator's
    oracle features) any sub-millimetre disagreement is then significant. ``lab`` needs the map's survey
    (``kmap.observations``, ``x_ref``, ``T_ref_views``).
    """
    T_b_a = invert(T_a_b)
    T_a_ref, T_b_ref = invert(free_a["T_free"]), invert(free_b["T_free"])

    def d_of(delta):
        return _log(T_b_a @ _left_exp(delta[:6]) @ T_a_ref @ invert(_left_exp(delta[6:]) @ T_b_ref))

    d0 = d_of(np.zeros(12))
    h = 1e-7
    J_d = np.array([(d_of(h * e) - d_of(-h * e)) / (2 * h) for e in np.eye(12)]).T
    sig_map = map_point_sigma(kmap)
    C = np.zeros((6, 6))
    B = np.zeros((6, len(kmap), 3))  # d's sensitivity to every map point (shared by the two views)
    gains = []
    for f, Jd in ((free_a, J_d[:, :6]), (free_b, J_d[:, 6:])):
        idx = np.asarray(f["map_idx"], int)
        J, A, u = _view_jacobians(kmap.p_ref[idx], f["T_free"])
        Jf = J.reshape(-1, 6)
        G = np.linalg.solve(Jf.T @ Jf, Jf.T)  # (6, 2N): the pose's least-squares response to its residuals
        gains.append(G)
        L = Jd @ G
        r = u - np.asarray(f["x_n"], float)
        var = float(np.sum(r**2) / max(2 * len(idx) - 6, 1))
        C += var * L @ L.T
        np.add.at(B, (slice(None), idx), np.einsum("kni,nij->knj", L.reshape(6, -1, 2), A))
    ray = kmap.p_ref / np.linalg.norm(kmap.p_ref, axis=1, keepdims=True)
    Bm = np.einsum("kmj,mj->km", B, ray) * sig_map  # (6, M): the depth error along each reference ray
    C += Bm @ Bm.T
    if lab is not None:
        J_lab = _lab_jacobian(kmap, [free_a, free_b], T_a_b, lab, gains)
        C += J_lab @ np.asarray(lab.cov, float) @ J_lab.T
    try:
        m2 = float(d0 @ np.linalg.solve(C, d0))
    except np.linalg.LinAlgError:
        m2 = float("inf")
    return d0, (m2 if np.isfinite(m2) else float("inf"))


def _overdispersion(lab) -> float:
    """Test 2's clean-run overdispersion for a covariance with the lab term (``lab`` given) or without it."""
    return RELATIVE_OVERDISPERSION if lab is not None else RELATIVE_OVERDISPERSION_FEATURES


def relative_pose_excess(d, m2: float, s2: float = RELATIVE_OVERDISPERSION) -> tuple:
    """The part of test 2's disagreement beyond what a clean run shows: ``(mm, deg)``.

    ``d = D + n``: the kinematic relative pose's error ``D`` plus the two free poses' noise ``n``, whose covariance
    is :func:`relative_pose_disagreement`'s ``C`` times the overdispersion ``s2`` (the spread of clean runs:
    :data:`RELATIVE_OVERDISPERSION` with the lab's covariances in ``C``, :data:`RELATIVE_OVERDISPERSION_FEATURES`
    without).
    Along the free poses' tilt-translation mode ``n`` is millimetres (clean runs: 2-18 mm and 0.14-2.3 deg, every
    one along that mode), so ``|d|`` overstates ``D``. The positive-part James-Stein estimate in the metric of that
    covariance (James & Stein 1961; it dominates ``d`` itself for 3 or more dimensions) shrinks ``d`` by its own
    significance: ``D_hat = max(0, 1 - (p - 2) s2 / m2) d``, ``p`` = :data:`RELATIVE_DOF`, ``m2`` the Mahalanobis
    square ``d^T C^-1 d``. A disagreement as significant as a clean run's counts little; one far beyond counts almost
    whole.

    Parameters
    ----------
    d : array_like (6,)
        Rotation vector (rad) and translation (m) of the disagreement.
    m2 : float
        Its Mahalanobis square (``inf`` counts it whole, NaN not at all).
    s2 : float
        The overdispersion of clean runs' squares.
    """
    d = np.asarray(d, float)
    scale = _shrinkage(m2, s2)
    return scale * float(np.linalg.norm(d[3:])) * 1e3, scale * float(np.rad2deg(np.linalg.norm(d[:3])))


def _shrinkage(m2: float, s2: float) -> float:
    """The positive-part James-Stein factor of :func:`relative_pose_excess` (0 for a NaN square)."""
    return max(0.0, 1.0 - (RELATIVE_DOF - 2) * s2 / m2) if m2 > 0 else 0.0


def with_relative_pose_excess(tests: dict) -> dict:
    """``tests`` with :func:`relative_pose_excess`'s statistics filled in from the stored disagreement and its
    Mahalanobis square where a locate.json of an earlier version lacks them (per region, then their root mean
    square, as :func:`assess_regions` pools them); a copy. Those versions' squares had no lab term: their
    overdispersion is :data:`RELATIVE_OVERDISPERSION_FEATURES`."""
    out = dict(tests)
    regions = sorted({k.split("/")[0] for k in out if k.endswith("/relative_pose_chi2")})
    for pre in [f"{r}/" for r in regions] or [""]:
        if f"{pre}relative_pose_excess_mm" in out or not np.isfinite(out.get(f"{pre}relative_pose_chi2", np.nan)):
            continue
        scale = _shrinkage(float(out[f"{pre}relative_pose_chi2"]), RELATIVE_OVERDISPERSION_FEATURES)
        for u in ("mm", "deg"):
            out[f"{pre}relative_pose_excess_{u}"] = scale * float(out[f"{pre}relative_pose_{u}"])
    if regions and "relative_pose_excess_mm" not in out:
        for u in ("mm", "deg"):
            v = [out[f"{r}/relative_pose_excess_{u}"] for r in regions if f"{r}/relative_pose_excess_{u}" in out]
            if v:
                out[f"relative_pose_excess_{u}"] = float(np.sqrt(np.mean(np.square(v))))
    return out


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
    T_ref_view = invert(homogeneous(cv2.Rodrigues(rvec)[0], tvec.ravel()))
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
            "map_idx": m.i1[free], "x_n": view.x_n[m.i2[free]],
            "residual_px": e[pred], "residual_vec": r[pred], "uv": view.features.uv[m.i2[pred]]}


def _rms(e):
    e = np.asarray(e, float)
    return float(np.sqrt(np.mean(e**2))) if len(e) else float("nan")


_STD_NORMAL_SQ = None


def norm_quantile(covariance, p: float) -> float:
    """The ``p`` quantile of ``|e|`` for ``e ~ N(0, covariance)`` (3 x 3, or any n x n).

    ``|e|^2`` is a weighted sum of chi-square(1) variables (the covariance's eigenvalues the weights), whose quantile
    has no closed form; it is taken over 400,000 fixed standard-normal draws (seeded: the same on every machine;
    relative error about 1 % at ``p = 1 - 1e-3``). For an isotropic covariance it is ``sigma sqrt(chi2_n^-1(p))``.
    """
    global _STD_NORMAL_SQ
    lam = np.clip(np.linalg.eigvalsh(np.asarray(covariance, float)), 0.0, None)
    if len(lam) > 6:
        raise ValueError(f"norm_quantile: at most 6 dimensions, got {len(lam)}")
    if _STD_NORMAL_SQ is None:  # fixed draws (400,000 x 6): the same quantile whatever was asked before
        _STD_NORMAL_SQ = np.random.default_rng(20261126).standard_normal((400_000, 6)) ** 2
    return float(np.sqrt(np.quantile(_STD_NORMAL_SQ[:, :len(lam)] @ lam, p)))


def protection_levels(covariance, tests: dict, kappa: float = 1.0, floor_mm: float | None = None,
                      floor_deg: float | None = None):
    """Protection radius (m) and angle (rad) from the pose covariance and the integrity tests' statistics.

    Per block (position, rotation): ``kappa * f_chi * q`` with ``q`` the ``1 - INTEGRITY_RISK`` quantile of the
    norm of a Gaussian error of that block's covariance (:func:`norm_quantile`), ``f_chi`` the test-3 inflation in
    ``tests`` (``inflation_chi2``) and ``kappa`` the estimator's measured covariance optimism (:func:`kappa_of`);
    then a third of test 2's disagreement beyond a clean run's (``relative_pose_excess_mm`` / ``_deg``,
    :func:`relative_pose_excess`) and the floor (default
    :data:`FLOOR_MM` / :data:`FLOOR_DEG`) are added in quadrature. Records ``kappa`` and the quantile factors
    (``q_factor_pos``, ``q_factor_rot``: ``q`` over the block's largest standard deviation) into ``tests``.

    Parameters
    ----------
    covariance : array_like (6, 6)
        Rotation vector (rad) then translation (m) of the base pose.
    tests : dict
        The statistics :func:`assess` computed (names carry units).
    """
    floor_mm = FLOOR_MM if floor_mm is None else float(floor_mm)
    floor_deg = FLOOR_DEG if floor_deg is None else float(floor_deg)
    cov = np.asarray(covariance, float)
    if not np.all(np.isfinite(cov)):
        return float("inf"), float("inf")
    f = float(kappa) * float(tests.get("inflation_chi2", 1.0))
    q_rot, q_pos = norm_quantile(cov[:3, :3], 1 - INTEGRITY_RISK), norm_quantile(cov[3:, 3:], 1 - INTEGRITY_RISK)
    s_rot = float(np.sqrt(max(np.linalg.eigvalsh(cov[:3, :3]).max(), 1e-300)))
    s_pos = float(np.sqrt(max(np.linalg.eigvalsh(cov[3:, 3:]).max(), 1e-300)))
    tests.update(kappa=float(kappa), q_factor_pos=q_pos / s_pos, q_factor_rot=q_rot / s_rot)
    return (_with_terms(f * q_pos, floor_mm * 1e-3, tests, "relative_pose_excess_mm", 1e-3),
            _with_terms(f * q_rot, np.deg2rad(floor_deg), tests, "relative_pose_excess_deg", np.deg2rad(1.0)))


def _with_terms(level: float, floor: float, tests: dict, key: str, unit: float) -> float:
    """A protection level ``level`` with the floor and a third of test 2's disagreement beyond a clean run's
    ``tests[key]`` (times ``unit`` into SI; absent or NaN when test 2 did not run) added in quadrature: a kinematic
    relative pose off by ``d`` moves the solution by about ``d``."""
    r = float(np.hypot(level, floor))
    d = tests.get(key)
    return float(np.hypot(r, d * unit / 3)) if d is not None and np.isfinite(d) else r


def point_covariance(covariance, T_site_base, p_site) -> np.ndarray:
    """The covariance (3, 3) of a point ``p_site`` the located base ``T_site_base`` carries: a base pose error
    ``(w, v)`` (left perturbation: rotation vector, then the base origin; the order of ``covariance`` (6, 6)) moves
    it by ``w x (p - t) + v``, so ``J C J^T`` with ``J = [-[p - t]x, I]`` (:func:`_point_jacobian`)."""
    J = _point_jacobian(T_site_base, p_site)
    return J @ np.asarray(covariance, float) @ J.T


def _point_jacobian(T_site_base, p_site) -> np.ndarray:
    """``J = [-[p - t]x, I]`` (3, 6): how a base pose error ``(w, v)`` moves the point ``p_site`` it carries."""
    return np.hstack([-skew(np.asarray(p_site, float) - np.asarray(T_site_base, float)[:3, 3]), np.eye(3)])


def point_protection_radius(covariance, tests: dict, T_site_base, p_site, floor_mm: float | None = None) -> float:
    """Protection radius (m) of a point the located base carries: a taught task's tool tip ``p_site`` (3,), fixed in
    the site frame and reached through the base pose ``T_site_base`` (4, 4).

    The covariance at the point is :func:`point_covariance`'s. The base origin is 1.6-2 m from the panel it was
    located on, and its error is mostly the rotation's at that lever arm: measured over the envelope
    (docs/integrity.md), the largest standard deviation at the panel centre is 9x smaller than at the base origin.
    Otherwise as :func:`protection_levels`' radius: the ``1 - INTEGRITY_RISK`` quantile of the error's norm
    (:func:`norm_quantile`) times test 3's inflation ``tests["inflation_chi2"]`` (the covariance as calibrated:
    ``locate_dataset`` applied :data:`KAPPA`), then the floor (default :data:`FLOOR_MM`: the arm's own execution
    through its calibrated model) and a third of test 2's disagreement beyond a clean run's in quadrature
    (:func:`_with_terms`)."""
    cov = np.asarray(covariance, float)
    if not np.all(np.isfinite(cov)):
        return float("inf")
    q = norm_quantile(point_covariance(cov, T_site_base, p_site), 1 - INTEGRITY_RISK)
    floor = (FLOOR_MM if floor_mm is None else float(floor_mm)) * 1e-3
    return _with_terms(float(tests.get("inflation_chi2", 1.0)) * q, floor, tests, "relative_pose_excess_mm", 1e-3)


def pose_condition(covariance, T_site_base, p_site) -> float:
    """Condition number of a base pose's covariance (6, 6) where the points ``p_site`` (N, 3) it was solved on are: the
    pose carried to their centroid (:func:`point_covariance`'s ``J``) and its rotation expressed as the displacement
    (m) at their RMS distance from it, so both blocks are in metres of the scene and the number does not depend on
    units or on the lever arm to the base origin. Near 1 for a pose the points fix equally in every direction; it
    grows as they become coincident, collinear or coplanar seen edge-on. NaN for a non-finite covariance or fewer
    than three points."""
    cov, p = np.asarray(covariance, float), np.asarray(p_site, float).reshape(-1, 3)
    if len(p) < 3 or not np.all(np.isfinite(cov)):
        return float("nan")
    c = p.mean(axis=0)
    spread = float(np.sqrt(np.mean(np.sum((p - c) ** 2, axis=1))))
    J = np.vstack([np.eye(3, 6), _point_jacobian(T_site_base, c)])  # the rotation kept, the origin moved to c
    D = np.diag([spread] * 3 + [1.0] * 3)
    ev = np.linalg.eigvalsh(D @ J @ (0.5 * (cov + cov.T)) @ J.T @ D)
    return float(ev.max() / ev.min()) if ev.min() > 0 else float("inf")


def smallest_eigenvalue(covariance) -> float:
    """Smallest eigenvalue of a covariance's symmetric part (NaN when it has a non-finite entry)."""
    cov = np.asarray(covariance, float)
    return float(np.linalg.eigvalsh(0.5 * (cov + cov.T)).min()) if np.all(np.isfinite(cov)) else float("nan")


def kappa_of(refine: str, pnp: bool = False, regions: int = 1, keypoints: str = "sift", covariance: str = "white",
             twins: str = "both") -> float:
    """The measured covariance optimism :data:`KAPPA` of an estimator (``refine`` mode; PnP: unmeasured); the joint
    bundle over more than one region of the scene (``regions`` solved together) has its own, and so has each on
    ``keypoints`` ``"aligned"`` (:mod:`bench.vision.patch_align`; the key's suffix ``_aligned``), with the
    ``covariance`` ``"field"`` (:mod:`bench.vision.field_covariance`; the suffix ``_field``) and with SIFT's
    ``twins`` ``"weighted"`` (``pipeline.twin_keypoints``; the suffix ``_weighted``)."""
    if pnp:
        return KAPPA_UNMEASURED
    key = "joints_regions" if str(refine) == "joints" and int(regions) > 1 else str(refine)
    key += "" if keypoints == "sift" else f"_{keypoints}"
    key += "" if covariance == "white" else f"_{covariance}"
    key += "" if twins == "both" else f"_{twins}"
    return KAPPA.get(key, KAPPA_UNMEASURED)


def assess(kmap: KeypointMap, surround: list, view_a: ViewObservation, view_b: ViewObservation, result,
           focal_px: float, image_size, config: MapConfig | None = None, seed: int = 0,
           lab: LabPrior | None = None) -> Integrity:
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
    lab : LabPrior, optional
        The lab calibrations' covariances for test 2 (without them its overdispersion is
        :data:`RELATIVE_OVERDISPERSION_FEATURES`).

    Returns
    -------
    Integrity
    """
    if not result.success:
        return Integrity("refused", [f"no localisation: {result.message}"])
    refuse, warn, soft, late, tests = _tests(kmap, surround, view_a, view_b, result, focal_px, image_size, config,
                                             seed, lab)
    return _verdict(refuse, warn + soft + late, tests, result.covariance)


def _tests(kmap, surround, view_a, view_b, result, focal_px, image_size, config, seed, lab=None) -> tuple:
    """Tests 1-6 of :func:`assess` on a localisation that succeeded: ``(refuse, warn, soft, late, tests)`` - the
    reasons to refuse, then the warnings of test 1, of tests 2, 3 and 5 (statistics that a localisation over several
    regions pools: :func:`assess_regions`) and of test 6, and the statistics."""
    cfg = config or MapConfig()
    refuse, warn, soft, late, tests = [], [], [], [], {}
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
    if "b" in loc and all(loc[k]["T_free"] is not None and loc[k]["free"] >= MIN_FREE_INLIERS for k in "ab"):
        d, m2 = relative_pose_disagreement(kmap, loc["a"], loc["b"], T_a_b, lab)
        s2 = _overdispersion(lab)
        d_t, d_r = float(np.linalg.norm(d[3:])), float(np.linalg.norm(d[:3]))
        tests["relative_pose_mm"], tests["relative_pose_deg"] = d_t * 1e3, np.rad2deg(d_r)
        tests["relative_pose_chi2"], tests["relative_pose_overdispersion"] = m2, s2
        ex_mm, ex_deg = relative_pose_excess(d, m2, s2)
        tests["relative_pose_excess_mm"], tests["relative_pose_excess_deg"] = ex_mm, ex_deg
        raw = d_t * 1e3 > RELATIVE_REFUSE_MM or np.rad2deg(d_r) > RELATIVE_REFUSE_DEG
        what = (f"the locate views' relative pose from the images differs from the joint readings' by "
                f"{d_t * 1e3:.1f} mm and {np.rad2deg(d_r):.2f} deg, Mahalanobis square {m2:.0f}")
        if raw and m2 > s2 * RELATIVE_Q_REFUSE:
            refuse.append(f"{what} (limits {RELATIVE_REFUSE_MM:g} mm, {RELATIVE_REFUSE_DEG:g} deg, "
                          f"{s2 * RELATIVE_Q_REFUSE:.0f})")
        elif ex_mm > RELATIVE_REFUSE_MM / 3 or ex_deg > RELATIVE_REFUSE_DEG / 3 or m2 > s2 * RELATIVE_Q_WARN:
            soft.append(f"{what}; beyond a clean run's {ex_mm:.1f} mm and {ex_deg:.2f} deg")

    # --- test 3: reprojection chi-square, locate views vs the survey's own noise -----------------------------------
    sigma_survey = _rms(np.concatenate(survey_res)) if survey_res else float("nan")
    res_loc = np.concatenate([c["residual_px"] for c in loc.values()])
    rms_loc = _rms(res_loc)
    # no detector localises better than NOISE_FLOOR_PX: below it the ratio would compare rounding errors (exact data)
    ratio = rms_loc / max(sigma_survey, NOISE_FLOOR_PX) if np.isfinite(sigma_survey) else float("nan")
    tests.update(survey_rms_px=sigma_survey, locate_rms_px=rms_loc, chi2_ratio=ratio,
                 survey_residuals=float(sum(len(r) for r in survey_res)), locate_residuals=float(len(res_loc)))
    if np.isfinite(ratio) and ratio > CHI2_RATIO_REFUSE:
        refuse.append(f"reprojection RMS {rms_loc:.2f} px at the solution, {ratio:.1f} x the survey's "
                      f"{sigma_survey:.2f} px (limit {CHI2_RATIO_REFUSE:g} x)")
    elif np.isfinite(ratio) and ratio > CHI2_RATIO_WARN:
        soft.append(f"reprojection RMS {rms_loc:.2f} px, {ratio:.1f} x the survey's")

    # --- test 4: whiteness ------------------------------------------------------------------------------------------
    rho = _whiteness(loc["a"]["uv"], loc["a"]["residual_vec"])
    tests["whiteness_rho"] = rho

    # --- test 5: support --------------------------------------------------------------------------------------------
    frac_in = result.n_inliers / max(result.n_matches, 1)
    spread = _hull_fraction(loc["a"]["uv"], image_size)
    tests.update(inliers=float(result.n_inliers), inlier_fraction=frac_in, spread_fraction=spread)
    if result.n_inliers < MIN_INLIERS:
        refuse.append(f"{result.n_inliers} inliers (need {MIN_INLIERS})")
    elif result.n_inliers < WARN_INLIERS:
        soft.append(f"only {result.n_inliers} inliers")
    if frac_in < WARN_INLIER_FRACTION:
        soft.append(f"inlier fraction {frac_in:.2f} of {result.n_matches} matches")
    if spread < WARN_SPREAD:
        soft.append(f"inliers cover {spread * 100:.1f} % of image a")

    # --- test 6: conditioning ---------------------------------------------------------------------------------------
    tests["condition"] = float(result.condition)
    tests["covariance_min_eig"] = smallest_eigenvalue(result.covariance)
    if not tests["covariance_min_eig"] > 0:  # a least-squares covariance that is not positive definite
        refuse.append(f"the pose's covariance is not positive definite (smallest eigenvalue "
                      f"{tests['covariance_min_eig']:.3g}): the pose is not determined")
    late += _conditioning(result, tests, refuse)

    return refuse, warn, soft, late, tests


def _conditioning(result, tests: dict, refuse: list) -> list:
    """Test 6's condition number: the joint bundle's :func:`pose_condition` when it refined the pose (its
    statistic ``pose_condition``; the thesis start's ``condition`` is then reported only: over 121 clean four-region
    and default runs it did not predict error / radius), else the thesis estimator's ``condition``. Appends a
    refusal to ``refuse``; returns the warnings."""
    cond, what = float(result.pose_condition), "pose (joint bundle)"
    if np.isnan(cond):
        cond, what = float(result.condition), "pose problem"
    else:
        tests["pose_condition"] = cond
    if not cond < REFUSE_CONDITION:
        refuse.append(f"ill-conditioned {what} (condition {cond:.3g})")
    elif cond > WARN_CONDITION:
        return [f"ill-conditioned {what} (condition {cond:.3g})"]
    return []


def _verdict(refuse: list, warn: list, tests: dict, covariance) -> Integrity:
    """The protection levels from ``covariance`` (as calibrated: ``locate_dataset`` applied :data:`KAPPA`) and the
    tests, and the level: refused on any reason to refuse, a warning on any warning or a level above the alert
    limits."""
    ratio = tests.get("chi2_ratio", float("nan"))
    tests["inflation_chi2"] = max(1.0, ratio) if np.isfinite(ratio) else 1.0
    pr, pa = protection_levels(covariance, tests)
    if refuse:
        return Integrity("refused", refuse + warn, float("inf"), float("inf"), tests)
    alert = _alert(pr, pa)
    warn += [alert] if alert else []
    return Integrity("warning" if warn else "ok", warn, pr, pa, tests)


def _alert(pr: float, pa: float) -> str | None:
    """The warning for protection levels (m, rad) above the alert limits; None within them."""
    if pr * 1e3 > ALERT_MM or np.rad2deg(pa) > ALERT_DEG:
        return (f"protection radius {pr * 1e3:.2f} mm / {np.rad2deg(pa):.3f} deg exceeds the alert limit "
                f"{ALERT_MM:g} mm / {ALERT_DEG:g} deg")
    return None


def relevel(integ: Integrity, covariance) -> Integrity:
    """The protection levels of a localisation that was not refused again, from a new ``covariance`` of its pose
    (as calibrated; e.g. with the INS's tilt fused: :func:`bench.vision.tilt.fuse`) with the same tests; the alert
    limits' warning follows them, the other reasons stay. Returns ``integ`` (changed in place)."""
    if integ.level == "refused":
        return integ
    old = _alert(integ.protection_radius_m, integ.protection_angle_rad)
    integ.reasons = [r for r in integ.reasons if r != old]
    integ.protection_radius_m, integ.protection_angle_rad = protection_levels(covariance, integ.tests)
    alert = _alert(integ.protection_radius_m, integ.protection_angle_rad)
    integ.reasons += [alert] if alert else []
    integ.level = "warning" if integ.reasons else "ok"
    return integ


def assess_regions(parts: list, result, focal_px: float, image_size, config: MapConfig | None = None,
                   seed: int = 0, lab: LabPrior | None = None) -> Integrity:
    """Integrity of a localisation over several regions of the scene, each with its own map and two locate views,
    solved together (``result``: one base pose and its calibrated covariance).

    Tests 1-6 (:func:`assess`) run in every region at the common solution. A region's reasons to refuse, and its
    test-1 warnings (a view against the map), are its own: they refuse or warn the whole, and each region's level is
    in ``regions`` (a caller may leave a refused region out and solve again). The soft tests pool the regions, so
    that more regions do not mean more chances of a false alarm: test 2 on the root mean square of the regions'
    relative-pose disagreements and of their parts beyond a clean run's (an error common to their kinematics shows
    in every one, their noise averages) and the sum of their Mahalanobis squares (against the overdispersion times
    chi2 with 6 per region degrees of freedom at 0.99; with ``lab``, :class:`LabPrior`, the lab's errors are in every
    region's square - common to the regions, so the sum is spread wider than that chi2: were they all of it and fully
    shared, 4 / 7 / 10 % false warnings with 2 / 3 / 4 regions instead of 1 %; the refusal is each region's), test 3
    on every region's residuals pooled (the locate views' RMS against the survey views'), test 5 on the inliers
    summed and the largest spread; test 6 on the common solution. The protection levels come from the common
    covariance with the pooled tests 2 and 3. The statistics are reported per region (``"<region>/<test>"``) and pooled.

    Parameters
    ----------
    parts : list of tuple
        Per region ``(name, kmap, surround, view_a, view_b, own)``: its map, surrounding views, locate views and its
        own (thesis) localisation, whose match and inlier counts it reports.
    lab : LabPrior, optional
        As :func:`assess`'s.
    """
    from scipy.stats import chi2

    if not result.success:
        return Integrity("refused", [f"no localisation: {result.message}"],
                         regions={p[0]: "refused" for p in parts})
    refuse, warn, late, tests, regions, region_reasons = [], [], [], {}, {}, {}
    keys = ("relative_pose_mm", "relative_pose_deg", "relative_pose_chi2", "relative_pose_excess_mm",
            "relative_pose_excess_deg", "survey_rms_px", "survey_residuals",
            "locate_rms_px", "locate_residuals", "spread_fraction")
    each = {k: [] for k in keys}
    n_in = n_match = 0
    for name, kmap, surround, a, b, own in parts:
        T_ref_a = invert(kmap.T_world_ref) @ np.asarray(result.T_world_base, float) @ np.asarray(a.T_base_cam, float)
        at = replace(result, T_ref_cam=T_ref_a, n_matches=own.n_matches, n_inliers=own.n_inliers)
        r_ref, r_warn, r_soft, late, t = _tests(kmap, surround, a, b, at, focal_px, image_size, config, seed, lab)
        regions[name] = "refused" if r_ref else "warning" if r_warn else "ok"
        region_reasons[name] = r_ref + r_warn + r_soft
        refuse += [f"region {name}: {r}" for r in r_ref]
        warn += [f"region {name}: {r}" for r in r_warn]
        tests.update({f"{name}/{k}": v for k, v in t.items()})
        for k, v in each.items():
            v.append(t.get(k, float("nan")))
        n_in, n_match = n_in + own.n_inliers, n_match + own.n_matches
    e = {k: np.array(v, float) for k, v in each.items()}
    soft = []
    # --- test 2 pooled
    ok = np.isfinite(e["relative_pose_mm"])
    if ok.any():
        pooled = {k: float(np.sqrt(np.mean(e[k][ok] ** 2))) for k in ("relative_pose_mm", "relative_pose_deg",
                                                                       "relative_pose_excess_mm",
                                                                       "relative_pose_excess_deg")}
        m2 = float(np.sum(e["relative_pose_chi2"][ok]))
        tests.update(pooled, relative_pose_chi2=m2)
        ex_mm, ex_deg = pooled["relative_pose_excess_mm"], pooled["relative_pose_excess_deg"]
        s2 = _overdispersion(lab)
        tests["relative_pose_overdispersion"] = s2
        limit = s2 * float(chi2.ppf(0.99, RELATIVE_DOF * int(ok.sum())))
        if ex_mm > RELATIVE_REFUSE_MM / 3 or ex_deg > RELATIVE_REFUSE_DEG / 3 or m2 > limit:
            soft.append(f"the locate views' relative poses from the images differ from the joint readings' by "
                        f"{pooled['relative_pose_mm']:.1f} mm and {pooled['relative_pose_deg']:.2f} deg (RMS over "
                        f"{int(ok.sum())} regions), Mahalanobis square {m2:.0f}; beyond a clean run's {ex_mm:.1f} "
                        f"mm and {ex_deg:.2f} deg")
    # --- test 3 pooled
    for k in ("survey", "locate"):
        rms, n = e[f"{k}_rms_px"], e[f"{k}_residuals"]
        ok = np.isfinite(rms) & (n > 0)
        tests[f"{k}_rms_px"] = float(np.sqrt(np.sum(n[ok] * rms[ok] ** 2) / n[ok].sum())) if ok.any() else np.nan
    ratio = tests["locate_rms_px"] / max(tests["survey_rms_px"], NOISE_FLOOR_PX)
    tests["chi2_ratio"] = ratio
    if np.isfinite(ratio) and ratio > CHI2_RATIO_WARN:
        soft.append(f"reprojection RMS {tests['locate_rms_px']:.2f} px, {ratio:.1f} x the survey's (every region)")
    # --- test 5 pooled
    frac_in = n_in / max(n_match, 1)
    spread = float(np.nanmax(e["spread_fraction"])) if np.isfinite(e["spread_fraction"]).any() else 0.0
    tests.update(inliers=float(n_in), inlier_fraction=frac_in, spread_fraction=spread, regions=float(len(parts)),
                 condition=float(result.condition), covariance_min_eig=smallest_eigenvalue(result.covariance))
    if not np.isnan(result.pose_condition):
        tests["pose_condition"] = float(result.pose_condition)
    if n_in < WARN_INLIERS:
        soft.append(f"only {n_in} inliers in {len(parts)} regions")
    if frac_in < WARN_INLIER_FRACTION:
        soft.append(f"inlier fraction {frac_in:.2f} of {n_match} matches")
    if spread < WARN_SPREAD:
        soft.append(f"inliers cover at most {spread * 100:.1f} % of a region's image a")
    out = _verdict(refuse, warn + soft + late, tests, result.covariance)  # test 6: the common solution's, as run last
    out.regions, out.region_reasons = regions, region_reasons
    return out
