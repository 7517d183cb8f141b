"""Nominal DH robot description and its YAML file (``models/ta40.yaml``).

Inside the code everything is SI (m, rad); the file uses the thesis's mm and degrees with the unit in each key, and
is converted here, at the boundary, only.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import AfterValidator, Field, model_validator

from bench.config import KeyProblem, MmDeg, Number, Section, Vec3, parse, section
from bench.fileio import read_yaml
from bench.geometry.transforms import check_vectors

#: Order of the six generalized errors inside one frame (thesis Table 2, Eq. 9): translations along x, y, z, then
#: rotations about y (s), z (r) and x (p).
PARAM_KINDS = ("x", "y", "z", "s", "r", "p")



@dataclass(frozen=True)
class Robot:
    """A serial arm of revolute joints in standard DH form (Eq. 8), SI units.

    Attributes
    ----------
    name : str
    joint_names : tuple of str, length n
    a, d, alpha, theta_offset : ndarray (n,)
        DH link length (m), offset (m), twist (rad) and joint-angle offset (rad): ``theta_i = q_i + theta_offset_i``.
    q_min, q_max : ndarray (n,)
        Joint limits (rad) on the joint readings ``q``.
    p_ee : ndarray (3,)
        Measured end-effector point in frame n (m); O6 for the TA-40.
    """

    name: str
    joint_names: tuple
    a: np.ndarray
    d: np.ndarray
    alpha: np.ndarray
    theta_offset: np.ndarray
    q_min: np.ndarray
    q_max: np.ndarray
    p_ee: np.ndarray

    @property
    def n(self) -> int:
        """Number of joints."""
        return len(self.a)

    @property
    def n_errors(self) -> int:
        """Number of generalized errors, ``6 (n + 1)`` (42 for the TA-40)."""
        return 6 * (self.n + 1)

    def with_ee_point(self, p_ee) -> Robot:
        """Copy with another measured point (m, in frame n)."""
        return Robot(self.name, self.joint_names, self.a, self.d, self.alpha, self.theta_offset, self.q_min,
                     self.q_max, np.asarray(p_ee, dtype=float).reshape(3))

    def random_configurations(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """``n`` joint vectors uniform within the joint limits, shape (n, dof), rad."""
        return rng.uniform(self.q_min, self.q_max, size=(n, self.n))

    def check_q(self, q, name="q") -> np.ndarray:
        """Validate joint readings ``q (..., n)`` in rad; one-line ``ValueError`` naming ``name`` otherwise."""
        q = check_vectors(q, name, self.n)
        if np.any(np.abs(q) > 4 * np.pi):
            raise ValueError(f"{name}: |angle| > 4*pi rad; were degrees given where radians are expected?")
        return q


def random_errors(rng: np.random.Generator, n_frames: int = 7, trans: float = 2e-3, rot: float = np.pi / 180):
    """Generalized errors uniform in +-``trans`` (m) and +-``rot`` (rad), as in the thesis's section 4.6 simulation."""
    e = np.empty((n_frames, 6))
    e[:, :3] = rng.uniform(-trans, trans, size=(n_frames, 3))
    e[:, 3:] = rng.uniform(-rot, rot, size=(n_frames, 3))
    return e.ravel()


def error_names(n_frames: int = 7) -> list[str]:
    """Names of the generalized errors in vector order: ``x0, y0, z0, s0, r0, p0, x1, ... p6``."""
    return [f"{k}{i}" for i in range(n_frames) for k in PARAM_KINDS]


def _not_radians(v: float) -> float:
    """A twist or offset of +-pi/2 or +-pi *in radians* (within 2e-3: 1.5708, 1.571, 3.1416, 3.14) does not occur
    in degrees in a nominal model: the radian value was given where degrees belong."""
    if any(abs(abs(v) - r) < 2e-3 for r in (np.pi / 2, np.pi)):
        raise ValueError(f"{v:g} looks like radians ({np.rad2deg(v):.1f} deg); the key is in degrees")
    return v


DEGREES = Annotated[float, AfterValidator(_not_radians)]


class Joint(Section):
    """One joint of a robot file: standard DH (Eq. 8) in mm and degrees, the limits of its reading."""

    name: str | None = None
    type: Literal["revolute"] = "revolute"
    a_mm: float
    d_mm: float
    alpha_deg: Annotated[DEGREES, Field(ge=-360, le=360)]
    theta_offset_deg: DEGREES = 0.0
    min_deg: float
    max_deg: float

    @model_validator(mode="after")
    def _limits(self):
        if not self.min_deg < self.max_deg:
            raise KeyProblem("min_deg", f"min_deg ({self.min_deg}) must be < max_deg ({self.max_deg})")
        return self


