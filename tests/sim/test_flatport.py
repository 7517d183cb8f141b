"""Flat-port refraction (issue 3 item 4b): Snell, slab shift, paraxial magnification, caustic, projection, stage."""

import time

import numpy as np
import pytest

from bench.camera.model import CameraModel
from bench.errors import ConfigError
from bench.sim.flatport import FlatPort, FlatPortStage, axis_crossing, project_flatport, refract, trace_rays

PORT = FlatPort(d0=0.03, t=0.012, n_air=1.0, n_glass=1.49, n_water=1.34, tilt=[0.03, -0.02], decentre=[0.002, 0.001])


def _random_dirs(rng, n, half_fov=0.6):
    x = rng.uniform(-half_fov, half_fov, (n, 2))
    return np.concatenate([x, np.ones((n, 1))], -1), x


def _sin_to_normal(d, n):
    return np.linalg.norm(np.cross(d, n), axis=-1) / np.linalg.norm(d, axis=-1)


def test_refract_obeys_snell_and_is_coplanar():
    rng = np.random.default_rng(3)
    d = rng.normal(size=(2000, 3))
    n = rng.normal(size=(2000, 3))
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    n1, n2 = rng.uniform(1.0, 1.6, 2000), rng.uniform(1.0, 1.6, 2000)
    t, ok = refract(d, n, n1, n2)
    sin_i, sin_t = _sin_to_normal(d, n), _sin_to_normal(t, n)
    assert np.array_equal(ok, n1 * sin_i <= n2)  # TIR exactly where sin(theta_t) would exceed 1
    assert np.all(np.isnan(t[~ok]))
    assert np.abs(n1[ok] * sin_i[ok] - n2[ok] * sin_t[ok]).max() <= 1e-12
    assert np.abs(np.einsum("ij,ij->i", np.cross(d[ok], n[ok]), t[ok])).max() <= 1e-12  # coplanar
    assert np.all(np.einsum("ij,ij->i", d[ok], n[ok]) * np.einsum("ij,ij->i", t[ok], n[ok]) > 0)  # transmitted
    t_same, _ = refract(d, n, 1.33, 1.33)
    np.testing.assert_allclose(t_same, d / np.linalg.norm(d, axis=-1, keepdims=True), atol=1e-15)


def test_trace_obeys_snell_at_each_interface():
    rng = np.random.default_rng(4)
    d, _ = _random_dirs(rng, 3000, 0.9)
    o, w, ok = trace_rays(d, PORT)
    assert np.all(ok)
    n = PORT.normal
    d1 = d / np.linalg.norm(d, axis=-1, keepdims=True)
    p1 = d1 * (PORT.h / (d1 @ n))[:, None]
    g = o - p1  # the direction in glass
    g /= np.linalg.norm(g, axis=-1, keepdims=True)
    s_a, s_g, s_w = (_sin_to_normal(v, n) for v in (d1, g, w))
    assert np.abs(PORT.n_air * s_a - PORT.n_glass * s_g).max() <= 1e-12
    assert np.abs(PORT.n_glass * s_g - PORT.n_water * s_w).max() <= 1e-12
    assert np.abs(o @ n - (PORT.h + PORT.t)).max() <= 1e-12  # the origins lie on the outer surface
    # all three segments in one plane with the normal
    assert np.abs(np.einsum("ij,ij->i", np.cross(d1, n), w)).max() <= 1e-12
    assert np.abs(np.einsum("ij,ij->i", np.cross(d1, n), g)).max() <= 1e-12


def test_ray_along_the_normal_is_undeviated():
    o, w, ok = trace_rays(PORT.normal, PORT)
    assert ok
    np.testing.assert_allclose(w, PORT.normal, atol=1e-15)
    np.testing.assert_allclose(o, PORT.normal * (PORT.h + PORT.t), atol=1e-15)


def test_slab_in_air_only_shifts_rays():
    port = FlatPort(d0=0.02, t=0.015, n_air=1.0, n_glass=1.52, n_water=1.0, tilt=[0.05, 0.02])
    rng = np.random.default_rng(5)
    d, _ = _random_dirs(rng, 1000, 0.8)
    o, w, ok = trace_rays(d, port)
    d1 = d / np.linalg.norm(d, axis=-1, keepdims=True)
    assert np.all(ok) and np.abs(w - d1).max() <= 1e-14  # parallel in and out
    # lateral shift of a slab: t sin(a - g) / cos(g)
    n = port.normal
    cos_a = d1 @ n
    sin_a = np.sqrt(1 - cos_a**2)
    sin_g = sin_a / port.n_glass
    cos_g = np.sqrt(1 - sin_g**2)
    shift = port.t * (sin_a * cos_g - cos_a * sin_g) / cos_g
    meas = np.linalg.norm(np.cross(o, d1), axis=-1)  # distance of the exit line from the camera centre
    assert np.abs(meas - shift).max() <= 1e-14


