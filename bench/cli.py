"""The ``bench`` command line (see ``shared/design.md``: ``bench run SCENARIO [--out DIR] [--seed N] [--set k=v]``)."""

from __future__ import annotations

import argparse
import contextlib
import os
import sys

from bench.errors import BenchError


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="bench", description="In-situ calibration bench for subsea manipulators.")
    sub = p.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run one scenario and write DIR/result.json")
    run.add_argument("scenario", help="scenario YAML file")
    run.add_argument("--out", default=None, help="output folder (default runs/<scenario name>)")
    run.add_argument("--seed", type=int, default=None, help="override the scenario's seed")
    run.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                     help="override a scenario key (dotted path), e.g. --set monte_carlo.seeds=50")
    run.add_argument("--quiet", action="store_true", help="print only the result path")

    sw = sub.add_parser("sweep", help="run a grid of scenario runs (resumable; one SQLite row per run)")
    sw.add_argument("scenario", help="scenario YAML file")
    sw.add_argument("--param", dest="params", action="append", default=[], metavar="KEY=V1,V2,...",
                    help="a swept scenario key and its values (repeatable: the grid is their product)")
    _add_grid_flags(sw, "seeds per grid point (seed, seed+1, ...; default 1)", 1, "sweep")
    sw.add_argument("--render-cache", default=None, metavar="DIR",
                    help="a render cache shared with other sweeps (e.g. an earlier sweep's OUT/runs/.render_cache): "
                         "the same seeds' images are taken from it, not rendered again")
    bu = sub.add_parser("budget", help="error budget: re-run with one error source switched off at a time")
    bu.add_argument("scenario", help="scenario YAML file (a kind that declares its error sources)")
    _add_grid_flags(bu, "seeds per variant (default 10)", 10, "budget")
    sim = sub.add_parser("sim", help="simulator commands")
    simsub = sim.add_subparsers(dest="sim_command", required=True)
    rend = simsub.add_parser("render", help="simulate a scenario's campaign and write its dataset (with truth/)")
    rend.add_argument("scenario", help="scenario YAML file (a kind that renders, e.g. in_situ)")
    rend.add_argument("--out", required=True, help="dataset folder to write (atomically; a previous render of the "
                                                    "same scenario there is replaced)")
    rend.add_argument("--seed", type=int, default=None)
    rend.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    rend.add_argument("--no-cache", action="store_true", help="render every view even if cached")
    raw = simsub.add_parser("export-raw", help="write a rendered dataset as raw files (JPEG photos, joint log in "
                                               "degrees, tracker export), truth dropped (docs/tutorial_real_data.md)")
    raw.add_argument("dataset", help="rendered dataset (bench sim render)")
    raw.add_argument("--out", required=True, help="new folder for the raw files")
    raw.add_argument("--jpeg-quality", type=int, default=95, help="JPEG quality of the photos (1-100, default 95)")

    loc = sub.add_parser("locate", help="in-situ base localisation on a dataset folder (section 3.9)")
    loc.add_argument("dataset", help="dataset folder (manifest.yaml, images/, joints.csv, camera.yaml, robot.yaml)")
    loc.add_argument("--out", default=None, help="folder for locate.json (default: print only)")
    loc.add_argument("--method", choices=("svd", "horn", "rodrigues"), default="svd",
                     help="absolute-orientation estimator (rodrigues = the thesis's quaternion method)")
    loc.add_argument("--pnp", action="store_true", help="single-view PnP against the map instead of two views")
    loc.add_argument("--refine", choices=("none", "pose", "bundle", "joints"), default="bundle",
                     help="after the thesis's alignment: none, the pose on the reprojection error (map fixed), "
                          "the pose and the map points together (default), or joints: also every view's joint angles "
                          "under the encoder prior of the dataset's encoders.yaml")
    loc.add_argument("--priors", default=None, help="with --refine joints: calibration_priors.yaml (the lab "
                     "calibrations' covariances) - the intrinsics and the mount (and the distortion, when the file "
                     "has distortion_covariance) are refined under them")
    loc.add_argument("--refine-k3", action="store_true", help="with --priors: the joint bundle also refines the "
                     "lens's k3 (which a Heikkila calibration holds fixed), under the priors file's "
                     "distortion_k3_sd or a wide default (bench.vision.joint_bundle.K3_PRIOR_SD)")
    loc.add_argument("--guided", action="store_true", help="with --refine joints: search the map again in both "
                     "locate views at the refined poses and re-run the joint bundle (bench.vision.guided)")
    loc.add_argument("--loss", choices=("none", "huber"), default="none", help="with --refine joints: the joint "
                     "bundle's loss, least squares (none) or Huber's M-estimate")
    loc.add_argument("--map-points", choices=("all", "located"), default="all", help="with --refine joints: the "
                     "map points the joint bundle weighs, all or only those both locate views matched")
    loc.add_argument("--keypoints", choices=("sift", "aligned"), default="sift", help="SIFT's keypoints (the "
                     "thesis's) or aligned: each matched keypoint moved onto its reference keypoint's image patch "
                     "(bench.vision.patch_align)")
    loc.add_argument("--twin-keypoints", choices=("both", "once", "weighted"), default="both", help="SIFT's twin "
                     "keypoints (a second orientation at the same pixel): both copies (the thesis's map, which counts "
                     "such a point twice in the covariance), one map point per detection, or both copies with each "
                     "view's shared keypoint weighed as what it is worth (bench.vision.insitu.TWIN_WORTH) in the joint "
                     "bundle")
    loc.add_argument("--covariance", choices=("white", "field"), default="white", help="with --refine joints: the "
                     "pose's covariance of white pixel noise, or with each view's keypoint error field measured on "
                     "the joint bundle's residuals (bench.vision.field_covariance)")
    loc.add_argument("--ins-tilt", choices=("fuse", "check"), default="fuse", help="with the dataset's vehicle.yaml "
                     "(the vehicle's INS): test 7, then the INS's tilt fused into the pose (fuse), or test 7 only "
                     "(check) (bench.vision.tilt)")
    loc.add_argument("--seed", type=int, default=0, help="RANSAC seed")
    loc.add_argument("--robot", default=None, help="calibrated robot file (default: the dataset's robot.yaml)")
    loc.add_argument("--camera", default=None, help="calibrated camera file (default: the dataset's camera.yaml)")
    fa = sub.add_parser("faults", help="inject dive faults into copies of a rendered in-situ dataset, localise and "
                                       "score each (integrity, protection radius, silent failures)")
    fa.add_argument("dataset", help="rendered in-situ dataset (bench sim render; with truth/)")
    fa.add_argument("--out", required=True, help="folder for faults.csv, faults.json and each fault's locate.json")
    fa.add_argument("--fault", action="append", default=None, help="only this fault (repeatable; default: all)")
    fa.add_argument("--seed", type=int, default=0, help="draws of the random faults and the RANSAC seed")
    fa.add_argument("--camera", default=None, help="lab camera calibration (default: calibrated from the dataset)")
    fa.add_argument("--robot", default=None, help="lab robot calibration (default: calibrated from the dataset)")
    fa.add_argument("--refine", default="joints", choices=["none", "pose", "bundle", "joints"],
                    help="the estimator (as bench locate --refine; default joints, the in-situ scenario's)")
    fa.add_argument("--priors", default=None, help="with --refine joints: the lab's calibration_priors.yaml (default: "
                    "the one calibrated from the dataset; none when --camera / --robot are given without it)")
    fa.add_argument("--keypoints", choices=("sift", "aligned"), default="sift",
                    help="the keypoints (as bench locate --keypoints)")
    fa.add_argument("--covariance", choices=("white", "field"), default="white",
                    help="with --refine joints: the pose's covariance (as bench locate --covariance)")
    fa.add_argument("--twin-keypoints", choices=("both", "once", "weighted"), default="both",
                    help="SIFT's twin keypoints (as bench locate --twin-keypoints)")
    fa.add_argument("--force", action="store_true", help="replace an earlier output of bench faults in --out")
    cc = sub.add_parser("calibrate-camera", help="corners + calibration (+ OpenCV reference) on a rig dataset or a "
                                                 "plain folder of photos")
    cc.add_argument("dataset", help="dataset folder (rig views, target.yaml) or a plain folder of photos (give the "
                                    "target by --target ...)")
    cc.add_argument("--out", required=True, help="folder for camera.yaml, calibration.json, per_view.csv, plots")
    cc.add_argument("--model", choices=("heikkila", "radial", "pinhole"), default="heikkila")
    cc.add_argument("--k3", action="store_true", help="also fit the third radial coefficient k3")
    cc.add_argument("--robot", default=None, help="(calibrated) robot file: also calibrate the camera mount on link 5 "
                                                  "(AX = XB from the views' joint readings) into OUT/robot.yaml")
    _add_target_flags(cc)
    cc.add_argument("--extractor", choices=("thesis", "opencv"), default="thesis",
                    help="corner extractor: the thesis's edge/k-means method or OpenCV's")
    _add_interchange_commands(sub)
    _add_dataset_commands(sub)
    for writer in [*(sub.choices[c] for c in _WRITERS), rend]:
        writer.add_argument("--force", action="store_true",
                            help="replace a previous output of this same command at --out (never a folder or file "
                                 "that bench did not write, nor another command's output)")
    from bench.robot import commands as robot_commands

    robot_commands.add_parsers(sub)
    return p


