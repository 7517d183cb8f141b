"""Which structure of the real keypoints' errors costs the in-situ pose? Residuals re-imposed, shuffled (issue 11).

    .venv/bin/python tools/keypoint_shuffle.py SCENARIO RUN [RUN ...] [--set KEY=VALUE ...] [--json OUT.jsonl]

EVALUATOR SIDE (it reads ``truth/``). Each RUN is a finished ``in_situ`` run folder (``dataset/``, ``calibrated/``,
``result.json``) of SCENARIO with the same ``--set``. The dataset is localised again as the kind does it
(``relocate_sweep.locate_run``); every map point the final solve had (the reference, the surrounding views that made
it, the two locate views where the solve used it: :func:`bench.scenario.in_situ_bound.observation_pattern`) is
triangulated through the **true** camera poses and optics from all of its detected pixels (Gauss-Newton), and each
observation's residual about that point is what no 3D point explains - the part of a keypoint's error that can move
the pose (a shift consistent with one 3D point only moves the map point). Then the pipeline runs again on exact
projections of those points (each point's descriptor fixed, so the matching is exact), with the residuals put back:

* ``exact`` - none (what the lab's calibration, the encoders and the estimator leave);
* ``obs_shuffle`` - every view's residuals permuted among the points that view observed: each view's marginal
  distribution (its heavy tails, its spread) kept, the link between a point's views broken;
* ``track_swap`` - whole points' residual vectors permuted among points of the same observation pattern: each
  point's structure over its views kept, its place in the image lost;
* ``white`` - Gaussian of each view's robust sigma (1.4826 MAD);
* ``smooth`` - each view's smooth part kept (a cubic polynomial in the pixel, least squares per axis, fitted to the
  residuals within 1 px) and the rest permuted as in ``obs_shuffle``: whether a field of that order carries it.

The unshuffled residuals give back the run's own estimate to ~1e-7 mm (checked at seed 1). Printed per run: the
base position (mm) and rotation (deg) errors of the pose as reported (the INS tilt fused) and of the images' pose;
then the RMS over runs. docs/bounds.md ("Which structure of the keypoints' errors costs the pose") quotes it.
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

VARIANTS = ("exact", "obs_shuffle", "track_swap", "white", "smooth")


def residuals(cfg, run: Path) -> dict:
    """The run's located map points' detected pixels ``uv (V, M, 2)`` (NaN: not observed), their best 3D points'
    exact projections ``P`` and the residuals ``uv - P``; views in the order reference, surrounding, locate."""
    from relocate_sweep import locate_run

    from bench.geometry.transforms import invert, transform_points
    from bench.scenario.bounds import true_projector
    from bench.scenario.in_situ import _true_camera_poses, _true_optics, imaging
    from bench.scenario.in_situ_bound import detected_pixels

    result = json.loads((run / "result.json").read_text())
    truth = yaml.safe_load((run / "dataset" / "truth" / "truth.yaml").read_text())
    det = {}
    res, _ = locate_run(run, result["seed"], cfg["pipeline"], details=det)
    if not res.success or res.used is None:
        raise ValueError(f"{run}: the run does not localise ({res.message})")
    lens, port, _ = _true_optics(truth)
    poses = _true_camera_poses(det["robot"], truth)
    obs, kmap = det["observations"], det["map"]
    role = {n: truth["views"][n]["role"] for n in obs}
    ref = next(n for n in obs if role[n] == "reference")
    sur = [n for n in obs if role[n] == "surround"]
    loc = [n for n in obs if role[n] == "locate"][:2]
    order = [ref, *sur, *loc]
    project = true_projector(lens, port, imaging(cfg))
    V, M = len(order), len(kmap)
    uv = np.full((V, M, 2), np.nan)

    uv[0] = obs[ref].features.uv[np.asarray(kmap.ref_index)]
    for i, (views, xs) in enumerate(kmap.observations):
        for k, x in zip(np.asarray(views, int), np.asarray(xs, float).reshape(-1, 2), strict=True):
            uv[1 + k, i] = detected_pixels(obs[sur[k]], x)[0]
    idx = np.asarray(res.used[0], int)
    for j in range(2):
        uv[V - 2 + j, idx] = detected_pixels(obs[loc[j]], res.used[1 + j])
    T = np.stack([poses[n] for n in order])
    X = transform_points(np.array(truth["T_world_base_survey"]) @ kmap.T_world_ref, kmap.p_ref)

    def proj(X):
        return np.stack([project(transform_points(invert(T[k]), X)) for k in range(V)])

    vis = np.all(np.isfinite(uv), axis=2)
    for _ in range(6):  # Gauss-Newton per point on every observed pixel
        r = np.where(vis[..., None], uv - proj(X), 0.0)
        Jx = np.stack([(proj(X + e) - proj(X - e)) / 2e-6 for e in 1e-6 * np.eye(3)], -1) * vis[..., None, None]
        A, b = np.einsum("vmai,vmaj->mij", Jx, Jx), np.einsum("vmai,vma->mi", Jx, r)
        X = X + np.linalg.solve(A + 1e-12 * np.eye(3), b[..., None])[..., 0]
    P = proj(X)
    return {"result": result, "truth": truth, "order": order, "uv": uv, "vis": vis, "P": P,
            "resid": np.where(vis[..., None], uv - P, np.nan)}


def variants(S: dict, rng) -> dict:
    """The pixels of every variant (module docstring), ``{name: (V, M, 2)}``."""
    P, r, vis = S["P"], S["resid"], S["vis"]
    out = {"exact": P}
    V, M = vis.shape
    rs = r.copy()
    for k in range(V):
        idx = np.flatnonzero(vis[k])
        rs[k, idx] = r[k, rng.permutation(idx)]
    out["obs_shuffle"] = P + rs
    rt, patterns = r.copy(), {}
    for j in range(M):
        patterns.setdefault(vis[:, j].tobytes(), []).append(j)
    for js in patterns.values():
        js = np.array(js)
        rt[:, js] = r[:, rng.permutation(js)]
    out["track_swap"] = P + rt
    rw = np.full_like(r, np.nan)
    for k in range(V):
        x = r[k][vis[k]]
        rw[k][vis[k]] = rng.normal(0.0, 1.4826 * np.median(np.abs(x - np.median(x, 0))), x.shape)
    out["white"] = P + rw
    rp = r.copy()
    for k in range(V):
        idx = np.flatnonzero(vis[k])
        u, v = (P[k, idx] - P[k, idx].mean(0)).T / 100.0
        B = np.stack([u**a * v**b for a in range(4) for b in range(4 - a)], axis=1)  # cubic: 10 terms
        fit = np.all(np.abs(r[k, idx]) < 1.0, axis=1)
        coef = np.zeros((B.shape[1], 2))  # too few to fit: no smooth part
        if fit.sum() > 3 * B.shape[1]:
            coef = np.linalg.lstsq(B[fit], r[k, idx][fit], rcond=None)[0]
        smooth = B @ coef
        rest = r[k, idx] - smooth
        rp[k, idx] = smooth + rest[rng.permutation(len(idx))]
    out["smooth"] = P + rp
    return out


def _features_fn(S: dict, uvmap):
    """``features_fn`` for the pipeline: in each view the points it observed, at the variant's pixels."""
    from bench.scenario.bounds import point_features

    rows, M = {n: k for k, n in enumerate(S["order"])}, S["uv"].shape[1]

    def fn(view):
        k = rows.get(view.name)
        idx = np.flatnonzero(S["vis"][k]) if k is not None else np.zeros(0, int)
        return point_features(uvmap[k, idx] if len(idx) else np.zeros((0, 2)), idx, M)
    return fn


