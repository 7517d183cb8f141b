import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bench.geometry.quaternion import (
    check_quaternion,
    left_matrix,
    matrix_to_quaternion,
    matrix_to_rodrigues,
    matrix_to_rotation_vector,
    quaternion_conjugate,
    quaternion_from_axis_angle,
    quaternion_inverse,
    quaternion_norm2,
    quaternion_product,
    quaternion_to_matrix,
    quaternion_to_rodrigues,
    quaternion_to_rotation_vector,
    random_quaternion,
    right_matrix,
    rodrigues_jacobian,
    rodrigues_to_matrix,
    rodrigues_to_quaternion,
    rotate_vector,
    rotation_vector_jacobian,
    rotation_vector_to_matrix,
    rotation_vector_to_quaternion,
)
from bench.geometry.transforms import random_rotation, rot_x, rotation_angle, skew, vee


def _same_rotation_q(a, b):
    """Distance between quaternions up to sign."""
    return np.minimum(np.abs(a - b).max(-1), np.abs(a + b).max(-1))


def _special_rotations(rng):
    """Rotations at and near the trouble spots 0 and pi, plus random ones: (M, 3) rotation vectors."""
    axes = np.concatenate([np.eye(3), -np.eye(3), rng.normal(size=(6, 3))])
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = [0.0, 1e-15, 1e-9, 1e-6, 0.5, np.pi / 2, 3.0, np.pi - 1e-9, np.pi - 1e-12, np.pi]
    return np.concatenate([a * axes for a in angles])


def test_product_eq_130_basis_and_matrix_forms():
    one, i, j, k = np.eye(4)
    assert np.array_equal(quaternion_product(i, j), k)  # i x j = k (text after Eq. 126)
    assert np.array_equal(quaternion_product(j, k), i)
    assert np.array_equal(quaternion_product(k, i), j)
    assert np.array_equal(quaternion_product(i, i), -one)
    rng = np.random.default_rng(11)
    a, b, c = rng.normal(size=(3, 50, 4))
    ab = quaternion_product(a, b)
    assert np.allclose(ab, np.einsum("nij,nj->ni", left_matrix(a), b), atol=1e-14)
    assert np.allclose(ab, np.einsum("nij,nj->ni", right_matrix(b), a), atol=1e-14)
    assert np.allclose(quaternion_product(ab, c), quaternion_product(a, quaternion_product(b, c)), atol=1e-13)
    assert np.allclose(quaternion_norm2(ab), quaternion_norm2(a) * quaternion_norm2(b), rtol=1e-13)  # Eq. 131
    assert np.allclose(quaternion_product(a, quaternion_inverse(a)), one, atol=1e-14)  # Eq. 132
    assert np.allclose(quaternion_conjugate(ab), quaternion_product(quaternion_conjugate(b), quaternion_conjugate(a)))


def test_rotation_eq_133_135_136_and_scipy():
    rng = np.random.default_rng(12)
    q = random_quaternion(rng, 200)
    assert np.all(q[:, 0] >= 0) and np.allclose(np.linalg.norm(q, axis=1), 1.0)
    R = quaternion_to_matrix(q)
    v = rng.normal(size=(200, 3))
    assert np.allclose(rotate_vector(q, v), np.einsum("nij,nj->ni", R, v), atol=1e-14)  # Eq. 135 == Eq. 136
    assert np.allclose(R, Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix(), atol=1e-14)  # SciPy is scalar-last
    assert np.allclose(np.swapaxes(R, 1, 2) @ R, np.eye(3), atol=1e-14)
    assert np.allclose(np.linalg.det(R), 1.0)
    q2 = random_quaternion(rng, 200)
    assert np.allclose(quaternion_to_matrix(quaternion_product(q, q2)), R @ quaternion_to_matrix(q2), atol=1e-14)
    # Eq. 133: axis-angle
    qa = quaternion_from_axis_angle([1.0, 0, 0], 0.3)
    assert np.allclose(quaternion_to_matrix(qa), rot_x(0.3), atol=1e-15)


def test_matrix_quaternion_round_trip_near_0_and_pi():
    rng = np.random.default_rng(13)
    phi = _special_rotations(rng)
    R = Rotation.from_rotvec(phi).as_matrix()  # an independent construction
    q = matrix_to_quaternion(R)
    assert np.all(q[:, 0] >= 0.0)
    assert np.abs(quaternion_to_matrix(q) - R).max() < 1e-14
    q_ref = Rotation.from_matrix(R).as_quat()[:, [3, 0, 1, 2]]
    assert _same_rotation_q(q, q_ref).max() < 1e-14
    # random rotations, batched shape kept
    Rr = random_rotation(rng, (4, 5))
    assert matrix_to_quaternion(Rr).shape == (4, 5, 4)
    assert np.abs(quaternion_to_matrix(matrix_to_quaternion(Rr)) - Rr).max() < 1e-14


