"""The realistic imaging stages (bench.sim.imaging) against closed forms and independent references."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from bench.errors import ConfigError
from bench.sim import imaging as im
from bench.sim.medium import Sensor

K = np.array([[975.3, 0.0, 329.3], [0.0, 975.3, 236.9], [0.0, 0.0, 1.0]])
SIZE = (640, 480)


def only(*stages, **overrides):
    """The realistic profile with every stage but ``stages`` off."""
    return im.imaging_profile("realistic", [s for s in im.STAGES if s not in stages], overrides=overrides or None)


def test_profiles_and_one_line_errors():
    assert im.imaging_profile("ideal").stages == {}
    assert set(im.imaging_profile("realistic").stages) == set(im.STAGES)
    assert "jpeg" not in im.imaging_profile("realistic", ["jpeg"]).stages
    with pytest.raises(ConfigError, match="camera.imaging.*realistic or ideal"):
        im.imaging_profile("fancy", source="s.yaml", field="camera.imaging")
    with pytest.raises(ConfigError, match="camera.imaging_off.*'jpg'"):
        im.imaging_profile("realistic", ["jpg"], source="s.yaml", field="camera.imaging")
    with pytest.raises(ConfigError, match="imaging_off.*list"):
        im.imaging_profile("realistic", "jpeg")
    with pytest.raises(ConfigError, match="imaging_params.defocus.f_number"):
        im.imaging_profile("realistic", overrides={"defocus": {"f_number": 0.1}})
    with pytest.raises(ConfigError, match="imaging_params.jpeg.quality"):
        im.imaging_profile("realistic", overrides={"jpeg": {"quality": 101}})


def test_coc_thin_lens_closed_form():
    f, N, df, pitch = 3.5e-3, 2.4, 1.0, 3.6e-6
    # by hand: aperture A = f / N; image distances v = f d / (d - f); blur c = A |v - v_f| / v
    for d in (0.4, 0.7, 1.0, 2.5, 10.0):
        v, vf = f * d / (d - f), f * df / (df - f)
        c = (f / N) * abs(v - vf) / v / pitch
        assert im.coc_diameter_px(d, f, N, df, pitch) == pytest.approx(c, rel=1e-12)
    assert im.coc_diameter_px(1.0, f, N, df, pitch) == 0.0
    assert im.coc_diameter_px(np.inf, f, N, df, pitch) == pytest.approx((f / N) * f / (df - f) / pitch)


def test_disk_kernel_second_moment():
    for R in (2.5, 4.0, 6.0):  # Sheppard's 1/12 holds once the disk spans several pixels
        k = im.disk_kernel(R)
        n = k.shape[0] // 2
        x = np.arange(-n, n + 1)
        assert k.sum() == pytest.approx(1.0, abs=1e-6)
        # a uniform disk of radius R has variance R^2 / 4 per axis (plus 1/12 px^2 of the pixel's own extent)
        assert float((k.sum(0) * x ** 2).sum()) == pytest.approx(R ** 2 / 4 + 1 / 12, rel=0.03)


def test_defocus_blur_is_the_disk_of_the_thin_lens_radius():
    prof = only("defocus", defocus={"lens_sigma_px": 0.0})
    chain = im.ImagingChain(prof, K, SIZE)
    p = prof["defocus"]
    f, pitch = K[0, 0] * p["pixel_pitch_um"] * 1e-6, p["pixel_pitch_um"] * 1e-6
    # the depth whose circle of confusion has radius 1.0 px exactly (nearer than the focus distance)
    A, df = f / p["f_number"], p["focus_distance_m"]
    g = 2.0 * pitch * (df - f) / (A * f)  # |d - df| / d
    d = df / (1 + g)
    assert 0.5 * im.coc_diameter_px(d, f, p["f_number"], df, pitch) == pytest.approx(1.0, rel=1e-9)
    rng = np.random.default_rng(3)
    img = rng.uniform(0, 1, (SIZE[1], SIZE[0], 3)).astype(np.float32)
    out = chain.blur(img, np.full(img.shape[:2], d), np.zeros(2))
    ref = cv2.filter2D(img, -1, im.disk_kernel(1.0), borderType=cv2.BORDER_REFLECT)
    assert np.abs(out - ref).max() < 1e-5
    # at the focus distance nothing is blurred
    assert np.abs(chain.blur(img, np.full(img.shape[:2], df), np.zeros(2)) - img).max() < 1e-6


def test_jpeg_stage_is_opencv_encoder_at_that_quality():
    prof = only("jpeg")
    chain = im.ImagingChain(prof, K, SIZE)
    rng = np.random.default_rng(0)
    img = cv2.GaussianBlur(rng.uniform(0, 1, (SIZE[1], SIZE[0], 3)).astype(np.float32), (0, 0), 2)
    out = chain.sensor(img, rng, None)
    u8 = np.clip(np.rint(img * 255.0), 0, 255).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", u8[..., ::-1].copy(), [cv2.IMWRITE_JPEG_QUALITY, 90])
    ref = cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1]
    assert np.array_equal(out, ref)


def test_frame_grabber_samples_cell_means_and_the_spline_passes_through_them():
    rng = np.random.default_rng(7)
    frame = cv2.GaussianBlur(rng.uniform(0, 255, (60, 90, 3)).astype(np.float32), (0, 0), 1.5)
    frame = np.clip(np.rint(frame), 0, 255).astype(np.uint8)
    out = im.frame_grab(frame, (30, 20), "cubic_spline")  # a 3x grabber: output pixel 3k+1 lies on sample k
    cells = np.rint(frame.astype(float).reshape(20, 3, 30, 3, 3).mean(axis=(1, 3)))  # the grabber's 8-bit samples
    assert out.shape == frame.shape and out.dtype == np.uint8
    assert np.array_equal(out[1::3, 1::3], cells)  # an interpolating spline reproduces its samples
    # between the samples it is the cubic B-spline's, not OpenCV's cubic convolution (the test can tell them apart)
    assert not np.array_equal(out, im.frame_grab(frame, (30, 20), "bicubic"))
    ref = cv2.resize(cells.astype(np.uint8), (90, 60), interpolation=cv2.INTER_CUBIC)
    assert np.array_equal(im.frame_grab(frame, (30, 20), "bicubic"), ref)
    with pytest.raises(ValueError, match="must not exceed"):
        im.frame_grab(frame, (100, 20))
    with pytest.raises(ValueError, match="upsample"):
        im.frame_grab(frame, (30, 20), "lanczos")


@pytest.mark.parametrize("method", im.UPSAMPLE)
def test_frame_grabber_keeps_a_spot_where_it_was_and_halves_the_resolution(method):
    v, u = np.mgrid[0:480, 0:640].astype(float)
    cx, cy = 321.3, 240.7
    spot = 40 + 180 * np.exp(-((u - cx) ** 2 + (v - cy) ** 2) / (2 * 12.0 ** 2))
    frame = np.repeat(np.rint(spot)[..., None], 3, -1).astype(np.uint8)
    f = im.frame_grab(frame, (320, 240), method)[..., 1].astype(float) - 40
    assert abs((f * u).sum() / f.sum() - cx) < 0.01 and abs((f * v).sum() / f.sum() - cy) < 0.01
    # a one-pixel checkerboard (above the grabber's Nyquist frequency) is averaged away to its mean
    board = np.where((u + v) % 2 == 0, 200, 50)[..., None].repeat(3, -1).astype(np.uint8)
    assert np.abs(im.frame_grab(board, (320, 240), method).astype(int) - 125).max() <= 1


def test_frame_grabber_stage_needs_an_analog_camera_and_can_be_switched_off():
    rng = np.random.default_rng(3)
    img = cv2.GaussianBlur(rng.uniform(0.1, 0.9, (SIZE[1], SIZE[0], 3)).astype(np.float32), (0, 0), 1.0)
    analog, digital = Sensor(digitiser_px=(320, 240)), Sensor()
    on = im.ImagingChain(only("frame_grabber"), K, SIZE)
    off = im.ImagingChain(only(), K, SIZE)
    grabbed = on.sensor(img, np.random.default_rng(1), analog)
    plain = off.sensor(img, np.random.default_rng(1), analog)
    assert np.array_equal(on.sensor(img, np.random.default_rng(1), digital), plain)  # a digital camera: no grabber
    assert np.array_equal(grabbed, im.frame_grab(plain, (320, 240)))
    assert np.std(grabbed.astype(float) - plain) > 1.0
    with pytest.raises(ValueError, match="digitiser_px"):
        Sensor(digitiser_px=(320, 2.5))
    with pytest.raises(ConfigError, match="imaging_params.frame_grabber.upsample"):
        im.imaging_profile("realistic", overrides={"frame_grabber": {"upsample": "nearest"}})


def test_bayer_mosaic_and_round_trip():
    rgb = np.zeros((8, 10, 3), np.uint8)
    rgb[..., 0], rgb[..., 1], rgb[..., 2] = 200, 120, 40
    raw = im.mosaic(rgb)
    assert raw[0, 0] == 200 and raw[0, 1] == 120 and raw[1, 0] == 120 and raw[1, 1] == 40  # RGGB
    for method in ("bilinear", "edge_aware", "vng"):
        back = im.demosaic(raw, method)
        assert np.array_equal(back[2:-2, 2:-2], rgb[2:-2, 2:-2]), method
    # a smooth colour image survives the round trip to within a few DN
    rng = np.random.default_rng(1)
    smooth = cv2.resize(rng.uniform(30, 220, (6, 8, 3)).astype(np.float32), (320, 240), interpolation=cv2.INTER_CUBIC)
    smooth = np.clip(smooth, 0, 255).astype(np.uint8)
    back = im.demosaic(im.mosaic(smooth), "edge_aware").astype(int)
    assert np.abs(back - smooth)[4:-4, 4:-4].mean() < 1.5


def test_rolling_shutter_row_timing():
    t = im.row_times_s(480, 0.03)
    assert t[0] == pytest.approx(-239.5 * 0.03 / 480) and t[-1] == pytest.approx(239.5 * 0.03 / 480)
    assert np.allclose(np.diff(t), 0.03 / 480)
    prof = only("rolling_shutter")
    chain = im.ImagingChain(prof, K, SIZE)
    img = np.zeros((SIZE[1], SIZE[0], 3), np.float32)
    img[:, 300:340] = 1.0  # a vertical bar
    img = cv2.GaussianBlur(img, (0, 0), 1.5)
    v = np.array([400.0, 0.0])  # px/s: 12 px over the readout
    out = chain.warp(img, v)
    u = np.arange(SIZE[0])
    for r in (0, 120, 240, 360, 479):
        c0 = np.sum(img[r, :, 1] * u) / img[r, :, 1].sum()
        c1 = np.sum(out[r, :, 1] * u) / out[r, :, 1].sum()
        assert c1 - c0 == pytest.approx(v[0] * t[r], abs=0.02)


def test_thin_prism_and_lateral_ca_displacements():
    s1 = 0.002
    prof = only("distortion", "chromatic", distortion={"thin_prism": [s1, 0.0, 0.0, 0.0]},
                chromatic={"lateral_ca_r": 0.001, "lateral_ca_b": 0.0})
    chain = im.ImagingChain(prof, K, SIZE)
    img = np.zeros((SIZE[1], SIZE[0], 3), np.float32)
    p = np.array([560.0, 400.0])
    cv2.circle(img, (int(p[0]), int(p[1])), 3, (1, 1, 1), -1)
    img = cv2.GaussianBlur(img, (0, 0), 1.5)
    out = chain.warp(img, np.zeros(2))
    vv, uu = np.mgrid[0:SIZE[1], 0:SIZE[0]]

    def centroid(a):
        return np.array([np.sum(a * uu), np.sum(a * vv)]) / a.sum()

    c = centroid(img[..., 1])
    x, y = (c[0] - K[0, 2]) / K[0, 0], (c[1] - K[1, 2]) / K[1, 1]
    d_prism = np.array([s1 * (x * x + y * y) * K[0, 0], 0.0])
    assert np.allclose(centroid(out[..., 1]) - c, d_prism, atol=0.03)  # G: the thin prism
    assert np.allclose(centroid(out[..., 0]) - c, d_prism + 0.001 * (c - K[:2, 2]), atol=0.03)  # R: + lateral CA


def test_chain_reproducible_from_seed_and_fixed_pattern_per_camera():
    prof = im.imaging_profile("realistic")
    chain = im.ImagingChain(prof, K, SIZE)
    rng = np.random.default_rng(5)
    img = rng.uniform(0.1, 0.9, (SIZE[1], SIZE[0], 3)).astype(np.float32)
    depth = np.full(SIZE[::-1], 0.9)
    spec = Sensor()
    a = chain.apply(img, depth, np.random.default_rng(11), spec)
    b = im.ImagingChain(prof, K, SIZE).apply(img, depth, np.random.default_rng(11), spec)
    c = chain.apply(img, depth, np.random.default_rng(12), spec)
    assert a.dtype == np.uint8 and a.shape == img.shape
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    # PRNU/DSNU: the same pattern in every frame of the camera (from pattern_seed, not the frame's seed)
    assert np.array_equal(chain._prnu, im.ImagingChain(prof, K, SIZE)._prnu)


def test_cockle_field_has_its_stated_covariance():
    """The cockle's draws (Monte Carlo, 4000 boards) have the closed-form variance and neighbour correlations."""
    p = im.REALISTIC["cockle"]
    s = 0.197 / 7
    L = im.cockle_factor(p, 8, s)
    z = (L @ np.random.default_rng(4).standard_normal((64, 4000))).reshape(8, 8, -1)
    assert np.sqrt(np.mean(z ** 2)) == pytest.approx(p["rms_mm"] * 1e-3, rel=0.03)

    def corr(a, b):
        return np.sum(a * b) / np.sqrt(np.sum(a * a) * np.sum(b * b))

    along = np.exp(-0.5 * (s / (p["length_along_rows_mm"] * 1e-3)) ** 2)
    across = np.exp(-0.5 * (s / (p["length_across_rows_mm"] * 1e-3)) ** 2)
    assert corr(z[:, :-1], z[:, 1:]) == pytest.approx(along, abs=0.02)  # neighbours along a row (x)
    assert corr(z[:-1], z[1:]) == pytest.approx(across, abs=0.02)  # neighbours across the rows (y)


