"""The printed target's tolerances (bench.camera.target_tolerance): parsing, the corners' covariance against the
simulator's own target errors (Monte Carlo), and the consider Monte Carlo."""

import numpy as np
import pytest

from bench.camera.corners import planar_board, two_plane_rig
from bench.camera.target_tolerance import (
    TargetTolerance,
    consider_covariance,
    consider_samples,
    object_point_covariance,
    parse_tolerance,
)
from bench.errors import ConfigError


def test_parse_tolerance_and_its_one_line_errors():
    t = parse_tolerance({"flatness_rms_mm": 0.4, "flatness_length_mm": [25, 17], "print_rms_mm": [0.05, 0.09],
                         "scale_rms_pct": 0.2, "fold_rms_deg": 0.2, "bow_sagitta_mm": 0.6}, "target.yaml")
    assert t.flatness_rms == pytest.approx(4e-4) and t.flatness_length == pytest.approx((0.025, 0.017))
    assert t.scale_rms == pytest.approx(0.002) and t.fold_rms == pytest.approx(np.deg2rad(0.2)) and t.any
    assert not parse_tolerance({}, "target.yaml").any
    for bad, field in (({"flatnes_rms_mm": 1}, "tolerance.flatnes_rms_mm"),
                       ({"print_rms_mm": 0.1}, "tolerance.print_rms_mm"),
                       ({"flatness_rms_mm": -1}, "tolerance.flatness_rms_mm"),
                       ({"flatness_rms_mm": float("nan")}, "tolerance.flatness_rms_mm"),
                       ({"flatness_length_mm": [0, 10]}, "tolerance.flatness_length_mm"),
                       ({"scale_rms_pct": True}, "tolerance.scale_rms_pct")):
        with pytest.raises(ConfigError) as e:
            parse_tolerance(bad, "target.yaml")
        assert e.value.field == field and "\n" not in str(e.value)
    with pytest.raises(ConfigError, match="tolerance"):
        parse_tolerance([1, 2], "target.yaml")


def test_target_yaml_carries_the_tolerance(tmp_path):
    from bench.camera.calibrate_dataset import load_target, load_target_tolerance

    p = tmp_path / "target.yaml"
    p.write_text("type: two_plane_rig\nsize_mm: 197\nmargin_mm: 20\ntolerance:\n  flatness_rms_mm: 0.4\n")
    assert load_target(p).n_corners == 72 and load_target_tolerance(p).flatness_rms == pytest.approx(4e-4)
    p.write_text("type: two_plane_rig\nsize_mm: 197\n")
    assert load_target_tolerance(p) is None
    p.write_text("type: chessboard\ninner: [7, 6]\nsquare_mm: 25\ntolerance:\n  wobble_mm: 1\n")
    with pytest.raises(ConfigError, match="tolerance.wobble_mm"):
        load_target(p)


def test_corner_covariance_is_the_simulated_rigs():
    """The pipeline's covariance of the rig's corners under the tolerances the simulator states equals the spread of
    the simulator's own printed rigs (2500 draws; the simulator and the pipeline share no code for it)."""
    from bench.sim.imaging import imaging_profile, stated_tolerance, target_geometry
    from bench.sim.scenes.rig import calibration_rig

    profile = imaging_profile("realistic")
    C = object_point_covariance(two_plane_rig(7, 0.197, 0.02), parse_tolerance(stated_tolerance(profile), "sim"))
    nominal = calibration_rig().features["corners"]
    rng = np.random.default_rng(11)
    D = np.array([(calibration_rig(errors=target_geometry(profile, 7, rng)).features["corners"] - nominal).ravel()
                  for _ in range(2500)])
    E = D.T @ D / len(D)
    d, e = np.sqrt(np.diag(C)), np.sqrt(np.diag(E))
    assert np.max(np.abs(e / d - 1)) < 0.08  # every coordinate's sigma (a 2500-draw estimate: 1.4 % rms)
    assert np.linalg.norm(E - C) / np.linalg.norm(C) < 0.06  # and the correlations


def test_covariance_pieces():
    g = planar_board((6, 5), 0.03)
    X = g.object_points()
    zero = object_point_covariance(g, TargetTolerance())
    assert not zero.any()
    # a scale moves every corner along its position from the pattern's outer corner
    C = object_point_covariance(g, TargetTolerance(scale_rms=0.01))
    p = (X + [0.03, 0.03, 0]).ravel() * 0.01
    assert np.allclose(C, np.outer(p, p), atol=1e-15)
    # flatness: out of plane only, rms on the diagonal
    C = object_point_covariance(g, TargetTolerance(flatness_rms=1e-3))
    assert np.allclose(np.diag(C)[2::3], 1e-6) and not np.diag(C)[0::3].any() and not np.diag(C)[1::3].any()
    # print offsets: the corners of one row move together along y
    C = object_point_covariance(g, TargetTolerance(print_rms=(0.0, 1e-4)))
    assert C[1, 3 * 5 + 1] == pytest.approx(1e-8) and C[1, 3 * 6 + 1] == 0.0  # same row (6 per row), next row


