"""Screenshots of every scenario kind's rerun recording as the viewer opens it (``make screenshots``).

For each kind (in-situ, x-y table, camera calibration, and a small ``bench sweep``: ``SWEEP``) this runs the kind's
smoke configuration (the one its tests use; ``--reuse`` keeps a recording that is already there), then opens the
recording in rerun's own viewer (``.venv/bin/rerun``) under a virtual X display and lets it write a screenshot of its
default layout - the blueprint the recording carries - with ``--screenshot-to``. The PNGs go to
``docs/figures/inspection_<kind>.png`` (downsampled to the window's size), shown in ``docs/inspection.md``.

Needs ``xvfb-run`` and a Vulkan driver (Debian: ``apt-get install xvfb mesa-vulkan-drivers``: the viewer then runs on
Mesa's software rasteriser). The virtual screen is larger than the window so that the pointer (at the screen's
centre) is outside it and no hover tooltip lands in the picture.

Usage: python tools/screenshots.py [--runs runs/screenshots] [--figures docs/figures] [--only in_situ ...] [--reuse]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
#: kind -> (scenario, seed, smoke overrides); the same configurations the kinds' tests run
KINDS = {
    "in_situ": ("scenarios/ta40_in_situ_manifold.yaml", 2,
                ["camera.supersample=1", "lab.rig_views=7", "lab.tracker_poses=60",
                 "survey.offsets_mm=[[130, 0], [-130, 0], [0, 130], [0, -130]]", "bound.mc_trials=4"]),
    "xy_table": ("scenarios/xy_table_webcam.yaml", 3,
                 ["sim.supersample=1", "sim.calibration_views=4", "outputs.plots=false", "bound.mc_trials=1",
                  "sim.positions=[1, 2, 4, 5, 6, 11, 12, 14, 15, 16, 17, 20, 21]",
                  "pipeline.intraocular_mm=[20, 100]", "pipeline.bundle_intraocular_mm=[100]"]),
    "camera_calibration": ("scenarios/camera_calibration_webcam.yaml", 3,
                           ["views.count=4", "camera.supersample=2", "pipeline.compare_extractors=false"]),
}
#: the sweep's screenshot: the x-y table's smoke configuration over the reference distance (3 runs, one seed)
SWEEP = ("scenarios/xy_table_webcam.yaml", 3, "sim.reference_distance_mm=600,700,800")
WINDOW = (1600, 1000)


def run_kind(kind: str, runs: Path, reuse: bool = False) -> Path:
    """The kind's smoke run (with ``reuse``, an existing recording is kept); returns the recording's path."""
    scenario, seed, overrides = KINDS[kind]
    out = runs / kind
    rrd = out / "recording.rrd"
    if reuse and rrd.is_file():
        return rrd
    cmd = [str(BIN / "bench"), "run", str(ROOT / scenario), "--out", str(out), "--seed", str(seed)]
    for o in overrides:
        cmd += ["--set", o]
    print(f"{kind}: running {scenario} (smoke configuration, seed {seed}) ...", flush=True)
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    if not rrd.is_file():
        raise SystemExit(f"{kind}: the run wrote no recording ({rrd})")
    return rrd


def run_sweep(runs: Path, reuse: bool = False) -> Path:
    """The small sweep of ``SWEEP`` (``bench sweep``, 2 workers); returns its ``sweep.rrd``."""
    scenario, seed, param = SWEEP
    out = runs / "sweep"
    rrd = out / "sweep.rrd"
    if reuse and rrd.is_file():
        return rrd
    cmd = [str(BIN / "bench"), "sweep", str(ROOT / scenario), "--param", param, "--seed", str(seed), "--workers", "2",
           "--out", str(out), "--force"]
    for o in KINDS["xy_table"][2]:
        if not o.startswith("sim.reference_distance_mm"):
            cmd += ["--set", o]
    print(f"sweep: {scenario} over {param} ...", flush=True)
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    if not rrd.is_file():
        raise SystemExit(f"sweep: the sweep wrote no recording ({rrd})")
    return rrd


def screenshot(rrd: Path, png: Path, timeout_s: float = 240.0) -> None:
    """Open ``rrd`` in the viewer under Xvfb and write its default layout to ``png`` (window size ``WINDOW``)."""
    import cv2

    xvfb = shutil.which("xvfb-run")
    viewer = BIN / "rerun"
    if xvfb is None:
        raise SystemExit("xvfb-run not found: install it (Debian: apt-get install xvfb mesa-vulkan-drivers)")
    if not viewer.is_file():
        raise SystemExit(f"{viewer} not found: the rerun viewer ships with rerun-sdk (pip install rerun-sdk)")
    w, h = WINDOW
    raw = png.with_name(f".{png.stem}.raw.png")
    png.parent.mkdir(parents=True, exist_ok=True)  # the viewer does not create it (it panics)
    env = dict(os.environ, RUST_LOG="error")  # no log toasts over the picture
    cmd = [xvfb, "-a", "-s", f"-screen 0 {5 * w}x{5 * h}x24", str(viewer), "--new", "--window-size", f"{w}x{h}",
           "--screenshot-to", str(raw), str(rrd)]
    try:
        subprocess.run(cmd, check=True, env=env, timeout=timeout_s, stdout=subprocess.DEVNULL,
                       stderr=subprocess.PIPE)
    except subprocess.CalledProcessError as exc:
        lines = exc.stderr.decode(errors="replace").strip().splitlines() if exc.stderr else []
        why = "; ".join(ln.strip() for ln in lines if "panicked" in ln)[-300:] or "; ".join(lines[-1:])
        raise SystemExit(f"{rrd}: the viewer failed ({why or exc.returncode})") from None
    img = cv2.imread(str(raw), cv2.IMREAD_COLOR)
    if img is None:
        raise SystemExit(f"{rrd}: the viewer wrote no screenshot")
    if img.shape[1] != w:
        img = cv2.resize(img, (w, round(img.shape[0] * w / img.shape[1])), interpolation=cv2.INTER_AREA)
    cv2.imwrite(str(png), img)
    raw.unlink(missing_ok=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=Path, default=ROOT / "runs" / "screenshots", help="folder of the smoke runs")
    ap.add_argument("--figures", type=Path, default=ROOT / "docs" / "figures", help="where the PNGs go")
    ap.add_argument("--only", nargs="+", choices=sorted(KINDS) + ["sweep"], default=sorted(KINDS) + ["sweep"],
                    help="kinds to render (and the sweep)")
    ap.add_argument("--reuse", action="store_true", help="keep recordings already in --runs")
    args = ap.parse_args(argv)
    for kind in args.only:
        rrd = run_sweep(args.runs, args.reuse) if kind == "sweep" else run_kind(kind, args.runs, args.reuse)
        png = args.figures / f"inspection_{kind}.png"
        screenshot(rrd, png)
        print(f"{kind}: {png.relative_to(ROOT) if png.is_relative_to(ROOT) else png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
