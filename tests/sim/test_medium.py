"""Water medium and sensor (issue 3 item 4c): each effect on its own, noise statistics, JPEG, seeding, bad input."""

import cv2
import numpy as np
import pytest
from scipy.stats import norm

from bench.sim.medium import (
    Light,
    MediumChain,
    Sensor,
    WaterMedium,
    apply_medium,
    attenuate,
    cos_beam,
    encode_jpeg,
    forward_scatter,
    illuminate,
    jpeg,
    lamp_geometry,
    path_length_m,
    pixel_rays,
    sensor,
    water_preset,
)

K = np.array([[100.0, 0.0, 31.5], [0.0, 105.0, 23.5], [0.0, 0.0, 1.0]])
SIZE = (64, 48)


def _texture(rng, h=48, w=64):
    return rng.uniform(0.05, 0.9, (h, w, 3))


def test_zero_path_leaves_the_image_unchanged():
    rng = np.random.default_rng(11)
    img = _texture(rng)
    zero = np.zeros(img.shape[:2])
    for name in ("clear_ocean", "coastal", "turbid_harbour"):
        med = water_preset(name)
        np.testing.assert_array_equal(attenuate(img, zero, med), img)
        np.testing.assert_array_equal(forward_scatter(img, zero, med.forward_scatter_px_per_m), img)
        out = apply_medium(img, zero, rng, MediumChain(medium=med))
        np.testing.assert_array_equal(out, img)


def test_attenuation_ratio_per_channel_on_a_grey_target():
    med = WaterMedium(beta_D_per_m=(0.6, 0.25, 0.35), beta_B_per_m=(0.5, 0.3, 0.4), B_inf=(0.0, 0.0, 0.0))
    grey = np.full((4, 5, 3), 0.5)
    r = np.linspace(0.0, 4.0, 20).reshape(4, 5)
    out = attenuate(grey, r, med)
    ratio = out / grey
    np.testing.assert_allclose(ratio, np.exp(-med.beta_D_per_m * r[..., None]), rtol=0, atol=1e-15)
    # with veiling light: the backscatter term adds exactly B_inf (1 - exp(-beta_B r)), independent of the target
    med2 = WaterMedium(beta_D_per_m=med.beta_D_per_m, beta_B_per_m=med.beta_B_per_m, B_inf=(0.1, 0.3, 0.2))
    np.testing.assert_allclose(attenuate(grey, r, med2) - out,
                               med2.B_inf * (1 - np.exp(-med2.beta_B_per_m * r[..., None])), atol=1e-15)


def test_backscatter_tends_to_veiling_light():
    med = water_preset("coastal")
    img = _texture(np.random.default_rng(12), 3, 4)
    far = attenuate(img, np.full((3, 4), 60.0), med)
    assert np.abs(far - med.B_inf).max() <= 1e-6
    np.testing.assert_array_equal(attenuate(img, np.full((3, 4), np.inf), med), np.broadcast_to(med.B_inf, (3, 4, 3)))
    ranges = np.array([[0.5, 1.0, 2.0, 4.0, 8.0]])
    dist = np.abs(attenuate(np.zeros((1, 5, 3)), ranges, med) - med.B_inf).max(axis=-1)[0]
    assert np.all(np.diff(dist) < 0)  # monotone approach


def test_path_length_from_depth():
    rays = pixel_rays(K, SIZE)
    z = np.full((48, 64), 2.0)
    r = path_length_m(z, rays)
    uu, vv = np.meshgrid(np.arange(64.0), np.arange(48.0))
    x, y = (uu - K[0, 2]) / K[0, 0], (vv - K[1, 2]) / K[1, 1]
    np.testing.assert_allclose(r, 2.0 * np.sqrt(1 + x**2 + y**2), rtol=1e-15)
    z[0, 0] = np.inf
    assert np.isinf(path_length_m(z, rays)[0, 0])


