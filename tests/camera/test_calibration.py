"""Camera calibration (thesis §3.3, Eq. 67-76, 196): exactness, Jacobian, Monte Carlo, OpenCV, real webcam data."""

import glob
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy import stats

from bench.camera import calibration as cal
from bench.camera import dlt
from bench.camera.plots import plot_residual_vectors
from bench.geometry.quaternion import rotation_vector_to_matrix
from bench.geometry.transforms import homogeneous, rot_x, rot_y, rot_z

SIZE = (640, 480)
WEBCAM = Path(__file__).resolve().parents[1] / "data" / "real_webcam_chessboard"  # see its PROVENANCE.md


def board_points(n=8, pitch=0.03):
    g = np.arange(n) * pitch
    a, b = np.meshgrid(g, g)
    return np.column_stack([a.ravel(), b.ravel(), np.zeros(a.size)])


def rig_points(n=6, pitch=0.03):
    """Two perpendicular planes, as the thesis's rig (Figure 19)."""
    g = (np.arange(n) + 1) * pitch
    a, b = np.meshgrid(g, g)
    a, b = a.ravel(), b.ravel()
    return np.vstack([np.column_stack([a, np.zeros_like(a), b]), np.column_stack([np.zeros_like(a), a, b])])


def project_cv(K, dist, T, X):
    """Reference projection by OpenCV (independent of our model code); OpenCV ignores ``K[0, 1]``, added here."""
    rvec = cv2.Rodrigues(T[:3, :3])[0]
    uv = cv2.projectPoints(X, rvec, T[:3, 3], K, dist)[0].reshape(-1, 2)
    y_d = (uv[:, 1] - K[1, 2]) / K[1, 1]
    uv[:, 0] += K[0, 1] * y_d
    return uv


def random_views(rng, K, dist, X, n_views, distance=0.6, tilt=0.35, margin=15):
    """Views of ``X`` fully inside the image (rejection sampling): lists of object points, pixels, poses."""
    Xs, uvs, Ts = [], [], []
    while len(Xs) < n_views:
        R = rot_x(np.pi + rng.normal(0, tilt)) @ rot_y(rng.normal(0, tilt)) @ rot_z(rng.uniform(-np.pi, np.pi))
        T = homogeneous(R, -R @ X.mean(axis=0) + [rng.normal(0, 0.02), rng.normal(0, 0.02),
                                                   distance + rng.normal(0, 0.05)])
        uv = project_cv(K, dist, T, X)
        if uv.min() < margin or uv[:, 0].max() > SIZE[0] - margin or uv[:, 1].max() > SIZE[1] - margin:
            continue
        Xs.append(X.copy())
        uvs.append(uv)
        Ts.append(T)
    return Xs, uvs, np.array(Ts)


TRUE_K = np.array([[702.5, 0.0, 327.25], [0.0, 698.75, 236.5], [0.0, 0.0, 1.0]])
TRUE_DIST = np.array([-0.21, 0.085, 6e-4, -4e-4, 0.0])


def test_jacobian_matches_finite_differences():
    rng = np.random.default_rng(21)
    K = TRUE_K.copy()
    K[0, 1] = 1.5
    dist = np.array([-0.2, 0.1, 1e-3, -2e-3, 0.02])
    Xs, uvs, Ts = random_views(rng, K, dist, rig_points(), 2)
    for model, k3 in [("heikkila", True), ("heikkila", False), ("radial", True), ("pinhole", False)]:
        problem = cal._Problem(Xs, [uv + rng.normal(0, 0.3, uv.shape) for uv in uvs], model, k3, fit_skew=True)
        names = cal.distortion_names(model, k3)
        d = np.array([dict(zip(["k1", "k2", "p1", "p2", "k3"], dist, strict=True))[n] for n in names])
        Tp = Ts @ homogeneous(rotation_vector_to_matrix(rng.normal(0, 0.01, (2, 3))), rng.normal(0, 1e-3, (2, 3)))
        s = cal._State(K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1], d, Tp[:, :3, :3], Tp[:, :3, 3])
        _, J = problem.residuals(s, jacobian=True)
        J_fd = np.empty_like(J)
        for j in range(problem.n_params):
            h = 1e-6 * (abs(problem.intrinsic_vector(s)[j]) + 1.0) if j < problem.n_intr else 1e-7
            e = np.zeros(problem.n_params)
            e[j] = h
            plus, minus = problem.residuals(problem.apply_step(s, e)), problem.residuals(problem.apply_step(s, -e))
            J_fd[:, j] = (plus - minus) / (2 * h)
        scale = np.abs(J).max(axis=0) + 1e-12
        assert np.max(np.abs(J - J_fd) / scale) < 1e-6, model


