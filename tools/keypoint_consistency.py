"""How precise are the SIFT keypoints of a scene? Their consistency across the x-y table's views (issue 12).

    .venv/bin/python tools/keypoint_consistency.py SCENARIO DATASET [DATASET ...] [--set KEY=VALUE ...]
                                                   [--reference p11] [--min-views 4] [--surface] [--json OUT.json]

EVALUATOR SIDE (it reads ``truth/``). Each DATASET is a ``bench sim render`` of an ``xy_table`` scenario (SCENARIO with
the same ``--set``, for the imaging profile's static warp). SIFT keypoints of the reference view are matched in every
other table view (Lowe's ratio 0.75, cross-checked: :func:`bench.vision.features.match_descriptors`); a reference
keypoint matched in at least ``--min-views`` views (the reference included) is a track. Each track is triangulated
through the **true** camera poses and optics (the linear midpoint of the views' rays, then the reprojection residual
through the true lens, port and prism in every view), so what is left is the keypoints' own error: detection noise, and
for a scene with relief and gloss the keypoints that are not points of any surface (occluding contours, highlights) and
move with the viewpoint.

A track's worst observation is dropped while it is beyond 3 px (a false match or a keypoint that slid far: what
RANSAC must reject; counted as ``gross``). Printed per dataset and pooled: tracks, observations, the robust per-axis
sigma of the kept residuals (1.4826 MAD, px), their RMS, the fraction beyond 1 px (the heavy tail), and ``gross``;
docs/realistic_imaging.md section 3.6 compares them with what the thesis's tables imply (~1 px).

Then the correlation of a track's residuals in two of its views, binned by the distance of the two camera centres,
beside a null (independent errors through the same triangulation). With ``--surface`` (a camera in air; the scene is
replayed from the seed in the dataset's manifest) the keypoints' own errors without a triangulation: each
observation's ray cast onto the true surfaces, seen in the reference view, minus the track's mean; their correlation
between views and their drift along the travel (docs/bounds.md, "The keypoints' errors are correlated between
views").
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

import cv2
import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.errors import BenchError  # noqa: E402


def _triangulate(rays_o, rays_d) -> np.ndarray:
    """The point nearest to the rays (origins (V, 3), unit directions (V, 3)) in least squares."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    for o, d in zip(rays_o, rays_d, strict=True):
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ o
    return np.linalg.solve(A, b)


GROSS_PX = 3.0


def _residuals(names, obs, T_tc, lens, project):
    """The reprojection residuals (V, 2) px of one track triangulated through the true poses; None behind a camera."""
    uv = np.array([obs[n] for n in names])
    d = np.c_[lens.undistort_pixels(uv), np.ones(len(uv))]
    R = np.array([T_tc[n][:3, :3] for n in names])
    c = np.array([T_tc[n][:3, 3] for n in names])
    d = np.einsum("vij,vj->vi", R, d)
    X = _triangulate(c, d / np.linalg.norm(d, axis=1, keepdims=True))
    p_cam = np.einsum("vji,vj->vi", R, X - c)
    return None if np.any(p_cam[:, 2] <= 0.05) else project(p_cam) - uv


def _dataset_seed(root: Path) -> int:
    """The seed ``bench sim render`` wrote into the dataset's manifest (``created_by: ... (seed N)``)."""
    text = yaml.safe_load((root / "manifest.yaml").read_text()).get("created_by", "")
    m = re.search(r"\(seed (\d+)\)", str(text))
    if not m:
        raise BenchError(f"{root / 'manifest.yaml'}: created_by names no seed (the scene is replayed from it)")
    return int(m.group(1))