def test_light_falloff_inverse_square_and_beam():
    light = Light(ref_range_m=1.0, beam_exponent=3.0, ambient=0.0)
    img = np.full((1, 3, 3), 0.4)
    r = np.array([[1.0, 2.0, 4.0]])
    out = illuminate(img, r, np.ones((1, 3)), light)
    np.testing.assert_allclose(out[0, :, 0], 0.4 / r[0] ** 2, rtol=1e-15)
    c = np.array([[1.0, 0.9, 0.5]])
    out = illuminate(img, np.ones((1, 3)), c, light)
    np.testing.assert_allclose(out[0, :, 1], 0.4 * c[0] ** 3, rtol=1e-15)
    med = water_preset("turbid_harbour")
    out = illuminate(img, r, np.ones((1, 3)), light, med)
    np.testing.assert_allclose(out[0], 0.4 / r[0, :, None] ** 2 * np.exp(-med.beta_D_per_m * r[0, :, None]),
                               rtol=1e-14)
    assert np.all(illuminate(img, np.full((1, 3), np.inf), np.ones((1, 3)), light) == 0)
    np.testing.assert_allclose(cos_beam(pixel_rays(K, SIZE))[23, 31], 1 / np.sqrt(1 + (0.5 / 100) ** 2 +
                                                                              (0.5 / 105) ** 2), rtol=1e-14)


def test_forward_scatter_blurs_more_with_range():
    img = np.zeros((40, 60, 3))
    img[:, 30:] = 1.0  # a vertical step edge
    near = forward_scatter(img, np.full((40, 60), 1.0), 0.5, 3.0)
    far = forward_scatter(img, np.full((40, 60), 5.0), 0.5, 3.0)

    def width(im):
        row = im[20, :, 0]
        return np.count_nonzero((row > 0.05) & (row < 0.95))

    assert 0 < width(near) < width(far)
    # at an exact blur level the result is that Gaussian blur (mean and symmetry of the edge preserved)
    assert abs(far[20, 29, 0] + far[20, 30, 0] - 1.0) <= 1e-6


def test_noise_variance_matches_shot_plus_read_model():
    spec = Sensor(full_well_e=2000.0, exposure=1.0, gain_dn_per_e=0.12, read_noise_e=6.0)
    rng = np.random.default_rng(13)
    level = 0.4
    img = np.full((200, 200, 3), level)
    out = sensor(img, rng, spec).astype(float)
    mean_e = level * spec.full_well_e
    var_model = spec.gain_dn_per_e**2 * (mean_e + spec.read_noise_e**2) + 1.0 / 12.0  # + quantisation
    n = out.size
    var = out.var(ddof=1)
    tol = 5 * var_model * np.sqrt(2.0 / (n - 1))  # 5 standard errors of a sample variance
    print(f"sensor: variance {var:.4f} DN^2 vs model {var_model:.4f} (tolerance {tol:.4f}); mean {out.mean():.3f} vs "
          f"{spec.gain_dn_per_e * mean_e:.3f} DN")
    assert abs(var - var_model) <= tol
    assert abs(out.mean() - spec.gain_dn_per_e * mean_e) <= 5 * np.sqrt(var_model / n) + 0.01
    # read noise alone (dark frame, gain 1), clipped at 0: P(DN >= k) = P(N(0, 3^2) >= k - 1/2)
    dark = sensor(np.zeros((200, 200, 3)), rng, Sensor(gain_dn_per_e=1.0, read_noise_e=3.0)).astype(float)
    for k in (1, 3, 6):
        p = norm.sf((k - 0.5) / 3.0)
        assert abs(np.mean(dark >= k) - p) <= 5 * np.sqrt(p * (1 - p) / dark.size)
    # full well clips: 5x full well gives Poisson(full well) electrons, mean 200 DN with sd 0.2 sqrt(1000) = 6.3 DN
    # (12 pixels all within +-10 DN, the check this replaces, holds with probability 0.23 only)
    sat = sensor(np.full((100, 100, 3), 5.0), rng, Sensor(full_well_e=1000.0, gain_dn_per_e=0.2, read_noise_e=0.0))
    sd = 0.2 * np.sqrt(1000.0)
    assert abs(sat.mean() - 200.0) <= 5 * sd / np.sqrt(sat.size)
    assert abs(sat.astype(float).std() / np.sqrt(sd**2 + 1 / 12) - 1) <= 5 * np.sqrt(0.5 / sat.size)
    assert sat.max() <= 200 + 6 * sd


