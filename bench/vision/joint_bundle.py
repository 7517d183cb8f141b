"""The localisation's maximum-likelihood estimate with the joint readings as measurements (issue 11).

The thesis's estimators (:func:`~bench.vision.insitu.locate`: RANSAC + absolute orientation, then optionally the
reprojection refinement and the bundle over the map) take every view's pose from the joint readings as exact. The
readings are measurements: encoders have noise and quantisation, ``sigma_enc`` per joint. At 0.7 m and a survey
baseline of ~100 mm, 0.002 deg on each of six joints moves the map as much as the keypoint noise does (Eq. 123:
the disparity error is amplified by range / baseline). :func:`joint_bundle` estimates, together,

* the base pose of the locate parking in the site (survey base) frame, ``T_site_b2`` (6: ``R' = exp(w) R``,
  ``t' = t + v`` - ``v`` is the base origin's shift, as in the scored error);
* every view's six joint angles, with the readings as a Gaussian prior of ``sigma_enc`` (rad);
* optionally the intrinsics and the mount, under the lab's covariances;
* every map point (site frame), eliminated point by point (Schur complement),

from every observation the matching produced: each map point in the reference view, in the surrounding views that
contributed to it (:attr:`~bench.vision.insitu.KeypointMap.observations`) and in the two locate views where the
final solve used it (:attr:`~bench.vision.insitu.LocateResult.used`). The camera poses are
``T_site_cam = link5(q, eps) T_link5_cam`` (survey) and ``T_site_b2 link5(q, eps) T_link5_cam`` (locate) through the
calibrated arm (Eq. 188), and with the lab calibrations' covariances as priors also the intrinsics ``fx, fy, cx,
cy`` and the camera mount (the survey's and the locate views' points observe them). Residuals are pixels through
the calibrated camera (Eq. 50, 75-76); ``sigma_px`` is re-estimated from the residuals, with a gate against heavy
tails. Jacobians: the projection and the point derivative analytic, the pose
derivatives by central differences of the kinematics (6 joints of every view at once, 6 base and 6 mount
coordinates) -
:func:`residuals_and_jacobian` is checked against a difference quotient of :func:`residuals` in the tests.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from bench.camera.model import check_dist, distort, distortion_jacobian, distortion_parameter_jacobian, to_pixels
from bench.geometry.quaternion import rotation_vector_to_matrix
from bench.geometry.transforms import homogeneous
from bench.robot.orientation import link5_frame
from bench.vision.bundle import solve
from bench.vision.field_covariance import FieldCovariance, field_covariance
from bench.vision.insitu import _proj_jac

#: the prior sd of the lens's k3 that a Heikkila calibration (k1 k2 p1 p2) does not estimate, when the joint bundle
#: refines it (``bench locate --refine-k3``, the in-situ kind's ``pipeline.refine_k3``): of the order of the k3 that
#: the best central camera of the bench's lens behind its flat port needs at 0.5-1.0 m (10.3-10.5); 10 and 100 gave
#: the same in-situ errors, so the views decide (docs/bounds.md)
K3_PRIOR_SD = 10.0


@dataclass(frozen=True)
class JointBundleResult:
    """Outcome of :func:`joint_bundle`.

    ``T_site_base`` (4, 4) the locate parking's base in the site frame; ``covariance`` (6, 6) its first-order
    covariance (rotation vector rad in the site frame, then the base origin m: the meaning of
    :attr:`~bench.vision.insitu.LocateResult.covariance`); ``q`` (V, 6) the refined joint angles (rad); ``K`` (3, 3)
    and ``T_link5_cam`` (4, 4) the intrinsics and mount (refined when their priors were given); ``sigma_px`` the
    pixel noise the residuals gave; ``rms_px`` the final residual RMS; ``observations`` those kept by the gate;
    ``field`` the keypoint error field behind ``covariance`` (:class:`~bench.vision.field_covariance.FieldCovariance`,
    with ``field_order``; None: white pixel noise).
    """

    success: bool
    message: str
    T_site_base: np.ndarray
    covariance: np.ndarray
    q: np.ndarray
    sigma_px: float
    rms_px: float
    observations: int
    iterations: int
    K: np.ndarray | None = None
    T_link5_cam: np.ndarray | None = None
    dist: np.ndarray | None = None
    field: FieldCovariance | None = None


class _Problem:
    """The observations, the camera and the kinematics of :func:`joint_bundle` (see the module docstring).

    Parameter vector: ``xi`` (6), the joints view by view (6 V), then ``d_K`` (``dfx, dfy, dcx, dcy`` px) if
    ``with_K``, ``d_dist`` (``dk1, dk2, dp1, dp2``, and ``dk3`` with ``with_k3``) if ``with_dist`` and ``d_mount``
    (6: ``T_link5_cam [[exp(w), v], [0, 1]]``) if ``with_mount``."""

    step = 1e-7

    def __init__(self, robot, eps, T_link5_cam, is_locate, view, point, uv, K, dist=None, with_K=False,
                 with_mount=False, with_dist=False, with_k3=False):
        self.robot, self.eps, self.mount = robot, np.asarray(eps, float), np.asarray(T_link5_cam, float)
        self.is_locate = np.asarray(is_locate, bool)
        self.view, self.point, self.uv = np.asarray(view, int), np.asarray(point, int), np.asarray(uv, float)
        self.K = np.asarray(K, float)
        self.dist = np.zeros(5) if dist is None or not len(dist) else check_dist(dist)
        self.with_K, self.with_mount, self.with_dist = bool(with_K), bool(with_mount), bool(with_dist)
        if with_k3 and not with_dist:
            raise ValueError("k3 is refined with the distortion block (with_dist)")
        self.nd = 5 if with_k3 else 4  # the distortion block's size
        self.V = len(self.is_locate)
        self.n = 6 + 6 * self.V + 4 * self.with_K + self.nd * self.with_dist + 6 * self.with_mount

    def split(self, theta):
        """``theta (n,)`` -> ``xi (6,), q (V, 6), d_K (4,), d_dist (4,) or (5,), d_mount (6,)`` (zeros for a block
        not estimated)."""
        xi, q = theta[:6], theta[6:6 + 6 * self.V].reshape(self.V, 6)
        k = 6 + 6 * self.V
        d_K = theta[k:k + 4] if self.with_K else np.zeros(4)
        k += 4 * self.with_K
        d_d = theta[k:k + self.nd] if self.with_dist else np.zeros(4)
        k += self.nd * self.with_dist
        d_m = theta[k:k + 6] if self.with_mount else np.zeros(6)
        return xi, q, d_K, d_d, d_m

    def distortion(self, d_dist) -> np.ndarray:
        """The distortion ``(5,)`` with ``k1, k2, p1, p2`` (and ``k3`` when ``d_dist`` has five) moved by
        ``d_dist``; otherwise k3 as calibrated."""
        return self.dist + (np.r_[d_dist, 0.0] if len(d_dist) == 4 else d_dist)

    def mounted(self, d_mount) -> np.ndarray:
        """The mount ``T_link5_cam`` (4, 4) moved by ``d_mount`` (a right perturbation ``[w, v]``)."""
        return self.mount @ homogeneous(rotation_vector_to_matrix(d_mount[:3]), d_mount[3:])

    def intrinsics(self, d_K) -> np.ndarray:
        K = self.K.copy()
        K[0, 0] += d_K[0]
        K[1, 1] += d_K[1]
        K[:2, 2] += d_K[2:]
        return K

    def poses(self, theta, T_b2) -> np.ndarray:
        """``T_cam_site`` (V, 4, 4) of every view."""
        xi, q, _, _, d_m = self.split(theta)
        T = np.array(T_b2, dtype=float)
        T[:3, :3] = rotation_vector_to_matrix(xi[:3]) @ T[:3, :3]
        T[:3, 3] += xi[3:]
        T_site_cam = link5_frame(self.robot, q, self.eps) @ self.mounted(d_m)
        T_site_cam[self.is_locate] = T @ T_site_cam[self.is_locate]
        return np.linalg.inv(T_site_cam)

    def camera_points(self, T_cs, X) -> np.ndarray:
        R, t = T_cs[self.view, :3, :3], T_cs[self.view, :3, 3]
        return np.einsum("nij,nj->ni", R, X[self.point]) + t

    def pixels(self, p, d_K, d_dist) -> np.ndarray:
        return to_pixels(distort(p[:, :2] / p[:, 2:3], self.distortion(d_dist)), self.intrinsics(d_K))


def residuals(problem: _Problem, theta, T_b2, X) -> np.ndarray:
    """Pixel residuals ``uv - K distort(pi(p_cam))`` (N, 2) of every observation."""
    p = problem.camera_points(problem.poses(theta, T_b2), X)
    _, _, d_K, d_d, _ = problem.split(theta)
    return problem.uv - problem.pixels(p, d_K, d_d)


def residuals_and_jacobian(problem: _Problem, theta, T_b2, X) -> tuple:
    """Residuals (N, 2), ``J_par (N, 2, n)`` (d residual / d parameters) and ``J_pt (N, 2, 3)`` (d residual of
    observation n / d its point), and the smallest depth (m) of a point in a camera."""
    T_cs = problem.poses(theta, T_b2)
    p = problem.camera_points(T_cs, X)
    _, _, d_K, d_d, _ = problem.split(theta)
    K, dist = problem.intrinsics(d_K), problem.distortion(d_d)
    z = p[:, 2]
    x_n, Jproj = _proj_jac(p)
    x_d = distort(x_n, dist)
    A = K[:2, :2] @ distortion_jacobian(x_n, dist) @ Jproj  # d uv / d p_cam (N, 2, 3)
    N, V, h = len(p), problem.V, problem.step
    J = np.zeros((N, 2, problem.n))

    def dp(at):
        """The camera points' central difference for a step ``h`` of the parameters ``at`` (an index or a slice)."""
        e = np.zeros(problem.n)
        e[at] = h
        return (problem.camera_points(problem.poses(theta + e, T_b2), X)
                - problem.camera_points(problem.poses(theta - e, T_b2), X)) / (2 * h)

    for c in range(6):  # the base pose: its rows are the locate views'
        J[:, :, c] = -np.einsum("nij,nj->ni", A, dp(c))
    for c in range(6):  # joint c of every view at once: rows of view v depend on its own joints only
        J[np.arange(N), :, 6 + 6 * problem.view + c] = -np.einsum("nij,nj->ni", A, dp(slice(6 + c, 6 + 6 * V, 6)))
    k = 6 + 6 * V
    if problem.with_K:  # u = fx x_d + s y_d + cx, v = fy y_d + cy
        J[:, 0, k], J[:, 1, k + 1], J[:, 0, k + 2], J[:, 1, k + 3] = -x_d[:, 0], -x_d[:, 1], -1.0, -1.0
        k += 4
    if problem.with_dist:
        J[:, :, k:k + 4] = -K[:2, :2] @ distortion_parameter_jacobian(x_n)
        if problem.nd == 5:  # x_d = x_n (1 + k1 r^2 + k2 r^4 + k3 r^6) + tangential: d x_d / d k3 = x_n r^6
            r6 = np.sum(x_n**2, axis=1) ** 3
            J[:, :, k + 4] = -(x_n * r6[:, None]) @ K[:2, :2].T
        k += problem.nd
    if problem.with_mount:
        for c in range(6):
            J[:, :, k + c] = -np.einsum("nij,nj->ni", A, dp(k + c))
    J_pt = -A @ T_cs[problem.view, :3, :3]
    uv = to_pixels(x_d, K)
    return problem.uv - uv, J, J_pt, float(z.min())


