"""The arm-calibration commands of the ``bench`` CLI: ``bench calibrate-robot`` and ``bench check-robot``.

Kept out of ``bench/cli.py`` (which only registers them) so that the robot commands evolve in one place.

* ``bench calibrate-robot DATASET --out DIR`` - a dataset's tracker campaign on its DH robot file (default the TA-40).
* ``bench calibrate-robot --urdf FILE --base-link L --tip-link L --measurements CSV --points x1,y1,z1 [...] --out DIR``
  - any serial arm from its URDF and marker measurements (:mod:`bench.robot.marker_calibration`).
* ``bench check-robot --robot DIR/robot.yaml --measurements CSV [--points ...] --out DIR2`` - held-out score.
"""

from __future__ import annotations

import json
from pathlib import Path

from bench.errors import BenchError


def add_parsers(sub) -> None:
    """Register ``calibrate-robot`` and ``check-robot`` on the ``bench`` sub-parser collection ``sub``."""
    cr = sub.add_parser("calibrate-robot", help="identify an arm's geometric errors: a dataset's tracker.csv (DH "
                                                "robot file) or any URDF arm from marker measurements")
    cr.add_argument("dataset", nargs="?", default=None,
                    help="dataset folder with tracker.csv (points in the base frame) and robot.yaml; omit with --urdf")
    cr.add_argument("--out", required=True, help="folder for robot.yaml (calibrated) and calibration.json")
    cr.add_argument("--force", action="store_true", help="replace a previous output of calibrate-robot at --out "
                                                         "(never a folder that bench did not write)")
    cr.add_argument("--robot", default=None, help="dataset mode: nominal DH robot file (default: the dataset's "
                                                  "robot.yaml, else models/ta40.yaml)")
    cr.add_argument("--tracker-frame", choices=("base", "estimate"), default="base",
                    help="dataset mode: tracker.csv is in the robot base frame (default, found from the arcs) or in "
                         "the tracker's own frame, whose pose is then estimated")
    cr.add_argument("--sigma-mm", type=float, default=None,
                    help="standard deviation of a measured coordinate, mm (dataset mode default 0.05; URDF mode "
                         "default: estimated from the residuals)")
    g = cr.add_argument_group("any arm from its URDF")
    g.add_argument("--urdf", default=None, help="URDF file (kinematics only; meshes are not read)")
    g.add_argument("--base-link", default=None, help="link the chain starts from (the robot base)")
    g.add_argument("--tip-link", default=None, help="link carrying the markers")
    g.add_argument("--measurements", default=None, help="CSV: one row per posture, joint columns named as the "
                                                        "URDF's joints, marker columns; other columns ignored")
    g.add_argument("--points", action="append", default=[], metavar="X,Y,Z",
                   help="the three columns of one marker on the tip link (repeatable: several markers)")
    g.add_argument("--units", choices=("m", "mm"), default="m", help="marker coordinates and prismatic readings")
    g.add_argument("--joint-units", choices=("rad", "deg"), default="rad", help="revolute readings")
    g.add_argument("--model", choices=("reduced", "prior"), default="prior",
                   help="reduced: identifiable errors only (hard elimination); prior: all errors with a 2 mm / "
                        "1 deg Gaussian prior (default)")
    g.add_argument("--weights", choices=("auto", "none"), default="none",
                   help="auto: per-posture weights from a marker_std_mm column; none: equal weights (default)")
    g.add_argument("--compliance", choices=("auto", "off"), default="auto",
                   help="auto: also estimate the joints' compliance under gravity when the URDF has <inertial> "
                        "masses (base z-up); off: geometry only")
    g.add_argument("--refuse-outliers", action="store_true", help="drop (and name) outlier postures and refit")
    ck = sub.add_parser("check-robot", help="score a URDF calibration on held-out postures (everything frozen)")
    ck.add_argument("--robot", required=True, help="robot.yaml written by calibrate-robot --urdf")
    ck.add_argument("--measurements", required=True, help="CSV of held-out postures (as for calibrate-robot)")
    ck.add_argument("--points", action="append", default=None, metavar="X,Y,Z",
                    help="marker columns (default: the calibration's)")
    ck.add_argument("--units", choices=("m", "mm"), default=None, help="default: the calibration's")
    ck.add_argument("--joint-units", choices=("rad", "deg"), default=None, help="default: the calibration's")
    ck.add_argument("--out", required=True, help="folder for check.json")
    ck.add_argument("--force", action="store_true", help="replace a previous output of check-robot at --out")