def test_consider_samples_calls_the_solver_with_perturbed_targets():
    g = two_plane_rig(7, 0.197, 0.02)
    X0 = g.object_points()
    Xs = [X0, X0[::2]]
    tol = TargetTolerance(flatness_rms=1e-3)

    def solve(Xs_m):
        assert len(Xs_m) == 2 and Xs_m[1].shape == (36, 3)
        assert np.allclose(Xs_m[1], Xs_m[0][::2])  # the same perturbed target in every view
        return (Xs_m[0] - X0).ravel()

    d = consider_samples(g, tol, Xs, solve, draws=400)
    assert d.shape == (400, 216)
    C = object_point_covariance(g, tol)
    assert np.sqrt(np.mean(d ** 2)) == pytest.approx(np.sqrt(np.trace(C) / 216), rel=0.05)
    assert len(consider_samples(g, tol, Xs, lambda Xs_m: None, draws=5)) == 0
    with pytest.raises(ValueError, match="not the target's corners"):
        consider_samples(g, tol, [X0 + 1e-3], solve, draws=1)


def test_consider_covariance_is_the_second_moment_and_refuses_too_few_runs():
    """The consider covariance is the second moment about zero of the runs' deviations (exactly, for a solve that
    returns known vectors); fewer than MIN_CONSIDER_DRAWS successful runs: a one-line error naming the file."""
    geometry = planar_board((4, 4), 0.02)
    Xs = [geometry.object_points()]
    tol = parse_tolerance({"print_rms_mm": [0.05, 0.05]}, "target.yaml")
    vectors = iter(np.arange(24, dtype=float).reshape(12, 2))
    cov, n = consider_covariance(geometry, tol, Xs, lambda _: next(vectors), draws=12)
    d = np.arange(24, dtype=float).reshape(12, 2)
    assert n == 12 and np.allclose(cov, d.T @ d / 12, rtol=0, atol=1e-12)
    with pytest.raises(ConfigError, match=r"rig/target.yaml: tolerance: only 0 of 12 calibrations"):
        consider_covariance(geometry, tol, Xs, lambda _: None, draws=12, source="rig/target.yaml")


def test_calibration_with_tolerance_predicts_the_spread_over_perturbed_rigs():
    """A camera calibrated on exact images of a rig that is not the nominal one errs by what the rig's tolerance
    predicts: over 100 rigs drawn from the tolerance (exact projections, nominal geometry in the calibration) the
    spread of fx, fy, cx, cy agrees with the consider covariance of 100 draws within 35 % (sampling: ~10 %; 300 and
    300 agree within 8 %); the formal covariance alone (no pixel noise: near zero) would call them all exact."""
    from bench.camera.calibration import calibrate_camera
    from bench.camera.target_tolerance import calibration_with_tolerance, sample_factor
    from bench.geometry.transforms import homogeneous, rot_x, rot_y, transform_points

    rng = np.random.default_rng(5)
    g = two_plane_rig(7, 0.197, 0.02)
    X0 = g.object_points()
    K = np.array([[975.0, 0.0, 322.0], [0.0, 970.0, 243.0], [0.0, 0.0, 1.0]])
    Rs = [rot_x(np.pi + 0.25 * a) @ rot_y(0.3 * b) for a, b in ((0, 0), (1, -1), (-1, 1), (1, 1), (-1, -1))]
    Ts = [homogeneous(R, np.array([0.02 * R[0, 0], 0.01, 0.95]) - R @ X0.mean(0)) for R in Rs]

    def project(X):
        p = np.stack([transform_points(T, X) for T in Ts])
        return [(K @ (q / q[:, 2:]).T).T[:, :2] for q in p]

    tol = TargetTolerance(flatness_rms=0.4e-3, flatness_length=(0.025, 0.017), print_rms=(0.05e-3, 0.09e-3))
    Xs = [X0] * len(Ts)
    cal = calibrate_camera(Xs, project(X0), (640, 480), model="pinhole")
    assert cal.success and np.abs(cal.K - K).max() < 1e-6  # exact on the nominal rig
    cal_t, C, n = calibration_with_tolerance(cal, g, tol, Xs, project(X0), draws=100)
    assert n == 100 and np.allclose(cal_t.covariance, cal.covariance + C) and np.all(cal_t.std > cal.std)
    L = sample_factor(object_point_covariance(g, tol))
    errs = []
    for _ in range(100):  # the true rig drawn from the tolerance; its exact images; the nominal rig in the solve
        X_true = X0 + (L @ rng.standard_normal(L.shape[1])).reshape(-1, 3)
        c = calibrate_camera(Xs, project(X_true), (640, 480), model="pinhole")
        errs.append(c.parameters - cal.parameters)
    spread, predicted = np.sqrt(np.mean(np.square(errs), axis=0)), cal_t.std
    assert cal.parameter_names == ["fx", "fy", "cx", "cy"] and np.all(cal.std < 1e-6 * predicted)
    assert np.all(np.abs(spread / predicted - 1) < 0.35), (spread, predicted)