class _Bound:
    """The problem at a fixed starting base pose, as :func:`bench.vision.bundle.solve` takes it."""

    def __init__(self, problem: _Problem, T_b2):
        self.problem, self.T_b2, self.point = problem, T_b2, problem.point

    def residuals(self, theta, X):
        return residuals(self.problem, theta, self.T_b2, X)

    def linearise(self, theta, X):
        return residuals_and_jacobian(self.problem, theta, self.T_b2, X)


def joint_bundle(robot, eps, T_link5_cam, q_read, is_locate, T_site_b2, view, point, uv, X, sigma_enc: float,
                 sigma_px: float, K, dist=None, cov_K=None, cov_mount=None, iterations: int = 10, rounds: int = 3,
                 gate: float | None = 3.5, cov_K_mount=None, cov_dist=None, cov_K_dist=None,
                 cov_dist_mount=None, loss: str | None = None, k3_sd: float | None = None,
                 field_order: int | None = None, image_size=None, weights=None) -> JointBundleResult:
    """Base pose, joints of every view, map points (and the intrinsics and mount under their lab priors) by maximum
    likelihood (see the module docstring).

    Parameters
    ----------
    robot, eps, T_link5_cam
        The calibrated arm: model, identified errors (42,), camera mount (4, 4).
    q_read : ndarray (V, 6)
        Joint readings (rad) of the views (reference, surrounding, then the locate views).
    is_locate : ndarray (V,) bool
        The views taken at the locate parking.
    T_site_b2 : ndarray (4, 4)
        Starting base pose of the locate parking in the site frame (e.g. the thesis estimator's).
    view, point : ndarray (N,) int
        Observation ``n`` is of point ``point[n]`` in view ``view[n]``; ``uv (N, 2)`` its keypoint (px).
    X : ndarray (M, 3)
        Starting points (site frame, m); every point must be observed in at least two views.
    sigma_enc : float
        Encoder standard deviation (rad per joint, quantisation included) - from the encoders' specification.
    sigma_px : float
        Starting pixel noise (px; re-estimated from the residuals).
    K, dist : ndarray (3, 3), (5,)
        The calibrated camera (intrinsics px, OpenCV distortion).
    cov_K : ndarray (4, 4), optional
        The lab calibration's covariance of ``fx, fy, cx, cy`` (px^2): given, the four are refined under it as a prior.
    cov_mount : ndarray (6, 6), optional
        The mount's covariance (rotation vector rad, then m; right perturbation): given, the mount is refined.
    cov_K_mount : ndarray (4, 6), optional
        Their cross-covariance (with both): the prior is then the joint one over the ten (a rig's tolerances move
        the focal length and the mount along the optical axis together).
    cov_dist : ndarray (4, 4) or (5, 5), optional
        The lab calibration's covariance of ``k1, k2, p1, p2`` (and ``k3`` when the lab fitted it: (5, 5)): given,
        those coefficients are refined under it as a prior; ``cov_K_dist`` (4, 4 or 5) and ``cov_dist_mount``
        (4 or 5, 6) its cross-covariances with the intrinsics and the mount.
    k3_sd : float, optional
        With a (4, 4) ``cov_dist``: the lens's sixth-order ``k3`` is refined too, under a prior of this standard
        deviation about its calibrated value, independent of the other blocks (the lab's Heikkila fit holds k3 fixed,
        so its covariance has no k3; behind a flat port the best central camera needs one: docs/bounds.md). A
        (5, 5) ``cov_dist`` carries k3 already, with its cross-covariances (the consistent prior).
    iterations, rounds : int
        Gauss-Newton iterations per round; rounds of re-estimating the pixel noise and the gate.
    gate : float or None
        After each round, observations whose residual exceeds ``gate`` x the robust sigma (median residual / 1.1774)
        weigh nothing in the next (keypoints' errors have heavy tails: measured ~0.09 px robust but 0.35 px RMS
        within 5 px under realistic imaging); ``None`` keeps every observation.
    loss : {None, "huber"}
        None: least squares on the observations the gate keeps; ``"huber"``: Huber's M-estimate by iteratively
        re-weighted least squares (:func:`bench.vision.bundle.solve`): the tail below the gate weighs less.
    field_order : int, optional
        Given (0-3, with ``image_size (w, h)``): the covariance is the estimate's with each view's keypoint error
        field of that order, measured on the residuals (:func:`bench.vision.field_covariance.field_covariance`;
        ``field`` of the result); None: the first-order covariance of white pixel noise.
    weights : ndarray (N,), optional
        Each observation's share of a measurement (:func:`detection_weights`: ``worth / k`` for each of the ``k``
        observations of one view at one pixel - one keypoint); None: each observation is one measurement.
    """
    if field_order is not None and image_size is None:
        raise ValueError("field_order needs the image_size (w, h)")
    if field_order is not None and weights is not None:
        raise ValueError("the keypoint-field covariance weighs every observation as one measurement: no weights")
    q_read = np.asarray(q_read, float)
    X = np.array(X, dtype=float)
    V, M = len(q_read), len(X)
    nan6 = np.full((6, 6), np.nan)
    if not (sigma_enc > 0 and sigma_px > 0):
        raise ValueError(f"sigma_enc ({sigma_enc} rad) and sigma_px ({sigma_px} px) must be > 0")
    counts = np.bincount(np.asarray(point, int), minlength=M)
    if np.any(counts < 2):
        raise ValueError(f"{int(np.sum(counts < 2))} points observed in fewer than two views")
    nd = distortion_block_size(cov_dist, k3_sd)
    problem = _Problem(robot, eps, T_link5_cam, is_locate, view, point, uv, K, dist, cov_K is not None,
                       cov_mount is not None, cov_dist is not None, nd == 5)
    n = problem.n
    info0 = np.zeros((n, n))  # the priors' information (rad^-2, px^-2, m^-2)
    info0[6:6 + 6 * V, 6:6 + 6 * V] = np.eye(6 * V) / sigma_enc**2
    k = 6 + 6 * V
    lab = lab_prior(cov_K, cov_dist, cov_mount, cov_K_dist, cov_K_mount, cov_dist_mount, k3_sd)
    if lab is not None:
        info0[k:, k:] = np.linalg.inv(lab)
    mean = np.r_[np.zeros(6), q_read.ravel(), np.zeros(n - 6 - 6 * V)]
    sol = solve(_Bound(problem, T_site_b2), mean, mean, info0, X, sigma_px, iterations, rounds, gate, dof_offset=6,
                loss=loss, weights=weights)
    if not sol.success:
        return JointBundleResult(False, sol.message, T_site_b2, nan6, q_read, sol.sigma_px, np.nan, len(problem.view),
                                 sol.iterations)
    theta, keep, s_px = sol.theta, sol.keep, sol.sigma_px
    cov, field = sol.covariance()[:6, :6], None
    if field_order is not None:
        field = field_covariance(_Bound(problem, T_site_b2), sol, info0, problem.view, problem.uv, image_size,
                                 field_order)
        cov = field.covariance[:6, :6]
    r = residuals(problem, theta, T_site_b2, sol.X)
    xi, q, d_K, d_d, d_m = problem.split(theta)
    T = np.array(T_site_b2, dtype=float)
    T[:3, :3] = rotation_vector_to_matrix(xi[:3]) @ T[:3, :3]
    T[:3, 3] += xi[3:]
    r = r[keep]
    rms = float(np.sqrt(np.mean(np.sum(r**2, axis=1)) / 2))
    extra = ((", intrinsics" if cov_K is not None else "")
             + (", distortion" + (" with k3" if nd == 5 else "") if cov_dist is not None else "")
             + (", mount" if cov_mount is not None else "")
             + ("" if field is None else f"; covariance with the keypoints' {field.message}"))
    return JointBundleResult(True, f"ok; joint bundle of {M} points, {len(r)} of {len(keep)} observations kept, {V} "
                             f"views' joints{extra}, sigma {s_px:.3g} px", T, cov, q, s_px, rms,
                             len(r), sol.iterations, problem.intrinsics(d_K), problem.mounted(d_m),
                             problem.distortion(d_d), field)