def test_cockle_draws_do_not_depend_on_rounding():
    """A seed must give the same rig on every machine: the cockle's factor is an eigen-decomposition, whose basis is
    arbitrary where eigenvalues repeat (bench.camera.target_tolerance.sample_factor had that problem). Here they
    are apart (smallest gap 5e-4 of the largest: the two correlation lengths differ), so under a 1e-15 perturbation
    of the covariance - another thread count or CPU kernel - every eigenvector stays itself to 1e-9, up to its sign.
    The sign is LAPACK's choice: numpy's bundled OpenBLAS makes the same one on every machine; a sign-free factor
    (the symmetric square root) would change every simulated rig, so it is left."""
    p = im.REALISTIC["cockle"]
    n, s = 8, 0.197 / 7
    L = im.cockle_factor(p, n, s)
    C = L @ L.T
    w, V = np.linalg.eigh(C)
    assert np.min(np.diff(w)) > 1e-5 * w.max()
    E = np.random.default_rng(1).standard_normal(C.shape)
    E = 0.5 * (E + E.T) * 1e-15 * np.abs(C).max()
    _, Vp = np.linalg.eigh(C + E)
    assert np.abs(np.abs(np.sum(V * Vp, axis=0)) - 1).max() < 1e-9


def test_cockle_moves_the_corners_out_of_plane_only():
    from bench.sim.scenes.rig import calibration_rig

    exact = calibration_rig()
    e = im.target_geometry(only("cockle"), 7, np.random.default_rng(0))
    rig = calibration_rig(errors=e)
    d = rig.features["corners_board_a"] - exact.features["corners_board_a"]
    assert np.allclose(d[:, [0, 2]], 0.0, atol=1e-15)  # board A's normal is the rig's y
    assert np.allclose(-d[:, 1], e["dz_m"]["a"][1:-1, 1:-1].ravel(), atol=1e-15)  # z into the board = -y of the rig
    assert 0.2e-3 < np.std(e["dz_m"]["a"]) < 0.7e-3
    # switching the cockle off leaves every other draw as it was
    a = im.target_geometry(im.imaging_profile("realistic"), 7, np.random.default_rng(9))
    b = im.target_geometry(im.imaging_profile("realistic", ["cockle"]), 7, np.random.default_rng(9))
    assert a["scale"] == b["scale"] and a["fold_error_rad"] == b["fold_error_rad"]
    assert np.array_equal(a["line_offsets_m"]["b"][1], b["line_offsets_m"]["b"][1]) and not np.any(b["dz_m"]["a"])