def test_calibration_with_tolerance_refuses_a_failed_calibration_and_too_few_draws_and_keeps_k3():
    from dataclasses import replace

    from bench.camera.calibration import calibrate_camera
    from bench.camera.target_tolerance import MIN_CONSIDER_DRAWS, calibration_with_tolerance
    from bench.geometry.transforms import homogeneous, rot_x, rot_y, transform_points

    g = two_plane_rig(7, 0.197, 0.02)
    X0 = g.object_points()
    K = np.array([[975.0, 0.0, 322.0], [0.0, 970.0, 243.0], [0.0, 0.0, 1.0]])
    Rs = [rot_x(np.pi + 0.25 * a) @ rot_y(0.3 * b) for a, b in ((0, 0), (1, -1), (-1, 1), (1, 1))]
    uvs = []
    for R in Rs:
        p = transform_points(homogeneous(R, np.array([0.0, 0.01, 0.95]) - R @ X0.mean(0)), X0)
        uvs.append((K @ (p / p[:, 2:]).T).T[:, :2])
    Xs = [X0] * len(Rs)
    tol = TargetTolerance(print_rms=(0.05e-3, 0.05e-3))
    cal = calibrate_camera(Xs, uvs, (640, 480), model="radial", k3=True)
    assert cal.success and "k3" in cal.parameter_names
    # k3 is among the parameters even where its estimate is exactly zero: every draw fits it too
    cal0 = replace(cal, dist=np.r_[cal.dist[:4], 0.0])
    _, C, n = calibration_with_tolerance(cal0, g, tol, Xs, uvs, draws=MIN_CONSIDER_DRAWS)
    assert n == MIN_CONSIDER_DRAWS and C.shape == (len(cal.parameter_names),) * 2
    with pytest.raises(ValueError, match="draws: expected at least 10"):
        calibration_with_tolerance(cal, g, tol, Xs, uvs, draws=5)
    with pytest.raises(ValueError, match="the nominal calibration failed"):
        calibration_with_tolerance(replace(cal, success=False, message="not converged"), g, tol, Xs, uvs)


def test_sample_factor_is_the_same_whatever_basis_eigh_returns():
    """The two-plane rig's corner covariance has (numerically) repeated eigenvalues: an eigenvector factor
    ``V sqrt(W)`` is then any rotation within each repeated subspace, and a 1e-15 perturbation of the matrix (or
    another BLAS, or another thread count) changes every draw completely. The symmetric square root does not."""
    from bench.camera.target_tolerance import sample_factor

    g = two_plane_rig(7, 0.197, 0.02)
    tol = TargetTolerance(flatness_rms=0.42e-3, flatness_length=(0.025, 0.017), bow_sagitta=0.6e-3,
                          print_rms=(0.05e-3, 0.09e-3), scale_rms=0.002, fold_rms=np.deg2rad(0.2))
    C = object_point_covariance(g, tol)
    rng = np.random.default_rng(2)
    E = rng.standard_normal(C.shape)
    E = 0.5 * (E + E.T) * 1e-15 * np.abs(C).max()
    w = np.linalg.eigvalsh(C)
    big = np.sort(w[w > 1e-10 * w.max()])
    assert np.min(np.diff(big)) < 1e-12 * w.max()  # the premise: repeated eigenvalues
    z = rng.standard_normal(len(C))
    L = sample_factor(C)
    np.testing.assert_allclose(L @ L.T, C, atol=1e-9 * np.abs(C).max())
    d0, d1 = L @ z, sample_factor(C + E) @ z
    assert np.abs(d1 - d0).max() < 1e-5 * np.abs(d0).max()