def _calibrate_urdf(args) -> int:
    from bench.fileio import prepare_output_dir
    from bench.robot.marker_calibration import identify, parse_points, read_measurements, write_calibration
    from bench.robot.urdf import load_urdf_chain

    missing = [o for o, v in (("--base-link", args.base_link), ("--tip-link", args.tip_link),
                              ("--measurements", args.measurements)) if v is None]
    if missing:
        raise BenchError(f"calibrate-robot --urdf: {', '.join(missing)} required")
    if args.sigma_mm is not None and not 0 < args.sigma_mm <= 50:
        raise BenchError(f"--sigma-mm: expected a standard deviation in (0, 50] mm, got {args.sigma_mm}")
    markers = parse_points(args.points)
    chain = load_urdf_chain(args.urdf, args.base_link, args.tip_link)
    meas = read_measurements(args.measurements, chain, markers, args.units, args.joint_units)
    out = prepare_output_dir(args.out, "calibrate-robot")
    cal = identify(chain, meas, args.model, args.weights, None if args.sigma_mm is None else args.sigma_mm * 1e-3,
                   args.refuse_outliers, compliance=args.compliance == "auto" and chain.body_mass is not None)
    robot_path, report_path = write_calibration(out, cal, args.urdf, args.units, args.joint_units,
                                                args.measurements)
    rep = json.loads(report_path.read_text())
    print(f"{chain.name}: {chain.n} joints ({', '.join(chain.joint_names)}), {len(markers)} marker(s), "
          f"{rep['n_postures']} postures; {rep['n_parameters']} parameters ({rep['n_error_parameters']} errors, "
          f"model {args.model})")
    print(f"RMS {rep['rms_mm']:.4g} mm (nominal {rep['rms_nominal_mm']:.4g} mm), max {rep['max_mm']:.4g} mm")
    if cal.compliance:
        print("compliance under gravity (rad/N m): " + ", ".join(f"{n} {c:.3g}" for n, c in cal.compliance.items()))
    if cal.outliers:  # in the final fit (after any refusal)
        print(f"outliers: {', '.join(cal.outliers)} (kept; --refuse-outliers drops them)")
    if cal.refused:
        print(f"refused: {', '.join(cal.refused)}")
    print(f"wrote {robot_path} and {report_path}")
    return 0


def _check(args) -> int:
    from bench.fileio import atomic_write_text, prepare_output_dir
    from bench.robot.marker_calibration import check

    rep = check(args.robot, args.measurements, args.points, args.units, args.joint_units)
    out = prepare_output_dir(args.out, "check-robot")
    atomic_write_text(Path(out) / "check.json", json.dumps(rep, indent=2) + "\n")
    print(f"{rep['n_postures']} postures, {rep['n_markers']} marker(s): RMS {rep['rms_mm']:.4g} mm, max "
          f"{rep['max_mm']:.4g} mm; wrote {Path(out) / 'check.json'}")
    return 0


def run(args) -> int:
    """Execute a command registered by :func:`add_parsers`; returns the exit status. The output folder is checked
    before any work and marked as this command's when it ends (:func:`bench.fileio.writing_output_dir`)."""
    from bench.fileio import writing_output_dir

    with writing_output_dir(args.out, args.command, force=args.force):
        return _run(args)


def _run(args) -> int:
    if args.command == "check-robot":
        return _check(args)
    if args.urdf is not None:
        if args.dataset is not None:
            raise BenchError("calibrate-robot: give a DATASET or --urdf, not both")
        return _calibrate_urdf(args)
    if args.dataset is None:
        raise BenchError("calibrate-robot: give a DATASET folder (tracker.csv) or --urdf FILE with --measurements")
    urdf_only = [o for o, v in (("--base-link", args.base_link), ("--tip-link", args.tip_link),
                                ("--measurements", args.measurements), ("--points", args.points)) if v]
    if urdf_only:
        raise BenchError(f"calibrate-robot DATASET: {', '.join(urdf_only)} belong to the --urdf mode (the dataset "
                         "mode reads tracker.csv and a DH robot file)")
    from bench.robot.calibrate_dataset import calibrate_robot_dataset

    sigma = 0.05 if args.sigma_mm is None else args.sigma_mm
    res = calibrate_robot_dataset(args.dataset, args.out, args.robot, sigma, verbose=True,
                                  tracker_frame=args.tracker_frame)
    return 0 if res.success else 1