def _add_grid_flags(parser, seeds_help: str, seeds: int, command: str) -> None:
    """The flags ``bench sweep`` and ``bench budget`` share: the fixed overrides, the seeds, the backend, the folder."""
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="a fixed override for every run")
    parser.add_argument("--seeds", type=int, default=seeds, help=seeds_help)
    parser.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    parser.add_argument("--backend", choices=("local", "ray"), default="local")
    parser.add_argument("--address", default=None, help="Ray cluster address (default: a local Ray instance)")
    parser.add_argument("--workers", type=int, default=None, help="local processes (default: CPU count)")
    parser.add_argument("--out", default=None, help=f"{command} folder (default runs/{command}-<scenario name>)")


def _add_target_flags(parser) -> None:
    """``--target chessboard --inner WxH --square-mm S`` or ``--target two_plane_rig --size-mm S [--squares N]
    [--margin-mm M]``: the calibration target (what ``target.yaml`` holds; docs/tutorial_real_data.md)."""
    parser.add_argument("--target", choices=("chessboard", "two_plane_rig"), default=None,
                        help="calibration target type (a dataset's target.yaml says it otherwise)")
    parser.add_argument("--inner", default=None, metavar="WxH", help="chessboard: inner corners per row x rows")
    parser.add_argument("--square-mm", type=float, default=None, help="chessboard: side of a square (mm)")
    parser.add_argument("--size-mm", type=float, default=None, help="two_plane_rig: side of one board's pattern (mm)")
    parser.add_argument("--squares", type=int, default=None, help="two_plane_rig: squares per side (default 7)")
    parser.add_argument("--margin-mm", type=float, default=None, help="two_plane_rig: border to the pattern (mm)")


