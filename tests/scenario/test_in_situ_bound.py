"""The in-situ Cramér-Rao bound: its block-assembled Jacobian against brute-force differences, and the bound against
a Monte Carlo of the maximum-likelihood estimator (a bundle adjustment over every parameter), which is efficient for
small noise; ideal features and the measured keypoint noise on a synthetic scene."""

import numpy as np
import pytest

from bench.camera.presets import load_preset
from bench.geometry.transforms import homogeneous, invert, rot_z, transform_points
from bench.robot.identifiability import closed_form_reduction
from bench.robot.model import default_robot_path, load_robot, random_errors
from bench.robot.orientation import link5_frame
from bench.scenario.bounds import ml_estimate
from bench.scenario.in_situ_bound import (
    _Model,
    crb_base_pose,
    fisher_factor,
    ideal_features,
    keypoint_sigma_px,
    track_noise_on_surface,
)
from bench.vision.insitu import ViewObservation

MOUNT = homogeneous(rot_z(np.pi), [0.12, 0.0, 0.3])
Q_SURVEY = np.deg2rad([[10.0, 30, 60, 0, 40, 0], [11.5, 30, 60, 0, 40, 0], [10, 31.5, 59, 0, 39, 0]])
Q_LOCATE = np.deg2rad([[9.5, 30.5, 60.5, 1, 40.5, 2], [11, 30.5, 60.5, 1, 40.5, 2]])


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(71)
    robot = load_robot(default_robot_path())
    eps = random_errors(rng)
    cam = load_preset("air_webcam")
    T_site_b2 = homogeneous(rot_z(np.deg2rad(1.0)), [0.02, -0.015, 0.005])
    T_ref = link5_frame(robot, Q_SURVEY[0], eps) @ MOUNT
    # 25 points ~1 m in front of the reference camera, visible in every view
    p_cam = np.c_[rng.uniform(-0.12, 0.12, (25, 2)), rng.uniform(0.9, 1.1, 25)]
    X = transform_points(T_ref, p_cam)
    views = [(q, False) for q in Q_SURVEY] + [(q, True) for q in Q_LOCATE]
    kept = closed_form_reduction(robot).kept
    cov_eps = np.diag(np.tile([1e-9, 1e-9, 1e-9, 1e-8, 1e-8, 1e-8], 5)[: len(kept)])
    return robot, eps, cam, T_site_b2, X, views, kept, cov_eps


def test_block_jacobian_equals_brute_force(scene):
    """The bound assembles its Jacobian from block perturbations; one column at a time gives the same matrix."""
    robot, eps, cam, T_site_b2, X, views, kept, cov_eps = scene
    model = _Model(robot, eps, kept, MOUNT, cam.project, T_site_b2, views, X, cam.size)
    assert model.vis.all()
    V, M, P = len(views), len(X), len(kept)
    J = model.jacobian_columnwise(*model.values0, X)
    assert np.allclose(model.jacobian(*model.values0, X), J, rtol=1e-6, atol=1e-6)
    sigma_px, sigma_enc = 0.3, 1e-4
    info = J.T @ J / sigma_px**2
    info[6:6 + 6 * V, 6:6 + 6 * V] += np.eye(6 * V) / sigma_enc**2
    info[6 + 6 * V:6 + 6 * V + P, 6 + 6 * V:6 + 6 * V + P] += np.linalg.inv(cov_eps)
    brute = np.linalg.inv(info)[:6, :6]
    crb = crb_base_pose(robot, eps, kept, cov_eps, MOUNT, cam.project, T_site_b2, views, X, cam.size, sigma_px,
                        sigma_enc)
    assert np.allclose(crb["cov"], brute, rtol=1e-5, atol=1e-16)
    assert crb["observations"] == V * M
    assert crb["pos_bound_m"] == pytest.approx(np.sqrt(np.trace(brute[3:, 3:])), rel=1e-6)


