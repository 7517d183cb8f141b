"""The x-y table's bundle (bench.vision.xy_table_bundle): its Jacobian against difference quotients, exactness on
noise-free data with a wrong R0 and wrong intrinsics, its covariance against a Monte Carlo, degenerate input."""

import numpy as np
import pytest

from bench.geometry.transforms import transform_points
from bench.sim.scenes.xy_table import lab_table_model, table4_commands
from bench.vision.handeye import mount_rotation
from bench.vision.xy_table_bundle import PairProblem, pair_bundle
from bench.vision.xy_table_positioning import (
    PositioningConfig,
    TableSpec,
    estimate_positions,
    stage_camera,
    stage_poses,
)
from tests.vision.test_xy_table_positioning import CAMERA, DEG, _scene

READ = lab_table_model().read(table4_commands())
R0 = mount_rotation(0.3 * DEG, 6.2 * DEG, -1.8 * DEG)
R0_SEARCHED = mount_rotation(0.3 * DEG, 7.0 * DEG, -0.5 * DEG)  # the search is ~2 deg off in the scenario
COV_K = np.diag([30.0, 30.0, 10.0, 10.0]) ** 2
COV_DIST = np.diag([0.3, 0.3, 0.03, 0.03, 3e-3, 3e-3, 3e-3, 3e-3]) ** 2  # k1 k2 p1 p2 and the thin prism's s1..s4


def _setup(rng, n=60):
    """A small campaign: the reference, three map views and a pair, ``n`` points seen by all; exact pixels."""
    read = READ[[10, 0, 5, 20, 3, 13]]
    T = stage_poses(read) @ stage_camera(R0, np.zeros(3))
    X = transform_points(T[0], np.c_[rng.uniform(-0.2, 0.2, (n, 2)), rng.uniform(0.6, 0.8, n)])
    view, point = np.repeat(np.arange(6), n), np.tile(np.arange(n), 6)
    in_pair = np.array([0, 0, 0, 0, 1, 1], bool)
    truth = PairProblem(read, in_pair, np.eye(4), T[4][:3, 3], R0, np.zeros(3), CAMERA.K, DIST, view, point,
                        np.zeros((6 * n, 2)), False)
    return read, T, X, view, point, in_pair, -truth.residuals(np.zeros(truth.n), X)


DIST = np.array([-0.1, 0.05, 1e-3, -2e-3, 0.0])


def test_jacobian_matches_difference_quotients():
    """Every block (pair, R0, intrinsics, distortion with the thin prism, centre, readings) and the points against
    central differences."""
    rng = np.random.default_rng(0)
    read, T, X, view, point, in_pair, uv = _setup(rng)
    T_a0 = T[4].copy()
    T_a0[:3, 3] += (0.002, -0.001, 0.003)
    p = PairProblem(read, in_pair, T_a0 @ np.linalg.inv(T[4]), T_a0[:3, 3], R0_SEARCHED, np.zeros(3), CAMERA.K, DIST,
                    view, point, uv, True, True, 8, True)
    X = X + rng.normal(0, 1e-3, X.shape)
    scale = np.r_[np.ones(9), 100 * np.ones(4), 0.1 * np.ones(4), 0.1 * np.ones(4), 0.1 * np.ones(3),
                  np.tile([1e-3, 1e-3, 1e-3], p.V)]
    theta = rng.normal(0, 1e-2, p.n) * scale
    r, J, J_pt, z = p.linearise(theta, X)
    assert p.n == 9 + 4 + 8 + 3 + 3 * 6 and z > 0 and np.array_equal(r, p.residuals(theta, X))
    h = 1e-6
    for c in range(p.n):
        e = np.zeros(p.n)
        e[c] = h
        fd = (p.residuals(theta + e, X) - p.residuals(theta - e, X)) / (2 * h)
        assert np.abs(J[:, :, c] - fd).max() <= 1e-5 * max(1.0, np.abs(fd).max()), c
    for k in range(3):  # each observation's derivative by its own point
        E = np.zeros_like(X)
        E[:, k] = h
        fd = (p.residuals(theta, X + E) - p.residuals(theta, X - E)) / (2 * h)
        assert np.abs(J_pt[:, :, k] - fd).max() <= 1e-5 * np.abs(fd).max()