def detection_weights(view, uv, tol_px: float, worth: float = 1.0) -> np.ndarray:
    """Each observation's share of a measurement: the ``k`` observations of one view whose keypoints lie within
    ``tol_px`` of each other (linked pairwise: one keypoint assigned to several map points - SIFT's twins, a second
    orientation at the same pixel, Lowe 2004 section 5) share ``worth`` measurements, ``worth / k`` each; the others
    are one each.

    Parameters
    ----------
    view : ndarray (N,) int
        Each observation's view.
    uv : ndarray (N, 2)
        Its keypoint (px).
    tol_px : float
        Keypoints closer than this (px) are one (> 0).
    worth : float
        What such a shared keypoint is worth, in measurements of a keypoint of its own (1: one measurement; more
        for a class of keypoints that errs less - :data:`bench.vision.insitu.TWIN_WORTH`); in (0, 2], and no share
        above 1.

    Returns
    -------
    ndarray (N,)
        Shares in (0, 1]; with ``worth`` 1 they sum to the number of distinct keypoints in each view.
    """
    view, uv = np.asarray(view, int), np.asarray(uv, float)
    if not tol_px > 0:
        raise ValueError(f"tol_px: expected > 0, got {tol_px}")
    if not 0 < worth <= 2:
        raise ValueError(f"worth: expected a keypoint's worth in (0, 2] measurements, got {worth}")
    if uv.shape != (len(view), 2) or not np.all(np.isfinite(uv)):
        raise ValueError(f"uv: expected ({len(view)}, 2) finite pixels, got shape {uv.shape}")
    w = np.ones(len(view))
    for v in np.unique(view):
        idx = np.flatnonzero(view == v)
        pairs = cKDTree(uv[idx]).query_pairs(tol_px, output_type="ndarray")
        if len(pairs) == 0:
            continue
        graph = csr_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(idx), len(idx)))
        _, label = connected_components(graph, directed=False)
        k = np.bincount(label)[label]
        w[idx] = np.where(k > 1, np.minimum(worth / k, 1.0), 1.0)
    return w


