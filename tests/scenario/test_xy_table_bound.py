"""The x-y table's Cramér-Rao bound on a small synthetic campaign (seven table poses, 60 points 0.7 m ahead): its table
model is the simulator's, its block Jacobian equals a column-by-column difference quotient, the experiment's shared
rows give the same bound as a model of its own per pair, the bound matches a Monte Carlo of the maximum-likelihood
estimator, the thesis's estimator is exact on exact data, and the corner noise measurement recovers sigma."""

from types import SimpleNamespace

import numpy as np
import pytest

from bench.camera.model import thin_prism
from bench.camera.presets import load_preset
from bench.geometry.transforms import homogeneous, rot_x, rot_y, rot_z, transform_points
from bench.scenario.bounds import ml_estimate, point_sigma_px
from bench.scenario.xy_table_bound import (
    TableKinematics,
    Unknowns,
    _PairModel,
    experiment_bounds,
    floor_positions,
    mc_ideal_positions,
    model_poses,
    position_bound,
    table_error_prior,
)
from bench.sim.scenes.xy_table import TableModel, random_table_errors
from bench.vision.xy_table_positioning import PositioningConfig, TableSpec

DEG = np.pi / 180
NAMES = [f"p{k:02d}" for k in range(1, 8)]
STEPS = np.c_[np.arange(-60, 61, 20) * 1e-3, np.zeros(7), np.arange(3, -4, -1) * DEG]  # x, z, rotation
MAP = ["p01", "p05", "p06", "p07"]  # views of 1p besides the reference p04
PAIR = ("p02", "p03")


def _truth(errors, readout="steps", offset=(0.0, 0.0, 0.0)):
    T_mc = homogeneous(rot_y(6 * DEG) @ rot_x(0.3 * DEG) @ rot_z(-1.8 * DEG), [0.5e-3, 0.3e-3, 1e-3])
    run = TableModel(errors, camera_offset_m=offset).run(STEPS)
    return {"positions": list(range(1, 8)), "steps": run.read.tolist(), "table_readout": readout,
            "read": (run.true if readout == "exact" else run.read).tolist(), "table_errors": dict(errors.__dict__),
            "camera_offset_m": list(offset), "T_mount_cam": T_mc.tolist()}, run.T_table_mount @ T_mc


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(81)
    truth, T_true = _truth(random_table_errors(rng))
    kin = TableKinematics(truth, NAMES)
    cam = load_preset("air_webcam")
    # table frame: 0.7 m ahead, where the cameras (turned 6 deg about y on their support) look
    X = np.c_[rng.uniform(-0.08, 0.22, 60), rng.uniform(-0.12, 0.12, 60), rng.uniform(0.65, 0.75, 60)]
    seen = {n: np.ones(len(X), bool) for n in NAMES}
    return kin, T_true, cam, X, seen


@pytest.mark.parametrize("readout", ["steps", "exact"])
def test_table_model_is_the_simulators(readout):
    """At the true table errors the bound's camera poses are the simulator's (steps: from the steps and the errors;
    exact readings: from the readings, the table's geometry errors only)."""
    truth, T_true = _truth(random_table_errors(np.random.default_rng(82)), readout, offset=(-0.1, 0.0, 0.0))
    kin = TableKinematics(truth, NAMES)
    assert len(kin.params) == (9 if readout == "steps" else 3)
    T = model_poses(kin)
    assert max(np.abs(T[n] - T_true[i]).max() for i, n in enumerate(NAMES)) < 1e-12


def test_block_jacobian_and_shared_rows(scene):
    """The block differences equal one column at a time; the experiment's bound (rows shared between pairs) equals
    the pair's own model."""
    kin, _, cam, X, seen = scene
    T0 = model_poses(kin)
    views = ["p04", *MAP, *PAIR]
    model = _PairModel(kin, views, [n in PAIR for n in views], T0[PAIR[0]][:3, 3], X, cam.project, cam.size,
                       np.stack([seen[n] for n in views]))
    assert model.vis.all() and model.n_params == 6 + 9
    J = model.jacobian(*model.values0, X)
    assert np.allclose(J, model.jacobian_columnwise(*model.values0, X), rtol=1e-6, atol=1e-4)
    prior = np.linalg.inv(table_error_prior(kin.params))
    own = position_bound(kin, prior, "p04", PAIR, MAP, X, seen, cam.project, cam.size, 0.2)
    result = SimpleNamespace(observations=dict.fromkeys(NAMES), T_table_cam=T0, pairs={20.0: [PAIR]})
    config = PositioningConfig(reference="p04", map_min_baseline_m=0.015)  # 1p: every view but the pair
    shared = experiment_bounds(result, kin, config, X, seen, cam.project, cam.size, 0.2)[(20.0, *PAIR)]
    assert np.allclose(shared["cov_pos"], own["cov_pos"], rtol=1e-8, atol=0)
    assert own["observations"] == len(views) * len(X)
    # the complete bound (intrinsics, distortion with the thin prism, R0, the camera centre): the shared rows hold
    # every block but the pair's displacement
    unknowns = Unknowns(K=cam.K, cov_K=np.diag([4.0, 4.0, 9.0, 9.0]), R0_free=True,
                        cov_dist=np.diag([0.3, 0.3, 0.03, 0.03, 1e-3, 1e-3, 1e-3, 1e-3]) ** 2,
                        offset_sigma=np.full(3, 1e-3))
    own = position_bound(kin, prior, "p04", PAIR, MAP, X, seen, cam.project, cam.size, 0.2, unknowns=unknowns)
    shared = experiment_bounds(result, kin, config, X, seen, cam.project, cam.size, 0.2,
                               unknowns=unknowns)[(20.0, *PAIR)]
    assert own["cov_pos"].trace() > 1.02 * position_bound(kin, prior, "p04", PAIR, MAP, X, seen, cam.project,
                                                          cam.size, 0.2)["cov_pos"].trace()
    for key in ("cov_pos", "cov_rot"):
        assert np.allclose(shared[key], own[key], rtol=1e-8, atol=0)