def test_thin_port_is_a_pinhole_with_focal_length_times_n_water():
    port = FlatPort(d0=1e-12, t=0.0, n_water=1.34)
    rng = np.random.default_rng(6)
    x_w = rng.uniform(-1e-4, 1e-4, (200, 2))  # paraxial directions in water
    p = np.concatenate([x_w, np.ones((200, 1))], -1) * rng.uniform(0.5, 3.0, (200, 1))
    x_n = project_flatport(p, port)
    ratio = x_n / x_w
    assert np.abs(ratio - port.n_water / port.n_air).max() <= 1e-7  # error O(theta^2)
    # and at any angle the exact thin-port law n_air sin(a) = n_water sin(w) holds
    x_w = rng.uniform(-0.5, 0.5, (200, 2))
    p = np.concatenate([x_w, np.ones((200, 1))], -1)
    x_n = project_flatport(p, port)
    sin_a = np.linalg.norm(x_n, axis=-1) / np.sqrt(1 + np.sum(x_n**2, -1))
    sin_w = np.linalg.norm(x_w, axis=-1) / np.sqrt(1 + np.sum(x_w**2, -1))
    assert np.abs(port.n_air * sin_a - port.n_water * sin_w).max() <= 1e-12
    # a thin port has a single viewpoint: all water rays cross the axis at the centre
    d, _ = _random_dirs(rng, 500, 0.7)
    assert np.nanmax(np.abs(axis_crossing(d, port))) <= 1e-9


def test_thick_port_has_no_single_viewpoint():
    port = FlatPort(d0=0.03, t=0.012)
    rng = np.random.default_rng(7)
    d, _ = _random_dirs(rng, 4000, 0.6)  # about +-31 deg in air
    z = axis_crossing(d, port)
    paraxial = port.h + port.t - (port.h * port.n_water / port.n_air + port.t * port.n_water / port.n_glass)
    z_small = axis_crossing(np.array([[1e-6, 0.0, 1.0]]), port)[0]
    assert abs(z_small - paraxial) <= 1e-9
    spread = np.nanmax(z) - np.nanmin(z)
    print(f"caustic: axis crossings from {1e3 * np.nanmin(z):.2f} to {1e3 * np.nanmax(z):.2f} mm "
          f"(spread {1e3 * spread:.2f} mm over +-31 deg; paraxial {1e3 * paraxial:.2f} mm)")
    assert spread > 1e-3  # millimetres, not a single viewpoint
    assert np.all(z <= paraxial + 1e-12)  # wider rays cross further back


def test_projection_round_trip():
    rng = np.random.default_rng(8)
    d, x = _random_dirs(rng, 5000, 0.7)
    o, w, ok = trace_rays(d, PORT)
    lam = rng.uniform(0.05, 5.0, 5000)
    res = project_flatport(o + lam[:, None] * w, PORT, full_output=True)
    err_px = 800.0 * np.abs(res.x_n - x).max()
    print(f"project_flatport round trip: max {err_px:.2e} px at f = 800 px, {res.iterations} iterations, "
          f"residual {res.max_residual:.1e} m")
    assert res.success and err_px <= 1e-9 and res.max_residual <= 1e-12


def test_projection_degenerate_points():
    x = project_flatport(np.array([[0.0, 0.0, 0.01], [0.1, 0.0, -1.0], [0.0, 0.0, 1.0], [np.nan, 0, 1]]),
                         FlatPort(d0=0.03, t=0.012), full_output=True)
    assert np.all(np.isnan(x.x_n[[0, 1, 3]])) and not x.success  # inside the housing, behind, NaN input
    np.testing.assert_allclose(x.x_n[2], 0.0, atol=1e-15)  # on the axis


@pytest.mark.parametrize("kwargs, field", [({"t": -0.001}, "t"), ({"d0": 0.0}, "d0"), ({"n_glass": 0.9}, "n_glass"),
                                            ({"tilt": [0.1]}, "tilt"), ({"n_water": float("nan")}, "n_water"),
                                            ({"tilt": [2.0, 0.0]}, "tilt")])
def test_bad_port(kwargs, field):
    with pytest.raises(ConfigError, match=f": {field}: ") as exc:
        FlatPort(**kwargs)
    assert "\n" not in str(exc.value)


