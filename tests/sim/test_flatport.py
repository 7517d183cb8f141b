"""Flat-port refraction (issue 3 item 4b): Snell, slab shift, paraxial magnification, caustic, projection, stage."""

import time

import numpy as np
import pytest

from bench.camera.flatport import FlatPort, axis_crossing, project_flatport, refract, trace_rays
from bench.camera.model import CameraModel
from bench.errors import ConfigError
from bench.sim.flatport import FlatPortStage

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


def test_stage_bands_and_pixel_tolerance(monkeypatch):
    """The stage's row bands (threads) do not change anything; stopping the colour sub-rays at a 0.001 px step changes
    the image by far less than the 1/32 px quantisation of the bilinear weights can show."""
    from bench.sim import parallel

    lens = CameraModel(160, 120, np.array([[150.0, 0, 79.5], [0, 152.0, 59.5], [0, 0, 1]]))
    stage = FlatPortStage(lens.K, lens.size, PORT, 2, lens=lens)
    spec = stage.render_spec(z_min=0.45)
    rng = np.random.default_rng(12)
    o, w, _ = trace_rays(lens.unproject(rng.uniform([10, 10], [150, 110], (40, 2))), PORT)
    blobs = o + ((PLANE_C - o @ PLANE_N) / (w @ PLANE_N))[:, None] * w
    rgb, depth = _plane_render(spec, blobs)
    out = stage.apply(rgb, depth, spec.K)
    strict = stage.apply(rgb, depth, spec.K, tol_px=0.0)  # the depth tolerance alone, as for the water path
    monkeypatch.setattr(parallel, "N_BANDS", 1)
    one = stage.apply(rgb, depth, spec.K)
    for a, b in ((out, one),):
        assert np.array_equal(a.image, b.image) and np.array_equal(a.water_path, b.water_path)
        assert np.array_equal(a.depth, b.depth) and np.array_equal(a.unresolved, b.unresolved)
    diff = np.abs(out.image - strict.image).max()
    print(f"stage: colour sub-rays stopped at 0.001 px vs |d lambda| <= 1e-6 lambda: max {diff:.4f} DN")
    assert diff <= 0.05 and np.array_equal(out.water_path, strict.water_path)


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


# ----------------------------------------------------------------------------------------------------------------------
# closed forms and pixels
# ----------------------------------------------------------------------------------------------------------------------
def _single_interface_quartic(rho_p, z_p, d, n_a, n_w):
    """Agrawal et al. 2012 (single flat interface at distance d, no tilt): the radius x where the ray meets the
    interface solves n_a^2 x^2 ((rho_p - x)^2 + (z_p - d)^2) = n_w^2 (rho_p - x)^2 (x^2 + d^2), a quartic; the
    physical root is the real one in [0, rho_p] that satisfies the unsquared Snell equation."""
    L = z_p - d
    a, b = n_a**2, n_w**2
    # expand a x^2 ((r - x)^2 + L^2) - b (r - x)^2 (x^2 + d^2) in powers of x
    r = rho_p
    p_rx2 = np.array([1.0, -2 * r, r * r])  # (r - x)^2 = x^2 - 2 r x + r^2
    lhs = a * np.polyadd(np.polymul([1.0, 0, 0], p_rx2), [L * L, 0, 0])
    rhs = b * np.polymul(p_rx2, [1.0, 0, d * d])
    roots = np.roots(np.polysub(lhs, rhs))
    best = None
    for x in roots[np.abs(roots.imag) <= 1e-9 * max(1.0, r)].real:
        if -1e-12 <= x <= r + 1e-12:
            snell = n_a * x / np.hypot(x, d) - n_w * (r - x) / np.hypot(r - x, L)
            if best is None or abs(snell) < abs(best[1]):
                best = (x, snell)
    return best[0]


