"""The keypoints' error field per view (:mod:`bench.scenario.bounds`): its basis and modes, its draws and prior, and
its measurement - unbiased for a known field under white noise, zero for white noise alone, and corrected for each
track's mean subtracted from its errors."""

import numpy as np
import pytest

from bench.scenario.bounds import (
    draw_field,
    field_basis,
    field_displacement,
    field_modes,
    field_order,
    field_prior_information,
    field_terms,
    measure_field,
    mode_sd,
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
    assert np.allclose(field_displacement(uv, c, SIZE), np.stack([expect @ c[:10], expect @ c[10:]], axis=1),
                       rtol=0, atol=1e-12)
    c1 = np.zeros(20)
    c1[[0, 1, 2, 10, 11, 12]] = c[[0, 1, 2, 10, 11, 12]]
    assert np.allclose(field_displacement(uv, c1, SIZE), field_displacement(uv, c1[[0, 1, 2, 10, 11, 12]], SIZE),
                       rtol=0, atol=1e-12)
    assert np.array_equal(mode_sd([0.3, 0.2, 0.1, 0.05]), [0.3, 0.2, 0.2, 0.1, 0.1, 0.1] + [0.05] * 4)
    for bad in (lambda: field_order(7), lambda: field_basis(uv, SIZE, order=4), lambda: field_terms(1.5)):
        with pytest.raises(ValueError, match="field"):
            bad()


@pytest.mark.parametrize("order", [1, 3])
def test_the_modes_are_orthonormal_over_the_keypoints(order):
    """``X = Q R``: ``Q`` orthonormal in mean square over the view's keypoints (1e-10), ``R`` upper triangular;
    keypoints that cannot resolve the modes (too few, or on a line) are a ValueError naming the field."""
    rng = np.random.default_rng(97)
    uv = rng.uniform([100, 50], [500, 300], (60, 2))  # keypoints on part of the image only
    R = field_modes(uv, SIZE, order)
    Q = field_basis(uv, SIZE, order) @ np.linalg.inv(R)
    assert np.allclose(Q.T @ Q / len(uv), np.eye(field_terms(order)), rtol=0, atol=1e-10)
    assert np.allclose(R, np.triu(R), rtol=0, atol=0)
    with pytest.raises(ValueError, match="field modes: 2 keypoints"):
        field_modes(uv[:2], SIZE, order)
    line = np.c_[np.linspace(10, 600, 40), np.full(40, 200.0)]
    with pytest.raises(ValueError, match="field modes: the 40 keypoints lie on a curve"):
        field_modes(line, SIZE, order)


def test_a_drawn_field_has_the_priors_covariance():
    """The prior information of a view's coefficients is the inverse of the drawn fields' covariance (exactly:
    ``R^T D^-1 R`` against ``R^-1 D R^-T``), and 4000 draws have each mode's variance (+-7 %) and no cross term."""
    rng = np.random.default_rng(98)
    uv = rng.uniform([0, 0], SIZE, (80, 2))
    degree_px = [0.03, 0.02, 0.01]
    R = field_modes(uv, SIZE, 2)
    sd = mode_sd(degree_px)
    cov_c = np.linalg.inv(R) @ np.diag(sd**2) @ np.linalg.inv(R).T
    info = field_prior_information(uv, degree_px, SIZE)
    assert np.allclose(info[:6, :6] @ cov_c, np.eye(6), rtol=0, atol=1e-8)
    assert np.array_equal(info[6:, 6:], info[:6, :6]) and not np.any(info[:6, 6:])
    a = np.array([R @ draw_field(rng, uv, degree_px, SIZE).reshape(2, -1).T for _ in range(4000)])  # (draws, 6, 2)
    cov = np.einsum("dka,dla->kl", a, a) / (2 * len(a))
    assert np.diag(cov) == pytest.approx(sd**2, rel=0.07)
    assert np.max(np.abs(cov - np.diag(np.diag(cov))) / np.outer(sd, sd)) < 0.07


def _views(rng, degree_px, n_views=8, n=300, sigma=0.1):
    uv = rng.uniform([0, 0], SIZE, (n_views, n, 2))
    field = np.stack([field_displacement(uv[v], draw_field(rng, uv[v], degree_px, SIZE), SIZE)
                      for v in range(n_views)])
    dev = rng.normal(0, sigma, uv.shape) + field
    view = np.repeat(np.arange(n_views), n)
    return dev.reshape(-1, 2), uv.reshape(-1, 2), view


@pytest.mark.parametrize("degree_px", [(0.03, 0.02), (0.0, 0.0), (0.03, 0.02, 0.012, 0.008)],
                         ids=["affine", "white", "cubic"])
def test_a_known_field_is_measured_without_bias(degree_px):
    """150 runs of 8 views x 300 keypoints, white noise 0.1 px: each degree's mean measured variance is the field's
    (+-10 %, or half the white noise's share of a mode, 0.1^2 / 300, near zero: the clip at zero biases a variance
    there upwards), and a white-noise run measures ~0."""
    rng = np.random.default_rng(91)
    order = len(degree_px) - 1
    var = []
    for _ in range(150):
        dev, uv, view = _views(rng, degree_px)
        m = measure_field(dev, uv, view, np.ones(len(dev)), SIZE, order=order)
        assert m["views"] == 8 and len(m["degree_px"]) == order + 1
        var.append(m["degree_px"] ** 2)
    white = 0.1**2 / 300
    for d, s in enumerate(degree_px):
        assert np.mean(np.array(var)[:, d]) == pytest.approx(s**2, abs=max(0.1 * s**2, 0.5 * white))
    if order == 3:
        assert [m["offset_px"], m["slope_px"], m["quadratic_px"], m["cubic_px"]] == list(m["degree_px"])


def test_subtracting_each_tracks_mean_is_corrected():
    """Tracks seen in 4 views each, errors taken about each track's mean (as on the panel's surfaces): without the
    correction (``shrink`` 1) the measured variance is 1 - 1/4 of the field's; with it, unbiased."""
    rng = np.random.default_rng(92)
    raw, fixed = [], []
    for _ in range(150):
        uv = rng.uniform([0, 0], SIZE, (4, 400, 2))  # track j seen in every view, at its own pixel there
        field = np.stack([field_displacement(uv[v], draw_field(rng, uv[v], (0.04, 0.03), SIZE), SIZE)
                          for v in range(4)])
        e = rng.normal(0, 0.08, uv.shape) + field
        dev = (e - e.mean(axis=0)).reshape(-1, 2)
        view = np.repeat(np.arange(4), 400)
        raw.append(measure_field(dev, uv.reshape(-1, 2), view, np.ones(len(dev)), SIZE)["offset_px"] ** 2)
        fixed.append(measure_field(dev, uv.reshape(-1, 2), view, np.full(len(dev), 0.75), SIZE)["offset_px"] ** 2)
    assert np.mean(fixed) == pytest.approx(0.04**2, rel=0.12)
    assert np.mean(raw) == pytest.approx(0.75 * 0.04**2, rel=0.12)


def test_rows_that_are_not_finite_are_left_out():
    rng = np.random.default_rng(94)
    dev, uv, view = _views(rng, (0.03, 0.02))
    m = measure_field(dev, uv, view, np.ones(len(dev)), SIZE)
    bad_dev, bad_uv = np.vstack([dev, [np.nan, 0.1], [0.1, 0.1]]), np.vstack([uv, [10.0, 10.0], [np.inf, 5.0]])
    m2 = measure_field(bad_dev, bad_uv, np.r_[view, 0, 1], np.ones(len(bad_dev)), SIZE)
    assert np.array_equal(m2.pop("degree_px"), m.pop("degree_px")) and m2 == m


def test_too_few_keypoints_measure_nothing():
    rng = np.random.default_rng(93)
    dev, uv, view = _views(rng, (0.03, 0.02), n_views=3, n=10)
    m = measure_field(dev, uv, view, np.ones(len(dev)), SIZE)
    assert m["views"] == 0 and np.isnan(m["offset_px"]) and np.isnan(m["slope_px"])
    m = measure_field(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, int), np.zeros(0), SIZE)
    assert m["views"] == 0
    line = np.c_[np.linspace(10, 600, 40), np.full(40, 200.0)]  # one view on a line: its modes unresolved
    m = measure_field(rng.normal(0, 0.1, (40, 2)), line, np.zeros(40, int), np.ones(40), SIZE)
    assert m["views"] == 0