def test_bad_input():
    with pytest.raises(ValueError, match="dirs_cam"):
        trace_rays(np.zeros((2, 2)), PORT)
    with pytest.raises(ValueError, match="dirs_cam"):
        trace_rays(np.zeros(3), PORT)
    with pytest.raises(ValueError, match="port"):
        trace_rays(np.ones(3), "port")
    with pytest.raises(ValueError, match="p_cam"):
        project_flatport(np.ones((3, 2)), PORT)


# ----------------------------------------------------------------------------------------------------------------------
# the image stage on an analytic render
# ----------------------------------------------------------------------------------------------------------------------
PLANE_N = np.array([0.25, -0.15, 1.0]) / np.linalg.norm([0.25, -0.15, 1.0])  # a slanted plane n . p = c
PLANE_C = 0.6
SIGMA = 0.004  # blob radius on the plane (m)


def _texture(pts, blobs):
    val = np.full(pts.shape[:-1], 30.0)
    for b in blobs:
        val += 200.0 * np.exp(-np.sum((pts - b) ** 2, -1) / (2 * SIGMA**2))
    return val


def _exact_port_image(lens, port, blobs, n=6):
    """The ideal output: every pixel footprint integrated by n x n rays traced analytically onto the plane."""
    sub = (np.arange(n) + 0.5) / n - 0.5
    us = (np.arange(lens.width)[:, None] + sub).ravel()
    vs = (np.arange(lens.height)[:, None] + sub).ravel()
    o, w, _ = trace_rays(lens.unproject(np.stack(np.meshgrid(us, vs), -1)), port)
    lam = (PLANE_C - o @ PLANE_N) / (w @ PLANE_N)
    val = _texture(o + lam[..., None] * w, blobs)
    return val.reshape(lens.height, n, lens.width, n).mean(axis=(1, 3))


def _centroids(img, uv_pred, R=6):
    out = []
    for uv in uv_pred:
        u0, v0 = (int(round(c)) for c in uv)
        win = img[v0 - R:v0 + R + 1, u0 - R:u0 + R + 1] - 30.0
        us, vs = np.meshgrid(np.arange(u0 - R, u0 + R + 1), np.arange(v0 - R, v0 + R + 1))
        out.append(np.array([np.sum(win * us), np.sum(win * vs)]) / np.sum(win))
    return np.array(out)


def _plane_render(spec, blobs):
    """Pinhole RGB and z-depth of a slanted plane textured with Gaussian blobs (3D centres ``blobs``)."""
    uu, vv = np.meshgrid(np.arange(spec.width, dtype=float), np.arange(spec.height, dtype=float))
    x = (uu - spec.K[0, 2]) / spec.K[0, 0]
    y = (vv - spec.K[1, 2]) / spec.K[1, 1]
    rays = np.stack([x, y, np.ones_like(x)], -1)
    z = PLANE_C / (rays @ PLANE_N)
    val = _texture(rays * z[..., None], blobs)
    rgb = np.stack([val, 0.5 * val, 0.25 * val + 10], -1).astype(np.float32)
    depth = z.copy()
    depth[(uu < 3) & (vv < 3)] = np.inf  # a patch of background in the corner (outside the view)
    return rgb, depth


def test_stage_places_points_where_project_flatport_says():
    lens = CameraModel(160, 120, np.array([[150.0, 0, 79.5], [0, 152.0, 59.5], [0, 0, 1]]),
                       dist=np.array([-0.05, 0.01, 0.0005, -0.0003, 0.0]))
    stage = FlatPortStage(lens.K, lens.size, PORT, 3, lens=lens)
    spec = stage.render_spec(z_min=0.45)
    # blob centres on the plane, spread over the image
    rng = np.random.default_rng(9)
    uv_t = np.stack(np.meshgrid(np.linspace(25, 135, 4), np.linspace(22, 98, 3)), -1).reshape(-1, 2)
    uv_t = uv_t + rng.uniform(-0.5, 0.5, uv_t.shape)
    o, w, _ = trace_rays(lens.unproject(uv_t), PORT)
    lam = (PLANE_C - o @ PLANE_N) / (w @ PLANE_N)
    blobs = o + lam[:, None] * w
    rgb, depth = _plane_render(spec, blobs)
    t0 = time.perf_counter()
    out = stage.apply(rgb, depth, spec.K)
    dt = time.perf_counter() - t0
    uv_pred = lens.project(np.concatenate([project_flatport(blobs, PORT), np.ones((len(blobs), 1))], -1))
    assert np.abs(uv_pred - uv_t).max() <= 1e-9  # the projection agrees with the trace through the lens
    c_stage = _centroids(out.image[..., 0], uv_pred)
    errs = np.linalg.norm(c_stage - uv_pred, axis=-1)
    err_exact = np.linalg.norm(c_stage - _centroids(_exact_port_image(lens, PORT, blobs), uv_pred), axis=-1)
    # the depth and water path at pixel centres against the analytic plane
    oc, wc, _ = stage.rays("centre")
    lam_true = (PLANE_C - oc @ PLANE_N) / (wc @ PLANE_N)
    path_err = np.abs(out.water_path - lam_true).max()
    print(f"stage: blob centroid vs project_flatport max {errs.max():.4f} px rms {np.sqrt(np.mean(errs**2)):.4f} px, "
          f"vs exact box-filtered image max {err_exact.max():.4f} px; "
          f"water path max err {1e6 * path_err:.2f} um; converged {out.converged_fraction:.4f}; {dt:.2f} s")
    assert errs.max() <= 0.1 and err_exact.max() <= 0.02
    assert path_err <= 1e-4 * lam_true.max()
    assert out.converged_fraction == 1.0 and out.unresolved.sum() == 0
    np.testing.assert_allclose(out.depth, oc[..., 2] + lam_true * wc[..., 2], rtol=1e-4)


