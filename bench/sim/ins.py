"""The vehicle's inertial sensor as the arm's base sees it: gravity's direction in the base frame at a parking.

A work-class ROV's fibre-optic gyrocompass / INS measures roll and pitch to ~0.01° (1 sigma per axis); the lab aligns
it to the arm's base to a stated accuracy. At each parking the reading is the true direction of gravity in the base
frame (world z up) turned by the sensor's noise (a fresh draw per parking, about the two horizontal axes) and by the
alignment's error (one draw, the same at every parking). :func:`vehicle_yaml_text` writes the dataset's
``vehicle.yaml``, which :mod:`bench.vision.tilt` reads.
"""

from __future__ import annotations

import numpy as np

from bench.geometry.quaternion import rotation_vector_to_matrix

DOWN_WORLD = np.array([0.0, 0.0, -1.0])


def down_in_base(T_world_base, tilt_sigma_rad: float, R_align, rng: np.random.Generator) -> np.ndarray:
    """The INS's gravity direction (3,) in the base frame of ``T_world_base``: the true one turned by a noise
    rotation about the horizontal (``tilt_sigma_rad`` per axis), then by the alignment ``R_align`` (3, 3)."""
    d = np.asarray(T_world_base, float)[:3, :3].T @ DOWN_WORLD
    n = rng.normal(0.0, tilt_sigma_rad, 3)
    n -= (n @ d) * d  # about horizontal axes only: a heading error does not move gravity
    return R_align @ rotation_vector_to_matrix(n) @ d


def vehicle_yaml_text(T_world_base_survey, T_world_base_locate, tilt_sigma_deg: float, alignment_sigma_deg: float,
                      rng: np.random.Generator) -> str:
    """``vehicle.yaml`` (:mod:`bench.vision.tilt`): the stated accuracies and the two parkings' readings."""
    R_align = rotation_vector_to_matrix(rng.normal(0.0, np.deg2rad(alignment_sigma_deg), 3))
    s, loc = (down_in_base(T, np.deg2rad(tilt_sigma_deg), R_align, rng)
              for T in (T_world_base_survey, T_world_base_locate))
    fmt = lambda v: "[" + ", ".join(f"{x:.12f}" for x in v) + "]"  # noqa: E731
    return ("# the vehicle's INS at each parking: gravity's direction in the arm's base frame (bench.vision.tilt)\n"
            f"tilt_sigma_deg: {tilt_sigma_deg:g}        # roll / pitch accuracy, 1 sigma per axis\n"
            f"alignment_sigma_deg: {alignment_sigma_deg:g}   # the lab's INS-to-base alignment, 1 sigma per axis\n"
            f"down_in_base:\n  survey: {fmt(s)}\n  locate: {fmt(loc)}\n")
