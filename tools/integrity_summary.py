"""Summarise an envelope sweep of the in-situ localisation's integrity (issue 13; docs/integrity.md).

    python tools/integrity_summary.py SWEEP_DIR [--doc docs/integrity.md] [--figure docs/figures/...png]
                                      [--locate relocated/locate.json]

Reads every finished run of a ``bench sweep`` of ``scenarios/ta40_envelope.yaml`` (``SWEEP_DIR/sweep.sqlite``, each
run's ``locate.json`` and its dataset's ``truth/truth.yaml`` - the evaluator's side) and reports, as the pipeline
reported them (the constants of :mod:`bench.vision.integrity` at the time of the run):

* silent failures: integrity ``ok`` while the base error exceeds the protection radius / angle or 3 mm;
* availability (share of ``ok``) per cell (water x standoff, and per appearance);
* among ok runs: median and 95th percentile of the base position / rotation error;
* covariance coverage: the share of runs whose position (rotation) error lies inside the covariance's 95 % region
  (NEES = e^T S^-1 e <= chi2_3(0.95)); NEES is also given for every successful run, ok or not;
* the median protection radius over the median error;
* the reported covariance's remaining optimism ``kappa`` fitted from the runs (``kappa^2 = q95(NEES_pos) /
  chi2_3(0.95)`` over the runs not refused; the reported covariance is already the estimator's times its
  :data:`bench.vision.integrity.KAPPA`), and - two-fold cross-validated by run id - the coverage and integrity the
  runs would have with that further ``kappa`` (the protection levels recomputed with
  :func:`bench.vision.integrity.protection_levels`);
* a Stanford-style plot: position error against protection radius for every run, coloured by integrity.

``--locate`` reads each run's localisation from another file of its folder (``tools/relocate_sweep.py`` writes
``relocated/locate.json``: the same datasets localised by a later version). ``--against`` pairs every run with
another localisation of the same dataset (e.g. ``regions_r0/locate.json``: ``tools/relocate_sweep.py --regions r0``,
the survey's first region alone) and tabulates both, per standoff. With ``--doc``, the markdown goes
between ``<!-- envelope:begin -->`` and ``<!-- envelope:end -->`` of that file.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import yaml
from scipy.stats import chi2

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.geometry.quaternion import matrix_to_rotation_vector  # noqa: E402
from bench.geometry.transforms import invert, transform_points  # noqa: E402
from bench.scenario.results import pose_errors  # noqa: E402
from bench.vision import integrity as I  # noqa: E402

SILENT_MM = 3.0
Q95 = float(chi2.ppf(0.95, 3))
BEGIN, END = "<!-- envelope:begin -->", "<!-- envelope:end -->"


def _texture_label(tex) -> str:
    if not tex:
        return "procedural"
    return Path(next(iter(tex.values()))).stem


def _at_panel_centre(truth, T, T_true, cov) -> dict:
    """The located base's error and covariance carried to the panel centre (site frame; evaluator side): the true
    error there, the covariance's largest standard deviation there and the rotation's, and the lever arm (m)."""
    c = transform_points(invert(np.array(truth["T_world_base_survey"])), np.array(truth["T_world_panel"])[:3, 3])
    x_c = transform_points(invert(T_true), c)  # the centre in the locate parking's base frame
    return {"err_centre_mm": float(np.linalg.norm(transform_points(T, x_c) - c) * 1e3),
            "sigma_centre_mm": float(np.sqrt(np.linalg.eigvalsh(I.point_covariance(cov, T, c)).max()) * 1e3),
            "sigma_rot_deg": float(np.rad2deg(np.sqrt(np.linalg.eigvalsh(cov[:3, :3]).max()))),
            "lever_m": float(np.linalg.norm(c - T[:3, 3]))}


def load_runs(sweep: Path, locate: str = "locate.json") -> list:
    """One dict per finished run: params, integrity, protection levels, true errors, NEES (``locate``: the
    localisation's file in the run's folder)."""
    from bench.scenario.sweep import read_runs

    out = []
    for row in read_runs(sweep, finished_only=False):
        rid, params, status = row["run_id"], row["params"], row["status"]
        run = {"run_id": rid, "seed": row["seed"], "status": status, "message": row["message"],
               "texture": _texture_label(params.get("site.textures", {})), "water": params.get("site.water", "?"),
               "standoff_m": float(params.get("site.standoff_m", float("nan"))),
               "total_s": row["timings"].get("total_s", float("nan"))}
        loc_path, truth_path = sweep / "runs" / rid / locate, sweep / "runs" / rid / "dataset" / "truth" / \
            "truth.yaml"
        if status != "done" or not loc_path.is_file():
            run.update(integrity="failed", success=False)
            out.append(run)
            continue
        rep = json.loads(loc_path.read_text())
        truth = yaml.safe_load(truth_path.read_text())
        T_true = invert(np.array(truth["T_world_base_survey"])) @ np.array(truth["T_world_base_locate"])
        run.update(integrity=rep["integrity"], reasons=rep["integrity_reasons"], success=bool(rep["success"]),
                   tests=rep.get("integrity_tests") or {}, pr_mm=rep["protection_radius_mm"],
                   pa_deg=rep["protection_angle_deg"])
        if rep["success"]:
            T = np.array(rep["T_world_base"])
            cov = np.array(rep["covariance"])
            e_t = T[:3, 3] - T_true[:3, 3]
            e_r = matrix_to_rotation_vector(T[:3, :3] @ T_true[:3, :3].T)  # left, world frame (as the covariance)
            if "T_world_panel" in truth:  # the panel centre (site frame), where the work is: the same pose there
                run.update(_at_panel_centre(truth, T, T_true, cov))
            err_mm, err_deg = pose_errors(T, T_true)
            run.update(cov=cov, err_mm=err_mm, err_deg=err_deg,
                       nees_pos=float(e_t @ np.linalg.solve(cov[3:, 3:], e_t)),
                       nees_rot=float(e_r @ np.linalg.solve(cov[:3, :3], e_r)),
                       sigma_mm=float(np.sqrt(np.linalg.eigvalsh(cov[3:, 3:]).max()) * 1e3))
        out.append(run)
    return out


def silent(r) -> bool:
    if r.get("integrity") != "ok":
        return False
    return bool(not r["err_mm"] <= min(r["pr_mm"], SILENT_MM) or not r["err_deg"] <= r["pa_deg"])


def relevel(r, kappa: float) -> dict:
    """The run's integrity and protection levels had the covariance been inflated by ``kappa`` (the other tests'
    outcomes as the run reported them; only the alert-limit warning depends on the protection levels)."""
    if r.get("integrity") in ("refused", "failed") or not r.get("success"):
        return {"integrity": r.get("integrity"), "pr_mm": r.get("pr_mm"), "pa_deg": r.get("pa_deg")}
    tests = I.with_relative_pose_excess(r["tests"])  # a locate.json of an earlier version: from its statistics
    pr, pa = I.protection_levels(r["cov"], tests, kappa=kappa)
    other = [x for x in r["reasons"] if "exceeds the alert limit" not in x]
    alert = pr * 1e3 > I.ALERT_MM or np.rad2deg(pa) > I.ALERT_DEG
    return {"integrity": "warning" if other or alert else "ok", "pr_mm": pr * 1e3, "pa_deg": float(np.rad2deg(pa))}


def fit_kappa(runs) -> float:
    """``kappa`` with which the covariance's 95 % region holds 95 % of the position errors of ``runs`` (>= 1)."""
    nees = np.array([r["nees_pos"] for r in runs if r.get("success") and r.get("integrity") != "refused"])
    if len(nees) < 5:
        return float("nan")
    return float(max(1.0, np.sqrt(np.quantile(nees, 0.95) / Q95)))