def test_target_geometry_moves_the_printed_corners():
    from bench.sim.scenes.rig import calibration_rig

    exact = calibration_rig()
    zero = calibration_rig(errors=im.target_geometry(im.imaging_profile("ideal"), 7, np.random.default_rng(0)))
    assert np.allclose(zero.features["corners"], exact.features["corners"], atol=1e-15)
    e = im.target_geometry(only("print_lines"), 7, np.random.default_rng(0))
    rig = calibration_rig(errors=e)
    d = rig.features["corners_board_a"] - exact.features["corners_board_a"]
    # board A's rows run along -z of the rig, its columns along -x: corner (i, j) moves by (ys[i+1], xs[j+1])
    xs, ys = e["line_offsets_m"]["a"]
    assert np.allclose(d[:, 2], -np.repeat(ys[1:-1], 6), atol=1e-12)
    assert np.allclose(d[:, 0], -np.tile(xs[1:-1], 6), atol=1e-12)
    assert 0.02e-3 < np.std(ys) < 0.2e-3  # feed 0.09 mm rms
    bow = calibration_rig(errors=im.target_geometry(only("flatness"), 7, np.random.default_rng(0)))
    dz = bow.features["corners_board_a"] - exact.features["corners_board_a"]
    assert 0.2e-3 < np.abs(dz[:, 1]).max() <= 0.6e-3 + 1e-12  # board A's normal is the rig's y


