import numpy as np
import pytest

from bench.geometry.fits import (
    Plane,
    fit_circle_2d,
    fit_circle_3d,
    fit_plane,
    plane_rotation,
    project_to_plane,
)
from bench.geometry.transforms import random_rotation


def _unit(v):
    return v / np.linalg.norm(v)


def _plane_points(rng, n, normal, d, spread=0.5, noise=0.0):
    """Points on ``normal . x + d = 0`` spread over ``spread`` m around the foot point ``-d normal``."""
    R = np.linalg.qr(np.column_stack([normal, rng.normal(size=(3, 2))]))[0]
    u = rng.uniform(-spread, spread, size=(n, 2))
    return -d * normal + u @ R[:, 1:].T + noise * rng.normal(size=(n, 1)) * normal, u


def _same_plane(plane: Plane, normal, d):
    s = np.sign(plane.normal @ normal)
    return np.abs(plane.normal - s * normal).max(), abs(plane.d - s * d)


def test_plane_noise_free_exact_far_from_origin():
    rng = np.random.default_rng(11)
    for _ in range(20):
        n = _unit(rng.normal(size=3))
        d = rng.uniform(-5, 5)
        pts, _ = _plane_points(rng, 30, n, d)
        plane = fit_plane(pts)
        en, ed = _same_plane(plane, n, d)
        assert en <= 1e-12 and ed <= 1e-12 and plane.rms <= 1e-12
        assert plane.d >= 0  # Eq. 31: d_p is a distance
        assert np.abs(plane.signed_distance(pts)).max() <= 1e-12


@pytest.mark.parametrize("method", ["normalized", "thesis"])
def test_plane_through_exactly_three_points(method):
    rng = np.random.default_rng(20)
    pts = rng.normal(size=(3, 3)) + 2.0
    plane = fit_plane(pts, method)
    assert np.abs(plane.signed_distance(pts)).max() <= 1e-12
    assert np.abs(plane.normal @ (pts[1] - pts[0])) <= 1e-12


def test_thesis_and_normalized_agree_on_well_conditioned_data():
    rng = np.random.default_rng(12)
    for _ in range(20):
        n = _unit(rng.normal(size=3))
        pts, _ = _plane_points(rng, 40, n, rng.uniform(-1.0, 1.0), spread=1.0)
        a, b = fit_plane(pts, "thesis"), fit_plane(pts, "normalized")
        assert np.abs(a.normal - b.normal).max() <= 1e-12 and abs(a.d - b.d) <= 1e-12


def test_thesis_and_normalized_with_noise_differ_by_a_small_fraction_of_the_spread():
    """With noise Eq. 29 on raw coordinates is an algebraic fit; it stays within 1 % of the fit's own scatter."""
    rng = np.random.default_rng(21)
    n = _unit(np.array([0.2, -0.4, 0.9]))
    pts0, u = _plane_points(rng, 40, n, 0.5, spread=1.0)
    sigma = 1e-3
    uc = u - u.mean(0)
    tilt_std = sigma * np.sqrt(np.trace(np.linalg.inv(uc.T @ uc)))
    for _ in range(20):
        pts = pts0 + sigma * rng.normal(size=pts0.shape)
        a, b = fit_plane(pts, "thesis"), fit_plane(pts, "normalized")
        assert np.linalg.norm(a.normal - b.normal) < 0.01 * tilt_std
        assert b.rms <= a.rms  # the orthogonal fit minimises the RMS distance


def test_thesis_formulation_is_ill_conditioned_far_away():
    """Eq. 29 on raw coordinates: a small arc 2 km from the tracker origin. Centring/scaling keeps full accuracy."""
    rng = np.random.default_rng(13)
    n = _unit(np.array([0.3, -0.5, 0.8]))
    pts, _ = _plane_points(rng, 30, n, 2000.0, spread=0.2)
    err_thesis = _same_plane(fit_plane(pts, "thesis"), n, 2000.0)[0]
    err_norm = _same_plane(fit_plane(pts, "normalized"), n, 2000.0)[0]
    assert err_norm <= 1e-11
    assert err_thesis > 1e3 * err_norm


def test_plane_normal_noise_matches_first_order_covariance():
    """Tilt covariance of the fitted normal: sigma^2 (U^T U)^-1 for centred in-plane coordinates U."""
    rng = np.random.default_rng(14)
    n = _unit(np.array([0.1, 0.2, 1.0]))
    pts0, u = _plane_points(rng, 25, n, 1.5, spread=0.4)
    sigma = 1e-4
    uc = u - u.mean(0)
    predicted = sigma * np.sqrt(np.trace(np.linalg.inv(uc.T @ uc)))
    tilts = []
    for _ in range(400):
        p = fit_plane(pts0 + sigma * rng.normal(size=pts0.shape))
        tilts.append(np.linalg.norm(np.cross(p.normal, n)))
    observed = np.sqrt(np.mean(np.square(tilts)))
    assert 0.85 < observed / predicted < 1.15


@pytest.mark.parametrize("signs", [(1, 1, 1), (-1, 1, 1), (1, -1, 1), (-1, -1, -1), (-1, 0, 0.5), (0, -1, 0)])
def test_plane_rotation_keeps_the_quadrant(signs):
    n = _unit(np.array(signs, dtype=float) * [0.6, 0.5, 0.7])
    R = plane_rotation(n)
    assert np.abs(R[:, 2] - n).max() <= 1e-15
    assert np.abs(R.T @ R - np.eye(3)).max() <= 1e-15 and np.linalg.det(R) == pytest.approx(1.0)
    R_printed = plane_rotation(n, quadrant_safe=False)  # Eq. 33's atan(b/a)
    if n[0] < 0:
        assert np.abs(R_printed[:, 2] - n).max() > 0.5  # the printed formula loses the quadrant
    elif n[0] > 0:
        assert np.abs(R_printed[:, 2] - n).max() <= 1e-15


