"""tools/xy_table_camera_axes.py: an estimate scored without its mount rotation errs by (R0^T - I) x its motion."""

import csv
import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from bench.geometry.transforms import rot_y

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("xy_table_camera_axes", ROOT / "tools" / "xy_table_camera_axes.py")
tool = importlib.util.module_from_spec(spec)
spec.loader.exec_module(tool)

COLS = ["d_mm", "method", "success"] + [f"{k}_{a}_mm" for k in ("est", "true") for a in "xyz"]


def _run(tmp: Path, theta_y0_deg: float, rows) -> Path:
    run = tmp / "runs" / "r1"
    run.mkdir(parents=True)
    (run / "result.json").write_text(json.dumps({"metrics": {"theta_x0_deg": 0.0, "theta_y0_deg": theta_y0_deg,
                                                             "theta_z0_deg": 0.0}}))
    with open(run / "combinations.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLS)
        w.writerows(rows)
    return run


def test_an_exact_estimate_scored_in_the_camera_axes_errs_by_the_turn(tmp_path, capsys):
    true = [np.array([-80.0, 0.0, 10.0]), np.array([60.0, 0.0, -14.0])]
    run = _run(tmp_path, 7.5, [[100.0, "lms", 1, *t, *t] for t in true] + [[100.0, "quaternion", 1, 1, 2, 3, 0, 0, 0],
                                                                            [100.0, "lms", 0, 9, 9, 9, 0, 0, 0]])
    table, camera = tool.errors(run, "lms")[100]
    assert np.abs(table).max() < 1e-12  # exact in the table's axes
    R0 = rot_y(np.deg2rad(7.5))
    want = np.sqrt(np.mean([(R0.T @ t - t) ** 2 for t in true], axis=0))
    assert camera == pytest.approx(want, abs=1e-9) and camera[2] > 0.1 * 70  # ~0.13 x the x motion, in z
    assert tool.main([str(tmp_path)]) == 0 and "camera axes" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="no successful combinations"):
        tool.main([str(tmp_path), "--method", "bundle"])
    with pytest.raises(SystemExit, match="no finished x-y table runs"):
        tool.main([str(tmp_path / "empty")])
    (run / "result.json").write_text(json.dumps({"metrics": {}}))
    with pytest.raises(SystemExit, match="no searched mount rotation"):
        tool.errors(run, "lms")
