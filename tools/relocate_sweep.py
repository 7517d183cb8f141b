"""Re-localise every finished run of an in-situ sweep with this version of the pipeline, without re-rendering.

    python tools/relocate_sweep.py SWEEP_DIR SCENARIO [--name relocated] [--workers 1] [--force]
        [--set pipeline.KEY=VALUE ...] [--regions r0[,r1...]]

Each run of a ``bench sweep`` of an ``in_situ`` scenario keeps its dataset (``runs/<id>/dataset``) and the lab's
calibration of it (``runs/<id>/calibrated``: camera, arm + mount, and the calibration priors). This tool runs
:func:`bench.vision.locate_dataset.locate_dataset` on them again, with the scenario's own pipeline settings (as the
``in_situ`` kind passes them: ``pipeline.method``, ``refine``, the RANSAC keys, the run's seed) and writes
``runs/<id>/<name>/locate.json``; ``SCENARIO`` is the sweep's scenario file (a run that set a ``pipeline.*`` key
is redone only when ``--set`` gives the key the run's value, else the sweep is refused; so is one over
``sources.*``, whose runs used oracle files, and a scenario of another name than the runs'). Use: the integrity
tests or the estimator changed after a long sweep whose renders and lab calibrations did not (``git diff`` of
``bench/sim`` and of the calibrations is empty): the re-localised runs are then what a new sweep would give, at ~3 s
per run instead of ~25 s.
``tools/integrity_summary.py --locate <name>/locate.json`` summarises them.

``--regions r0`` localises each run from the views of the named regions of its survey only (the manifest's
``region``; a view without one, such as a taught task pose, is kept): the dataset is cut to them in
``runs/<id>/<name>/dataset`` (manifest, joint log, the images hard-linked; no ``truth/``) and localised from
there, so that a survey over several regions and the same survey's first region alone are compared on the same
renders (``tools/integrity_summary.py --against <name>/locate.json``); the default name is then
``regions_<names>``. A run already re-localised is skipped
(``--force`` redoes it, removing the old file first); a run that fails is reported and the others go on. The
workers end with this process, whatever ends it (:func:`bench.scenario.sweep._end_with_parent`).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _dotted(cfg: dict, key: str):
    """The value of a dotted ``key`` in the loaded scenario ``cfg`` (None where a level is missing)."""
    for part in key.split("."):
        cfg = cfg.get(part) if isinstance(cfg, dict) else None
    return cfg


def _runs(sweep: Path) -> list:
    """``[(run_id, seed, params)]`` of the finished runs."""
    from bench.scenario.sweep import read_runs

    if not (sweep / "sweep.sqlite").is_file():
        raise SystemExit(f"{sweep}: not a bench sweep folder (no sweep.sqlite)")
    return [(r["run_id"], int(r["seed"]), r["params"]) for r in read_runs(sweep)]


def locate_run(run: Path, seed: int, pipeline: dict, out=None, details=None, features_fn=None, dataset=None) -> tuple:
    """:func:`bench.vision.locate_dataset.locate_dataset` on a run's ``dataset/`` (or ``dataset``) with its
    ``calibrated/`` lab files and the scenario's ``pipeline`` settings, as the ``in_situ`` kind passes them;
    ``(result, report)``. ``features_fn`` replaces the SIFT detector (an evaluator's keypoints, as ``locate_dataset``
    takes it)."""
    import warnings

    from bench.scenario.in_situ_lab import refines_k3
    from bench.vision.insitu import twin_map_config
    from bench.vision.locate_dataset import locate_dataset

    cal = run / "calibrated"
    priors = cal / "calibration_priors.yaml"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return locate_dataset(run / "dataset" if dataset is None else dataset, out, method=pipeline["method"],
                              seed=seed,
                              config=twin_map_config(pipeline.get("twin_keypoints", "both")),
                              verbose=False, camera_path=cal / "camera.yaml", robot_path=cal / "robot.yaml",
                              refine=pipeline["refine"], ransac=dict(iterations=pipeline["ransac_iterations"],
                                                                     d_r=pipeline["d_r_mm"] * 1e-3,
                                                                     r_lim=pipeline["r_lim"]),
                              priors_path=priors if priors.is_file() and pipeline["refine"] == "joints" else None,
                              guided=pipeline.get("guided", False),
                              loss=None if pipeline.get("loss", "none") == "none" else pipeline["loss"],
                              map_points=pipeline.get("map_points", "all"), keypoints=pipeline.get("keypoints", "sift"),
                              pnp=pipeline.get("locate", "two_view") == "pnp", details=details,
                              ins_tilt=pipeline.get("ins_tilt", "fuse"),
                              refine_k3=refines_k3(pipeline), features_fn=features_fn,
                              covariance=pipeline.get("covariance", "white"))


#: The marker's command of a cut dataset (:func:`cut_regions`).
CUT = "relocate_sweep --regions"


def cut_regions(dataset: Path, regions: list, out: Path) -> Path:
    """A copy of ``dataset`` at ``out`` with only the views of ``regions`` (and the views without a region): the
    manifest's views and the joint log's rows cut to them, their images hard-linked (copied across file systems),
    the other files copied, ``truth/`` left out. A region the dataset does not have is a one-line error naming
    the manifest."""
    import csv
    import io
    import shutil

    import yaml

    from bench.errors import ConfigError
    from bench.fileio import OUTPUT_MARKER, check_output_dir, check_replaceable, mark_output_dir, record_output_entries

    man_path = dataset / "manifest.yaml"
    man = yaml.safe_load(man_path.read_text())
    views = man.get("views") or []
    have = list(dict.fromkeys(v.get("region") for v in views if v.get("region")))
    missing = [r for r in regions if r not in have]
    if missing:
        raise ConfigError(man_path, "views[].region", f"no region {missing[0]!r} (the survey's regions: "
                                                      f"{', '.join(have) or 'none'})")
    keep = [v for v in views if not v.get("region") or v["region"] in regions]
    # an earlier cut is replaced; a folder of anyone else's is refused (a one-line error naming it), never removed
    if check_output_dir(out, CUT, force=True, option="the cut dataset") in ("own", "replace"):
        check_replaceable(out, "the cut dataset")
        shutil.rmtree(out)
    out.mkdir(parents=True, exist_ok=True)
    for f in dataset.iterdir():
        if f.is_file() and f.name not in ("manifest.yaml", "joints.csv", OUTPUT_MARKER):
            shutil.copy2(f, out / f.name)
    for v in keep:
        if v.get("image"):
            dst = out / v["image"]
            dst.parent.mkdir(parents=True, exist_ok=True)
            try:
                os.link(dataset / v["image"], dst)
            except OSError:
                shutil.copy2(dataset / v["image"], dst)
    (out / "manifest.yaml").write_text(yaml.safe_dump({**man, "views": keep}, sort_keys=False))
    if (dataset / "joints.csv").is_file():
        names = {v["name"] for v in keep}
        lines = [ln for ln in (dataset / "joints.csv").read_text().splitlines() if ln.strip()]
        rows = list(csv.reader(lines))
        buf = io.StringIO()
        csv.writer(buf, lineterminator="\n").writerows([rows[0], *(r for r in rows[1:] if r and r[0] in names)])
        (out / "joints.csv").write_text(buf.getvalue())
    mark_output_dir(out, CUT)
    record_output_entries(out)
    return out


def relocate(run_dir: str, seed: int, pipeline: dict, name: str, regions=None) -> tuple:
    """One run: ``(run_id, integrity or the error, seconds)``; ``regions``: localised from those regions' views
    only (:func:`cut_regions`)."""
    from bench.errors import BenchError

    run = Path(run_dir)
    (run / name / "locate.json").unlink(missing_ok=True)  # never a stale result beside a failed run
    t0 = time.perf_counter()
    try:
        if regions:
            _, rep = locate_run(run, seed, pipeline, out=run / name,
                                dataset=cut_regions(run / "dataset", regions, run / name / "dataset"))
        else:
            _, rep = locate_run(run, seed, pipeline, out=run / name)
    except BenchError as exc:
        return run.name, f"error: {exc}", time.perf_counter() - t0
    except Exception as exc:  # noqa: BLE001 - one run's failure is reported; the others go on
        return run.name, f"error: {type(exc).__name__}: {exc}", time.perf_counter() - t0
    return run.name, rep["integrity"], time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sweep", type=Path)
    ap.add_argument("scenario", type=Path, help="the sweep's scenario file (its pipeline settings)")
    ap.add_argument("--name", help="sub-folder of each run for the new locate.json (default relocated, or "
                                   "regions_<names> with --regions)")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--force", action="store_true", help="re-localise runs already done")
    ap.add_argument("--set", action="append", default=[], metavar="pipeline.KEY=VALUE",
                    help="override a pipeline key of the scenario (e.g. pipeline.guided=true); repeatable")
    ap.add_argument("--regions", help="localise from these regions' views only, e.g. r0 (comma-separated)")
    args = ap.parse_args(argv)
    regions = [r.strip() for r in args.regions.split(",") if r.strip()] if args.regions is not None else None
    if regions is not None and not regions:
        raise SystemExit(f"--regions {args.regions!r}: expected region names separated by commas, e.g. r0")
    if args.name is None:
        args.name = "regions_" + "_".join(regions) if regions else "relocated"
    if args.workers < 1:
        raise SystemExit(f"--workers: expected >= 1, got {args.workers}")
    if not args.name or "/" in args.name or args.name.startswith(".") or args.name in ("dataset", "calibrated"):
        raise SystemExit(f"--name {args.name!r}: expected a new sub-folder name (not dataset or calibrated)")
    from bench.errors import BenchError
    from bench.scenario.runner import load_scenario

    for item in args.set:
        if not item.startswith("pipeline."):
            raise SystemExit(f"--set {item}: only pipeline.* keys (the renders and the lab files are the runs' own)")
    try:
        cfg = load_scenario(args.scenario, overrides=args.set)
    except BenchError as exc:
        raise SystemExit(str(exc)) from None
    if cfg.get("kind") != "in_situ":
        raise SystemExit(f"{args.scenario}: kind {cfg.get('kind')!r}, expected in_situ")
    todo = []
    for rid, seed, params in _runs(args.sweep):
        swept = sorted(k for k in params if k.startswith("sources.") or k.startswith("pipeline.")
                       and _dotted(cfg, k) != params[k])  # a pipeline key --set to the run's own value is redone
        if swept:
            raise SystemExit(f"{args.sweep}: run {rid} sets {', '.join(f'{k}={params[k]!r}' for k in swept)}: its "
                             "localisation cannot be redone from the scenario's settings and the lab's files (a "
                             "pipeline key: --set it to the run's value)")
        run = args.sweep / "runs" / rid
        res = run / "result.json"
        if not (run / "dataset").is_dir() or not res.is_file():
            print(f"{rid}: no dataset or result.json, skipped", file=sys.stderr)
            continue
        name = json.loads(res.read_text()).get("scenario")
        if name != cfg.get("name"):
            raise SystemExit(f"{run}: a run of scenario {name!r}, not of {args.scenario} ({cfg.get('name')!r})")
        if (run / args.name / "locate.json").is_file() and not args.force:
            continue
        todo.append((str(run), seed, cfg["pipeline"], args.name, regions))
    print(f"{len(todo)} runs to re-localise", file=sys.stderr)
    from bench.scenario.sweep import _end_with_parent, stop_pool

    counts, futs = {}, []
    pool = ProcessPoolExecutor(args.workers, initializer=_end_with_parent, initargs=(os.getpid(),))
    try:
        futs = [pool.submit(relocate, *job) for job in todo]
        for i, f in enumerate(as_completed(futs), 1):
            rid, integrity, dt = f.result()
            key = integrity if not integrity.startswith("error") else "error"
            counts[key] = counts.get(key, 0) + 1
            if key == "error":  # in full, on its own line: the reason names the file or field
                print(f"\r[{i}/{len(todo)}] {rid}: {integrity}", file=sys.stderr)
            else:
                print(f"\r[{i}/{len(todo)}] {rid}: {integrity[:60]} ({dt:.1f} s)" + " " * 10, end="",
                      file=sys.stderr)
    except KeyboardInterrupt:
        print(f"\ninterrupted after {sum(counts.values())} runs {counts}: the next start does the rest",
              file=sys.stderr)
        return 130
    finally:  # an interrupt: the running runs stopped, the queued ones dropped
        stop_pool(pool, any(not f.done() for f in futs))
    print(f"\n{counts}", file=sys.stderr)
    return 1 if counts.get("error") else 0


if __name__ == "__main__":
    raise SystemExit(main())