@pytest.mark.parametrize("wrong", ["none", "R0", "R0+K+dist", "R0+K+dist+prism", "R0+K+dist+centre"])
def test_noise_free_bundle_is_exact(wrong):
    """Exact pixels: whatever R0, intrinsics, distortion (with or without the thin prism) and camera centre on the
    stage it starts from (under priors), the bundle finds every camera a to <= 1e-9 m - where the thesis's
    estimators, given the same wrong R0, camera and centre, err by millimetres."""
    centre = np.array([5e-4, 3e-4, 1e-3]) if "centre" in wrong else np.zeros(3)  # true centre minus the nominal
    feats, readings, T_tc = _scene(READ, centre, R0, "p11", n_points=400)
    spec = TableSpec(np.zeros(3), camera_offset_sigma_m=np.full(3, 1e-3) if "centre" in wrong else None)
    cfg = PositioningConfig(reference="p11", intraocular_mm=(50.0, 100.0), methods=("lms_ratio", "bundle"),
                            bundle_centre="centre" in wrong)
    camera = CAMERA
    if "K" in wrong:
        K = CAMERA.K.copy()
        K[0, 0] *= 1.01
        K[1, 1] *= 1.01
        K[:2, 2] += (1.5, -2.0)
        camera = CAMERA.replace(K=K, dist=np.array([0.02, -0.05, 1e-3, -1e-3, 0.0]), model="heikkila")
    res = estimate_positions(feats, readings, camera, spec, cfg, R0=R0 if wrong == "none" else
                             R0_SEARCHED, cov_K=COV_K if "K" in wrong else None,
                             cov_dist=(COV_DIST if "prism" in wrong else COV_DIST[:4, :4]) if "dist" in wrong else None)
    err = {m: [] for m in cfg.methods}
    for c in res.combinations:
        assert c.success, c.message
        err[c.method].append(np.abs(c.p_table - (T_tc[c.a][:3, 3] - T_tc["p11"][:3, 3])).max())
    assert len(err["bundle"]) == len(err["lms_ratio"]) == 23  # 13 pairs at 50 mm, 10 at 100 mm
    assert max(err["bundle"]) <= 1e-9, max(err["bundle"])
    if wrong != "none":
        assert max(err["lms_ratio"]) > 1e-4


def test_refined_readings_absorb_a_reading_error():
    """Exact pixels, one map view's reading off by 0.05 deg and the reference's by 0.05 mm: with the readings exact
    the bundle errs by tens of micrometres (and its residuals show it: sigma ~0.2 px); refining every reading under
    a one-step prior takes that error down tenfold and the residuals to ~0."""
    rng = np.random.default_rng(3)
    read, T, X, view, point, in_pair, uv = _setup(rng, n=80)
    bad = read.copy()
    bad[2, 2] += np.deg2rad(0.05)
    bad[0, 0] += 5e-5
    sigma = np.array([1e-4, 1e-4, np.deg2rad(0.1)]) / np.sqrt(12)
    args = (bad, in_pair, T[4], R0_SEARCHED, np.zeros(3), CAMERA.K, DIST, view, point, uv, X)
    exact = pair_bundle(*args, cov_K=COV_K)
    refined = pair_bundle(*args, cov_K=COV_K, reading_sigma=sigma)
    true = T[4][:3, 3] - T[0][:3, 3]
    e_exact, e_refined = (np.abs(r.p_table - true).max() for r in (exact, refined))
    assert e_exact > 2e-5 and exact.sigma_px > 0.1
    assert e_refined < e_exact / 10 and refined.sigma_px < 1e-3, (e_exact, e_refined, refined.sigma_px)


def test_covariance_agrees_with_monte_carlo():
    """0.2 px Gaussian pixel noise, 60 draws: the RMS error of camera a's position per axis matches the bundle's
    own first-order standard deviation within 25 % (the chi-square spread of 60 draws is ~9 %)."""
    rng = np.random.default_rng(1)
    read, T, X, view, point, in_pair, uv = _setup(rng, n=80)
    true = T[4][:3, 3] - T[0][:3, 3]
    errs, stds = [], []
    for _ in range(60):
        T_a0 = T[4].copy()
        T_a0[:3, 3] += rng.normal(0, 1e-3, 3)
        res = pair_bundle(read, in_pair, T_a0, R0_SEARCHED, np.zeros(3), CAMERA.K, DIST, view, point,
                          uv + rng.normal(0, 0.2, uv.shape), X + rng.normal(0, 1e-3, X.shape), cov_K=COV_K)
        assert res.success, res.message
        errs.append(res.p_table - true)
        stds.append(np.sqrt(np.diag(res.cov_p)))
    rms, std = np.sqrt(np.mean(np.square(errs), axis=0)), np.sqrt(np.mean(np.square(stds), axis=0))
    assert np.all(np.abs(rms / std - 1) < 0.25), (rms, std)