def _target_from_flags(args):
    from bench.camera.calibrate_dataset import target_spec

    given = [f for f in ("inner", "square_mm", "size_mm", "squares", "margin_mm") if getattr(args, f) is not None]
    if args.target is None:
        if given:
            raise BenchError(f"--{given[0].replace('_', '-')}: describes a target; give --target too")
        return None
    return target_spec(args.target, args.inner, args.square_mm, args.squares, args.size_mm, args.margin_mm)


def _add_dataset_commands(sub) -> None:
    """``bench dataset init``: a dataset folder from raw files (bench/dataset_init.py, docs/tutorial_real_data.md)."""
    ds = sub.add_parser("dataset", help="dataset folder commands")
    dsub = ds.add_subparsers(dest="dataset_command", required=True)
    di = dsub.add_parser("init", help="build a dataset folder from photos, a joint log, a tracker export and the "
                                      "nominal robot/camera files")
    di.add_argument("--out", required=True, help="dataset folder to create (new or empty)")
    di.add_argument("--images", default=None, help="folder of photos (JPEG/PNG), one per view, named by view")
    di.add_argument("--joints", default=None, help="joint log: a row per view (and per taught frame)")
    di.add_argument("--joint-units", choices=("deg", "rad"), default=None,
                    help="the joint log's unit, unless its columns or a '# units:' line state it")
    di.add_argument("--tracker", default=None, help="laser-tracker export (points with their joint readings)")
    di.add_argument("--tracker-units", choices=("mm", "m"), default=None, help="the tracker export's length unit")
    di.add_argument("--tracker-joints", default=None, help="joint log of the tracker points (if not in the export)")
    di.add_argument("--tracker-joint-units", choices=("deg", "rad"), default=None,
                    help="unit of the tracker points' joint readings")
    di.add_argument("--robot", default=None, help="nominal robot file (e.g. models/ta40.yaml)")
    di.add_argument("--camera", default=None, help="nominal camera file (camera.yaml)")
    di.add_argument("--role", dest="roles", action="append", default=[], metavar="ROLE=PATTERN",
                    help="views whose name matches PATTERN get ROLE (rig, reference, surround, locate, task)")
    di.add_argument("--region", dest="regions", action="append", default=[], metavar="NAME=PATTERN",
                    help="a survey over several parts of the scene: its reference, surrounding and locate views whose "
                         "name matches PATTERN are region NAME (each one's map and locate views; bench locate "
                         "solves the regions together)")
    di.add_argument("--kind", choices=("in_situ", "camera_calibration", "kinematic"), default=None,
                    help="campaign kind (default: from the files given)")
    di.add_argument("--name", default=None, help="dataset name (default: the folder's name)")
    _add_target_flags(di)


