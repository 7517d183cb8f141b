"""Evaluator side: how far each site view's camera pose, from its joint readings through the lab's calibration, is
from the truth (docs/integrity.md, "The covariance with each view's keypoint field").

    python tools/view_pose_errors.py RUN [RUN ...]

``RUN`` an in-situ run folder (``dataset/`` with ``truth/truth.yaml`` and ``joints.csv``, ``calibrated/robot.yaml``).
For every reference, surrounding and locate view: the rotation (camera frame, mdeg and px at the focal length) and
translation (mm) of the calibrated pose relative to the reference view against the true one - before the in-situ
refinement of the mount and lens, which takes out what is common to all views.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def view_errors(run: Path) -> list:
    """``[(view, role, rotation vector (3,) rad, translation (3,) m, focal px)]`` of a run's site views."""
    from bench.geometry.quaternion import matrix_to_rotation_vector
    from bench.robot.calibration_file import load_calibrated_robot
    from bench.robot.orientation import link5_frame

    truth_path, joints_path = run / "dataset" / "truth" / "truth.yaml", run / "dataset" / "joints.csv"
    robot_path = run / "calibrated" / "robot.yaml"
    for p in (truth_path, joints_path, robot_path):
        if not p.is_file():
            raise SystemExit(f"{p}: missing (an in-situ run folder with its truth and lab calibration)")
    truth = yaml.safe_load(truth_path.read_text())
    robot, eps_c, mount_c = load_calibrated_robot(robot_path)
    eps_t, mount_t = np.array(truth["errors"]), np.array(truth["T_link5_cam_effective"])
    with open(joints_path, newline="") as fh:
        q_read = {r["view"]: np.deg2rad([float(r[f"q{i}_deg"]) for i in range(1, 7)]) for r in csv.DictReader(fh)}
    views = {k: v for k, v in truth["views"].items() if v["role"] in ("reference", "surround", "locate")}
    ref = next(k for k, v in views.items() if v["role"] == "reference")

    def poses(k):
        T_b = np.array(views[k]["T_world_base"])
        return (T_b @ link5_frame(robot, np.array(views[k]["q_true"]), eps_t) @ mount_t,
                T_b @ link5_frame(robot, q_read[k], eps_c) @ mount_c)

    Tt0, Tp0 = poses(ref)
    out = []
    for k, v in views.items():
        Tt, Tp = poses(k)
        E = np.linalg.inv(np.linalg.inv(Tp0) @ Tp) @ (np.linalg.inv(Tt0) @ Tt)
        out.append((k, v["role"], matrix_to_rotation_vector(E[:3, :3]), E[:3, 3], float(truth["camera_K"][0][0])))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path)
    args = ap.parse_args(argv)
    for run in args.runs:
        rows = view_errors(run)
        print(f"{run}:")
        for name, role, w, t, f in rows:
            print(f"  {name:10s} {role:9s} rotation {np.rad2deg(np.linalg.norm(w)) * 1e3:7.2f} mdeg "
                  f"({np.linalg.norm(w) * f:5.2f} px)  translation {np.linalg.norm(t) * 1e3:6.2f} mm")
        other = [r for r in rows if r[1] != "reference"]
        print(f"  median: {np.median([np.rad2deg(np.linalg.norm(r[2])) * 1e3 for r in other]):.1f} mdeg, "
              f"{np.median([np.linalg.norm(r[3]) * 1e3 for r in other]):.2f} mm")
    return 0


if __name__ == "__main__":
    sys.exit(main())
