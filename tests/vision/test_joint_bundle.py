"""The joint-refining bundle (bench.vision.joint_bundle): its Jacobian against a difference quotient of the
residuals, and on a synthetic two-parking scene with encoder and pixel noise it beats the pose taken from the
readings as exact and recovers the true base within its reported covariance."""

import numpy as np
import pytest

from bench.geometry.transforms import homogeneous, invert, rot_z, transform_points
from bench.robot.model import default_robot_path, load_robot, random_errors
from bench.robot.orientation import link5_frame
from bench.vision.joint_bundle import _Problem, joint_bundle, residuals, residuals_and_jacobian

MOUNT = homogeneous(rot_z(np.pi), [0.12, 0.0, 0.3])
Q = np.deg2rad([[10.0, 30, 60, 0, 40, 0], [11.5, 30, 60, 0, 40, 0], [10, 31.5, 59, 0, 39, 0],
                [8.5, 30, 60.5, 0, 40, 0], [9.5, 30.5, 60.5, 1, 40.5, 2], [11, 30.5, 60.5, 1, 40.5, 2]])
LOC = np.array([False, False, False, False, True, True])
F = 800.0
K = np.array([[F, 0.0, 320.0], [0.0, F, 240.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.2, 0.05, 0.001, -0.001, 0.0])


def _scene(rng, n=60):
    robot = load_robot(default_robot_path())
    eps = random_errors(rng)
    T_b2 = homogeneous(rot_z(np.deg2rad(1.0)), [0.02, -0.015, 0.005])
    T_ref = link5_frame(robot, Q[0], eps) @ MOUNT
    X = transform_points(T_ref, np.c_[rng.uniform(-0.2, 0.2, (n, 2)), rng.uniform(0.8, 1.2, n)])
    view = np.repeat(np.arange(len(Q)), n)
    point = np.tile(np.arange(n), len(Q))
    problem = _Problem(robot, eps, MOUNT, LOC, view, point, np.zeros((len(view), 2)), K)
    x = -residuals(problem, np.r_[np.zeros(6), Q.ravel()], T_b2, X)  # exact projections (px)
    return robot, eps, T_b2, X, view, point, x


def test_jacobian_equals_difference_quotient():
    """Every block (base, joints, intrinsics, distortion, mount) and the points, with a distorted lens."""
    rng = np.random.default_rng(81)
    robot, eps, T_b2, X, view, point, x = _scene(rng, 8)
    problem = _Problem(robot, eps, MOUNT, LOC, view, point, x, K, DIST, with_K=True, with_mount=True, with_dist=True)
    theta = np.r_[rng.normal(0, 1e-3, 6), (Q + rng.normal(0, 1e-4, Q.shape)).ravel(), rng.normal(0, 1, 4),
                  rng.normal(0, 1e-2, 4), rng.normal(0, 1e-3, 6)]
    r, J, J_pt, _ = residuals_and_jacobian(problem, theta, T_b2, X)
    assert J.shape[2] == problem.n == 6 + 6 * len(Q) + 14
    h = 1e-6
    for c in range(len(theta)):
        e = np.zeros_like(theta)
        e[c] = h * (1e3 if 6 + 6 * len(Q) <= c < 10 + 6 * len(Q) else 1)  # px steps for the intrinsics
        d = (residuals(problem, theta + e, T_b2, X) - residuals(problem, theta - e, T_b2, X)) / (2 * e[c])
        assert np.allclose(d, J[:, :, c], atol=1e-3 * max(1, np.abs(J[:, :, c]).max()) * 1e-2), c
    for c in range(3):
        dX = np.zeros_like(X)
        dX[:, c] = h
        d = (residuals(problem, theta, T_b2, X + dX) - residuals(problem, theta, T_b2, X - dX)) / (2 * h)
        assert np.allclose(d, J_pt[:, :, c], rtol=1e-5, atol=1e-3)


def test_recovers_the_base_under_encoder_noise():
    rng = np.random.default_rng(82)
    robot, eps, T_b2, X, view, point, x = _scene(rng)
    sigma_px, sigma_enc = 0.1, np.deg2rad(0.01)
    errs, z = [], []
    for _ in range(6):
        q_read = Q + rng.normal(0, sigma_enc, Q.shape)
        xn = x + rng.normal(0, sigma_px, x.shape)
        start = T_b2.copy()
        start[:3, 3] += rng.normal(0, 1e-3, 3)
        jb = joint_bundle(robot, eps, MOUNT, q_read, LOC, start, view, point, xn, X + rng.normal(0, 1e-3, X.shape),
                          sigma_enc, 0.3, K)
        assert jb.success and jb.sigma_px == pytest.approx(sigma_px, rel=0.25)
        e = jb.T_site_base[:3, 3] - T_b2[:3, 3]
        errs.append(np.linalg.norm(e))
        z.append(e @ np.linalg.solve(jb.covariance[3:, 3:], e))
    # the base error is at the scale of the reported covariance (chi-square with 3 dof: mean 3)
    assert 0.5 < np.mean(z) < 8
    with pytest.raises(ValueError, match="sigma_enc"):
        joint_bundle(robot, eps, MOUNT, Q, LOC, T_b2, view, point, x, X, 0.0, 0.1, K)
    with pytest.raises(ValueError, match="fewer than two views"):
        keep = (point != 0) | (view == 0)  # point 0 only in the reference view
        joint_bundle(robot, eps, MOUNT, Q, LOC, T_b2, view[keep], point[keep], x[keep], X, sigma_enc, 0.1, K)
    assert np.all(np.isfinite(invert(jb.T_site_base)))


def test_encoder_specification_errors(tmp_path):
    """refine 'joints' reads the encoders' datasheet; a missing file or a bad value names the file and key."""
    from bench.errors import ConfigError
    from bench.vision.locate_dataset import encoder_sigma_rad

    with pytest.raises(ConfigError, match="encoders.yaml"):
        encoder_sigma_rad(tmp_path)
    (tmp_path / "encoders.yaml").write_text("noise_deg: 0.002\nresolution_deg: 0.001\n")
    assert encoder_sigma_rad(tmp_path) == pytest.approx(np.deg2rad(np.hypot(0.002, 0.001 / np.sqrt(12))))
    (tmp_path / "encoders.yaml").write_text("noise_deg: fast\nresolution_deg: 0.001\n")
    with pytest.raises(ConfigError, match="noise_deg"):
        encoder_sigma_rad(tmp_path)


def test_gate_rejects_gross_keypoints():
    """A few keypoints 3-6 px off (a similar-looking feature nearby): the gate drops them, the plain least squares
    is pulled; the gated sigma is the Gaussian one."""
    rng = np.random.default_rng(83)
    robot, eps, T_b2, X, view, point, x = _scene(rng)
    sigma_enc = np.deg2rad(0.002)
    xn = x + rng.normal(0, 0.1, x.shape)
    bad = rng.choice(len(x), 15, replace=False)
    xn[bad] += rng.uniform(3, 6, (15, 2)) * rng.choice([-1, 1], (15, 2))
    out = {}
    for gate in (None, 3.5):
        jb = joint_bundle(robot, eps, MOUNT, Q, LOC, T_b2, view, point, xn, X, sigma_enc, 0.3, K, gate=gate)
        out[gate] = (np.linalg.norm(jb.T_site_base[:3, 3] - T_b2[:3, 3]), jb.sigma_px, jb.observations)
    assert out[3.5][1] == pytest.approx(0.1, rel=0.2) and out[None][1] > 0.3
    assert out[3.5][2] <= len(x) - 15 and out[3.5][0] < out[None][0]


def test_priors_file_with_the_intrinsics_mount_cross_covariance(tmp_path):
    """calibration_priors.yaml may carry the 4 x 6 cross-covariance (the rig's tolerances move the focal length and
    the mount together); it round-trips, and a wrong shape or a joint matrix that is not positive definite is a
    one-line error naming the key."""
    from bench.errors import ConfigError
    from bench.vision.joint_bundle import lab_prior, priors_yaml_text, read_priors

    rng = np.random.default_rng(3)
    A = rng.normal(size=(10, 10))
    C = A @ A.T + 0.1 * np.eye(10)
    p = tmp_path / "calibration_priors.yaml"
    p.write_text(priors_yaml_text(C[:4, :4], C[4:, 4:], "test", C[:4, 4:]))
    got = read_priors(p)
    assert np.allclose(lab_prior(got["cov_K"], None, got["cov_mount"], cov_K_mount=got["cov_K_mount"]), C,
                       rtol=1e-12)
    p.write_text(priors_yaml_text(C[:4, :4], C[4:, 4:], "no cross"))
    assert read_priors(p)["cov_K_mount"] is None
    p.write_text(priors_yaml_text(C[:4, :4], C[4:, 4:], "wrong shape", C[:4, 4:9]))
    with pytest.raises(ConfigError, match="intrinsics_mount_covariance"):
        read_priors(p)
    p.write_text(priors_yaml_text(np.eye(4), np.eye(6), "not PD", np.full((4, 6), 2.0)))
    with pytest.raises(ConfigError, match="not positive definite"):
        read_priors(p)


def test_joint_prior_information_over_adjacent_blocks():
    """A tuple of adjacent blocks takes one joint information matrix; with a zero cross term it is the two blocks'."""
    from types import SimpleNamespace

    from bench.scenario.bounds import Block, MultiViewModel

    blocks = [Block("xi", 6), Block("q", 6, per_view=True), Block("d_K", 4), Block("d_mount", 6)]
    m = SimpleNamespace(blocks=blocks, offsets=[0, 6, 18, 22], n_params=28, n_views=2)
    P = np.diag(np.arange(1.0, 11.0))
    joint = MultiViewModel.prior_information(m, {("d_K", "d_mount"): P})
    apart = MultiViewModel.prior_information(m, {"d_K": P[:4, :4], "d_mount": P[4:, 4:]})
    assert np.array_equal(joint, apart) and joint[18:, 18:].trace() == P.trace()
    with pytest.raises(ValueError, match="adjacent"):
        MultiViewModel.prior_information(m, {("xi", "d_K"): np.eye(10)})


def _random_lab_prior(rng, nd: int) -> tuple:
    """A random joint prior (10 + nd, 10 + nd) - intrinsics, a distortion block of ``nd`` (4 or 5), mount - and its
    blocks as :func:`~bench.vision.joint_bundle.lab_prior` takes them."""
    n = 10 + nd
    A = rng.normal(size=(n, n))
    C = A @ A.T + 0.1 * np.eye(n)
    d = slice(4, 4 + nd)
    return C, dict(cov_K=C[:4, :4], cov_dist=C[d, d], cov_mount=C[4 + nd:, 4 + nd:], cov_K_dist=C[:4, d],
                   cov_K_mount=C[:4, 4 + nd:], cov_dist_mount=C[d, 4 + nd:])


def test_lab_prior_orders_blocks_and_the_priors_file_carries_the_distortion(tmp_path):
    """lab_prior puts intrinsics, distortion, mount in the joint bundle's order with the cross-covariances given
    (zero otherwise); the priors file round-trips the distortion blocks and refuses a cross term without its block."""
    from bench.errors import ConfigError
    from bench.vision.joint_bundle import lab_blocks, lab_prior, priors_yaml_text, read_priors

    C, blocks = _random_lab_prior(np.random.default_rng(5), 4)
    assert np.allclose(lab_prior(**blocks), C)
    no_cross = lab_prior(C[:4, :4], None, C[8:, 8:])
    assert no_cross.shape == (10, 10) and not no_cross[:4, 4:].any()
    assert lab_prior() is None
    p = tmp_path / "calibration_priors.yaml"
    p.write_text(priors_yaml_text(notes="test", **blocks))
    got = read_priors(p)
    assert got["k3_sd"] is None and np.allclose(lab_prior(**lab_blocks(got)), C, rtol=1e-12)
    p.write_text(priors_yaml_text(C[:4, :4], C[8:, 8:], "cross without its block", cov_K_dist=C[:4, 4:8]))
    with pytest.raises(ConfigError, match="distortion_covariance"):
        read_priors(p)
    p.write_text(priors_yaml_text(notes="k3", k3_sd=10.0, **blocks))
    assert read_priors(p)["k3_sd"] == 10.0
    big = lab_prior(**blocks, k3_sd=10.0)  # k3 after k1 k2 p1 p2, independent of the rest
    assert big.shape == (15, 15) and big[8, 8] == 100.0 and not big[8, np.r_[:8, 9:15]].any()
    assert np.array_equal(np.delete(np.delete(big, 8, 0), 8, 1), C)
    assert lab_prior(C[:4, :4], None, C[8:, 8:], k3_sd=10.0).shape == (10, 10)  # no lens block: no k3
    for bad, msg in ((0.0, "positive number"), ("wide", "positive number"), (True, "positive number")):
        p.write_text(priors_yaml_text(notes="bad k3", **blocks) + f"distortion_k3_sd: {bad}\n")
        with pytest.raises(ConfigError, match=f"distortion_k3_sd: .*{msg}"):
            read_priors(p)
    p.write_text(priors_yaml_text(C[:4, :4], C[8:, 8:], "k3 without the lens block", k3_sd=10.0))
    with pytest.raises(ConfigError, match="distortion_k3_sd: needs distortion_covariance"):
        read_priors(p)


def test_k3_jacobian_equals_difference_quotient():
    """The k3 column of the distortion block (with every other block), against a difference quotient."""
    rng = np.random.default_rng(83)
    robot, eps, T_b2, X, view, point, x = _scene(rng, 8)
    problem = _Problem(robot, eps, MOUNT, LOC, view, point, x, K, DIST, with_K=True, with_mount=True, with_dist=True,
                       with_k3=True)
    theta = np.r_[rng.normal(0, 1e-3, 6), (Q + rng.normal(0, 1e-4, Q.shape)).ravel(), rng.normal(0, 1, 4),
                  rng.normal(0, 1e-2, 5), rng.normal(0, 1e-3, 6)]
    _, J, _, _ = residuals_and_jacobian(problem, theta, T_b2, X)
    assert problem.n == 6 + 6 * len(Q) + 15
    c, h = 6 + 6 * len(Q) + 8, 1e-6
    e = np.zeros_like(theta)
    e[c] = h
    d = (residuals(problem, theta + e, T_b2, X) - residuals(problem, theta - e, T_b2, X)) / (2 * h)
    assert np.abs(J[:, :, c]).max() > 1e-3 and np.allclose(d, J[:, :, c], rtol=1e-4, atol=1e-7)
    assert np.allclose(problem.distortion(theta[c - 4:c + 1]), DIST + theta[c - 4:c + 1])
    with pytest.raises(ValueError, match="with the distortion block"):
        _Problem(robot, eps, MOUNT, LOC, view, point, x, K, DIST, with_k3=True)


def test_k3_refined_in_situ_removes_a_lens_the_lab_fitted_without_it():
    """The true lens has a k3 the lab's fit (k3 = 0) lacks; with k3 refined under a wide prior the joint bundle finds
    it from the views and the base exactly (noise-free), where the bundle without it is biased by the missing
    term."""
    rng = np.random.default_rng(84)
    robot, eps, T_b2, X, view, point, _ = _scene(rng, 80)
    true_dist = DIST + np.r_[0, 0, 0, 0, 0.8]
    truth = _Problem(robot, eps, MOUNT, LOC, view, point, np.zeros((len(view), 2)), K, true_dist)
    x = -residuals(truth, np.r_[np.zeros(6), Q.ravel()], T_b2, X)  # exact projections through the true lens
    sigma_enc = np.deg2rad(0.002)
    errs = {}
    for k3 in (None, 10.0):
        res = joint_bundle(robot, eps, MOUNT, Q, LOC, np.eye(4), view, point, x, X, sigma_enc, 0.05, K, DIST,
                           cov_dist=np.diag([1e-4, 1e-4, 1e-8, 1e-8]), gate=None, k3_sd=k3)
        assert res.success, res.message
        errs[k3] = np.linalg.norm(res.T_site_base[:3, 3] - T_b2[:3, 3])
        if k3 is not None:  # noise-free: exact
            assert np.allclose(res.dist, true_dist, atol=1e-6), res.dist
    assert errs[10.0] < 1e-9 and errs[None] > 1e-6, errs  # without k3, k2 absorbs it and the base moves
    with pytest.raises(ValueError, match="needs the distortion's prior"):
        joint_bundle(robot, eps, MOUNT, Q, LOC, np.eye(4), view, point, x, X, sigma_enc, 0.05, K, DIST, k3_sd=10.0)


def test_the_lab_k3_covariance_is_the_distortion_block_with_its_cross_terms(tmp_path):
    """A lab that fitted k3 writes a 5 x 5 distortion block (k1 k2 p1 p2 k3) with 4 x 5 and 5 x 6 cross-covariances:
    it round-trips, orders as the 15-parameter prior, and the joint bundle under a block-diagonal one is the bundle
    with ``k3_sd`` to 1e-9; mismatched shapes, a 5 x 5 block with ``distortion_k3_sd`` and a bad block size are
    one-line errors."""
    from bench.errors import ConfigError
    from bench.vision.joint_bundle import distortion_block_size, lab_blocks, lab_prior, priors_yaml_text, read_priors

    C, blocks = _random_lab_prior(np.random.default_rng(6), 5)
    assert np.allclose(lab_prior(**blocks), C)
    p = tmp_path / "calibration_priors.yaml"
    p.write_text(priors_yaml_text(notes="lab k3", **blocks))
    got = read_priors(p)
    assert got["cov_dist"].shape == (5, 5) and np.allclose(lab_prior(**lab_blocks(got)), C, rtol=1e-12)
    assert [distortion_block_size(got["cov_dist"]), distortion_block_size(C[4:8, 4:8], 10.0),
            distortion_block_size(C[4:8, 4:8]), distortion_block_size()] == [5, 5, 4, 0]
    for bad, key in (({**blocks, "cov_K_dist": C[:4, 4:8]}, "intrinsics_distortion_covariance"),
                     ({**blocks, "cov_dist_mount": C[4:8, 9:]}, "distortion_mount_covariance"),
                     ({**blocks, "cov_dist": C[4:10, 4:10], "cov_K_dist": None, "cov_dist_mount": None},
                      "distortion_covariance")):
        p.write_text(priors_yaml_text(notes="bad", **bad))
        with pytest.raises(ConfigError, match=f"{key}: expected a"):
            read_priors(p)
    p.write_text(priors_yaml_text(notes="k3 twice", k3_sd=10.0, **blocks))
    with pytest.raises(ConfigError, match="distortion_k3_sd: distortion_covariance is 5 x 5"):
        read_priors(p)
    with pytest.raises(ValueError, match="k3_sd with a 5 x 5"):
        lab_prior(**blocks, k3_sd=10.0)
    with pytest.raises(ValueError, match="4 x 4 .* or 5 x 5"):
        distortion_block_size(np.eye(3))
    # the 5 x 5 block with k3 apart is the same prior as the 4 x 4 one and k3_sd: the same bundle
    rng = np.random.default_rng(85)
    robot, eps, T_b2, X, view, point, _ = _scene(rng, 60)
    truth = _Problem(robot, eps, MOUNT, LOC, view, point, np.zeros((len(view), 2)), K, DIST + np.r_[0, 0, 0, 0, 0.5])
    x = -residuals(truth, np.r_[np.zeros(6), Q.ravel()], T_b2, X) + rng.normal(0, 0.1, (len(view), 2))
    cov4 = np.diag([1e-4, 1e-4, 1e-8, 1e-8])
    cov_K = np.diag([4.0, 4.0, 1.0, 1.0])
    args = (robot, eps, MOUNT, Q, LOC, np.eye(4), view, point, x, X, np.deg2rad(0.002), 0.1, K, DIST)
    a = joint_bundle(*args, cov_K=cov_K, cov_dist=cov4, k3_sd=3.0, gate=None)
    b = joint_bundle(*args, cov_K=cov_K, cov_dist=np.diag(np.r_[np.diag(cov4), 9.0]), gate=None)
    assert a.success and b.success and "with k3" in b.message
    assert np.allclose(a.T_site_base, b.T_site_base, atol=1e-9) and np.allclose(a.dist, b.dist, atol=1e-9)
    assert abs(b.dist[4] - DIST[4]) > 0.1  # k3 was refined


def test_observations_of_every_map_point_or_the_located_ones():
    """observations_of: 'located' gives the points both locate views matched, in the reference, their survey views
    and the two locate views; 'all' then appends every other map point, renumbered after them, in the reference and
    its survey views only (no locate observation); an unknown choice is a ValueError."""
    from types import SimpleNamespace

    from bench.vision.joint_bundle import observations_of

    rng = np.random.default_rng(83)
    x_ref = rng.normal(size=(4, 2))
    obs = [(np.array([0, 1]), rng.normal(size=(2, 2))), (np.array([1]), rng.normal(size=(1, 2))),
           (np.array([0]), rng.normal(size=(1, 2))), (np.array([0, 1]), rng.normal(size=(2, 2)))]
    kmap = SimpleNamespace(x_ref=x_ref, p_ref=rng.normal(size=(4, 3)), observations=obs)
    used = (np.array([3, 1]), rng.normal(size=(2, 2)), rng.normal(size=(2, 2)))
    view, point, x, idx = observations_of(kmap, used, 2, "located")
    assert idx.tolist() == [3, 1] and point.tolist() == [0, 0, 0, 0, 0, 1, 1, 1, 1]
    assert view.tolist() == [0, 1, 2, 3, 4, 0, 2, 3, 4]
    assert np.array_equal(x[[0, 4, 6, 8]], [x_ref[3], used[2][0], obs[1][1][0], used[2][1]])
    view_a, point_a, x_a, idx_a = observations_of(kmap, used, 2)  # default: all
    assert idx_a.tolist() == [3, 1, 0, 2]
    assert np.array_equal(view_a[:9], view) and np.array_equal(x_a[:9], x)
    assert view_a[9:].tolist() == [0, 1, 2, 0, 1] and point_a[9:].tolist() == [2, 2, 2, 3, 3]
    assert np.array_equal(x_a[9:], [x_ref[0], *obs[0][1], x_ref[2], *obs[2][1]])
    assert not np.any(np.isin(view_a[point_a >= 2], [3, 4]))  # the survey-only points: no locate observation
    with pytest.raises(ValueError, match="map_points"):
        observations_of(kmap, used, 2, "some")


def test_survey_only_points_tighten_the_base_through_the_shared_camera():
    """Points the locate views do not see still weigh on the survey views' joints, the intrinsics and the mount, which
    the base pose shares: with the intrinsics and the mount refined under loose priors, adding 40 survey-only points
    to 20 seen everywhere shrinks the base position covariance (by 14 % here; the pixel noise each bundle estimates
    differs by 2 %), and the estimate stays consistent with it."""
    rng = np.random.default_rng(84)
    robot, eps, T_b2, X, view, point, x = _scene(rng)
    drop = LOC[view] & (point >= 20)  # points 20..59: survey only
    priors = dict(cov_mount=np.diag([np.deg2rad(0.5)] * 3 + [2e-3] * 3) ** 2, cov_K=np.diag([20.0, 20, 10, 10]) ** 2)
    sigma_enc, sigma_px = np.deg2rad(0.01), 0.1
    q_read = Q + rng.normal(0, sigma_enc, Q.shape)
    xn = x + rng.normal(0, sigma_px, x.shape)
    keep = point < 20
    few = joint_bundle(robot, eps, MOUNT, q_read, LOC, T_b2, view[keep], point[keep], xn[keep], X[:20], sigma_enc,
                       0.3, K, **priors)
    many = joint_bundle(robot, eps, MOUNT, q_read, LOC, T_b2, view[~drop], point[~drop], xn[~drop], X, sigma_enc,
                        0.3, K, **priors)
    assert few.success and many.success
    assert np.trace(many.covariance[3:, 3:]) < 0.95 * np.trace(few.covariance[3:, 3:])
    e = many.T_site_base[:3, 3] - T_b2[:3, 3]
    assert e @ np.linalg.solve(many.covariance[3:, 3:], e) < 16.3  # chi2_3(0.999)


def test_a_keypoint_weighed_once_is_the_bundle_without_its_twin():
    """SIFT's twins: a second map point whose keypoint is the first's in every view. Weighed as one measurement
    (``detection_weights``: 1/2 each), the bundle is the one without the copies - the pose to 1e-9 m, the pixel
    noise to 1e-9, the covariance to 1e-7 of its size - while unweighted it counts them twice and its covariance
    shrinks."""
    from bench.vision.joint_bundle import detection_weights

    rng = np.random.default_rng(85)
    robot, eps, T_b2, X, view, point, x = _scene(rng)
    sigma_enc = np.deg2rad(0.002)
    xn = x + rng.normal(0, 0.1, x.shape)
    twin = point < 20  # points 0-19 get a copy: the same keypoint in every view
    view2, point2, xn2 = np.r_[view, view[twin]], np.r_[point, point[twin] + len(X)], np.r_[xn, xn[twin]]
    X2 = np.r_[X, X[:20]]
    w = detection_weights(view2, xn2, 0.01)
    assert np.allclose(w, np.r_[np.where(twin, 0.5, 1.0), np.full(twin.sum(), 0.5)])
    one = joint_bundle(robot, eps, MOUNT, Q, LOC, T_b2, view, point, xn, X, sigma_enc, 0.3, K, gate=None)
    weighed = joint_bundle(robot, eps, MOUNT, Q, LOC, T_b2, view2, point2, xn2, X2, sigma_enc, 0.3, K, gate=None,
                           weights=w)
    twice = joint_bundle(robot, eps, MOUNT, Q, LOC, T_b2, view2, point2, xn2, X2, sigma_enc, 0.3, K, gate=None)
    assert one.success and weighed.success and twice.success
    assert np.abs(weighed.T_site_base - one.T_site_base).max() < 1e-9
    assert weighed.sigma_px == pytest.approx(one.sigma_px, rel=1e-9)
    # (the two solves stop at rounding level on different sums: the covariances agree to ~1e-9 of their size)
    assert np.abs(weighed.covariance - one.covariance).max() < 1e-7 * np.abs(one.covariance).max()
    assert np.trace(twice.covariance[3:, 3:]) < 0.95 * np.trace(one.covariance[3:, 3:])
    # with the gate on, the weighed bundle keeps what the one without copies keeps (its median sees the copies)
    gated = joint_bundle(robot, eps, MOUNT, Q, LOC, T_b2, view2, point2, xn2, X2, sigma_enc, 0.3, K, weights=w)
    ref = joint_bundle(robot, eps, MOUNT, Q, LOC, T_b2, view, point, xn, X, sigma_enc, 0.3, K)
    assert np.linalg.norm(gated.T_site_base[:3, 3] - ref.T_site_base[:3, 3]) < 0.05 * np.sqrt(
        np.trace(ref.covariance[3:, 3:]))
    with pytest.raises(ValueError, match="weights"):
        joint_bundle(robot, eps, MOUNT, Q, LOC, T_b2, view, point, xn, X, sigma_enc, 0.3, K, weights=np.zeros(len(xn)))
    with pytest.raises(ValueError, match="weights"):
        joint_bundle(robot, eps, MOUNT, Q, LOC, T_b2, view, point, xn, X, sigma_enc, 0.3, K, weights=w)  # wrong length
    with pytest.raises(ValueError, match="no weights"):
        joint_bundle(robot, eps, MOUNT, Q, LOC, T_b2, view2, point2, xn2, X2, sigma_enc, 0.3, K, weights=w,
                     field_order=1, image_size=(640, 480))


def test_detection_weights_share_a_keypoint_between_its_observations():
    from bench.vision.joint_bundle import detection_weights

    view = np.array([0, 0, 0, 0, 1, 1, 1])
    uv = np.array([[10, 10], [10, 10], [10.006, 10], [30, 30], [10, 10], [10.5, 10], [30, 30]], float)
    w = detection_weights(view, uv, 0.01)
    assert w.tolist() == pytest.approx([1 / 3, 1 / 3, 1 / 3, 1, 1, 1, 1])  # one view's copies only, chained
    assert np.bincount(view, weights=w).tolist() == pytest.approx([2, 3])  # the distinct keypoints of each view
    chain = np.array([[0, 0], [0.008, 0], [0.016, 0]], float)  # each within 0.01 px of the next, the ends not
    assert detection_weights(np.zeros(3, int), chain, 0.01) == pytest.approx(np.full(3, 1 / 3))
    assert detection_weights(np.zeros(0, int), np.zeros((0, 2)), 0.01).shape == (0,)
    # a shared keypoint worth 1.5 measurements: 0.75 for each of two, 0.5 for each of three, never above 1
    assert detection_weights(view, uv, 0.01, worth=1.5).tolist() == pytest.approx([0.5, 0.5, 0.5, 1, 1, 1, 1])
    assert detection_weights(view[:2], uv[:2], 0.01, worth=1.5).tolist() == pytest.approx([0.75, 0.75])
    assert detection_weights(view[:2], uv[:2], 0.01, worth=2.0).tolist() == pytest.approx([1.0, 1.0])
    for bad in (0.0, 2.5, np.nan):
        with pytest.raises(ValueError, match="worth"):
            detection_weights(view, uv, 0.01, worth=bad)
    with pytest.raises(ValueError, match="tol_px"):
        detection_weights(view, uv, 0.0)
    with pytest.raises(ValueError, match="uv"):
        detection_weights(view, uv[:3], 0.01)
    with pytest.raises(ValueError, match="uv"):
        detection_weights(view, np.where(uv == 30, np.nan, uv), 0.01)
