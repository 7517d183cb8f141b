"""Property tests (hypothesis) of the geometry core: SE(3) round trips, the rotation parametrisations near 0 and pi,
closest points of nearly parallel lines.

Derandomized and database-less (``SETTINGS``), so CI sees the same examples every run; the example counts keep the
whole file to a few seconds. Rotations are drawn from a mixture that over-samples the trouble spots: angles exactly
0 and pi, within 1e-16 .. 1e-3 of them, and generic ones, about generic and coordinate axes (the latter make
Shepperd's pivot choice tie).
"""

import numpy as np
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from bench.geometry.lines import closest_points_between_lines
from bench.geometry.quaternion import (
    matrix_to_quaternion,
    matrix_to_rodrigues,
    matrix_to_rotation_vector,
    quaternion_product,
    quaternion_to_matrix,
    quaternion_to_rotation_vector,
    rodrigues_jacobian,
    rodrigues_to_matrix,
    rodrigues_to_quaternion,
    rotate_vector,
    rotation_vector_to_matrix,
    rotation_vector_to_quaternion,
)
from bench.geometry.transforms import (
    check_transform,
    homogeneous,
    invert,
    rotation_angle,
    skew,
    transform_points,
    vee,
)

SETTINGS = settings(deadline=None, max_examples=100, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
EPS = np.finfo(float).eps

finite = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)
small_exp = st.floats(-16.0, -3.0)


@st.composite
def unit_axes(draw):
    """Unit vectors: generic ones and +-coordinate axes (ties in Shepperd's pivot)."""
    if draw(st.booleans()):
        k = draw(st.integers(0, 2))
        v = np.zeros(3)
        v[k] = draw(st.sampled_from([-1.0, 1.0]))
        return v
    v = np.array([draw(finite), draw(finite), draw(finite)])
    assume(np.linalg.norm(v) > 0.1)
    return v / np.linalg.norm(v)


@st.composite
def angles(draw):
    """Rotation angles in [0, pi], over-sampling 0 and pi."""
    kind = draw(st.sampled_from(["zero", "near0", "pi", "nearpi", "generic"]))
    if kind == "zero":
        return 0.0
    if kind == "pi":
        return np.pi
    if kind == "near0":
        return 10.0 ** draw(small_exp)
    if kind == "nearpi":
        return np.pi - 10.0 ** draw(small_exp)
    return draw(st.floats(0.0, np.pi))


@st.composite
def rotation_vectors(draw):
    return draw(angles()) * draw(unit_axes())


@st.composite
def rigid_transforms(draw, max_translation=1e3):
    phi = draw(rotation_vectors())
    scale = 10.0 ** draw(st.floats(-3.0, np.log10(max_translation)))
    t = scale * np.array([draw(finite), draw(finite), draw(finite)])
    return homogeneous(rotation_vector_to_matrix(phi), t)


def _angle_between(R1, R2):
    return float(rotation_angle(np.swapaxes(R1, -1, -2) @ R2))


# ------------------------------------------------------------------------------------------------ SE(3)


@SETTINGS
@given(rigid_transforms(), rigid_transforms())
def test_invert_and_compose_round_trip(T, U):
    scale = 1.0 + np.abs(T[:3, 3]).max()
    assert np.abs(T @ invert(T) - np.eye(4)).max() <= 8 * EPS * scale
    assert np.abs(invert(invert(T)) - T).max() <= 8 * EPS * scale
    TU = T @ U
    check_transform(TU, "TU")  # a product of rigid transforms stays rigid
    s2 = scale + np.abs(U[:3, 3]).max()
    assert np.abs(invert(TU) - invert(U) @ invert(T)).max() <= 16 * EPS * s2


@SETTINGS
@given(rigid_transforms(), st.lists(st.tuples(finite, finite, finite), min_size=1, max_size=8),
       st.floats(-3.0, 6.0))
def test_transform_points_round_trip_and_rigidity(T, pts, log_scale):
    p = np.array(pts) * 10.0**log_scale
    q = transform_points(T, p)
    scale = 1.0 + np.abs(T[:3, 3]).max() + np.abs(p).max()
    assert np.abs(transform_points(invert(T), q) - p).max() <= 16 * EPS * scale
    # distances are kept (rigid), and the homogeneous product gives the same points
    d_p = np.linalg.norm(p[:, None] - p[None], axis=-1)
    d_q = np.linalg.norm(q[:, None] - q[None], axis=-1)
    assert np.abs(d_p - d_q).max(initial=0.0) <= 32 * EPS * scale
    ph = np.concatenate([p, np.ones((len(p), 1))], axis=1)
    assert np.abs((ph @ T.T)[:, :3] - q).max() <= 8 * EPS * scale