def test_bound_equals_the_ml_estimator_spread(scene):
    """The ML estimator (bundle adjustment over the pair's displacement, the table's nine errors and the points, the
    errors' prior included) on noisy pixels and tables drawn from the prior: its spread of c_a - c_ref matches the
    bound (Monte Carlo, 60 draws: +-35 % on the trace, ~3 standard errors of a variance estimate); noise-free, it
    returns the truth."""
    kin, _, cam, X, seen = scene
    sigma = 0.2
    T0 = model_poses(kin)
    views = ["p04", *MAP, *PAIR]
    model = _PairModel(kin, views, [n in PAIR for n in views], T0[PAIR[0]][:3, 3], X, cam.project, cam.size,
                       np.stack([seen[n] for n in views]))
    cov_prior = table_error_prior(kin.params)
    priors = {"table": np.linalg.inv(cov_prior)}
    bound = position_bound(kin, priors["table"], "p04", PAIR, MAP, X, seen, cam.project, cam.size, sigma)

    def g(xi, v):
        T = model.camera_poses(xi, v)
        return T[-2, :3, 3] - T[0, :3, 3]

    rng = np.random.default_rng(83)
    L = np.linalg.cholesky(cov_prior)
    xi0 = np.zeros(6)
    exact = ml_estimate(model, model.pixels(xi0, kin.v0, X), sigma, priors, [xi0, kin.v0],
                        [np.r_[rng.normal(0, 1e-3, 3), rng.normal(0, 2e-3, 3)], kin.v0], X + 1e-3, tol=1e-13)
    assert np.abs(g(*exact["values"]) - g(xi0, kin.v0)).max() < 1e-9 and np.abs(exact["X"] - X).max() < 1e-9
    errs = []
    for _ in range(60):
        v_true = kin.v0 + L @ rng.normal(size=len(kin.v0))  # this campaign's table, drawn from the prior
        uv = model.pixels(xi0, v_true, X) + rng.normal(0, sigma, (len(views), len(X), 2))
        est = ml_estimate(model, uv, sigma, priors, [xi0, kin.v0], [rng.normal(0, 1e-3, 6), kin.v0],
                          X + rng.normal(0, 1e-3, X.shape), tol=1e-10)
        assert est["success"]
        errs.append(g(*est["values"]) - g(xi0, v_true))
    cov_mc = np.cov(np.array(errs).T)
    assert np.trace(cov_mc) == pytest.approx(np.trace(bound["cov_pos"]), rel=0.35)


def test_ml_estimate_budget_is_not_convergence(scene):
    """The ML estimator stopped by its evaluation budget (one step from a start far off) says so: not success."""
    kin, _, cam, X, seen = scene
    views = ["p04", *MAP, *PAIR]
    model = _PairModel(kin, views, [n in PAIR for n in views], model_poses(kin)[PAIR[0]][:3, 3], X, cam.project,
                       cam.size, np.stack([seen[n] for n in views]))
    priors = {"table": np.linalg.inv(table_error_prior(kin.params))}
    uv = model.pixels(np.zeros(6), kin.v0, X)
    est = ml_estimate(model, uv, 0.2, priors, [np.zeros(6), kin.v0], [np.full(6, 5e-3), kin.v0], X + 5e-3,
                      iterations=1)
    assert not est["success"] and "evaluations" in est["message"] and est["iterations"] <= 2