def test_srgb_transfer_is_the_standards():
    """IEC 61966-2-1: linear segment 12.92 x up to 0.0031308, 1.055 x^(1/2.4) - 0.055 above; the standard's own
    inverse (decoding) takes every encoded value back."""
    assert im.srgb_oetf(0.0) == 0.0 and im.srgb_oetf(1.0) == pytest.approx(1.0, abs=1e-12)
    assert im.srgb_oetf(0.0031308) == pytest.approx(0.0031308 * 12.92, rel=1e-12)
    assert im.srgb_oetf(0.18) == pytest.approx(0.461356, abs=1e-6)  # 18 % grey: 117.6 DN
    x = np.linspace(0, 1, 1001)
    v = im.srgb_oetf(x)
    back = np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)
    assert np.abs(back - x).max() < 1e-6  # the standard rounds its breakpoint (0.04045 vs 0.0404482)
    assert np.abs(im.srgb_eotf(v) - back).max() < 1e-12
    assert np.all(np.diff(v) > 0)


def test_tone_stage_codes_through_the_adc_and_the_transfer_function():
    """A flat linear field through the ADC (10 bit), the transfer function and 8 bits; the exposure scale acts on
    a manual-exposure camera only (the automatic exposure meters the scene itself)."""
    prof = only("tone")
    chain = im.ImagingChain(prof, K, SIZE)
    img = np.full((SIZE[1], SIZE[0], 3), 0.18, np.float32)
    out = chain.sensor(img, np.random.default_rng(0), None)
    code = np.rint(0.18 * 1023)
    assert np.all(out == np.rint(255 * im.srgb_oetf(code / 1023)))  # 118 DN
    quiet = Sensor(read_noise_e=0.0, full_well_e=1e8, gain_dn_per_e=255.0 / 1e8)  # shot noise ~1e-4 of the signal
    k = prof["tone"]["exposure_scale"]
    manual = chain.sensor(img, np.random.default_rng(1), quiet).astype(float).mean()
    assert manual == pytest.approx(255 * im.srgb_oetf(0.18 * k), abs=0.6)
    auto = Sensor(read_noise_e=0.0, full_well_e=1e8, gain_dn_per_e=255.0 / 1e8, auto_exposure_target=0.4)
    # the automatic exposure's target is a grey level of the encoded output: a flat field reads it exactly
    assert chain.sensor(img, np.random.default_rng(1), auto).astype(float).mean() == pytest.approx(255 * 0.4, abs=0.6)


