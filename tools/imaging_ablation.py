"""Ablation of the realistic imaging profile (issue 12): each error stage's share of the calibration residual.

    .venv/bin/python tools/imaging_ablation.py [--seeds 1 2] [--set KEY=VALUE ...] [--out DIR] [--doc FILE]

Runs the ``camera_calibration_webcam`` scenario (Table 3's protocol: seven rig photos, each calibrated alone with
the pin-hole model, and the multi-view Heikkilä calibration) under ``camera.imaging=ideal``, ``realistic`` (all
stages on) and ``realistic`` with each stage of :data:`bench.sim.imaging.STAGES` switched off in turn
(``camera.imaging_off=[stage]``), for every seed, and tabulates the medians over the seeds of

* ``table3_chi_mean_px`` - Table 3's chi (Eq. 196), the mean over the seven single-image calibrations;
* ``reproj_rms_px`` - the multi-view calibration's RMS;
* ``corner_rms_px`` - the extracted corners against the true projections of the printed corners (the image chain);
* ``model_floor_rms_px`` - the model fitted to the exact projections of the (perturbed) rig (the target's share).

A stage's share is read from ``all on`` minus ``stage off``: positive = the stage adds to the residual. The last
row is the extractor's share in Table 3's chi: the "all on" runs' chi on sub-pixel edge positions
(``table3_chi_subpixel_mean_px``) instead of the edge map's pixels, as printed. Residuals
add in quadrature, so the shares do not sum to the total. The table goes between the markers
``<!-- ablation:begin -->`` and ``<!-- ablation:end -->`` of ``--doc`` (docs/realistic_imaging.md), the figures of
every run to ``DIR/ablation.json``. Renders are cached in ``DIR/.render_cache`` (a rerun re-renders nothing).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.sim.imaging import STAGES  # noqa: E402

SCENARIO = ROOT / "scenarios" / "camera_calibration_webcam.yaml"
METRICS = ("table3_chi_mean_px", "table3_chi_subpixel_mean_px", "reproj_rms_px", "corner_rms_px",
           "model_floor_rms_px")
BEGIN, END = "<!-- ablation:begin -->", "<!-- ablation:end -->"
#: every run: no second extractor, no tolerance Monte Carlo, no plots, no recording (speed); the figures are the same
FIXED = ["pipeline.compare_extractors=false", "pipeline.target_tolerance=false", "outputs.plots=false",
         "outputs.rerun=false", "outputs.cache=true"]


#: the extractor's share, the last row: Table 3's chi on sub-pixel edge positions instead of the edge map's pixels
#: (printed) - the "all on" runs report it (``table3_chi_subpixel_mean_px``); the other figures are theirs
SUBPIXEL = "sub-pixel edges (Table 3)"


def configurations() -> list[tuple[str, list[str]]]:
    """``(label, overrides)``: ideal, all on, then each stage off."""
    out = [("ideal", ["camera.imaging=ideal"]), ("all on", ["camera.imaging=realistic"])]
    out += [(f"{s} off", ["camera.imaging=realistic", f"camera.imaging_off=[{s}]"]) for s in STAGES]
    return out


def run_all(seeds, extra, out: Path, verbose: bool = True) -> dict:
    """Run every configuration for every seed; returns ``{label: {seed: metrics}}`` (failures: ``{"error": msg}``)."""
    from bench.errors import BenchError
    from bench.scenario.runner import run_scenario_file

    results: dict = {}
    for label, overrides in configurations():
        results[label] = {}
        for seed in seeds:
            t0 = time.perf_counter()
            run_dir = out / "runs" / label.replace(" ", "_") / f"seed{seed}"
            try:
                path = run_scenario_file(SCENARIO, out=run_dir, seed=seed, overrides=FIXED + overrides + list(extra),
                                         verbose=False, quiet=True, force=True)
                m = json.loads(Path(path).read_text())["metrics"]
                results[label][seed] = {k: float(m[k]) for k in METRICS if k in m}
            except BenchError as e:
                results[label][seed] = {"error": str(e)}
            if verbose:
                print(f"{label:>22s} seed {seed}: {results[label][seed]} ({time.perf_counter() - t0:.0f} s)",
                      file=sys.stderr)
    return results


def table(results: dict, seeds, extra) -> str:
    """The markdown block (between the markers) of the medians over the seeds."""
    def med(label, key):
        v = [r[key] for r in results[label].values() if key in r]
        return statistics.median(v) if v else float("nan")

    lines = [BEGIN, f"*`.venv/bin/python tools/imaging_ablation.py --seeds {' '.join(map(str, seeds))}"
             + "".join(f" --set {e}" for e in extra) + f"`: medians over {len(seeds)} seed(s) of "
             "camera_calibration_webcam (px); share = all on minus that stage off.*", "",
             "| configuration | Table 3 chi | share | multi-view RMS | share | corner RMS | model floor | failed |",
             "|---|---|---|---|---|---|---|---|"]
    chi_all, rms_all = med("all on", "table3_chi_mean_px"), med("all on", "reproj_rms_px")
    rows = [(label, label, "table3_chi_mean_px") for label in results]
    if "all on" in results:
        rows.append((SUBPIXEL, "all on", "table3_chi_subpixel_mean_px"))
    for name, label, chi_key in rows:
        chi, rms = med(label, chi_key), med(label, "reproj_rms_px")
        share = name.endswith(" off") or name == SUBPIXEL
        failed = sum("error" in r for r in results[label].values())
        lines.append(f"| {name} | {chi:.3f} | {f'{chi_all - chi:+.3f}' if share else ''} | {rms:.3f} | "
                     f"{f'{rms_all - rms:+.3f}' if share else ''} | {med(label, 'corner_rms_px'):.3f} | "
                     f"{med(label, 'model_floor_rms_px'):.3f} | {failed or ''} |")
    return "\n".join(lines + [END])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--set", dest="extra", action="append", default=[], metavar="KEY=VALUE",
                    help="extra scenario override for every run (e.g. camera.supersample=2)")
    ap.add_argument("--out", default="runs/imaging_ablation")
    ap.add_argument("--doc", default=str(ROOT / "docs" / "realistic_imaging.md"),
                    help="markdown file whose ablation block is regenerated ('' to leave it)")
    args = ap.parse_args(argv)
    if any(s < 0 for s in args.seeds):
        raise SystemExit(f"--seeds: expected non-negative integers, got {args.seeds}")
    for e in args.extra:
        if "=" not in e:
            raise SystemExit(f"--set: expected KEY=VALUE, got {e!r}")
    from bench.errors import BenchError
    from bench.scenario.runner import load_scenario

    try:  # a bad --set is one error now, not one per run
        load_scenario(SCENARIO, overrides=FIXED + list(args.extra))
    except BenchError as e:
        raise SystemExit(f"--set: {e}") from None
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results = run_all(args.seeds, args.extra, out)
    (out / "ablation.json").write_text(json.dumps({"seeds": args.seeds, "overrides": args.extra,
                                                   "results": results}, indent=2) + "\n")
    block = table(results, args.seeds, args.extra)
    print(block)
    if args.doc:
        page = Path(args.doc)
        text = page.read_text() if page.is_file() else ""
        if BEGIN in text and END in text:
            page.write_text(text[:text.index(BEGIN)] + block + text[text.index(END) + len(END):])
            print(f"updated the ablation block of {page}", file=sys.stderr)
        else:
            print(f"{page}: no {BEGIN} ... {END} block; not updated (figures in {out / 'ablation.json'})",
                  file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
