"""The projection chain (Eq. 46-51, 67-68, 75-76) against OpenCV, its inverses, and bad input."""

import cv2
import numpy as np
import pytest

from bench.camera.model import (
    CameraModel,
    check_dist,
    check_K,
    distort,
    distortion_jacobian,
    from_pixels,
    model_of,
    project_pinhole,
    radial_eq67,
    random_camera_model,
    to_pixels,
    undistort,
    unproject_pinhole,
)
from bench.camera.presets import load_preset


def _points(rng, n=2000):
    return np.column_stack([rng.uniform(-1.2, 1.2, (n, 2)), rng.uniform(1.5, 4.0, n)])


def test_projection_matches_opencv_project_points():
    rng = np.random.default_rng(11)
    worst = 0.0
    for i in range(20):
        cam = random_camera_model(rng, model=("heikkila", "radial", "pinhole")[i % 3], skew=False, k3=i % 2 == 0)
        p_cam = _points(rng)
        ref = cv2.projectPoints(p_cam, np.zeros(3), np.zeros(3), cam.K, cam.dist)[0][:, 0]
        worst = max(worst, np.max(np.abs(cam.project(p_cam) - ref)))
    assert worst <= 1e-9


def test_projection_with_skew_is_opencv_plus_shear():
    # OpenCV's functions ignore K[0, 1]; with skew the pixel is u = fx x_d + skew y_d + cx (Eq. 49-50)
    rng = np.random.default_rng(12)
    cam = random_camera_model(rng, skew=True)
    assert cam.skew != 0
    p_cam = _points(rng)
    K0 = cam.K.copy()
    K0[0, 1] = 0.0
    ref = cv2.projectPoints(p_cam, np.zeros(3), np.zeros(3), K0, cam.dist)[0][:, 0]
    ref[:, 0] += cam.skew * (ref[:, 1] - cam.cy) / cam.fy
    assert np.max(np.abs(cam.project(p_cam) - ref)) <= 1e-9


def test_undistort_matches_opencv_and_inverts_distort():
    rng = np.random.default_rng(13)
    for _ in range(10):
        cam = random_camera_model(rng, skew=False, k3=True)
        uv = np.column_stack([rng.uniform(0, cam.width - 1, 500), rng.uniform(0, cam.height - 1, 500)])
        res = undistort(from_pixels(uv, cam.K), cam.dist, full_output=True)
        assert res.success and res.max_residual <= 1e-12
        # OpenCV's fixed-point iteration, run to its own convergence
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
        ref = cv2.undistortPoints(uv.reshape(-1, 1, 2), cam.K, cam.dist, criteria=crit)[:, 0]
        assert np.max(np.abs(res.x_n - ref)) * cam.fx <= 1e-6
        # exact inverse of the forward model
        assert np.max(np.abs(to_pixels(distort(res.x_n, cam.dist), cam.K) - uv)) <= 1e-9


def test_unproject_then_project_is_identity_and_rays_are_unit():
    rng = np.random.default_rng(14)
    cam = random_camera_model(rng)
    uv = np.column_stack([rng.uniform(-0.5, cam.width - 0.5, (3, 400)).ravel(),
                          rng.uniform(-0.5, cam.height - 0.5, (3, 400)).ravel()]).reshape(3, 400, 2)
    rays = cam.unproject(uv)
    assert rays.shape == (3, 400, 3)
    assert np.allclose(np.linalg.norm(rays, axis=-1), 1.0, atol=1e-15)
    assert np.max(np.abs(cam.project(2.5 * rays) - uv)) <= 1e-9


@pytest.mark.parametrize("preset", ["underwater_in_air", "underwater_in_water"])
def test_distort_undistort_round_trip_over_the_whole_image(preset):
    cam = load_preset(preset)
    uu, vv = np.meshgrid(np.linspace(-0.5, cam.width - 0.5, 641), np.linspace(-0.5, cam.height - 0.5, 481))
    uv = np.stack([uu, vv], axis=-1)
    res = undistort(from_pixels(uv, cam.K), cam.dist, full_output=True)
    assert res.success and res.max_residual <= 1e-12
    back = to_pixels(distort(res.x_n, cam.dist), cam.K)
    err = np.max(np.linalg.norm(back - uv, axis=-1))
    print(f"{preset}: distortion_roundtrip_max_px = {err:.3e}")
    assert err <= 1e-8  # the brief's requirement is 0.02 px
    # and the other direction: ideal points -> distorted -> ideal
    x_n = res.x_n[::10, ::10]
    assert np.max(np.abs(undistort(distort(x_n, cam.dist), cam.dist) - x_n)) * cam.fx <= 1e-8


