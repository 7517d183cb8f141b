import warnings

import numpy as np
import pytest

from bench.geometry.lines import closest_points_between_lines, closest_points_thesis, midpoint


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _lines_with_known_answer(rng, n):
    """Skew lines built around known closest points c1, c2 and parameters g1, g2."""
    d1, d2 = rng.normal(size=(2, n, 3))
    normal = _unit(np.cross(d1, d2))
    c1 = rng.normal(size=(n, 3))
    gap = rng.uniform(0.0, 0.5, size=n)
    c2 = c1 + gap[:, None] * normal
    g1, g2 = rng.uniform(-3, 3, size=(2, n))
    return c1 - g1[:, None] * d1, d1, c2 - g2[:, None] * d2, d2, c1, c2, g1, g2, gap


def test_known_closest_points_exact():
    rng = np.random.default_rng(31)
    p1, d1, p2, d2, c1, c2, g1, g2, gap = _lines_with_known_answer(rng, 1000)
    cp = closest_points_between_lines(p1, d1, p2, d2)
    assert not cp.parallel.any()
    assert np.abs(cp.p1 - c1).max() <= 1e-12 and np.abs(cp.p2 - c2).max() <= 1e-12
    assert np.abs(cp.gamma1 - g1).max() <= 1e-12 and np.abs(cp.gamma2 - g2).max() <= 1e-12
    assert np.abs(cp.distance - gap).max() <= 1e-12
    assert np.abs(cp.midpoint - 0.5 * (c1 + c2)).max() <= 1e-12
    assert np.abs(midpoint(p1, d1, p2, d2) - 0.5 * (c1 + c2)).max() <= 1e-12


def test_segment_is_perpendicular_to_both_lines():  # Eq. 109-110
    rng = np.random.default_rng(32)
    p1, d1, p2, d2 = rng.normal(size=(4, 500, 3))
    cp = closest_points_between_lines(p1, d1, p2, d2)
    r = cp.p1 - cp.p2
    assert np.abs(np.sum(r * d1, -1)).max() <= 1e-12 and np.abs(np.sum(r * d2, -1)).max() <= 1e-12
    # and it is the minimum: moving along either line only increases the distance
    for s in (1e-3, -1e-3):
        assert np.all(np.linalg.norm(cp.p1 + s * d1 - cp.p2, axis=-1) >= cp.distance)


def test_matches_the_printed_equations_on_well_conditioned_lines():  # Eq. 113-117
    rng = np.random.default_rng(33)
    p1, d1, p2, d2 = rng.normal(size=(4, 200, 3))
    cp = closest_points_between_lines(p1, d1, p2, d2)
    g1, g2 = closest_points_thesis(p1, p1 + d1, p2, p2 + d2)
    assert np.abs(cp.gamma1 - g1).max() <= 1e-9 and np.abs(cp.gamma2 - g2).max() <= 1e-9


def test_broadcasting_over_leading_axes():
    rng = np.random.default_rng(34)
    p1, d1 = rng.normal(size=(2, 5, 1, 3))
    p2, d2 = rng.normal(size=(2, 1, 4, 3))
    cp = closest_points_between_lines(p1, d1, p2, d2)
    assert cp.p1.shape == (5, 4, 3) and cp.gamma2.shape == (5, 4) and cp.parallel.shape == (5, 4)
    one = closest_points_between_lines(p1[2, 0], d1[2, 0], p2[0, 3], d2[0, 3])
    assert np.allclose(one.p2, cp.p2[2, 3], atol=1e-14) and one.p1.shape == (3,)


@pytest.mark.parametrize("angle", [0.0, 1e-14, 1e-11])
def test_parallel_lines_are_flagged_and_finite(angle):
    d1 = np.array([0.3, -0.2, 0.9])
    axis = _unit(np.cross(d1, [1.0, 0, 0]))
    d2 = np.cos(angle) * d1 + np.sin(angle) * np.linalg.norm(d1) * axis
    offset = 0.25 * _unit(np.cross(d1, axis))  # perpendicular separation of 0.25
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no divide-by-zero / invalid warnings
        cp = closest_points_between_lines(np.zeros(3), d1, offset + 7 * d1, -2 * d2)
    assert cp.parallel
    assert np.all(np.isfinite([cp.gamma1, cp.gamma2, cp.distance])) and np.all(np.isfinite(cp.p2))
    assert cp.gamma1 == 0.0 and cp.distance == pytest.approx(0.25, abs=1e-9)
    with pytest.raises(ValueError, match="parallel"):
        midpoint(np.zeros(3), d1, offset, d2)


def test_batch_mixes_parallel_and_skew_lines():
    p1 = np.zeros((3, 3))
    d1 = np.array([[1.0, 0, 0], [1, 0, 0], [1, 0, 0]])
    p2 = np.array([[0, 1.0, 0], [0, 0, 1.0], [5, 0, 2.0]])
    d2 = np.array([[2.0, 0, 0], [0, 1, 0], [-1, 0, 0]])
    cp = closest_points_between_lines(p1, d1, p2, d2)
    assert cp.parallel.tolist() == [True, False, True]
    assert np.allclose(cp.distance, [1.0, 1.0, 2.0]) and np.allclose(cp.p2[1], [0, 0, 1.0])


def test_nearly_parallel_lines_stay_accurate():
    """Lines 1e-6 rad apart crossing at a known point: the cross-product form keeps the digits that the printed
    difference of products (Eq. 116) loses."""
    rng = np.random.default_rng(35)
    d1 = _unit(rng.normal(size=3))
    perp = _unit(np.cross(d1, rng.normal(size=3)))
    d2 = np.cos(1e-6) * d1 + np.sin(1e-6) * perp
    c = rng.normal(size=3)
    cp = closest_points_between_lines(c - 3 * d1, d1, c + 5 * d2, d2)
    assert not cp.parallel
    # the inputs' rounding (1e-16) alone moves the crossing by ~1e-16 / sin(1e-6) along the lines
    assert abs(cp.gamma1 - 3) < 1e-8 and abs(cp.gamma2 + 5) < 1e-8 and cp.distance < 1e-9
    g1, g2 = closest_points_thesis(c - 3 * d1, c - 2 * d1, c + 5 * d2, c + 6 * d2)
    assert abs(g1 - 3) > 1e-5 and abs(g2 + 5) > 1e-5  # the printed form: ~1e-3 here


@pytest.mark.parametrize(
    "args, match",
    [
        ((np.zeros(3), np.zeros(3), np.ones(3), [0, 1.0, 0]), "d1: zero-length"),
        ((np.zeros(3), [1.0, 0, 0], np.ones(3), np.zeros(3)), "d2: zero-length"),
        ((np.zeros(3), [1.0, np.nan, 0], np.ones(3), [0, 1.0, 0]), "d1: contains NaN"),
        ((np.zeros(2), [1.0, 0, 0], np.ones(3), [0, 1.0, 0]), r"p1: expected shape \(\.\.\., 3\)"),
        ((np.zeros(3), [1.0, 0, 0], "abc", [0, 1.0, 0]), "p2: expected a numeric"),
    ],
)
def test_bad_input_names_the_argument(args, match):
    with pytest.raises(ValueError, match=match):
        closest_points_between_lines(*args)