def test_rotation_vector_round_trip_near_0_and_pi():
    rng = np.random.default_rng(14)
    phi = _special_rotations(rng)
    R = rotation_vector_to_matrix(phi)
    assert np.abs(R - Rotation.from_rotvec(phi).as_matrix()).max() < 1e-15
    back = matrix_to_rotation_vector(R)
    theta = np.linalg.norm(phi, axis=1)
    below_pi = theta < np.pi - 1e-6
    # below pi the log is unique; relative accuracy holds even for 1e-15 rad
    err = np.linalg.norm(back[below_pi] - phi[below_pi], axis=1)
    assert np.all(err <= 1e-15 + 1e-13 * theta[below_pi])
    # at/near pi: phi and -phi (angle 2 pi - theta) are the same rotation; compare matrices and the angle
    assert np.abs(rotation_vector_to_matrix(back) - R).max() < 1e-14
    assert np.allclose(np.linalg.norm(back, axis=1), np.minimum(theta, 2 * np.pi - theta), atol=1e-12)
    assert np.allclose(np.linalg.norm(back, axis=1), rotation_angle(R), atol=1e-12)
    # quaternion <-> rotation vector, tiny angle series
    q = rotation_vector_to_quaternion(np.array([1e-10, -2e-10, 3e-10]))
    assert np.allclose(quaternion_to_rotation_vector(q), [1e-10, -2e-10, 3e-10], rtol=1e-12, atol=0)


