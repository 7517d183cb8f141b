"""Which property of the desk robot scene moves the x-y table's errors? (issue 12, docs/realistic_imaging.md 3.6)

    .venv/bin/python tools/desk_robot_ablation.py [--seeds 1 2 3 4] [--out runs/desk-robot-ablation]

Runs ``scenarios/xy_table_webcam.yaml`` with ``sim.reference_object=robot`` (bound, plots and recording off, renders
not cached) in three variants of :mod:`bench.sim.scenes.desk_robot`, changed through its module constants:

* ``as_built``: the scene as the scenario renders it;
* ``matte``: every material without specular reflection (no highlights);
* ``near_wall``: the wall 0.15 m behind the arm's centre instead of 0.45 m (the depth spread of the view shrinks from
  0.7-1.15 m to 0.7-0.85 m).

Prints per variant the medians over the seeds of LMS + error ratio and quaternion errors (x / y / z, mm) at
d_o = 40 and 100 mm, and writes them to ``OUT/ablation.json``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

VARIANTS = {"as_built": {}, "matte": {"ALUMINIUM": (0.0, 0.1), "PLASTIC": (0.0, 0.3), "PAINT": (0.0, 0.4)},
            "near_wall": {"WALL_Z_M": -0.15}}
CELLS = [(m, d) for m in ("lms_ratio", "quaternion") for d in (40.0, 100.0)]


def cell_errors(result: dict) -> dict:
    rows = result["tables"]["position_error_vs_intraocular"]
    out = {}
    for i, m in enumerate(rows["method"]):
        key = (m, float(rows["d_mm"][i]))
        if key in CELLS:
            out[f"{m}@{key[1]:g}"] = [float(rows[f"err_{a}_mm"][i]) for a in "xyz"]
    return out


def main(argv=None) -> int:
    import bench.sim.scenes.desk_robot as dr
    from bench.scenario.runner import run_scenario_file

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    ap.add_argument("--out", default="runs/desk-robot-ablation")
    a = ap.parse_args(argv)
    saved = {k: getattr(dr, k) for v in VARIANTS.values() for k in v}
    summary = {}
    for name, change in VARIANTS.items():
        for k, v in saved.items():
            setattr(dr, k, change.get(k, v))
        per_seed = []
        for s in a.seeds:
            out = Path(a.out) / name / f"seed{s}"
            path = run_scenario_file(ROOT / "scenarios" / "xy_table_webcam.yaml", out=out, seed=s, quiet=True,
                                     verbose=False, force=True,
                                     overrides=["sim.reference_object=robot", "bound.enabled=false",
                                                "outputs.plots=false", "outputs.rerun=false", "outputs.cache=false"])
            per_seed.append(cell_errors(json.loads(Path(path).read_text())))
        summary[name] = {c: [statistics.median(r[c][i] for r in per_seed) for i in range(3)] for c in per_seed[0]}
        print(name + ": " + "; ".join(f"{c} {' / '.join(f'{v:.2f}' for v in xyz)}" for c, xyz in summary[name].items()))
    for k, v in saved.items():
        setattr(dr, k, v)
    Path(a.out).mkdir(parents=True, exist_ok=True)
    (Path(a.out) / "ablation.json").write_text(json.dumps({"seeds": a.seeds, "medians_mm": summary}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
