"""Quaternion algebra (thesis section 3.7.1, Eq. 126-136) and Rodrigues parameters (Eq. 145), batched.

Convention: **scalar first**, ``q = [q0, q1, q2, q3] = [a0, a^T]^T`` (Eq. 127), Hamilton product (Eq. 130:
``i j = k``), active rotations: ``v' = q o v o q*`` (Eq. 135) equals ``R v`` with ``R`` of Eq. 136. A rotation by
``theta`` about the unit axis ``k`` is ``q = [cos(theta / 2), sin(theta / 2) k]`` (Eq. 133); ``q`` and ``-q`` are the
same rotation, and functions returning a quaternion from a rotation choose ``q0 >= 0``. SciPy's
``Rotation.as_quat()`` is scalar *last* (``[x, y, z, w]``).

Rotation vectors ``phi = theta k`` (rad) and Rodrigues (Gibbs) parameters ``x = tan(theta / 2) k`` (Eq. 145) are
the other two parametrisations. Conversions are robust near ``theta = 0`` (series, no division by the angle) and
near ``theta = pi`` (Shepperd's method for matrix -> quaternion, ``atan2`` for the angle). Rodrigues parameters are
infinite at ``theta = pi``: :func:`quaternion_to_rodrigues` raises there.

Every function broadcasts over leading axes: quaternions ``(..., 4)``, vectors ``(..., 3)``, matrices
``(..., 3, 3)``.
"""

from __future__ import annotations

import numpy as np

from bench.geometry.transforms import check_vectors, skew


def check_quaternion(q, name="q", unit=False, tol=1e-6):
    """Validate quaternions ``q (..., 4)``: finite, non-zero, and of unit norm if ``unit``; returns a float array."""
    q = check_vectors(q, name, 4, " (scalar first)")
    n = np.linalg.norm(q, axis=-1)
    if np.any(n == 0.0):
        raise ValueError(f"{name}: zero quaternion")
    if unit and np.any(np.abs(n - 1.0) > tol):
        raise ValueError(f"{name}: not a unit quaternion (norm {n.flat[np.argmax(np.abs(n - 1.0))]:.6g})")
    return q


def quaternion_conjugate(q):
    """Hamilton conjugate ``q* = [q0, -q^T]^T`` (Eq. 128)."""
    q = np.asarray(q, dtype=float)
    return np.concatenate([q[..., :1], -q[..., 1:]], axis=-1)