def test_per_view_noise_equals_brute_force(scene):
    """One pixel noise per view (the locate views' own): the bound is the inverse of ``J^T W J`` + priors with ``W``
    the views' ``1 / sigma^2``; a scalar and a constant vector give the same bound; noisier locate views raise it."""
    robot, eps, cam, T_site_b2, X, views, kept, cov_eps = scene
    model = _Model(robot, eps, kept, MOUNT, cam.project, T_site_b2, views, X, cam.size)
    V, M, P = len(views), len(X), len(kept)
    J = model.jacobian_columnwise(*model.values0, X)  # rows: view by view, point by point, u v
    sigma = np.array([0.2, 0.25, 0.3, 0.5, 0.4])
    sigma_enc = 1e-4
    w = np.repeat(1 / sigma**2, 2 * M)
    info = J.T @ (J * w[:, None])
    info[6:6 + 6 * V, 6:6 + 6 * V] += np.eye(6 * V) / sigma_enc**2
    info[6 + 6 * V:6 + 6 * V + P, 6 + 6 * V:6 + 6 * V + P] += np.linalg.inv(cov_eps)
    brute = np.linalg.inv(info)[:6, :6]
    args = (robot, eps, kept, cov_eps, MOUNT, cam.project, T_site_b2, views, X, cam.size)
    crb = crb_base_pose(*args, sigma, sigma_enc)
    assert np.allclose(crb["cov"], brute, rtol=1e-5, atol=1e-16)
    same = crb_base_pose(*args, np.full(V, 0.3), sigma_enc)["cov"]
    assert np.allclose(same, crb_base_pose(*args, 0.3, sigma_enc)["cov"], rtol=1e-12, atol=0)
    worse = crb_base_pose(*args, np.r_[np.full(3, 0.3), 0.6, 0.6], sigma_enc)
    assert worse["pos_bound_m"] > crb_base_pose(*args, 0.3, sigma_enc)["pos_bound_m"]
    with pytest.raises(ValueError, match="sigma_px"):
        crb_base_pose(*args, np.r_[np.full(4, 0.3), np.nan], sigma_enc)


def test_the_ins_tilt_in_the_bound(scene):
    """The INS's tilt measures only the base pose, so its update of the bound's 6 x 6 covariance
    (:class:`~bench.vision.tilt.TiltUpdate`, as the in-situ kind applies it) equals the bound of the whole problem with
    the tilt's information ``H^T S^-1 H`` on the pose block (1e-6 relative); it lowers the rotation's bound and
    leaves the heading's and the origin's information alone; a Monte Carlo summary fused with it has its RMS near
    that covariance's."""
    from bench.scenario.bounds import crb
    from bench.scenario.in_situ_bound import _mc_summary
    from bench.sim.ins import DOWN_WORLD
    from bench.vision.tilt import VehicleTilt, tilt_update

    robot, eps, cam, T_site_b2, X, views, kept, cov_eps = scene
    sigma_px, sigma_enc = 0.3, 1e-4
    args = (robot, eps, kept, cov_eps, MOUNT, cam.project, T_site_b2, views, X, cam.size, sigma_px, sigma_enc)
    vision = crb_base_pose(*args)["cov"]
    R1 = np.eye(3)
    tilt = VehicleTilt(R1.T @ DOWN_WORLD, T_site_b2[:3, :3].T @ DOWN_WORLD, np.deg2rad(0.01), np.deg2rad(0.05))
    upd = tilt_update(T_site_b2[:3, :3], vision, tilt)
    model = _Model(robot, eps, kept, MOUNT, cam.project, T_site_b2, views, X, cam.size)
    priors = {"q": np.eye(6) / sigma_enc**2, "d_eps": np.linalg.inv(cov_eps), "xi": upd.H.T @ np.linalg.solve(
        upd.S, upd.H)}
    whole = crb(model, sigma_px, priors)["cov"][:6, :6]
    assert np.allclose(upd.covariance(vision), whole, rtol=1e-6, atol=1e-6 * np.abs(whole).max())
    assert np.trace(whole[:3, :3]) < 0.8 * np.trace(vision[:3, :3])
    # the information it adds is of rank 2: none about the heading (a turn about gravity) or the origin
    added = np.linalg.inv(whole) - np.linalg.inv(vision)
    assert np.linalg.matrix_rank(added, tol=1e-6 * np.abs(added).max()) == 2
    assert np.abs(added @ np.r_[tilt.down_survey, 0, 0, 0]).max() < 1e-6 * np.abs(added).max()
    assert np.abs(added[3:]).max() < 1e-6 * np.abs(added).max()
    rng = np.random.default_rng(73)
    errs = rng.multivariate_normal(np.zeros(6), vision, size=4000)
    mc = _mc_summary(errs, 4000, 0, upd, rng)
    fused = upd.covariance(vision)
    assert mc["rot_rms_rad"] == pytest.approx(np.sqrt(np.trace(fused[:3, :3])), rel=0.05)
    assert mc["pos_rms_m"] == pytest.approx(np.sqrt(np.trace(fused[3:, 3:])), rel=0.05)


