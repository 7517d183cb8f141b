"""The calibrated robot file: the nominal model (``models/ta40.yaml`` format) plus what calibration found.

``robot.yaml`` of a dataset holds the nominal DH model and joint limits; after calibration it also holds::

    calibration:
      errors:            # the 42 generalized errors (Eq. 9-10, exact form), thesis units, unit in every key
        x0_mm: ...       # x, y, z in mm; s, r, p in rad; frames 0..6, Table 2 order
        ...
      camera_mount:      # T_link5_cam: the camera's optical frame (OpenCV) in link 5 (Eq. 188)
        translation_mm: [x, y, z]
        quaternion_wxyz: [w, x, y, z]
      notes: free text

:func:`load_calibrated_robot` returns the nominal :class:`Robot`, the error vector (SI, zeros if absent) and the
mount (``None`` if absent). Every malformed entry is a one-line :class:`ConfigError` naming the file and the key.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from bench.config import parse
from bench.errors import ConfigError
from bench.fileio import atomic_write_text, read_yaml
from bench.geometry.quaternion import matrix_to_quaternion, quaternion_to_matrix
from bench.geometry.transforms import check_transform, homogeneous
from bench.robot.model import Robot, RobotFile, error_names, robot_from_dict

_UNIT = {"x": "mm", "y": "mm", "z": "mm", "s": "rad", "r": "rad", "p": "rad"}


def _error_key(name: str) -> str:
    return f"{name}_{_UNIT[name[0]]}"


def calibration_section(robot: Robot, eps=None, T_link5_cam=None, notes: str = "") -> dict:
    """The ``calibration`` mapping for a robot file (thesis units, units in the keys)."""
    out = {}
    if eps is not None:
        eps = np.asarray(eps, dtype=float).reshape(robot.n_errors)
        out["errors"] = {_error_key(n): float(v * (1e3 if n[0] in "xyz" else 1.0))
                         for n, v in zip(error_names(robot.n + 1), eps, strict=True)}
    if T_link5_cam is not None:
        T = check_transform(T_link5_cam, "T_link5_cam")
        out["camera_mount"] = {"translation_mm": [float(v) for v in T[:3, 3] * 1e3],
                               "quaternion_wxyz": [float(v) for v in matrix_to_quaternion(T[:3, :3])]}
    if notes:
        out["notes"] = str(notes)
    return out


def write_calibrated_robot(path, nominal_file, robot: Robot, eps=None, T_link5_cam=None, notes: str = "") -> Path:
    """Copy the nominal robot file to ``path`` with a ``calibration`` section (replacing any earlier one)."""
    data = yaml.safe_load(Path(nominal_file).read_text())
    data.pop("calibration", None)
    data["calibration"] = calibration_section(robot, eps, T_link5_cam, notes)
    return atomic_write_text(path, yaml.safe_dump(data, sort_keys=False))


def load_calibrated_robot(path):
    """``(robot, eps (42,) SI, T_link5_cam (4, 4) or None)`` from a (possibly calibrated) robot file."""
    path = Path(path)
    data = read_yaml(path)
    robot = robot_from_dict(data, str(path))  # checks the calibration section too (RobotFile)
    cal = parse(RobotFile, data, str(path))["calibration"] or {}
    eps = np.zeros(robot.n_errors)
    names = error_names(robot.n + 1)
    keys = [_error_key(n) for n in names]
    bad = set(cal.get("errors") or {}) - set(keys)
    if bad:
        b = sorted(bad)[0]
        hint = f" (did you mean {b}_{_UNIT[b[0]]}?)" if b in names else ""
        raise ConfigError(path, f"calibration.errors.{b}", f"unknown key{hint}")
    for i, (n, k) in enumerate(zip(names, keys, strict=True)):
        v = (cal.get("errors") or {}).get(k, 0.0)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
            raise ConfigError(path, f"calibration.errors.{k}", f"expected a finite number, got {v!r}")
        eps[i] = v * (1e-3 if n[0] in "xyz" else 1.0)
        if n[0] in "srp" and abs(eps[i]) > 0.5:
            raise ConfigError(path, f"calibration.errors.{k}", f"{v} rad is not a plausible error (degrees?)")
    T = None
    if cal.get("camera_mount"):
        m = cal["camera_mount"]
        T = homogeneous(quaternion_to_matrix(np.array(m["quaternion_wxyz"], float)),
                        np.array(m["translation_mm"], float) * 1e-3)
    return robot, eps, T