def quaternion_product(a, b):
    """Hamilton product ``a o b = [a0 b0 - a.b, a0 b + b0 a + a x b]`` (Eq. 130), shape ``(..., 4)``."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    a0, av = a[..., :1], a[..., 1:]
    b0, bv = b[..., :1], b[..., 1:]
    s = a0 * b0 - np.sum(av * bv, axis=-1, keepdims=True)
    v = a0 * bv + b0 * av + np.cross(av, bv)
    return np.concatenate([s, v], axis=-1)


def quaternion_norm2(q):
    """``N(q) = q^T q`` (Eq. 131), the squared norm, shape ``(...)``."""
    q = np.asarray(q, dtype=float)
    return np.sum(q * q, axis=-1)


def quaternion_inverse(q):
    """``q^-1 = q* / N(q)`` (Eq. 132); equals ``q*`` for unit quaternions."""
    q = check_quaternion(q)
    return quaternion_conjugate(q) / quaternion_norm2(q)[..., None]


def left_matrix(a):
    """``L(a) (..., 4, 4)`` with ``a o b = L(a) b`` (matrix form of Eq. 130, left factor)."""
    a = np.asarray(a, dtype=float)
    a0, a1, a2, a3 = np.moveaxis(a, -1, 0)
    return np.stack(
        [
            np.stack([a0, -a1, -a2, -a3], -1),
            np.stack([a1, a0, -a3, a2], -1),
            np.stack([a2, a3, a0, -a1], -1),
            np.stack([a3, -a2, a1, a0], -1),
        ],
        -2,
    )


def right_matrix(b):
    """``R(b) (..., 4, 4)`` with ``a o b = R(b) a`` (matrix form of Eq. 130, right factor)."""
    b = np.asarray(b, dtype=float)
    b0, b1, b2, b3 = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            np.stack([b0, -b1, -b2, -b3], -1),
            np.stack([b1, b0, b3, -b2], -1),
            np.stack([b2, -b3, b0, b1], -1),
            np.stack([b3, b2, -b1, b0], -1),
        ],
        -2,
    )


def pure_quaternion(v):
    """The pure quaternion ``[0, v^T]^T`` of vectors ``v (..., 3)``."""
    v = np.asarray(v, dtype=float)
    return np.concatenate([np.zeros(v.shape[:-1] + (1,)), v], axis=-1)


def rotate_vector(q, v):
    """``q o v o q*`` (Eq. 135) for unit ``q (..., 4)`` and ``v (..., 3)``; returns the vector part ``(..., 3)``."""
    return quaternion_product(quaternion_product(q, pure_quaternion(v)), quaternion_conjugate(q))[..., 1:]


def quaternion_from_axis_angle(k, theta):
    """``q = [cos(theta / 2), sin(theta / 2) k]`` (Eq. 133) for unit axes ``k (..., 3)`` and angles (rad)."""
    k = np.asarray(k, dtype=float)
    k = k / np.linalg.norm(k, axis=-1, keepdims=True)
    half = 0.5 * np.asarray(theta, dtype=float)[..., None]
    return np.concatenate([np.cos(half), np.sin(half) * k], axis=-1)


def quaternion_to_matrix(q):
    """Rotation matrix of Eq. 136 for quaternions ``q (..., 4)`` (normalised first), shape ``(..., 3, 3)``."""
    q = check_quaternion(q)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    q0, q1, q2, q3 = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3, 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2)], -1),
            np.stack([2 * (q1 * q2 + q0 * q3), q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3, 2 * (q2 * q3 - q0 * q1)], -1),
            np.stack([2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3], -1),
        ],
        -2,
    )


def matrix_to_quaternion(R):
    """Unit quaternion ``(..., 4)`` with ``q0 >= 0`` of rotation matrices ``R (..., 3, 3)`` (inverse of Eq. 136).

    Shepperd's method: the largest of ``4 q0^2, 4 q1^2, 4 q2^2, 4 q3^2`` (the diagonal of the symmetric 4x4
    matrix built from ``R``) is taken as the pivot, so the division is never by a small number - accurate for every
    angle including ``pi``.
    """
    R = np.asarray(R, dtype=float)
    if R.shape[-2:] != (3, 3):
        raise ValueError(f"R: expected shape (..., 3, 3), got {R.shape}")
    if not np.all(np.isfinite(R)):
        raise ValueError("R: contains NaN or inf")
    r = R.reshape((-1, 3, 3))
    tr = np.trace(r, axis1=-2, axis2=-1)
    d = np.stack([tr, r[:, 0, 0], r[:, 1, 1], r[:, 2, 2]], -1)
    pivot = np.argmax(d, axis=-1)
    q = np.empty((r.shape[0], 4))
    for k in range(4):
        m = pivot == k
        if not np.any(m):
            continue
        s = r[m]
        if k == 0:
            w = np.sqrt(np.maximum(1.0 + tr[m], 0.0)) * 2.0  # 4 q0
            q[m] = np.stack([0.25 * w, (s[:, 2, 1] - s[:, 1, 2]) / w, (s[:, 0, 2] - s[:, 2, 0]) / w,
                             (s[:, 1, 0] - s[:, 0, 1]) / w], -1)
        else:
            i, j, l = (k - 1), k % 3, (k + 1) % 3
            w = np.sqrt(np.maximum(1.0 + s[:, i, i] - s[:, j, j] - s[:, l, l], 0.0)) * 2.0  # 4 q_k
            qq = np.empty((s.shape[0], 4))
            qq[:, 0] = (s[:, l, j] - s[:, j, l]) / w
            qq[:, 1 + i] = 0.25 * w
            qq[:, 1 + j] = (s[:, j, i] + s[:, i, j]) / w
            qq[:, 1 + l] = (s[:, l, i] + s[:, i, l]) / w
            q[m] = qq
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    q *= np.where(q[:, :1] < 0.0, -1.0, 1.0)
    return q.reshape(R.shape[:-2] + (4,))


def quaternion_to_rotation_vector(q):
    """Rotation vector ``theta k`` (rad, ``theta`` in [0, pi]) of quaternions ``q (..., 4)``; exact near 0 and pi."""
    q = check_quaternion(q)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    q = q * np.where(q[..., :1] < 0.0, -1.0, 1.0)
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1)
    theta = 2.0 * np.arctan2(s, q[..., 0])
    # theta / sin(theta / 2), with its series 2 + theta^2 / 12 near 0
    small = s < 1e-8
    scale = np.where(small, 2.0 + theta**2 / 12.0, theta / np.where(small, 1.0, s))
    return scale[..., None] * v


def rotation_vector_to_quaternion(phi):
    """Unit quaternion of rotation vectors ``phi (..., 3)`` (rad); exact near 0."""
    phi = np.asarray(phi, dtype=float)
    theta = np.linalg.norm(phi, axis=-1)
    small = theta < 1e-8
    # sin(theta / 2) / theta with its series 1/2 - theta^2 / 48 near 0
    scale = np.where(small, 0.5 - theta**2 / 48.0, np.sin(0.5 * theta) / np.where(small, 1.0, theta))
    return np.concatenate([np.cos(0.5 * theta)[..., None], scale[..., None] * phi], axis=-1)


def rotation_vector_to_matrix(phi):
    """``exp([phi]x)``, shape ``(..., 3, 3)``, via the quaternion (Eq. 136)."""
    return quaternion_to_matrix(rotation_vector_to_quaternion(phi))


def axis_angle_to_matrix(axis, angle):
    """Rotations by ``angle`` (rad, any shape) about one fixed ``axis`` (3,; normalised here): ``(..., 3, 3)``.

    Rodrigues' formula ``I + sin(angle) [a]x + (1 - cos(angle)) [a]x^2``, the exponential map for a known unit axis
    (a revolute joint's motion): the same rotation as :func:`rotation_vector_to_matrix` of ``angle * axis`` to
    rounding, without a norm and a quaternion per angle (the forward kinematics call it 10^4-10^5 times a run).
    """
    a = np.asarray(axis, dtype=float)
    n = np.linalg.norm(a) if a.shape == (3,) else np.nan
    if not (np.isfinite(n) and n > 0):
        raise ValueError(f"axis: expected a non-zero finite 3-vector, got {axis!r}")
    K = skew(a / n)
    angle = np.asarray(angle, dtype=float)
    s, c = np.sin(angle)[..., None, None], np.cos(angle)[..., None, None]
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


def matrix_to_rotation_vector(R):
    """``log(R)`` as a rotation vector (rad, angle in [0, pi]) via Shepperd's quaternion; exact near 0 and pi."""
    return quaternion_to_rotation_vector(matrix_to_quaternion(R))


def rotation_vector_jacobian(phi):
    """Left Jacobian of the exponential map: how a change of the rotation vector turns the rotation.

    ``exp([phi + delta_phi]x) = exp([J delta_phi]x) exp([phi]x)`` to first order, hence
    ``d(exp([phi]x) v) / d phi = -[exp([phi]x) v]x J``. With ``theta = |phi|``,
    ``J = I + (1 - cos theta) / theta^2 [phi]x + (theta - sin theta) / theta^3 [phi]x^2``; the coefficients by their
    series below ``theta = 1e-2`` (no cancellation, exact at 0). Regular for ``theta < 2 pi``.

    Parameters
    ----------
    phi : array_like (..., 3)
        Rotation vectors ``theta k`` (rad).

    Returns
    -------
    J : ndarray (..., 3, 3)
        ``delta_phi_left = J delta_phi`` (rad per rad), as :func:`rodrigues_jacobian` for Rodrigues parameters.
    """
    phi = np.asarray(phi, dtype=float)
    th = np.linalg.norm(phi, axis=-1)
    small = th < 1e-2
    t = np.where(small, 1.0, th)
    t2 = th * th
    # (1 - cos t) / t^2 = 2 sin^2(t / 2) / t^2 and (t - sin t) / t^3, with their series to t^6 (truncation < 1e-22)
    a = np.where(small, 0.5 - t2 / 24.0 * (1.0 - t2 / 30.0 * (1.0 - t2 / 56.0)), 2.0 * (np.sin(0.5 * t) / t) ** 2)
    b = np.where(small, 1.0 / 6.0 - t2 / 120.0 * (1.0 - t2 / 42.0 * (1.0 - t2 / 72.0)), (t - np.sin(t)) / t**3)
    K = skew(phi)
    return np.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K)


