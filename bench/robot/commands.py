"""The arm-calibration commands of the ``bench`` CLI: ``bench calibrate-robot`` and ``bench check-robot``.

Kept out of ``bench/cli.py`` (which only registers them) so that the robot commands evolve in one place.
"""

from __future__ import annotations

COMMANDS = ("calibrate-robot",)


def add_parsers(sub) -> None:
    """Register ``calibrate-robot`` on the ``bench`` sub-parser collection ``sub``."""
    cr = sub.add_parser("calibrate-robot", help="identify the arm's geometric errors from tracker points "
                                                "(a dataset's tracker.csv)")
    cr.add_argument("dataset", help="dataset folder with tracker.csv (points in the base frame) and robot.yaml")
    cr.add_argument("--out", required=True, help="folder for robot.yaml (calibrated) and calibration.json")
    cr.add_argument("--robot", default=None, help="nominal DH robot file (default: the dataset's robot.yaml, else "
                                                  "models/ta40.yaml)")
    cr.add_argument("--sigma-mm", type=float, default=0.05,
                    help="standard deviation of a tracker coordinate, mm (weights, covariance; default 0.05)")


def run(args) -> int:
    """Execute a command registered by :func:`add_parsers`; returns the exit status."""
    from bench.robot.calibrate_dataset import calibrate_robot_dataset

    res = calibrate_robot_dataset(args.dataset, args.out, args.robot, args.sigma_mm, verbose=True)
    return 0 if res.success else 1
