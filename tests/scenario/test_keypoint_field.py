"""The keypoints' error field per view (:func:`bench.scenario.bounds.measure_field`): its basis, and its
measurement - unbiased for a known field under white noise, zero for white noise alone, and corrected for each
track's mean subtracted from its errors."""

import numpy as np
import pytest

from bench.scenario.bounds import draw_fields, field_basis, field_displacement, field_sd, measure_field

SIZE = (640, 480)


def test_field_displacement_is_affine_about_the_image_centre():
    c = np.array([0.1, 0.02, -0.03, -0.2, 0.01, 0.04])
    uv = np.array([[320.0, 240.0], [420.0, 240.0], [320.0, 140.0], [0.0, 0.0]])
    d = field_displacement(uv, c, SIZE)
    assert np.allclose(d[0], [0.1, -0.2], atol=1e-12)  # the centre: the offsets
    assert np.allclose(d[1] - d[0], [0.02, 0.01], atol=1e-12)  # 100 px right: the u slopes
    assert np.allclose(d[2] - d[0], [0.03, -0.04], atol=1e-12)  # 100 px up
    assert np.allclose(field_basis(uv, SIZE)[3], [1.0, -3.2, -2.4])
    assert np.allclose(field_displacement(uv[None].repeat(2, 0), np.stack([c, 2 * c])[:, None], SIZE)[1], 2 * d)
    assert np.array_equal(field_sd(0.3, 0.2), [0.3, 0.2, 0.2, 0.3, 0.2, 0.2])


def _views(rng, sd, n_views=8, n=300, sigma=0.1):
    uv = rng.uniform([0, 0], SIZE, (n_views, n, 2))
    fields = draw_fields(rng, sd, n_views)
    dev = rng.normal(0, sigma, uv.shape) + field_displacement(uv, fields[:, None], SIZE)
    view = np.repeat(np.arange(n_views), n)
    return dev.reshape(-1, 2), uv.reshape(-1, 2), view


@pytest.mark.parametrize("offset, slope", [(0.03, 0.02), (0.0, 0.0)])
def test_a_known_field_is_measured_without_bias(offset, slope):
    """200 runs of 8 views x 300 keypoints, white noise 0.1 px: the mean measured variances are the field's (+-10 %
    of the total scatter the white noise gives them), and a white-noise run measures ~0."""
    rng = np.random.default_rng(91)
    var = []
    for _ in range(200):
        dev, uv, view = _views(rng, field_sd(offset, slope))
        m = measure_field(dev, uv, view, np.ones(len(dev)), SIZE)
        assert m["views"] == 8
        var.append([m["offset_px"] ** 2, m["slope_px"] ** 2])
    var = np.array(var)
    # the clip at zero biases a variance near zero upwards: compare against the white-noise scale of each
    white = np.array([0.1**2 / 300, 0.1**2 / 300 / ((SIZE[0] / 100) ** 2 / 12)])
    assert np.mean(var[:, 0]) == pytest.approx(offset**2, abs=max(0.1 * offset**2, 0.5 * white[0]))
    assert np.mean(var[:, 1]) == pytest.approx(slope**2, abs=max(0.1 * slope**2, 0.5 * white[1]))


def test_subtracting_each_tracks_mean_is_corrected():
    """Tracks seen in 4 views each, errors taken about each track's mean (as on the panel's surfaces): without the
    correction (``shrink`` 1) the measured variance is 1 - 1/4 of the field's; with it, unbiased."""
    rng = np.random.default_rng(92)
    sd = field_sd(0.04, 0.03)
    raw, fixed = [], []
    for _ in range(150):
        uv = rng.uniform([0, 0], SIZE, (4, 400, 2))  # track j seen in every view, at its own pixel there
        fields = draw_fields(rng, sd, 4)
        e = rng.normal(0, 0.08, uv.shape) + field_displacement(uv, fields[:, None], SIZE)
        dev = (e - e.mean(axis=0)).reshape(-1, 2)
        view = np.repeat(np.arange(4), 400)
        raw.append(measure_field(dev, uv.reshape(-1, 2), view, np.ones(len(dev)), SIZE)["offset_px"] ** 2)
        fixed.append(measure_field(dev, uv.reshape(-1, 2), view, np.full(len(dev), 0.75), SIZE)["offset_px"] ** 2)
    assert np.mean(fixed) == pytest.approx(0.04**2, rel=0.12)
    assert np.mean(raw) == pytest.approx(0.75 * 0.04**2, rel=0.12)


def test_rows_that_are_not_finite_are_left_out():
    rng = np.random.default_rng(94)
    dev, uv, view = _views(rng, field_sd(0.03, 0.02))
    m = measure_field(dev, uv, view, np.ones(len(dev)), SIZE)
    bad_dev, bad_uv = np.vstack([dev, [np.nan, 0.1], [0.1, 0.1]]), np.vstack([uv, [10.0, 10.0], [np.inf, 5.0]])
    m2 = measure_field(bad_dev, bad_uv, np.r_[view, 0, 1], np.ones(len(bad_dev)), SIZE)
    assert m2 == m


def test_too_few_keypoints_measure_nothing():
    rng = np.random.default_rng(93)
    dev, uv, view = _views(rng, field_sd(0.03, 0.02), n_views=3, n=10)
    m = measure_field(dev, uv, view, np.ones(len(dev)), SIZE)
    assert m["views"] == 0 and np.isnan(m["offset_px"]) and np.isnan(m["slope_px"])
    m = measure_field(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, int), np.zeros(0), SIZE)
    assert m["views"] == 0