def distortion_block_size(cov_dist=None, k3_sd=None) -> int:
    """How many lens coefficients the joint bundle (and the bound) refine: 0 without ``cov_dist``; 4 (``k1 k2 p1
    p2``) with a (4, 4) one; 5 (``k3`` too) with a (5, 5) one - the lab fitted k3 and its covariance carries it - or
    with a (4, 4) one and ``k3_sd``, k3's independent prior sd. ValueError for ``k3_sd`` without a (4, 4) block or
    not > 0."""
    if cov_dist is None:
        if k3_sd is not None:
            raise ValueError(f"k3_sd ({k3_sd}) needs the distortion's prior cov_dist")
        return 0
    n = len(cov_dist)
    if n not in (4, 5):
        raise ValueError(f"cov_dist must be 4 x 4 (k1 k2 p1 p2) or 5 x 5 (and k3), got {np.shape(cov_dist)}")
    if k3_sd is None:
        return n
    if n == 5:
        raise ValueError("k3_sd with a 5 x 5 cov_dist: its k3 has a prior already")
    if not (np.isfinite(k3_sd) and k3_sd > 0):
        raise ValueError(f"k3_sd ({k3_sd}) must be > 0")
    return 5


def lab_blocks(priors: dict) -> dict:
    """The covariance blocks of a :func:`read_priors` dict, for :func:`lab_prior` (its ``k3_sd`` left out)."""
    return {k: v for k, v in priors.items() if k != "k3_sd"}