def consistency(dataset, cfg, reference="p11", min_views=4, surface=False) -> dict:
    """The residuals of ``dataset``'s SIFT tracks through the true geometry (see the module docstring); with
    ``surface``, also the keypoints' own errors on the scene's surfaces (:func:`surface_pairs`)."""
    from bench.scenario.bounds import true_projector
    from bench.scenario.xy_table import imaging, true_optics
    from bench.vision.features import detect_sift, match_descriptors

    root = Path(dataset)
    if cfg.get("kind") != "xy_table":
        raise BenchError(f"{cfg['_file']}: an xy_table scenario is needed, got kind {cfg.get('kind')!r}")
    truth = yaml.safe_load((root / "truth" / "truth.yaml").read_text())
    missing = [k for k in ("T_table_cam", "camera_K", "camera_size", "optics") if k not in (truth or {})]
    if missing:
        raise BenchError(f"{root / 'truth' / 'truth.yaml'}: not an x-y table dataset's truth (no {missing[0]})")
    lens, port = true_optics(truth)
    project = true_projector(lens, port, imaging(cfg))
    T_tc = {n: np.array(T, float) for n, T in truth["T_table_cam"].items()}
    if reference not in T_tc:
        raise BenchError(f"{root}: no table view {reference!r} (views: {', '.join(sorted(T_tc))})")
    feats = {n: detect_sift(cv2.imread(str(root / "images" / f"{n}.png"), cv2.IMREAD_GRAYSCALE)) for n in T_tc}
    tracks = {i: {reference: feats[reference].uv[i]} for i in range(len(feats[reference]))}
    for n in T_tc:
        if n != reference:
            m = match_descriptors(feats[reference], feats[n], 0.75, mutual=True)
            for i, j in zip(m.i1, m.i2, strict=True):
                tracks[i][n] = feats[n].uv[j]
    res, gross, kept = [], 0, []
    for obs in tracks.values():
        names = list(obs)
        while len(names) >= min_views:  # drop a track's worst observation while it is beyond 3 px (a false match)
            r = _residuals(names, obs, T_tc, lens, project)
            if r is None:
                break
            worst = int(np.argmax(np.linalg.norm(r, axis=1)))
            if np.linalg.norm(r[worst]) <= GROSS_PX:
                res.append(r)
                kept.append((names, r, {n: obs[n] for n in names}))
                break
            names.pop(worst)
            gross += 1
    r = np.concatenate(res) if res else np.empty((0, 2))
    norm = np.linalg.norm(r, axis=1)
    mad = 1.4826 * np.median(np.abs(r - np.median(r, axis=0)), axis=0) if len(r) else np.full(2, np.nan)
    return {"dataset": str(root), "keypoints_reference": len(feats[reference]), "tracks": len(res),
            "observations": int(len(r)), "robust_sigma_px": [float(v) for v in mad],
            "rms_px": float(np.sqrt(np.mean(norm**2))) if len(r) else float("nan"),
            "beyond_1px": float(np.mean(norm > 1.0)) if len(r) else float("nan"),
            "gross": gross / max(1, gross + len(r)), "residuals": r,
            "kept": kept, "sigma": mad, "geometry": (T_tc, lens, project),
            "surface": _surface(root, cfg, truth, tracks, T_tc, lens, port, project, reference, min_views)
            if surface else None}


def _surface(root, cfg, truth, tracks, T_tc, lens, port, project, reference, min_views) -> tuple:
    from bench.scenario.scene_points import SceneRays
    from bench.scenario.xy_table import replay_reference_object

    if port is not None:
        raise BenchError(f"{root}: --surface casts the rays of a camera in air; this one is behind a flat port")
    if truth.get("reference_object") != cfg["sim"]["reference_object"]:  # else another scene is replayed
        raise BenchError(f"{root}: rendered with sim.reference_object={truth.get('reference_object')}, the scenario "
                         f"has {cfg['sim']['reference_object']} (pass the render's --set)")
    obj = replay_reference_object({**cfg, "seed": _dataset_seed(root)}, truth)
    if obj is None:
        raise BenchError(f"{root}: the scene replayed from its seed is not the rendered one (another version?)")
    rays = SceneRays(obj, np.array(truth["T_table_reference"], float))
    return surface_pairs(tracks, T_tc, lens, project, rays, reference, min_views)


#: a track is typical when every error of it is within this many robust sigmas (pooled) of the track's mean
TYPICAL_SIGMAS = 4.0
#: camera-centre distances (m) that bin the correlation of a track's residuals between two of its views
CORRELATION_EDGES_M = (0.0, 0.02, 0.04, 0.07, 0.1, 0.15, 0.25)