def test_bound_equals_the_ml_estimator_spread(scene):
    """Bundle adjustment over base pose, joints, arm errors and points (the ML estimator,
    :func:`bench.scenario.bounds.ml_estimate`) on noisy pixels, readings and arm errors: its spread matches the bound
    (Monte Carlo, 80 draws: +-30 % on the traces, ~3 standard errors of a variance estimate). The locate views'
    pixels are 1.5 x noisier than the survey's (their own noise, as measured in the scenes), and the estimator weighs
    each view by its noise."""
    robot, eps, cam, T_site_b2, X, views, kept, cov_eps = scene
    sigma_px = np.array([0.3 if loc else 0.2 for _, loc in views])
    sigma_enc = 2e-5
    model = _Model(robot, eps, kept, MOUNT, cam.project, T_site_b2, views, X, cam.size)
    P = len(kept)
    crb = crb_base_pose(robot, eps, kept, cov_eps, MOUNT, cam.project, T_site_b2, views, X, cam.size, sigma_px,
                        sigma_enc)
    uv0 = model.pixels(*model.values0, X)
    L = np.linalg.cholesky(cov_eps)
    priors = {"q": np.eye(6) / sigma_enc**2, "d_eps": np.linalg.inv(cov_eps)}
    rng = np.random.default_rng(72)
    errs = []
    for _ in range(80):
        uv = uv0 + rng.normal(0, 1.0, uv0.shape) * sigma_px[:, None, None]
        q_read = model.q0 + rng.normal(0, sigma_enc, model.q0.shape)
        e_prior = L @ rng.normal(size=P)  # the lab's estimate of the arm errors, relative to the truth
        # from a start off the truth by more than the noise
        xi0 = np.r_[rng.normal(0, 1e-3, 3), rng.normal(0, 2e-3, 3)]
        est = ml_estimate(model, uv, sigma_px, priors, [np.zeros(6), q_read, e_prior], [xi0, q_read, e_prior],
                          X + rng.normal(0, 2e-3, X.shape), iterations=6, tol=1e-4 * crb["pos_bound_m"])
        assert est["step"] < 1e-3 * crb["pos_bound_m"]  # converged, far below the spread measured
        errs.append(est["values"][0])
    cov_mc = np.cov(np.array(errs).T)
    assert np.trace(cov_mc[3:, 3:]) == pytest.approx(np.trace(crb["cov"][3:, 3:]), rel=0.3)
    assert np.trace(cov_mc[:3, :3]) == pytest.approx(np.trace(crb["cov"][:3, :3]), rel=0.3)


def test_ideal_features_and_measured_noise(scene):
    """Ideal features match the same 3D point in every view; with noise sigma added in both views, the epipolar
    measurement recovers sigma."""
    robot, eps, cam, _, X, views, _, _ = scene
    rng = np.random.default_rng(73)
    poses = {f"v{k}": link5_frame(robot, q, eps) @ MOUNT for k, (q, _) in enumerate(views[:3])}
    f0 = ideal_features(X, poses["v0"], cam.project, cam.size)
    assert len(f0) == len(X) and np.allclose(f0.uv, cam.project(transform_points(invert(poses["v0"]), X)))
    sigma = 0.3
    Xd = np.r_[X, X + 0.01, X - 0.01]  # more points for the statistics
    obs = {n: ideal_features(Xd, T, cam.project, cam.size, sigma, rng) for n, T in poses.items()}
    obs = {n: ViewObservation(n, f, cam.undistort_pixels(f.uv), poses[n]) for n, f in obs.items()}
    est, n = keypoint_sigma_px(obs["v0"], [obs["v1"], obs["v2"]], poses, cam, cam.project)
    assert n == 2 * len(Xd)
    assert est == pytest.approx(sigma, rel=0.2)