def rodrigues_to_quaternion(x):
    """Unit quaternion of Rodrigues parameters ``x = tan(theta / 2) k`` (Eq. 145): ``[1, x] / sqrt(1 + |x|^2)``.

    Equivalent to Eq. 155-156 and 133 (``k = x / |x|``, ``theta = 2 atan(|x|)``) without dividing by ``|x|``.
    """
    x = np.asarray(x, dtype=float)
    if not np.all(np.isfinite(x)):
        raise ValueError("x: Rodrigues parameters contain NaN or inf")
    q = np.concatenate([np.ones(x.shape[:-1] + (1,)), x], axis=-1)
    return q / np.sqrt(1.0 + np.sum(x * x, axis=-1, keepdims=True))


def quaternion_to_rodrigues(q):
    """Rodrigues parameters ``x = q_vec / q0 = tan(theta / 2) k`` (Eq. 145); ``ValueError`` at ``theta = pi``."""
    q = check_quaternion(q)
    if np.any(q[..., 0] == 0.0):
        raise ValueError("q: rotation angle is pi, the Rodrigues parameters are infinite")
    return q[..., 1:] / q[..., :1]


def rodrigues_to_matrix(x):
    """Cayley form ``R = (I - [x]x)^-1 (I + [x]x) = ((1 - |x|^2) I + 2 x x^T + 2 [x]x) / (1 + |x|^2)``."""
    x = np.asarray(x, dtype=float)
    n2 = np.sum(x * x, axis=-1)[..., None, None]
    return ((1.0 - n2) * np.eye(3) + 2.0 * x[..., :, None] * x[..., None, :] + 2.0 * skew(x)) / (1.0 + n2)