def _track_pairs(kept, T_tc, lens, project, sigma, rng, max_px=1.0) -> np.ndarray:
    """Per pair of views of a track whose residuals are all within ``max_px``: ``(distance of the two camera
    centres (m), r_a (2), r_b (2), the same two residuals of a null track)``. The null track is the triangulated
    point's projections plus independent Gaussian errors of the measured robust ``sigma`` (2,) per axis, through the
    same triangulation: the correlation the triangulation alone gives."""
    rows = []
    for names, r, obs in kept:
        if np.abs(r).max() > max_px:
            continue
        fit = np.array([obs[n] for n in names]) + r  # the triangulated point's projections
        r0 = _residuals(names, {n: fit[k] + rng.normal(0.0, sigma) for k, n in enumerate(names)}, T_tc, lens,
                        project)
        if r0 is None:
            continue
        c = np.array([T_tc[n][:3, 3] for n in names])
        a, b = np.triu_indices(len(names), 1)
        rows.append(np.c_[np.linalg.norm(c[a] - c[b], axis=1), r[a], r[b], r0[a], r0[b]])
    return np.concatenate(rows) if rows else np.empty((0, 9))


def _unproject(uv, lens, project, iterations=6):
    """Unit rays (N, 3) in the camera frame through pixels ``uv (N, 2)`` of the true projector ``project`` (the lens
    and the imaging profile's static warp): the lens's own inverse, then Newton steps on the normalized coordinates
    (numeric Jacobian) until ``project`` gives ``uv`` back (~1e-9 px)."""
    x = lens.undistort_pixels(uv)
    h = 1e-7
    for _ in range(iterations):
        f = project(np.c_[x, np.ones(len(x))]) - uv
        J = np.stack([(project(np.c_[x + e, np.ones(len(x))]) - project(np.c_[x - e, np.ones(len(x))])) / (2 * h)
                      for e in (np.array([h, 0.0]), np.array([0.0, h]))], axis=-1)  # (N, 2, 2)
        x = x - np.linalg.solve(J, f[..., None])[..., 0]
    d = np.c_[x, np.ones(len(x))]
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def surface_pairs(tracks, T_tc, lens, project, rays, reference, min_views=4) -> tuple:
    """The keypoints' own errors, without a triangulation to hide part of them: each observation's ray (through the
    true optics and pose) is cast onto the scene's true surfaces (:class:`bench.scenario.scene_points.SceneRays`) and
    the surface point is projected into the reference view; a track's error in view k is that pixel minus the
    track's mean over its views (the worst dropped while beyond 3 px: a ray that missed the keypoint's surface).
    Returns ``(pairs, drift)``: per pair of views of a track ``(distance of the two camera centres (m), e_a (2), e_b
    (2), -1 / (n - 1), the track's largest error (px))``, the fourth the correlation independent errors would have
    after the mean of the track's ``n`` views is removed; and the errors' linear drift with the camera along the
    table's travel (per track of >= 6 views, ``e ~ slope (x - mean x)``, ``x`` the camera centre's along the travel):
    the robust spread over the tracks of the slope per image axis (px per m) and the median fraction of a track's
    error variance it explains."""
    T_ref_inv = np.linalg.inv(T_tc[reference])
    rows, drift = [], []
    for obs in tracks.values():
        names = [n for n in obs if n in T_tc]
        if len(names) < min_views:
            continue
        d_cam = _unproject(np.array([obs[n] for n in names]), lens, project)
        T = np.array([T_tc[n] for n in names])
        X = rays.first_hits(T[:, :3, 3], np.einsum("vij,vj->vi", T[:, :3, :3], d_cam))  # NaN: the ray left the scene
        u = project(X @ T_ref_inv[:3, :3].T + T_ref_inv[:3, 3])
        keep = np.all(np.isfinite(u), axis=1)
        while keep.sum() >= min_views:
            e = u - u[keep].mean(axis=0)
            worst = int(np.argmax(np.where(keep, np.linalg.norm(e, axis=1), -1.0)))
            if np.linalg.norm(e[worst]) <= GROSS_PX:
                break
            keep[worst] = False
        if keep.sum() < min_views:
            continue
        e = (u - u[keep].mean(axis=0))[keep]
        c = np.array([T_tc[n][:3, 3] for n, k in zip(names, keep, strict=True) if k])
        a, b = np.triu_indices(len(e), 1)
        rows.append(np.c_[np.linalg.norm(c[a] - c[b], axis=1), e[a], e[b], np.full(len(a), -1.0 / (len(e) - 1)),
                          np.full(len(a), np.abs(e).max())])
        if len(e) >= 6:  # the drift: e linear in the camera's x along the travel, slope (2,) px per m
            cx = c[:, 0] - c[:, 0].mean()
            slope = cx @ e / max(cx @ cx, 1e-12)
            drift.append((slope, 1.0 - np.sum((e - np.outer(cx, slope)) ** 2) / max(np.sum(e**2), 1e-30)))
    pairs = np.concatenate(rows) if rows else np.empty((0, 7))
    slopes = np.array([d[0] for d in drift]).reshape(-1, 2)
    return pairs, {"tracks": len(drift),
                   "slope_x_px_per_m_robust_std": [float(v) for v in 1.4826 * np.median(np.abs(slopes), axis=0)],
                   "explained_median": float(np.median([d[1] for d in drift])) if drift else float("nan")}