def test_rodrigues_parameters_eq_145():
    rng = np.random.default_rng(15)
    x = rng.normal(size=(100, 3)) * np.array([[1e-9], [1.0], [30.0], [1e4]]).repeat(25, 0)
    q = rodrigues_to_quaternion(x)
    theta = 2 * np.arctan(np.linalg.norm(x, axis=1))  # Eq. 156 (corrected: 2 atan |x|)
    k = x / np.linalg.norm(x, axis=1, keepdims=True)  # Eq. 155
    assert np.allclose(q, quaternion_from_axis_angle(k, theta), atol=1e-15)  # Eq. 133
    assert np.abs(rodrigues_to_matrix(x) - quaternion_to_matrix(q)).max() < 1e-14  # Cayley == Eq. 136
    assert np.allclose(quaternion_to_rodrigues(q), x, rtol=1e-10)
    assert np.allclose(matrix_to_rodrigues(rodrigues_to_matrix(x[:75])), x[:75], rtol=1e-10, atol=1e-20)
    # Cayley form R = (I - [x]x)^-1 (I + [x]x)
    from bench.geometry.transforms import skew

    S = skew(x[30])
    assert np.allclose(np.linalg.solve(np.eye(3) - S, np.eye(3) + S), rodrigues_to_matrix(x[30]), atol=1e-14)
    with pytest.raises(ValueError, match="pi"):
        quaternion_to_rodrigues([0.0, 1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="NaN"):
        rodrigues_to_quaternion([np.nan, 0, 0])


def test_rodrigues_jacobian_finite_differences():
    rng = np.random.default_rng(16)
    for x in [np.zeros(3), rng.normal(size=3) * 0.3, rng.normal(size=3) * 3.0]:
        J = rodrigues_jacobian(x)
        R = rodrigues_to_matrix(x)
        h = 1e-6
        Jfd = np.empty((3, 3))
        for c in range(3):
            dx = np.zeros(3)
            dx[c] = h
            Rp, Rm = rodrigues_to_matrix(x + dx), rodrigues_to_matrix(x - dx)
            Jfd[:, c] = (vee(Rp @ R.T) - vee(Rm @ R.T)) / (2 * h)  # left rotation vector
        assert np.abs(J - Jfd).max() < 1e-8 * max(1.0, np.abs(J).max())


def test_rotation_vector_jacobian_against_scipy_near_0_and_pi():
    """``J = int_0^1 exp(s [phi]x) ds`` (the left Jacobian's integral form), by Gauss-Legendre quadrature on SciPy's
    ``Rotation.from_rotvec`` - an independent construction, exact to rounding for a smooth integrand."""
    rng = np.random.default_rng(17)
    axes = rng.normal(size=(4, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    extra = [1e-2 * (1 - 1e-12), 1e-2, 1e-2 * (1 + 1e-12), 2.0, 5.0, 6.0]  # both sides of the series switch; up to 2 pi
    phi = np.concatenate([_special_rotations(rng), np.concatenate([a * axes for a in extra])])
    s, w = np.polynomial.legendre.leggauss(30)
    s, w = 0.5 * (s + 1.0), 0.5 * w
    ref = np.einsum("k,knij->nij", w, Rotation.from_rotvec((s[:, None, None] * phi).reshape(-1, 3)).as_matrix()
                    .reshape(len(s), len(phi), 3, 3))
    J = rotation_vector_jacobian(phi)
    assert J.shape == (len(phi), 3, 3)
    assert np.abs(J - ref).max() < 4e-15
    assert np.array_equal(rotation_vector_jacobian(np.zeros(3)), np.eye(3))
    assert np.abs(np.einsum("nij,nj->ni", J, phi) - phi).max() < 1e-14  # J phi = phi
    assert np.abs(rotation_vector_to_matrix(phi) @ rotation_vector_jacobian(-phi) - J).max() < 1e-14  # J_l = R J_r
    assert rotation_vector_jacobian(np.zeros((2, 5, 3))).shape == (2, 5, 3, 3)


def test_rotation_vector_jacobian_finite_differences():
    """``exp([phi + delta]x) exp([phi]x)^T = exp([J delta]x)``, and ``d(R v) / d phi = -[R v]x J``, by central
    differences of SciPy's rotation vectors (small, mid, near pi, beyond pi)."""
    rng = np.random.default_rng(18)
    v = rng.normal(size=3)
    for theta in [0.0, 1e-6, 1e-2, 0.7, 3.0, np.pi - 1e-6, 4.0]:
        axis = rng.normal(size=3)
        phi = theta * axis / np.linalg.norm(axis)
        J = rotation_vector_jacobian(phi)
        R = Rotation.from_rotvec(phi)
        h = 1e-6
        Jfd, Dfd = np.empty((3, 3)), np.empty((3, 3))
        for c in range(3):
            dphi = np.zeros(3)
            dphi[c] = h
            Rp, Rm = Rotation.from_rotvec(phi + dphi), Rotation.from_rotvec(phi - dphi)
            Jfd[:, c] = ((Rp * R.inv()).as_rotvec() - (Rm * R.inv()).as_rotvec()) / (2 * h)
            Dfd[:, c] = (Rp.apply(v) - Rm.apply(v)) / (2 * h)
        assert np.abs(J - Jfd).max() < 1e-8
        assert np.abs(-skew(R.apply(v)) @ J - Dfd).max() < 1e-8


def test_check_quaternion_errors():
    with pytest.raises(ValueError, match="shape"):
        check_quaternion(np.zeros(3))
    with pytest.raises(ValueError, match="NaN"):
        check_quaternion([np.nan, 0, 0, 1])
    with pytest.raises(ValueError, match="zero"):
        check_quaternion([0.0, 0, 0, 0])
    with pytest.raises(ValueError, match="unit"):
        check_quaternion([2.0, 0, 0, 0], unit=True)
    with pytest.raises(ValueError, match="R:"):
        matrix_to_quaternion(np.eye(4))


def test_axis_angle_to_matrix_is_the_exponential_map_of_one_axis():
    """A revolute joint's rotation (Rodrigues for a fixed axis) equals the exponential map of ``angle * axis`` and
    SciPy's rotation, over angles of any shape; the axis is normalised; a zero or non-finite axis is refused."""
    from scipy.spatial.transform import Rotation

    from bench.geometry.quaternion import axis_angle_to_matrix, rotation_vector_to_matrix

    rng = np.random.default_rng(5)
    axis = rng.normal(size=3)
    angle = rng.uniform(-4, 4, (7, 5))
    R = axis_angle_to_matrix(axis, angle)
    phi = angle[..., None] * axis / np.linalg.norm(axis)
    assert R.shape == (7, 5, 3, 3)
    assert np.max(np.abs(R - rotation_vector_to_matrix(phi))) < 1e-14
    assert np.max(np.abs(R.reshape(-1, 3, 3) - Rotation.from_rotvec(phi.reshape(-1, 3)).as_matrix())) < 1e-14
    assert np.array_equal(axis_angle_to_matrix([0, 0, 1], 0.0), np.eye(3))
    for bad in ([0, 0, 0], [np.nan, 0, 1], [1, 0]):
        with pytest.raises(ValueError, match="axis"):
            axis_angle_to_matrix(bad, 0.1)
