"""Thesis Appendix A (TA-40 kinematics), transcribed as printed, for ``test_appendix_a.py``.

Source: the thesis in ``../shared/seed/000_3fc37a772f2f4fe4.txt`` from the line " Appendix A" (about line 2313):
(a) the closed-form end-effector position X, Y, Z, (b) the 3x6 joint-space Jacobian J(1..3, 1..6) and (c) the 3x42
Identification Jacobian J(r.c). The text is an OCR/LaTeX transcription of the thesis.

Every expression is copied term by term in the printed order, ``·`` becoming ``*`` (``c_1`` -> ``c1``, ``a_3`` ->
``a3``), with the printed line breaks kept, so each line here can be compared with the thesis line by line. Misprints
are NOT corrected in place: the printed expressions are what the tests check. Where the printed parentheses are odd
a comment says how they were read. The corrected versions of the entries that disagree with the derivative are in
:func:`corrections` at the end, apart from the transcription.

Conventions
-----------
* Inputs: ``c = (c1, ..., c6)``, ``s = (s1, ..., s6)``, cosines and sines of the joint angles theta_1..6 (any
  broadcastable array shapes), and the DH lengths ``a1, a2, a3, d4, d6`` (the appendix prints them in mm,
  :data:`THESIS_LENGTHS_MM`; any length unit works, the results are in that unit, or per radian).
* Entry names used by the tests: ``"X"``, ``"Y"``, ``"Z"``; ``"J(r,c)"`` for the joint Jacobian; ``"Je(r.c)"`` for
  the Identification Jacobian (1-based row and column as printed).
* Identification Jacobian columns are frame-major, ``x, y, z, s, r, p`` per frame 0..6 (translations along x, y, z,
  rotations about y, z, x), the same order as ``bench.robot.jacobian.identification_jacobian``.
"""

from __future__ import annotations

import numpy as np

#: The constants printed under the abbreviations (mm): ``a1=115; a2=753; a3=188; d4=747; d6=360;``
THESIS_LENGTHS_MM = {"a1": 115.0, "a2": 753.0, "a3": 188.0, "d4": 747.0, "d6": 360.0}


def cos_sin(theta):
    """``(c1..c6), (s1..s6)`` of joint angles ``theta (..., 6)`` in rad, the appendix's abbreviations."""
    theta = np.asarray(theta, dtype=float)
    return tuple(np.cos(theta[..., i]) for i in range(6)), tuple(np.sin(theta[..., i]) for i in range(6))


def _assemble(J, n_rows, n_cols, c, s):
    """Dense ``(..., n_rows, n_cols)`` array from the 1-based entries ``J[r, col]`` (scalars broadcast)."""
    if sorted(J) != [(r, k) for r in range(1, n_rows + 1) for k in range(1, n_cols + 1)]:
        raise AssertionError("transcription incomplete or duplicated")
    out = np.zeros(np.broadcast(*c, *s).shape + (n_rows, n_cols))
    for (r, k), v in J.items():
        out[..., r - 1, k - 1] = v
    return out