def test_single_interface_matches_the_quartic_closed_form_and_thin_glass_converges_to_it():
    n_a, n_w, d = 1.0, 1.34, 0.025
    rng = np.random.default_rng(21)
    p = np.concatenate([rng.uniform(-0.8, 0.8, (300, 2)), rng.uniform(0.2, 3.0, (300, 1))], -1)
    x_quartic = np.array([_single_interface_quartic(np.hypot(*q[:2]), q[2], d, n_a, n_w) for q in p])
    tan_a_quartic = x_quartic / d  # the in-air ray's radial slope
    single = FlatPort(d0=d, t=0.0, n_air=n_a, n_glass=1.52, n_water=n_w)
    x_n = project_flatport(p, single)
    err0 = np.abs(np.linalg.norm(x_n, axis=-1) - tan_a_quartic).max()
    # the direction of x_n is the point's azimuth (the ray stays in the plane of the axis and the point)
    az = np.abs(x_n[:, 0] * p[:, 1] - x_n[:, 1] * p[:, 0]).max()
    errs = []
    for t in (1e-4, 1e-6, 1e-8):
        thin = FlatPort(d0=d, t=t, n_air=n_a, n_glass=1.52, n_water=n_w)
        errs.append(np.abs(project_flatport(p, thin) - x_n).max())
    print(f"single interface vs quartic closed form: max {err0:.1e} (tan); thin glass t = 1e-4/1e-6/1e-8 m -> "
          f"{errs[0]:.1e}/{errs[1]:.1e}/{errs[2]:.1e}")
    assert err0 <= 1e-9 and az <= 1e-12
    assert errs[2] <= 1e-7
    # first order in t: every factor 100 in thickness divides the difference by 100
    assert abs(errs[0] / errs[1] / 100 - 1) <= 0.02 and abs(errs[1] / errs[2] / 100 - 1) <= 0.02


