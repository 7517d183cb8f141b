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

from bench.errors import ConfigError
from bench.fileio import atomic_write_text, read_yaml
from bench.geometry.quaternion import matrix_to_quaternion, quaternion_to_matrix
from bench.geometry.transforms import check_transform, homogeneous
from bench.robot.model import Robot, error_names, robot_from_dict

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
    path = Path(path)
    atomic_write_text(path, yaml.safe_dump(data, sort_keys=False))
    return path


def load_calibrated_robot(path):
    """``(robot, eps (42,) SI, T_link5_cam (4, 4) or None)`` from a (possibly calibrated) robot file."""
    path = Path(path)
    data = read_yaml(path)
    robot = robot_from_dict(data, str(path))
    cal = data.get("calibration") or {}
    if not isinstance(cal, dict):
        raise ConfigError(path, "calibration", "expected a mapping")
    unknown = set(cal) - {"errors", "camera_mount", "notes"}
    if unknown:
        raise ConfigError(path, f"calibration.{sorted(unknown)[0]}", "unknown key (allowed: errors, camera_mount, "
                                                                     "notes)")
    eps = np.zeros(robot.n_errors)
    if "errors" in cal:
        errs = cal["errors"]
        names = error_names(robot.n + 1)
        keys = [_error_key(n) for n in names]
        if not isinstance(errs, dict):
            raise ConfigError(path, "calibration.errors", "expected a mapping of x0_mm, y0_mm, ... p6_rad")
        bad = set(errs) - set(keys)
        if bad:
            b = sorted(bad)[0]
            hint = f" (did you mean {b}_{_UNIT[b[0]]}?)" if b in names else ""
            raise ConfigError(path, f"calibration.errors.{b}", f"unknown key{hint}")
        for i, (n, k) in enumerate(zip(names, keys, strict=True)):
            v = errs.get(k, 0.0)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                raise ConfigError(path, f"calibration.errors.{k}", f"expected a finite number, got {v!r}")
            eps[i] = v * (1e-3 if n[0] in "xyz" else 1.0)
            if n[0] in "srp" and abs(eps[i]) > 0.5:
                raise ConfigError(path, f"calibration.errors.{k}", f"{v} rad is not a plausible error (degrees?)")
    T = None
    if "camera_mount" in cal:
        m = cal["camera_mount"]
        try:
            t = np.array(m["translation_mm"], dtype=float).reshape(3) * 1e-3
            q = np.array(m["quaternion_wxyz"], dtype=float).reshape(4)
        except (KeyError, TypeError, ValueError):
            raise ConfigError(path, "calibration.camera_mount", "expected translation_mm: [3 numbers] and "
                                                                "quaternion_wxyz: [4 numbers]") from None
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(q))) or abs(np.linalg.norm(q) - 1.0) > 1e-6:
            raise ConfigError(path, "calibration.camera_mount.quaternion_wxyz", "must be a finite unit quaternion")
        T = homogeneous(quaternion_to_matrix(q), t)
    return robot, eps, T
