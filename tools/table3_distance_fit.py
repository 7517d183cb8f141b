"""Fit the Table 3 rig distance to the spread of the seven single-image calibrations, then read χ there.

    python tools/table3_distance_fit.py 750=SWEEP 800=SWEEP[,SWEEP] 900=SWEEP ... [--stats alpha_px,beta_px]

Each argument is a rig distance (mm) and the ``camera_calibration_webcam`` sweep(s) run at it (``bench sweep
scenarios/camera_calibration_webcam.yaml --set rig.distance_mm=D ...``). Per distance: the medians over the seeds of
each statistic's std over the seven pictures (ddof 1, as Table 3's own spread is computed here) and of χ. Per
statistic a power law in the distance is fitted to those medians (least squares in logarithms); the fitted distance
minimises the sum of squared log ratios of the power laws to Table 3's spreads (taken from the runs' ``table3``
tables, the thesis's columns), on a grid from 600 to 1200 mm; a 90 % interval from a bootstrap over each distance's
seeds. χ at the fitted distance is read from the same kind of power law through χ's medians: a prediction, since χ
is not fitted. docs/realistic_imaging.md (3.1) explains the protocol.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

STATS = ("alpha_px", "beta_px", "u0_px", "v0_px")
GRID_MM = np.linspace(600.0, 1200.0, 2001)


def seed_rows(sweeps) -> tuple[list, dict]:
    """Per finished run ``{stat: std over the seven pictures, "chi": χ}``, and Table 3's spreads."""
    from bench.scenario.sweep import read_runs

    rows, thesis = [], {}
    for sweep in sweeps:
        for r in read_runs(sweep):
            if not r["result_path"]:
                continue
            t = json.loads(Path(r["result_path"]).read_text()).get("tables", {}).get("table3")
            if t is None:
                raise ValueError(f"{sweep}: its runs have no Table 3 table (not a camera_calibration_webcam sweep)")
            rows.append({**{k: float(np.std(t[k][:7], ddof=1)) for k in STATS}, "chi": float(t["chi_px"][7])})
            thesis = {k: float(np.std(t[f"thesis_{k}"][:7], ddof=1)) for k in STATS}
    return rows, thesis


def power_law(data: dict, key: str) -> np.ndarray:
    """``[exponent, log factor]`` of ``median(key) = factor * distance^exponent`` through the distances' medians."""
    dists = sorted(data)
    return np.polyfit(np.log(dists), np.log([np.median([r[key] for r in data[d]]) for d in dists]), 1)


def fit_distance(data: dict, thesis: dict, stats) -> float:
    """The distance (mm) whose power-law spreads best match Table 3's (least squares in logarithms)."""
    cost = sum((np.polyval(power_law(data, k), np.log(GRID_MM)) - np.log(thesis[k])) ** 2 for k in stats)
    return float(GRID_MM[np.argmin(cost)])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sweeps", nargs="+", metavar="D=SWEEP[,SWEEP]")
    ap.add_argument("--stats", default="alpha_px,beta_px", help=f"spreads to fit, of {', '.join(STATS)}")
    ap.add_argument("--bootstrap", type=int, default=2000, help="resamples for the interval (default 2000)")
    args = ap.parse_args(argv)
    if args.bootstrap < 1:
        ap.error(f"--bootstrap: expected at least 1 resample, got {args.bootstrap}")
    stats = args.stats.split(",")
    if unknown := sorted(set(stats) - set(STATS)):
        ap.error(f"--stats: unknown {unknown}; expected some of {', '.join(STATS)}")
    data, thesis = {}, {}
    for arg in args.sweeps:
        dist, _, folders = arg.partition("=")
        try:
            dist = float(dist)
        except ValueError:
            ap.error(f"{arg}: expected DISTANCE_MM=SWEEP[,SWEEP]")
        if not np.isfinite(dist) or dist <= 0:
            ap.error(f"{arg}: the distance must be a positive number of mm")
        if dist in data:
            ap.error(f"{arg}: {dist:g} mm given twice (give its sweeps as {dist:g}=SWEEP,SWEEP)")
        try:
            rows, th = seed_rows([Path(f) for f in folders.split(",")])
        except ValueError as exc:
            ap.error(str(exc))
        data[dist] = rows
        if not rows:
            ap.error(f"{arg}: no finished run")
        thesis = thesis or th
    if len(data) < 2:
        ap.error("at least two distances are needed for a fit")
    print("Table 3's spreads: " + ", ".join(f"{k} {v:.2f}" for k, v in thesis.items()))
    for dist in sorted(data):
        med = {k: np.median([r[k] for r in data[dist]]) for k in (*STATS, "chi")}
        band = sum(0.33 <= r["chi"] <= 0.58 for r in data[dist])
        print(f"{dist:6.0f} mm: {len(data[dist])} runs; " + ", ".join(f"{k} {med[k]:.2f}" for k in STATS)
              + f"; chi {med['chi']:.3f} ({band} in 0.33-0.58)")
    print("power-law exponents: " + ", ".join(f"{k} {power_law(data, k)[0]:.2f}" for k in stats))
    best = fit_distance(data, thesis, stats)
    rng = np.random.default_rng(0)
    boot = [fit_distance({d: [rows[i] for i in rng.integers(0, len(rows), len(rows))] for d, rows in data.items()},
                         thesis, stats) for _ in range(args.bootstrap)]
    lo, hi = np.percentile(boot, [5, 95])
    chi = power_law(data, "chi")
    print(f"fitted to {', '.join(stats)}: {best:.0f} mm, 90 % bootstrap [{lo:.0f}, {hi:.0f}]; "
          f"chi there (power law through the medians) {np.exp(np.polyval(chi, np.log(best))):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