@SETTINGS
@given(rigid_transforms(), st.sampled_from(["reflect", "scale", "nan", "last_row", "shear"]),
       st.floats(1e-5, 1.0))
def test_check_transform_refuses_what_is_not_rigid(T, defect, size):
    bad = T.copy()
    if defect == "reflect":
        bad[:3, 0] *= -1.0
    elif defect == "scale":
        bad[:3, :3] *= 1.0 + size
    elif defect == "nan":
        bad[1, 2] = np.nan
    elif defect == "last_row":
        bad[3, 0] = size
    else:
        bad[0, 1] += size
    try:
        check_transform(bad, "T_a_b")
    except ValueError as exc:
        assert str(exc).startswith("T_a_b: ") and "\n" not in str(exc)
    else:
        raise AssertionError(f"check_transform accepted a {defect} defect of size {size}")
    check_transform(T, "T_a_b")


@SETTINGS
@given(st.tuples(finite, finite, finite), st.tuples(finite, finite, finite))
def test_skew_vee_cross(a, b):
    a, b = np.array(a), np.array(b)
    assert np.array_equal(vee(skew(a)), a)
    assert np.abs(skew(a) @ b - np.cross(a, b)).max() <= 4 * EPS
    assert np.array_equal(skew(a), -skew(a).T)


# ------------------------------------------------------------------------------------------------ rotations


@SETTINGS
@given(rotation_vectors())
def test_rotation_vector_matrix_quaternion_round_trips(phi):
    theta = np.linalg.norm(phi)
    R = rotation_vector_to_matrix(phi)
    check_transform(homogeneous(R, np.zeros(3)), "R", tol=1e-14)
    assert abs(float(rotation_angle(R)) - theta) <= 4 * EPS * max(1.0, theta)
    back = matrix_to_rotation_vector(R)
    if theta < np.pi - 1e-6:  # the log is unique: relative accuracy even at 1e-16 rad
        assert np.linalg.norm(back - phi) <= 4 * EPS * theta + 1e-300
    else:  # phi and -phi are the same rotation at pi; both the angle and the matrix must come back
        assert abs(np.linalg.norm(back) - theta) <= 1e-14
        assert np.abs(rotation_vector_to_matrix(back) - R).max() <= 1e-14
    q = matrix_to_quaternion(R)
    assert q[0] >= 0.0 and abs(np.linalg.norm(q) - 1.0) <= 4 * EPS
    assert np.abs(quaternion_to_matrix(q) - R).max() <= 1e-15 * 8
    q_phi = rotation_vector_to_quaternion(phi)
    assert min(np.abs(q - q_phi).max(), np.abs(q + q_phi).max()) <= 1e-15 * 4
    phi_q = quaternion_to_rotation_vector(q_phi)
    assert np.linalg.norm(phi_q - phi) <= 8 * EPS * max(theta, 1e-300) or theta > np.pi - 1e-6


@SETTINGS
@given(rotation_vectors(), rotation_vectors(), st.tuples(finite, finite, finite))
def test_quaternion_product_is_matrix_product(phi_a, phi_b, v):
    qa, qb = rotation_vector_to_quaternion(phi_a), rotation_vector_to_quaternion(phi_b)
    Ra, Rb = quaternion_to_matrix(qa), quaternion_to_matrix(qb)
    assert np.abs(quaternion_to_matrix(quaternion_product(qa, qb)) - Ra @ Rb).max() <= 16 * EPS  # Eq. 130, 136
    assert np.abs(rotate_vector(qa, np.array(v)) - Ra @ np.array(v)).max() <= 16 * EPS  # Eq. 135


@st.composite
def rodrigues_vectors(draw):
    """``tan(theta / 2) k`` from 0 to 1e6 (theta within ~2e-6 of pi)."""
    mag = draw(st.one_of(st.just(0.0), st.floats(-12.0, 6.0).map(lambda e: 10.0**e)))
    return mag * draw(unit_axes())