class _Plane:
    """Ray casting onto the plane through ``point`` with normal ``normal`` (the interface of
    :class:`bench.scenario.scene_points.SceneRays`)."""

    def __init__(self, point, normal):
        self.point, self.normal = np.asarray(point, float), np.asarray(normal, float)

    def first_hits(self, origins, directions):
        s = ((self.point - origins) @ self.normal) / (directions @ self.normal)
        return origins + s[:, None] * directions


def test_locate_views_own_noise_is_measured_on_the_surface(scene):
    """Tracks on a plane: exact pixels give zero noise; survey views with sigma and locate views with 2 sigma give
    back sigma and a ratio of 2 - the reference keypoint's own error moves the surface point, which every view
    shares and the measurement removes."""
    robot, eps, cam, T_site_b2, _, views, _, _ = scene
    rng = np.random.default_rng(74)
    T = [link5_frame(robot, q, eps) @ MOUNT for q, _ in views]
    T = [T_site_b2 @ t if loc else t for t, (_, loc) in zip(T, views, strict=True)]
    T_ref, T_survey, T_loc = T[0], np.stack(T[1:3]), np.stack(T[3:])
    n_plane = T_ref[:3, 2]
    plane = _Plane(T_ref[:3, 3] + 1.0 * n_plane, n_plane)  # 1 m in front of the reference, facing it
    p_cam = np.c_[rng.uniform(-0.25, 0.25, (400, 2)), np.ones(400)]
    P = plane.first_hits(np.tile(T_ref[:3, 3], (400, 1)), transform_points(T_ref, p_cam) - T_ref[:3, 3])

    def pixels(T_wc, s):
        uv = cam.project(transform_points(invert(T_wc), P))
        return uv + rng.normal(0, s, uv.shape) if s else uv

    def measure(s, s_loc):
        uv_ref = pixels(T_ref, s)
        sur = np.stack([pixels(t, s) for t in T_survey], axis=1)  # (N, 2 views, 2)
        loc = np.stack([pixels(t, s_loc) for t in T_loc], axis=1)
        tracks = [(np.arange(2), sur[j]) for j in range(len(P))]
        return track_noise_on_surface(uv_ref, tracks, loc, T_ref, T_survey, T_loc, cam, None, cam.project, plane)

    exact = measure(0.0, 0.0)
    assert exact["points"] == 400 and exact["survey_px"] < 1e-6 and exact["locate_px"] < 1e-6
    assert np.isnan(exact["survey_fisher"]) and np.isnan(exact["locate_fisher"])  # no errors, no shape
    noisy = measure(0.2, 0.4)
    assert noisy["survey_px"] == pytest.approx(0.2, rel=0.15)
    assert noisy["ratio"] == pytest.approx(2.0, rel=0.15)
    # Gaussian errors: the robust sigma carries the information (the deviations about a track's mean of two views
    # are Gaussian too)
    assert noisy["survey_fisher"] == pytest.approx(1.0, abs=0.1)
    assert noisy["locate_fisher"] == pytest.approx(1.0, abs=0.1)


def test_fisher_factor_against_the_score_of_the_true_density():
    """Gaussian errors give 1; two known scale mixtures give sigma_F / robust sigma, with sigma_F from a Monte Carlo
    of the true density's score E[(d log f / dx)^2] (independent of the fitted mixture and the radial integral),
    within 3 %: above 1 (half at 0.1 px, half at 0.2 px: the tails take information from the core) and below 1 (half
    at 0.4 px: the robust sigma is widened by a tail that tells little, the core more than it says); fewer than 20
    errors: NaN."""
    rng = np.random.default_rng(75)
    assert fisher_factor(rng.normal(0, 0.1, (20000, 2))) == pytest.approx(1.0, abs=0.02)
    for wide, side in ((0.2, 1), (0.4, -1)):
        pi, s = np.array([0.5, 0.5]), np.array([0.1, wide])
        e = rng.normal(size=(40000, 2)) * rng.choice(s, 40000, p=pi)[:, None]
        N = pi / (2 * np.pi * s**2) * np.exp(-np.sum(e**2, axis=1)[:, None] / (2 * s**2))
        score_x = -e[:, 0] * (N / s**2).sum(axis=1) / N.sum(axis=1)
        reference = 1 / np.sqrt(np.mean(score_x**2)) / (1.4826 * np.median(np.abs(e - np.median(e))))
        assert side * (reference - 1) > 0.04
        assert fisher_factor(e) == pytest.approx(reference, rel=0.03)
    assert np.isnan(fisher_factor(e[:19]))


