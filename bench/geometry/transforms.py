"""Homogeneous transforms (thesis Eq. 1-5), batched over leading axes.

Names carry frames: ``T_a_b`` maps coordinates in frame ``b`` to frame ``a`` (``p_a = T_a_b @ p_b``).
All angles in radians, lengths in metres.
"""

from __future__ import annotations

import numpy as np


def rot_x(angle):
    """Rotation about x (Eq. 3), shape ``angle.shape + (3, 3)``."""
    c, s = np.cos(angle), np.sin(angle)
    if np.ndim(c) == 0:  # one angle: a literal (the stacks below cost ~10x more; error matrices build many)
        c, s = float(c), float(s)
        return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def rot_y(angle):
    """Rotation about y (Eq. 4), shape ``angle.shape + (3, 3)``."""
    c, s = np.cos(angle), np.sin(angle)
    if np.ndim(c) == 0:  # one angle: a literal (the stacks below cost ~10x more; error matrices build many)
        c, s = float(c), float(s)
        return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def rot_z(angle):
    """Rotation about z (Eq. 5), shape ``angle.shape + (3, 3)``."""
    c, s = np.cos(angle), np.sin(angle)
    if np.ndim(c) == 0:  # one angle: a literal (the stacks below cost ~10x more; error matrices build many)
        c, s = float(c), float(s)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def homogeneous(R, t):
    """Stack ``R (..., 3, 3)`` and ``t (..., 3)`` into ``T (..., 4, 4)`` (Eq. 1)."""
    R = np.asarray(R, dtype=float)
    t = np.asarray(t, dtype=float)
    shape = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = np.zeros(shape + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def invert(T):
    """Inverse of rigid transforms ``T (..., 4, 4)``."""
    R = np.swapaxes(T[..., :3, :3], -1, -2)
    return homogeneous(R, -np.einsum("...ij,...j->...i", R, T[..., :3, 3]))


def transform_points(T_a_b, p_b):
    """``p_a = T_a_b p_b`` for points ``p_b (..., 3)``; broadcasts over leading axes."""
    return np.einsum("...ij,...j->...i", T_a_b[..., :3, :3], p_b) + T_a_b[..., :3, 3]


def skew(v):
    """Cross-product matrix ``[v]x`` of ``v (..., 3)``."""
    v = np.asarray(v, dtype=float)
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], -2)


def vee(S):
    """Inverse of :func:`skew` for the skew-symmetric part of ``S (..., 3, 3)``."""
    return 0.5 * np.stack([S[..., 2, 1] - S[..., 1, 2], S[..., 0, 2] - S[..., 2, 0], S[..., 1, 0] - S[..., 0, 1]], -1)


def rotation_angle(R):
    """Angle (rad) of rotations ``R (..., 3, 3)``, robust near 0 and pi."""
    c = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    s = np.linalg.norm(vee(R), axis=-1)
    return np.arctan2(s, c)


def check_vectors(v, name: str, dim: int, note: str = "") -> np.ndarray:
    """``v`` as a float array of shape ``(..., dim)`` with finite entries; otherwise a one-line ``ValueError`` naming
    ``name`` (``note`` follows the expected shape in the message)."""
    try:
        v = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a numeric (..., {dim}) array") from None
    if v.shape[-1:] != (dim,):
        raise ValueError(f"{name}: expected shape (..., {dim}){note}, got {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{name}: contains NaN or inf")
    return v


def check_transform(T, name="T", tol=1e-6):
    """Raise ``ValueError`` naming ``name`` unless ``T`` is a finite rigid transform (..., 4, 4)."""
    T = np.asarray(T, dtype=float)
    if T.shape[-2:] != (4, 4):
        raise ValueError(f"{name}: expected shape (..., 4, 4), got {T.shape}")
    if not np.all(np.isfinite(T)):
        raise ValueError(f"{name}: contains NaN or inf")
    R = T[..., :3, :3]
    err = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max(initial=0.0)
    if err > tol or np.any(np.abs(np.linalg.det(R) - 1.0) > tol):
        raise ValueError(f"{name}: rotation part is not orthonormal (error {err:.2e})")
    if np.any(np.abs(T[..., 3, :] - [0, 0, 0, 1]) > tol):
        raise ValueError(f"{name}: last row is not [0, 0, 0, 1]")
    return T


def random_rotation(rng: np.random.Generator, size=()):
    """Uniformly distributed rotations, shape ``size + (3, 3)`` (from random unit quaternions)."""
    q = rng.normal(size=tuple(np.atleast_1d(size)) + (4,) if size != () else (4,))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    R = np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )
    return R


def random_transform(rng: np.random.Generator, size=(), scale=1.0):
    """Random rigid transforms with uniformly random rotation and normal translation of std ``scale`` (m)."""
    R = random_rotation(rng, size)
    t = rng.normal(scale=scale, size=R.shape[:-2] + (3,))
    return homogeneous(R, t)