def test_thesis_estimator_exact_on_exact_data(scene):
    """The Monte Carlo's estimator (map, 2p, RANSAC + LMS + error ratio) on exact projections of a table without
    errors, given the true camera, R0 and centre: every estimate exact."""
    kin, _, cam, X, seen = scene
    T_mc = kin.T_mount_cam
    spec = TableSpec(T_mc[:3, 3].copy())
    config = PositioningConfig(reference="p04", intraocular_mm=(20.0, 40.0), map_min_baseline_m=0.03,
                               methods=("lms_ratio",))
    mc = mc_ideal_positions(kin, X, seen, cam, spec, T_mc[:3, :3], config, 0.0, np.random.default_rng(84), 1,
                            table_errors=False)
    assert mc.pop("failures") == 0
    assert sorted(mc) == [20.0, 40.0] and sum(len(e) for e in mc.values()) == 7  # 1-2, 2-3, 5-6, 6-7; 1-3, 3-5, 5-7
    assert max(np.abs(e).max() for e in mc.values()) < 1e-9


def test_complete_bound_blocks_and_monotonicity(scene):
    """The intrinsics (d_K) and camera-rotation (d_R0) blocks: their block differences equal one column at a time,
    d_K moves the pixels exactly as ``c + dc + (f + df) / f (uv - c)``; the complete bound is never below the bound
    with those exact, equals it (1e-9 relative) as the intrinsics' covariance goes to zero and R0 stays exact, and
    grows with that covariance."""
    kin, _, cam, X, seen = scene
    T0 = model_poses(kin)
    views = ["p04", *MAP, *PAIR]
    vis = np.stack([seen[n] for n in views])
    model = _PairModel(kin, views, [n in PAIR for n in views], T0[PAIR[0]][:3, 3], X, cam.project, cam.size, vis,
                       K=cam.K, with_R0=True, K_lens=cam.K, with_offset=True)
    assert model.n_params == 6 + 9 + 3 + 4 + 4 + 3
    J = model.jacobian(*model.values0, X)
    assert np.allclose(J, model.jacobian_columnwise(*model.values0, X), rtol=1e-6, atol=1e-4)
    dK = np.array([3.0, -2.0, 1.5, 0.5])
    uv0 = model.pixels(*model.values0, X)
    uv = model.pixels(*model.values0[:3], dK, np.zeros(4), np.zeros(3), X)
    f, c = np.diag(cam.K)[:2], cam.K[:2, 2]
    assert np.abs(uv - (c + dK[2:] + (1 + dK[:2] / f) * (uv0 - c))).max() < 1e-9
    # d_dist: the lens's distortion moved by d (k1, k2, p1, p2); distort is linear in its coefficients, so through a
    # lens in air the block moves the pixels exactly as the lens with dist + d does
    dd = np.array([0.02, -0.01, 1e-3, -2e-3])
    uv = model.pixels(*model.values0[:4], dd, np.zeros(3), X)
    p_cam = transform_points(np.linalg.inv(model.camera_poses(*model.values0))[:, None], X[None])
    moved = cam.replace(dist=cam.dist + np.r_[dd, np.zeros(len(cam.dist) - 4)], model="heikkila")
    assert np.abs((uv - uv0) - (moved.project(p_cam) - cam.project(p_cam))).max() < 1e-9
    assert np.abs(uv - uv0).max() > 0.5  # the check is not vacuous
    # with the thin prism (8 coefficients) its four move the pixels by K thin_prism(x_n, s) (linear in s)
    m8 = _PairModel(kin, views, [n in PAIR for n in views], T0[PAIR[0]][:3, 3], X, cam.project, cam.size, vis,
                    K_lens=cam.K, n_dist=8)
    sp = np.array([5e-4, 1e-4, -5e-4, 2e-4])
    uv8 = m8.pixels(*m8.values0[:-1], np.r_[np.zeros(4), sp], X)
    x_n = p_cam[..., :2] / p_cam[..., 2:3]
    shift = thin_prism(x_n.reshape(-1, 2), sp).reshape(x_n.shape) @ cam.K[:2, :2].T
    assert np.abs((uv8 - m8.pixels(*m8.values0, X)) - shift).max() < 1e-9 and np.abs(shift).max() > 0.01
    prior = np.linalg.inv(table_error_prior(kin.params))

    def trace(unknowns):
        b = position_bound(kin, prior, "p04", PAIR, MAP, X, seen, cam.project, cam.size, 0.2, unknowns=unknowns)
        return np.trace(b["cov_pos"])

    exact = trace(None)
    assert trace(Unknowns(cam.K, np.eye(4) * 1e-10)) == pytest.approx(exact, rel=1e-9)
    small, large = trace(Unknowns(cam.K, np.eye(4) * 1.0)), trace(Unknowns(cam.K, np.eye(4) * 100.0))
    assert exact < small < large
    assert trace(Unknowns(R0_free=True)) >= exact * (1 - 1e-9)
    assert trace(Unknowns(cam.K, np.eye(4) * 100.0, R0_free=True)) >= large * (1 - 1e-9)
    # the distortion under a prior: equal as it goes to zero, growing with it
    assert trace(Unknowns(cam.K, cov_dist=np.eye(4) * 1e-16)) == pytest.approx(exact, rel=1e-9)
    assert exact < trace(Unknowns(cam.K, cov_dist=np.diag([0.3, 0.3, 0.03, 0.03]) ** 2))
    # the camera centre on the stage under a stated tolerance: the same
    assert trace(Unknowns(offset_sigma=np.full(3, 1e-9))) == pytest.approx(exact, rel=1e-9)
    assert exact < trace(Unknowns(offset_sigma=np.full(3, 1e-3)))
    # d_o moves every camera centre by R_table_mount d_o and leaves the rotations
    d_o = np.array([1e-3, -2e-3, 5e-4])
    T0v, T1v = model.camera_poses(*model.values0), model.camera_poses(*model.values0[:5], d_o)
    R_tm = T0v[:, :3, :3] @ kin.T_mount_cam[:3, :3].T
    assert np.abs(T1v[:, :3, 3] - T0v[:, :3, 3] - R_tm @ d_o).max() < 1e-15
    assert np.array_equal(T1v[:, :3, :3], T0v[:, :3, :3])


