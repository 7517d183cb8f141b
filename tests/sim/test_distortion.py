"""The distortion stage: an exact inverse warp of a supersampled pinhole render (issue 3 item 4a)."""

import time

import numpy as np
import pytest

from bench.camera.model import from_pixels, to_pixels, undistort
from bench.camera.presets import load_preset
from bench.sim.distortion import DistortionStage, ideal_subsample_grid, render_K, subsample_coordinates

BG, AMP = 20.0, 200.0


def _blob_render(camera, spec, sigma_px, rng):
    """A render of Gaussian blobs drawn analytically in ideal coordinates; their known pixels in the target."""
    uu, vv = np.meshgrid(np.linspace(40, camera.width - 41, 8), np.linspace(40, camera.height - 41, 6))
    uv_true = np.stack([uu, vv], -1).reshape(-1, 2) + rng.uniform(-0.5, 0.5, (48, 2))
    x_c = undistort(from_pixels(uv_true, camera.K), camera.dist)  # ideal centres of the blobs
    sigma_n = sigma_px / camera.fy
    img = np.full((spec.height, spec.width), BG, dtype=np.float32)
    c_r = to_pixels(x_c, spec.K)
    rad = int(np.ceil(7 * sigma_n * spec.K[0, 0]))
    for (cu, cv), x in zip(c_r, x_c, strict=True):
        u0, v0 = int(round(cu)), int(round(cv))
        us, vs = np.arange(u0 - rad, u0 + rad + 1), np.arange(v0 - rad, v0 + rad + 1)
        pu, pv = np.meshgrid(us, vs)
        xn = from_pixels(np.stack([pu, pv], -1).astype(float), spec.K)
        g = AMP * np.exp(-np.sum((xn - x) ** 2, axis=-1) / (2 * sigma_n**2))
        img[vs[0]:vs[-1] + 1, us[0]:us[-1] + 1] += g.astype(np.float32)
    return img, uv_true, x_c, sigma_n


def _centroid(values, u0, v0, R):
    us, vs = np.meshgrid(np.arange(u0 - R, u0 + R + 1), np.arange(v0 - R, v0 + R + 1))
    w = values - BG
    return np.array([np.sum(w * us), np.sum(w * vs)]) / np.sum(w)


def _exact_box_pixels(camera, x_c, sigma_n, u0, v0, R, n=8):
    """The ideal output pixels: the continuous distorted blob integrated over each pixel footprint (n x n)."""
    sub = (np.arange(n) + 0.5) / n - 0.5
    us = (np.arange(u0 - R, u0 + R + 1)[:, None] + sub).ravel()
    vs = (np.arange(v0 - R, v0 + R + 1)[:, None] + sub).ravel()
    pu, pv = np.meshgrid(us, vs)
    xn = undistort(from_pixels(np.stack([pu, pv], -1), camera.K), camera.dist)
    g = BG + AMP * np.exp(-np.sum((xn - x_c) ** 2, axis=-1) / (2 * sigma_n**2))
    m = 2 * R + 1
    return g.reshape(m, n, m, n).mean(axis=(1, 3))


@pytest.mark.parametrize("preset, s", [("underwater_in_air", 3), ("underwater_in_water", 2)])
def test_warped_blob_centroids_match_the_camera_projection(preset, s):
    camera = load_preset(preset)
    stage = DistortionStage(camera, s)
    spec = stage.render_spec()
    rng = np.random.default_rng(41)
    render, uv_true, x_c, sigma_n = _blob_render(camera, spec, 1.5, rng)
    t = time.perf_counter()
    out = stage.warp_image(render, spec.K)
    t_first = time.perf_counter() - t
    t = time.perf_counter()
    stage.warp_image(render, spec.K)
    t_cached = time.perf_counter() - t
    assert out.shape == (camera.height, camera.width) and out.dtype == np.float32
    R = 9
    err_proj, err_exact = [], []
    for uv, x in zip(uv_true, x_c, strict=True):
        u0, v0 = (int(round(c)) for c in uv)
        win = out[v0 - R:v0 + R + 1, u0 - R:u0 + R + 1]
        c_warp = _centroid(win, u0, v0, R)
        c_exact = _centroid(_exact_box_pixels(camera, x, sigma_n, u0, v0, R), u0, v0, R)
        err_proj.append(np.linalg.norm(c_warp - uv))  # includes the centroid's own second-order shift
        err_exact.append(np.linalg.norm(c_warp - c_exact))  # the warp alone
    err_proj, err_exact = np.array(err_proj), np.array(err_exact)
    print(f"{preset} s={s}: centroid vs CameraModel.project max {err_proj.max():.4f} px rms "
          f"{np.sqrt(np.mean(err_proj**2)):.4f} px; vs exact box-filtered image max {err_exact.max():.4f} px; "
          f"maps {t_first:.2f} s, warp {1e3 * t_cached:.1f} ms")
    assert err_exact.max() <= 0.01
    assert err_proj.max() <= 0.05  # the rest is the centroid shift of a blob seen through the distortion