def test_same_seed_same_image_and_jpeg_ordering():
    rng = np.random.default_rng(14)
    img = _texture(rng, 64, 96)
    med = water_preset("coastal")
    chain = MediumChain(medium=med, light=Light(ambient=0.3), sensor=Sensor())
    r = np.full((64, 96), 1.5)
    c = np.ones((64, 96))
    a = apply_medium(img, r, np.random.default_rng(5), chain, c)
    b = apply_medium(img, r, np.random.default_rng(5), chain, c)
    d = apply_medium(img, r, np.random.default_rng(6), chain, c)
    assert a.dtype == np.uint8 and np.array_equal(a, b) and not np.array_equal(a, d)
    smooth = cv2.GaussianBlur(img, (0, 0), 2.0)
    clean = np.clip(np.rint(smooth * 255), 0, 255).astype(np.uint8)
    errs = [np.sqrt(np.mean((jpeg(clean, q).astype(float) - clean) ** 2)) for q in (95, 75, 40, 10)]
    print("JPEG rms error (DN) at quality 95/75/40/10:", np.round(errs, 2))
    assert all(e1 < e2 for e1, e2 in zip(errs, errs[1:], strict=False))
    assert np.array_equal(jpeg(clean, 0), clean)


@pytest.mark.parametrize("make, match", [
    (lambda: WaterMedium(beta_D_per_m=(-0.1, 0, 0)), "beta_D_per_m"),
    (lambda: WaterMedium(B_inf=(0.1, 2.0, 0.1)), "B_inf"),
    (lambda: WaterMedium(beta_B_per_m=(0.1, 0.2)), "beta_B_per_m"),
    (lambda: Light(ref_range_m=0.0), "ref_range_m"),
    (lambda: Sensor(jpeg_quality=101), "jpeg_quality"),
    (lambda: Sensor(full_well_e=float("nan")), "full_well_e"),
    (lambda: water_preset("bathtub"), "clear_ocean, coastal, turbid_harbour"),
    (lambda: attenuate(np.zeros((2, 2, 3)), np.full((2, 2), np.nan), water_preset("coastal")), "path_m"),
    (lambda: attenuate(np.zeros((2, 2)), np.zeros((2, 2)), water_preset("coastal")), "image"),
    (lambda: sensor(np.zeros((2, 2, 3)), 3, Sensor()), "rng"),
    (lambda: apply_medium(np.zeros((2, 2, 3)), np.ones((2, 2)), np.random.default_rng(0),
                          MediumChain(light=Light())), "cos_theta"),
])
def test_bad_input(make, match):
    with pytest.raises(ValueError, match=match) as exc:
        make()
    assert "\n" not in str(exc.value)