def _stats(runs, label: str) -> list:
    ok = [r for r in runs if r.get("integrity") == "ok"]
    succ = [r for r in runs if r.get("success") and r.get("integrity") != "refused"]
    n = {lv: sum(r.get("integrity") == lv for r in runs) for lv in ("warning", "refused", "failed")}
    lines = [f"| {label} | {len(runs)} | {len(ok)} ({100 * len(ok) / max(len(runs), 1):.0f} %) | {n['warning']} | "
             f"{n['refused']} | {n['failed']} | {sum(silent(r) for r in runs)} | "]
    if ok:
        e = np.array([r["err_mm"] for r in ok])
        a = np.array([r["err_deg"] for r in ok])
        pr = np.array([r["pr_mm"] for r in ok])
        lines[0] += (f"{np.median(e):.2f} / {np.percentile(e, 95):.2f} | {np.median(a):.3f} / "
                     f"{np.percentile(a, 95):.3f} | {np.median(pr):.2f} | {np.median(pr) / np.median(e):.1f} | ")
    else:
        lines[0] += "- | - | - | - | "
    if succ:
        cov_pos = np.mean([r["nees_pos"] <= Q95 for r in succ])
        cov_rot = np.mean([r["nees_rot"] <= Q95 for r in succ])
        lines[0] += f"{100 * cov_pos:.0f} % / {100 * cov_rot:.0f} % ({len(succ)}) |"
    else:
        lines[0] += "- |"
    return lines