def test_projection_in_pixels_round_trip_with_skew():
    K = np.array([[812.0, 1.5, 330.2], [0.0, 798.0, 241.7], [0.0, 0.0, 1.0]])
    rng = np.random.default_rng(22)
    uv = np.stack([rng.uniform(0, 639, 3000), rng.uniform(0, 479, 3000)], -1)
    y = (uv[:, 1] - K[1, 2]) / K[1, 1]
    x = (uv[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
    o, w, ok = trace_rays(np.stack([x, y, np.ones_like(x)], -1), PORT)
    lam = rng.uniform(0.05, 8.0, 3000)
    res = project_flatport(o + lam[:, None] * w, PORT, K, full_output=True)
    err = np.abs(res.x_n - uv).max()
    print(f"project_flatport(trace_rays) in pixels (skewed K, f ~ 800 px): max {err:.1e} px")
    assert res.success and err <= 1e-9
    with pytest.raises(ValueError, match="K"):
        project_flatport(o[:2] + w[:2], PORT, np.eye(2))


# ----------------------------------------------------------------------------------------------------------------------
# the residual approximation at occlusion boundaries
# ----------------------------------------------------------------------------------------------------------------------
Z_NEAR, Z_FAR, X_EDGE = 0.4, 1.0, 0.06  # a near half-plane x < X_EDGE at z = Z_NEAR in front of a wall at Z_FAR


def _two_plane_value(pts, near):
    far_val = 128.0 + 100.0 * np.sin(2 * np.pi * pts[..., 0] / 0.15) * np.cos(2 * np.pi * pts[..., 1] / 0.2)
    near_val = 40.0 + 20.0 * np.cos(2 * np.pi * pts[..., 1] / 0.08)
    return np.where(near, near_val, far_val)


def _two_plane_hits(o, w):
    """Exact first hits of water rays: the near half-plane if the ray crosses z = Z_NEAR at x < X_EDGE, else the
    wall. Returns (points, near mask)."""
    p_near = o + ((Z_NEAR - o[..., 2]) / w[..., 2])[..., None] * w
    p_far = o + ((Z_FAR - o[..., 2]) / w[..., 2])[..., None] * w
    near = p_near[..., 0] < X_EDGE
    return np.where(near[..., None], p_near, p_far), near


def test_occlusion_residual_is_confined_to_the_predicted_disocclusion_band():
    """A single-centre render cannot show the part of the wall that the port's shifted rays see behind the edge of a
    near object: the stage is exact elsewhere and errs only in the band the analytic geometry predicts."""
    K = np.array([[160.0, 0, 79.5], [0, 160.0, 59.5], [0, 0, 1]])
    s = 2
    stage = FlatPortStage(K, (160, 120), PORT, s)
    spec = stage.render_spec(z_min=0.35)
    uu, vv = np.meshgrid(np.arange(spec.width, dtype=float), np.arange(spec.height, dtype=float))
    rays = np.stack([(uu - spec.K[0, 2]) / spec.K[0, 0], (vv - spec.K[1, 2]) / spec.K[1, 1], np.ones_like(uu)], -1)
    pts, near = _two_plane_hits(np.zeros(3), rays)
    rgb = np.repeat(_two_plane_value(pts, near)[..., None], 3, -1).astype(np.float32)
    out = stage.apply(rgb, pts[..., 2], spec.K)
    # the exact image: the same sub-rays traced analytically
    o, w, _ = stage.rays("sub")
    hits, near_sub = _two_plane_hits(o, w)
    exact = _two_plane_value(hits, near_sub).reshape(120, s, 160, s).mean(axis=(1, 3))
    # predicted trouble: sub-rays that really see the wall at a point the camera centre sees occluded
    hidden = ~near_sub & (hits[..., 0] * Z_NEAR / hits[..., 2] < X_EDGE)
    band = hidden.reshape(120, s, 160, s).any(axis=(1, 3))
    band_cols = np.flatnonzero(band.any(axis=0))
    grown = np.zeros_like(band)
    for dv in (-1, 0, 1):
        for du in (-1, 0, 1):
            grown |= np.roll(np.roll(band, dv, 0), du, 1)  # + the bilinear footprint of the neighbours
    err = np.abs(out.image[..., 0] - exact)
    outside, inside = err[~grown], err[band]
    width = band.sum(axis=1)
    print(f"occlusion: disocclusion band {width.min()}-{width.max()} px wide (columns {band_cols.min()}-"
          f"{band_cols.max()}); error outside the band max {outside.max():.3f} DN (of 255), inside max "
          f"{inside.max():.1f} DN, mean {inside.mean():.1f} DN; unresolved sub-rays {out.unresolved.sum()} "
          f"({np.count_nonzero(hidden)} predicted)")
    assert 1 <= width.max() <= 3  # parallax of the port: a ~1-3 px band at f = 160 px for these depths
    # everywhere else the stage agrees with the exact ray trace up to the bilinear interpolation of the smooth
    # textures in the render (~ A (pi / period)^2 / 2 <= 0.2 DN at these periods of 60 and 80 render px)
    assert outside.max() <= 0.3
    assert inside.max() > 5.0  # the band really is wrong (the test can see the approximation)
    # the unresolved sub-rays lie in the predicted band (+ the bilinear footprint of the depth edge), nowhere else
    unres_px = out.unresolved > 0
    assert np.all(grown[unres_px]) and unres_px.sum() >= 0.5 * band.sum()


def test_optics_preset_configs_in_file_units_and_overrides():
    from bench.sim.optics_presets import PRESET_CONFIGS, optics_from_config, optics_preset, preset_config

    for name in PRESET_CONFIGS:
        cfg = preset_config(name)
        built = optics_from_config(cfg, "test", name)
        if cfg["port"] is not None:
            assert built.port.d0 == cfg["port"]["lens_to_glass_mm"] * 1e-3
            assert built.port.t == cfg["port"]["glass_thickness_mm"] * 1e-3
            np.testing.assert_allclose(built.port.tilt, np.deg2rad(cfg["port"]["tilt_deg"]), rtol=1e-15)
            np.testing.assert_allclose(built.port.decentre, np.array(cfg["port"]["decentre_mm"]) * 1e-3, rtol=1e-15)
        cfg["sensor"]["jpeg_quality"] = 55
        assert PRESET_CONFIGS[name]["sensor"]["jpeg_quality"] == 0  # preset_config is a copy
    p = optics_preset("underwater_in_water", {"port": {"glass_thickness_mm": 8.0}, "light": None,
                                              "water": {"preset": "turbid_harbour"}, "sensor": {"jpeg_quality": 40}})
    assert p.port.t == 0.008 and p.port.d0 == 0.02 and p.chain.medium.name == "turbid_harbour"
    assert p.chain.light is None and p.chain.sensor.jpeg_quality == 40 and p.chain.sensor.read_noise_e == 5.0
    # the lab's frame grabber (section 5.3) belongs to the in-air lab camera; the dive camera is digital
    assert optics_preset("underwater_in_air").chain.sensor.digitiser_px == (320, 240)
    assert optics_preset("underwater_in_water").chain.sensor.digitiser_px is None
    assert optics_preset("air_webcam").chain.sensor.digitiser_px is None
    custom = optics_preset("underwater_in_water", {"water": None})
    assert custom.chain.medium is None and custom.port.n_water == 1.34
    water = {"beta_D_per_m": [0.4, 0.1, 0.05], "beta_B_per_m": [0.3, 0.1, 0.05], "B_inf": [0.0, 0.1, 0.2],
             "forward_scatter_px_per_m": 0.2}
    med = optics_preset("underwater_in_water", {"water": water}).chain.medium  # replaces the preset name whole
    assert med.name == "custom" and med.forward_scatter_px_per_m == 0.2
    np.testing.assert_array_equal(med.beta_D_per_m, water["beta_D_per_m"])
    np.testing.assert_array_equal(med.beta_B_per_m, water["beta_B_per_m"])
    np.testing.assert_array_equal(med.B_inf, water["B_inf"])


@pytest.mark.parametrize("preset, overrides, field", [
    ("underwater_in_water", {"port": {"glass_thickness_mm": -1.0}}, "port.glass_thickness_mm"),
    ("underwater_in_water", {"port": {"lens_to_glass_mm": 0.0}}, "port.lens_to_glass_mm"),
    ("underwater_in_water", {"port": {"n_glass": 0.9}}, "port.n_glass"),
    ("underwater_in_water", {"port": {"n_water": "sea"}}, "port.n_water"),
    ("underwater_in_water", {"port": {"tilt_deg": [50.0, 0.0]}}, "port.tilt_deg"),
    ("underwater_in_water", {"port": {"tilt_deg": [1.0]}}, "port.tilt_deg"),
    ("underwater_in_water", {"port": {"tilt_deg": [0.0, 40.0], "decentre_mm": [-30.0, 0.0]}}, "port.decentre_mm"),
    ("underwater_in_water", {"port": {"thickness": 3.0}}, "port.thickness"),
    ("underwater_in_water", {"water": {"preset": "bathtub"}}, "water.preset"),
    ("underwater_in_water", {"water": {"preset": "coastal", "B_inf": [0, 0, 0]}}, "water.B_inf"),
    ("air_webcam", {"water": {"beta_D_per_m": [-0.1, 0, 0], "beta_B_per_m": [0, 0, 0], "B_inf": [0, 0, 0],
                              "forward_scatter_px_per_m": 0.0}}, "water.beta_D_per_m"),
    ("underwater_in_air", {"water": {"preset": "coastal"}}, "water"),
    ("underwater_in_water", {"light": {"ref_range_m": 0.0}}, "light.ref_range_m"),
    ("underwater_in_water", {"light": {"axis": [0.0, 0.0, 0.0]}}, "light.axis"),
    ("underwater_in_water", {"sensor": {"jpeg_quality": 101}}, "sensor.jpeg_quality"),
    ("underwater_in_water", {"sensor": {"full_well_e": float("nan")}}, "sensor.full_well_e"),
    ("underwater_in_water", {"lens": {}}, "lens"),
    ("underwater_in_air", {"sensor": {"digitiser_px": [320]}}, "sensor.digitiser_px"),
    ("underwater_in_air", {"sensor": {"digitiser_px": [320.5, 240]}}, "sensor.digitiser_px"),
])
def test_impossible_optics_are_one_line_config_errors(preset, overrides, field):
    from bench.sim.optics_presets import optics_preset

    with pytest.raises(ConfigError) as exc:
        optics_preset(preset, overrides)
    assert exc.value.field == field and "\n" not in str(exc.value)
    assert str(exc.value).startswith(f"optics preset '{preset}': {field}: ")


def test_centred_port_keeps_the_glass_plane():
    """A decentred, tilted port as a centred one: with its tilt, the same plane (h and normal) at d0 = h / n_z; without
    it, the square port at that axial distance (plus an offset); a centred port's axial_d0 is its d0."""
    port = FlatPort(d0=0.02, t=0.008, tilt=np.array([0.02, -0.015]), decentre=np.array([0.003, -0.002]))
    same = port.centred()
    assert np.allclose(same.normal, port.normal, atol=0, rtol=0) and abs(same.h - port.h) < 1e-15
    assert not same.decentre.any() and same.d0 == port.axial_d0 and same.t == port.t
    square = port.centred(1e-3, keep_tilt=False)
    assert not square.tilt.any() and square.d0 == pytest.approx(port.axial_d0 + 1e-3, abs=1e-15)
    assert FlatPort(d0=0.02).axial_d0 == 0.02