def position(c, s, a1, a2, a3, d4, d6):
    """End-Effector Position (X, Y, Z) as printed, shape (..., 3)."""
    c1, c2, c3, c4, c5, c6 = c
    s1, s2, s3, s4, s5, s6 = s
    # X: the parentheses are balanced as printed, "d_6 \cdot ((c1c2c3 - c1s2s3) \cdot c4 + s1s4) \cdot s5 +
    # (c1c2s3 + c1s2c3) \cdot c5 + ...", so d6 multiplies the s5 term only and the c5 term carries no length. Read
    # literally (one '(' after "d_6 \cdot" is missing compared with Y and Z; see KNOWN_MISPRINTS and corrections()).
    X = (d6 * ((c1 * c2 * c3 - c1 * s2 * s3) * c4 + s1 * s4) * s5 + (c1 * c2 * s3 + c1 * s2 * c3) * c5
         + d4 * (c1 * c2 * s3 + c1 * s2 * c3) + a3 * (c1 * c2 * c3 - c1 * s2 * s3) + a2 * c1 * c2 + a1 * c1)
    # Y: the second line is printed at the top of the next equation block (the one that holds Z); it starts with '+'
    # and Z starts with "Z &=", so it is read as the continuation of Y.
    Y = (d6 * (((s1 * c2 * c3 - s1 * s2 * s3) * c4 - c1 * s4) * s5 + (s1 * c2 * s3 + s1 * s2 * c3) * c5)
         + (s1 * c2 * s3 + s1 * s2 * c3) * d4 + s1 * c2 * a3 * c3 - s1 * s2 * a3 * s3 + s1 * a2 * c2 + a1 * s1)
    Z = (d6 * ((s2 * c3 + c2 * s3) * c4 * s5 + (s2 * s3 - c2 * c3) * c5)
         + d4 * (s2 * s3 - c2 * c3) + a3 * (s2 * c3 + c2 * s3) + a2 * s2)
    return np.stack(np.broadcast_arrays(X, Y, Z), axis=-1)


def joint_jacobian(c, s, a1, a2, a3, d4, d6):
    """Jacobian matrix J(1..3, 1..6) = d(X, Y, Z)/d(theta_1..6) as printed, shape (..., 3, 6)."""
    c1, c2, c3, c4, c5, c6 = c
    s1, s2, s3, s4, s5, s6 = s
    J = {}
    J[1, 1] = (
        (((-s1 * c2 * c3 + s1 * s2 * s3) * c4 + c1 * s4) * s5 - (s1 * c2 * s3 + s1 * s2 * c3) * c5) * d6
        + (-s1 * c2 * s3 - s1 * s2 * c3) * d4 - s1 * c2 * a3 * c3 + s1 * s2 * a3 * s3 - s1 * a2 * c2 - a1 * s1
    )
    # Printed with one '(' too many: the leading '(((' opens three groups and only two are closed. Wherever the
    # missing ')' is put (after '* d6' or at the end of the entry) the value is the same; closed after '* d6'.
    J[1, 2] = (
        (((-c1 * c2 * s3 - c1 * s2 * c3) * c4 * s5 - (c1 * s2 * s3 - c1 * c2 * c3) * c5) * d6)  # <- ')' added
        + (c1 * c2 * c3 - c1 * s2 * s3) * d4 - c1 * s2 * a3 * c3 - c1 * c2 * a3 * s3 - c1 * a2 * s2
    )
    # Printed with one '(' too many: the leading '(((' opens three groups and only two are closed. Wherever the
    # missing ')' is put (after '* d6' or at the end of the entry) the value is the same; closed after '* d6'.
    J[1, 3] = (
        (((-c1 * c2 * s3 - c1 * s2 * c3) * c4 * s5 - (c1 * s2 * s3 - c1 * c2 * c3) * c5) * d6)  # <- ')' added
        + (c1 * c2 * c3 - c1 * s2 * s3) * d4 - c1 * c2 * a3 * s3 - c1 * s2 * a3 * c3
    )
    # '(- (' is a unary minus in front of the group, as printed.
    J[1, 4] = (- (c1 * c2 * c3 - c1 * s2 * s3) * s4 + s1 * c4) * s5 * d6
    J[1, 5] = (((c1 * c2 * c3 - c1 * s2 * s3) * c4 + s1 * s4) * c5 + (-c1 * c2 * s3 - c1 * s2 * c3) * s5) * d6
    J[1, 6] = 0
    J[2, 1] = (
        (((c1 * c2 * c3 - c1 * s2 * s3) * c4 + s1 * s4) * s5 - (-c1 * c2 * s3 - c1 * s2 * c3) * c5) * d6
        + (c1 * c2 * s3 + c1 * s2 * c3) * d4 + c1 * c2 * a3 * c3 - c1 * s2 * a3 * s3 + c1 * a2 * c2 + a1 * c1
    )
    # Printed with one '(' too many: the leading '(((' opens three groups and only two are closed. Wherever the
    # missing ')' is put (after '* d6' or at the end of the entry) the value is the same; closed after '* d6'.
    J[2, 2] = (
        (((-s1 * c2 * s3 - s1 * s2 * c3) * c4 * s5 - (-s1 * c2 * c3 + s1 * s2 * s3) * c5) * d6)  # <- ')' added
        + (s1 * c2 * c3 - s1 * s2 * s3) * d4 - s1 * s2 * a3 * c3 - s1 * c2 * a3 * s3 - s1 * a2 * s2
    )
    # Printed with one '(' too many: the leading '(((' opens three groups and only two are closed. Wherever the
    # missing ')' is put (after '* d6' or at the end of the entry) the value is the same; closed after '* d6'.
    J[2, 3] = (
        (((-s1 * c2 * s3 - s1 * s2 * c3) * c4 * s5 - (-s1 * c2 * c3 + s1 * s2 * s3) * c5) * d6)  # <- ')' added
        + (s1 * c2 * c3 - s1 * s2 * s3) * d4 - s1 * c2 * a3 * s3 - s1 * s2 * a3 * c3
    )
    J[2, 4] = (- (s1 * c2 * c3 - s1 * s2 * s3) * s4 - c1 * c4) * s5 * d6
    J[2, 5] = (((s1 * c2 * c3 - s1 * s2 * s3) * c4 - c1 * s4) * c5 + (-s1 * c2 * s3 - s1 * s2 * c3) * s5) * d6
    J[2, 6] = 0
    J[3, 1] = 0
    J[3, 2] = (
        ((-s2 * s3 + c2 * c3) * c4 * s5 - (-c2 * s3 - s2 * c3) * c5) * d6
        + (s2 * c3 + c2 * s3) * d4 + c2 * a3 * c3 - s2 * a3 * s3 + a2 * c2
    )
    J[3, 3] = (
        ((-s2 * s3 + c2 * c3) * c4 * s5 - (-c2 * s3 - s2 * c3) * c5) * d6
        + (s2 * c3 + c2 * s3) * d4 - s2 * a3 * s3 + c2 * a3 * c3
    )
    J[3, 4] = -(s2 * c3 + c2 * s3) * s4 * s5 * d6
    J[3, 5] = ((s2 * c3 + c2 * s3) * c4 * c5 + (-s2 * s3 + c2 * c3) * s5) * d6
    J[3, 6] = 0
    return _assemble(J, 3, 6, c, s)