def test_stage_background_and_occlusion():
    K = np.array([[80.0, 0, 39.5], [0, 80.0, 29.5], [0, 0, 1]])
    stage = FlatPortStage(K, (80, 60), PORT, 2, background=(7.0, 7.0, 7.0))
    spec = stage.render_spec(z_min=0.3)
    rgb = np.full((spec.height, spec.width, 3), 100.0, dtype=np.float32)
    depth = np.full((spec.height, spec.width), np.inf)
    depth[:, : spec.width // 2] = 0.5  # a wall on the left half, background on the right
    rgb[:, spec.width // 2:] = 50.0
    out = stage.apply(rgb, depth, spec.K)
    assert np.all(np.isinf(out.depth[:, -5:])) and np.all(np.isinf(out.water_path[:, -5:]))
    np.testing.assert_allclose(out.image[:, -5:], 50.0)  # background at infinity sampled along the ray
    np.testing.assert_allclose(out.image[:, :5], 100.0)
    assert np.all(np.isfinite(out.depth[:, :5]))


def test_stage_speed_640x480():
    K = np.array([[510.0, 0, 319.5], [0, 540.0, 239.5], [0, 0, 1]])
    stage = FlatPortStage(K, (640, 480), PORT, 2)
    t0 = time.perf_counter()
    spec = stage.render_spec(z_min=0.4)
    t_rays = time.perf_counter() - t0
    uu, vv = np.meshgrid(np.arange(spec.width), np.arange(spec.height))
    rgb = np.stack([(uu * 7 % 256), (vv * 5 % 256), ((uu + vv) % 256)], -1).astype(np.uint8)
    depth = 0.8 + 1e-4 * uu
    stage.apply(rgb, depth, spec.K)
    t0 = time.perf_counter()
    out = stage.apply(rgb, depth, spec.K)
    dt = time.perf_counter() - t0
    print(f"stage 640x480 s=2: rays {t_rays:.2f} s (once), apply {dt:.2f} s; render {spec.width}x{spec.height}")
    assert out.image.shape == (480, 640, 3) and out.image.dtype == np.uint8
    assert out.converged_fraction == 1.0


def test_stage_bad_input():
    K = np.array([[80.0, 0, 39.5], [0, 80.0, 29.5], [0, 0, 1]])
    stage = FlatPortStage(K, (80, 60), PORT, 2)
    spec = stage.render_spec(z_min=0.3)
    rgb = np.zeros((spec.height, spec.width, 3), np.float32)
    with pytest.raises(ValueError, match="depth"):
        stage.apply(rgb, np.ones((5, 5)), spec.K)
    with pytest.raises(ValueError, match="depth"):
        stage.apply(rgb, np.zeros((spec.height, spec.width)), spec.K)
    small = np.eye(3)
    small[0, 0] = small[1, 1] = 20.0
    with pytest.raises(ValueError, match="K_render"):
        stage.apply(rgb[:20, :20], np.ones((20, 20)), small)
    with pytest.raises(ValueError, match="z_min"):
        stage.render_spec(z_min=0.01)
    with pytest.raises(ValueError, match="lens"):
        FlatPortStage(K, (80, 61), PORT, 2, lens=CameraModel(80, 60, K))
    with pytest.raises(ValueError, match="supersample"):
        FlatPortStage(K, (80, 60), PORT, 0)


# ----------------------------------------------------------------------------------------------------------------------
# optics presets (housing + medium parts)
# ----------------------------------------------------------------------------------------------------------------------
def test_optics_presets():
    from bench.camera.presets import load_preset
    from bench.sim.optics_presets import optics_preset, optics_preset_names

    assert optics_preset_names() == ["air_webcam", "underwater_in_air", "underwater_in_water"]
    webcam = optics_preset("air_webcam")
    assert webcam.port is None and webcam.chain.medium is None and webcam.chain.sensor is not None
    in_air, in_water = optics_preset("underwater_in_air"), optics_preset("underwater_in_water")
    assert in_air.port.n_water == in_air.port.n_air and in_air.chain.medium is None
    assert in_water.port.n_water > 1.3 and in_water.chain.medium.name == "coastal"
    for p in (webcam, in_air, in_water):
        load_preset(p.nominal_camera), load_preset(p.lens_camera)
    # the submerged port magnifies the inner camera by ~ n_water near the image centre (Table 15 vs 9: 1.30)
    lens = load_preset(in_water.lens_camera)
    p = np.array([[0.001, 0.0005, 2.0]])
    x_port = project_flatport(p, in_water.port)
    x_port0 = project_flatport(np.array([[0.0, 0.0, 2.0]]), in_water.port)
    ratio = np.linalg.norm(x_port - x_port0) / np.linalg.norm(p[0, :2] / p[0, 2])
    print(f"underwater_in_water: paraxial magnification {ratio:.4f} (n_water {in_water.port.n_water}; thesis "
          f"Table 15/9 focal ratio {662.6 / 510.06:.4f}); lens fx {lens.fx:.1f} px")
    assert abs(ratio - in_water.port.n_water) <= 0.01
    shift = project_flatport(p, in_air.port) - project_flatport(np.array([[0.0, 0.0, 2.0]]), in_air.port)
    in_air_ratio = np.linalg.norm(shift) / np.linalg.norm(p[0, :2] / p[0, 2])
    assert abs(in_air_ratio - 1.0) <= 0.01  # a slab in air does not magnify (only shifts by ~mm at 2 m)
    with pytest.raises(ValueError, match="known: air_webcam, underwater_in_air, underwater_in_water") as exc:
        optics_preset("deep_sea")
    assert "\n" not in str(exc.value)


def test_composed_lens_and_port_stage():
    """Lens distortion (the inner camera) then the port: known points land where lens.project(project_flatport)."""
    from bench.sim.optics_presets import optics_preset

    preset = optics_preset("underwater_in_water")
    from bench.camera.presets import load_preset

    full = load_preset(preset.lens_camera)
    s = 4  # a 1/4-scale camera keeps the test fast
    K = full.K.copy()
    K[:2] /= s
    K[0, 2], K[1, 2] = (full.cx + 0.5) / s - 0.5, (full.cy + 0.5) / s - 0.5
    lens = CameraModel(full.width // s, full.height // s, K, dist=full.dist)
    stage = FlatPortStage(lens.K, lens.size, preset.port, 3, lens=lens)
    spec = stage.render_spec(z_min=0.45)
    uv_t = np.stack(np.meshgrid(np.linspace(20, 140, 4), np.linspace(18, 100, 3)), -1).reshape(-1, 2) + 0.3
    o, w, _ = trace_rays(lens.unproject(uv_t), preset.port)
    lam = (PLANE_C - o @ PLANE_N) / (w @ PLANE_N)
    blobs = o + lam[:, None] * w
    rgb, depth = _plane_render(spec, blobs)
    out = stage.apply(rgb, depth, spec.K)
    uv_pred = lens.project(np.concatenate([project_flatport(blobs, preset.port), np.ones((len(blobs), 1))], -1))
    c_stage = _centroids(out.image[..., 0], uv_pred)
    c_exact = _centroids(_exact_port_image(lens, preset.port, blobs), uv_pred)
    err_exact = np.linalg.norm(c_stage - c_exact, axis=-1)
    err_proj = np.linalg.norm(c_stage - uv_pred, axis=-1)
    print(f"composed lens + port (underwater_in_water, 160x120, s=3): centroid vs exact box-filtered image max "
          f"{err_exact.max():.4f} px; vs lens.project(project_flatport) max {err_proj.max():.4f} px (includes the "
          f"centroid's own shift under the strong lens distortion)")
    assert err_exact.max() <= 0.02
    assert np.all(err_proj <= 0.1 + np.linalg.norm(c_exact - uv_pred, axis=-1))