def locate_with(cfg, run: Path, S: dict, uvmap) -> list:
    """The pipeline on the given pixels: ``[pos mm, rot deg]`` of the pose as reported, then of the images' pose."""
    from relocate_sweep import locate_run

    from bench.geometry.transforms import invert
    from bench.scenario.results import pose_errors

    res, rep = locate_run(run, S["result"]["seed"], cfg["pipeline"], features_fn=_features_fn(S, uvmap))
    if not res.success:
        return [float("nan")] * 4
    tr = S["truth"]
    T_true = invert(np.array(tr["T_world_base_survey"])) @ np.array(tr["T_world_base_locate"])
    vision = np.array(rep.get("T_world_base_vision", res.T_world_base))
    return [float(x) for x in (*pose_errors(res.T_world_base, T_true), *pose_errors(vision, T_true))]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenario")
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--json", type=Path, help="append one JSON line per run to this file")
    ap.add_argument("--variants", nargs="+", choices=VARIANTS, default=list(VARIANTS),
                    help="run only these (the others' random draws are made all the same: a variant's pixels do not"
                         " depend on which are run)")
    args = ap.parse_args(argv)
    from bench.errors import BenchError
    from bench.scenario.runner import load_scenario

    rows = []
    print("run               seed | as run          | " + " | ".join(f"{v:<15}" for v in args.variants)
          + "   (position mm / rotation deg, as reported)")
    for run in args.runs:
        try:
            result = json.loads((run / "result.json").read_text())
            cfg = load_scenario(args.scenario, result["seed"], args.overrides)
            S = residuals(cfg, run)
            m = result["metrics"]
            row = {"run": run.name, "seed": result["seed"],
                   "as_run": [m["base_pos_err_mm"], m["base_rot_err_deg"], m["base_pos_err_vision_mm"],
                              m["base_rot_err_vision_deg"]],
                   "limit": [m.get("base_pos_bound_mm"), m.get("base_rot_bound_deg")]}
            for name, uvm in variants(S, np.random.default_rng(result["seed"])).items():
                if name in args.variants:
                    row[name] = locate_with(cfg, run, S, uvm)
        except FileNotFoundError as exc:
            print(f"{run}: not a finished in_situ run ({exc.filename} is missing)")
            continue
        except (OSError, KeyError, ValueError, json.JSONDecodeError, BenchError) as exc:
            print(f"{run}: {type(exc).__name__}: {exc}")
            continue
        rows.append(row)
        if args.json:
            with args.json.open("a") as f:
                f.write(json.dumps(row) + "\n")
        cells = " | ".join(f"{row[k][0]:6.3f} {row[k][1]:7.4f}" for k in ("as_run", *VARIANTS) if k in row)
        print(f"{row['run']:<17} {row['seed']:>4} | {cells}", flush=True)
    if not rows:
        return 1
    print(summary(rows))
    return 0


def summary(rows: list) -> str:
    """RMS over the runs of each variant's errors (position mm, rotation deg; as reported and the images' pose)."""
    lines = [f"RMS over {len(rows)} runs (as reported | images' pose):"]
    for k in (k for k in ("as_run", *VARIANTS) if k in rows[0]):
        e = np.array([r[k] for r in rows], float)
        rms = np.sqrt(np.nanmean(e**2, axis=0))
        lines.append(f"  {k:<12} {rms[0]:.3f} mm {rms[1]:.4f} deg | {rms[2]:.3f} mm {rms[3]:.4f} deg")
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
