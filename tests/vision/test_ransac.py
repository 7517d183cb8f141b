import numpy as np
import pytest

from bench.geometry.quaternion import matrix_to_rotation_vector
from bench.geometry.transforms import homogeneous, random_rotation, transform_points
from bench.vision.absolute_orientation import (
    METHODS,
    absolute_orientation,
    predicted_covariance,
    random_correspondences,
)
from bench.vision.ransac import (
    THESIS_DISTANCE,
    THESIS_ITERATIONS,
    THESIS_R_LIM,
    adaptive_iterations,
    error_ratios,
    ransac_absolute_orientation,
)


def _pose_error(T_est, T):
    return np.r_[matrix_to_rotation_vector(T_est[:3, :3] @ T[:3, :3].T), T_est[:3, 3] - T[:3, 3]]


def test_thesis_parameters():
    assert (THESIS_ITERATIONS, THESIS_DISTANCE, THESIS_R_LIM) == (100, 0.02, 0.1)  # section 5.2.2


@pytest.mark.parametrize("method", METHODS)
def test_noise_free_with_outliers_exact(method):
    rng = np.random.default_rng(21)
    p1, p2, T, inlier = random_correspondences(rng, 120, spread=0.3, outlier_fraction=0.4)
    r = ransac_absolute_orientation(p1, p2, method=method, rng=1)
    assert r.success and r.iterations == 100 and r.required_iterations == 100
    assert np.array_equal(r.inliers, inlier) and np.array_equal(r.ransac_inliers, inlier)
    assert np.abs(r.T - T).max() <= 1e-9 * (1 + np.abs(T[:3, 3]).max())
    assert r.rms < 1e-12
    assert np.all(r.residuals[~inlier] > 0.1 - 1e-9)


@pytest.mark.parametrize("fraction", [0.3, 0.6])
@pytest.mark.parametrize("method", METHODS)
def test_noisy_outliers_true_inliers_and_pose_to_noise_level(fraction, method):
    rng = np.random.default_rng(22)
    s = 1e-3
    p1, p2, T, inlier = random_correspondences(rng, 200, spread=0.3, sigma1=s, sigma2=s, outlier_fraction=fraction)
    r = ransac_absolute_orientation(p1, p2, method=method, rng=2)
    assert r.success
    assert np.array_equal(r.ransac_inliers, inlier)
    # the refit is the oracle fit on the true inliers
    oracle = absolute_orientation(p1[inlier], p2[inlier], method=method)
    assert np.abs(r.T - oracle.T).max() < 1e-12
    # and the pose error is at the noise level predicted by first-order propagation (chi^2, 6 dof, p = 0.999)
    P = predicted_covariance(p1[inlier], p2[inlier], T[:3, :3], np.sqrt(2) * s, method=method)
    e = _pose_error(r.T, T)
    assert e @ np.linalg.solve(P, e) < 22.46
    assert r.rms == pytest.approx(np.sqrt(2 * 3) * s, rel=0.15)


def test_fixed_vs_adaptive_iterations():
    assert adaptive_iterations(0.7) == 11  # log(0.01) / log(1 - 0.343) = 10.9
    assert adaptive_iterations(0.4) == 70  # log(0.01) / log(1 - 0.064) = 69.6
    assert adaptive_iterations(1.0) == 1
    assert adaptive_iterations(0.0, max_iterations=500) == 500
    assert adaptive_iterations(0.05, max_iterations=500) == 500  # capped (36839 needed)
    assert adaptive_iterations(0.4, confidence=0.999) == 105
    rng = np.random.default_rng(23)
    for fraction, expected in ((0.3, 11), (0.6, 70)):
        p1, p2, T, inlier = random_correspondences(rng, 100, spread=0.3, sigma1=1e-3, outlier_fraction=fraction)
        fixed = ransac_absolute_orientation(p1, p2, rng=3)
        adapt = ransac_absolute_orientation(p1, p2, adaptive=True, rng=3)
        assert fixed.iterations == 100
        assert adapt.iterations == adapt.required_iterations == expected
        assert np.array_equal(adapt.inliers, inlier) and np.array_equal(fixed.inliers, inlier)
        assert np.abs(adapt.T - fixed.T).max() < 1e-12
    # no consensus: adaptive runs to its cap
    p1, p2 = rng.uniform(-1, 1, (2, 50, 3))
    r = ransac_absolute_orientation(p1, p2, adaptive=True, max_iterations=300, rng=4)
    assert not r.success and r.iterations == 300