def test_model_projection_matches_opencv():
    # our forward model (bench.camera.model's distortion + pose + K) against cv2.projectPoints
    rng = np.random.default_rng(22)
    Xs, uvs, Ts = random_views(rng, TRUE_K, TRUE_DIST, board_points(), 3)
    problem = cal._Problem(Xs, uvs, "heikkila", True, fit_skew=False)
    s = cal._State(*TRUE_K[[0, 1, 0, 1], [0, 1, 2, 2]], 0.0, TRUE_DIST.copy(), Ts[:, :3, :3], Ts[:, :3, 3])
    assert np.abs(problem.residuals(s)).max() < 1e-9


@pytest.mark.parametrize("model,k3,fit_skew,target", [
    ("heikkila", False, False, "board"),
    ("heikkila", True, True, "board"),
    ("radial", False, False, "board"),
    ("pinhole", False, True, "rig"),
    ("heikkila", False, True, "rig"),
])
def test_noise_free_calibration_recovers_truth(model, k3, fit_skew, target):
    rng = np.random.default_rng(23)
    K = TRUE_K.copy()
    if fit_skew:
        K[0, 1] = -2.0
    dist = TRUE_DIST.copy()
    if model != "heikkila":
        dist[2:4] = 0.0
    if model == "pinhole":
        dist[:] = 0.0
    if k3:
        dist[4] = 0.03
    X = board_points() if target == "board" else rig_points()
    Xs, uvs, Ts = random_views(rng, K, dist, X, 6 if target == "board" else 2)
    r = cal.calibrate_camera(Xs, uvs, SIZE, model, k3=k3, fit_skew=fit_skew)
    assert r.success, r.message
    assert np.abs(r.K - K).max() / K[0, 0] < 1e-8
    assert np.abs(r.dist - dist).max() < 1e-8
    assert np.abs(r.T_cam_target - Ts).max() < 1e-8
    assert r.rms_px < 1e-8 and r.per_view_rms_px.shape == (len(Xs),)
    assert r.parameter_names[:4] == ["fx", "fy", "cx", "cy"]


def test_monte_carlo_errors_match_reported_standard_errors():
    """sigma = 0.2 px: the intrinsic errors, normalised by the reported covariance, are chi-square distributed."""
    rng = np.random.default_rng(24)
    Xs, uvs, _ = random_views(rng, TRUE_K, TRUE_DIST, board_points(7), 5)
    truth = np.concatenate([TRUE_K[[0, 1, 0, 1], [0, 1, 2, 2]], TRUE_DIST[:4]])
    draws, maha, z = 30, [], []
    for _ in range(draws):
        noisy = [uv + rng.normal(0, 0.2, uv.shape) for uv in uvs]
        r = cal.calibrate_camera(Xs, noisy, SIZE, "heikkila")
        assert r.success, r.message
        e = r.parameters - truth
        maha.append(e @ np.linalg.solve(r.covariance, e))
        z.append(e / r.std)
        assert r.sigma_px == pytest.approx(0.2, rel=0.15)
    p = len(truth)
    total = float(np.sum(maha))  # ~ chi2(p * draws) if the covariance is right
    lo, hi = stats.chi2.ppf([0.001, 0.999], p * draws)
    assert lo < total < hi, (total, lo, hi)
    # per parameter: mean of z^2 ~ chi2(draws) / draws
    lo1, hi1 = stats.chi2.ppf([0.0005, 0.9995], draws) / draws
    zz = np.mean(np.square(z), axis=0)
    assert np.all((zz > lo1) & (zz < hi1)), zz


def test_same_optimum_as_opencv_on_synthetic_data():
    rng = np.random.default_rng(25)
    Xs, uvs, _ = random_views(rng, TRUE_K, TRUE_DIST, board_points(), 8)
    # detections as float32, like findChessboardCornersSB returns them (OpenCV only takes float32)
    noisy = [(uv + rng.normal(0, 0.2, uv.shape)).astype(np.float32).astype(float) for uv in uvs]
    for model in ("heikkila", "radial", "pinhole"):
        ours = cal.calibrate_camera(Xs, noisy, SIZE, model)
        ref = cal.opencv_reference(Xs, noisy, SIZE, model)
        assert ours.success and ref.success, (ours.message, ref.message)
        assert abs(ours.rms_px - ref.rms_px) < 1e-6, model
        assert ours.rms_px <= ref.rms_px + 1e-9
        assert np.abs(ours.K - ref.K).max() < 1e-3, model
        assert np.abs(ours.dist - ref.dist).max() < 1e-5, model


