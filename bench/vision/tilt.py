"""The located base's tilt against the vehicle's inertial sensor: a check no image can make (issue 13).

A work-class ROV carries a fibre-optic gyrocompass / INS whose roll and pitch are good to ~0.01° (1 sigma; the
class of the iXblue Octans that work-class vehicles carry). The arm's base is bolted to the vehicle, so at every
parking the INS gives the direction of gravity in the base frame, ``d`` (a unit vector, through the lab's
INS-to-base alignment). The localisation gives the rotation ``R`` of the base at the localisation in the survey base
frame, so ``R d_locate`` must be ``d_survey``.

The check is what the vision tests cannot see: a camera knocked on its mount between the survey and the
localisation turns the located base by the knock, while both locate views stay consistent with each other and the
map (docs/integrity.md, "A fault the tests do not see"). The tilt sees the part of that turn about a horizontal
axis; a turn about the vertical (heading) stays invisible to it.

The statistic is the tilt disagreement ``e = d_survey x (R d_locate)`` (rad, horizontal) and its Mahalanobis
square over the covariance a consistent localisation gives it: the pose's rotation covariance (as calibrated, and
inflated by test 3) with the protection levels' floor (:data:`~bench.vision.integrity.FLOOR_DEG`) seen in the
horizontal plane, the INS's noise at both parkings (``tilt_sigma_deg`` per axis, each), and the alignment's error
turned through the base's rotation between the parkings (``(R - I) a``). Beyond the chi-square (2 degrees of
freedom) quantile at ``1 - INTEGRITY_RISK`` the pose or the INS is not what it claims: :func:`check` refuses.
Measured (docs/integrity.md): 40 clean runs median 1.2, largest 6.1, against the limit 13.8; cameras knocked by 0.2°
5.9-117 (18 of 20 refused).

A tilt that agrees is then *fused* into the pose (:func:`fuse`, ``locate_dataset(ins_tilt="fuse")``, the default):
a linear measurement update of the 6-dof pose by the two horizontal components of ``e`` (a loosely coupled
INS / vision update), whose innovation test is the check above. The INS's roll and pitch are better than the
rotation the images give about horizontal axes, and the base origin's error follows its rotation's through the
lever arm from the panel, so both shrink. The bound takes the same information (:class:`TiltUpdate`), so that the
efficiency compares an estimator with the bound of the same data.

The file (``vehicle.yaml`` in the dataset, optional)::

    tilt_sigma_deg: 0.01          # the INS's roll / pitch accuracy, 1 sigma per axis
    alignment_sigma_deg: 0.05     # the lab's INS-to-base alignment, 1 sigma per axis
    down_in_base:                 # gravity's direction in the arm's base frame at each parking (unit vectors)
      survey: [x, y, z]
      locate: [x, y, z]

Units: rad inside; degrees in the file, as the datasheets give them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import numpy as np
from pydantic import AfterValidator
from scipy.stats import chi2

from bench.config import PositiveFloat, Section, Vec3, about, at_most, parse
from bench.fileio import read_yaml
from bench.geometry.quaternion import rotation_vector_to_matrix
from bench.vision.integrity import FLOOR_DEG, INTEGRITY_RISK, Integrity

VEHICLE_FILE = "vehicle.yaml"


def _unit(v: list) -> list:
    if abs(float(np.linalg.norm(v)) - 1.0) > 1e-3:
        raise ValueError(f"expected a unit vector (gravity's direction, not its acceleration), got {v!r}")
    return v


SigmaDeg = Annotated[PositiveFloat, at_most(5, "{v} deg is implausible for an INS's accuracy (the unit is deg)")]
UnitVec3 = Annotated[Vec3, AfterValidator(_unit)]


class _Parkings(Section):
    survey: Annotated[UnitVec3, about("gravity's direction in the base frame at the survey's parking")]
    locate: Annotated[UnitVec3, about("the same at the localisation's parking")]


class VehicleFile(Section):
    """The schema of ``vehicle.yaml`` (module docstring)."""

    tilt_sigma_deg: Annotated[SigmaDeg, about("the INS's roll / pitch accuracy, 1 sigma per axis")]
    alignment_sigma_deg: Annotated[SigmaDeg, about("the lab's INS-to-base alignment, 1 sigma per axis")]
    down_in_base: _Parkings


@dataclass(frozen=True)
class VehicleTilt:
    """Gravity's direction in the base frame at the survey's and the localisation's parking (unit vectors (3,)), with
    the INS's tilt accuracy and the INS-to-base alignment's (1 sigma per axis, rad)."""

    down_survey: np.ndarray
    down_locate: np.ndarray
    tilt_sigma_rad: float
    alignment_sigma_rad: float


def read_vehicle_yaml(path) -> VehicleTilt:
    """:class:`VehicleTilt` from a ``vehicle.yaml`` (:class:`VehicleFile`); one-line errors naming the field."""
    f = parse(VehicleFile, read_yaml(path), path)
    d = {k: np.asarray(v, float) / np.linalg.norm(v) for k, v in f["down_in_base"].items()}
    return VehicleTilt(d["survey"], d["locate"], float(np.deg2rad(f["tilt_sigma_deg"])),
                       float(np.deg2rad(f["alignment_sigma_deg"])))


def tilt_disagreement(R_survey_locate, tilt: VehicleTilt) -> np.ndarray:
    """``e`` (3,) rad: the rotation, about a horizontal axis, that takes gravity as the located base carries it
    (``R d_locate``) onto gravity at the survey (``d_survey``); small-angle, ``|e| = sin`` of the angle between them."""
    return np.cross(tilt.down_survey, np.asarray(R_survey_locate, float) @ tilt.down_locate)


def _horizontal_basis(down) -> np.ndarray:
    """An orthonormal basis (3, 2) of the plane perpendicular to ``down`` (the horizontal)."""
    return np.linalg.svd(np.eye(3) - np.outer(down, down))[0][:, :2]


def tilt_covariance(R_survey_locate, covariance_rot, tilt: VehicleTilt, floor_rad: float = 0.0) -> np.ndarray:
    """The covariance (3, 3, rank 2: the horizontal plane) of :func:`tilt_disagreement` on a consistent
    localisation: the pose's rotation covariance ``covariance_rot`` (3, 3; left perturbation, the survey base frame)
    plus ``floor_rad`` per axis, the INS's noise at both parkings and its alignment turned through ``R - I``."""
    B = _horizontal_basis(tilt.down_survey)
    P = B @ B.T  # the horizontal plane: e = P w for a rotation error w
    A = np.asarray(R_survey_locate, float) - np.eye(3)  # a fixed misalignment a moves e by P (R - I) a
    C = np.asarray(covariance_rot, float) + floor_rad**2 * np.eye(3) + 2 * tilt.tilt_sigma_rad**2 * np.eye(3)
    return P @ (C + tilt.alignment_sigma_rad**2 * (A @ A.T)) @ P


