"""Where the joint bundle's base-pose error comes from: its linear response to the true keypoint errors, and the rest.

    .venv/bin/python tools/keypoint_error_decomposition.py SCENARIO RUN [RUN ...] [--set KEY=VALUE ...] [--json OUT]

EVALUATOR SIDE (it reads ``truth/``). Each RUN is a finished ``in_situ`` run folder of SCENARIO (with the same
``--set``). The dataset is localised again with the scenario's estimator and the run's lab files
(``relocate_sweep.locate_run``) and the joint bundle's last solve is kept. Every observation's own keypoint error is
measured on the panel's true surface as in ``tools/locate_keypoint_noise.py`` (the reference keypoint's ray cast onto
the true panel, that point projected through the true optics into each view: detected minus true; a point's
position is free in the bundle, so the choice of the reference makes no difference to the pose; a point with an
error beyond :data:`TRUTH_GATE_PX` in any view - its ray met an edge or an occluder - is left out and its errors
count as zero). The bundle's
linear response at its solution (:meth:`bench.vision.bundle.Elimination.response`) carries those errors onto the
base pose, and the base-pose error (before the INS tilt) splits into

* ``kp``: the response to the keypoint errors; ``rest`` = the error less it (the encoders, the arm's and the
  camera's calibration errors, the refraction, the linearisation);
* the keypoint part again split: ``track`` - each map point's mean error over its views (what a point's views
  share: the point absorbs most of it), ``offset`` - each view's mean error, ``dev`` - each observation's deviation
  from its track's mean;
* ``twin_pairs`` / ``twin_error_corr``: SIFT's twin keypoints among the points (a second orientation at the same
  pixel, which the thesis's map, the default, keeps; ``--set pipeline.twin_keypoints=once`` merges them) and how
  their true errors correlate in the other views; ``twin_error_rms_px`` / ``single_error_rms_px`` the true error's
  RMS (per axis) in the other views of the twins' and of the other points' observations, ``twin_dev_rms_px`` /
  ``single_dev_rms_px`` that of their deviations from their point's mean (the part the point does not absorb).

Each part's position NEES is against the bundle's own first-order covariance (white pixel noise at its robust
``sigma_px``, kappa 1); ``nees_dev_sandwich`` against the covariance those deviations would give if they were
independent with their measured RMS (locate views and survey views each their own), ``trace_ratio`` that
covariance's trace over the bundle's. A part whose NEES runs above chi-square 3's (median 2.37) is where the
covariance is optimistic. docs/integrity.md ("Where the covariance's optimism comes from") quotes its output.
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
sys.path.insert(0, str(ROOT / "tools"))

Q95_CHI2_3 = 7.815
#: a measured error beyond this (px) is the ray-cast's, not the keypoint's: the point is left out
TRUTH_GATE_PX = 1.0


class _Spy:
    """Within ``with``: keeps the last joint bundle's solve (``problem, info0, sol``) and its call's observations;
    the module's functions are restored on leaving."""

    def __enter__(self):
        import bench.vision.joint_bundle as jb_module

        self.last, self.calls, self.module = {}, {}, jb_module
        self.saved = solve, joint_bundle = jb_module.solve, jb_module.joint_bundle

        def spy_solve(problem, theta0, mean, info0, X, *a, **k):
            sol = solve(problem, theta0, mean, info0, X, *a, **k)
            self.last.update(problem=problem, info0=info0, sol=sol)
            return sol

        def spy_bundle(robot, eps, T_link5_cam, q_read, is_loc, T_start, view, point, uv, X, *a, **k):
            out = joint_bundle(robot, eps, T_link5_cam, q_read, is_loc, T_start, view, point, uv, X, *a, **k)
            self.calls.update(view=np.asarray(view), point=np.asarray(point), uv=np.asarray(uv), n_views=len(q_read),
                              out=out)
            return out

        jb_module.solve, jb_module.joint_bundle = spy_solve, spy_bundle
        return self

    def __exit__(self, *exc):
        self.module.solve, self.module.joint_bundle = self.saved


def _true_errors(cfg, truth, det, names, view, point, uv) -> tuple:
    """Each observation's keypoint error (N, 2) px on the true surface and whether it was measured (N,) bool."""
    from bench.geometry.transforms import invert, transform_points
    from bench.scenario.bounds import true_projector
    from bench.scenario.in_situ import _true_camera_poses, _true_optics, imaging, replay_panel
    from bench.scenario.in_situ_bound import surface_points
    from bench.scenario.scene_points import SceneRays

    lens, port, _ = _true_optics(truth)
    poses = _true_camera_poses(det["robot"], truth)
    project = true_projector(lens, port, imaging(cfg))
    surface = SceneRays(replay_panel(cfg), np.array(truth["T_world_panel"], float))
    ref = np.full(point.max() + 1, -1)
    ref[point[view == 0]] = np.where(view == 0)[0]  # every point is observed in the reference (view 0)
    P = surface_points(uv[ref], poses[names[0]], lens, port, surface)
    b, good = np.zeros((len(view), 2)), np.zeros(len(view), bool)
    for k, n in enumerate(names):
        sel = view == k
        uv_true = project(transform_points(invert(poses[n]), P[point[sel]]))
        b[sel] = uv[sel] - uv_true
        good[sel] = np.all(np.isfinite(uv_true), axis=1)
    # a kept observation is within the bundle's gate (~0.4 px): beyond TRUTH_GATE_PX the ray met another surface than
    # the keypoint's (an edge, an occluder), so the point's truth is unknown: all its observations are left out
    bad = np.unique(point[good & (np.abs(b).max(axis=1) > TRUTH_GATE_PX)])
    good &= ~np.isin(point, bad)
    b[~good] = 0.0
    return b, good