def test_intrinsics_and_mount_blocks(scene):
    """The intrinsics and mount blocks: block Jacobian = column by column; their priors only raise the bound, and a
    very tight prior gives back the bound with them exact; a sparser observation pattern raises it too."""
    robot, eps, cam, T_site_b2, X, views, kept, cov_eps = scene
    model = _Model(robot, eps, kept, MOUNT, cam.project, T_site_b2, views, X, cam.size, K=cam.K, with_mount=True)
    J = model.jacobian_columnwise(*model.values0, X)
    assert np.allclose(model.jacobian(*model.values0, X), J, rtol=1e-5, atol=1e-5)
    args = (robot, eps, kept, cov_eps, MOUNT, cam.project, T_site_b2, views, X, cam.size, 0.3, 1e-4)
    exact = crb_base_pose(*args)
    loose = crb_base_pose(*args, cov_K=np.diag([4.0, 4, 1, 1]), K=cam.K, cov_mount=np.diag([1e-6] * 3 + [1e-6] * 3))
    tight = crb_base_pose(*args, cov_K=np.eye(4) * 1e-12, K=cam.K, cov_mount=np.eye(6) * 1e-16)
    assert loose["pos_bound_m"] > exact["pos_bound_m"]  # shared by survey and locate views: largely cancels
    assert tight["pos_bound_m"] == pytest.approx(exact["pos_bound_m"], rel=1e-3)
    vis = np.ones((len(views), len(X)), bool)
    vis[-2:, ::2] = False  # half the points not observed in the locate views
    sparse = crb_base_pose(*args, vis=vis)
    assert sparse["observations"] == vis.sum() and sparse["pos_bound_m"] > exact["pos_bound_m"] * 1.1


def test_the_lens_k3_block(scene):
    """The distortion block with k3 (``k3_sd``): block Jacobian = column by column, and its k3 column the exact pixel
    change of k3; a wide k3 prior only raises the bound, a very tight one gives back the bound with k3 exact; a 5 x 5
    lens covariance (the lab's own k3) with k3 independent is the same bound."""
    robot, eps, cam, T_site_b2, X, views, kept, cov_eps = scene
    dist = np.r_[-0.2, 0.05, 0.001, -0.001, 0.3]
    model = _Model(robot, eps, kept, MOUNT, cam.project, T_site_b2, views, X, cam.size, K=cam.K, dist=dist, k3=True)
    J = model.jacobian_columnwise(*model.values0, X)
    assert np.allclose(model.jacobian(*model.values0, X), J, rtol=1e-5, atol=1e-5)
    i = model.blocks.index(next(b for b in model.blocks if b.name == "d_dist"))
    def moved(dk3):
        vals = [v.copy() for v in model.values0]
        vals[i][4] = dk3
        return model.pixels(*vals, X) - model.pixels(*model.values0, X)

    assert np.abs(moved(1.0)).max() > 1e-3  # k3 moves the pixels off the centre (these within ~0.17 of it), linearly
    assert np.allclose(moved(2.0), 2 * moved(1.0), rtol=1e-9, atol=1e-12)
    args = (robot, eps, kept, cov_eps, MOUNT, cam.project, T_site_b2, views, X, cam.size, 0.3, 1e-4)
    lab = dict(cov_K=np.diag([4.0, 4, 1, 1]), K=cam.K, dist=dist, cov_dist=np.diag([1e-4, 1e-4, 1e-7, 1e-7]))
    without = crb_base_pose(*args, **lab)
    wide = crb_base_pose(*args, **lab, k3_sd=10.0)
    tight = crb_base_pose(*args, **lab, k3_sd=1e-9)
    assert wide["pos_bound_m"] > without["pos_bound_m"] and wide["rot_bound_rad"] > without["rot_bound_rad"]
    assert tight["pos_bound_m"] == pytest.approx(without["pos_bound_m"], rel=1e-6)
    lab5 = {**lab, "cov_dist": np.diag(np.r_[np.diag(lab["cov_dist"]), 100.0])}  # the lab's k3 block, k3 apart
    same = crb_base_pose(*args, **lab5)
    assert np.allclose(same["cov"], wide["cov"], rtol=1e-9, atol=0)
    assert crb_base_pose(*args, k3_sd=10.0)["pos_bound_m"] == crb_base_pose(*args)["pos_bound_m"]  # no lens block
    with pytest.raises(ValueError, match="distortion"):
        _Model(robot, eps, kept, MOUNT, cam.project, T_site_b2, views, X, cam.size, K=cam.K, k3=True)