@dataclass(frozen=True)
class TiltUpdate:
    """The linear measurement update of a pose by the INS's tilt (module docstring).

    Attributes
    ----------
    H : ndarray (2, 6)
        The measurement: the horizontal components (basis ``B`` (3, 2) of the survey's horizontal) of a pose error
        ``(w, v)`` (left perturbation, rotation vector rad then m): ``B^T w``.
    S : ndarray (2, 2)
        The INS's noise in those components (rad^2): both parkings' readings and the alignment turned through
        ``R - I``.
    K : ndarray (6, 2)
        The gain ``C H^T (H C H^T + S)^-1`` for the pose covariance ``C`` it was made with.
    """

    H: np.ndarray
    S: np.ndarray
    K: np.ndarray

    def covariance(self, covariance) -> np.ndarray:
        """The fused pose's covariance (6, 6), ``(I - K H) C`` (symmetrised)."""
        C = (np.eye(6) - self.K @ self.H) @ np.asarray(covariance, float)
        return 0.5 * (C + C.T)

    def error(self, e, rng: np.random.Generator | None = None) -> np.ndarray:
        """The fused pose's error (..., 6) for the pose's error ``e`` (..., 6): ``(I - K H) e + K n`` with the INS's
        noise ``n ~ N(0, S)`` drawn from ``rng`` (none: ``n = 0``, a noise-free INS - the floor's)."""
        e = np.asarray(e, float)
        out = e - e @ (self.K @ self.H).T
        if rng is not None:
            n = rng.multivariate_normal(np.zeros(2), self.S, size=e.shape[:-1])
            out = out + n @ self.K.T
        return out


