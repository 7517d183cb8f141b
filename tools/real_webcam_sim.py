"""Simulate the real webcam photos (issue 12): same camera, same board, same 19 poses; compare the calibrations.

    .venv/bin/python tools/real_webcam_sim.py [--seeds 1 2 3] [--supersample 3] [--square-mm 25] [--imaging realistic]
                                              [--off STAGE ...] [--json OUT.json] [--save-images DIR]

The real photos (tests/data/real_webcam_chessboard: 19 views, 640 x 480, a board of 8 x 8 squares = 7 x 7 inner
corners) are calibrated by the bench (``tools/real_camera_stats.py``: ``cv2.findChessboardCornersSB`` with the
ACCURACY flag, Heikkilä model). That calibration gives the simulated camera (its K and, as the realistic profile's
``distortion`` stage, its k1 k2 p1 p2) and each view's board pose (the calibration's ``T_cam_target``, the unit
squares scaled to ``--square-mm``: the real board's size is not recorded; 25 mm fills A4). For each seed the
simulator renders the board at those 19 poses with the bench's chain (MuJoCo, supersampled, lens stage, lamp and
sensor of the ``air_webcam`` preset) under ``--imaging`` (the printed board's line offsets, scale and bow drawn from
the seed as for the rig), detects and calibrates the renders with the same code as the real photos, and prints the
residual statistics of both (:func:`real_camera_stats.residual_statistics`: RMS, per-view spread, neighbour
correlation along board rows and columns; and SIFT's localisation noise on the board plane,
:func:`real_camera_stats.measure_sift_precision`) with the simulated/real ratios. Issue 12's acceptance: RMS within
+-30 % of the real photos', the residuals' row correlation comparable.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

import real_camera_stats as rcs  # noqa: E402

PATTERN = (7, 7)
STATS = ("rms_px", "per_view_rms_cv", "row_corr_lag1", "row_corr_lag2", "col_corr_lag1", "col_corr_lag2",
         "sift_plane_px")


def real_calibration(data_dir=rcs.DEFAULT_DATA):
    """``(result, views)``: the bench's calibration of the real photos and their detections."""
    import glob

    files = sorted(glob.glob(str(Path(data_dir) / "*.jpg")) + glob.glob(str(Path(data_dir) / "*.png")))
    views = rcs.detect(files, PATTERN)
    if len(views) < 3:
        raise SystemExit(f"{data_dir}: the 7x7 board was found in only {len(views)} images")
    res, _ = rcs.calibrate(views, PATTERN)
    if not res.success:
        raise SystemExit(f"{data_dir}: calibration failed: {res.message}")
    return res, views


def board_poses(res, square_m: float) -> np.ndarray:
    """``T_cam_board`` (V, 4, 4): the calibration's target poses (unit squares, origin at the first inner corner)
    in metres and moved to the sim board's frame (origin at the pattern's outer corner, one square before)."""
    T = np.array(res.T_cam_target, float).copy()
    T[:, :3, 3] *= square_m
    shift = np.eye(4)
    shift[:3, 3] = [-square_m, -square_m, 0.0]
    return T @ shift