def observations_of(kmap, used, n_surround: int, map_points: str = "all") -> tuple:
    """``(view, point, x, points)`` of :func:`joint_bundle` from a map and a locate result's ``used``: the map points
    seen in the locate views (renumbered ``0..M-1``; ``points`` their map indices), each in the reference (view 0),
    its surrounding views (1..K) and the two locate views (K + 1, K + 2); with ``map_points="all"`` then every other
    map point, in the reference and its surrounding views only. Those hold the survey views' joints and the shared
    lens, intrinsics and mount, which the base pose depends on (the bound counts them too: measured in docs/bounds.md,
    they take the in-situ efficiency from 0.68 to 0.91 in air); ``"located"`` leaves them out (the earlier
    estimator)."""
    if map_points not in ("all", "located"):
        raise ValueError(f"map_points: expected 'all' or 'located', got {map_points!r}")
    idx, x_a, x_b = used
    idx = np.asarray(idx, int)
    view, point, x = [], [], []
    for j, i in enumerate(idx):
        views, xs = kmap.observations[i]
        view += [0, *(1 + np.asarray(views, int)), n_surround + 1, n_surround + 2]
        point += [j] * (len(views) + 3)
        x += [kmap.x_ref[i], *np.asarray(xs).reshape(-1, 2), x_a[j], x_b[j]]
    if map_points == "all":
        rest = np.setdiff1d(np.arange(len(kmap.p_ref)), idx)
        for j, i in enumerate(rest, start=len(idx)):
            views, xs = kmap.observations[i]
            view += [0, *(1 + np.asarray(views, int))]
            point += [j] * (len(views) + 1)
            x += [kmap.x_ref[i], *np.asarray(xs).reshape(-1, 2)]
        idx = np.r_[idx, rest]
    return np.array(view, int), np.array(point, int), np.array(x, float).reshape(-1, 2), idx