def _group_mean(values, groups, mask, size) -> np.ndarray:
    """The mean of ``values (N, 2)`` over each group (``groups (N,)`` int) of the rows ``mask`` selects: (size, 2)."""
    out = np.zeros((size, 2))
    np.add.at(out, groups[mask], values[mask])
    return out / np.maximum(np.bincount(groups[mask], minlength=size), 1)[:, None]


def _twin_error_correlation(b, dev, ok, view, point, uv) -> dict:
    """SIFT's twins among the bundle's points (reference keypoints within ``TWIN_PX`` of each other: ``twin_pairs``)
    and the correlation of their true errors in the other views (``twin_error_corr``: sum of the pairs' products over
    the mean of their squares, pooled over the views and axes; NaN without twins); the RMS in the other views of the
    true errors ``b`` and of their deviations ``dev`` from each point's mean, for the twins and for the other points."""
    from scipy.spatial import cKDTree

    from bench.vision.insitu import TWIN_PX

    ref = view == 0
    uv0 = np.full((int(point.max()) + 1, 2), np.inf)
    uv0[point[ref]] = uv[ref]
    finite = np.flatnonzero(np.isfinite(uv0[:, 0]))
    pairs = finite[cKDTree(uv0[finite]).query_pairs(TWIN_PX, output_type="ndarray")] if len(finite) > 1 else []
    at = {(int(v), int(p)): i for i, (v, p) in enumerate(zip(view, point, strict=True)) if ok[i] and v > 0}
    num = den = 0.0
    for p, q in pairs:
        for v in range(1, int(view.max()) + 1):
            i, j = at.get((v, int(p))), at.get((v, int(q)))
            if i is not None and j is not None:
                num += float(b[i] @ b[j])
                den += 0.5 * float(b[i] @ b[i] + b[j] @ b[j])
    in_pair = np.isin(point, np.asarray(pairs, int).ravel())
    twin, single = (m & ok & (view > 0) for m in (in_pair, ~in_pair))

    def rms(e, m):
        return float(np.sqrt(np.mean(e[m] ** 2))) if m.any() else float("nan")

    return {"twin_pairs": len(pairs), "twin_error_corr": num / den if den else float("nan"),
            "twin_error_rms_px": rms(b, twin), "single_error_rms_px": rms(b, single),
            "twin_dev_rms_px": rms(dev, twin), "single_dev_rms_px": rms(dev, single)}


def _pose_response_matrix(el, keep) -> np.ndarray:
    """The base pose's response (6, N, 2) to a unit pixel error of each kept observation."""
    N = el.J.shape[0]
    G = np.zeros((6, N, 2))
    idx = np.where(keep)[0]
    for lo in range(0, len(idx), 150):
        ch = idx[lo:lo + 150]
        E = np.zeros((N, 2, 2 * len(ch)))
        cols = 2 * np.arange(len(ch))
        E[ch, 0, cols], E[ch, 1, cols + 1] = 1.0, 1.0
        d_theta, _ = el.response(E)
        G[:, ch, 0], G[:, ch, 1] = d_theta[:6, cols], d_theta[:6, cols + 1]
    return G