def simulate(res, seed: int, square_m: float, supersample: int, imaging: str = "realistic", off=(),
             save_images=None) -> dict:
    """Render the 19 poses for one seed, detect, calibrate; returns the residual statistics (+ ``views``)."""
    import cv2

    from bench.camera.presets import load_preset
    from bench.scenario.camera_calibration import TableRigScene
    from bench.sim.imaging import handling_dz, imaging_profile, lens_distortion, target_geometry
    from bench.sim.optics_presets import optics_preset
    from bench.sim.scenes.rig import planar_board
    from bench.sim.scenes.xy_table import lab_table_model

    profile = imaging_profile(imaging, list(off), source="real_webcam_sim", field="--imaging")
    optics = optics_preset("air_webcam")
    # the true camera: the real photos' K; their distortion is the realistic profile's distortion stage
    lens = load_preset(optics.lens_camera)
    lens = lens.replace(K=np.array(res.K, float), dist=lens_distortion(profile, np.zeros(5)), model=None,
                        name="real webcam (simulated)")
    errors = None
    if profile.stages:
        e = target_geometry(profile, 8, np.random.default_rng(np.random.SeedSequence([seed, 0x7A12])), square_m)
        errors = {"line_offsets_m": e["line_offsets_m"]["a"], "scale": e["scale"],
                  "bow_sagitta_m": e["bow_sagitta_m"]["a"], "dz_m": e["dz_m"]["a"]}
    table = lab_table_model(None)
    run = table.run(np.zeros((1, 3)))
    qpos = {name: vals[0] for name, vals in run.qpos.items()}
    uvs, found, scene, T_world_cam, views = [], 0, None, None, []
    try:
        for k, T_cb in enumerate(board_poses(res, square_m)):
            if scene is None or profile.on("handling"):  # a hand-held board flexes anew in every photo
                if scene is not None:
                    scene.close()
                view_errors = errors
                if profile.on("handling"):
                    flex = handling_dz(profile, 8, np.random.default_rng(np.random.SeedSequence([seed, 0x7A14, k])),
                                       square_m)
                    view_errors = dict(errors, dz_m=errors["dz_m"] + flex)
                board = planar_board(8, 8, square_m, name="board", errors=view_errors)
                scene = TableRigScene(lens, optics, table, board, supersample, None, z_min=0.1, imaging=profile)
                T_world_cam = scene.pose(qpos, np.eye(4))
            img, T_wc = scene.render(qpos, T_world_cam @ T_cb, seed=seed * 1000 + k)
            if not np.allclose(T_wc, T_world_cam):
                raise RuntimeError("the camera moved between views (the table stands still)")
            grey = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
            if save_images:
                Path(save_images).mkdir(parents=True, exist_ok=True)
                cv2.imwrite(str(Path(save_images) / f"seed{seed}_view{k:02d}.png"), grey)
            ok, c = cv2.findChessboardCornersSB(grey, PATTERN, flags=cv2.CALIB_CB_ACCURACY)
            if ok:
                found += 1
                uvs.append(c.reshape(-1, 2).astype(float))
                views.append((None, None, grey, uvs[-1]))
    finally:
        if scene is not None:
            scene.close()
    if found < 3:
        raise SystemExit(f"seed {seed}: the board was found in only {found} of {len(res.T_cam_target)} renders")
    from bench.camera import calibration as cal

    obj = np.zeros((49, 3))
    obj[:, :2] = np.mgrid[0:7, 0:7].T.reshape(-1, 2)
    sim = cal.calibrate_camera([obj] * len(uvs), uvs, (lens.width, lens.height), "heikkila")
    if not sim.success:
        raise SystemExit(f"seed {seed}: calibration of the renders failed: {sim.message}")
    out = rcs.residual_statistics(sim.residuals_px, PATTERN)
    out.update(rcs.measure_sift_precision(views, PATTERN, sim.K, sim.dist))
    out["views"] = found
    out["fx_px"] = float(sim.K[0, 0])
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--supersample", type=int, default=3)
    ap.add_argument("--square-mm", type=float, default=25.0)
    ap.add_argument("--imaging", default="realistic", choices=("realistic", "ideal"))
    ap.add_argument("--off", nargs="*", default=[], help="stages of the realistic profile switched off")
    ap.add_argument("--json", default=None)
    ap.add_argument("--save-images", default=None, help="also write the grey renders here (PNG)")
    args = ap.parse_args(argv)
    if not 1 <= args.supersample <= 8:
        raise SystemExit(f"--supersample: expected 1..8, got {args.supersample}")
    if not 5.0 <= args.square_mm <= 100.0:
        raise SystemExit(f"--square-mm: expected 5..100 mm, got {args.square_mm}")
    from bench.errors import BenchError
    from bench.sim.imaging import imaging_profile

    try:
        imaging_profile(args.imaging, list(args.off), source="real_webcam_sim", field="--imaging")
    except BenchError as e:
        raise SystemExit(str(e).replace("--imaging_off", "--off")) from None
    if any(s < 0 for s in args.seeds):
        raise SystemExit(f"--seeds: expected non-negative integers, got {args.seeds}")
    res, real_views = real_calibration()
    real = rcs.residual_statistics(res.residuals_px, PATTERN)
    real.update(rcs.measure_sift_precision(real_views, PATTERN, res.K, res.dist))
    sims = {}
    for seed in args.seeds:
        sims[seed] = simulate(res, seed, args.square_mm * 1e-3, args.supersample, args.imaging, args.off,
                              args.save_images)
        print(f"seed {seed}: " + ", ".join(f"{k} {sims[seed][k]:.3f}" for k in STATS), file=sys.stderr)
    print(f"{'statistic':<18}{'real':>10}{'sim median':>12}{'sim range':>18}")
    summary = {}
    for k in STATS:
        v = [s[k] for s in sims.values()]
        summary[k] = {"real": real[k], "sim_median": statistics.median(v), "sim_min": min(v), "sim_max": max(v)}
        print(f"{k:<18}{real[k]:>10.3f}{statistics.median(v):>12.3f}{f'{min(v):.3f}..{max(v):.3f}':>18}")
    ratio = summary["rms_px"]["sim_median"] / real["rms_px"]
    print(f"RMS sim / real {ratio:.2f} (issue 12 target 0.7..1.3)")
    if args.json:
        Path(args.json).write_text(json.dumps({"args": vars(args), "real": {k: real[k] for k in STATS},
                                               "sims": {str(s): v for s, v in sims.items()}, "summary": summary},
                                              indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