def lab_prior(cov_K=None, cov_dist=None, cov_mount=None, cov_K_dist=None, cov_K_mount=None, cov_dist_mount=None,
              k3_sd=None):
    """The joint covariance of the lab's blocks that are given, in the order intrinsics (4), distortion (4), mount
    (6) - the joint bundle's and the bound's parameter order; a cross-covariance not given (or whose blocks are not
    both given) is zero. The distortion block is ``k1 k2 p1 p2`` (4) or, when the lab fitted k3, ``k1 k2 p1 p2 k3``
    (5, its cross-covariances 4 x 5 and 5 x 6). With ``k3_sd`` and a (4, 4) distortion block, ``k3`` follows ``k1
    k2 p1 p2``, variance ``k3_sd**2`` and no cross-covariance (the order when k3 is refined). None when no block is
    given."""
    distortion_block_size(cov_dist, k3_sd if cov_dist is not None else None)
    blocks = [(n, C) for n, C in (("K", cov_K), ("dist", cov_dist), ("mount", cov_mount)) if C is not None]
    if not blocks:
        return None
    cross = {("K", "dist"): cov_K_dist, ("K", "mount"): cov_K_mount, ("dist", "mount"): cov_dist_mount}
    rows = []
    for i, (a, A) in enumerate(blocks):
        row = []
        for j, (b, B) in enumerate(blocks):
            if i == j:
                row.append(np.asarray(A, float))
            elif i < j:
                c = cross[a, b]
                row.append(np.zeros((len(A), len(B))) if c is None else np.asarray(c, float))
            else:  # below the diagonal: the transpose of the block above it
                c = cross[b, a]
                row.append(np.zeros((len(A), len(B))) if c is None else np.asarray(c, float).T)
        rows.append(row)
    lab = np.block(rows)
    if k3_sd is None or cov_dist is None:
        return lab
    at = 4 * (cov_K is not None) + 4  # after k1 k2 p1 p2
    keep = np.r_[0:at, at + 1:len(lab) + 1]
    out = np.zeros((len(lab) + 1, len(lab) + 1))
    out[np.ix_(keep, keep)] = lab
    out[at, at] = float(k3_sd) ** 2
    return out