def test_identity_camera_reproduces_the_render_exactly():
    camera = load_preset("air_webcam")
    spec = render_K(camera, 1, margin=2)
    assert (spec.width, spec.height) == (camera.width + 4, camera.height + 4)
    assert np.allclose(spec.K, camera.K + np.array([[0, 0, 2], [0, 0, 2], [0, 0, 0]]))
    render = np.random.default_rng(42).integers(0, 256, (spec.height, spec.width, 3), dtype=np.uint8)
    out = DistortionStage(camera, 1).warp_image(render, spec.K)
    assert out.dtype == np.uint8 and np.array_equal(out, render[2:-2, 2:-2])


def test_supersampling_is_a_box_filter_over_the_pixel_footprint():
    camera = load_preset("air_webcam")
    s = 4
    spec = render_K(camera, s, margin=2)
    # a render whose value is its own x coordinate in ideal normalised units: the box average is the mean over the
    # sub-samples, i.e. the value at the pixel centre for this linear function
    uu, vv = np.meshgrid(np.arange(spec.width, dtype=float), np.arange(spec.height, dtype=float))
    render = from_pixels(np.stack([uu, vv], -1), spec.K)[..., 0].astype(np.float32)
    out = DistortionStage(camera, s).warp_image(render, spec.K)
    pu, pv = np.meshgrid(np.arange(camera.width, dtype=float), np.arange(camera.height, dtype=float))
    expected = from_pixels(np.stack([pu, pv], -1), camera.K)[..., 0]
    assert np.max(np.abs(out - expected)) * camera.fx <= 1e-3  # float32 render, 1/32 px bilinear weights
    assert np.allclose(subsample_coordinates(2, 4), [-0.375, -0.125, 0.125, 0.375, 0.625, 0.875, 1.125, 1.375])


def test_depth_is_never_averaged_across_an_edge():
    camera = load_preset("underwater_in_water")
    s = 2
    stage = DistortionStage(camera, s)
    spec = stage.render_spec()
    uu, vv = np.meshgrid(np.arange(spec.width, dtype=float), np.arange(spec.height, dtype=float))
    x_r = from_pixels(np.stack([uu, vv], -1), spec.K)
    edge = 0.05 + 0.2 * x_r[..., 1]  # a slanted edge in ideal coordinates
    depth = np.where(x_r[..., 0] < edge, 1.0, 5.0).astype(np.float32)
    center = stage.warp_depth(depth, spec.K, "center")
    low = stage.warp_depth(depth, spec.K, "min")
    assert set(np.unique(center)) == {1.0, 5.0} and set(np.unique(low)) == {1.0, 5.0}
    assert np.all(low <= center)
    # pixel centres clearly on one side of the edge get that side's depth
    pu, pv = np.meshgrid(np.arange(camera.width, dtype=float), np.arange(camera.height, dtype=float))
    x = undistort(from_pixels(np.stack([pu, pv], -1), camera.K), camera.dist)
    gap = (x[..., 0] - (0.05 + 0.2 * x[..., 1])) * spec.K[0, 0]  # render px from the edge
    assert np.all(center[gap < -1] == 1.0) and np.all(center[gap > 1] == 5.0)
    image, d = stage.apply(np.zeros((spec.height, spec.width, 3), np.uint8), spec.K, depth=depth)
    assert image.shape == (camera.height, camera.width, 3) and np.array_equal(d, center)


def test_maps_are_cached_and_exact():
    camera = load_preset("underwater_in_water")
    stage = DistortionStage(camera, 2)
    spec = stage.render_spec()
    assert stage.maps(spec.K, (spec.width, spec.height)) is DistortionStage(camera, 2).maps(spec.K,
                                                                                             (spec.width, spec.height))
    grid = ideal_subsample_grid(camera, 2)
    uu, vv = np.meshgrid(subsample_coordinates(camera.width, 2), subsample_coordinates(camera.height, 2))
    back = camera.project(np.concatenate([grid, np.ones(grid.shape[:-1] + (1,))], -1))
    assert np.max(np.abs(back - np.stack([uu, vv], -1))) <= 1e-9


def test_bad_input():
    camera = load_preset("underwater_in_air")
    with pytest.raises(ValueError, match="supersample"):
        DistortionStage(camera, 0)
    with pytest.raises(ValueError, match="camera: expected a CameraModel"):
        DistortionStage("underwater_in_air", 2)
    stage = DistortionStage(camera, 1)
    spec = stage.render_spec()
    small = np.zeros((spec.height - 40, spec.width - 40), np.float32)
    with pytest.raises(ValueError, match="K_render: a .* render does not cover"):
        stage.warp_image(small, spec.K)
    with pytest.raises(ValueError, match="image: contains NaN"):
        stage.warp_image(np.full((spec.height, spec.width), np.nan, np.float32), spec.K)
    with pytest.raises(ValueError, match="mode"):
        stage.warp_depth(np.ones((spec.height, spec.width)), spec.K, "mean")
    bad_K = spec.K.copy()
    bad_K[1, 1] = 0.0
    with pytest.raises(ValueError, match="K_render: focal lengths"):
        stage.warp_image(np.zeros((spec.height, spec.width), np.float32), bad_K)
