"""``make benchmark``: speed and accuracy figures as medians over repeated runs, written to one JSON file.

Steps of the pipeline (identification, FK + Jacobian, SIFT, matching, map building, the in-situ solve, camera
calibration), the renderer, whole scenario runs (Table 2, the in-situ scenario, the full x-y table webcam run with
its renders cached), and - measured in the same run - the same steps by the obvious peer as ratios: Pinocchio for
forward kinematics, OpenCV ``calibrateCamera`` for camera calibration (same detections), OpenCV ``solvePnPRansac``
for localisation (same map and view). Targets are those of the issues; they are benchmarks, not tests. The block
between the markers of ``docs/benchmarks.md`` is regenerated from the JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.robot.identifiability import closed_form_reduction  # noqa: E402
from bench.robot.identification import identify_iterative, identify_linear  # noqa: E402
from bench.robot.jacobian import identification_jacobian  # noqa: E402
from bench.robot.kinematics import ee_position  # noqa: E402
from bench.robot.model import default_robot_path, load_robot, random_errors  # noqa: E402


def median_time(fn, repeats):
    fn()  # warm-up
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def vision_and_render(repeats: int) -> dict:
    """SIFT per 640x480 image and render fps of the panel scene through each optics chain (supersample 2)."""
    from bench.camera.presets import load_preset
    from bench.geometry.transforms import homogeneous
    from bench.sim.campaign import ArmScene
    from bench.sim.mjcf import NOMINAL_T_LINK5_CAM
    from bench.sim.optics_presets import optics_preset
    from bench.sim.scenes.base import place
    from bench.sim.scenes.panel import manifold_panel
    from bench.sim.views import camera_frames
    from bench.vision.features import detect_sift

    robot = load_robot(default_robot_path())
    q = np.deg2rad([28.0, 37.0, 49.0, 82.0, 29.0, 0.0])
    T_cam = camera_frames(robot, q, NOMINAL_T_LINK5_CAM)
    R = np.column_stack([T_cam[:3, 0], -T_cam[:3, 1], -T_cam[:3, 2]])  # panel x, y (up), z (out): facing the camera
    panel = place(manifold_panel(np.random.default_rng(0)), homogeneous(R, T_cam[:3, 3] + T_cam[:3, 2]), "panel_site")
    from bench.sim.imaging import imaging_profile

    out = {}
    img = None
    # (figure suffix, optics preset, imaging profile): the ideal chains, then the underwater chain + realistic imaging
    for key, name, imaging in (("air_webcam", "air_webcam", "ideal"),
                               ("underwater_in_water", "underwater_in_water", "ideal"),
                               ("realistic_underwater_in_water", "underwater_in_water", "realistic")):
        optics = optics_preset(name)
        scene = ArmScene(robot, None, np.eye(4), NOMINAL_T_LINK5_CAM, load_preset(optics.lens_camera), [panel], 2,
                         optics.chain, None, port=optics.port, imaging=imaging_profile(imaging))
        frame = scene.render(q, 0)  # warm-up: maps and rays built once
        times, cpu = [], []
        for k in range(max(3, repeats // 4)):
            t0, c0 = time.perf_counter(), time.process_time()
            scene.render(q + 1e-4 * k, k)
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)  # all threads of the process (renderer, bands): load-independent
        scene.close()
        out[f"render_fps_{key}"] = 1.0 / statistics.median(times)
        out[f"render_cpu_ms_{key}"] = 1e3 * statistics.median(cpu)
        out[f"panel_sift_keypoints_{key}"] = float(len(detect_sift(frame, channel_order="rgb")))
        img = frame if img is None else img
    # issue 12: realistic imaging (the default) costs at most 1.5x the ideal underwater chain per frame (CPU ms)
    out["render_ms_realistic"] = 1e3 / out["render_fps_realistic_underwater_in_water"]
    out["render_cpu_ratio_realistic_over_underwater"] = (out["render_cpu_ms_realistic_underwater_in_water"]
                                                         / out["render_cpu_ms_underwater_in_water"])
    # the figure: the panel scene at 640 x 480, supersampled, through the underwater chain (port + medium)
    out["render_fps"] = out["render_fps_underwater_in_water"]
    out["sift_640x480_s"] = median_time(lambda: detect_sift(img, channel_order="rgb"), repeats)
    out["panel_sift_keypoints"] = out["panel_sift_keypoints_air_webcam"]  # img is the air frame
    return out


def pipeline_steps(run_dir: Path, repeats: int) -> dict:
    """Matching, map building, the two-view solve and the PnP peer, camera calibration and the OpenCV peer, on the
    dataset and calibration files of an in-situ run (``run_dir``)."""
    import yaml

    from bench.camera.calibrate_dataset import detect_dataset_corners
    from bench.camera.calibration import calibrate_camera, opencv_reference
    from bench.geometry.transforms import invert
    from bench.scenario.results import pose_errors
    from bench.vision.features import match_descriptors, orientation_filter
    from bench.vision.insitu import build_map, locate, locate_pnp
    from bench.vision.locate_dataset import locate_dataset

    details: dict = {}
    locate_dataset(run_dir / "dataset", None, verbose=False, camera_path=run_dir / "calibrated" / "camera.yaml",
                   robot_path=run_dir / "calibrated" / "robot.yaml", details=details)
    obs, kmap, cam = details["observations"], details["map"], details["camera"]
    truth = yaml.safe_load((run_dir / "dataset" / "truth" / "truth.yaml").read_text())
    roles = {n: truth["views"][n]["role"] for n in obs}
    ref = obs[[n for n, r in roles.items() if r == "reference"][0]]
    surround = [obs[n] for n, r in roles.items() if r == "surround"]
    a, b = (obs[n] for n in [n for n, r in roles.items() if r == "locate"][:2])
    T_true = invert(np.array(truth["T_world_base_survey"])) @ np.array(truth["T_world_base_locate"])
    out = {}
    out["matching_s"] = median_time(lambda: orientation_filter(ref.features, a.features,
                                                               match_descriptors(ref.features, a.features)), repeats)
    out["map_building_s"] = median_time(lambda: build_map(ref, surround), repeats)
    out["insitu_solve_s"] = median_time(lambda: locate(kmap, a, b, rng=0), repeats)
    out["pnp_solve_s"] = median_time(lambda: locate_pnp(kmap, a, focal_px=cam.fx), repeats)
    out["solve_time_ratio_ours_over_pnp"] = out["insitu_solve_s"] / out["pnp_solve_s"]
    for key, res in (("two_view", locate(kmap, a, b, rng=0)), ("pnp", locate_pnp(kmap, a, focal_px=cam.fx))):
        if res.success:
            out[f"{key}_base_pos_err_mm"], out[f"{key}_base_rot_err_deg"] = pose_errors(res.T_world_base, T_true)
    corners = detect_dataset_corners(run_dir / "dataset", extractor="opencv")
    Xs, uvs, size = corners.object_points, corners.image_points, corners.image_size
    ours = calibrate_camera(Xs, uvs, size, model="heikkila")
    peer = opencv_reference(Xs, uvs, size, model="heikkila")
    out["camera_calibration_s"] = median_time(lambda: calibrate_camera(Xs, uvs, size, model="heikkila"),
                                              max(3, repeats // 4))
    # the peer as OpenCV runs by default (its threads); the pipeline's reference runs on one thread to reproduce
    out["opencv_calibrate_camera_s"] = median_time(lambda: opencv_reference(Xs, uvs, size, model="heikkila",
                                                                            one_thread=False), max(3, repeats // 4))
    out["calibration_time_ratio_ours_over_opencv"] = out["camera_calibration_s"] / out["opencv_calibrate_camera_s"]
    out["calibration_rms_px"], out["opencv_calibration_rms_px"] = float(ours.rms_px), float(peer.rms_px)
    out["calibration_views"] = float(len(Xs))
    return out


def xy_table_run(tmp: Path) -> dict:
    """The full x-y table webcam run (all intraocular distances, four methods) with its renders cached."""
    from bench.scenario.runner import run_scenario_file

    scenario = ROOT / "scenarios" / "xy_table_webcam.yaml"
    run_scenario_file(scenario, out=tmp / "xy" / "first", verbose=False, quiet=True)  # fills the render cache
    t0 = time.perf_counter()
    path = run_scenario_file(scenario, out=tmp / "xy" / "cached", verbose=False, quiet=True)
    wall = time.perf_counter() - t0
    res = json.loads(Path(path).read_text())
    return {"xy_table_webcam_run_cached_s": wall,
            **{f"xy_table_webcam.{k}": res["metrics"][k] for k in ("lms_ratio_err_x_mm_at_100",
                                                                   "lms_ratio_err_y_mm_at_100",
                                                                   "lms_ratio_err_z_mm_at_100") if k in res["metrics"]}}


TARGETS = {"render_cpu_ratio_realistic_over_underwater": 1.5,
           "fk_jacobian_10000_s": 0.050, "identification_100_iterative_s": 0.020, "render_fps": 5.0,
           "sift_640x480_s": 0.1, "insitu_solve_s": 0.3, "insitu.insitu_solve_s": 0.3, "insitu.base_pos_err_mm": 2.0,
           "insitu.base_rot_err_deg": 0.05, "xy_table_webcam_run_cached_s": 60.0,
           "table2.max_abs_reduced_error_linear": 1e-9, "table2.heldout_rms_mm_noise_free_exact": 1e-6,
           "table2.heldout_rms_mm_calibrated": 0.03}
BEGIN, END = "<!-- benchmark:begin -->", "<!-- benchmark:end -->"


def doc_block(doc: dict) -> str:
    """The Benchmarks block of docs/benchmarks.md: every figure with its target, and the machine."""
    m, targets = doc["machine"], doc["targets"]
    rows = [f"| `{k}` | {v:.4g} | {f'{targets[k]:.3g}' if k in targets else ''} |" for k, v in doc["figures"].items()]
    head = (f"*Generated by `make benchmark` on {doc['date']} ({m['processor']}, {m['cpus']} CPUs, Python "
            f"{m['python']}, load average {m['load_average']:.1f} at the start); medians over {doc['repeats']} "
            "repeats where a step is repeated.*")
    return "\n".join([BEGIN, head, "", "| figure | value | target |", "|---|---|---|", *rows, END])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default="runs/benchmark.json")
    ap.add_argument("--repeats", type=int, default=21)
    ap.add_argument("--skip-scenario", action="store_true", help="speed figures only")
    ap.add_argument("--doc", default=str(ROOT / "docs" / "benchmarks.md"),
                    help="markdown file whose Benchmarks block is regenerated ('' to leave it)")
    args = ap.parse_args(argv)
    load = os.getloadavg()[0]
    rng = np.random.default_rng(0)
    robot = load_robot(default_robot_path())
    red = closed_form_reduction(robot)
    figures: dict[str, float] = {}

    q10k = robot.random_configurations(rng, 10_000)
    figures["fk_jacobian_10000_s"] = median_time(lambda: identification_jacobian(robot, q10k, return_points=True),
                                                 args.repeats)
    figures["fk_10000_s"] = median_time(lambda: ee_position(robot, q10k), args.repeats)
    from bench.judge.pinocchio_model import PinocchioArm

    arm = PinocchioArm(robot)
    figures["pinocchio_ee_10000_s"] = median_time(lambda: arm.ee_position(q10k), max(3, args.repeats // 4))
    figures["fk_speed_ratio_pinocchio_over_ours"] = figures["pinocchio_ee_10000_s"] / figures["fk_10000_s"]

    eps = random_errors(rng, robot.n + 1)
    eps[-6:] = 0.0
    q100 = robot.random_configurations(rng, 100)
    pts = ee_position(robot, q100, eps) + rng.normal(scale=5e-5, size=(100, 3))
    figures["identification_100_linear_s"] = median_time(lambda: identify_linear(robot, q100, pts, red, 5e-5),
                                                         args.repeats)
    figures["identification_100_iterative_s"] = median_time(
        lambda: identify_iterative(robot, q100, pts, red, 5e-5), args.repeats)

    figures.update(vision_and_render(args.repeats))

    if not args.skip_scenario:
        from bench.scenario.runner import run_scenario_file

        with tempfile.TemporaryDirectory() as tmp:
            path = run_scenario_file(ROOT / "scenarios" / "table2_kinematic_identification.yaml", out=tmp,
                                     verbose=False)
            res = json.loads(Path(path).read_text())
        for k in ("max_abs_reduced_error_linear", "heldout_rms_mm_uncalibrated", "heldout_rms_mm_calibrated",
                  "heldout_rms_mm_noise_free_exact", "mc_std_ratio_median", "mc_std_ratio_min", "mc_std_ratio_max",
                  "mc_heldout_rms_mm_median", "heldout_rms_mm_selected_poses_median",
                  "heldout_rms_mm_random_poses_median"):
            figures[f"table2.{k}"] = res["metrics"][k]
        figures["table2.scenario_total_s"] = res["timings_s"]["total"]
        with tempfile.TemporaryDirectory() as tmp:
            path = run_scenario_file(ROOT / "scenarios" / "ta40_in_situ_manifold.yaml", out=Path(tmp) / "run",
                                     verbose=False, overrides=["outputs.cache=false"])
            res = json.loads(Path(path).read_text())
            for k in ("base_pos_err_mm", "base_rot_err_deg", "valve_tool_err_mm", "insitu_solve_s", "map_points",
                      "inliers", "render_fps", "panel_sift_keypoints", "marker_projection_rms_px",
                      "sim_vs_fk_max_err_m", "sim_vs_pinocchio_max_err_m", "distortion_roundtrip_max_px"):
                if k in res["metrics"]:
                    figures[f"insitu.{k}"] = res["metrics"][k]
            figures["insitu.scenario_total_s"] = res["timings_s"]["total_s"]
            figures.update(pipeline_steps(Path(tmp) / "run", args.repeats))
            figures.update(xy_table_run(Path(tmp)))

    doc = {"figures": figures, "repeats": args.repeats, "date": time.strftime("%Y-%m-%d"),
           "machine": {"python": platform.python_version(), "processor": platform.machine(),
                       "cpus": os.cpu_count(), "load_average": load, "numpy": np.__version__},
           "targets": {k: v for k, v in TARGETS.items() if k in figures}}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(doc, indent=2) + "\n")
    print(f"{'figure':<48}{'value':>14}{'target':>12}")
    for k, v in figures.items():
        t = doc["targets"].get(k)
        print(f"{k:<48}{v:>14.6g}{'' if t is None else f'{t:>12.3g}'}")
    print(f"wrote {out}")
    if args.doc:
        page = Path(args.doc)
        text = page.read_text() if page.is_file() else ""
        if BEGIN in text and END in text:
            page.write_text(text[:text.index(BEGIN)] + doc_block(doc) + text[text.index(END) + len(END):])
            print(f"updated the Benchmarks block of {page}")
        else:
            print(f"{page}: no {BEGIN} ... {END} block; not updated (the figures are in {out})", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