#: optional keys of calibration_priors.yaml: (key, name in read_priors' dict, shape)
#: ("d": the distortion block's size, 4 - k1 k2 p1 p2 - or 5 with k3, set by distortion_covariance)
_OPTIONAL_PRIORS = (("intrinsics_mount_covariance", "cov_K_mount", (4, 6)),
                    ("distortion_covariance", "cov_dist", ("d", "d")),
                    ("intrinsics_distortion_covariance", "cov_K_dist", (4, "d")),
                    ("distortion_mount_covariance", "cov_dist_mount", ("d", 6)))


def priors_yaml_text(cov_K, cov_mount, notes: str = "", cov_K_mount=None, cov_dist=None, cov_K_dist=None,
                     cov_dist_mount=None, k3_sd=None) -> str:
    """The lab calibrations' covariances as a YAML file for :func:`read_priors` (``calibration_priors.yaml``):
    ``intrinsics_covariance_px2`` (4 x 4, fx fy cx cy), ``mount_covariance`` (6 x 6: rotation vector rad, then
    m, a right perturbation of the mount) and, when known, ``intrinsics_mount_covariance`` (4 x 6, their
    cross-covariance), ``distortion_covariance`` (4 x 4, k1 k2 p1 p2) and its cross-covariances
    ``intrinsics_distortion_covariance`` (4 x 4) and ``distortion_mount_covariance`` (4 x 6) - 5 x 5, 4 x 5 and
    5 x 6 with ``k3`` when the lab fitted it and k3 is to be refined under its covariance; ``distortion_k3_sd`` (a
    number, with the 4 x 4 block) when the lens's k3, which the lab's fit held fixed, is to be refined under that
    standard deviation.
    """
    import yaml

    data = {"notes": notes, "intrinsics_covariance_px2": np.asarray(cov_K, float).tolist(),
            "mount_covariance": np.asarray(cov_mount, float).tolist()}
    given = {"cov_K_mount": cov_K_mount, "cov_dist": cov_dist, "cov_K_dist": cov_K_dist,
             "cov_dist_mount": cov_dist_mount}
    for key, name, _ in _OPTIONAL_PRIORS:
        if given[name] is not None:
            data[key] = np.asarray(given[name], float).tolist()
    if k3_sd is not None:
        data["distortion_k3_sd"] = float(k3_sd)
    return yaml.safe_dump(data, sort_keys=False)