def test_offset_lamp_geometry_and_falloff():
    rays = pixel_rays(K, SIZE)
    pts = rays * 2.0  # a fronto-parallel wall at z = 2 m
    # co-located: lamp_geometry gives the ray length and the ray's angle to the optical axis
    r0, c0 = lamp_geometry(pts, Light())
    np.testing.assert_allclose(r0, path_length_m(np.full((48, 64), 2.0), rays), rtol=1e-15)
    np.testing.assert_allclose(c0, cos_beam(rays), rtol=1e-15)
    # a lamp 0.3 m to the right, tilted 10 deg towards the axis
    ang = np.deg2rad(-10.0)
    light = Light(ref_range_m=1.5, beam_exponent=4.0, position_m=(0.3, 0.0, 0.0), axis=(np.sin(ang), 0, np.cos(ang)))
    r, c = lamp_geometry(pts, light)
    v = pts - np.array([0.3, 0.0, 0.0])
    np.testing.assert_allclose(r, np.linalg.norm(v, axis=-1), rtol=1e-15)
    np.testing.assert_allclose(c, v @ light.axis / np.linalg.norm(v, axis=-1), rtol=1e-14)
    # the brightest point on the wall is where the beam axis meets it: x = 0.3 + 2 tan(-10 deg) < 0.3
    img = np.full((48, 64, 3), 0.5)
    out = apply_medium(img, np.linalg.norm(pts, axis=-1), np.random.default_rng(0), MediumChain(light=light),
                       points_cam=pts)
    np.testing.assert_allclose(out[..., 0], 0.5 * (1.5 / r) ** 2 * c**4, rtol=1e-14)
    lit = out[24, :, 0]
    u_peak = np.argmax(lit)
    assert lit[u_peak] > lit[0] and lit[u_peak] > lit[-1]  # a beam spot inside the image (not at the border)
    # the analytic spot on that row, from a fine 1D search of (1 / r^2) cos^4 along the wall
    x_fine = np.linspace(-1.0, 1.0, 200001)
    y_row = (24 - K[1, 2]) / K[1, 1] * 2.0
    v_fine = np.stack([x_fine - 0.3, np.full_like(x_fine, y_row), np.full_like(x_fine, 2.0)], -1)
    r_fine = np.linalg.norm(v_fine, axis=-1)
    x_true = x_fine[np.argmax((v_fine @ light.axis / r_fine) ** 4 / r_fine**2)]
    u_true = K[0, 2] + K[0, 0] * x_true / 2.0
    assert 0.3 + 2.0 * np.tan(ang) < x_true < 0.3  # between the beam axis and the lamp's foot (1/r^2 pull)
    assert abs(u_peak - u_true) <= 0.5 + 1e-9
    # background pixels get no lamp light
    pts_bg = pts.copy()
    pts_bg[0, 0] = np.inf
    r_bg, c_bg = lamp_geometry(pts_bg, light)
    assert np.isinf(r_bg[0, 0]) and c_bg[0, 0] == 0
    # an offset lamp needs the points
    with pytest.raises(ValueError, match="points_cam"):
        apply_medium(img, np.ones((48, 64)), np.random.default_rng(0), MediumChain(light=light), np.ones((48, 64)))


def test_jpeg_quality_100_beats_30_in_size_and_psnr():
    rng = np.random.default_rng(15)
    img = np.clip(np.rint(cv2.GaussianBlur(_texture(rng, 64, 96), (0, 0), 1.5) * 255), 0, 255).astype(np.uint8)

    def psnr(a):
        return 10 * np.log10(255.0**2 / np.mean((a.astype(float) - img) ** 2))

    size = {q: len(encode_jpeg(img, q)) for q in (100, 30)}
    quality = {q: psnr(jpeg(img, q)) for q in (100, 30)}
    print(f"JPEG 96x64: q100 {size[100]} B {quality[100]:.1f} dB; q30 {size[30]} B {quality[30]:.1f} dB")
    assert size[100] > 1.5 * size[30] and quality[100] > quality[30] + 5.0
    with pytest.raises(ValueError, match="quality"):
        encode_jpeg(img, 0)


def test_auto_exposure_brings_the_mean_to_the_target_within_its_limit():
    rng = np.random.default_rng(16)
    img = _texture(rng, 96, 128) * 0.2  # a dark frame: mean luma ~0.095
    luma = float((img @ [0.299, 0.587, 0.114]).mean())
    manual = Sensor(read_noise_e=0.0)
    auto = Sensor(read_noise_e=0.0, auto_exposure_target=0.4, auto_exposure_max=16.0)
    assert manual.exposure_for(img) == 1.0
    assert auto.exposure_for(img) == pytest.approx(0.4 / luma, rel=1e-6)
    out = sensor(img, np.random.default_rng(1), auto).astype(float)
    mean_luma_dn = float((out @ [0.299, 0.587, 0.114]).mean())
    assert abs(mean_luma_dn - 0.4 * 255) <= 0.5  # the frame's mean grey value is the target (noise averages out)
    # the exposure time scales the electrons, not the gain: relative shot noise falls as 1/sqrt(exposure)
    flat = np.full((100, 100, 3), 0.05)
    dn = sensor(flat, np.random.default_rng(2), auto).astype(float)
    e = dn.mean() / auto.gain_dn_per_e
    assert e == pytest.approx(0.4 * auto.full_well_e, rel=0.01)
    assert dn.std() == pytest.approx(np.sqrt(auto.gain_dn_per_e**2 * e + 1 / 12), rel=0.05)
    # limited: a very dark frame gets the longest exposure, a black one too (no division by zero)
    capped = Sensor(read_noise_e=0.0, auto_exposure_target=0.4, auto_exposure_max=2.0)
    assert capped.exposure_for(img) == 2.0 and capped.exposure_for(np.zeros((4, 4, 3))) == 2.0
    with pytest.raises(ValueError, match="auto_exposure_target"):
        Sensor(auto_exposure_target=1.5)
    with pytest.raises(ValueError, match="auto_exposure_max"):
        Sensor(auto_exposure_target=0.4, auto_exposure_max=0.0)