def test_model_floor_is_zero_for_a_central_camera(scene):
    """The floor's estimator on noise-free features: exact (1e-9 m) through a central lens (no port, no warp), where
    the best central camera is the lens itself."""
    kin, _, cam, X, seen = scene
    T_mc = kin.T_mount_cam
    config = PositioningConfig(reference="p04", intraocular_mm=(20.0, 40.0), map_min_baseline_m=0.03,
                               methods=("lms_ratio",))
    floor, fails, misfit = floor_positions(kin, X, seen, cam, None, None, TableSpec(T_mc[:3, 3].copy()),
                                           T_mc[:3, :3], config)
    assert fails == 0 and misfit == 0.0 and sorted(floor) == [20.0, 40.0]
    assert max(np.abs(e).max() for e in floor.values()) < 1e-9


def test_model_floor_through_a_flat_port(scene):
    """Behind a flat port the floor's central camera is placed where it was fitted (its pose in the lens frame moved
    onto the stage): its misfit to the true optics is small (0.12 px here, against 5 px for the same camera left at
    the lens centre) and the estimates all succeed. Scored against the lens centres, as the run is, each estimate
    errs by what the port's virtual centre ``t`` (6.7 mm ahead of the lens here) does over the pair's rotation
    against the reference, ``(R_a - R_ref) t``: in x within 25 % of it, pair by pair."""
    from bench.geometry.transforms import invert
    from bench.scenario.bounds import best_central_camera
    from bench.sim.optics_presets import optics_preset

    kin, _, _, X, seen = scene
    lens = load_preset("underwater_in_air")
    port = optics_preset("underwater_in_water").port
    T_mc = kin.T_mount_cam
    config = PositioningConfig(reference="p04", intraocular_mm=(20.0, 40.0), map_min_baseline_m=0.03,
                               methods=("lms_ratio",))
    floor, fails, misfit = floor_positions(kin, X, seen, lens, port, None, TableSpec(T_mc[:3, 3].copy()),
                                           T_mc[:3, :3], config)
    assert fails == 0 and misfit < 0.3
    e = np.concatenate(list(floor.values()))
    assert 1e-7 < np.abs(e).max() < 5e-4
    T0 = model_poses(kin)
    depths = np.concatenate([transform_points(invert(T0[n]), X)[:, 2] for n in NAMES])
    _, T_lc = best_central_camera(lens, port, (depths.min(), depths.max()))
    terms = {n: (T0[n][:3, :3] - T0["p04"][:3, :3]) @ T_lc[:3, 3] for n in NAMES if n != "p04"}
    for errors in floor.values():
        a = [min(terms, key=lambda n: np.linalg.norm(err - terms[n])) for err in errors]
        assert len(set(a)) == len(a)  # one pair per first view at each d_o
        for err, n in zip(errors, a, strict=True):
            assert abs(err[0] - terms[n][0]) < 0.25 * abs(terms[n][0]) and abs(terms[n][0]) > 1e-4


def test_corner_noise_measurement():
    """Corner localisation noise against the true projections: sigma recovered from 2000 noisy corners (5 %), zero
    when exact, gross errors left out."""
    rng = np.random.default_rng(85)
    uv = rng.uniform(0, 600, (1000, 2))
    noisy = uv + rng.normal(0, 0.15, uv.shape)
    noisy[:20] += 40.0  # gross errors
    sigma, bias, n = point_sigma_px(noisy, uv)
    assert sigma == pytest.approx(0.15, rel=0.05) and n == 980 and np.abs(bias).max() < 0.02
    assert point_sigma_px(uv, uv)[0] == 0.0