def identification_jacobian(c, s, a1, a2, a3, d4, d6):
    """Identification Jacobian Matrix J(1..3 . 1..42) as printed, shape (..., 3, 42)."""
    c1, c2, c3, c4, c5, c6 = c
    s1, s2, s3, s4, s5, s6 = s
    J = {}
    # Columns 1-3 are printed with a comma, J(r,c), the others with a dot, J(r.c); same matrix.
    J[1, 1] = 1
    J[2, 1] = 0
    J[3, 1] = 0
    J[1, 2] = 0
    J[2, 2] = 1
    J[3, 2] = 0
    J[1, 3] = 0
    J[2, 3] = 0
    J[3, 3] = 1
    J[1, 4] = (
        s2 * a3 * c3 + a2 * s2 + c2 * a3 * s3 + (s2 * s3 - c2 * c3) * d4
        + ((s2 * c3 + c2 * s3) * c4 * s5 - (-s2 * s3 + c2 * c3) * c5) * d6
    )
    J[2, 4] = 0
    J[3, 4] = (
        c1 * s2 * a3 * s3 - a1 * c1 - c1 * a2 * c2 - c1 * c2 * a3 * c3 + (-c1 * c2 * s3 - c1 * s2 * c3) * d4
        + (((-c1 * c2 * c3 + c1 * s2 * s3) * c4 - s1 * s4) * s5 - (c1 * c2 * s3 + c1 * s2 * c3) * c5) * d6
    )
    J[1, 5] = (
        -s1 * c2 * a3 * c3 + s1 * s2 * a3 * s3 - a1 * s1 - s1 * a2 * c2 + (-s1 * c2 * s3 - s1 * s2 * c3) * d4
        + (((-s1 * c2 * c3 + s1 * s2 * s3) * c4 + c1 * s4) * s5 - (s1 * c2 * s3 + s1 * s2 * c3) * c5) * d6
    )
    J[2, 5] = (
        c1 * c2 * a3 * c3 - c1 * s2 * a3 * s3 + a1 * c1 + c1 * a2 * c2 + (c1 * c2 * s3 + c1 * s2 * c3) * d4
        + (((c1 * c2 * c3 - c1 * s2 * s3) * c4 + s1 * s4) * s5 + (c1 * c2 * s3 + c1 * s2 * c3) * c5) * d6
    )
    J[3, 5] = 0
    J[1, 6] = 0
    J[2, 6] = (
        -a2 * s2 - s2 * a3 * c3 - c2 * a3 * s3 + (-s2 * s3 + c2 * c3) * d4
        + ((-s2 * c3 - c2 * s3) * c4 * s5 - (s2 * s3 - c2 * c3) * c5) * d6
    )
    J[3, 6] = (
        a1 * s1 - s1 * s2 * a3 * s3 + s1 * a2 * c2 + s1 * c2 * a3 * c3 + (s1 * c2 * s3 + s1 * s2 * c3) * d4
        + (((s1 * c2 * c3 - s1 * s2 * s3) * c4 - c1 * s4) * s5 + (s1 * c2 * s3 + s1 * s2 * c3) * c5) * d6
    )
    J[1, 7] = c1
    J[2, 7] = s1
    J[3, 7] = 0
    J[1, 8] = 0
    J[2, 8] = 0
    J[3, 8] = 1
    J[1, 9] = s1
    J[2, 9] = -c1
    J[3, 9] = 0
    J[1, 10] = (
        -s1 * c2 * a3 * c3 + s1 * s2 * a3 * s3 - s1 * a2 * c2 - (s1 * c2 * s3 + s1 * s2 * c3) * d4
        + (((-s1 * c2 * c3 + s1 * s2 * s3) * c4 + c1 * s4) * s5 - (s1 * c2 * s3 + s1 * s2 * c3) * c5) * d6
    )
    J[2, 10] = (
        c1 * c2 * a3 * c3 - c1 * s2 * a3 * s3 + c1 * a2 * c2 + (c1 * c2 * s3 + c1 * s2 * c3) * d4
        + (((c1 * c2 * c3 - c1 * s2 * s3) * c4 + s1 * s4) * s5 + (c1 * c2 * s3 + c1 * s2 * c3) * c5) * d6
    )
    J[3, 10] = 0
    # Printed with one '(' too many: '+ (((' opens three groups and only two are closed. Wherever the missing ')'
    # is put (before or after '* d6') the value is the same; closed after '* d6', at the end of the entry.
    J[1, 11] = (
        -c1 * s2 * a3 * c3 - c1 * a2 * s2 - c1 * c2 * a3 * s3 + (-c1 * s2 * s3 + c1 * c2 * c3) * d4
        + (((-c1 * s2 * c3 - c1 * c2 * s3) * c4 * s5 - (c1 * s2 * s3 - c1 * c2 * c3) * c5) * d6)  # <- ')' added
    )
    # Printed with one '(' too many: '+ (((' opens three groups and only two are closed. Wherever the missing ')'
    # is put (before or after '* d6') the value is the same; closed after '* d6', at the end of the entry.
    J[2, 11] = (
        -s1 * a2 * s2 - s1 * s2 * a3 * c3 - s1 * c2 * a3 * s3 + (-s1 * s2 * s3 + s1 * c2 * c3) * d4
        + (((-s1 * s2 * c3 - s1 * c2 * s3) * c4 * s5 - (s1 * s2 * s3 - s1 * c2 * c3) * c5) * d6)  # <- ')' added
    )
    # The printed line break falls inside the d6 group; the parentheses are balanced (same for J(3.17), J(1.22),
    # J(2.22)).
    J[3, 11] = (
        -s2 * a3 * s3 + a2 * c2 + c2 * a3 * c3 + (c2 * s3 + s2 * c3) * d4 + ((c2 * c3 - s2 * s3) * c4 * s5
        + (c2 * s3 + s2 * c3) * c5) * d6
    )
    # Printed with one '(' too many: '+ (((' opens three groups and only two are closed. Wherever the missing ')'
    # is put (before or after '* d6') the value is the same; closed after '* d6', at the end of the entry.
    J[1, 12] = (
        s1 * s2 * a3 * c3 + s1 * a2 * s2 + s1 * c2 * a3 * s3 + (s1 * s2 * s3 - s1 * c2 * c3) * d4
        + (((s1 * s2 * c3 + s1 * c2 * s3) * c4 * s5 - (-s1 * s2 * s3 + s1 * c2 * c3) * c5) * d6)  # <- ')' added
    )
    # Printed with one '(' too many: '+ (((' opens three groups and only two are closed. Wherever the missing ')'
    # is put (before or after '* d6') the value is the same; closed after '* d6', at the end of the entry.
    J[2, 12] = (
        -c1 * a2 * s2 - c1 * s2 * a3 * c3 - c1 * c2 * a3 * s3 + (-c1 * s2 * s3 + c1 * c2 * c3) * d4
        + (((-c1 * s2 * c3 - c1 * c2 * s3) * c4 * s5 - (c1 * s2 * s3 - c1 * c2 * c3) * c5) * d6)  # <- ')' added
    )
    J[3, 12] = -s4 * s5 * d6
    J[1, 13] = c1 * c2
    J[2, 13] = s1 * c2
    J[3, 13] = s2
    J[1, 14] = -c1 * s2
    J[2, 14] = -s1 * s2
    J[3, 14] = c2
    J[1, 15] = s1
    J[2, 15] = -c1
    J[3, 15] = 0
    J[1, 16] = -s1 * a3 * c3 - s1 * s3 * d4 + ((-s1 * c3 * c4 + c1 * c2 * s4) * s5 - s1 * s3 * c5) * d6
    J[2, 16] = c1 * a3 * c3 + c1 * s3 * d4 + ((c1 * c3 * c4 + s1 * c2 * s4) * s5 + c1 * s3 * c5) * d6
    J[3, 16] = s2 * s4 * s5 * d6
    J[1, 17] = (
        -c1 * s2 * a3 * c3 - c1 * c2 * a3 * s3 + (-c1 * s2 * s3 + c1 * c2 * c3) * d4
        + ((-c1 * s2 * c3 - c1 * c2 * s3) * c4 * s5 - (c1 * s2 * s3 - c1 * c2 * c3) * c5) * d6
    )
    J[2, 17] = (
        -s1 * s2 * a3 * c3 - s1 * c2 * a3 * s3 + (-s1 * s2 * s3 + s1 * c2 * c3) * d4
        + ((-s1 * s2 * c3 - s1 * c2 * s3) * c4 * s5 - (s1 * s2 * s3 - s1 * c2 * c3) * c5) * d6
    )
    J[3, 17] = (
        -s2 * a3 * s3 + c2 * a3 * c3 + (c2 * s3 + s2 * c3) * d4 + ((c2 * c3 - s2 * s3) * c4 * s5
        + (c2 * s3 + s2 * c3) * c5) * d6
    )
    J[1, 18] = s1 * a3 * s3 - s1 * c3 * d4 + ((s1 * s3 * c4 + c1 * s2 * s4) * s5 - s1 * c3 * c5) * d6
    J[2, 18] = -c1 * a3 * s3 + c1 * c3 * d4 + ((-c1 * s3 * c4 + s1 * s2 * s4) * s5 + c1 * c3 * c5) * d6
    J[3, 18] = -c2 * s4 * s5 * d6
    J[1, 19] = c1 * c2 * c3 - c1 * s2 * s3
    J[2, 19] = s1 * c2 * c3 - s1 * s2 * s3
    J[3, 19] = s2 * c3 + c2 * s3
    J[1, 20] = s1
    J[2, 20] = -c1
    J[3, 20] = 0
    J[1, 21] = c1 * c2 * s3 + c1 * s2 * c3
    J[2, 21] = s1 * c2 * s3 + s1 * s2 * c3
    J[3, 21] = s2 * s3 - c2 * c3
    J[1, 22] = (
        (c1 * c2 * c3 - c1 * s2 * s3) * d4 + ((-c1 * c2 * s3 - c1 * s2 * c3) * c4 * s5
        + (c1 * c2 * c3 - c1 * s2 * s3) * c5) * d6
    )
    J[2, 22] = (
        (s1 * c2 * c3 - s1 * s2 * s3) * d4 + ((-s1 * c2 * s3 - s1 * s2 * c3) * c4 * s5
        + (s1 * c2 * c3 - s1 * s2 * s3) * c5) * d6
    )
    J[3, 22] = (s2 * c3 + c2 * s3) * d4 + ((-s2 * s3 + c2 * c3) * c4 * s5 + (s2 * c3 + c2 * s3) * c5) * d6
    J[1, 23] = (s1 * c4 + (-c1 * c2 * c3 + c1 * s2 * s3) * s4) * s5 * d6
    J[2, 23] = (-c1 * c4 + (-s1 * c2 * c3 + s1 * s2 * s3) * s4) * s5 * d6
    J[3, 23] = (-s2 * c3 - c2 * s3) * s4 * s5 * d6
    J[1, 24] = -s1 * d4 + ((c1 * c2 * s3 + c1 * s2 * c3) * s4 * s5 - s1 * c5) * d6
    J[2, 24] = c1 * d4 + ((s1 * c2 * s3 + s1 * s2 * c3) * s4 * s5 + c1 * c5) * d6
    J[3, 24] = (s2 * s3 - c2 * c3) * s4 * s5 * d6
    J[1, 25] = (c1 * c2 * c3 - c1 * s2 * s3) * c4 + s1 * s4
    J[2, 25] = (s1 * c2 * c3 - s1 * s2 * s3) * c4 - c1 * s4
    J[3, 25] = (s2 * c3 + c2 * s3) * c4
    J[1, 26] = -c1 * c2 * s3 - c1 * s2 * c3
    J[2, 26] = -s1 * c2 * s3 - s1 * s2 * c3
    J[3, 26] = -s2 * s3 + c2 * c3
    J[1, 27] = (-c1 * c2 * c3 + c1 * s2 * s3) * s4 + s1 * c4
    J[2, 27] = (-s1 * c2 * c3 + s1 * s2 * s3) * s4 - c1 * c4
    J[3, 27] = (-s2 * c3 - c2 * s3) * s4
    J[1, 28] = ((c1 * c2 * c3 - c1 * s2 * s3) * s4 - s1 * c4) * s5 * d6
    J[2, 28] = ((s1 * c2 * c3 - s1 * s2 * s3) * s4 + c1 * c4) * s5 * d6
    J[3, 28] = (s2 * c3 + c2 * s3) * s4 * s5 * d6
    # J(1.29) and J(2.29) (the r4 column, i.e. rotation about z4 = the joint-5 axis, so they should equal the
    # joint-Jacobian J(1,5), J(2,5) printed above) are transcribed exactly as printed; parentheses are balanced
    # and unambiguous. Compare J(3.29) on the next line, where c5 multiplies only the c4 term. See KNOWN_MISPRINTS.
    J[1, 29] = ((-c1 * c2 * s3 - c1 * s2 * c3) * s5 + (c1 * c2 * c3 - c1 * s2 * s3) * c4 - s1 * s4) * c5 * d6
    J[2, 29] = ((-s1 * c2 * s3 - s1 * s2 * c3) * s5 + (s1 * c2 * c3 - s1 * s2 * s3) * c4 + c1 * s4) * c5 * d6
    J[3, 29] = ((-s2 * s3 + c2 * c3) * s5 + (s2 * c3 + c2 * s3) * c4 * c5) * d6
    J[1, 30] = -((-c1 * c2 * c3 + c1 * s2 * s3) * s4 + s1 * c4) * c5 * d6
    J[2, 30] = -((-s1 * c2 * c3 + s1 * s2 * s3) * s4 - c1 * c4) * c5 * d6
    J[3, 30] = -(-s2 * c3 - c2 * s3) * s4 * c5 * d6
    J[1, 31] = ((c1 * c2 * c3 - c1 * s2 * s3) * c4 + s1 * s4) * c5 - (c1 * c2 * s3 + c1 * s2 * c3) * s5
    J[2, 31] = ((s1 * c2 * c3 - s1 * s2 * s3) * c4 - c1 * s4) * c5 - (s1 * c2 * s3 + s1 * s2 * c3) * s5
    J[3, 31] = (s2 * c3 + c2 * s3) * c4 * c5 + (-s2 * s3 + c2 * c3) * s5
    J[1, 32] = -(c1 * c2 * c3 - c1 * s2 * s3) * s4 + s1 * c4
    J[2, 32] = -(s1 * c2 * c3 - s1 * s2 * s3) * s4 - c1 * c4
    J[3, 32] = -(s2 * c3 + c2 * s3) * s4
    J[1, 33] = ((c1 * c2 * c3 - c1 * s2 * s3) * c4 + s1 * s4) * s5 + (c1 * c2 * s3 + c1 * s2 * c3) * c5
    J[2, 33] = ((s1 * c2 * c3 - s1 * s2 * s3) * c4 - c1 * s4) * s5 + (s1 * c2 * s3 + s1 * s2 * c3) * c5
    J[3, 33] = (s2 * c3 + c2 * s3) * c4 * s5 + (s2 * s3 - c2 * c3) * c5
    J[1, 34] = (((c1 * c2 * c3 - c1 * s2 * s3) * c4 + s1 * s4) * c5 - (c1 * c2 * s3 + c1 * s2 * c3) * s5) * d6
    J[2, 34] = (((s1 * c2 * c3 - s1 * s2 * s3) * c4 - c1 * s4) * c5 - (s1 * c2 * s3 + s1 * s2 * c3) * s5) * d6
    J[3, 34] = ((s2 * c3 + c2 * s3) * c4 * c5 + (c2 * c3 - s2 * s3) * s5) * d6
    J[1, 35] = 0
    J[2, 35] = 0
    J[3, 35] = 0
    J[1, 36] = ((c1 * c2 * c3 - c1 * s2 * s3) * s4 - s1 * c4) * d6
    J[2, 36] = ((s1 * c2 * c3 - s1 * s2 * s3) * s4 + c1 * c4) * d6
    J[3, 36] = (s2 * c3 + c2 * s3) * s4 * d6
    # '(- (' in the second line is a unary minus in front of the group, as printed (likewise J(2.37), J(1.38),
    # J(2.38), J(3.38)).
    J[1, 37] = (
        (((c1 * c2 * c3 - c1 * s2 * s3) * c4 + s1 * s4) * c5 - (c1 * c2 * s3 + c1 * s2 * c3) * s5) * c6
        + (- (c1 * c2 * c3 - c1 * s2 * s3) * s4 + s1 * c4) * s6
    )
    J[2, 37] = (
        (((s1 * c2 * c3 - s1 * s2 * s3) * c4 - c1 * s4) * c5 - (s1 * c2 * s3 + s1 * s2 * c3) * s5) * c6
        + (- (s1 * c2 * c3 - s1 * s2 * s3) * s4 - c1 * c4) * s6
    )
    J[3, 37] = ((s2 * c3 + c2 * s3) * c4 * c5 + (-s2 * s3 + c2 * c3) * s5) * c6 - (s2 * c3 + c2 * s3) * s4 * s6
    J[1, 38] = (
        (-((c1 * c2 * c3 - c1 * s2 * s3) * c4 + s1 * s4) * c5
        + (c1 * c2 * s3 + c1 * s2 * c3) * s5) * s6 + (- (c1 * c2 * c3 - c1 * s2 * s3) * s4 + s1 * c4) * c6
    )
    J[2, 38] = (
        (-((s1 * c2 * c3 - s1 * s2 * s3) * c4 - c1 * s4) * c5 + (s1 * c2 * s3 + s1 * s2 * c3) * s5) * s6
        + (- (s1 * c2 * c3 - s1 * s2 * s3) * s4 - c1 * c4) * c6
    )
    J[3, 38] = (- (s2 * c3 + c2 * s3) * c4 * c5 - (-s2 * s3 + c2 * c3) * s5) * s6 - (s2 * c3 + c2 * s3) * s4 * c6
    J[1, 39] = ((c1 * c2 * c3 - c1 * s2 * s3) * c4 + s1 * s4) * s5 + (c1 * c2 * s3 + c1 * s2 * c3) * c5
    J[2, 39] = ((s1 * c2 * c3 - s1 * s2 * s3) * c4 - c1 * s4) * s5 + (s1 * c2 * s3 + s1 * s2 * c3) * c5
    J[3, 39] = (s2 * c3 + c2 * s3) * c4 * s5 + (s2 * s3 - c2 * c3) * c5
    J[1, 40] = 0
    J[2, 40] = 0
    J[3, 40] = 0
    J[1, 41] = 0
    J[2, 41] = 0
    J[3, 41] = 0
    J[1, 42] = 0
    J[2, 42] = 0
    J[3, 42] = 0
    return _assemble(J, 3, 42, c, s)


