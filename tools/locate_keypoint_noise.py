"""Are the locate views' keypoints noisier than the survey's? Measured on the panel's true surface (issue 11).

    .venv/bin/python tools/locate_keypoint_noise.py SCENARIO RUN [RUN ...] [--set KEY=VALUE ...]

EVALUATOR SIDE (it reads ``truth/``). Each RUN is a finished ``in_situ`` run folder (``dataset/``, ``calibrated/``,
``result.json``) of SCENARIO with the same ``--set`` (e.g. ``camera.preset=air_webcam``; the seed is the run's). The
dataset is localised again with the scenario's estimator and the run's lab files (``relocate_sweep.locate_run``); for
every map point the final solve used, the reference keypoint's ray (true lens, port, pose) is cast onto the panel's true
surfaces (the panel drawn again from the seed: :func:`bench.scenario.in_situ.replay_panel`), and that surface point is
projected through the true optics into every view that observed the point: detected minus true is each observation's own
error, with nothing fitted to hide any of it. Per run:

* ``survey``: the robust sigma (1.4826 MAD, per axis) of the survey views' errors about each track's survey mean,
  corrected for the mean's degrees of freedom - the noise the map's views share no part of;
* ``locate``: the robust sigma of the locate views' errors about the same survey mean, less the mean's own noise -
  what a locate view adds when it sees the point from the other parking
  (:func:`bench.scenario.in_situ_bound.track_noise_on_surface`, which the ``in_situ`` kind's bound uses too);
* ``F survey``, ``F locate``: how much less each pixel tells than its robust sigma says, sigma of the Fisher
  information of the errors' density (a Gaussian scale mixture fitted to them) over the robust sigma
  (:func:`bench.scenario.in_situ_bound.fisher_factor`; the bound multiplies its sigmas by them);
* beside them the run's ``keypoint_sigma_px`` (the survey's, from epipolar distances) and
  ``keypoint_sigma_locate_px`` (the bound's locate noise), when the run has them.

docs/bounds.md ("The locate views' own keypoint noise") quotes its output.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))


def measure(cfg, run: Path) -> dict:
    """One run's survey and locate noise on the true surface (module docstring)."""
    from relocate_sweep import locate_run

    from bench.scenario.bounds import true_projector
    from bench.scenario.in_situ import _true_camera_poses, _true_optics, imaging, replay_panel
    from bench.scenario.in_situ_bound import track_noise_on_surface, track_pixels
    from bench.scenario.scene_points import SceneRays

    result = json.loads((run / "result.json").read_text())
    truth = yaml.safe_load((run / "dataset" / "truth" / "truth.yaml").read_text())
    det = {}
    res, _ = locate_run(run, result["seed"], cfg["pipeline"], details=det)
    if not res.success or res.used is None:
        return {"run": run.name, "error": f"no localisation ({res.message})"}
    lens, port, _ = _true_optics(truth)
    poses = _true_camera_poses(det["robot"], truth)
    obs = det["observations"]
    role = {n: truth["views"][n]["role"] for n in obs}
    ref = next(n for n in obs if role[n] == "reference")
    survey = [n for n in obs if role[n] == "surround"]
    locate = [n for n in obs if role[n] == "locate"][:2]
    surface = SceneRays(replay_panel(cfg), np.array(truth["T_world_panel"], float))
    tn = track_noise_on_surface(*track_pixels(det["map"], res.used, obs, ref, survey, locate), poses[ref],
                                np.stack([poses[n] for n in survey]), np.stack([poses[n] for n in locate]), lens, port,
                                true_projector(lens, port, imaging(cfg)), surface)
    m = result["metrics"]
    return {"run": run.name, "seed": result["seed"], "points": tn["points"], "survey_px": tn["survey_px"],
            "locate_px": tn["locate_px"], "ratio": tn["ratio"], "survey_fisher": tn["survey_fisher"],
            "locate_fisher": tn["locate_fisher"], "bound_survey_px": m.get("keypoint_sigma_px"),
            "bound_locate_px": m.get("keypoint_sigma_locate_px")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenario")
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args(argv)
    from bench.errors import BenchError
    from bench.scenario.runner import load_scenario

    rows = []
    print("run               seed points  survey  locate  ratio  F survey  F locate | bound's survey  locate")
    for run in args.runs:
        try:
            result = json.loads((run / "result.json").read_text())
            row = measure(load_scenario(args.scenario, result["seed"], args.overrides), run)
        except FileNotFoundError as exc:
            row = {"run": str(run), "error": f"not a finished in_situ run ({exc.filename} is missing)"}
        except (OSError, KeyError, json.JSONDecodeError, BenchError) as exc:
            row = {"run": str(run), "error": f"{type(exc).__name__}: {exc}"}
        if "error" in row:
            print(f"{row['run']}: {row['error']}")
            continue
        rows.append(row)
        b = "  ".join("   -  " if row[k] is None else f"{row[k]:.3f}" for k in ("bound_survey_px", "bound_locate_px"))
        print(f"{row['run']:<17} {row['seed']:>4} {row['points']:>6}  {row['survey_px']:.3f}   {row['locate_px']:.3f}"
              f"   {row['ratio']:.2f}   {row['survey_fisher']:.3f}     {row['locate_fisher']:.3f}    | {b}", flush=True)
    if rows:
        keys = ("survey_px", "locate_px", "ratio", "survey_fisher", "locate_fisher")
        med = {k: float(np.median([r[k] for r in rows])) for k in keys}
        print(f"median over {len(rows)} runs: survey {med['survey_px']:.3f} px, locate {med['locate_px']:.3f} px, "
              f"ratio {med['ratio']:.2f}, Fisher factors {med['survey_fisher']:.3f} (survey) "
              f"{med['locate_fisher']:.3f} (locate)")
    return 0 if rows else 1


if __name__ == "__main__":
    raise SystemExit(main())
