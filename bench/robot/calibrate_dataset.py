"""``bench calibrate-robot DATASET --out DIR``: arm calibration from a dataset's laser-tracker campaign (thesis §4.4).

Input: a dataset folder (``bench.dataset``) with ``tracker.csv`` (``point, x_mm, y_mm, z_mm, q1_deg .. q6_deg``: the
measured end-effector point in the robot base frame - the frame the lab found from the two probe arcs, §2.9 - and the
joint readings it was taken at) and the nominal DH robot file ``robot.yaml`` (default: the dataset's, else the TA-40
model ``models/ta40.yaml``).

Method: the 25 identifiable generalized errors of the closed-form reduction (Eq. 21, 23, 167) estimated by
Levenberg-Marquardt on the exact error model (:func:`bench.robot.identification.identify_iterative`; Eq. 14 is its
linear first step), each coordinate weighted by the tracker's standard deviation ``sigma_mm``.

Output: ``DIR/robot.yaml`` - the nominal file plus a ``calibration.errors`` section (all ``6 (n + 1)`` errors, the
eliminated ones zero; loadable by ``bench locate --robot`` and ``bench export``) - and ``DIR/calibration.json``
(``rms_mm``, ``max_mm``, ``n_postures``, ``n_parameters``, the kept and merged parameters, the covariance in SI units,
``chi2_per_dof``, per-posture residuals).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.errors import BenchError, ConfigError
from bench.fileio import atomic_write_text, prepare_output_dir
from bench.robot.calibration_file import write_calibrated_robot
from bench.robot.identifiability import closed_form_reduction
from bench.robot.identification import identify_iterative
from bench.robot.kinematics import ee_position
from bench.robot.model import default_robot_path, load_robot


@dataclass
class DatasetCalibration:
    """What :func:`calibrate_robot_dataset` found (SI units) and where it wrote it."""

    success: bool
    message: str
    eps: np.ndarray
    rms_mm: float
    max_mm: float
    n_postures: int
    n_parameters: int
    robot_path: Path
    report_path: Path


def check_plausible(robot, eps, err_nominal, source) -> None:
    """Refuse an identification whose "errors" are not errors: a translation beyond a tenth of the arm's reach or a
    rotation beyond 0.2 rad (11 deg) means that the nominal model does not describe the measured arm (wrong units,
    wrong robot file, points in another frame) - the generalized error model can fit almost anything with large
    enough translations, so a small residual alone proves nothing."""
    reach = float(np.sum(np.abs(robot.a)) + np.sum(np.abs(robot.d)))
    e = np.asarray(eps).reshape(-1, 6)
    trans, rot = float(np.abs(e[:, :3]).max()), float(np.abs(e[:, 3:]).max())
    nominal_rms = float(np.sqrt(np.mean(np.square(err_nominal))))
    if trans > 0.1 * reach or rot > 0.2:
        hint = (f"the points lie {nominal_rms:.3g} m RMS from the nominal model of an arm reaching {reach:.3g} m: "
                "mm given as m?" if nominal_rms > 10 * reach else "wrong robot file or points in another frame?")
        raise ConfigError(source, "<identification>",
                          f"implausible errors (largest translation {trans * 1e3:.4g} mm, rotation "
                          f"{np.rad2deg(rot):.3g} deg; at most {0.1 * reach * 1e3:.4g} mm and 11.5 deg): {hint}")


def _estimate_frame(robot, q, p, names, sigma_mm):
    """Tracker points in an unknown tracker frame: the DH arm as a chain with the thesis's error frames
    (:func:`bench.robot.chain.chain_from_dh`), the tracker-to-base transform and the measured point's offset
    estimated jointly with the identifiable errors (:func:`bench.robot.marker_calibration.identify`, closed-form
    start from any rotation). Returns ``(eps (6 (n+1),), T_tracker_base, errors (m,) m, nominal errors, report)``;
    the offset's difference to the file's ``ee_point_mm`` is written as translation errors of frame n (exact: the
    last frame's errors are otherwise merged into the offset)."""
    from bench.geometry.quaternion import matrix_to_quaternion
    from bench.robot.chain import chain_from_dh
    from bench.robot.marker_calibration import Measurements, identify
    from bench.robot.model import error_names

    chain = chain_from_dh(robot)
    meas = Measurements(q, p[:, None, :], list(names), [("x_mm", "y_mm", "z_mm")])
    cal = identify(chain, meas, model="reduced", weights="none", sigma_m=sigma_mm * 1e-3,
                   nominal_offsets=robot.p_ee[None])
    eps = cal.eps.copy()
    n = robot.n
    eps[6 * n: 6 * n + 3] += cal.U[0] - robot.p_ee
    all_names = error_names(n + 1)
    std = np.sqrt(np.diag(cal.covariance))
    T = cal.T_meas_base
    report = {
        "method": "tracker frame estimated: closed-form start (any rotation) + least squares on the exact model "
                  "(Eq. 10) of the numerically identifiable errors, the tracker-to-base transform and the point",
        "T_tracker_base": {"translation_mm": [float(v) for v in T[:3, 3] * 1e3],
                           "quaternion_wxyz": [float(v) for v in matrix_to_quaternion(T[:3, :3])]},
        "n_parameters": int(6 + 3 + len(cal.kept)), "message": cal.message,
        "kept": [{"name": all_names[c], "value": float(eps[c] * (1e3 if all_names[c][0] in "xyz" else 1.0)),
                  "std": float(sd * (1e3 if all_names[c][0] in "xyz" else 1.0)),
                  "unit": "mm" if all_names[c][0] in "xyz" else "rad"}
                 for c, sd in zip(cal.kept, std[9:], strict=True)],
        "merged": cal.merged,
        "covariance_parameters": ["T_tracker_base.rot_x_rad", "T_tracker_base.rot_y_rad", "T_tracker_base.rot_z_rad",
                                  "T_tracker_base.x_m", "T_tracker_base.y_m", "T_tracker_base.z_m", "point.x_m",
                                  "point.y_m", "point.z_m"] + [all_names[c] for c in cal.kept],
        "covariance": cal.covariance.tolist(),
    }
    return eps, T, cal.residuals[:, 0], cal.nominal_residuals[:, 0], report


def calibrate_robot_dataset(dataset, out, robot_file=None, sigma_mm: float = 0.05,
                            verbose: bool = False, tracker_frame: str = "base") -> DatasetCalibration:
    """Identify the arm's generalized errors from the dataset's tracker campaign and write the calibrated files.

    Parameters
    ----------
    dataset : path
        Dataset folder with ``tracker.csv`` (points in the robot base frame, mm; readings in degrees).
    out : path
        Output folder (new, empty, or an earlier output of this command).
    robot_file : path, optional
        Nominal DH robot file; default the dataset's ``robot.yaml``, else ``models/ta40.yaml``.
    sigma_mm : float
        Standard deviation of each tracker coordinate (mm): the weights, the a-priori covariance and the chi-square
        consistency check (an identification whose residuals exceed 100 sigma is refused).
    tracker_frame : {"base", "estimate"}
        ``base``: the points are in the robot base frame (the lab's arcs, §2.9, set it up; the thesis's method,
        Table 2). ``estimate``: in the tracker's own frame, whose pose is estimated with the errors (the base-frame
        errors merge into it); ``calibration.json`` then holds ``T_tracker_base``.
    """
    from bench.dataset import load_dataset

    t0 = time.perf_counter()
    if not (isinstance(sigma_mm, (int, float)) and np.isfinite(sigma_mm) and 0 < sigma_mm <= 50):
        raise BenchError(f"--sigma-mm: expected a tracker standard deviation in (0, 50] mm, got {sigma_mm!r}")
    ds = load_dataset(dataset)
    if ds.tracker is None:
        raise ConfigError(ds.root / "tracker.csv", "<file>", "not found: calibrate-robot needs the tracker campaign "
                                                             "(point, x_mm, y_mm, z_mm, q1_deg .. q6_deg)")
    nominal = Path(robot_file) if robot_file is not None else (ds.robot_path or default_robot_path())
    robot = load_robot(nominal)
    q, p = ds.tracker["q"], ds.tracker["p"]
    if q.shape[1] != robot.n:
        raise ConfigError(nominal, "joints", f"{robot.n} joints, tracker.csv has readings of {q.shape[1]}")
    if tracker_frame not in ("base", "estimate"):
        raise BenchError(f"--tracker-frame: expected base or estimate, got {tracker_frame!r}")
    out = prepare_output_dir(out, "calibrate-robot")
    if tracker_frame == "estimate":
        return _write_estimated(ds, robot, nominal, q, p, sigma_mm, out, t0, verbose)
    red = closed_form_reduction(robot)
    res = identify_iterative(robot, q, p, red, sigma=sigma_mm * 1e-3)
    if not res.success:
        raise ConfigError(ds.root / "tracker.csv", "<identification>", res.message)
    err = np.linalg.norm(p - ee_position(robot, q, res.eps), axis=1)
    err0 = np.linalg.norm(p - ee_position(robot, q), axis=1)
    check_plausible(robot, res.eps, err0, ds.root / "tracker.csv")
    notes = (f"identified from {len(q)} tracker points of {ds.root.name} (closed-form reduction, {len(red.kept)} "
             f"parameters, Levenberg-Marquardt on the exact model); RMS {np.sqrt(np.mean(err**2)) * 1e3:.4g} mm")
    write_calibrated_robot(out / "robot.yaml", nominal, robot, res.eps, notes=notes)
    std = res.std
    report = {
        "method": "closed-form reduction (Eq. 21, 23, 167) + Levenberg-Marquardt on the exact model (Eq. 10, 14)",
        "dataset": str(ds.root), "nominal_robot": str(nominal), "message": res.message,
        "rms_mm": float(np.sqrt(np.mean(err**2)) * 1e3), "max_mm": float(err.max() * 1e3),
        "rms_nominal_mm": float(np.sqrt(np.mean(err0**2)) * 1e3),
        "n_postures": int(len(q)), "n_parameters": int(len(red.kept)), "sigma_mm": float(sigma_mm),
        "chi2_per_dof": float(res.chi2_per_dof), "condition_number": float(res.condition_number),
        "iterations": int(res.iterations),
        "kept": [{"name": n, "value": float(v * (1e3 if n[0] in "xyz" else 1.0)),
                  "std": float(s * (1e3 if n[0] in "xyz" else 1.0)), "unit": "mm" if n[0] in "xyz" else "rad"}
                 for n, v, s in zip(red.names, res.eps_dot, std, strict=True)],
        "merged": red.merged,
        "covariance_units": "SI: m for x, y, z; rad for s, r, p (products for the off-diagonal entries)",
        "covariance": res.covariance.tolist(),
        "per_posture": [{"point": n, "error_mm": float(e * 1e3)} for n, e in zip(ds.tracker["point"], err,
                                                                                   strict=True)],
        "timings_s": {"calibration_s": time.perf_counter() - t0},
    }
    atomic_write_text(out / "calibration.json", json.dumps(report, indent=2) + "\n")
    if verbose:
        print(f"{len(q)} postures, {len(red.kept)} parameters: RMS {report['rms_mm']:.4g} mm (nominal "
              f"{report['rms_nominal_mm']:.4g} mm), max {report['max_mm']:.4g} mm, chi2/dof "
              f"{report['chi2_per_dof']:.3g}")
        print(f"wrote {out / 'robot.yaml'} and {out / 'calibration.json'}")
    return DatasetCalibration(True, res.message, res.eps, report["rms_mm"], report["max_mm"], len(q),
                              len(red.kept), out / "robot.yaml", out / "calibration.json")


def _write_estimated(ds, robot, nominal, q, p, sigma_mm, out, t0, verbose) -> DatasetCalibration:
    """The ``tracker_frame="estimate"`` branch of :func:`calibrate_robot_dataset`: identify, check, write."""
    eps, T, err, err0, rep = _estimate_frame(robot, q, p, ds.tracker["point"], sigma_mm)
    check_plausible(robot, eps, err0, ds.root / "tracker.csv")
    rms = float(np.sqrt(np.mean(err**2)) * 1e3)
    write_calibrated_robot(out / "robot.yaml", nominal, robot, eps,
                           notes=f"identified from {len(q)} tracker points of {ds.root.name} in the tracker's frame "
                                 f"(its pose estimated: see calibration.json T_tracker_base); RMS {rms:.4g} mm")
    report = {"dataset": str(ds.root), "nominal_robot": str(nominal), "tracker_frame": "estimate", "rms_mm": rms,
              "max_mm": float(err.max() * 1e3), "rms_nominal_mm": float(np.sqrt(np.mean(err0**2)) * 1e3),
              "n_postures": int(len(q)), "sigma_mm": float(sigma_mm), **rep,
              "covariance_units": "SI (rad, m)",
              "per_posture": [{"point": n, "error_mm": float(e * 1e3)} for n, e in zip(ds.tracker["point"], err,
                                                                                         strict=True)],
              "timings_s": {"calibration_s": time.perf_counter() - t0}}
    atomic_write_text(out / "calibration.json", json.dumps(report, indent=2) + "\n")
    if verbose:
        print(f"{len(q)} postures, tracker frame estimated, {report['n_parameters']} parameters: RMS {rms:.4g} mm "
              f"(nominal {report['rms_nominal_mm']:.4g} mm), max {report['max_mm']:.4g} mm")
        print(f"wrote {out / 'robot.yaml'} and {out / 'calibration.json'}")
    return DatasetCalibration(True, rep["message"], eps, rms, report["max_mm"], len(q), report["n_parameters"],
                              out / "robot.yaml", out / "calibration.json")