def test_step_tolerance_stops_within_a_fraction_of_a_sigma(monkeypatch):
    """The rounds end once a step is shorter than STEP_TOL standard deviations: against iterating to rounding
    level (0.3 px noise, intrinsics and distortion under priors, a start 2 mm off), the position moves by less than
    2 STEP_TOL standard deviations (Mahalanobis) and no more iterations are taken."""
    import bench.vision.xy_table_bundle as xb

    rng = np.random.default_rng(11)
    read, T, X, view, point, in_pair, uv = _setup(rng, n=80)
    T_a0 = T[4].copy()
    T_a0[:3, 3] += (2e-3, -1e-3, 2e-3)
    args = (read, in_pair, T_a0, R0_SEARCHED, np.zeros(3), CAMERA.K, DIST, view, point,
            uv + rng.normal(0, 0.3, uv.shape), X + rng.normal(0, 2e-3, X.shape))
    short, tol = pair_bundle(*args, cov_K=COV_K, cov_dist=COV_DIST[:4, :4]), xb.STEP_TOL
    monkeypatch.setattr(xb, "STEP_TOL", None)
    full = pair_bundle(*args, cov_K=COV_K, cov_dist=COV_DIST[:4, :4])
    assert short.success and full.success and short.iterations <= full.iterations
    d = short.p_table - full.p_table
    assert 0 < float(d @ np.linalg.solve(full.cov_p, d)) ** 0.5 < 2 * tol, (short.iterations, full.iterations)


def test_an_estimate_off_its_optimum_is_refused():
    """Out of iterations far from the optimum (one Gauss-Newton step from a start 3 mm off, 0.3 px noise): no
    position and no covariance are offered."""
    rng = np.random.default_rng(7)
    read, T, X, view, point, in_pair, uv = _setup(rng, n=60)
    T_a0 = T[4].copy()
    T_a0[:3, 3] += (3e-3, -2e-3, 3e-3)
    res = pair_bundle(read, in_pair, T_a0, R0_SEARCHED, np.zeros(3), CAMERA.K, DIST, view, point,
                      uv + rng.normal(0, 0.3, uv.shape), X + rng.normal(0, 2e-3, X.shape), cov_K=COV_K, iterations=1,
                      rounds=1)
    assert not res.success and "not converged" in res.message and np.all(np.isnan(res.p_table))
    full = pair_bundle(read, in_pair, T_a0, R0_SEARCHED, np.zeros(3), CAMERA.K, DIST, view, point,
                       uv + rng.normal(0, 0.3, uv.shape), X + rng.normal(0, 2e-3, X.shape), cov_K=COV_K)
    assert full.success, full.message


def test_degenerate_input():
    rng = np.random.default_rng(2)
    read, T, X, view, point, in_pair, uv = _setup(rng, n=2)
    args = (np.zeros(3), CAMERA.K, None, view, point, uv, X)
    res = pair_bundle(read, in_pair, T[4], R0, *args)
    assert not res.success and "points" in res.message and np.all(np.isnan(res.p_table))
    with pytest.raises(ValueError, match="in_pair"):
        pair_bundle(read, in_pair[::-1], T[4], R0, *args)
    with pytest.raises(ValueError, match="R0_prior_deg"):
        pair_bundle(read, in_pair, T[4], R0, *args, R0_prior_deg=0.0)
    with pytest.raises(ValueError, match="reading_sigma"):
        pair_bundle(read, in_pair, T[4], R0, *args, reading_sigma=[1e-4, 0.0, 1e-3])


def test_unknown_method_names_the_bundle():
    feats, readings, _ = _scene(READ[:3], np.zeros(3), R0, "p01", n_points=50)
    cfg = PositioningConfig(reference="p01", methods=("lsm",))
    with pytest.raises(ValueError, match="bundle"):
        estimate_positions(feats, readings, CAMERA, TableSpec(np.zeros(3)), cfg, R0=R0)
