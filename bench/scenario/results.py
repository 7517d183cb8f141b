"""``result.json`` (see ``shared/design.md``) and its tables, written atomically so no half-written file is left."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from bench.fileio import _clean, atomic_write_text, write_table_csv  # noqa: F401 - write_table_csv re-exported
from bench.geometry.transforms import rotation_angle


def write_result(out_dir, scenario: str, seed: int, metrics: dict, tables: dict, timings_s: dict,
                 artifacts: dict) -> Path:
    """Write ``out_dir/result.json`` with the contract's keys; non-finite numbers become ``null``."""
    doc = {
        "scenario": scenario,
        "seed": int(seed),
        "metrics": {k: _clean(float(v)) for k, v in metrics.items()},
        "tables": {name: {c: [_clean(v) for v in vals] for c, vals in t.items()} for name, t in tables.items()},
        "timings_s": {k: _clean(float(v)) for k, v in timings_s.items()},
        "artifacts": {k: str(v) for k, v in artifacts.items()},
    }
    path = Path(out_dir) / "result.json"
    atomic_write_text(path, json.dumps(doc, indent=2) + "\n")
    return path


def pose_errors(T_est, T_true) -> tuple:
    """``(position error mm, rotation error deg)`` of an estimated pose ``T_est`` (4, 4) against the true one: the
    distance of the origins and the angle of ``R_est^T R_true``."""
    return (float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3]) * 1e3),
            float(np.rad2deg(rotation_angle(T_est[:3, :3].T @ T_true[:3, :3]))))
