"""Probe the integrity with small joint offsets: is any localisation silently wrong? (issue 13; docs/integrity.md)

    .venv/bin/python tools/joint_offset_probe.py DATASET --lab CALIBRATED_DIR [--offsets 0.05 0.2] [--seed 1]
                                                 [--json OUT.json]

``bench faults``' ``joint_offset`` (0.5 deg) is refused at once; the dangerous offsets are those small enough to
pass the consistency tests yet large enough to move the base by millimetres. For each of the two locate views and
the middle survey view, each joint and each offset (deg), the dataset's ``joints.csv`` is changed in a scratch copy,
the dataset is localised as the in-situ kind does (``refine: joints`` under ``CALIBRATED_DIR/calibration_priors.yaml``,
with its ``camera.yaml`` and ``robot.yaml``: ``bench faults`` writes them to ``OUT/calibrated``) and scored against
``truth/`` (:func:`bench.scenario.faults.score`, :func:`~bench.scenario.faults.is_silent`). Prints one line per
case and the number of silent failures; exits 1 if there is any.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.dataset import load_dataset  # noqa: E402
from bench.scenario import faults as F  # noqa: E402
from bench.vision.locate_dataset import locate_dataset  # noqa: E402


def probe(dataset: Path, lab: Path, offsets, seed: int = 0, verbose: bool = True, keypoints: str = "sift") -> list:
    """One row per (view, joint, offset): the true errors, the integrity, the protection levels, ``silent``
    (``keypoints``: as :func:`~bench.vision.locate_dataset.locate_dataset`'s)."""
    roles = F._site_views(load_dataset(dataset))
    header, rows0 = F._joints(dataset)
    views = [*roles["locate"][:2], roles["surround"][(len(roles["surround"]) - 1) // 2]]
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp) / "dataset"
        shutil.copytree(dataset, work)
        for view in views:
            for j in range(1, len(header)):  # joint 6 too: it does not move a camera on link 5 (a control)
                for dq in offsets:
                    F._write_joints(work, header, rows0)  # the readings as logged, then the one offset
                    F._offset_joint(work, view, j, dq)
                    res, rep = locate_dataset(work, None, verbose=False, camera_path=lab / "camera.yaml",
                                              robot_path=lab / "robot.yaml", seed=seed, refine="joints",
                                              priors_path=lab / "calibration_priors.yaml", keypoints=keypoints)
                    row = {"case": f"{view} {header[j]} {dq:+g} deg", **F.score(dataset, rep, res.T_world_base),
                           "integrity": rep["integrity"],
                           "protection_radius_mm": rep["protection_radius_mm"] or float("inf"),
                           "protection_angle_deg": rep["protection_angle_deg"] or float("inf"),
                           "reasons": rep["integrity_reasons"]}
                    row["silent"] = F.is_silent(row)
                    out.append(row)
                    if verbose:
                        print(f"{row['case']:<28} {row['pos_err_mm']:8.2f} mm {row['rot_err_deg']:7.4f} deg "
                              f"{row['integrity']:<8} PR {row['protection_radius_mm']:6.2f} mm"
                              f"{'  SILENT' if row['silent'] else ''}", flush=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dataset", type=Path, help="a rendered in-situ dataset (with truth/)")
    ap.add_argument("--lab", type=Path, required=True, help="folder with the lab's camera.yaml, robot.yaml and "
                                                            "calibration_priors.yaml")
    ap.add_argument("--offsets", type=float, nargs="+", default=[0.05, 0.2], help="joint offsets (deg)")
    ap.add_argument("--seed", type=int, default=0, help="RANSAC seed")
    ap.add_argument("--json", type=Path, default=None, help="write the rows here")
    ap.add_argument("--keypoints", choices=("sift", "aligned"), default="sift", help="as bench locate --keypoints")
    args = ap.parse_args(argv)
    for p in (args.dataset / "truth" / "truth.yaml", *(args.lab / f for f in ("camera.yaml", "robot.yaml",
                                                                               "calibration_priors.yaml"))):
        if not p.is_file():
            print(f"error: {p}: missing", file=sys.stderr)
            return 2
    rows = probe(args.dataset, args.lab, args.offsets, args.seed, keypoints=args.keypoints)
    n = sum(r["silent"] for r in rows)
    print(f"{n} silent failures in {len(rows)} cases; worst error among ok: "
          f"{max([r['pos_err_mm'] for r in rows if r['integrity'] == 'ok'] or [np.nan]):.2f} mm")
    if args.json:
        safe = [{k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in r.items()} for r in rows]
        args.json.write_text(json.dumps(safe, indent=1) + "\n")
    return 1 if n else 0


if __name__ == "__main__":
    raise SystemExit(main())
