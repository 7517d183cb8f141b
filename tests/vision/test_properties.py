"""Property tests (hypothesis) of the vision geometry: absolute orientation (all three methods) under reflection-prone
and degenerate spreads, triangulation of nearly parallel rays.

Derandomized and database-less (``SETTINGS``): CI sees the same examples every run. Point sets are drawn in shapes
that break naive implementations: generic, exactly coplanar (a mirror image is then a proper rotation - plain SVD
returns a reflection), thin slabs, nearly collinear needles, every point duplicated, and far from the origin
(offsets up to 1e6 m).
"""

import numpy as np
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from bench.geometry.quaternion import rotation_vector_to_matrix
from bench.geometry.transforms import homogeneous, invert, rotation_angle, transform_points
from bench.vision.absolute_orientation import METHODS, WARN_CONDITION, absolute_orientation
from bench.vision.triangulation import (
    reprojection_jacobian,
    triangulate_linear,
    triangulate_midpoint,
    triangulate_optimal,
)

SETTINGS = settings(deadline=None, max_examples=60, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
EPS = np.finfo(float).eps
unit = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)


@st.composite
def rotations(draw):
    """Rotation matrices over-sampling angles at and near 0 and pi."""
    k = np.array([draw(unit), draw(unit), draw(unit)])
    assume(np.linalg.norm(k) > 0.1)
    kind = draw(st.sampled_from(["zero", "near0", "pi", "nearpi", "generic"]))
    angle = {"zero": 0.0, "pi": np.pi, "near0": 10.0 ** draw(st.floats(-14, -3)),
             "nearpi": np.pi - 10.0 ** draw(st.floats(-14, -3)), "generic": draw(st.floats(0.0, np.pi))}[kind]
    return rotation_vector_to_matrix(angle * k / np.linalg.norm(k))


@st.composite
def point_sets(draw):
    """``(p2 (n, 3), shape, spread, offset)``: points about a centre ``offset`` away, spread ``spread`` (m)."""
    shape = draw(st.sampled_from(["generic", "coplanar", "slab", "duplicated", "needle"]))
    n = draw(st.integers(3, 12))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    spread = 10.0 ** draw(st.floats(-2.0, 1.0))
    offset = 10.0 ** draw(st.floats(-3.0, 6.0))
    c = rng.normal(size=(n, 3))
    if shape in ("coplanar", "slab"):
        c[:, 2] = 0.0 if shape == "coplanar" else 1e-6 * c[:, 2]
    elif shape == "needle":
        c[:, 1:] *= 1e-5
    c = c @ rotation_vector_to_matrix(rng.normal(size=3)).T  # the degenerate direction is not an axis
    if shape == "duplicated":
        c = np.concatenate([c, c])[rng.permutation(2 * n)]
    centre = offset * rng.normal(size=3) / np.sqrt(3)
    return centre + spread * c, shape, spread, offset


def _condition(p):
    c = p - p.mean(0)
    H = np.trace(c.T @ c) * np.eye(3) - c.T @ c
    lam = np.linalg.eigvalsh(H)
    return lam[-1] / lam[0] if lam[0] > 0 else np.inf


def _proper(R):
    return abs(np.linalg.det(R) - 1.0) <= 1e-12 and np.abs(R.T @ R - np.eye(3)).max() <= 1e-12


@SETTINGS
@given(point_sets(), rotations(), st.tuples(unit, unit, unit), st.sampled_from(METHODS))
def test_absolute_orientation_exact_or_refused(pts, R, t, method):
    """Noise-free ``p1 = R p2 + t``: every method returns a proper rotation that maps p2 onto p1 to the precision the
    spread's conditioning allows, or refuses a (nearly) collinear spread with ``success=False``."""
    p2, shape, spread, offset = pts
    T = homogeneous(R, 10.0 * np.array(t) * max(spread, 1.0))
    p1 = transform_points(T, p2)
    res = absolute_orientation(p1, p2, method=method)
    cond = _condition(p2)
    if not res.success:
        assert shape == "needle" and "collinear" in res.message and np.all(np.isnan(res.T)), res.message
        return
    assert _proper(res.R), (method, shape)
    # data rounding is eps * (offset + spread); relative to the spread it tilts the rotation by that much, amplified
    # by the conditioning of the spread (sqrt of the eigenvalue ratio of the inertia matrix)
    rel = EPS * (offset + spread + np.abs(T[:3, 3]).max()) / spread
    assert rotation_angle(res.R.T @ R) <= 1e3 * rel * np.sqrt(cond) + 1e-12, (method, shape, cond)
    assert res.rms <= 1e3 * rel * spread * np.sqrt(cond) + 1e-12 * spread
    if cond > WARN_CONDITION:
        assert "ill-conditioned" in res.message


@SETTINGS
@given(point_sets(), rotations(), st.integers(0, 2), st.sampled_from(METHODS))
def test_mirror_images_give_proper_rotations(pts, R, axis, method):
    """``p1`` is the mirror image of ``p2``: never a reflection. For an exactly coplanar set the mirror image *is* a
    rotated copy, and every method must find it exactly (plain ``V U^T`` returns the reflection there)."""
    p2, shape, spread, offset = pts
    assume(shape != "needle")
    S = np.eye(3)
    S[axis, axis] = -1.0
    centre = p2.mean(0)
    p1 = (p2 - centre) @ (R @ S).T + centre
    res = absolute_orientation(p1, p2, method=method)
    assert res.success and _proper(res.R), (method, shape, res.message)
    svd = absolute_orientation(p1, p2, method="svd")
    if method != "rodrigues":  # SVD and Horn minimise the same cost: the same optimum
        assert res.rms <= svd.rms + 1e-9 * (spread + offset * EPS * 1e6)
    if shape == "coplanar":
        assert res.rms <= 1e-6 * spread + 1e3 * EPS * offset, (method, res.rms)


