"""A view's keypoint error field: the smooth displacement over the image that moves a whole view's keypoints together
(docs/bounds.md, "The field to cubic order, in each view's own modes").

Pure numpy, shared by the bound (:mod:`bench.scenario.bounds` measures and draws the field against the truth) and the
localisation (:mod:`bench.vision.field_covariance` measures it on the joint bundle's residuals). A field of order
``p`` is, per image axis, a polynomial in the monomials ``x^i y^j`` (``i + j <= p``) of the centred pixel
coordinates; over a view's keypoints it is written in that view's orthonormal modes (``X = Q R``), each degree's
modes with one standard deviation.
"""

from __future__ import annotations

import numpy as np

#: Pixels per unit of the field's image coordinates (the monomials' scale).
FIELD_UNIT_PX = 100.0
#: The names of the field's degrees (the metrics ``keypoint_field_<name>_px``): offset, slope, then the quadratic and
#: cubic modes.
FIELD_DEGREES = ("offset", "slope", "quadratic", "cubic")


def field_terms(order: int) -> int:
    """The number of monomials ``x^i y^j``, ``i + j <= order``, of a field of that order (1: 3, 2: 6, 3: 10)."""
    if not 0 <= int(order) < len(FIELD_DEGREES) or int(order) != order:
        raise ValueError(f"field order: expected an integer 0..{len(FIELD_DEGREES) - 1}, got {order}")
    return (int(order) + 1) * (int(order) + 2) // 2


def field_order(n_coefficients: int) -> int:
    """The order of a field of ``n_coefficients`` (both axes': 6, 12, 20 for orders 1, 2, 3)."""
    for order in range(len(FIELD_DEGREES)):
        if 2 * field_terms(order) == n_coefficients:
            return order
    raise ValueError(f"a field's coefficients: expected 2, 6, 12 or 20 (orders 0-3, both axes), got {n_coefficients}")


def field_degrees(order: int) -> np.ndarray:
    """Each basis term's degree (:func:`field_terms` (order),): ``[0, 1, 1, 2, 2, 2, 3, ...]``."""
    return np.concatenate([np.full(d + 1, d) for d in range(order + 1)])


def field_basis(uv, size, order: int = 1) -> np.ndarray:
    """The field's basis (..., :func:`field_terms` (order)) at pixels ``uv (..., 2)`` in an image of ``size (w, h)``:
    the monomials of ``x = (u - w/2) / 100``, ``y = (v - h/2) / 100`` (:data:`FIELD_UNIT_PX`) by degree, each
    degree from ``x^d`` to ``y^d``: ``[1, x, y, x^2, x y, y^2, x^3, x^2 y, x y^2, y^3]`` to order 3."""
    field_terms(order)  # the order checked
    xy = (np.asarray(uv, float) - 0.5 * np.asarray(size, float)) / FIELD_UNIT_PX
    x, y = xy[..., 0], xy[..., 1]
    terms = [x ** (d - j) * y ** j for d in range(int(order) + 1) for j in range(d + 1)]
    return np.stack(terms, axis=-1)


def field_displacement(uv, coefficients, size) -> np.ndarray:
    """The displacement (..., 2) px of a view's error field ``coefficients (..., 2 n)`` at pixels ``uv (..., 2)``:
    ``du`` the first ``n`` coefficients against :func:`field_basis`, ``dv`` the last ``n``; the field's order from
    ``2 n`` (:func:`field_order`; 6 coefficients ``(a0, a1, a2, b0, b1, b2)``: affine)."""
    c = np.asarray(coefficients, float)
    n = c.shape[-1] // 2
    X = field_basis(uv, size, field_order(c.shape[-1]))
    return np.stack([np.sum(X * c[..., :n], axis=-1), np.sum(X * c[..., n:], axis=-1)], axis=-1)


def field_modes(uv, size, order: int) -> np.ndarray:
    """The view's field modes at its keypoints ``uv (N, 2)``: the upper-triangular ``R`` (n, n) with ``X = Q R``,
    ``X`` the monomials (:func:`field_basis`) at the keypoints and ``Q`` orthonormal in mean square over them
    (``Q^T Q / N = I``: Gram-Schmidt of the monomials in degree order, ``R^T R = X^T X / N``). A field's mode
    amplitudes are ``a = R c`` (px: each mode's RMS displacement over the keypoints) for monomial coefficients ``c``.
    Raises ``ValueError`` when the keypoints do not resolve the modes (fewer than n, or on a curve of that order)."""
    return monomial_modes(field_basis(np.asarray(uv, float).reshape(-1, 2), size, order), order)


def monomial_modes(X, order: int) -> np.ndarray:
    """:func:`field_modes` of the monomials ``X (N, n)`` (:func:`field_basis`) at the keypoints."""
    n = X.shape[1]
    if len(X) < n:
        raise ValueError(f"field modes: {len(X)} keypoints cannot resolve the {n} modes of order {order}")
    try:
        return np.linalg.cholesky(X.T @ X / len(X)).T
    except np.linalg.LinAlgError:
        raise ValueError(f"field modes: the {len(X)} keypoints lie on a curve of order {order}") from None


def mode_sd(degree_px) -> np.ndarray:
    """Each mode's standard deviation (:func:`field_terms` (order),) from each degree's ``degree_px`` (order + 1,;
    measured by :func:`bench.scenario.bounds.measure_field` or :func:`bench.vision.field_covariance.field_covariance`):
    the modes of one degree alike."""
    d = np.asarray(degree_px, float)
    return d[field_degrees(len(d) - 1)]