def _bins(pairs):
    """``(from_mm, to_mm, rows)`` of the pairs in each camera-distance bin (:data:`CORRELATION_EDGES_M`) with >= 10."""
    edges = [*CORRELATION_EDGES_M, np.inf]
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sel = (pairs[:, 0] >= lo) & (pairs[:, 0] < hi)
        if sel.sum() >= 10:
            yield lo * 1e3, hi * 1e3, pairs[sel]


def _corr(q, i, j) -> list:
    """Per image axis, the correlation of columns ``i, i + 1`` with ``j, j + 1``."""
    return [float(np.corrcoef(q[:, i + k], q[:, j + k])[0, 1]) for k in (0, 1)]


def correlation_table(pairs) -> list:
    """Per camera-distance bin: pairs, the correlation of the two residuals per image axis, and the null's."""
    return [dict(zip(("from_mm", "to_mm", "pairs", "corr_x", "corr_y", "null_x", "null_y"),
                     (lo, hi, len(q), *_corr(q, 1, 3), *_corr(q, 5, 7)), strict=True)) for lo, hi, q in _bins(pairs)]


def surface_table(pairs) -> list:
    """Per camera-distance bin: pairs, the correlation of the two views' errors per image axis, their robust sigma
    (px), and the null for independent errors after the track's mean is removed (``-1 / (n - 1)`` for a track of n
    views, averaged over the bin's pairs)."""
    out = []
    for lo, hi, q in _bins(pairs):
        sig = 1.4826 * np.median(np.abs(np.r_[q[:, 1:3], q[:, 3:5]]), axis=0)
        out.append(dict(zip(("from_mm", "to_mm", "pairs", "corr_x", "corr_y", "null", "sigma_x_px", "sigma_y_px"),
                            (lo, hi, len(q), *_corr(q, 1, 3), float(np.mean(q[:, 5])), *map(float, sig)),
                            strict=True)))
    return out