class CameraMount(Section):
    """``calibration.camera_mount``: T_link5_cam, the camera's optical frame (OpenCV) in link 5 (Eq. 188)."""

    translation_mm: Vec3
    quaternion_wxyz: Annotated[list[Number], Field(min_length=4, max_length=4)]

    @model_validator(mode="after")
    def _unit(self):
        if abs(np.linalg.norm(self.quaternion_wxyz) - 1.0) > 1e-6:
            raise KeyProblem("quaternion_wxyz", f"must be a finite unit quaternion, got {self.quaternion_wxyz}")
        return self


class Calibration(Section):
    """``calibration`` (:mod:`bench.robot.calibration_file`); ``errors`` is checked against the robot's error names
    there (their number depends on the joints)."""

    errors: dict = {}
    camera_mount: CameraMount | None = None
    notes: str = ""


class RobotFile(Section):
    """A robot file (``models/ta40.yaml``): the thesis's mm and degrees, the unit in every key.

    Beyond the types, the units are checked for plausibility: every joint limit within +-2 pi (radians: a
    manipulator whose every joint moves less than 6.3 degrees either way is not one); a non-zero ``a_mm`` / ``d_mm``
    below 1 mm beside a link of 100 mm or more, or a whole arm shorter than 10 mm (metres: a nominal dimension below
    1 mm is below the tolerance that the calibration identifies as an error).
    """

    name: str
    units: MmDeg = section(MmDeg)
    joints: Annotated[list[Joint], Field(min_length=1)]
    ee_point_mm: Vec3 = [0.0, 0.0, 0.0]  # the measured end-effector point, in the last frame
    calibration: Calibration | None = None

    @model_validator(mode="after")
    def _units(self):
        limits = np.array([[j.min_deg, j.max_deg] for j in self.joints])
        if np.all(np.abs(limits) <= 2 * np.pi + 1e-3) and np.abs(limits).max() > 1.0:
            raise KeyProblem("joints[0].min_deg", "every joint limit lies within +-2 pi: radians given where degrees "
                                                  "belong?")
        lengths = np.abs([j.a_mm for j in self.joints] + [j.d_mm for j in self.joints])
        names = [f"joints[{i}].a_mm" for i in range(len(self.joints))] + [
            f"joints[{i}].d_mm" for i in range(len(self.joints))]
        if 0.0 < lengths.sum() < 10.0:
            raise KeyProblem(names[int(np.argmax(lengths))], f"the arm is {lengths.sum():.4g} mm long in all: metres "
                                                             "given where mm belong?")
        for name, v in zip(names, lengths, strict=True):
            if 0.0 < v < 1.0 and lengths.max() >= 100.0:
                raise KeyProblem(name, f"{v:g} mm beside links of {lengths.max():g} mm: metres given where mm belong?")
        return self


def robot_from_dict(data: dict, source: str = "<robot>") -> Robot:
    """Build a :class:`Robot` from the parsed YAML mapping of a robot file, checked by :class:`RobotFile`."""
    f = parse(RobotFile, data, source)
    js = f["joints"]
    col = {k: np.array([j[k] for j in js], dtype=float) for k in ("a_mm", "d_mm", "alpha_deg", "theta_offset_deg",
                                                                  "min_deg", "max_deg")}
    return Robot(f["name"], tuple(j["name"] or f"joint{i + 1}" for i, j in enumerate(js)), col["a_mm"] * 1e-3,
                 col["d_mm"] * 1e-3, np.deg2rad(col["alpha_deg"]), np.deg2rad(col["theta_offset_deg"]),
                 np.deg2rad(col["min_deg"]), np.deg2rad(col["max_deg"]), np.array(f["ee_point_mm"], dtype=float) * 1e-3)


def load_robot(path) -> Robot:
    """Load and validate a robot file such as ``models/ta40.yaml``; one-line :class:`ConfigError` on bad input."""
    return robot_from_dict(read_yaml(path), str(Path(path)))


def default_robot_path() -> Path:
    """Path of the TA-40 model shipped in ``models/``."""
    return Path(__file__).resolve().parents[2] / "models" / "ta40.yaml"