def test_plane_rotation_precise_near_the_pole():
    n = _unit(np.array([1e-9, 0.0, 1.0]))
    assert np.abs(plane_rotation(n)[:, 2] - n).max() <= 1e-16
    assert np.abs(plane_rotation(n, quadrant_safe=False)[:, 2] - n).max() > 5e-10  # acos(c) near c = 1


def test_projection_into_the_plane():
    rng = np.random.default_rng(15)
    n = _unit(rng.normal(size=3))
    pts, _ = _plane_points(rng, 10, n, 0.7)
    plane = fit_plane(pts)
    xy, z, R_p = project_to_plane(pts, plane)  # Eq. 35
    assert np.abs(z + plane.d).max() <= 1e-12  # every point at z' = n.x = -d_p
    dist3 = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
    dist2 = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
    assert np.abs(dist3 - dist2).max() <= 1e-12
    assert np.abs(np.column_stack([xy, z]) @ R_p.T - pts).max() <= 1e-12


@pytest.mark.parametrize("span_deg", [20.0, 90.0, 360.0])
def test_circle_2d_noise_free_exact(span_deg):
    rng = np.random.default_rng(16)
    c, r = rng.uniform(-3, 3, size=2), rng.uniform(0.2, 2.0)
    t = rng.uniform(0, 2 * np.pi) + np.deg2rad(np.linspace(0, span_deg, 15, endpoint=span_deg < 360))
    xy = c + r * np.column_stack([np.cos(t), np.sin(t)])
    fit = fit_circle_2d(xy)
    center, radius, rms = fit  # tuple-unpackable (Eq. 42-44)
    assert np.abs(center - c).max() <= 1e-9 and abs(radius - r) <= 1e-9 and rms <= 1e-9


def test_circle_2d_noise_matches_theory():
    """Full circle, N equally spaced points: centre std sigma sqrt(2/N) per axis, radius std sigma/sqrt(N)."""
    rng = np.random.default_rng(17)
    N, sigma, r = 24, 1e-4, 0.8
    t = np.linspace(0, 2 * np.pi, N, endpoint=False)
    xy0 = np.column_stack([np.cos(t), np.sin(t)]) * r + [0.3, -1.2]
    est = np.array([np.r_[f.center, f.radius] for f in
                    (fit_circle_2d(xy0 + sigma * rng.normal(size=xy0.shape)) for _ in range(600))])
    err = est - [0.3, -1.2, r]
    std = np.sqrt(np.mean(err**2, axis=0))
    assert np.all(np.abs(std[:2] / (sigma * np.sqrt(2 / N)) - 1) < 0.12)
    assert abs(std[2] / (sigma / np.sqrt(N)) - 1) < 0.12


@pytest.mark.parametrize("span_deg", [20.0, 40.0, 180.0])
def test_circle_3d_noise_free_exact(span_deg):
    rng = np.random.default_rng(18)
    for _ in range(10):
        R = random_rotation(rng)
        c, r = rng.normal(scale=2.0, size=3), rng.uniform(0.3, 2.0)
        t = np.deg2rad(np.linspace(0, span_deg, 12)) + rng.uniform(0, 2 * np.pi)
        pts = c + r * np.column_stack([np.cos(t), np.sin(t), np.zeros_like(t)]) @ R.T
        circ = fit_circle_3d(pts)
        assert np.abs(circ.center - c).max() <= 1e-9 and abs(circ.radius - r) <= 1e-9
        assert np.linalg.norm(np.cross(circ.normal, R[:, 2])) <= 1e-9 and circ.rms <= 1e-9


def test_circle_3d_rms_includes_out_of_plane_noise():
    rng = np.random.default_rng(19)
    t = np.linspace(0, 2 * np.pi, 2000, endpoint=False)
    pts = np.column_stack([np.cos(t), np.sin(t), np.zeros_like(t)]) + 1e-3 * rng.normal(size=(2000, 3))
    assert fit_circle_3d(pts).rms == pytest.approx(np.sqrt(2) * 1e-3, rel=0.05)  # radial + normal components


@pytest.mark.parametrize(
    "func, arg, match",
    [
        (fit_plane, np.zeros((2, 3)), "points: needs at least 3"),
        (fit_plane, np.outer(np.arange(5.0), [1, 2, 3]), "points: points are collinear"),
        (fit_plane, np.ones((4, 3)), "points: all points coincide"),
        (fit_plane, np.array([[0, 0, 0], [1, 0, 0], [0, np.nan, 1.0]]), "points: contains NaN"),
        (fit_plane, np.zeros((5, 2)), r"points: expected shape \(N, 3\)"),
        (fit_circle_2d, np.column_stack([np.arange(4.0), 2 * np.arange(4.0) + 1]), "xy: points are collinear"),
        (fit_circle_2d, np.zeros((2, 2)), "xy: needs at least 3"),
        (fit_circle_2d, np.array([[0, 0], [1, 0], [np.inf, 1.0]]), "xy: contains NaN or inf"),
        (fit_circle_3d, np.outer(np.arange(6.0), [0.2, -1, 0.5]) + 3.0, "points: points are collinear"),
        (fit_circle_3d, np.array([[1, 2, 3.0]] * 3) + [[0, 0, 0], [1e-17, 0, 0], [0, 0, 0]], "points: all points"),
    ],
)
def test_degenerate_input_names_the_argument(func, arg, match):
    with pytest.raises(ValueError, match=match) as info:
        func(arg)
    assert "\n" not in str(info.value)


def test_bad_method():
    with pytest.raises(ValueError, match="method"):
        fit_plane(np.eye(3), method="svd")