def test_distortion_jacobian_by_finite_differences():
    rng = np.random.default_rng(15)
    cam = random_camera_model(rng, k3=True)
    x = rng.uniform(-0.6, 0.6, (50, 2))
    J = distortion_jacobian(x, cam.dist)
    h = 1e-6
    for j in range(2):
        dx = np.zeros(2)
        dx[j] = h
        fd = (distort(x + dx, cam.dist) - distort(x - dx, cam.dist)) / (2 * h)
        assert np.max(np.abs(J[:, :, j] - fd)) <= 1e-8


def test_pixels_round_trip_with_skew_and_eq50():
    K = np.array([[975.3, -3.1, 329.3], [0.0, 970.2, 236.9], [0.0, 0.0, 1.0]])
    rng = np.random.default_rng(16)
    x = rng.normal(size=(4, 7, 2))
    assert np.max(np.abs(from_pixels(to_pixels(x, K), K) - x)) <= 1e-14
    xh = np.concatenate([x, np.ones(x.shape[:-1] + (1,))], axis=-1)
    assert np.max(np.abs(to_pixels(x, K) - (xh @ K.T)[..., :2])) <= 1e-12  # Eq. 50


def test_radial_eq67_equals_the_chain_with_skew():
    rng = np.random.default_rng(17)
    K = np.array([[800.0, 2.5, 320.0], [0.0, 790.0, 240.0], [0.0, 0.0, 1.0]])
    uv = rng.uniform(0, 600, (100, 2))
    k1, k2 = -0.21, 0.05
    ref = to_pixels(distort(from_pixels(uv, K), [k1, k2, 0, 0]), K)
    assert np.max(np.abs(radial_eq67(uv, K, k1, k2) - ref)) <= 1e-9


def test_pinhole_stage_and_points_behind():
    p = np.array([[0.1, -0.2, 2.0], [0.0, 0.0, -1.0], [1.0, 1.0, 0.0]])
    x = project_pinhole(p)
    assert np.allclose(x[0], [0.05, -0.1]) and np.all(np.isnan(x[1:]))
    r = unproject_pinhole(x[:1], normalize=False)
    assert np.allclose(r, [[0.05, -0.1, 1.0]])


def test_models_and_validation_errors():
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    assert model_of([]) == "pinhole" and model_of([0.1, 0, 0, 0]) == "radial"
    assert model_of([0.1, 0, 1e-3, 0, 0]) == "heikkila"
    assert CameraModel(640, 480, K, [0.1, 0, 0, 0], model="heikkila").model == "heikkila"
    with pytest.raises(ValueError, match="model: 'radial' cannot hold"):
        CameraModel(640, 480, K, [0.1, 0, 1e-3, 0], model="radial")
    bad_f = K.copy()
    bad_f[0, 0] = -500.0
    with pytest.raises(ValueError, match="focal lengths"):
        CameraModel(640, 480, bad_f)
    bad_nan = K.copy()
    bad_nan[0, 2] = np.nan
    with pytest.raises(ValueError, match="K: contains NaN"):
        check_K(bad_nan)
    with pytest.raises(ValueError, match="dist: contains NaN"):
        check_dist([0.1, np.nan, 0, 0])
    with pytest.raises(ValueError, match="dist: expected 4 or 5"):
        check_dist([0.1, 0.2, 0.3])
    with pytest.raises(ValueError, match="width"):
        CameraModel(0, 480, K)
    with pytest.raises(ValueError, match="pixel_pitch"):
        CameraModel(640, 480, K, pixel_pitch=0.01)  # mm given for m
    with pytest.raises(ValueError, match="p_cam: contains NaN"):
        CameraModel(640, 480, K).project([[0.0, np.nan, 1.0]])
    with pytest.raises(ValueError, match="uv: expected shape"):
        CameraModel(640, 480, K).unproject(np.zeros((3, 3)))


def test_non_invertible_distortion_is_reported():
    K = np.array([[400.0, 0, 320], [0, 400, 240], [0, 0, 1]])
    cam = CameraModel(640, 480, K, [-0.6, 0.0, 0, 0])  # folds over at r^2 = 1/1.8, inside the image
    with pytest.raises(ValueError, match="dist: distortion"):
        cam.check_invertible()
    res = undistort(np.array([[0.9, 0.7]]), cam.dist, full_output=True)
    assert not res.success and np.all(np.isnan(res.x_n)) and "did not converge" in res.message