def _dataset_command(args) -> int:
    from bench.dataset_init import init_dataset

    res = init_dataset(args.out, args.images, args.joints, args.joint_units, args.tracker, args.tracker_units,
                       args.tracker_joints, args.tracker_joint_units, args.robot, args.camera, args.roles, args.kind,
                       _target_from_flags(args), args.name, args.regions)
    roles = ", ".join(f"{n} {r}" for r, n in res.roles.items())
    print(f"wrote {res.root} ({res.kind}: {res.views} views - {roles}; {res.tracker_points} tracker points)")
    return 0


_INTERCHANGE = ("export", "export-camera", "import-tracker", "import-joints")
#: commands that write an output folder or file (bench.fileio: they claim it first); plus ``sim render``
_WRITERS = ("run", "sweep", "budget", "locate", "calibrate-camera", *_INTERCHANGE)


def _preflight(args, stack) -> None:
    """Checks before any work: a negative ``--seed`` (any command), ``--seeds`` below 1 (sweep, budget);
    ``locate --out`` and ``calibrate-camera --out`` write their folder at the end: refuse a foreign one now, mark what
    they wrote when they end (:func:`bench.fileio.writing_output_dir`); the other commands claim their own."""
    seed, seeds = getattr(args, "seed", None), getattr(args, "seeds", None)
    if seed is not None and seed < 0:
        raise BenchError(f"--seed: expected a non-negative integer, got {seed}")
    if seeds is not None and seeds < 1:
        raise BenchError(f"--seeds: must be >= 1, got {seeds}")
    if args.command in ("locate", "calibrate-camera") and getattr(args, "out", None):
        from bench.fileio import writing_output_dir

        stack.enter_context(writing_output_dir(args.out, args.command, force=args.force, identity=_identity(args)))


def _identity(args) -> str:
    """``bench locate`` / ``calibrate-camera --out``'s identity: the inputs and every option the result depends on
    (a re-run with them writes into the folder again; another camera file, seed, model, ... is refused without
    --force, naming what differs)."""
    from bench.fileio import settings_identity

    if args.command == "calibrate-camera":
        return settings_identity({"dataset": args.dataset, "robot": args.robot}, model=args.model, k3=args.k3,
                                 extractor=args.extractor, target=args.target, inner=args.inner,
                                 square_mm=args.square_mm, squares=args.squares, size_mm=args.size_mm,
                                 margin_mm=args.margin_mm)
    return settings_identity({"dataset": args.dataset, "camera": args.camera, "robot": args.robot,
                              "priors": args.priors}, method=args.method, pnp=args.pnp, refine=args.refine,
                             guided=args.guided, loss=args.loss, map_points=args.map_points,
                             keypoints=args.keypoints, ins_tilt=args.ins_tilt, seed=args.seed,
                             **({} if args.covariance == "white" else {"covariance": args.covariance}))


def _add_interchange_commands(sub) -> None:
    """``bench export``, ``export-camera``, ``import-tracker``, ``import-joints`` (README: Interchange)."""
    ex = sub.add_parser("export", help="write a (calibrated) robot file as URDF or MJCF")
    ex.add_argument("robot", help="robot.yaml, e.g. the calibrated one (errors + camera mount)")
    ex.add_argument("--format", required=True, choices=("urdf", "mjcf"))
    ex.add_argument("--out", required=True, help="file to write (atomically)")
    ex.add_argument("--name", default=None, help="model name in the file (default: the robot file's name)")
    ex.add_argument("--velocity-deg-s", type=float, default=None, help="URDF joint speed limit (default: 0 = unknown)")
    ex.add_argument("--effort-nm", type=float, default=None, help="URDF joint effort limit (default: 0 = unknown)")
    ec = sub.add_parser("export-camera", help="write camera.yaml as OpenCV FileStorage YAML or ROS camera_info")
    ec.add_argument("camera", help="camera.yaml")
    ec.add_argument("--format", required=True, choices=("opencv", "ros"))
    ec.add_argument("--out", required=True, help="file to write (atomically)")
    it = sub.add_parser("import-tracker", help="convert a laser-tracker export to the dataset's tracker.csv")
    it.add_argument("file", help="tracker export (CSV; units in the column names or given by --units)")
    it.add_argument("--units", choices=("mm", "m"), default=None, help="the coordinates' unit")
    it.add_argument("--joints", default=None, help="joint log with a reading per point (matched by name)")
    it.add_argument("--joint-units", choices=("deg", "rad"), default=None, help="the joint readings' unit")
    it.add_argument("--out", required=True, help="tracker.csv to write (atomically)")
    ij = sub.add_parser("import-joints", help="convert a joint log to the dataset's joints.csv")
    ij.add_argument("file", help="joint log (CSV; units in the column names or given by --units)")
    ij.add_argument("--units", choices=("deg", "rad"), default=None, help="the readings' unit")
    ij.add_argument("--out", required=True, help="joints.csv to write (atomically)")