def test_paraxial_intrinsics_keep_the_principal_point():
    """The central camera of a lens behind a flat port: focal lengths times n_w / n_a, principal point unmoved."""
    from bench.scenario.in_situ import _paraxial_K

    K = np.array([[800.0, 0.5, 301.0], [0, 805, 229], [0, 0, 1]])
    Ke = _paraxial_K(K, 1.34)
    assert np.allclose(Ke[:2, 2], K[:2, 2]) and np.allclose(Ke[[0, 1], [0, 1]], 1.34 * K[[0, 1], [0, 1]])
    assert Ke[0, 1] == pytest.approx(1.34 * 0.5) and Ke[2, 2] == 1


def test_best_central_camera():
    """No port: the lens itself. A flat port: the fitted central camera is much closer to the true optics than the
    paraxial one, but not exact (the floor is the part no central model removes)."""
    from bench.camera.flatport import lens_port_projector
    from bench.scenario.in_situ import _paraxial_K
    from bench.scenario.in_situ_bound import best_central_camera
    from bench.sim.optics_presets import optics_preset

    lens = load_preset("underwater_in_air")
    cam, T = best_central_camera(lens, None, (0.5, 1.0))
    assert cam is lens and np.array_equal(T, np.eye(4))
    port = optics_preset("underwater_in_water").port
    cam, T = best_central_camera(lens, port, (0.5, 1.0), n=800, rng=np.random.default_rng(74))
    rng = np.random.default_rng(75)
    z = rng.uniform(0.5, 1.0, 300)
    p = np.c_[rng.uniform(-0.25, 0.25, (300, 2)) * z[:, None], z]
    true = lens_port_projector(lens, port)(p)
    fit = cam.project((p - T[:3, 3]) @ T[:3, :3])
    parax = lens.replace(K=_paraxial_K(lens.K, port.n_water / port.n_air)).project(p)
    e_fit, e_par = (np.sqrt(np.nanmean(np.sum((u - true) ** 2, axis=1))) for u in (fit, parax))
    assert e_fit < 0.5 * e_par and e_fit > 1e-4


def test_pnp_variant_bound_floor_and_monte_carlo(scene):
    """PnP of one locate view (pipeline.locate: pnp): its observation pattern has one locate row; its bound is the
    same model with one locate view, at least the two-view bound (less information, Loewner order); on noise-free
    features through a central lens its floor is 0 (the PnP estimator is exact); and the Monte Carlo of PnP with the
    bound's noise does not beat the bound."""
    from bench.scenario.in_situ_bound import mc_ideal_estimator, model_floor, observation_pattern
    from bench.sim.encoders import EncoderModel

    robot, eps, cam, T_site_b2, X, views, kept, cov_eps = scene
    class _Map:  # two map points: the first seen by survey views 0 and 2, the second by view 1
        observations = [(np.array([0, 2]), None), (np.array([1]), None)]

        def __len__(self):
            return 2

    vis = observation_pattern(_Map(), 5, [1], n_locate=1)
    assert vis.tolist() == [[True, True], [True, False], [False, True], [True, False], [False, True]]
    sigma_px, sigma_enc = 0.3, 1e-4
    two = crb_base_pose(robot, eps, kept, cov_eps, MOUNT, cam.project, T_site_b2, views, X, cam.size, sigma_px,
                        sigma_enc)
    one = crb_base_pose(robot, eps, kept, cov_eps, MOUNT, cam.project, T_site_b2, views[:4], X, cam.size, sigma_px,
                        sigma_enc)
    assert np.linalg.eigvalsh(one["cov"] - two["cov"]).min() > -1e-9 * np.abs(two["cov"]).max()
    assert one["pos_bound_m"] > two["pos_bound_m"] and one["observations"] == 4 * len(X)
    names = ["ref", "s1", "s2", "locate0"]
    floor = model_floor(robot, eps, MOUNT, cam, None, T_site_b2, views[:4], names, X, refine="none")
    assert floor["pos_m"] < 1e-8 and floor["rot_rad"] < 1e-8  # OpenCV's LM stops at its own criteria (~4 nm here)
    enc = EncoderModel(noise_std_rad=sigma_enc, resolution_rad=0.0)
    mc = mc_ideal_estimator(robot, eps, kept, cov_eps, MOUNT, cam, T_site_b2, views[:4], names, X, sigma_px, enc,
                            np.random.default_rng(74), trials=30, refine="none")
    print(mc, one["pos_bound_m"])
    assert mc["pos_rms_m"] > 0.8 * one["pos_bound_m"]


