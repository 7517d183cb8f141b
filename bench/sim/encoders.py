"""What the joint encoders report versus what the arm does.

The simulator renders at the *true* joint angles; the dataset carries only the *readings*: the true angle plus a
fixed per-joint offset (an encoder zero error), white noise, quantisation to the encoder resolution, and optional
backlash (the reading lags the true angle by half the backlash in the direction of the last motion). Angles in rad.
:func:`motion_directions` gives that direction along a sequence of poses, so a campaign reads its views in the order
the arm visits them (a joint approached from above and from below reads differently: a hysteresis loop of width
``backlash_rad``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class EncoderModel:
    """Joint-encoder errors (rad). ``resolution_rad = 0`` means no quantisation."""

    noise_std_rad: float = 0.0
    resolution_rad: float = 0.0
    backlash_rad: float = 0.0
    offset_rad: tuple = ()

    def __post_init__(self):
        for key in ("noise_std_rad", "resolution_rad", "backlash_rad"):
            v = getattr(self, key)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v >= 0):
                raise ValueError(f"{key}: expected a non-negative number (rad), got {v!r}")
            if v > 0.1:
                raise ValueError(f"{key}: {v} rad is implausible for an encoder (degrees given as radians?)")

    def read(self, q_true, rng: np.random.Generator, direction=None) -> np.ndarray:
        """Readings for true angles ``q_true (..., n)``.

        ``direction (..., n)``: sign of the last motion of each joint (+1, -1, or 0 for unknown/none); with backlash
        the reading is ``q_true - direction * backlash / 2``.
        """
        q = np.asarray(q_true, dtype=float)
        if not np.all(np.isfinite(q)):
            raise ValueError("q_true: contains NaN or inf")
        out = q.copy()
        if len(self.offset_rad):
            out = out + np.asarray(self.offset_rad, dtype=float)
        if self.backlash_rad and direction is not None:
            out = out - np.sign(np.asarray(direction, dtype=float)) * self.backlash_rad / 2
        if self.noise_std_rad:
            out = out + rng.normal(0.0, self.noise_std_rad, size=q.shape)
        if self.resolution_rad:
            out = np.round(out / self.resolution_rad) * self.resolution_rad
        return out

    def drive_to(self, q_command, rng: np.random.Generator, direction=None) -> np.ndarray:
        """True angles the joint servos settle at when commanded to *read* ``q_command (..., n)`` (rad).

        The servo loop stops when the (noisy, quantised) reading equals the command, so the arm ends at
        ``q_command - offset + direction * backlash / 2`` minus the reading noise, anywhere within half a count of
        the quantisation step. ``read(drive_to(q))`` returns ``q`` up to that noise.
        """
        q = np.asarray(q_command, dtype=float)
        if not np.all(np.isfinite(q)):
            raise ValueError("q_command: contains NaN or inf")
        out = q.copy()
        if len(self.offset_rad):
            out = out - np.asarray(self.offset_rad, dtype=float)
        if self.backlash_rad and direction is not None:
            out = out + np.sign(np.asarray(direction, dtype=float)) * self.backlash_rad / 2
        if self.noise_std_rad:
            out = out - rng.normal(0.0, self.noise_std_rad, size=q.shape)
        if self.resolution_rad:
            out = out + rng.uniform(-0.5, 0.5, size=q.shape) * self.resolution_rad
        return out


def motion_directions(q_sequence, tol_rad: float = 1e-12) -> np.ndarray:
    """Sign of each joint's last motion on arrival at every pose of ``q_sequence (m, n)`` (rad): ``(m, n)``.

    +1 / -1 after a move up / down, the previous sign when a joint does not move, 0 before its first move.
    """
    q = np.asarray(q_sequence, dtype=float)
    if q.ndim != 2 or not np.all(np.isfinite(q)):
        raise ValueError(f"q_sequence: expected a finite (m, n) array of joint angles (rad), got shape {q.shape}")
    step = np.diff(q, axis=0)
    sign = np.where(step > tol_rad, 1.0, np.where(step < -tol_rad, -1.0, 0.0))
    out = np.zeros_like(q)
    for i in range(1, len(q)):
        out[i] = np.where(sign[i - 1] != 0, sign[i - 1], out[i - 1])
    return out
