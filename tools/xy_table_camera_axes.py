"""The x-y table's errors scored in the reference camera's axes instead of the table's (issue 12, a probe of the
thesis's underwater z; docs/realistic_imaging.md section 3.6, item 4).

    .venv/bin/python tools/xy_table_camera_axes.py SWEEP_DIR [--method lms]

The ``xy_table`` kind scores each combination's estimated camera position in the table's axes: the estimate, found
in the reference camera's axes, turned by the searched mount rotation ``R0`` (Eq. 197), against the table's true
motion. Had a scorer compared the estimate *without* that turn against the table's motion (Table 10's columns), each
error would carry ``(R0^T - I)`` times the camera's motion: with ``theta_y0`` 7.5 deg about 0.13 x the x motion in z.
This tool recomputes every finished run's per-combination errors that way (``R0^T est - true``, ``R0`` from the
run's ``theta_*0_deg`` metrics, evaluator side) and prints, per intraocular distance, the median over the seeds of
the RMS over the combinations per axis, beside the kind's own (table axes).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def errors(run: Path, method: str) -> dict:
    """``{d_mm: (rms in table axes (3,), rms in camera axes (3,))}`` of one run's combinations of ``method``."""
    from bench.vision.handeye import mount_rotation

    m = json.loads((run / "result.json").read_text())["metrics"]
    if "theta_y0_deg" not in m:
        raise SystemExit(f"{run}: no searched mount rotation in result.json (pipeline.mount_bias was not 'estimated')")
    deg = np.pi / 180
    R0 = mount_rotation(*(m[f"theta_{a}0_deg"] * deg for a in "xyz"))  # Eq. 197
    per: dict = {}
    with open(run / "combinations.csv", newline="") as f:
        for row in csv.DictReader(f):
            if row["method"] != method or row["success"] != "1":
                continue
            est = np.array([float(row[f"est_{a}_mm"]) for a in "xyz"])
            true = np.array([float(row[f"true_{a}_mm"]) for a in "xyz"])
            per.setdefault(int(round(float(row["d_mm"]))), []).append((est - true, R0.T @ est - true))
    return {d: tuple(np.sqrt(np.mean(np.array([e[k] for e in v]) ** 2, axis=0)) for k in (0, 1))
            for d, v in per.items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sweep", type=Path, help="a bench sweep folder of an xy_table scenario")
    ap.add_argument("--method", default="lms", help="the estimator (combinations.csv's method; default lms)")
    args = ap.parse_args(argv)
    runs = sorted(p for p in (args.sweep / "runs").glob("*") if (p / "combinations.csv").is_file())
    if not runs:
        raise SystemExit(f"{args.sweep}: no finished x-y table runs (runs/*/combinations.csv)")
    acc: dict = {}
    for run in runs:
        for d, pair in errors(run, args.method).items():
            acc.setdefault(d, []).append(pair)
    if not acc:
        raise SystemExit(f"{args.sweep}: no successful combinations of method {args.method!r}")
    print(f"{len(runs)} runs, method {args.method}: median over the seeds of the RMS error (mm) x / y / z")
    print("d_o (mm) | table axes (as scored) | camera axes (R0 not applied)")
    for d in sorted(acc):
        t, c = (np.median([p[k] for p in acc[d]], axis=0) for k in (0, 1))
        print(f"{d:8d} | {' / '.join(f'{v:.1f}' for v in t):>22} | {' / '.join(f'{v:.1f}' for v in c)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