@pytest.mark.parametrize("degree_px", [(0.2, 0.1), (0.2, 0.1, 0.05, 0.03)], ids=["affine", "cubic"])
def test_the_views_error_field_in_the_bound(scene, degree_px):
    """Every view's keypoint error field (affine, cubic) as a nuisance under its prior (``field``: independent modes
    over the view's keypoints) is the bound of pixels whose noise is correlated within a view:
    ``J^T (sigma^2 I + A P A^T)^-1 J`` + priors with ``A`` the fields' pixel columns and ``P`` each view's
    ``R^-1 D R^-T`` (Woodbury, 1e-5 relative); a vanishing field gives the white bound; a field raises it."""
    from scipy.linalg import block_diag

    from bench.scenario.bounds import field_basis, field_modes, field_terms, mode_sd

    robot, eps, cam, T_site_b2, X, views, kept, cov_eps = scene
    sigma_px, sigma_enc = 0.2, 1e-4
    order = len(degree_px) - 1
    n = field_terms(order)
    model = _Model(robot, eps, kept, MOUNT, cam.project, T_site_b2, views, X, cam.size)
    V, M, P = len(views), len(X), len(kept)
    J = model.jacobian_columnwise(*model.values0, X)  # rows: view by view, point by point, u v
    uv = model.pixels(*model.values0, X)  # (V, M, 2)
    A = np.zeros((V, M, 2, V, 2 * n))
    prior_cov = np.zeros((V, 2 * n, 2 * n))
    for v in range(V):
        B = field_basis(uv[v], cam.size, order)  # (M, n)
        A[v, :, 0, v, :n], A[v, :, 1, v, n:] = B, B
        Ri = np.linalg.inv(field_modes(uv[v], cam.size, order))  # every point seen in every view here
        prior_cov[v, :n, :n] = prior_cov[v, n:, n:] = Ri @ np.diag(mode_sd(degree_px) ** 2) @ Ri.T
    A = A.reshape(2 * V * M, 2 * n * V)
    sd = np.asarray(degree_px)
    cov_px = sigma_px**2 * np.eye(2 * V * M) + A @ block_diag(*prior_cov) @ A.T
    info = J.T @ np.linalg.solve(cov_px, J)
    info[6:6 + 6 * V, 6:6 + 6 * V] += np.eye(6 * V) / sigma_enc**2
    info[6 + 6 * V:6 + 6 * V + P, 6 + 6 * V:6 + 6 * V + P] += np.linalg.inv(cov_eps)
    brute = np.linalg.inv(info)[:6, :6]
    args = (robot, eps, kept, cov_eps, MOUNT, cam.project, T_site_b2, views, X, cam.size, sigma_px, sigma_enc)
    with_field = crb_base_pose(*args, field=sd)
    assert np.allclose(with_field["cov"], brute, rtol=1e-5, atol=1e-5 * np.abs(brute).max())
    white = crb_base_pose(*args)
    assert np.allclose(crb_base_pose(*args, field=sd * 1e-6)["cov"], white["cov"], rtol=1e-6,
                       atol=1e-6 * np.abs(white["cov"]).max())
    assert np.allclose(crb_base_pose(*args, field=np.zeros(order + 1))["cov"], white["cov"], rtol=0, atol=0)
    assert with_field["pos_bound_m"] > 1.05 * white["pos_bound_m"]
    assert with_field["rot_bound_rad"] > 1.05 * white["rot_bound_rad"]