def test_seeded_and_batch_independent():
    rng = np.random.default_rng(24)
    p1, p2, _, _ = random_correspondences(rng, 80, spread=0.3, sigma1=2e-3, outlier_fraction=0.5)
    a = ransac_absolute_orientation(p1, p2, rng=5, adaptive=True, batch=1)
    b = ransac_absolute_orientation(p1, p2, rng=5, adaptive=True, batch=1000)
    c = ransac_absolute_orientation(p1, p2, rng=np.random.default_rng(5), adaptive=True)
    assert a.iterations == b.iterations == c.iterations
    assert np.array_equal(a.T, b.T) and np.array_equal(a.T, c.T)


def _planted_near_centre(rng, n_good=60, n_bad=4):
    """Inliers on a shell (0.15-0.4 m from the centre, 0.5 mm noise) plus ``n_bad`` pairs 2-6 cm from the centre
    with 8-15 mm errors: within d_r = 20 mm (RANSAC keeps them) but with error ratios 0.13-0.75 > r_lim = 0.1."""
    T = homogeneous(random_rotation(rng), rng.normal(size=3))
    d = rng.normal(size=(n_good + n_bad, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    radius = np.r_[rng.uniform(0.15, 0.4, n_good), rng.uniform(0.02, 0.06, n_bad)]
    centre = np.array([0.3, -0.2, 0.8])
    p2 = centre + d * radius[:, None]
    p1 = transform_points(T, p2) + rng.normal(scale=0.5e-3, size=p2.shape)
    e = rng.normal(size=(n_bad, 3))
    p1[n_good:] += e / np.linalg.norm(e, axis=1, keepdims=True) * rng.uniform(8e-3, 15e-3, (n_bad, 1))
    bad = np.zeros(n_good + n_bad, dtype=bool)
    bad[n_good:] = True
    # gross outliers as well
    p1[:10] += rng.uniform(0.2, 1.0, (10, 3))
    gross = np.zeros_like(bad)
    gross[:10] = True
    return p1, p2, T, bad, gross


@pytest.mark.parametrize("method", METHODS)
def test_error_ratio_elimination_removes_planted_pairs_and_stops_at_r_lim(method):
    rng = np.random.default_rng(25)
    p1, p2, T, bad, gross = _planted_near_centre(rng)
    plain = ransac_absolute_orientation(p1, p2, method=method, rng=6)
    assert np.array_equal(plain.inliers, ~gross)  # RANSAC removes the gross ones and keeps the planted ones
    r = ransac_absolute_orientation(p1, p2, method=method, rng=6, r_lim=0.1)
    assert r.success and r.elimination_converged
    assert np.array_equal(r.ransac_inliers, ~gross)
    assert np.array_equal(r.inliers, ~gross & ~bad)  # exactly the planted pairs went
    assert sorted(h.index for h in r.history) == sorted(np.flatnonzero(bad))
    assert all(h.ratio >= 0.1 for h in r.history)
    assert [h.n_remaining for h in r.history] == list(range(int((~gross).sum()) - 1, int((~gross & ~bad).sum()) - 1,
                                                           -1))
    assert r.history[-1].max_ratio_after < 0.1
    ratios = error_ratios(p1[r.inliers], r.residuals[r.inliers])
    assert ratios.max() < 0.1
    # the removed pairs were the worst by Eq. 161 (corrected): the first removal is the largest ratio
    first = error_ratios(p1[plain.inliers], plain.residuals[plain.inliers])
    assert r.history[0].index == np.flatnonzero(plain.inliers)[np.argmax(first)]
    assert r.rms < plain.rms


@pytest.mark.parametrize("method", ["rodrigues", "svd"])
def test_error_ratio_elimination_improves_the_pose_on_average(method):
    """Over 20 draws of the planted configuration, the mean transfer error over the points drops by > 1.8x."""
    before, after = [], []
    for seed in range(20):
        rng = np.random.default_rng(2500 + seed)
        p1, p2, T, _, _ = _planted_near_centre(rng)
        plain = ransac_absolute_orientation(p1, p2, method=method, rng=seed)
        elim = ransac_absolute_orientation(p1, p2, method=method, rng=seed, r_lim=THESIS_R_LIM)
        for res, out in ((plain, before), (elim, after)):
            out.append(np.sqrt(np.mean(np.sum((transform_points(res.T, p2) - transform_points(T, p2)) ** 2, 1))))
    assert np.mean(before) > 1.8 * np.mean(after), (np.mean(before), np.mean(after))


def test_error_ratio_definition_and_stop_at_min_points():
    p = np.array([[0.0, 0, 0], [1.0, 0, 0], [-1.0, 0, 0], [0, 2.0, 0], [0, -2.0, 0]])
    d = np.array([0.1, 0.1, 0.2, 0.0, 0.4])
    r = error_ratios(p, d)  # centre is the origin
    assert np.isinf(r[0]) and np.allclose(r[1:], [0.1, 0.2, 0.0, 0.2])
    assert error_ratios(p[[0, 1, 2]], np.array([0.0, 0.1, 0.1]))[0] == 0.0
    # an r_lim below the noise level eliminates down to min_points and says so
    rng = np.random.default_rng(26)
    p1, p2, _, _ = random_correspondences(rng, 12, spread=0.3, sigma1=1e-3)
    res = ransac_absolute_orientation(p1, p2, rng=7, r_lim=1e-9, min_points=5)
    assert res.success and not res.elimination_converged
    assert res.inliers.sum() == 5 and len(res.history) == 7
    assert "stopped before all ratios" in res.message


def test_degenerate_cases():
    rng = np.random.default_rng(27)
    p1, p2, _, _ = random_correspondences(rng, 10)
    r = ransac_absolute_orientation(p1[:2], p2[:2], rng=8)
    assert not r.success and ">= 3 pairs" in r.message and np.all(np.isnan(r.T))
    # all pairs collinear: every sample is degenerate
    line = np.outer(np.linspace(-1, 1, 20), [0.2, 0.5, -0.3])
    r = ransac_absolute_orientation(line + 1.0, line, rng=8)
    assert not r.success and "no consensus" in r.message and r.iterations == 100
    # all outliers: two unrelated point clouds
    q1, q2 = rng.uniform(-1, 1, (2, 60, 3))
    for method in METHODS:
        r = ransac_absolute_orientation(q1, q2, method=method, rng=9)
        assert not r.success and "no consensus" in r.message and not r.inliers.any()
    # exactly three pairs, noise-free: accepted with min_inliers = 3
    p1, p2, T, _ = random_correspondences(rng, 3)
    r = ransac_absolute_orientation(p1, p2, rng=10, min_inliers=3)
    assert r.success and np.abs(r.T - T).max() < 1e-9
    assert not ransac_absolute_orientation(p1, p2, rng=10).success  # default needs 4


def test_bad_input_raises_one_line():
    p = np.arange(15.0).reshape(5, 3) ** 1.5
    for kwargs, match in [
        (dict(d_r=-1.0), "d_r"),
        (dict(r_lim=0.0), "r_lim"),
        (dict(method="lms"), "method"),
        (dict(refit_method="x"), "refit_method"),
        (dict(confidence=1.0), "confidence"),
        (dict(iterations=0), "iterations"),
        (dict(min_points=2), "min_points"),
    ]:
        with pytest.raises(ValueError, match=match) as info:
            ransac_absolute_orientation(p, p, **kwargs)
        assert "\n" not in str(info.value)
    with pytest.raises(ValueError, match="NaN"):
        ransac_absolute_orientation(p, np.where(p > 10, np.nan, p))
    with pytest.raises(ValueError, match="mismatched"):
        ransac_absolute_orientation(p, p[:4])
