"""The thesis's Heikkilä parameters (Eq. 74-86) and their mapping to OpenCV's K, dist."""

import numpy as np
import pytest

from bench.camera.heikkila import (
    THESIS_PIXEL_PITCH,
    HeikkilaParameters,
    camera_from_heikkila,
    eq75_as_printed,
    fit_implicit_inverse,
    heikkila_of,
    heikkila_project,
    heikkila_to_opencv,
    opencv_to_heikkila,
)
from bench.camera.model import distort, undistort
from bench.camera.presets import load_preset

TABLE9 = HeikkilaParameters(s_u=1.061, f=510.06e-5, u0=298.45, v0=229.20, k1=1.38e-2 * 1e6, k2=1.45e-3 * 1e12,
                            p1=9.20e-5 * 1e3, p2=2.28e-4 * 1e3)


def _random_params(rng):
    return HeikkilaParameters(s_u=rng.uniform(0.95, 1.1), f=rng.uniform(3e-3, 8e-3), u0=rng.uniform(280, 360),
                              v0=rng.uniform(200, 280), k1=rng.uniform(-5e3, 2e4), k2=rng.uniform(0, 2e9),
                              p1=rng.uniform(-0.5, 0.5), p2=rng.uniform(-0.5, 0.5),
                              pixel_pitch=rng.uniform(3e-6, 1.2e-5))


def test_heikkila_and_opencv_give_identical_pixels():
    rng = np.random.default_rng(21)
    worst = 0.0
    for _ in range(20):
        params = _random_params(rng)
        cam = camera_from_heikkila(params, 640, 480)
        p_cam = np.column_stack([rng.uniform(-0.4, 0.4, (500, 2)), rng.uniform(1.0, 3.0, 500)])
        worst = max(worst, np.max(np.abs(cam.project(p_cam) - heikkila_project(params, p_cam))))
    assert worst <= 1e-9


def test_mapping_round_trip_is_exact():
    rng = np.random.default_rng(22)
    for _ in range(20):
        params = _random_params(rng)
        back = opencv_to_heikkila(*heikkila_to_opencv(params), pixel_pitch=params.pixel_pitch)
        for key in ("s_u", "f", "u0", "v0", "k1", "k2", "p1", "p2", "pixel_pitch"):
            assert getattr(back, key) == pytest.approx(getattr(params, key), rel=1e-13, abs=1e-300)


def test_table9_in_opencv_form():
    K, dist = heikkila_to_opencv(TABLE9)
    f_mm = 5.1006
    assert np.allclose(K, [[1.061 * 510.06, 0, 298.45], [0, 510.06, 229.20], [0, 0, 1]], rtol=1e-14)
    assert np.allclose(dist, [1.38e-2 * f_mm**2, 1.45e-3 * f_mm**4, 9.20e-5 * f_mm, 2.28e-4 * f_mm, 0], rtol=1e-12)
    preset = load_preset("underwater_in_air")
    assert np.allclose(preset.K, K, rtol=1e-14) and np.allclose(preset.dist, dist, rtol=1e-12)
    assert heikkila_of(preset).f_px == pytest.approx(510.06, rel=1e-14)
    assert preset.pixel_pitch == THESIS_PIXEL_PITCH


def test_eq75_as_printed_differs_by_exactly_the_two_misprints():
    rng = np.random.default_rng(23)
    x_n = rng.uniform(-0.6, 0.6, (200, 2))
    cam = camera_from_heikkila(TABLE9, 640, 480)
    printed = eq75_as_printed(TABLE9, x_n)
    consistent = cam.project(np.concatenate([x_n, np.ones((200, 1))], axis=1))
    _, d = heikkila_to_opencv(TABLE9)
    u, v = x_n.T
    expected = np.column_stack([cam.fx * d[1] * (v**5 - u**5), cam.fy * d[0] * (u**2 * v**2 - u**2 * v)])
    assert np.max(np.abs(printed - consistent - expected)) <= 1e-9
    assert np.max(np.abs(printed - consistent)) > 1.0  # the misprints matter (px)