def test_gauss_newton_step_is_the_least_squares_solution():
    rng = np.random.default_rng(31)
    J = rng.normal(size=(40, 6)) * np.array([1e3, 1.0, 1e-3, 5.0, 1e2, 0.1])  # badly scaled columns
    r = rng.normal(size=40)
    step, decrease = cal.gauss_newton_step(J, r)
    x = np.linalg.lstsq(J, -r, rcond=None)[0]
    assert np.allclose(step, x, rtol=1e-8, atol=0)
    # the predicted decrease is the exact decrease of a linear problem
    assert decrease == pytest.approx(0.5 * (r @ r) - 0.5 * np.sum((r + J @ step) ** 2), rel=1e-9)


def test_converges_where_the_step_criterion_random_walks(monkeypatch):
    """Corners of a realistic-imaging rig campaign (camera_calibration_webcam at rig.distance_mm 1000, seed 8, thesis
    extractor): LM reaches the optimum in ~28 iterations and then stepped at rounding level (~1e-10 relative, above
    the 1e-12 step tolerance) until 200 iterations ran out; the Gauss-Newton decrease criterion stops it there."""
    data = np.load(Path(__file__).resolve().parents[1] / "data" / "calibration" / "realistic_webcam_rig_seed8.npz")
    arrays = [data[f"arr_{i}"] for i in range(len(data.files))]
    Xs, uvs = arrays[: len(arrays) // 2], arrays[len(arrays) // 2:]
    r = cal.calibrate_camera(Xs, uvs, SIZE, "heikkila")
    assert r.success and "Gauss-Newton" in r.message and r.iterations < 60, (r.message, r.iterations)
    # at the optimum: no step (Gauss-Newton or damped) lowers the cost measurably, and the gradient is ~0
    problem = cal._Problem(Xs, uvs, "heikkila", False, False)
    s = cal._State(r.K[0, 0], r.K[1, 1], r.K[0, 2], r.K[1, 2], 0.0, r.dist[:4].copy(), r.T_cam_target[:, :3, :3].copy(),
                   r.T_cam_target[:, :3, 3].copy())
    res, J = problem.residuals(s, jacobian=True)
    assert 0.5 * res @ res == pytest.approx(r.cost, rel=1e-12)
    assert cal.gauss_newton_step(J, res)[1] < 1e-12 * r.cost
    assert r.rms_px == pytest.approx(0.2913, abs=1e-4)  # the realistic rig images' calibration residual
    # the step criterion alone (decrease and creep tolerances 0) runs out of iterations at the same optimum
    monkeypatch.setattr(cal, "GN_DECREASE_TOL", 0.0)
    monkeypatch.setattr(cal, "CREEP_TOL", 0.0)
    stuck = cal.calibrate_camera(Xs, uvs, SIZE, "heikkila", max_iterations=60, initial=(r.K, r.dist, r.T_cam_target))
    assert not stuck.success and "not converged" in stuck.message
    assert stuck.rms_px == pytest.approx(r.rms_px, rel=1e-10)


@pytest.mark.parametrize("name, image_size", [("realistic_webcam_rig_seed9", (640, 480)),
                                              ("realistic_underwater_rig_seed14", (640, 480))])
def test_converges_along_a_flat_valley(name, image_size):
    """Rig corners where LM creeps along a flat, curved valley: every step lowers the cost as the Gauss-Newton model
    predicts and the next points elsewhere. camera_calibration_webcam seed 9 (realistic imaging, the radial-only
    webcam lens, the thesis's extractor; ``bench sim render scenarios/camera_calibration_webcam.yaml --seed 9 --set
    rig.distance_mm=1000``) took 366 iterations to the Gauss-Newton criterion; xy_table_underwater seed 14 (OpenCV's
    corners of its calibration views) 4,493 (55 s). Both failed at the old cap of 200 ("not converged"). The creep
    criterion stops them once 50 iterations move the estimate by < 0.01 standard deviations, at OpenCV's optimum."""
    data = np.load(Path(__file__).resolve().parents[1] / "data" / "calibration" / f"{name}.npz")
    arrays = [data[f"arr_{i}"] for i in range(len(data.files))]
    Xs, uvs = arrays[: len(arrays) // 2], [u.astype(float) for u in arrays[len(arrays) // 2:]]
    r = cal.calibrate_camera(Xs, uvs, image_size, "heikkila")
    assert r.success and "standard deviations" in r.message and r.iterations < 400, (r.message, r.iterations)
    ref = cal.opencv_reference(Xs, uvs, image_size, "heikkila")
    assert r.rms_px == pytest.approx(ref.rms_px, rel=1e-7)  # OpenCV's optimum (OpenCV stops at 30 iterations)
    sd = np.sqrt(np.diag(r.covariance))[:4]
    assert np.all(np.abs(r.parameters[:4] - np.array([ref.K[0, 0], ref.K[1, 1], ref.K[0, 2], ref.K[1, 2]])) < 0.05 * sd)


def test_degenerate_inputs_fail_clearly():
    rng = np.random.default_rng(26)
    Xs, uvs, _ = random_views(rng, TRUE_K, TRUE_DIST, board_points(), 3)
    line = np.column_stack([np.arange(10.0) * 0.01, np.zeros(10), np.zeros(10)])
    r = cal.calibrate_camera([line] + Xs[1:], [uvs[0][:10]] + uvs[1:], SIZE)
    assert not r.success and "collinear" in r.message and "object_points[0]" in r.message
    r = cal.calibrate_camera(Xs[:1], uvs[:1], SIZE)
    assert not r.success and "planar target" in r.message
    bad = uvs[1].copy()
    bad[5, 0] = np.nan
    with pytest.raises(ValueError, match=r"image_points\[1\]: contains NaN"):
        cal.calibrate_camera(Xs, [uvs[0], bad, uvs[2]], SIZE)
    with pytest.raises(ValueError, match="model"):
        cal.calibrate_camera(Xs, uvs, SIZE, "fisheye")
    with pytest.raises(ValueError, match="image_size"):
        cal.calibrate_camera(Xs, uvs, (640,))
    with pytest.raises(ValueError, match="views"):
        cal.calibrate_camera(Xs, uvs[:2], SIZE)
    with pytest.raises(ValueError, match=r"object_points\[0\]: expected shape \(N, 3\)"):
        cal.calibrate_camera([X[:, :2] for X in Xs], uvs, SIZE)
    # OpenCV's (N, 1, 2) layout is accepted
    assert cal.calibrate_camera(Xs, [uv[:, None, :] for uv in uvs], SIZE, "pinhole").success


def test_table3_per_view_pinhole_on_the_rig():
    rng = np.random.default_rng(27)
    K = TRUE_K.copy()
    K[0, 1] = -1.0
    Xs, uvs, _ = random_views(rng, K, np.zeros(5), rig_points(), 3)
    rows = cal.per_view_pinhole(Xs + [board_points()], uvs + [uvs[0][: len(board_points())]])
    alpha, beta, theta, u0, v0 = dlt.thesis_parameters(K)
    for row in rows[:3]:
        assert row["alpha_px"] == pytest.approx(alpha, rel=1e-9) and row["beta_px"] == pytest.approx(beta, rel=1e-9)
        assert row["theta_deg"] == pytest.approx(np.degrees(theta), rel=1e-9) and row["chi_px"] < 1e-9
    assert np.isnan(rows[3]["alpha_px"]) and "plane" in rows[3]["note"]


def detect_webcam_views():
    """7x7 inner corners, unit squares; OpenCV's SB detector (corner extraction itself is another module's)."""
    files = sorted(glob.glob(str(WEBCAM / "*.jpg")))
    obj = np.zeros((49, 3))
    obj[:, :2] = np.mgrid[0:7, 0:7].T.reshape(-1, 2)
    Xs, uvs = [], []
    for f in files:
        ok, c = cv2.findChessboardCornersSB(cv2.imread(f, cv2.IMREAD_GRAYSCALE), (7, 7), flags=cv2.CALIB_CB_ACCURACY)
        assert ok, f
        Xs.append(obj.copy())
        uvs.append(c.reshape(-1, 2).astype(float))
    return files, Xs, uvs


def test_real_webcam_calibration_no_worse_than_opencv(tmp_path):
    files, Xs, uvs = detect_webcam_views()
    assert len(files) == 19
    ours = cal.calibrate_camera(Xs, uvs, SIZE, "heikkila")
    ref = cal.opencv_reference(Xs, uvs, SIZE, "heikkila")
    assert ours.success, ours.message
    assert ours.rms_px < 0.6  # measured 0.5570 px (JPEG webcam, hand-held board)
    assert ours.rms_px <= ref.rms_px + 1e-6
    assert np.abs(ours.K - ref.K).max() < 1e-3 and np.abs(ours.dist - ref.dist).max() < 1e-6
    assert np.all(ours.std[:4] < 10.0)  # focal lengths and principal point to a few px (speed: make benchmark)
    # the symmetric board: a relabelling of a view by any symmetry of the square grid (rotation or reflection) is
    # absorbed by that view's pose (a reflection of a planar grid is a 180-degree turn about an in-plane axis)
    rng = np.random.default_rng(28)
    relabelled = []
    for uv in uvs:
        grid = uv.reshape(7, 7, 2)
        grid = np.rot90(grid, k=int(rng.integers(4)))
        relabelled.append((grid.transpose(1, 0, 2) if rng.integers(2) else grid).reshape(-1, 2))
    again = cal.calibrate_camera(Xs, relabelled, SIZE, "heikkila")
    assert again.success and abs(again.rms_px - ours.rms_px) < 1e-9
    assert np.abs(again.K - ours.K).max() < 1e-6
    camera = ours.camera
    assert camera.model == "heikkila" and np.allclose(camera.K, ours.K) and (camera.width, camera.height) == SIZE
    png = plot_residual_vectors(tmp_path / "residuals.png", uvs[0], ours.residuals_px[0],
                                image=cv2.imread(files[0]), rms_px=ours.per_view_rms_px[0])
    assert png.stat().st_size > 10_000



def test_jackknife_views_matches_formal_errors_for_independent_noise_and_exceeds_them_for_correlated():
    """Independent corner noise: the leave-one-view-out spread agrees with sigma^2 (J^T J)^-1 (within the scatter of
    a 6-view jackknife); an error shared by all corners of a view (each view's image scaled about its centre, as a
    mis-rendered or warped board would be) is invisible to the formal errors but not to the jackknife."""
    rng = np.random.default_rng(31)
    K = np.array([[820.0, 0, 318.0], [0, 815.0, 243.0], [0, 0, 1]])
    dist = np.array([-0.2, 0.08, 1e-3, -5e-4, 0.0])
    Xs, uvs, _ = random_views(rng, K, dist, rig_points(4), 6)
    noisy = [uv + rng.normal(0, 0.05, uv.shape) for uv in uvs]
    res = cal.calibrate_camera(Xs, noisy, SIZE)
    jk, est = cal.jackknife_views(Xs, noisy, SIZE, result=res)
    assert est.shape == (6, 8) and np.all(np.isfinite(jk))
    # the leave-one-out fits start from the full one: a warm start reaches the same optimum as the linear start
    again = cal.calibrate_camera(Xs, noisy, SIZE, initial=(res.K, res.dist, res.T_cam_target))
    assert np.allclose(again.parameters, res.parameters, rtol=1e-9, atol=1e-12)
    with pytest.raises(ValueError, match=r"initial: expected shapes"):
        cal.calibrate_camera(Xs, noisy, SIZE, initial=(res.K, res.dist, res.T_cam_target[:2]))
    ratio = jk / res.std
    assert 0.5 < np.exp(np.mean(np.log(ratio))) < 2.0 and np.all((ratio > 0.25) & (ratio < 4.0)), ratio
    scaled = [(uv - uv.mean(0)) * (1 + rng.normal(0, 3e-3)) + uv.mean(0) + rng.normal(0, 0.02, uv.shape)
              for uv in uvs]
    res2 = cal.calibrate_camera(Xs, scaled, SIZE)
    jk2, _ = cal.jackknife_views(Xs, scaled, SIZE)
    assert np.all(jk2[:2] > 2.5 * res2.std[:2])  # fx, fy: the per-view scale errors are focal-length errors (3x)
    one, _ = cal.jackknife_views(Xs[:1], uvs[:1], SIZE)
    assert np.all(np.isnan(one))


def test_opencv_reference_is_the_same_from_call_to_call():
    """cv2.calibrateCamera sums over views on several threads: on 2 threads the same detections gave intrinsics
    ~1e-6 px apart from call to call (found by the lean pass). The reference runs on one thread: identical."""
    import cv2

    from bench.camera.calibration import opencv_reference
    from bench.camera.photo_stats import board_points, detect_views, photo_paths

    views = detect_views(photo_paths(Path(__file__).parents[1] / "data" / "real_webcam_chessboard")[:8], (7, 7))
    Xs, uvs = [board_points((7, 7))] * len(views), [v.uv for v in views]
    threads = cv2.getNumThreads()
    cv2.setNumThreads(2)
    try:
        Ks = [opencv_reference(Xs, uvs, views[0].grey.shape[::-1]).K for _ in range(4)]
        assert cv2.getNumThreads() == 2  # restored
    finally:
        cv2.setNumThreads(threads)
    assert all(np.array_equal(K, Ks[0]) for K in Ks)
