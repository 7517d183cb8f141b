import numpy as np
import pytest

from bench.geometry.quaternion import matrix_to_rotation_vector, rotation_vector_to_matrix
from bench.geometry.transforms import homogeneous, invert, random_rotation, transform_points
from bench.vision.triangulation import (
    required_baseline,
    stereo_sensitivity,
    triangulate_linear,
    triangulate_midpoint,
    triangulate_optimal,
)


def _views(rng, n_views, n_points, baseline=0.2, depth=1.5):
    """Cameras near the origin looking along +z (small random rotations), points ~depth in front."""
    T = [np.eye(4)]
    for _ in range(n_views - 1):
        t = rng.uniform(-baseline, baseline, 3) * [1, 1, 0.2]
        T.append(homogeneous(_small(random_rotation(rng)), t))
    T = np.stack(T)
    p = np.column_stack([rng.uniform(-0.4, 0.4, n_points), rng.uniform(-0.3, 0.3, n_points),
                         rng.uniform(depth - 0.3, depth + 0.3, n_points)])
    return T, p


def _small(R, scale=0.1):
    """A rotation a fraction of the way to R (keeps every view facing the points)."""
    return rotation_vector_to_matrix(scale * matrix_to_rotation_vector(R))


def _project(T, p):
    pc = transform_points(invert(T)[:, None], p[None])
    return pc[..., :2] / pc[..., 2:3], pc[..., 2]


def test_noise_free_exactness():
    rng = np.random.default_rng(31)
    T, p = _views(rng, 5, 200)
    x, z = _project(T, p)
    m = triangulate_midpoint(T[:2], x[:2])
    assert m.valid.all() and np.abs(m.points - p).max() <= 1e-9 * np.abs(p).max()
    assert m.gap.max() <= 1e-12 and np.allclose(m.depth, z[:2], rtol=1e-12)
    for views in (slice(0, 2), slice(0, 5)):
        lin = triangulate_linear(T[views], x[views])
        assert lin.valid.all() and np.abs(lin.points - p).max() <= 1e-9 * np.abs(p).max()
        opt = triangulate_optimal(T[views], x[views])
        assert np.abs(opt.points - p).max() <= 1e-9 * np.abs(p).max() and opt.rms.max() < 1e-12


def test_depth_noise_matches_eq_123_and_optimal_is_no_worse():
    rng = np.random.default_rng(32)
    alpha, sigma_px, d_int, z = 800.0, 0.5, 0.1, 1.2
    T = np.stack([np.eye(4), homogeneous(np.eye(3), [d_int, 0.0, 0.0])])  # parallel stereo pair
    p = np.tile([0.05, 0.0, z], (4000, 1))
    x, _ = _project(T, p)
    xn = x + rng.normal(0.0, sigma_px / alpha, x.shape)
    m = triangulate_midpoint(T, xn).points
    po = triangulate_optimal(T, xn).points
    # disparity error of two independent image points: sigma_s = sqrt(2) sigma_px
    pred = np.abs(stereo_sensitivity(0.05 / z * alpha, 0.0, 0.0, 0.0, alpha, alpha, d_int, z, np.sqrt(2) * sigma_px))
    assert np.std(m[:, 2]) == pytest.approx(pred[2], rel=0.08)
    assert np.std(po[:, 2]) == pytest.approx(pred[2], rel=0.08)
    err_mid = np.sqrt(np.mean(np.sum((m - p) ** 2, 1)))
    err_opt = np.sqrt(np.mean(np.sum((po - p) ** 2, 1)))
    assert err_opt <= err_mid * 1.01


def test_required_baseline_eq_199():
    # thesis section 5.2.2: 1 px keypoints, 10 mm depth resolution at 700 mm with alpha ~ 1000 px -> 49 mm
    assert required_baseline(0.7, 1000.0, 0.010) == pytest.approx(0.049)
    d = required_baseline(0.7, 1000.0, 0.010)
    assert abs(stereo_sensitivity(500, 0, 500, 0, 1000.0, 1000.0, d, 0.7)[2]) == pytest.approx(0.010)


def test_degenerate_geometry():
    x = np.array([[0.1, 0.0]])
    same = triangulate_midpoint([np.eye(4), np.eye(4)], [x, np.array([[0.0, 0.0]])])  # zero baseline
    assert not same.valid.any() and np.isnan(same.points).all()
    shifted = homogeneous(np.eye(3), [0.1, 0, 0])
    par = triangulate_midpoint([np.eye(4), shifted], [x, x])  # parallel rays
    assert not par.valid.any() and np.isnan(par.gap).all()
    lin = triangulate_linear(np.stack([np.eye(4), np.eye(4)]), np.stack([x, np.array([[0.0, 0.0]])]))
    assert np.isnan(lin.points).all() and not lin.valid.any()
    # regression: zero baseline raised LinAlgError ("SVD did not converge") in triangulate_optimal
    for p0 in (None, [[0.1, 0.0, 1.0]]):
        opt = triangulate_optimal(np.stack([np.eye(4), np.eye(4)]), np.stack([x, x]), p0=p0)
        assert np.isnan(opt.points).all() and np.isnan(opt.rms).all()
    behind = triangulate_midpoint([np.eye(4), shifted], [np.array([[0.1, 0.0]]), np.array([[0.2, 0.0]])])
    assert not behind.valid.any()  # rays diverge: the closest points lie behind the cameras
    with pytest.raises(ValueError, match="x_n"):
        triangulate_midpoint([np.eye(4), shifted], [np.array([[np.nan, 0.0]]), x])
    with pytest.raises(ValueError, match="V >= 2"):
        triangulate_linear(np.eye(4)[None], x[None])
    with pytest.raises(ValueError, match="must be > 0"):
        required_baseline(0.7, 1000.0, 0.0)