def test_implicit_inverse_corrected_beats_printed_and_iteration_beats_both():
    cam = load_preset("underwater_in_water")
    corrected = fit_implicit_inverse(cam)
    printed = fit_implicit_inverse(cam, as_printed=True)
    print(f"implicit inverse (Eq. 77-86) on Table 15: corrected max {corrected.max_px:.3f} px, "
          f"printed max {printed.max_px:.3f} px")
    assert corrected.max_px < printed.max_px
    # the exact inverse, for comparison, on the same kind of points
    rng = np.random.default_rng(24)
    x_n = rng.uniform(-0.4, 0.4, (500, 2))
    x_d = distort(x_n, cam.dist)
    err_iter = np.max(np.abs(undistort(x_d, cam.dist) - x_n)) * cam.fx
    err_impl = np.max(np.abs(corrected.apply(x_d) - x_n)) * cam.fx
    assert err_iter <= 1e-9 < err_impl
    # with mild distortion the implicit model is the good approximation Heikkilä intended
    mild = cam.replace(dist=cam.dist * 0.05)
    assert fit_implicit_inverse(mild).max_px < 0.01


def test_bad_heikkila_parameters():
    with pytest.raises(ValueError, match="f: focal length must be > 0"):
        HeikkilaParameters(s_u=1, f=0.0, u0=0, v0=0, k1=0, k2=0, p1=0, p2=0)
    with pytest.raises(ValueError, match="k1: must be finite"):
        HeikkilaParameters(s_u=1, f=5e-3, u0=0, v0=0, k1=np.nan, k2=0, p1=0, p2=0)
    with pytest.raises(ValueError, match="s_u"):
        HeikkilaParameters(s_u=-1, f=5e-3, u0=0, v0=0, k1=0, k2=0, p1=0, p2=0)
    K, dist = heikkila_to_opencv(TABLE9)
    K[0, 1] = 1.0
    with pytest.raises(ValueError, match="K: skew"):
        opencv_to_heikkila(K, dist)
    with pytest.raises(ValueError, match="pixel_pitch: needed"):
        heikkila_of(load_preset("underwater_in_air").replace(pixel_pitch=None))


def test_heikkila_jacobian_and_covariance():
    """The derivative of the OpenCV -> Heikkila map against central differences; the covariance is J C J^T."""
    from bench.camera.heikkila import heikkila_covariance, heikkila_jacobian, opencv_to_heikkila

    cam = load_preset("underwater_in_air")
    x0 = np.r_[cam.fx, cam.fy, cam.cx, cam.cy, cam.dist[:4]]

    def h(x):
        K = np.array([[x[0], 0, x[2]], [0, x[1], x[3]], [0, 0, 1]])
        p = opencv_to_heikkila(K, np.r_[x[4:], 0.0])
        return np.array([p.s_u, p.f, p.u0, p.v0, p.k1, p.k2, p.p1, p.p2])

    J = heikkila_jacobian(cam.K, cam.dist)
    Jn = np.empty((8, 8))
    for i in range(8):
        e = np.zeros(8)
        e[i] = 1e-6 * max(abs(x0[i]), 1e-3)
        Jn[:, i] = (h(x0 + e) - h(x0 - e)) / (2 * e[i])
    assert np.allclose(J, Jn, rtol=1e-7, atol=0)
    C = np.diag(np.r_[0.1, 0.1, 0.05, 0.05, 1e-4, 1e-3, 1e-5, 1e-5]) ** 2
    assert np.allclose(heikkila_covariance(cam.K, cam.dist, C), J @ C @ J.T)
    with pytest.raises(ValueError, match="cov_opencv"):
        heikkila_covariance(cam.K, cam.dist, np.eye(4))