HEADER = ("| cell | runs | ok | warning | refused | failed | silent | ok: pos err median / p95 (mm) | "
          "ok: rot err median / p95 (deg) | ok: median PR (mm) | PR / err (medians) | 95 % coverage pos / rot "
          "(runs not refused) |\n|---|---|---|---|---|---|---|---|---|---|---|---|")


def lever_arm(succ) -> list:
    """Where the base position's uncertainty comes from, per standoff (medians over the runs not refused): the
    covariance's largest standard deviation at the base origin and at the panel centre (the same pose; the work is
    there), the base rotation's, the lever arm from the base origin to the panel, and the true errors at both."""
    lines = ["The base pose's uncertainty at the base origin and at the panel centre (the same pose and covariance; "
             "medians over the runs not refused; evaluator side - the panel centre is the truth's):", "",
             "| standoff | runs | largest sd at the base origin (mm) | at the panel centre (mm) | rotation sd (deg) | "
             "lever arm (m) | error at the base origin / at the panel centre (mm) |", "|---|---|---|---|---|---|---|"]
    for s in sorted({r["standoff_m"] for r in succ}):
        cell = [r for r in succ if r["standoff_m"] == s]
        m = {k: np.median([r[k] for r in cell]) for k in ("sigma_mm", "sigma_centre_mm", "sigma_rot_deg", "lever_m",
                                                          "err_mm", "err_centre_mm")}
        lines.append(f"| {s:g} m | {len(cell)} | {m['sigma_mm']:.2f} | {m['sigma_centre_mm']:.3f} | "
                     f"{m['sigma_rot_deg']:.4f} | {m['lever_m']:.2f} | {m['err_mm']:.2f} / {m['err_centre_mm']:.3f} |")
    return lines


#: What a warning's sentence names (bench/vision/integrity.py's wording), in the order tested.
REASONS = (("the alert limit", ("exceeds the alert limit",)), ("test 1 (consensus)", ("consensus", "is not where")),
           ("test 2 (relative pose)", ("relative pose",)), ("test 3 (reprojection)", ("reprojection RMS",)),
           ("support", ("inliers", "inlier fraction")), ("conditioning", ("condition",)),
           ("single view", ("single-view",)))


def warning_reasons(runs) -> str:
    """One sentence: how many warned runs each test warned (a run may have several reasons), and how many the alert
    limit alone did."""
    warned = [r for r in runs if r.get("integrity") == "warning"]
    if not warned:
        return "No warnings."

    def kinds(r):
        return {name for x in r.get("reasons", []) for name, keys in REASONS if any(k in x for k in keys)}

    count = {name: sum(name in kinds(r) for r in warned) for name, _ in REASONS}
    alone = sum(kinds(r) == {"the alert limit"} for r in warned)
    named = ", ".join(f"{name} {n}" for name, n in count.items() if n)
    return f"The {len(warned)} warnings by reason (a run may have several): {named}; the alert limit alone: {alone}."


