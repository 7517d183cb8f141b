"""``make benchmark``: speed and accuracy figures as medians over repeated runs, written to one JSON file.

Speed targets of the kinematics issue (benchmarks, not tests): identification of 100 poses <= 20 ms; FK + Jacobian
of 10 000 configurations <= 50 ms. Accuracy figures come from the full Table 2 scenario run.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.robot.identifiability import closed_form_reduction  # noqa: E402
from bench.robot.identification import identify_iterative, identify_linear  # noqa: E402
from bench.robot.jacobian import identification_jacobian  # noqa: E402
from bench.robot.kinematics import ee_position  # noqa: E402
from bench.robot.model import default_robot_path, load_robot, random_errors  # noqa: E402


def median_time(fn, repeats):
    fn()  # warm-up
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default="runs/benchmark.json")
    ap.add_argument("--repeats", type=int, default=21)
    ap.add_argument("--skip-scenario", action="store_true", help="speed figures only")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    robot = load_robot(default_robot_path())
    red = closed_form_reduction(robot)
    figures: dict[str, float] = {}

    q10k = robot.random_configurations(rng, 10_000)
    figures["fk_jacobian_10000_s"] = median_time(lambda: identification_jacobian(robot, q10k, return_points=True),
                                                 args.repeats)
    figures["fk_10000_s"] = median_time(lambda: ee_position(robot, q10k), args.repeats)
    try:
        import pinocchio as pin
        from bench.judge.pinocchio_arm import build_pinocchio_model

        model, frames = build_pinocchio_model(robot)
        data = model.createData()
        fid = frames["ee_point"]

        def pin_fk():
            for qi in q10k:
                pin.framesForwardKinematics(model, data, qi)
                data.oMf[fid].translation  # noqa: B018

        figures["pinocchio_fk_10000_s"] = median_time(pin_fk, max(3, args.repeats // 4))
        figures["fk_speed_ratio_vs_pinocchio"] = figures["pinocchio_fk_10000_s"] / figures["fk_10000_s"]
    except ImportError:
        pass

    eps = random_errors(rng, robot.n + 1)
    eps[-6:] = 0.0
    q100 = robot.random_configurations(rng, 100)
    pts = ee_position(robot, q100, eps) + rng.normal(scale=5e-5, size=(100, 3))
    figures["identification_100_linear_s"] = median_time(lambda: identify_linear(robot, q100, pts, red, 5e-5),
                                                         args.repeats)
    figures["identification_100_iterative_s"] = median_time(
        lambda: identify_iterative(robot, q100, pts, red, 5e-5), args.repeats)

    if not args.skip_scenario:
        from bench.scenario.runner import run_scenario_file

        with tempfile.TemporaryDirectory() as tmp:
            path = run_scenario_file(ROOT / "scenarios" / "table2_kinematic_identification.yaml", out=tmp,
                                     verbose=False)
            res = json.loads(Path(path).read_text())
        for k in ("max_abs_reduced_error_linear", "heldout_rms_mm_uncalibrated", "heldout_rms_mm_calibrated",
                  "heldout_rms_mm_noise_free_exact", "mc_std_ratio_median", "mc_std_ratio_min", "mc_std_ratio_max",
                  "mc_heldout_rms_mm_median", "heldout_rms_mm_selected_poses_median",
                  "heldout_rms_mm_random_poses_median"):
            figures[f"table2.{k}"] = res["metrics"][k]
        figures["table2.scenario_total_s"] = res["timings_s"]["total"]

    doc = {"figures": figures, "repeats": args.repeats, "machine": {"python": platform.python_version(),
                                                                    "processor": platform.machine(),
                                                                    "numpy": np.__version__},
           "targets": {"fk_jacobian_10000_s": 0.050, "identification_100_iterative_s": 0.020,
                       "table2.max_abs_reduced_error_linear": 1e-9, "table2.heldout_rms_mm_noise_free_exact": 1e-6,
                       "table2.heldout_rms_mm_calibrated": 0.03}}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(doc, indent=2) + "\n")
    print(f"{'figure':<48}{'value':>14}{'target':>12}")
    for k, v in figures.items():
        t = doc["targets"].get(k)
        print(f"{k:<48}{v:>14.6g}{'' if t is None else f'{t:>12.3g}'}")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