def decompose(scenario: Path, run: Path, overrides: list) -> dict:
    """One run's decomposition (module docstring)."""
    from relocate_sweep import locate_run

    from bench.geometry.quaternion import matrix_to_rotation_vector
    from bench.geometry.transforms import invert
    from bench.scenario.runner import load_scenario
    from bench.vision.bundle import Elimination

    result = json.loads((run / "result.json").read_text())
    cfg = load_scenario(scenario, result["seed"], ["outputs.rerun=false", *overrides])
    truth = yaml.safe_load((run / "dataset" / "truth" / "truth.yaml").read_text())
    det = {}
    with _Spy() as spy, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        locate_run(run, result["seed"], cfg["pipeline"], details=det)
    if not spy.last or not spy.calls["out"].success:
        return {"run": run.name, "error": "no joint bundle"}
    problem, info0, sol = spy.last["problem"], spy.last["info0"], spy.last["sol"]
    view, point, uv = spy.calls["view"], spy.calls["point"], spy.calls["uv"]
    obs = det["observations"]
    role = {n: truth["views"][n]["role"] for n in obs}
    names = [n for r in ("reference", "surround") for n in obs if role[n] == r] + \
            [n for n in obs if role[n] == "locate"][:2]
    if len(names) != spy.calls["n_views"]:
        return {"run": run.name, "error": "several regions: not decomposed (one region only)"}
    b, good = _true_errors(cfg, truth, det, names, view, point, uv)
    keep = np.asarray(sol.keep, bool)
    ok = keep & good
    if ok.sum() < 0.5 * keep.sum():
        return {"run": run.name, "error": f"only {int(ok.sum())} of {int(keep.sum())} observations meet the true panel "
                                          f"within {TRUTH_GATE_PX:g} px: is {scenario} (with --set) the run's?"}
    s = float(sol.sigma_px)
    _, J, J_pt, _ = problem.linearise(sol.theta, sol.X)
    el = Elimination(problem.point, J, J_pt, len(sol.X), info0 * s**2, keep)
    C = s**2 * np.linalg.inv(el.S)[3:6, 3:6]  # the bundle's own position covariance (m^2), white, kappa 1

    def pose_of(e):
        return el.response(np.where(ok[:, None], e, 0.0)[:, :, None])[0][:6, 0]

    def nees(d, cov=C):
        return float(d[3:] @ np.linalg.solve(cov, d[3:]))

    T_true = invert(np.array(truth["T_world_base_survey"])) @ np.array(truth["T_world_base_locate"])
    T_est = spy.calls["out"].T_site_base
    d_tot = np.r_[matrix_to_rotation_vector(T_est[:3, :3] @ T_true[:3, :3].T), T_est[:3, 3] - T_true[:3, 3]]
    M = int(point.max()) + 1
    track_means = _group_mean(b, point, ok, M)
    track = track_means[point]
    offset = _group_mean(b, view, ok, len(names))[view]
    dev = b - track
    d_kp, d_dev = pose_of(b), pose_of(dev)
    is_loc = np.isin(view, [k for k, n in enumerate(names) if role[n] == "locate"])
    rms = {g: float(np.sqrt(np.mean(dev[m & ok] ** 2))) for g, m in (("locate", is_loc), ("survey", ~is_loc))}
    G = _pose_response_matrix(el, keep)[3:]
    sig = np.where(is_loc, rms["locate"], rms["survey"])
    C_sw = np.einsum("inj,knj->ik", G * sig[None, :, None], G * sig[None, :, None])
    twins = _twin_error_correlation(b, dev, ok, view, point, uv)
    return {"run": run.name, "seed": result["seed"], "observations": int(keep.sum()), "sigma_px": s,
            "true_px_robust": float(1.4826 * np.median(np.abs(b[ok]))),
            "track_rms_px": float(np.sqrt(np.mean(track_means[np.bincount(point[ok], minlength=M) > 0] ** 2))),
            "dev_locate_rms_px": rms["locate"], "dev_survey_rms_px": rms["survey"],
            "err_mm": 1e3 * float(np.linalg.norm(d_tot[3:])), "kp_mm": 1e3 * float(np.linalg.norm(d_kp[3:])),
            "rest_mm": 1e3 * float(np.linalg.norm(d_tot[3:] - d_kp[3:])),
            "nees_tot": nees(d_tot), "nees_kp": nees(d_kp), "nees_rest": nees(d_tot - d_kp),
            "nees_track": nees(pose_of(track)), "nees_offset": nees(pose_of(offset)), "nees_dev": nees(d_dev),
            "nees_dev_sandwich": nees(d_dev, C_sw), "trace_ratio": float(np.trace(C_sw) / np.trace(C)), **twins}


def summary(rows: list) -> str:
    """Medians (and the 95 % coverage of each NEES) over the runs."""
    good = [r for r in rows if "error" not in r]
    if not good:
        return "no run decomposed"
    lines = [f"{len(good)} runs (medians; NEES: coverage of chi2_3's 95 % region)"]
    for k in good[0]:
        if k in ("run", "seed"):
            continue
        v = np.array([r[k] for r in good], float)
        cov = f"  in 95 %: {np.mean(v <= Q95_CHI2_3):.0%}" if k.startswith("nees") else ""
        lines.append(f"  {k:20s} {np.median(v):8.3f}{cov}")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenario", type=Path)
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="the sweep's overrides")
    ap.add_argument("--json", type=Path, help="write every run's figures here")
    args = ap.parse_args(argv)
    rows = []
    for run in args.runs:
        for f in ("result.json", "dataset/truth/truth.yaml"):
            if not (run / f).is_file():
                raise SystemExit(f"{run / f}: missing (expected a finished in_situ run folder)")
        row = decompose(args.scenario, run, args.set)
        rows.append(row)
        print(json.dumps({k: round(v, 4) if isinstance(v, float) else v for k, v in row.items()}), flush=True)
    print(summary(rows))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
