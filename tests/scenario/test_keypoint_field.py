"""The keypoints' error field per view (:func:`bench.scenario.bounds.measure_field`): its basis, and its
measurement - unbiased for a known field under white noise, zero for white noise alone, and corrected for each
track's mean subtracted from its errors."""

import numpy as np
import pytest

from bench.scenario.bounds import (
    draw_fields,
    field_basis,
    field_displacement,
    field_order,
    field_sd,
    field_terms,
    measure_field,
)

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


def test_a_cubic_field_is_the_polynomial_by_degree():
    """Order 3: the ten monomials of x = (u - w/2)/100, y = (v - h/2)/100 by degree; 20 coefficients, u's then v's;
    the affine field is its first three terms."""
    rng = np.random.default_rng(95)
    uv = rng.uniform([0, 0], SIZE, (50, 2))
    x, y = (uv[:, 0] - 320) / 100, (uv[:, 1] - 240) / 100
    B = field_basis(uv, SIZE, order=3)
    expect = np.stack([np.ones(50), x, y, x * x, x * y, y * y, x**3, x * x * y, x * y * y, y**3], axis=1)
    assert np.allclose(B, expect, rtol=0, atol=1e-12)
    assert [field_terms(o) for o in range(4)] == [1, 3, 6, 10]
    assert [field_order(n) for n in (2, 6, 12, 20)] == [0, 1, 2, 3]
    c = rng.normal(size=20)
    d = field_displacement(uv, c, SIZE)
    assert np.allclose(d, np.stack([expect @ c[:10], expect @ c[10:]], axis=1), rtol=0, atol=1e-12)
    c1 = np.zeros(20)
    c1[[0, 1, 2, 10, 11, 12]] = c[[0, 1, 2, 10, 11, 12]]
    assert np.allclose(field_displacement(uv, c1, SIZE), field_displacement(uv, c1[[0, 1, 2, 10, 11, 12]], SIZE),
                       rtol=0, atol=1e-12)
    assert np.array_equal(field_sd(0.3, 0.2, 0.1, 0.05), np.tile([0.3, 0.2, 0.2, 0.1, 0.1, 0.1] + [0.05] * 4, 2))
    for bad in (lambda: field_order(7), lambda: field_basis(uv, SIZE, order=4), lambda: field_terms(1.5)):
        with pytest.raises(ValueError, match="field"):
            bad()


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


def test_a_known_cubic_field_is_measured_without_bias():
    """Order 3, 120 runs of 8 views x 300 keypoints, white noise 0.1 px: each degree's mean measured variance is the
    field's (+-12 %); measured as affine, the curvature shows up in the slopes and offsets instead."""
    rng = np.random.default_rng(96)
    degree_sd = (0.03, 0.02, 0.012, 0.006)
    var, affine = [], []
    for _ in range(120):
        dev, uv, view = _views(rng, field_sd(*degree_sd))
        m = measure_field(dev, uv, view, np.ones(len(dev)), SIZE, order=3)
        assert m["views"] == 8 and len(m["degree_px"]) == 4
        assert [m["offset_px"], m["slope_px"], m["quadratic_px"], m["cubic_px"]] == list(m["degree_px"])
        var.append(m["degree_px"] ** 2)
        affine.append(measure_field(dev, uv, view, np.ones(len(dev)), SIZE)["slope_px"] ** 2)
    assert np.mean(var, axis=0) == pytest.approx(np.square(degree_sd), rel=0.12)
    assert np.mean(affine) > 1.5 * degree_sd[1] ** 2


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
    assert np.array_equal(m2.pop("degree_px"), m.pop("degree_px")) and m2 == m


def test_too_few_keypoints_measure_nothing():
    rng = np.random.default_rng(93)
    dev, uv, view = _views(rng, field_sd(0.03, 0.02), n_views=3, n=10)
    m = measure_field(dev, uv, view, np.ones(len(dev)), SIZE)
    assert m["views"] == 0 and np.isnan(m["offset_px"]) and np.isnan(m["slope_px"])
    m = measure_field(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, int), np.zeros(0), SIZE)
    assert m["views"] == 0