def test_row_bands_do_not_change_the_chain_but_the_sensor_draws_per_band(monkeypatch):
    """The per-pixel stages are split into row bands run in threads: the noise-free chain is the same for any split;
    the noise of a seed is fixed by the (fixed) number of bands."""
    from bench.sim import parallel

    rng = np.random.default_rng(17)
    img = _texture(rng, 96, 64)
    r = rng.uniform(0.5, 2.0, (96, 64))
    c = rng.uniform(0.5, 1.0, (96, 64))
    chain = MediumChain(medium=water_preset("coastal"), light=Light(ambient=0.2))
    noisy = MediumChain(medium=water_preset("coastal"), light=Light(ambient=0.2), sensor=Sensor())
    two = apply_medium(img, r, np.random.default_rng(0), chain, c)
    two_noisy = apply_medium(img, r, np.random.default_rng(0), noisy, c)
    monkeypatch.setattr(parallel, "N_BANDS", 1)
    one = apply_medium(img, r, np.random.default_rng(0), chain, c)
    assert np.array_equal(one, two)
    np.testing.assert_allclose(two, forward_scatter(attenuate(illuminate(img, r, c, chain.light, chain.medium), r,
                                                              chain.medium), r, 0.4, 3.0), rtol=1e-5, atol=1e-6)
    monkeypatch.setattr(parallel, "N_BANDS", 2)
    monkeypatch.setattr(parallel, "_POOL", None)
    monkeypatch.setattr(parallel.os, "cpu_count", lambda: 1)  # one core: the bands run one after the other
    assert np.array_equal(apply_medium(img, r, np.random.default_rng(0), noisy, c), two_noisy)


def test_normal_limit_of_bright_shot_noise_matches_exact_poisson_counts():
    """Above SHOT_NOISE_NORMAL_ABOVE_E electrons the sensor draws N(E, E + r^2) instead of Poisson(E) + N(0, r^2):
    the DN histograms of the two agree (two-sample chi-square) at the threshold, where the skew is largest."""
    from scipy.stats import chi2_contingency

    from bench.sim.medium import SHOT_NOISE_NORMAL_ABOVE_E

    def p_same(a, b):
        lo, hi = int(min(a.min(), b.min())), int(max(a.max(), b.max()))
        table = np.array([np.bincount(x.astype(int) - lo, minlength=hi - lo + 1) for x in (a, b)])
        return chi2_contingency(table[:, table.sum(axis=0) >= 20])[1]  # bins with enough counts

    spec = Sensor(full_well_e=10000.0, gain_dn_per_e=0.1, read_noise_e=5.0)  # 10 e- per DN: the shape shows
    rng = np.random.default_rng(22)
    for e_mean in (SHOT_NOISE_NORMAL_ABOVE_E, 2000.0):
        img = np.full((300, 400, 3), e_mean / spec.full_well_e)
        fast = sensor(img, np.random.default_rng(21), spec).ravel().astype(float)
        exact = np.clip(np.rint(spec.gain_dn_per_e * (rng.poisson(e_mean, fast.size)
                                                      + rng.normal(0, spec.read_noise_e, fast.size))), 0, 255)
        p = p_same(fast, exact)
        print(f"sensor at {e_mean:.0f} e-: normal limit vs exact Poisson, chi-square p = {p:.3f}")
        assert p > 1e-3
        assert abs(fast.mean() - exact.mean()) <= 5 * np.sqrt(2 * exact.var() / fast.size)
        # the comparison can see a wrong spread: a 5 % larger standard deviation is rejected
        wrong = np.clip(np.rint(spec.gain_dn_per_e * rng.normal(e_mean, 1.05 * np.sqrt(e_mean + 25.0), fast.size)),
                        0, 255)
        assert p_same(fast, wrong) < 1e-3
