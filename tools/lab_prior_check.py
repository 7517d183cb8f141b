"""Are the lab priors right? The lab calibrations' actual errors against ``calibration_priors.yaml`` (evaluator side).

    python tools/lab_prior_check.py SWEEP_DIR [SWEEP_DIR ...]

The joint bundle, test 2 and the in-situ bound all take the lab's intrinsics, lens and mount as uncertain with the
covariance the lab wrote (its own noise and the rig's tolerances, with every cross-covariance). This tool measures
whether the lab's *actual* errors follow it: per run of an in-situ sweep, the error vector ``e`` (calibrated minus
true, in the priors' order: ``fx fy cx cy`` px, ``k1 k2 p1 p2``, the mount's right perturbation rad then m) and its
Mahalanobis square ``e^T C^-1 e``, which is chi-square with 10, 14 or 15 (the lab's k3 too) degrees of freedom when
the priors are right;
also per block (intrinsics, intrinsics + lens, mount) and with the cross-covariances between blocks left out.

The truth: the camera's ``camera_K`` / ``camera_dist`` (a camera in air; in water the central calibration has no
true value - it absorbs the port - and the run is skipped), and for the mount the one the *calibrated* arm needs at
the in-situ views, ``T_link5_cam_cal exp(-e) = mean_views L_cal(q)^-1 L_true(q) T_link5_cam_true`` (the lab's AX = XB
finds the mount of its calibrated arm, whose link 5 is not the true one: the arm's own errors are the
identification's, in its covariance).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

def lab_error(truth: dict, K, dist, robot, eps_cal, T_mount_cal, n_params: int) -> np.ndarray:
    """The lab's error (calibrated minus true) in the priors' order (10, 14 or 15,) - see the module docstring."""
    from bench.geometry.quaternion import matrix_to_rotation_vector
    from bench.geometry.transforms import invert
    from bench.robot.orientation import link5_frame

    K_t, d_t = np.asarray(truth["camera_K"], float), np.asarray(truth["camera_dist"], float)
    e_K = np.array([K[0, 0] - K_t[0, 0], K[1, 1] - K_t[1, 1], K[0, 2] - K_t[0, 2], K[1, 2] - K_t[1, 2]])
    q = np.array([v["q_true"] for v in truth["views"].values() if v["role"] in ("reference", "surround", "locate")])
    L_true = link5_frame(robot, q, np.asarray(truth["errors"], float))
    L_cal = link5_frame(robot, q, eps_cal)
    M_true = np.asarray(truth["T_link5_cam"], float)
    D = [invert(M_true) @ invert(L_true[i]) @ L_cal[i] @ T_mount_cal for i in range(len(q))]  # exp(e) per view
    e_m = np.mean([np.r_[matrix_to_rotation_vector(d[:3, :3]), d[:3, 3]] for d in D], axis=0)
    nd = n_params - 10  # the lens's coefficients: none, k1 k2 p1 p2, or with the lab's k3 too
    return np.r_[e_K, np.asarray(dist, float)[:nd] - d_t[:nd], e_m]


def squares(e, C) -> dict:
    """``e^T C^-1 e`` of the whole vector, of each block, and with the cross-covariances between blocks zeroed."""
    nd = len(e) - 10  # the lens block's size: 0 (none), 4 or 5
    blocks = {"intrinsics": slice(0, 4), "lens": slice(4, 4 + nd), "mount": slice(4 + nd, 10 + nd)}
    if not nd:
        del blocks["lens"]
    out = {"all": float(e @ np.linalg.solve(C, e))}
    diag = np.zeros_like(C)
    for name, s in blocks.items():
        out[name] = float(e[s] @ np.linalg.solve(C[s, s], e[s]))
        diag[s, s] = C[s, s]
    out["blocks apart"] = float(e @ np.linalg.solve(diag, e))
    return out


def check_run(run: Path) -> dict | None:
    """:func:`squares` of one run of an in-situ sweep (None: a camera in water, or no lab files)."""
    import yaml

    from bench.camera.io import read_camera_yaml
    from bench.robot.calibration_file import load_calibrated_robot
    from bench.vision.joint_bundle import lab_blocks, lab_prior, read_priors

    truth_path, lab = run / "dataset" / "truth" / "truth.yaml", run / "calibrated"
    if not truth_path.is_file() or not (lab / "calibration_priors.yaml").is_file():
        return None
    truth = yaml.safe_load(truth_path.read_text())
    if truth.get("water") or truth.get("port"):
        return None
    C = lab_prior(**lab_blocks(read_priors(lab / "calibration_priors.yaml")))
    cam = read_camera_yaml(lab / "camera.yaml")
    robot, eps, T_mount = load_calibrated_robot(lab / "robot.yaml")
    e = lab_error(truth, cam.K, cam.dist, robot, eps, T_mount, len(C))
    return {**squares(e, C), "dof": len(C), "z": e / np.sqrt(np.diag(C))}


def main(argv=None) -> int:
    from scipy.stats import chi2

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sweeps", nargs="+", type=Path)
    args = ap.parse_args(argv)
    rows = []
    for sweep in args.sweeps:
        if not (sweep / "runs").is_dir():
            print(f"{sweep}: not a bench sweep folder (no runs/)", file=sys.stderr)
            return 2
        rows += [r for run in sorted((sweep / "runs").iterdir()) if (r := check_run(run)) is not None]
    if not rows:
        print("no run with a camera in air and its lab files (in water the central calibration has no truth)",
              file=sys.stderr)
        return 2
    dof = rows[0]["dof"]
    z = np.array([r["z"] for r in rows])
    print(f"{len(rows)} runs; Mahalanobis square of the lab's error under its priors, median (mean) against "
          f"chi-square's:")
    for key in rows[0]:
        if key in ("dof", "z"):
            continue
        k = {"all": dof, "blocks apart": dof, "intrinsics": 4, "lens": dof - 10, "mount": 6}[key]
        x = np.array([r[key] for r in rows])
        print(f"  {key:13s} {np.median(x):7.2f} ({np.mean(x):6.2f})  chi2_{k}: {chi2.median(k):5.2f} ({k})  "
              f"beyond its 95 %: {np.mean(x > chi2.ppf(0.95, k)):.0%}")
    print("  RMS z per parameter:", " ".join(f"{v:.2f}" for v in np.sqrt(np.mean(z**2, axis=0))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