def matrix_to_rodrigues(R):
    """Rodrigues parameters of ``R (..., 3, 3)``; ``ValueError`` at ``theta = pi``."""
    return quaternion_to_rodrigues(matrix_to_quaternion(R))


def rodrigues_jacobian(x):
    """``J (..., 3, 3)`` with ``delta_phi = J delta_x``: a change ``delta_x`` of the Rodrigues parameters rotates
    ``R(x)`` by the small rotation vector ``delta_phi`` applied on the left, ``R(x + delta_x) = exp([delta_phi]x) R(x)``
    to first order. ``J = 2 (I + [x]x) / (1 + |x|^2)`` (from ``omega = 2 vec(q_dot o q*)`` with
    ``q = [1, x] / sqrt(1 + |x|^2)``).
    """
    x = np.asarray(x, dtype=float)
    n2 = np.sum(x * x, axis=-1)[..., None, None]
    return 2.0 * (np.eye(3) + skew(x)) / (1.0 + n2)


def random_quaternion(rng: np.random.Generator, size=()):
    """Uniformly distributed unit quaternions with ``q0 >= 0``, shape ``size + (4,)``."""
    shape = tuple(np.atleast_1d(size)) if size != () else ()
    q = rng.normal(size=shape + (4,))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return q * np.where(q[..., :1] < 0.0, -1.0, 1.0)