def tilt_update(R_survey_locate, covariance, tilt: VehicleTilt) -> TiltUpdate:
    """:class:`TiltUpdate` of a pose of rotation ``R_survey_locate`` (3, 3) and covariance (6, 6; rotation vector
    rad, then m) by the INS's tilt."""
    B = _horizontal_basis(tilt.down_survey)
    H = np.hstack([B.T, np.zeros((2, 3))])  # e = P w at the truth (R d_locate = d_survey): B^T e = B^T w
    S = B.T @ tilt_covariance(R_survey_locate, np.zeros((3, 3)), tilt) @ B
    C = np.asarray(covariance, float)
    K = np.linalg.solve(H @ C @ H.T + S, H @ C).T  # C H^T (H C H^T + S)^-1 (both symmetric)
    return TiltUpdate(H, S, K)


def fuse(T_survey_locate, covariance, tilt: VehicleTilt, inflation: float = 1.0) -> tuple:
    """The pose with the INS's tilt fused (module docstring): ``(T (4, 4), covariance (6, 6), correction (6,))``.

    ``covariance`` is the pose's as calibrated; ``inflation`` test 3's factor (``inflation_chi2``), which the
    protection levels apply to it: the update weighs the pose by ``inflation**2 * covariance`` and returns the fused
    covariance divided by it again, so that the levels computed from it as before are the fused pose's. The
    ``correction`` ``(w, v)`` moves the pose as ``R' = exp(w) R``, ``t' = t + v`` (left perturbation). The gain
    weighs the pose by its covariance alone, without the protection levels' floor that test 7 also allows (the
    fusion that was measured, docs/integrity.md).
    """
    T = np.asarray(T_survey_locate, float)
    C = float(inflation) ** 2 * np.asarray(covariance, float)
    upd = tilt_update(T[:3, :3], C, tilt)
    dx = -upd.K @ (upd.H[:, :3] @ tilt_disagreement(T[:3, :3], tilt))  # the innovation: -B^T e
    out = T.copy()
    out[:3, :3] = rotation_vector_to_matrix(dx[:3]) @ T[:3, :3]
    out[:3, 3] = T[:3, 3] + dx[3:]
    return out, upd.covariance(C) / float(inflation) ** 2, dx


def check(integ: Integrity, T_survey_locate, covariance, tilt: VehicleTilt) -> Integrity:
    """Test 7 on a localisation that was not refused (module docstring): ``covariance`` (6, 6) the pose's, as
    calibrated (rotation first), inflated by test 3's factor in ``integ.tests``. Records ``tilt_disagreement_deg``,
    ``tilt_mahalanobis_sq`` and ``tilt_limit_sq`` in ``integ.tests``; refused beyond the limit. Returns ``integ``
    (changed in place)."""
    if integ.level == "refused":
        return integ
    R = np.asarray(T_survey_locate, float)[:3, :3]
    f = float(integ.tests.get("inflation_chi2", 1.0))
    S = tilt_covariance(R, f**2 * np.asarray(covariance, float)[:3, :3], tilt, np.deg2rad(FLOOR_DEG))
    e = tilt_disagreement(R, tilt)
    B = _horizontal_basis(tilt.down_survey)  # S has rank 2: solved in the plane
    m2 = float((B.T @ e) @ np.linalg.solve(B.T @ S @ B, B.T @ e))
    limit = float(chi2.ppf(1 - INTEGRITY_RISK, 2))
    integ.tests.update(tilt_disagreement_deg=float(np.rad2deg(np.linalg.norm(e))), tilt_mahalanobis_sq=m2,
                       tilt_limit_sq=limit)
    if not m2 <= limit:
        integ.reasons.insert(0, f"the located base's tilt disagrees with the vehicle's INS by "
                                f"{np.rad2deg(np.linalg.norm(e)):.3f} deg (Mahalanobis square {m2:.1f} > {limit:.1f}): "
                                "the camera's mount or the arm moved since the lab, or the INS is wrong")
        integ.level = "refused"
        integ.protection_radius_m = integ.protection_angle_rad = float("inf")
    return integ