@SETTINGS
@given(rodrigues_vectors())
def test_rodrigues_round_trip_and_cayley_form(x):
    n = np.linalg.norm(x)
    R = rodrigues_to_matrix(x)  # Cayley form
    assert np.abs(R - quaternion_to_matrix(rodrigues_to_quaternion(x))).max() <= 16 * EPS  # Eq. 145 -> 136
    assert abs(float(rotation_angle(R)) - 2 * np.arctan(n)) <= 1e-15 * 8 * max(1.0, n)  # Eq. 156 corrected
    back = matrix_to_rodrigues(R)
    # x = q_vec / q0 with q0 = 1 / sqrt(1 + |x|^2) known to ~eps: relative error ~ eps (1 + |x|)
    assert np.linalg.norm(back - x) <= 16 * EPS * (1.0 + n) * max(n, 1e-300) + 1e-300


@SETTINGS
@given(rodrigues_vectors().filter(lambda x: np.linalg.norm(x) < 1e3), st.integers(0, 2))
def test_rodrigues_jacobian_against_central_differences(x, k):
    """``R(x + h e_k) R(x)^T = exp([J e_k h]x)`` to first order (the derivative ``rodrigues_jacobian`` claims)."""
    h = 1e-6 * max(1.0, np.linalg.norm(x))
    e = np.zeros(3)
    e[k] = h
    R0 = rodrigues_to_matrix(x)
    num = (matrix_to_rotation_vector(rodrigues_to_matrix(x + e) @ R0.T)
           - matrix_to_rotation_vector(rodrigues_to_matrix(x - e) @ R0.T)) / (2 * h)
    J = rodrigues_jacobian(x)
    assert np.linalg.norm(num - J[:, k]) <= 1e-7 * max(1.0, np.linalg.norm(J[:, k])) + 1e-9


# ------------------------------------------------------------------------------------------------ lines


@SETTINGS
@given(unit_axes(), st.floats(-16.0, 0.0), st.tuples(finite, finite, finite), st.floats(-3.0, 3.0),
       st.floats(-2.0, 2.0), st.floats(-2.0, 2.0))
def test_closest_points_of_nearly_parallel_lines(d1, log_angle, w, log_sep, g1, g2):
    """Two lines at angle 1e-16 .. 1 rad through points ``g`` apart along them, separated by ``sep``: the returned
    points are finite, the distance is the true one, and the segment is perpendicular to both lines (Eq. 109-110)
    to the rounding of the inputs (``eps`` times the lever arm) however nearly parallel they are. The positions along
    the lines are ill-conditioned: rounding the directions (``eps``) turns the common normal by ``eps / angle`` and
    moves the closest points by ``eps (|p| + sep / angle) / angle``; that is the tolerance on ``gamma``."""
    angle = 10.0**log_angle
    w = np.array(w)
    perp = np.cross(d1, w)
    assume(np.linalg.norm(perp) > 1e-3)
    perp /= np.linalg.norm(perp)
    other = np.cross(d1, perp)  # unit, perpendicular to d1 and perp
    d2 = np.cos(angle) * d1 + np.sin(angle) * perp
    sep = 10.0**log_sep
    c = np.array([0.3, -1.2, 2.0])
    # common normal along `other`: line 1 through c, line 2 through c + sep * other
    p1, p2 = c + g1 * d1, c + sep * other + g2 * d2
    cp = closest_points_between_lines(p1, d1, p2, d2)
    assert np.all(np.isfinite(np.concatenate([cp.p1, cp.p2, [cp.gamma1, cp.gamma2, cp.distance]])))
    lever = 1.0 + np.abs(c).max() + sep + abs(cp.gamma1) + abs(cp.gamma2)
    assert abs(cp.distance - sep) <= 64 * EPS * lever
    seg = cp.p2 - cp.p1
    assert abs(seg @ d2) <= 64 * EPS * lever  # P_2 is the foot of P_1 on line 2 (Eq. 117)
    if cp.parallel:
        assert angle <= 1e-8 and cp.gamma1 == 0.0
    else:
        assert abs(seg @ d1) <= 64 * EPS * lever
        tol = 64 * EPS * (1.0 + np.abs(c).max() + sep / np.sin(angle)) / np.sin(angle)
        assert abs(cp.gamma1 + g1) <= tol and abs(cp.gamma2 + g2) <= tol