def test_unsharp_mask_closed_forms():
    """Flat and linear-ramp luma are left alone (the Gaussian reproduces both); a step gets the undershoot
    ``amount h (Phi(x / sigma) - H(x))`` (continuous closed form, here at the pixel beside the edge within the
    pixel sampling); a pure chroma change is not sharpened; coring removes detail below its threshold."""
    from scipy.special import ndtr

    H, W = 40, 200
    ramp = np.tile(np.linspace(40, 200, W, dtype=np.float32), (H, 1))[..., None].repeat(3, 2)
    out = im.unsharp_luma(ramp, 2.0, 1.5)
    assert np.abs(out - ramp)[:, 20:-20].max() < 1e-3
    flat = np.full((H, W, 3), 90, np.float32)
    assert np.abs(im.unsharp_luma(flat, 2.0, 1.5) - flat).max() < 1e-4
    # a step of h DN between pixels 99 and 100 (edge at x = 99.5)
    h, a, s = 100.0, 1.5, 2.0
    step = np.zeros((H, W, 3), np.float32)
    step[:, 100:] = h
    out = im.unsharp_luma(step, a, s)[H // 2, :, 0]
    x = np.arange(W) - 99.5
    # the sampled Gaussian of OpenCV against the continuous one: within 1 % of the step at every pixel
    expected = h * (x > 0) + a * (h * (x > 0) - h * ndtr(x / s))
    assert np.abs(out - expected)[20:-20].max() < 0.01 * a * h
    assert out[99] == pytest.approx(-a * h * ndtr(-0.5 / s), rel=0.05)
    # equal luma, different colour: no detail to sharpen
    chroma = np.zeros((H, W, 3), np.float32)
    chroma[:, :100] = (100.0, 100.0, 100.0)
    chroma[:, 100:] = (100.0 + 0.587 / 0.299 * 20, 80.0, 100.0)  # 0.299 dR + 0.587 dG = 0
    assert np.abs(im.unsharp_luma(chroma, a, s) - chroma).max() < 1e-3
    # coring: noise of 0.3 DN rms under a 1 DN threshold is not amplified
    rng = np.random.default_rng(0)
    noisy = flat + rng.normal(0, 0.3, (H, W, 1)).astype(np.float32).repeat(3, 2)
    sharpened = im.unsharp_luma(noisy, a, s, coring_dn=1.0)
    assert np.abs(sharpened - noisy).max() < 0.5 and np.std(im.unsharp_luma(noisy, a, s) - noisy) > 0.2


def test_toner_black_reaches_the_rendered_board():
    """The ``toner`` stage states the printed black's reflectance; ideal imaging keeps the scene's default."""
    from bench.sim.scenes.rig import BLACK_REFLECTANCE

    g = im.target_geometry(im.imaging_profile("realistic"), 7, np.random.default_rng(0))
    assert g["black_reflectance"] == im.REALISTIC["toner"]["black_reflectance"] != BLACK_REFLECTANCE
    g = im.target_geometry(im.imaging_profile("realistic", ["toner"]), 7, np.random.default_rng(0))
    assert g["black_reflectance"] == BLACK_REFLECTANCE


def test_stage_parameters_from_the_scenario_are_checked_by_name():
    """``camera.imaging_params`` replaces a stage's parameters; a wrong stage, key, type or range is a one-line error
    naming it, under ideal imaging too."""
    prof = im.imaging_profile("realistic", overrides={"sharpen": {"coring_dn": 1.5}}, field="camera.imaging")
    assert prof["sharpen"]["coring_dn"] == 1.5 and prof["sharpen"]["amount"] == im.REALISTIC["sharpen"]["amount"]
    assert im.REALISTIC["sharpen"]["coring_dn"] != 1.5  # the module's profile is not modified
    for bad, match in (({"sharpn": {"amount": 1}}, r"camera\.imaging_params\.sharpn: unknown stage"),
                       ({"sharpen": {"amt": 1}}, r"camera\.imaging_params\.sharpen\.amt: unknown key"),
                       ({"sharpen": {"amount": "lots"}}, r"camera\.imaging_params\.sharpen\.amount: expected a number"),
                       ({"tone": {"exposure_scale": -1}}, r"camera\.imaging_params\.tone\.exposure_scale"),
                       ({"tone": 5}, r"camera\.imaging_params\.tone: unknown stage or not a mapping"),
                       ({"tone": {"adc_bits": 10.5}}, r"camera\.imaging_params\.tone\.adc_bits: expected whole bits"),
                       ({"distortion": {"dist": [-0.02, -0.2, 0.0]}},
                        r"camera\.imaging_params\.distortion\.dist: expected 5 finite numbers"),
                       ({"distortion": {"thin_prism": [float("nan"), 0, 0, 0]}},
                        r"camera\.imaging_params\.distortion\.thin_prism: expected 4 finite numbers")):
        for name in ("realistic", "ideal"):
            with pytest.raises(ConfigError, match=match):
                im.imaging_profile(name, overrides=bad, source="s.yaml", field="camera.imaging")