def _interchange(args) -> int:
    if args.command == "export":
        from math import radians

        from bench.robot.export import export_robot

        for opt, val in (("--velocity-deg-s", args.velocity_deg_s), ("--effort-nm", args.effort_nm)):
            if val is not None and not val > 0:
                raise BenchError(f"{opt}: expected a positive limit, got {val}")
        vel = None if args.velocity_deg_s is None else radians(args.velocity_deg_s)
        path = export_robot(args.robot, args.format, args.out, args.name, vel, args.effort_nm, force=args.force)
        print(f"wrote {path} ({args.format.upper()})")
        if args.format == "urdf" and (vel is None or args.effort_nm is None):  # after the write: errors come alone
            print("bench: warning: URDF joint limits: effort and velocity are not known to the robot file; written as "
                  "0 (= unknown, with a comment), which a consumer may read as 'cannot move' or 'unlimited': give "
                  "--velocity-deg-s and --effort-nm", file=sys.stderr)
    elif args.command == "export-camera":
        from bench.camera.export import export_camera

        print(f"wrote {export_camera(args.camera, args.format, args.out, force=args.force)} ({args.format})")
    else:
        from bench.robot.importers import import_joints, import_tracker

        res = (import_tracker(args.file, args.out, args.units, args.joints, args.joint_units, force=args.force)
               if args.command == "import-tracker" else import_joints(args.file, args.out, args.units,
                                                                      force=args.force))
        print(f"wrote {res.path}: {res.rows} rows (read in {', '.join(res.units.values())})")
    return 0


def _sim_render(args) -> None:
    from pathlib import Path

    from bench.scenario.runner import kind_module, load_scenario

    cfg = load_scenario(args.scenario, args.seed, args.overrides)
    module = kind_module(cfg["kind"])
    if not hasattr(module, "render"):
        raise BenchError(f"{args.scenario}: kind {cfg['kind']!r} has no simulated campaign to render")
    from bench.fileio import check_replaceable, claimed_output_dir

    cache = None if args.no_cache else Path(args.out).resolve().parent / ".render_cache"
    with claimed_output_dir(args.out, "sim render", force=args.force, identity=cfg["name"]):
        check_replaceable(args.out)  # a dataset is replaced whole: refuse a user's file in it before rendering
        checks = module.render(cfg, args.out, verbose=True, cache_dir=cache)
    for k, v in checks.items():
        print(f"  {k:<32} {v:.6g}" if isinstance(v, float) else f"  {k:<32} {v}")


def _sweep(args) -> None:
    from pathlib import Path

    from bench.config import parse_set
    from bench.scenario.sweep import parse_param, run_sweep

    params = [parse_param(p) for p in args.params]
    fixed = dict(parse_set(item) for item in args.overrides)
    out = args.out or str(Path("runs") / f"sweep-{Path(args.scenario).stem}")
    res = run_sweep(args.scenario, params, list(range(args.seed, args.seed + args.seeds)), out, args.backend,
                    args.address, args.workers, fixed=fixed, force=args.force, render_cache=args.render_cache)
    print(f"{res['rows']} finished runs in {res['store']}; summary {res['summary']}")
    for p in res["plots"]:
        print(f"plot {p}")
    if res.get("recording"):
        print(f"rerun recording {res['recording']}")
    for e in res["errors"]:
        print(f"failed: {e}")


