"""Nominal DH robot description and its YAML file (``models/ta40.yaml``).

Inside the code everything is SI (m, rad); the file uses the thesis's mm and degrees with the unit in each key, and
is converted here, at the boundary, only.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.errors import ConfigError
from bench.fileio import read_yaml

#: Order of the six generalized errors inside one frame (thesis Table 2, Eq. 9): translations along x, y, z, then
#: rotations about y (s), z (r) and x (p).
PARAM_KINDS = ("x", "y", "z", "s", "r", "p")

_JOINT_KEYS = {"name", "type", "a_mm", "d_mm", "alpha_deg", "theta_offset_deg", "min_deg", "max_deg"}
_TOP_KEYS = {"name", "units", "joints", "ee_point_mm", "calibration"}  # calibration: bench.robot.calibration_file


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
        q = np.asarray(q, dtype=float)
        if q.shape[-1:] != (self.n,):
            raise ValueError(f"{name}: expected shape (..., {self.n}), got {q.shape}")
        if not np.all(np.isfinite(q)):
            raise ValueError(f"{name}: contains NaN or inf")
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


def _number(src, field, value):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(src, field, f"expected a number, got {value!r}")
    if not np.isfinite(value):
        raise ConfigError(src, field, "must be finite")
    return float(value)


def _check_units(source, joints, arr) -> None:
    """Plausibility of the units in the robot file (one-line :class:`ConfigError` naming the field).

    * ``alpha_deg`` / ``theta_offset_deg`` equal to +-pi/2 or +-pi *in radians* (within 2e-3: 1.5708, 1.571, 3.1416,
      3.14): a twist or offset of 1.57 or 3.14 degrees does not occur in a nominal model; the degree value is given.
    * every joint limit within +-2 pi: radians (a manipulator whose every joint moves less than 6.3 degrees either
      way is not one).
    * a non-zero ``a_mm`` / ``d_mm`` below 1 mm beside a link of 100 mm or more, or a whole arm shorter than 10 mm:
      metres (a nominal dimension below 1 mm is below the tolerance that the calibration identifies as an error).
    """
    for i, j in enumerate(joints):
        for key in ("alpha_deg", "theta_offset_deg"):
            v = float(j.get(key, 0.0))
            if any(abs(abs(v) - r) < 2e-3 for r in (np.pi / 2, np.pi)):
                raise ConfigError(source, f"joints[{i}].{key}", f"{v:g} looks like radians ({np.rad2deg(v):.1f} deg); "
                                                                "the key is in degrees")
    limits = np.concatenate([arr["lo"], arr["hi"]])  # rad, from the *_deg values
    if np.all(np.abs(np.rad2deg(limits)) <= 2 * np.pi + 1e-3) and np.abs(np.rad2deg(limits)).max() > 1.0:
        raise ConfigError(source, "joints[0].min_deg", "every joint limit lies within +-2 pi: radians given where "
                                                      "degrees belong?")
    lengths = np.abs(np.concatenate([arr["a"], arr["d"]])) * 1e3  # mm
    names = [f"joints[{i}].a_mm" for i in range(len(arr["a"]))] + [f"joints[{i}].d_mm" for i in range(len(arr["d"]))]
    if 0.0 < lengths.sum() < 10.0:
        raise ConfigError(source, names[int(np.argmax(lengths))], f"the arm is {lengths.sum():.4g} mm long in all: "
                                                                  "metres given where mm belong?")
    for name, v in zip(names, lengths, strict=True):
        if 0.0 < v < 1.0 and lengths.max() >= 100.0:
            raise ConfigError(source, name, f"{v:g} mm beside links of {lengths.max():g} mm: metres given where mm "
                                            "belong?")


def robot_from_dict(data: dict, source: str = "<robot>") -> Robot:
    """Build a :class:`Robot` from the parsed YAML mapping, validating every field (units in key names)."""
    if not isinstance(data, dict):
        raise ConfigError(source, "<top>", "expected a mapping")
    unknown = set(data) - _TOP_KEYS
    if unknown:
        raise ConfigError(source, sorted(unknown)[0], f"unknown key (allowed: {', '.join(sorted(_TOP_KEYS))})")
    for key in ("name", "joints"):
        if key not in data:
            raise ConfigError(source, key, "missing")
    units = data.get("units", {"length": "mm", "angle": "deg"})
    if units != {"length": "mm", "angle": "deg"}:
        raise ConfigError(source, "units", f"must be {{length: mm, angle: deg}}, got {units!r}")
    joints = data["joints"]
    if not isinstance(joints, list) or not joints:
        raise ConfigError(source, "joints", "expected a non-empty list")
    cols = {k: [] for k in ("a", "d", "alpha", "off", "lo", "hi")}
    names = []
    for i, j in enumerate(joints):
        where = f"joints[{i}]"
        if not isinstance(j, dict):
            raise ConfigError(source, where, "expected a mapping")
        unknown = set(j) - _JOINT_KEYS
        if unknown:
            bad = sorted(unknown)[0]
            hint = " (units go in the key: a_mm, d_mm, alpha_deg, ...)" if bad.split("_")[0] in {
                "a", "d", "alpha", "theta", "min", "max"} else ""
            raise ConfigError(source, f"{where}.{bad}", f"unknown key{hint}")
        for key in ("a_mm", "d_mm", "alpha_deg", "min_deg", "max_deg"):
            if key not in j:
                raise ConfigError(source, f"{where}.{key}", "missing")
        if j.get("type", "revolute") != "revolute":
            raise ConfigError(source, f"{where}.type", f"only 'revolute' joints are supported, got {j['type']!r}")
        names.append(str(j.get("name", f"joint{i + 1}")))
        cols["a"].append(_number(source, f"{where}.a_mm", j["a_mm"]) * 1e-3)
        cols["d"].append(_number(source, f"{where}.d_mm", j["d_mm"]) * 1e-3)
        alpha = _number(source, f"{where}.alpha_deg", j["alpha_deg"])
        if abs(alpha) > 360:
            raise ConfigError(source, f"{where}.alpha_deg", f"{alpha} is not a plausible angle in degrees")
        cols["alpha"].append(np.deg2rad(alpha))
        cols["off"].append(np.deg2rad(_number(source, f"{where}.theta_offset_deg", j.get("theta_offset_deg", 0.0))))
        lo = _number(source, f"{where}.min_deg", j["min_deg"])
        hi = _number(source, f"{where}.max_deg", j["max_deg"])
        if not lo < hi:
            raise ConfigError(source, f"{where}.min_deg", f"min_deg ({lo}) must be < max_deg ({hi})")
        cols["lo"].append(np.deg2rad(lo))
        cols["hi"].append(np.deg2rad(hi))
    p = data.get("ee_point_mm", [0.0, 0.0, 0.0])
    if not isinstance(p, list) or len(p) != 3:
        raise ConfigError(source, "ee_point_mm", "expected a list of 3 numbers (mm, in the last frame)")
    p_ee = np.array([_number(source, f"ee_point_mm[{k}]", v) for k, v in enumerate(p)]) * 1e-3
    arr = {k: np.array(v, dtype=float) for k, v in cols.items()}
    _check_units(source, joints, arr)
    return Robot(str(data["name"]), tuple(names), arr["a"], arr["d"], arr["alpha"], arr["off"], arr["lo"], arr["hi"],
                 p_ee)


def load_robot(path) -> Robot:
    """Load and validate a robot file such as ``models/ta40.yaml``; one-line :class:`ConfigError` on bad input."""
    path = Path(path)
    data = read_yaml(path)
    return robot_from_dict(data, str(path))


def default_robot_path() -> Path:
    """Path of the TA-40 model shipped in ``models/``."""
    return Path(__file__).resolve().parents[2] / "models" / "ta40.yaml"
