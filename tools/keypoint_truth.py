"""EVALUATOR SIDE: how far SIFT's and the aligned keypoints of an in-situ run lie from the truth.

    python tools/keypoint_truth.py SWEEP RUN_ID [SCENARIO]

For one finished run of a ``bench sweep`` of an ``in_situ`` scenario (default ``scenarios/ta40_envelope.yaml``; the
run's own parameters from ``sweep.sqlite``), in every region: SIFT in the reference view and in each surrounding and
locate view, matched as the pipeline matches them, then aligned (:func:`bench.vision.patch_align.align_view`). The
truth of a match is where the reference keypoint's ray (the true lens, flat port and pose) meets the panel's true
surfaces (:class:`bench.scenario.scene_points.SceneRays`), projected through the true optics into the view: the
error of a view's keypoint is against the surface point its reference keypoint images, which is what every view of
a map point must agree on. Prints, over the matches whose SIFT error is below 1.5 px (the others are wrong matches,
which no alignment makes right): the median and RMS error of SIFT's keypoints and of the keypoints the pipeline
then uses (aligned where the alignment was accepted, SIFT's elsewhere), the share aligned, and how many of the
keypoints SIFT placed within 0.25 px the alignment moved beyond 0.5 px - over every view, the surrounding (survey)
views and the locate views.
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


def errors(sweep: Path, run_id: str, scenario: Path) -> dict:
    """Per accepted match: ``sift`` and ``used`` errors (px), ``aligned`` (bool), ``locate`` (bool: a locate view's,
    else a surrounding view's) - every region's views pooled."""
    from bench.camera.flatport import trace_rays
    from bench.dataset import load_dataset
    from bench.geometry.transforms import invert, transform_points
    from bench.robot.model import load_robot
    from bench.scenario.bounds import true_projector
    from bench.scenario.in_situ import _true_camera_poses, _true_optics, imaging, replay_panel
    from bench.scenario.runner import load_scenario
    from bench.scenario.scene_points import SceneRays
    from bench.scenario.sweep import read_runs
    from bench.vision.features import detect_sift
    from bench.vision.insitu import MapConfig, view_matches
    from bench.vision.patch_align import align_view, grey, unique_matches

    row = next((r for r in read_runs(sweep) if r["run_id"] == run_id), None)
    if row is None:
        raise SystemExit(f"{sweep}: no finished run {run_id!r}")
    params, seed = row["params"], int(row["seed"])
    cfg = load_scenario(scenario, seed=seed, overrides=[f"{k}={json.dumps(v)}" for k, v in params.items()])
    run = sweep / "runs" / run_id
    truth = yaml.safe_load((run / "dataset" / "truth" / "truth.yaml").read_text())
    lens, port, _ = _true_optics(truth)
    project = true_projector(lens, port, imaging(cfg))
    poses = _true_camera_poses(load_robot(Path(cfg["_file"]).parent / cfg["robot"]), truth)
    surface = SceneRays(replay_panel(cfg), np.array(truth["T_world_panel"], float))
    ds = load_dataset(run / "dataset")
    out = {"sift": [], "used": [], "aligned": [], "locate": []}
    for region in dict.fromkeys(v.region for v in ds.views if v.role == "reference"):
        ref = next(v for v in ds.views if v.role == "reference" and v.region == region)
        img = ref.image()
        f_ref, g_ref = detect_sift(img, channel_order="rgb"), grey(img)
        for v in (v for v in ds.views if v.role in ("surround", "locate") and v.region == region):
            img = v.image()
            f = detect_sift(img, channel_order="rgb")
            m = view_matches(f_ref, f, MapConfig())
            if len(m) < 4:
                continue
            uv, al = align_view(g_ref, grey(img), f_ref.uv, f.uv, m.i1, m.i2, m.distance)
            keep = unique_matches(m.i2, m.distance)  # the matches align_view kept, in its order
            dirs = lens.unproject(f_ref.uv[m.i1[keep]])
            origins = np.zeros_like(dirs)
            if port is not None:
                origins, dirs, _ = trace_rays(dirs, port)
            T = poses[ref.name]
            P = surface.first_hits(origins @ T[:3, :3].T + T[:3, 3], dirs @ T[:3, :3].T)
            hit = np.all(np.isfinite(P), axis=1)
            true = project(transform_points(invert(poses[v.name]), P[hit]))
            out["sift"].append(np.linalg.norm(f.uv[m.i2[keep]][hit] - true, axis=1))
            out["used"].append(np.linalg.norm(al.uv[hit] - true, axis=1))
            out["aligned"].append(al.ok[hit])
            out["locate"].append(np.full(int(hit.sum()), v.role == "locate"))
    return {k: np.concatenate(v) if v else np.empty(0) for k, v in out.items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sweep", type=Path)
    ap.add_argument("run_id")
    ap.add_argument("scenario", type=Path, nargs="?", default=ROOT / "scenarios" / "ta40_envelope.yaml")
    a = ap.parse_args(argv)
    e = errors(a.sweep, a.run_id, a.scenario)
    for role, sel in (("survey and locate views", np.ones(len(e["sift"]), bool)), ("survey views", ~e["locate"]),
                      ("locate views", e["locate"])):
        s = sel & (e["sift"] < 1.5)  # SIFT's inliers; beyond, a wrong match
        if not s.any():
            print(f"{a.run_id}, {role}: no match within 1.5 px of the truth")
            continue
        sift, used, aligned = e["sift"][s], e["used"][s], e["aligned"][s]
        print(f"{a.run_id}, {role}: {s.sum()} matches within 1.5 px of the truth (of {sel.sum()}), "
              f"{aligned.mean() * 100:.0f} % aligned")
        for name, x in (("SIFT", sift), ("used (aligned where accepted)", used)):
            print(f"  {name}: median {np.median(x):.3f} px, RMS {np.sqrt(np.mean(x ** 2)):.3f} px, beyond 0.5 px "
                  f"{np.mean(x > 0.5) * 100:.1f} %")
        good = sift < 0.25
        print(f"  of the {good.sum()} SIFT placed within 0.25 px, moved beyond 0.5 px: "
              f"{np.mean(aligned[good] & (used[good] > 0.5)) * 100:.2f} %")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