def _budget(args) -> None:
    from pathlib import Path

    from bench.config import parse_set
    from bench.scenario.budget import run_budget

    fixed = dict(parse_set(item) for item in args.overrides)
    out = args.out or str(Path("runs") / f"budget-{Path(args.scenario).stem}")
    res = run_budget(args.scenario, list(range(args.seed, args.seed + args.seeds)), out, args.backend, args.address,
                     args.workers, fixed=fixed, force=args.force)
    for k, v in res["metrics"].items():
        print(f"  {k:<44} {v:.4g}")
    print(f"wrote {res['result']}")


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    stack = contextlib.ExitStack()
    try:
        _preflight(args, stack)
        if args.command == "run":
            from bench.scenario.runner import run_scenario_file

            run_scenario_file(args.scenario, out=args.out, seed=args.seed, overrides=args.overrides,
                              verbose=not args.quiet, force=args.force)
        elif args.command == "sweep":
            _sweep(args)
        elif args.command == "budget":
            _budget(args)
        elif args.command == "sim" and args.sim_command == "export-raw":
            from bench.sim.export_raw import export_raw

            res = export_raw(args.dataset, args.out, args.jpeg_quality)
            print(f"wrote {res['out']}: {res['photos']} photos, {res['frames']} joint-log rows, "
                  f"{res['tracker_points']} tracker points (no truth)")
        elif args.command == "sim":
            _sim_render(args)
        elif args.command == "calibrate-camera":
            from bench.camera.calibrate_dataset import calibrate_dataset

            res, _ = calibrate_dataset(args.dataset, args.out, model=args.model, extractor=args.extractor,
                                       target=_target_from_flags(args), k3=args.k3, robot=args.robot)
            return 0 if res.success else 1
        elif args.command == "locate":
            from bench.vision.insitu import twin_map_config
            from bench.vision.locate_dataset import locate_dataset

            if args.refine_k3 and not args.priors:
                raise BenchError("--refine-k3: needs --priors (k3 is refined with the lens's k1 k2 p1 p2 under the "
                                 "lab's covariance of them)")
            for flag, on in ((f"--priors {args.priors}", args.priors), ("--guided", args.guided),
                             (f"--loss {args.loss}", args.loss != "none"),
                             (f"--map-points {args.map_points}", args.map_points != "all"),
                             (f"--covariance {args.covariance}", args.covariance != "white")):
                if on and (args.refine != "joints" or args.pnp):
                    raise BenchError(f"{flag}: used only by --refine joints (two views), got --refine {args.refine}"
                                     f"{' --pnp' if args.pnp else ''}")
            res, rep = locate_dataset(args.dataset, args.out, method=args.method, pnp=args.pnp, seed=args.seed,
                                      camera_path=args.camera, robot_path=args.robot, refine=args.refine,
                                      priors_path=args.priors, guided=args.guided,
                                      loss=None if args.loss == "none" else args.loss, map_points=args.map_points,
                                      keypoints=args.keypoints, ins_tilt=args.ins_tilt, refine_k3=args.refine_k3,
                                      covariance=args.covariance,
                                      config=twin_map_config(args.twin_keypoints))
            return 0 if res.success and rep["integrity"] != "refused" else 1  # refused: do not use the pose
        elif args.command == "faults":
            from bench.scenario.faults import run_faults

            if args.covariance != "white" and args.refine != "joints":
                raise BenchError(f"--covariance {args.covariance}: used only by --refine joints, got --refine "
                                 f"{args.refine}")
            rows = run_faults(args.dataset, args.out, faults=args.fault, seed=args.seed, camera=args.camera,
                              robot=args.robot, force=args.force, refine=args.refine, priors=args.priors,
                              keypoints=args.keypoints, covariance=args.covariance,
                              twin_keypoints=args.twin_keypoints)
            return 1 if any(r["silent"] for r in rows) else 0
        elif args.command in _INTERCHANGE:
            return _interchange(args)
        elif args.command == "dataset":
            return _dataset_command(args)
        elif args.command in ("calibrate-robot", "check-robot"):
            from bench.robot import commands as robot_commands

            return robot_commands.run(args)
        return 0
    except BenchError as exc:
        print(f"bench: error: {exc}", file=sys.stderr)
        return 2
    except (ValueError, OSError) as exc:  # bad input caught by a library check: one line, not a traceback
        if os.environ.get("BENCH_DEBUG"):
            raise
        msg = " ".join(str(exc).split()) or type(exc).__name__
        print(f"bench: error: {msg} (BENCH_DEBUG=1 shows the traceback)", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("bench: interrupted", file=sys.stderr)
        return 130
    finally:
        stack.close()