def report(runs, figure: Path | None, locate: str = "locate.json") -> str:
    done = [r for r in runs if r.get("integrity") != "failed"]
    lines = [f"{len(runs)} runs ({len(done)} finished), run time median "
             f"{np.nanmedian([r['total_s'] for r in runs]):.0f} s on the shared 2-core machine.", "",
             "As run (the constants of bench/vision/integrity.py at the time of the run):" if locate == "locate.json"
             else f"Localised again by a later version (`{locate}`, `tools/relocate_sweep.py`: the renders and lab "
                  "calibrations as run):", "", HEADER]
    lines += _stats(runs, "all")
    for w in ("clear_ocean", "coastal", "turbid_harbour"):
        for s in sorted({r["standoff_m"] for r in runs}):
            cell = [r for r in runs if r["water"] == w and r["standoff_m"] == s]
            if cell:
                lines += _stats(cell, f"{w}, {s:g} m")
    for t in sorted({r["texture"] for r in runs}):
        lines += _stats([r for r in runs if r["texture"] == t], f"texture {t}")
    env = [r for r in runs if r["water"] in ("clear_ocean", "coastal") and r["standoff_m"] <= 1.0]
    if env:
        lines += _stats(env, "clear + coastal, 0.5-1.0 m")
    lines += ["", warning_reasons(runs)]
    succ = [r for r in runs if r.get("success") and r.get("integrity") != "refused"]
    if succ:
        nees = np.array([r["nees_pos"] for r in succ])
        sig = np.array([r["sigma_mm"] for r in succ])
        err = np.array([r["err_mm"] for r in succ])
        ratio = err / np.array([r["pr_mm"] or np.nan for r in succ])
        ok = [r for r in succ if r["integrity"] == "ok"]
        lines += ["", f"Among the {len(succ)} runs not refused: position error median / p95 / max {np.median(err):.2f}"
                      f" / {np.percentile(err, 95):.2f} / {err.max():.2f} mm; error / protection radius median "
                      f"{np.nanmedian(ratio):.2f}, max {np.nanmax(ratio):.2f}."]
        if ok:
            lines += ["", f"Among the {len(ok)} ok runs: 95 % coverage of the reported covariance "
                          f"{100 * np.mean([r['nees_pos'] <= Q95 for r in ok]):.0f} % (position) / "
                          f"{100 * np.mean([r['nees_rot'] <= Q95 for r in ok]):.0f} % (rotation)."]
        lines += ["", f"Position NEES over the {len(succ)} runs not refused: median {np.median(nees):.1f} (chi2_3 "
                      f"median 2.37), 95th percentile {np.quantile(nees, 0.95):.1f} (chi2_3: {Q95:.2f}); largest "
                      f"covariance standard deviation median {np.median(sig):.3f} mm against a median error "
                      f"{np.median(err):.2f} mm."]
        if any("lever_m" in r for r in succ):
            lines += ["", *lever_arm([r for r in succ if "lever_m" in r])]
        ids = sorted(r["run_id"] for r in succ)
        folds = [set(ids[0::2]), set(ids[1::2])]
        lines += ["", "Two-fold cross-validation of kappa (fitted on one half of the runs by run id, applied to the "
                      "other):",
                  "", "| fold | kappa fitted on the other half | runs | ok | silent | 95 % coverage pos | "
                  "ok: median PR / median err |", "|---|---|---|---|---|---|---|"]
        for k, fold in enumerate(folds):
            kap = fit_kappa([r for r in succ if r["run_id"] not in fold])
            test = [r for r in runs if r["run_id"] in fold]
            re = [{**r, **relevel(r, kap)} for r in test]
            ok = [r for r in re if r["integrity"] == "ok"]
            cov = np.mean([r["nees_pos"] <= Q95 * kap**2 for r in test if r.get("success")])
            ratio = np.median([r["pr_mm"] for r in ok]) / np.median([r["err_mm"] for r in ok]) if ok else np.nan
            lines.append(f"| {k} | {kap:.2f} | {len(test)} | {len(ok)} | {sum(silent(r) for r in re)} | "
                         f"{100 * cov:.0f} % | {ratio:.1f} |")
        lines += ["", f"kappa fitted on all {len(succ)} runs: {fit_kappa(succ):.2f}."]
    if figure is not None:
        plot(runs, figure)
        rel = f"figures/{figure.name}" if figure.parent.name == "figures" else figure.name
        lines += ["", f"![error against protection radius]({rel})"]
    return "\n".join(lines) + "\n"


def paired(runs, other, label: str) -> str:
    """Markdown: ``runs`` against ``other`` (the same runs' datasets localised otherwise, by run id), per standoff:
    the integrity counts both ways, and over the runs with a pose both ways the median position / rotation errors
    and how many ``runs`` localised more precisely."""
    by_id = {r["run_id"]: r for r in other}
    pairs = [(by_id[r["run_id"]], r) for r in runs if r["run_id"] in by_id]
    lines = [f"Paired with `{label}` ({len(pairs)} runs; the same datasets and lab calibrations):", "",
             "| standoff | runs | ok / warning / refused: other | this | runs with a pose both ways | "
             "position error medians other / this (mm) | rotation error medians other / this (deg) | "
             "this more precise |", "|---|---|---|---|---|---|---|---|"]

    def counts(rs):
        return " / ".join(str(sum(r.get("integrity") == lv for r in rs)) for lv in ("ok", "warning", "refused"))

    for s in [None, *sorted({b["standoff_m"] for _, b in pairs})]:
        cell = [(a, b) for a, b in pairs if s is None or b["standoff_m"] == s]
        both = [(a, b) for a, b in cell if all(x.get("success") and x.get("integrity") != "refused"
                                               for x in (a, b))]
        row = f"| {'all' if s is None else f'{s:g} m'} | {len(cell)} | {counts([a for a, _ in cell])} | " \
              f"{counts([b for _, b in cell])} | {len(both)} | "
        if both:
            e = np.array([[a["err_mm"], b["err_mm"]] for a, b in both])
            d = np.array([[a["err_deg"], b["err_deg"]] for a, b in both])
            row += (f"{np.median(e[:, 0]):.2f} / {np.median(e[:, 1]):.2f} | {np.median(d[:, 0]):.3f} / "
                    f"{np.median(d[:, 1]):.3f} | {int(np.sum(e[:, 1] < e[:, 0]))} of {len(both)} |")
        else:
            row += "- | - | - |"
        lines.append(row)
    return "\n".join(lines) + "\n"