@SETTINGS
@given(point_sets(), rotations(), st.sampled_from(["svd", "horn"]), st.floats(1e-4, 1e-2))
def test_inverse_and_permutation_symmetry_on_noisy_data(pts, R, method, noise):
    """Least-squares methods: swapping the sets inverts the transform; reordering the points changes nothing."""
    p2, shape, spread, offset = pts
    assume(shape in ("generic", "duplicated") and offset < 1e3)
    rng = np.random.default_rng(len(p2))
    p1 = p2 @ R.T + rng.normal(scale=noise * spread, size=p2.shape)
    fwd = absolute_orientation(p1, p2, method=method)
    bwd = absolute_orientation(p2, p1, method=method)
    perm = rng.permutation(len(p2))
    shuffled = absolute_orientation(p1[perm], p2[perm], method=method)
    assert fwd.success and bwd.success and shuffled.success
    scale = spread + offset
    assert np.abs(fwd.T @ bwd.T - np.eye(4)).max() <= 1e-9 * scale
    assert np.abs(fwd.T - shuffled.T).max() <= 1e-9 * scale


@SETTINGS
@given(st.integers(0, 2), st.integers(1, 4), st.sampled_from(METHODS))
def test_too_few_distinct_points_are_results_not_errors(n_distinct, copies, method):
    """0-2 distinct points, each repeated: coincident or collinear, never a pose and never an exception."""
    rng = np.random.default_rng(n_distinct * 10 + copies)
    base = rng.normal(size=(max(n_distinct, 1), 3))
    p2 = np.repeat(base, copies, axis=0)
    res = absolute_orientation(p2 + 1.0, p2, method=method)
    assert not res.success and np.all(np.isnan(res.R))
    assert ">= 3 points" in res.message or "collinear or coincident" in res.message


# ------------------------------------------------------------------------------------------------ triangulation


@st.composite
def stereo_pairs(draw):
    """Two cameras ``b`` apart (0 or 1e-12 .. 1 times the depth), converging or parallel, and points in front."""
    depth = 10.0 ** draw(st.floats(-1.0, 2.0))
    b = 0.0 if draw(st.booleans()) and draw(st.booleans()) else depth * 10.0 ** draw(st.floats(-12.0, 0.0))
    direction = np.array([draw(unit), draw(unit), 0.2 * draw(unit)])  # mostly sideways, a little along the axis
    assume(np.linalg.norm(direction[:2]) > 0.3)
    direction /= np.linalg.norm(direction)
    toe_in = draw(st.floats(0.0, 0.2)) * b / depth  # slightly converging cameras (rad)
    T1 = np.eye(4)
    T2 = homogeneous(rotation_vector_to_matrix(np.cross([0, 0, 1.0], direction) * toe_in), b * direction)
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    n = draw(st.integers(1, 6))
    p = np.column_stack([rng.uniform(-0.3, 0.3, (n, 2)) * depth, depth * rng.uniform(0.8, 1.2, n)])
    return T1, T2, p, b, depth


def _xn(T, p):
    pc = transform_points(invert(T), p)
    return pc[:, :2] / pc[:, 2:3]


@SETTINGS
@given(stereo_pairs())
def test_triangulation_of_nearly_parallel_rays(pair):
    """Noise-free rays, baseline 0 .. depth: no method raises; every point is finite and valid, or NaN and flagged
    ``valid=False`` (the same contract for every method), and a valid point is as accurate as the baseline allows: the
    rounding of the normalized coordinates (eps) moves it by ``eps depth^2 / b`` (Eq. 123 with ds = eps)."""
    T1, T2, p, b, depth = pair
    x1, x2 = _xn(T1, p), _xn(T2, p)
    tol = 1e3 * EPS * depth * (1.0 + depth / max(b, 1e-300))
    T = np.stack([T1, T2])
    x = np.stack([x1, x2])
    mid = triangulate_midpoint(T, x)
    lin = triangulate_linear(T, x)
    opt = triangulate_optimal(T, x)
    for est in (mid, lin, opt):
        good = est.valid
        assert np.all(np.isfinite(est.points[good])) and np.all(np.isnan(est.points[~good]))
        assert np.all(np.isnan(est.gap[~good])) and np.all(np.isnan(est.rms[~good]))
        assert np.all(np.linalg.norm(est.points[good] - p[good], axis=1) <= tol)
        if b == 0.0:
            assert not good.any()  # zero baseline: the rays coincide
        if b >= 1e-3 * depth:  # a usable baseline: every method triangulates every point
            assert good.all()


@SETTINGS
@given(stereo_pairs().filter(lambda s: s[3] > 1e-3 * s[4]), st.integers(0, 2))
def test_reprojection_jacobian_against_central_differences(pair, k):
    """``reprojection_jacobian`` (the Gauss-Newton step of :func:`triangulate_optimal`) is the derivative of the
    projections."""
    T1, T2, p, b, depth = pair
    T = np.stack([T1, T2])
    proj, J = reprojection_jacobian(T, p)
    h = 1e-6 * depth
    e = np.zeros(3)
    e[k] = h
    num = (reprojection_jacobian(T, p + e)[0] - reprojection_jacobian(T, p - e)[0]) / (2 * h)
    assert np.abs(num - J[..., k]).max() <= 1e-6 * (1.0 + np.abs(J).max())
    assert np.abs(proj - np.stack([_xn(T1, p), _xn(T2, p)])).max() <= 1e3 * EPS