def read_priors(path) -> dict:
    """``{"cov_K": (4, 4), "cov_mount": (6, 6), "cov_K_mount": (4, 6) or None}`` from a ``calibration_priors.yaml``;
    a missing key, a wrong shape or a matrix that is not symmetric positive definite (the joint one too, with the
    optional cross-covariance) is a one-line error naming the file and key."""
    from pathlib import Path

    from bench.errors import ConfigError
    from bench.fileio import read_yaml

    path = Path(path)
    data = read_yaml(path, missing="missing (the lab calibrations' covariances for refine 'joints')") or {}
    if not isinstance(data, dict):
        raise ConfigError(path, "<top>", f"expected a mapping of covariances, got {type(data).__name__}")
    out = {}
    for key, name, n in (("intrinsics_covariance_px2", "cov_K", 4), ("mount_covariance", "cov_mount", 6)):
        try:
            C = np.array(data[key], dtype=float)
        except (KeyError, TypeError, ValueError):
            raise ConfigError(path, key, f"expected a {n} x {n} matrix of numbers") from None
        if C.shape != (n, n) or not np.all(np.isfinite(C)) or not np.allclose(C, C.T, rtol=1e-6, atol=0):
            raise ConfigError(path, key, f"expected a symmetric {n} x {n} matrix, got shape {C.shape}")
        if np.linalg.eigvalsh(C).min() <= 0:
            raise ConfigError(path, key, "not positive definite")
        out[name] = C
    nd = 4  # the distortion block's size: 5 when the lab fitted k3 (a 5 x 5 distortion_covariance)
    for key, name, spec in _OPTIONAL_PRIORS:
        out[name] = None
        if data.get(key) is None:
            continue
        shape = tuple(nd if n == "d" else n for n in spec)
        wanted = "4 x 4 or 5 x 5 (k1 k2 p1 p2 [k3])" if name == "cov_dist" else f"{shape[0]} x {shape[1]}"
        try:
            C = np.array(data[key], dtype=float)
        except (TypeError, ValueError):
            raise ConfigError(path, key, f"expected a {wanted} matrix of numbers") from None
        if name == "cov_dist" and C.shape in ((4, 4), (5, 5)):
            shape = C.shape
            nd = C.shape[0]
        if C.shape != shape or not np.all(np.isfinite(C)):
            raise ConfigError(path, key, f"expected a {wanted} matrix of finite numbers, got shape {C.shape}")
        out[name] = C
    if out["cov_dist"] is None and (out["cov_K_dist"] is not None or out["cov_dist_mount"] is not None):
        raise ConfigError(path, "distortion_covariance", "missing (a distortion cross-covariance is given)")
    k3 = data.get("distortion_k3_sd")
    if k3 is not None:
        if isinstance(k3, bool) or not isinstance(k3, (int, float)) or not (np.isfinite(k3) and k3 > 0):
            raise ConfigError(path, "distortion_k3_sd", f"expected a positive number, got {k3!r}")
        if out["cov_dist"] is None:
            raise ConfigError(path, "distortion_k3_sd", "needs distortion_covariance (k3 is refined with k1 k2 p1 p2)")
        if nd == 5:
            raise ConfigError(path, "distortion_k3_sd", "distortion_covariance is 5 x 5: its k3 has a prior already")
    out["k3_sd"] = None if k3 is None else float(k3)
    if np.linalg.eigvalsh(lab_prior(**lab_blocks(out))).min() <= 0:
        bad = "distortion_covariance" if out["cov_dist"] is not None else "intrinsics_mount_covariance"
        raise ConfigError(path, bad, "the joint covariance with the other blocks is not positive definite")
    return out