def plot(runs, path: Path) -> None:
    from bench.fileio import atomic_save_figure, headless_pyplot

    plt = headless_pyplot()
    fig, ax = plt.subplots(figsize=(6.0, 5.0))
    colours = {"ok": "tab:green", "warning": "tab:orange", "refused": "tab:red"}
    top = 1.0
    for level, c in colours.items():
        pts = [(r["pr_mm"] if r.get("pr_mm") else np.nan, r["err_mm"]) for r in runs
               if r.get("integrity") == level and r.get("success")]
        if not pts:
            continue
        x, y = np.array(pts).T
        x = np.where(np.isfinite(x), x, np.nanmax(np.r_[x, y, 1.0]) * 1.5)  # refused: no radius, drawn at the edge
        top = max(top, np.nanmax(np.r_[x, y]))
        ax.scatter(x, y, s=18, c=c, label=f"{level} ({len(pts)})", alpha=0.8, edgecolors="none")
    ax.plot([0, top * 1.1], [0, top * 1.1], "k--", lw=0.8, label="error = protection radius")
    ax.axhline(SILENT_MM, color="grey", lw=0.8, ls=":", label=f"{SILENT_MM:g} mm alert limit")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("protection radius (mm); refused: drawn at the right edge")
    ax.set_ylabel("true base position error (mm)")
    ax.set_title("In-situ localisation integrity (Stanford plot)")
    ax.legend(fontsize=8, loc="upper left")
    atomic_save_figure(fig, path, dpi=110)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sweep", type=Path, nargs="+", help="one or more bench sweep folders (their runs pooled)")
    ap.add_argument("--doc", type=Path, help="markdown file with the envelope markers to fill")
    ap.add_argument("--figure", type=Path, help="Stanford plot (PNG)")
    ap.add_argument("--locate", default="locate.json",
                    help="each run's localisation file, relative to its folder (default locate.json)")
    ap.add_argument("--against", metavar="LOCATE",
                    help="pair every run with this other localisation file of its folder (e.g. regions_r0/locate.json)")
    ap.add_argument("--seeds", help="only the runs of these seeds, e.g. 1,2 (a sweep resumed with fewer seeds keeps "
                                    "the rows of the others)")
    args = ap.parse_args(argv)
    try:
        seeds = None if args.seeds is None else {int(v) for v in args.seeds.split(",")}
    except ValueError:
        print(f"integrity_summary: --seeds {args.seeds!r}: expected whole numbers separated by commas",
              file=sys.stderr)
        return 2
    runs, others = [], []
    for sweep in args.sweep:
        if not (sweep / "sweep.sqlite").is_file():
            print(f"integrity_summary: {sweep}: no sweep.sqlite (not a bench sweep folder)", file=sys.stderr)
            return 2
        found = load_runs(sweep, args.locate)
        if found and not any((sweep / "runs" / r["run_id"] / args.locate).is_file() for r in found):
            print(f"integrity_summary: {sweep}: none of its {len(found)} runs has {args.locate} (a sweep of another "
                  "kind than in_situ, or not localised again under that name)", file=sys.stderr)
            return 2
        runs += [r for r in found if seeds is None or r["seed"] in seeds]
        if args.against:
            other = load_runs(sweep, args.against)
            if other and not any((sweep / "runs" / r["run_id"] / args.against).is_file() for r in other):
                print(f"integrity_summary: {sweep}: none of its runs has {args.against} (--against)", file=sys.stderr)
                return 2
            others += other
    text = report(runs, args.figure, args.locate)
    if args.against:
        text += "\n" + paired(runs, others, args.against)
    print(text)
    if args.doc:
        doc = args.doc.read_text()
        if BEGIN not in doc or END not in doc:
            print(f"integrity_summary: {args.doc}: no {BEGIN} ... {END} markers", file=sys.stderr)
            return 2
        head, rest = doc.split(BEGIN, 1)
        from bench.fileio import atomic_write_text

        atomic_write_text(args.doc, head + BEGIN + "\n" + text + END + rest.split(END, 1)[1])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