def main(argv=None) -> int:
    from bench.scenario.runner import load_scenario

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenario")
    ap.add_argument("datasets", nargs="+")
    ap.add_argument("--set", action="append", default=[], dest="overrides")
    ap.add_argument("--reference", default="p11")
    ap.add_argument("--min-views", type=int, default=4)
    ap.add_argument("--surface", action="store_true",
                    help="also the keypoints' own errors on the true surfaces (ray casting), correlated between views")
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    try:
        cfg = load_scenario(a.scenario, overrides=a.overrides)
        out = [consistency(d, cfg, a.reference, a.min_views, a.surface) for d in a.datasets]
    except (BenchError, OSError) as exc:
        print(f"keypoint_consistency: {exc}", file=sys.stderr)
        return 1
    pooled = np.concatenate([o.pop("residuals") for o in out])
    corr = correlation_table(np.concatenate([_track_pairs(o["kept"], *o["geometry"], o["sigma"],
                                                          np.random.default_rng(0)) for o in out]))
    surface = [o.pop("surface") for o in out]
    surface_corr, typical_corr = [], []
    if a.surface:
        sp = np.concatenate([sp[0] for sp in surface])
        sigma = 1.4826 * np.median(np.abs(sp[:, 1:5]))
        surface_corr = surface_table(sp)
        typical_corr = surface_table(sp[sp[:, 6] <= TYPICAL_SIGMAS * sigma])
    for o, sp in zip(out, surface, strict=True):
        if sp is not None:
            o["drift"] = sp[1]
    norm = np.linalg.norm(pooled, axis=1)
    mad = 1.4826 * np.median(np.abs(pooled - np.median(pooled, axis=0)), axis=0)
    gross = sum(o["gross"] * o["observations"] / (1 - o["gross"]) for o in out)
    summary = {"robust_sigma_px": [float(v) for v in mad], "rms_px": float(np.sqrt(np.mean(norm**2))),
               "beyond_1px": float(np.mean(norm > 1.0)), "observations": int(len(pooled)),
               "gross": gross / (gross + len(pooled)), "correlation": corr,
               "surface_correlation": surface_corr, "surface_correlation_typical": typical_corr}
    for o in out:
        for k in ("kept", "geometry", "sigma"):
            o.pop(k, None)
    for o in out:
        print(f"{o['dataset']}: {o['keypoints_reference']} keypoints, {o['tracks']} tracks, {o['observations']} obs, "
              f"robust sigma {o['robust_sigma_px'][0]:.3f} / {o['robust_sigma_px'][1]:.3f} px, RMS {o['rms_px']:.2f} "
              f"px, beyond 1 px {100 * o['beyond_1px']:.1f} %, gross (> 3 px, dropped) {100 * o['gross']:.1f} %")
    print(f"pooled: robust sigma {mad[0]:.3f} / {mad[1]:.3f} px, RMS {summary['rms_px']:.2f} px, beyond 1 px "
          f"{100 * summary['beyond_1px']:.1f} % of {summary['observations']}, gross {100 * summary['gross']:.1f} %")
    print("correlation of a track's residuals in two views, by the distance of their camera centres "
          "(null: independent errors through the same triangulation):")
    for c in corr:
        print(f"  {c['from_mm']:5.0f}-{c['to_mm']:5.0f} mm: {c['pairs']:6d} pairs, x {c['corr_x']:+.2f} "
              f"(null {c['null_x']:+.2f}), y {c['corr_y']:+.2f} (null {c['null_y']:+.2f})")
    if a.surface:
        print("the keypoints' own errors (rays cast onto the true surfaces, seen in the reference view, minus the "
              "track's mean), correlated between two views (null: -1 / (views - 1)):")
        for title, table in (("every track (within 3 px)", surface_corr),
                             (f"typical tracks (every error within {TYPICAL_SIGMAS:g} robust sigma)", typical_corr)):
            print(f"  {title}:")
            for c in table:
                print(f"    {c['from_mm']:5.0f}-{c['to_mm']:5.0f} mm: {c['pairs']:6d} pairs, x {c['corr_x']:+.2f}, "
                      f"y {c['corr_y']:+.2f} (null {c['null']:+.2f}); sigma {c['sigma_x_px']:.3f} / "
                      f"{c['sigma_y_px']:.3f} px")
        for o in out:
            d = o["drift"]
            print(f"  {o['dataset']}: drift with the camera's x over {d['tracks']} tracks: slope spread "
                  f"{d['slope_x_px_per_m_robust_std'][0]:.2f} / {d['slope_x_px_per_m_robust_std'][1]:.2f} px per m "
                  f"(image x / y), explaining {100 * d['explained_median']:.0f} % of a track's error variance "
                  f"(median)")

    if a.json:
        Path(a.json).write_text(json.dumps({"datasets": out, "pooled": summary}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