# ----------------------------------------------------------------------------------------------------------------------
# Not a transcription: the corrected forms of the entries that disagree with the derivative (KNOWN_MISPRINTS in
# test_appendix_a.py), each the smallest change to the print that agrees.


def corrections(c, s, a1, a2, a3, d4, d6):
    """Corrected values of the misprinted entries, ``{name: array}``."""
    c1, c2, c3, c4, c5, c6 = c
    s1, s2, s3, s4, s5, s6 = s
    return {
        # one '(' added after "d6 *" and one ')' after the c5 term, as Y and Z are printed
        "X": (d6 * (((c1 * c2 * c3 - c1 * s2 * s3) * c4 + s1 * s4) * s5 + (c1 * c2 * s3 + c1 * s2 * c3) * c5)
              + d4 * (c1 * c2 * s3 + c1 * s2 * c3) + a3 * (c1 * c2 * c3 - c1 * s2 * s3) + a2 * c1 * c2 + a1 * c1),
        # c5 moved onto the c4 group and the sign of s1*s4 flipped (= the printed J(1,5))
        "Je(1.29)": ((-c1 * c2 * s3 - c1 * s2 * c3) * s5 + ((c1 * c2 * c3 - c1 * s2 * s3) * c4 + s1 * s4) * c5) * d6,
        # c5 moved onto the c4 group and the sign of c1*s4 flipped (= the printed J(2,5))
        "Je(2.29)": ((-s1 * c2 * s3 - s1 * s2 * c3) * s5 + ((s1 * c2 * c3 - s1 * s2 * s3) * c4 - c1 * s4) * c5) * d6,
    }
