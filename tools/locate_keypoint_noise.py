"""Are the locate views' keypoints noisier than the survey's? Measured on the panel's true surface (issue 11).

    .venv/bin/python tools/locate_keypoint_noise.py SCENARIO RUN [RUN ...] [--set KEY=VALUE ...]

EVALUATOR SIDE (it reads ``truth/``). Each RUN is a finished ``in_situ`` run folder (``dataset/``, ``calibrated/``,
``result.json``) of SCENARIO with the same ``--set`` (e.g. ``camera.preset=air_webcam``; the seed is the run's). The
dataset is localised again with the scenario's estimator and the run's lab files; for every map point the final
solve used, the reference keypoint's ray (true lens, port, pose) is cast onto the panel's true surfaces (the panel
drawn again from the seed: :func:`bench.scenario.in_situ.replay_panel`), and that surface point is projected through
the true optics into every view that observed the point: detected minus true is each observation's own error, with
nothing fitted to hide any of it. Per run:

* ``survey``: the robust sigma (1.4826 MAD, per axis) of the survey views' errors about each track's survey mean,
  corrected for the mean's degrees of freedom - the noise the map's views share no part of;
* ``locate``: the robust sigma of the locate views' errors about the same survey mean, less the mean's own noise -
  what a locate view adds when it sees the point from the other parking;
* beside them the run's ``keypoint_sigma_px`` and ``keypoint_sigma_locate_px`` (the bound's, from epipolar
  distances), when the run has them.

docs/bounds.md ("The locate views' own keypoint noise") quotes its output.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def robust_sd(a) -> float:
    a = np.asarray(a, float).ravel()
    return float(1.4826 * np.median(np.abs(a - np.median(a))))


def measure(cfg, run: Path) -> dict:
    """One run's survey and locate noise on the true surface (module docstring)."""
    from bench.camera.flatport import trace_rays
    from bench.camera.model import distort, to_pixels
    from bench.geometry.transforms import invert, transform_points
    from bench.scenario.bounds import true_projector
    from bench.scenario.in_situ import _true_camera_poses, _true_optics, imaging, replay_panel
    from bench.scenario.scene_points import SceneRays
    from bench.vision.insitu import MapConfig
    from bench.vision.locate_dataset import locate_dataset

    result = json.loads((run / "result.json").read_text())
    truth = yaml.safe_load((run / "dataset" / "truth" / "truth.yaml").read_text())
    cal, p, det = run / "calibrated", cfg["pipeline"], {}
    priors = cal / "calibration_priors.yaml"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res, _ = locate_dataset(run / "dataset", None, method=p["method"], seed=result["seed"], config=MapConfig(),
                                verbose=False, camera_path=cal / "camera.yaml", robot_path=cal / "robot.yaml",
                                refine=p["refine"], ransac=dict(iterations=p["ransac_iterations"],
                                                                d_r=p["d_r_mm"] * 1e-3, r_lim=p["r_lim"]),
                                priors_path=priors if priors.is_file() and p["refine"] == "joints" else None,
                                details=det)
    if not res.success or res.used is None:
        return {"run": run.name, "error": f"no localisation ({res.message})"}
    lens, port, _ = _true_optics(truth)
    project = true_projector(lens, port, imaging(cfg))
    poses = _true_camera_poses(det["robot"], truth)
    obs, kmap, cam = det["observations"], det["map"], det["camera"]
    role = {n: truth["views"][n]["role"] for n in obs}
    ref = next(n for n in obs if role[n] == "reference")
    survey = [n for n in obs if role[n] == "surround"]
    locate = [n for n in obs if role[n] == "locate"][:2]
    idx, x_a, x_b = res.used

    def pixels(x):  # a normalized keypoint back to the pixel it was detected at (the calibrated camera's round trip)
        return to_pixels(distort(np.atleast_2d(x), cam.dist), cam.K)

    dirs = lens.unproject(pixels(kmap.x_ref[idx]))
    origins = np.zeros_like(dirs)
    if port is not None:
        origins, dirs, _ = trace_rays(dirs, port)
    T = poses[ref]
    surface = SceneRays(replay_panel(cfg), np.array(truth["T_world_panel"], float))
    P = surface.first_hits(origins @ T[:3, :3].T + T[:3, 3], dirs @ T[:3, :3].T)

    def error(name, x, point):
        return (pixels(x) - project(transform_points(invert(poses[name]), point[None])))[0]

    dev_survey, dev_locate, n_survey = [], [], []
    for j in np.flatnonzero(np.all(np.isfinite(P), axis=1)):
        views, xs = kmap.observations[idx[j]]
        e_s = np.array([error(survey[k], x, P[j]) for k, x in zip(views, np.asarray(xs).reshape(-1, 2), strict=True)])
        if len(e_s) < 2:
            continue
        mean = e_s.mean(axis=0)
        dev_survey.append(e_s - mean)
        n_survey.append(len(e_s))
        dev_locate += [error(locate[0], x_a[j], P[j]) - mean, error(locate[1], x_b[j], P[j]) - mean]
    n = float(np.mean(n_survey))
    s_survey = robust_sd(np.concatenate(dev_survey)) * np.sqrt(n / (n - 1))
    s_locate = np.sqrt(max(robust_sd(dev_locate) ** 2 - s_survey**2 / n, 0.0))
    m = result["metrics"]
    return {"run": run.name, "seed": result["seed"], "points": len(n_survey), "survey_px": float(s_survey),
            "locate_px": float(s_locate), "ratio": float(s_locate / s_survey),
            "bound_survey_px": m.get("keypoint_sigma_px"), "bound_locate_px": m.get("keypoint_sigma_locate_px")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenario")
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args(argv)
    from bench.errors import BenchError
    from bench.scenario.runner import load_scenario

    rows = []
    print("run               seed points  survey  locate  ratio | bound's survey  locate")
    for run in args.runs:
        try:
            result = json.loads((run / "result.json").read_text())
            row = measure(load_scenario(args.scenario, result["seed"], args.overrides), run)
        except (OSError, KeyError, json.JSONDecodeError, BenchError) as exc:
            row = {"run": run.name, "error": f"{type(exc).__name__}: {exc}"}
        if "error" in row:
            print(f"{row['run']}: {row['error']}")
            continue
        rows.append(row)
        b = "  ".join("   -  " if row[k] is None else f"{row[k]:.3f}" for k in ("bound_survey_px", "bound_locate_px"))
        print(f"{row['run']:<17} {row['seed']:>4} {row['points']:>6}  {row['survey_px']:.3f}   {row['locate_px']:.3f}"
              f"   {row['ratio']:.2f} | {b}", flush=True)
    if rows:
        med = {k: float(np.median([r[k] for r in rows])) for k in ("survey_px", "locate_px", "ratio")}
        print(f"median over {len(rows)} runs: survey {med['survey_px']:.3f} px, locate {med['locate_px']:.3f} px, "
              f"ratio {med['ratio']:.2f}")
    return 0 if rows else 1


if __name__ == "__main__":
    raise SystemExit(main())
