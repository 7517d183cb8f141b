"""``make reproduce``'s last step: ``docs/results.md``, generated from runs.

Reads what ``make reproduce`` wrote under ``--runs`` (each part optional; a missing part is listed as not run) and
writes ``docs/results.md``: the headline table first (what, measured under realistic imaging, the same under ideal
imaging where ``make reproduce`` ran the ideal twin, target, thesis), then every table, the thesis's numbers beside
ours, targets beside measurements, figures copied to ``docs/figures/``. Nothing here is typed
by hand: re-run ``make reproduce`` to refresh it. The README quotes rows of the headline table verbatim
(``tests/test_docs.py`` checks that each still appears here).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np

from bench.scenario.sweep import read_runs

ROOT = Path(__file__).resolve().parents[1]


def _load(path):
    p = Path(path)
    return json.loads(p.read_text()) if p.is_file() else None


def _fmt(v, digits=3):
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "—"
    if isinstance(v, (int, np.integer)) or (isinstance(v, float) and v.is_integer() and abs(v) < 1e6):
        return f"{int(v)}"
    return f"{v:.{digits}g}"


def _table(header, rows) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(out)


def _xy_errors(runs) -> dict:
    """``{(method, d_mm, axis): [per-seed RMS error]}`` and ``{(method, d_mm, "thesis"): [x, y, z]}`` from the
    seeds' ``position_error_vs_intraocular`` tables (RMS over the pair combinations)."""
    per = {}
    for r in runs:
        res = _load(r["result_path"]) if r["result_path"] else None
        if not res:
            continue
        t = res["tables"]["position_error_vs_intraocular"]
        for i, (d, m) in enumerate(zip(t["d_mm"], t["method"], strict=True)):
            for ax in "xyz":
                per.setdefault((m, d, ax), []).append(t[f"err_{ax}_mm"][i])
            per.setdefault((m, d, "thesis"), [t.get(f"thesis_err_{a}_mm", [None] * 999)[i] for a in "xyz"])
    return per


def _xy_efficiency(runs) -> dict:
    """The x-y table's efficiency at d_o = 100 mm over the seeds, RMS limit / RMS 3D error, per estimator (``LMS +
    ratio``, ``bundle``), and the seeds used ``n``; ``{}`` without the bound's metrics."""
    ms = [r["metrics"] for r in (_load(x["result_path"]) if x["result_path"] else None for x in runs) if r]
    ms = [m for m in ms if np.isfinite(m.get("lms_ratio_bound_pos_at_100_mm", np.nan))]
    if not ms:
        return {}
    b = np.sqrt(np.mean([m["lms_ratio_bound_pos_at_100_mm"] ** 2 for m in ms]))
    out = {"n": len(ms)}
    for label, key in (("LMS + ratio", "lms_ratio_err_pos_at_100_mm"), ("bundle", "bundle_err_pos_at_100_mm")):
        e = [m[key] for m in ms if np.isfinite(m.get(key, np.nan))]
        if len(e) == len(ms):
            out[label] = float(b / np.sqrt(np.mean(np.square(e))))
    return out


def _stats(values):
    v = np.array([x for x in values if x is not None and np.isfinite(x)], dtype=float)
    if not len(v):
        return {"n": 0}
    return {"n": len(v), "median": float(np.median(v)), "q25": float(np.percentile(v, 25)),
            "q75": float(np.percentile(v, 75)), "min": float(v.min()), "max": float(v.max()),
            "rms": float(np.sqrt(np.mean(v**2)))}


def bound_plot(runs, path, title) -> bool:
    """Per seed, the base error beside its limit (CRB + floor in quadrature), the CRB and the model floor, position
    and rotation, seeds ordered by error; PNG at ``path``. False (nothing written) when the runs lack the metrics."""
    from bench.fileio import atomic_save_figure, headless_pyplot

    plt = headless_pyplot()
    panels = (("pos", "mm", "base position"), ("rot", "deg", "base rotation"))
    data = {}
    for q, unit, _ in panels:
        rows = [[r["metrics"].get(f"base_{q}_{k}_{unit}") for k in ("err", "bound", "crb", "floor")] for r in runs]
        rows = np.array([[np.nan if v is None else v for v in row] for row in rows], dtype=float)
        rows = rows[np.all(np.isfinite(rows[:, :2]), axis=1)]
        if not len(rows):
            return False
        data[q] = rows[np.argsort(rows[:, 0])]
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
    for ax, (q, unit, name) in zip(axes, panels, strict=True):
        d = data[q]
        x = np.arange(len(d))
        ax.bar(x, d[:, 0], color="0.7", label="error")
        ax.plot(x, d[:, 1], "o", color="C3", label="limit (CRB ⊕ floor)")
        ax.plot(x, d[:, 2], "_", color="C0", markersize=12, label="CRB")
        ax.plot(x, d[:, 3], "v", color="C2", markersize=4, label="model floor")
        eff = np.sqrt(np.mean(d[:, 1] ** 2)) / np.sqrt(np.mean(d[:, 0] ** 2))
        ax.set_title(f"{name}: efficiency {eff:.2f} (RMS limit / RMS error)", fontsize=9)
        ax.set_xlabel("seeds, by error")
        ax.set_ylabel(unit)
        ax.set_xticks([])
    axes[0].legend(fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    atomic_save_figure(fig, path, dpi=110)
    return True


class Report:
    def __init__(self, runs: Path, docs: Path):
        self.runs, self.docs = runs, docs
        self.figures = docs / "figures"
        self.md: list[str] = []
        self.headline: list[list[str]] = []  # [what, measured (realistic), ideal, target, thesis]
        self.missing: list[str] = []

    def figure(self, src, name, caption) -> None:
        src = Path(src)
        if not src.is_file():
            return
        self.figures.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, self.figures / name)
        self.md.append(f"![{caption}](figures/{name})\n\n*{caption}*\n")

    def head(self, what, measured, target="", thesis="", ideal="") -> None:
        self.headline.append([what, measured, ideal or "—", target, thesis])

    # --- sections ----------------------------------------------------------------------------------------------------
    def table2(self):
        r = _load(self.runs / "table2" / "result.json")
        if r is None:
            self.missing.append("Table 2 (`runs/table2`)")
            return
        m = r["metrics"]
        self.md.append("## Table 2 and the lab calibration of the arm\n\n`bench run "
                       "scenarios/table2_kinematic_identification.yaml --set monte_carlo.seeds=500`\n")
        rows = [["max abs error of ε̇, noise-free linear (Eq. 14)", _fmt(m.get("max_abs_reduced_error_linear")),
                 "≤ 1e-9"],
                ["held-out RMS, noise-free, exact model iterated (mm)", _fmt(m.get("heldout_rms_mm_noise_free_exact")),
                 "≤ 1e-6"],
                ["held-out RMS, σ = 0.05 mm, this draw (mm)", _fmt(m.get("heldout_rms_mm_calibrated")), "≤ 0.03"],
                ["held-out RMS over the Monte Carlo, RMS (mm)", _fmt(m.get("mc_heldout_rms_mm_rms")), ""],
                ["Cramér-Rao bound of the held-out RMS (mm)", _fmt(m.get("heldout_rms_bound_mm")), ""],
                ["efficiency, bound / Monte Carlo RMS", _fmt(m.get("mc_heldout_efficiency")), ""],
                ["predicted / Monte Carlo std of ε̇ (median, min, max)",
                 f"{_fmt(m.get('mc_std_ratio_median'))}, {_fmt(m.get('mc_std_ratio_min'))}, "
                 f"{_fmt(m.get('mc_std_ratio_max'))}", "within ±20 %"],
                ["held-out RMS, O1-selected vs random poses (mm)",
                 f"{_fmt(m.get('heldout_rms_mm_selected_poses_median'))} vs "
                 f"{_fmt(m.get('heldout_rms_mm_random_poses_median'))}", "selected better"],
                ["identification of 100 poses (s)", _fmt(m.get("identification_s")), "≤ 0.02 (benchmark)"]]
        self.md.append(_table(["figure", "measured", "target"], rows) + "\n")
        self.head("Table 2: held-out RMS after calibration, σ = 0.05 mm (mm)",
                  f"{_fmt(m.get('mc_heldout_rms_mm_rms'))} RMS over {_fmt(m.get('mc_seeds'))} draws "
                  f"(bound {_fmt(m.get('heldout_rms_bound_mm'))})", "≤ 0.03", "")
        self.figure(self.runs / "table2" / "figures_36_39.png", "figures_36_39.png",
                    "End effector vs link 5 after calibration (thesis Figures 36-39)")

    def tracker(self):
        r = _load(self.runs / "tracker_base_frame" / "result.json")
        if r is None:
            self.missing.append("tracker base frame (`runs/tracker_base_frame`)")
            return
        t = r["tables"]["base_accuracy_vs_noise"]
        self.md.append("## Base frame from tracker arcs (§2.9)\n\n`bench run scenarios/tracker_base_frame.yaml`\n")
        rows = [[_fmt(t["sigma_mm"][i]), _fmt(t["span_deg"][i]), _fmt(t["pos_err_mm_rms"][i]),
                 _fmt(t["predicted_pos_std_mm"][i]), _fmt(t.get("pos_bound_mm", [None] * 99)[i]),
                 _fmt(t["rot_err_deg_rms"][i]), _fmt(t.get("rot_bound_deg", [None] * 99)[i])]
                for i in range(len(t["sigma_mm"]))]
        self.md.append(_table(["σ (mm)", "arc (°)", "origin RMS (mm)", "fit's prediction (mm)",
                               "bound with readings (mm)", "rotation RMS (°)", "rotation bound (°)"], rows) + "\n")
        self.figure(self.runs / "tracker_base_frame" / "base_accuracy_vs_noise.png", "tracker_base_accuracy.png",
                    "Base frame accuracy vs tracker noise and arc span, with the Cramér-Rao bound")

    def insitu(self, folder="sweep-insitu", title="TA-40 in situ, underwater camera (`make demo`'s scenario)",
               ideal=None):
        runs = read_runs(self.runs / folder)
        twin = read_runs(self.runs / ideal) if ideal else []
        if not runs:
            self.missing.append(f"{title} (`runs/{folder}`)")
            return
        keys = [("base_pos_err_mm", "≤ 2"), ("base_rot_err_deg", "≤ 0.05"), ("valve_tool_err_mm", "≤ 3"),
                ("insitu_solve_s", "≤ 0.3"), ("map_points", ""), ("inliers", ""), ("base_pos_bound_mm", ""),
                ("base_rot_bound_deg", ""), ("base_pos_crb_mm", ""), ("base_pos_floor_mm", ""),
                ("base_pos_bound_mc_mm", ""), ("keypoint_sigma_px", ""), ("keypoint_sigma_locate_px", ""),
                ("valve_tool_err_uncompensated_mm", ""), ("panel_sift_keypoints", ""), ("arm_heldout_rms_mm", ""),
                ("mount_rot_err_deg", ""), ("parking_attempts", ""), ("integrity_ok", ""),
                ("protection_radius_mm", ""), ("protection_angle_deg", ""), ("base_pos_err_vision_mm", ""),
                ("base_rot_err_vision_deg", ""), ("base_pos_bound_vision_mm", ""), ("base_rot_bound_vision_deg", ""),
                ("base_rot_err_vision_heading_deg", ""), ("base_rot_crb_heading_deg", "")]
        rows, st = [], {}
        for k, target in keys:
            s = st[k] = _stats(r["metrics"].get(k) for r in runs)
            if s["n"]:
                rows.append([f"`{k}`", _fmt(s["median"]), f"{_fmt(s['q25'])} – {_fmt(s['q75'])}", _fmt(s["max"]),
                             target])
        n = len(runs)
        self.md.append(f"## {title}\n\n`bench sweep scenarios/ta40_in_situ_manifold.yaml --seeds {n}` "
                       f"(folder `{folder}`): median, interquartile range and worst over {n} seeds\n")
        self.md.append(_table(["metric", "median", "IQR", "max", "target (median)"], rows) + "\n")
        eff = []
        for q, unit in (("pos", "mm"), ("rot", "deg")):
            e, b = st.get(f"base_{q}_err_{unit}", {}), st.get(f"base_{q}_bound_{unit}", {})
            if e.get("n") and b.get("n"):
                eff.append(f"{q}: {b['rms'] / e['rms']:.2f}")
        vision = [f"{q}: {st[f'base_{q}_bound_vision_{u}']['rms'] / st[f'base_{q}_err_vision_{u}']['rms']:.2f}"
                  for q, u in (("pos", "mm"), ("rot", "deg"))
                  if st[f"base_{q}_bound_vision_{u}"]["n"] and st[f"base_{q}_err_vision_{u}"]["n"]]
        if eff:
            self.md.append(f"Efficiency (RMS bound / RMS error over the seeds): {', '.join(eff)} (target ≥ 0.75)"
                           + (f"; the images' pose before the INS's tilt against the limit without it: "
                              f"{', '.join(vision)}" if vision else "") + ".\n")
            name = f"bound-{folder}.png"
            if bound_plot(runs, self.figures / name, f"{title}: error, limit, CRB and floor per seed"):
                self.md.append(f"![Error against the limit per seed]({'figures/' + name})\n\n*Per seed (ordered "
                               "by error): the base error (bars), the limit = CRB ⊕ model floor (red), the CRB and "
                               "the floor alone.*\n")
        def errors(st):
            return (f"{_fmt(st['base_pos_err_mm'].get('median'))} mm / {_fmt(st['base_rot_err_deg'].get('median'))}"
                    f"° / {_fmt(st['valve_tool_err_mm'].get('median'))} mm")

        tw = {k: _stats(r["metrics"].get(k) for r in twin) for k, _ in keys} if twin else None
        if ideal and not twin:
            self.missing.append(f"{title}, ideal imaging (`runs/{ideal}`)")
        self.head(f"{title}: base position / rotation, valve tool tip (median of {n})", errors(st),
                  "≤ 2 mm / ≤ 0.05° / ≤ 3 mm", "", errors(tw) + f" ({len(twin)} seeds)" if tw else "")
        if eff:
            self.head(f"{title}: efficiency (RMS bound / RMS error)", ", ".join(eff), "≥ 0.75", "",
                      ", ".join(f"{q}: {tw[f'base_{q}_bound_{u}']['rms'] / tw[f'base_{q}_err_{u}']['rms']:.2f}"
                                for q, u in (("pos", "mm"), ("rot", "deg"))
                                if tw[f"base_{q}_bound_{u}"]["n"] and tw[f"base_{q}_err_{u}"]["n"]) if tw else "")
        ok = st.get("integrity_ok", {})
        if ok.get("n"):
            self.head(f"{title}: integrity ok / warning / refused, protection radius / error (median)",
                      self._integrity(runs), "0 outside", "", self._integrity(twin) if twin else "")

    @staticmethod
    def _integrity(runs) -> str:
        """``ok / warning / refused``, the median protection radius over the error, and how many poses not refused
        lay outside their protection radius or angle (confident and wrong)."""
        m = [r["metrics"] for r in runs]
        def finite(x, k):
            v = x.get(k)
            return v is not None and np.isfinite(v)

        if not any(finite(x, "integrity_ok") for x in m):
            return ""  # runs of a version without the integrity tests
        ok = sum(1 for x in m if x.get("integrity_ok") == 1)
        refused = sum(1 for x in m if x.get("integrity_refused") == 1)
        kept = [x for x in m if x.get("integrity_refused") != 1]
        level = [x for x in kept if finite(x, "protection_radius_mm") and finite(x, "base_pos_err_mm")]
        ratio = [x["protection_radius_mm"] / x["base_pos_err_mm"] for x in level if x["base_pos_err_mm"] > 0]
        outside = sum(1 for x in level if x["base_pos_err_mm"] > x["protection_radius_mm"]
                      or x.get("base_rot_err_deg", 0) > x.get("protection_angle_deg", np.inf))
        med = _fmt(np.median(ratio), 2) if ratio else "—"
        return (f"{ok} / {len(m) - ok - refused} / {refused}; radius / error {med}; "
                f"{outside} outside their protection level")

    def budget(self, folder="budget-insitu", title="Error budget of the in-situ localisation"):
        r = _load(self.runs / folder / "result.json")
        if r is None:
            self.missing.append(f"{title} (`runs/{folder}`)")
            return
        b, v = r["tables"]["budget"], r["tables"]["variants"]
        cols = [c for c in b if c.startswith("budget_") and not c.endswith(("_lo", "_hi", "_difference", "_method"))]

        def cell(c, i):  # the budget with its 90 % paired-bootstrap interval when the run has one
            if f"{c}_lo" not in b:
                return _fmt(b[c][i])
            return f"{_fmt(b[c][i])} [{_fmt(b[f'{c}_lo'][i])}, {_fmt(b[f'{c}_hi'][i])}]"

        self.md.append(f"## {title}\n\n`bench budget` (folder `{folder}`): RMS over "
                       f"{_fmt(v['runs'][0])} seeds with every source real, with one switched off, with all off\n")
        self.md.append(_table(["variant", "runs"] + [c.replace("rms_", "RMS ") for c in v if c.startswith("rms_")],
                              [[v["variant"][i], _fmt(v["runs"][i])] + [_fmt(v[c][i]) for c in v
                                                                        if c.startswith("rms_")]
                               for i in range(len(v["variant"]))]) + "\n")
        displaced = all(set(b.get(f"{c}_method", [])) == {"paired displacement"} for c in cols)
        how = ("the RMS over the seeds of the displacement that switching it off causes, seed by seed, "
               "`sqrt(mean |e_full − e_without|²)`" if displaced else "`sqrt(RMS_full² − RMS_without²)`")
        self.md.append(f"Share of the final error each source explains, {how} [90 % bootstrap over the "
                       "seeds]:\n")
        self.md.append(_table(["source"] + [c.replace("budget_", "") for c in cols],
                              [[b["source"][i]] + [cell(c, i) for c in cols] for i in range(len(b["source"]))])
                       + "\n")
        if displaced:  # its rows carry the difference of mean squares beside each share
            self.md.append("Beside it, the difference of the mean squares, `sqrt(max(0, RMS_full² − "
                           "RMS_without²))` (the same share under independent sources, with every source's noise "
                           "in it): " + "; ".join(
                               f"{c.replace('budget_', '')}: " + ", ".join(
                                   f"{b['source'][i]} {_fmt(b[f'{c}_difference'][i])}" for i in
                                   range(len(b["source"]))) for c in cols) + ".\n")
        closure = [(c.replace("budget_", ""), r["metrics"].get(f"budget_closure_{c[7:]}")) for c in cols]
        self.md.append("Closure, `sqrt(Σ shares² + RMS_none²) / RMS_full` (1 when the shares add up): "
                       + ", ".join(f"{n} {_fmt(x)}" for n, x in closure if x is not None) + ".\n")
        self.figure(self.runs / folder / "budget.png", f"{folder}.png", title)
        full = r["metrics"].get("rms_full_" + cols[0][7:])
        self.head(f"{title}: sources of `{cols[0][7:]}` (RMS {_fmt(full)} over {_fmt(v['runs'][0])} seeds)",
                  "; ".join(f"{b['source'][i]} {cell(cols[0], i)}"
                            for i in np.argsort(np.nan_to_num(b[cols[0]]))[::-1]))

    def xy_table(self, name, thesis_tables):
        run = _load(self.runs / name / "result.json")
        runs = read_runs(self.runs / f"sweep-{name}")
        if run is None and not runs:
            self.missing.append(f"{name} (`runs/{name}`, `runs/sweep-{name}`)")
            return
        self.md.append(f"## {name}: thesis Tables {thesis_tables}\n")
        per = _xy_errors(runs)
        twin_runs = read_runs(self.runs / f"sweep-{name}-ideal")
        twin = _xy_errors(twin_runs)
        if name == "xy_table_webcam" and not twin_runs:
            self.missing.append(f"{name}, ideal imaging (`runs/sweep-{name}-ideal`)")

        def ideal(d):  # the ideal twin's medians at d_o = d mm, "" when it was not run
            if ("lms_ratio", d, "x") not in twin:
                return ""
            return " / ".join(_fmt(np.median(twin[("lms_ratio", d, ax)]), 2) for ax in "xyz") + \
                f" mm ({len(twin_runs)} seeds)"
        if per:
            ds = sorted({d for (_, d, _) in per})
            self.md.append(f"Median over {len(runs)} seeds (`bench sweep scenarios/{name}.yaml --seeds "
                           f"{len(runs)}`) of the RMS position error over the pair combinations, ours (thesis), mm:\n")
            for m in ("quaternion", "quaternion_ratio", "lms", "lms_ratio"):
                if (m, ds[0], "x") not in per:
                    continue
                rows = [[f"error {ax}"] + [f"{_fmt(np.median(per[(m, d, ax)]), 2)} "
                                           f"({_fmt(per[(m, d, 'thesis')]['xyz'.index(ax)], 3)})" for d in ds]
                        for ax in "xyz"]
                self.md.append(f"**{m}**\n\n" + _table(["d_o (mm)"] + [_fmt(d) for d in ds], rows) + "\n")
            bd = [d for d in ds if ("bundle", d, "x") in per]
            if bd:  # the maximum-likelihood bundle, beside the thesis's four (not in the thesis)
                rows = [[f"error {ax}"] + [_fmt(np.median(per[("bundle", d, ax)]), 2) for d in bd] for ax in "xyz"]
                self.md.append("**bundle** (maximum likelihood over the estimate's views: the pair, R0, the "
                               "intrinsics and the distortion under priors, the points; not in the thesis)\n\n"
                               + _table(["d_o (mm)"] + [_fmt(d) for d in bd], rows) + "\n")
            eff = _xy_efficiency(runs)
            if eff:
                tw = _xy_efficiency(twin_runs)
                self.head(f"{name}: efficiency at d = 100 mm (RMS limit / RMS error over {eff['n']} seeds)",
                          ", ".join(f"{k} {v:.2f}" for k, v in eff.items() if k != "n"), "≥ 0.75", "",
                          ", ".join(f"{k} {v:.2f}" for k, v in tw.items() if k != "n") + f" ({tw['n']} seeds)"
                          if tw else "")
            if ("lms_ratio", 100.0, "x") in per:
                med = [np.median(per[("lms_ratio", 100.0, ax)]) for ax in "xyz"]
                q75 = [np.percentile(per[("lms_ratio", 100.0, ax)], 75) for ax in "xyz"]
                th = per[("lms_ratio", 100.0, "thesis")]
                self.head(f"{name}: LMS + error ratio at d = 100 mm, x / y / z (median of {len(runs)}; 75 %)",
                          " / ".join(_fmt(v, 2) for v in med) + " mm (" + " / ".join(_fmt(v, 2) for v in q75) + ")",
                          "≤ 1.0 mm" if "webcam" in name else "≤ 2.0 mm", " / ".join(_fmt(v) for v in th) + " mm",
                          ideal(100.0))
            if ("lms_ratio", 20.0, "x") in per:
                med = [np.median(per[("lms_ratio", 20.0, ax)]) for ax in "xyz"]
                th = per[("lms_ratio", 20.0, "thesis")]
                self.head(f"{name}: LMS + error ratio at d = 20 mm (median of {len(runs)})",
                          " / ".join(_fmt(v, 2) for v in med) + " mm", "≤ 5 mm",
                          " / ".join(_fmt(v) for v in th) + " mm", ideal(20.0))
        if run is not None:
            tot = run["timings_s"].get("total_s")
            if tot is not None and "webcam" in name:
                self.head(f"{name}: one full run, renders cached (s)", _fmt(tot), "≤ 60", "")
            self.figure(self.runs / name / "position_error_vs_intraocular.png", f"{name}.png",
                        f"{name}: RMS position error vs intraocular distance, ours and the thesis's (dashed)")

    def camera(self, name):
        r = _load(self.runs / name / "result.json")
        if r is None:
            self.missing.append(f"{name} (`runs/{name}`)")
            return
        m, t = r["metrics"], r["tables"]
        self.md.append(f"## {name}\n\n`bench run scenarios/{name}.yaml`\n")
        keys = [k for k in m if k.endswith(("reproj_rms_px", "focal_err_pct", "corner_rms_px", "model_floor_rms_px"))
                or "within_" in k or k in ("heikkila_n_coeffs", "focal_ratio_water_air",
                                           "thesis_focal_ratio_water_air", "table3_alpha_mean_err_pct",
                                           "table3_chi_mean_px")]
        self.md.append(_table(["metric", "value"], [[f"`{k}`", _fmt(m[k], 4)] for k in keys]) + "\n")
        for tname in ("table3", "heikkila"):
            if tname in t:
                cols = list(t[tname])
                rows = list(zip(*[[_fmt(v, 4) if not isinstance(v, str) else v for v in t[tname][c]] for c in cols],
                                strict=True))
                self.md.append(f"**{tname}**\n\n" + _table(cols, rows) + "\n")
        if "reproj_rms_px" in m:
            def fig(m):
                return (f"{_fmt(m['reproj_rms_px'], 3)}, {_fmt(m.get('opencv_reproj_rms_px'), 3)}, "
                        f"{_fmt(m.get('focal_err_pct'), 3)}")

            twin = _load(self.runs / f"{name}-ideal" / "result.json")
            if twin is None and "webcam" in name:
                self.missing.append(f"{name}, ideal imaging (`runs/{name}-ideal`)")
            self.head(f"{name}: reprojection RMS (px), OpenCV on the same corners, focal error (%)", fig(m),
                      "ideal: ≤ 0.1 px and ≤ OpenCV; ≤ 0.1 %" if "webcam" in name else "", "",
                      fig(twin["metrics"]) if twin and "reproj_rms_px" in twin["metrics"] else "")
        for png in sorted((self.runs / name).glob("*.png")):
            self.figure(png, f"{name}_{png.name}", f"{name}: {png.stem.replace('_', ' ')}")

    def table3(self, name="camera_calibration_webcam"):
        """Table 3's protocol over seeds: χ and the spread of α, β over the seven pictures, realistic beside ideal."""
        runs = read_runs(self.runs / f"sweep-{name}")
        if not runs:
            self.missing.append(f"Table 3 over seeds (`runs/sweep-{name}`)")
            return
        twin = read_runs(self.runs / f"sweep-{name}-ideal")
        if not twin:
            self.missing.append(f"Table 3 over seeds, ideal imaging (`runs/sweep-{name}-ideal`)")
        keys = ("table3_chi_mean_px", "table3_chi_subpixel_mean_px", "table3_alpha_std_px", "table3_beta_std_px",
                "table3_alpha_mean_err_pct", "reproj_rms_px", "focal_err_pct", "corner_rms_px",
                "heikkila_within_2std", "heikkila_within_3std")
        thesis = {"table3_chi_mean_px": 0.443, "table3_alpha_std_px": runs[0]["metrics"].get(
            "thesis_table3_alpha_std_px"), "table3_beta_std_px": runs[0]["metrics"].get("thesis_table3_beta_std_px")}
        st = {k: _stats(r["metrics"].get(k) for r in runs) for k in keys}
        tw = {k: _stats(r["metrics"].get(k) for r in twin) for k in keys}

        def cell(s):
            return f"{_fmt(s['median'], 3)} ({_fmt(s['q25'], 2)} – {_fmt(s['q75'], 2)})" if s.get("n") else "—"

        self.md.append(f"## Table 3 over seeds ({name})\n\n`bench sweep scenarios/{name}.yaml --seeds {len(runs)} "
                       "--set pipeline.compare_extractors=false` (folder `sweep-{name}`, and `-ideal` with "
                       "`camera.imaging=ideal`): median (interquartile range)\n".replace("{name}", name))
        self.md.append(_table(["metric", f"realistic ({len(runs)} seeds)", f"ideal ({len(twin)} seeds)", "thesis"],
                              [[f"`{k}`", cell(st[k]), cell(tw[k]), _fmt(thesis.get(k), 3)] for k in keys]) + "\n")
        def fig(st):
            return (f"{_fmt(st['table3_chi_mean_px'].get('median'), 3)}; "
                    f"{_fmt(st['table3_alpha_std_px'].get('median'), 2)} / "
                    f"{_fmt(st['table3_beta_std_px'].get('median'), 2)}")

        self.head(f"Table 3 protocol ({name}): χ (px); std of α / β over the pictures (px) (median of {len(runs)})",
                  fig(st), "χ 0.33 – 0.58; std within 2× of Table 3's",
                  f"0.443; {_fmt(thesis['table3_alpha_std_px'], 2)} / {_fmt(thesis['table3_beta_std_px'], 2)}",
                  fig(tw) if twin else "")

    def real_webcam(self, name="real_webcam_replica"):
        """The real webcam photos simulated (a ``camera_replica`` sweep): calibration residuals, sim beside real."""
        runs = read_runs(self.runs / f"sweep-{name}")
        if not runs:
            self.missing.append(f"the real webcam photos simulated (`runs/sweep-{name}`)")
            return
        from bench.scenario.camera_replica import STATS

        self.md.append(f"## The real webcam photos simulated\n\n`bench sweep scenarios/{name}.yaml --seeds {len(runs)}`"
                       f" (folder `sweep-{name}`): the real photos' calibration residuals beside the simulated ones "
                       "(same camera, board and 19 poses; same detector and calibration code)\n")
        rows = []
        for k in STATS + ("rms_ratio", "sift_ratio", "sim_focal_error_pct"):
            real = runs[0]["metrics"].get(f"real_{k}")
            st = _stats(r["metrics"].get(k if real is None else f"sim_{k}") for r in runs)
            rows.append([f"`{k}`", _fmt(real, 3) if real is not None else "—", _fmt(st.get("median"), 3),
                         f"{_fmt(st.get('min'), 3)} – {_fmt(st.get('max'), 3)}" if st.get("n") else "—"])
        self.md.append(_table(["statistic", "real photos", "simulated (median)", "range"], rows) + "\n")
        real = runs[0]["metrics"]["real_rms_px"]
        sim = _stats(r["metrics"].get("sim_rms_px") for r in runs)
        self.head(f"The real webcam photos simulated: calibration RMS (px), simulated (median of {len(runs)}) vs real",
                  f"{_fmt(sim['median'], 3)} vs {_fmt(real, 3)} (× {sim['median'] / real:.2f})", "× 0.7 – 1.3", "")

    def envelope(self, folder="envelope", locate="locate.json"):
        """Issue 13's envelope sweep (``tools/integrity_summary.py``'s tables and Stanford plot) and its headline."""
        sys.path.insert(0, str(ROOT / "tools"))
        import integrity_summary as S

        sweep = self.runs / folder
        if not (sweep / "sweep.sqlite").is_file():
            self.missing.append(f"the operating envelope (`runs/{folder}`)")
            return
        runs = S.load_runs(sweep, locate)
        fig = self.figures / "envelope_stanford.png"  # docs/integrity.md keeps its own
        self.figures.mkdir(parents=True, exist_ok=True)
        self.md.append(f"## The operating envelope: integrity (issue 13)\n\n`bench sweep scenarios/ta40_envelope.yaml` "
                       f"(folder `{folder}`; the grid in the scenario's header), summarised by "
                       f"`tools/integrity_summary.py`\n")
        self.md.append(S.report(runs, fig, locate))
        cell = [r for r in runs if r["water"] in ("clear_ocean", "coastal") and r["standoff_m"] <= 1.0]
        ok = [r for r in runs if r.get("integrity") == "ok"]
        if not ok:
            return
        e = np.array([r["err_mm"] for r in ok])
        a = np.array([r["err_deg"] for r in ok])
        cov = np.mean([r["nees_pos"] <= S.Q95 for r in ok])
        ratio = np.median([r["pr_mm"] for r in ok]) / np.median(e)
        avail = sum(r.get("integrity") == "ok" for r in cell) / max(len(cell), 1)
        self.head(f"Operating envelope ({len(runs)} runs): silent failures; availability clear + coastal 0.5-1.0 m; "
                  "ok runs: error median / p95, 95 % coverage (position), protection radius / error",
                  f"{sum(S.silent(r) for r in runs)}; {100 * avail:.0f} %; {np.median(e):.2f} mm / "
                  f"{np.percentile(e, 95):.2f} mm, {np.percentile(a, 95):.3f}° p95; {100 * cov:.0f} %; {ratio:.1f}",
                  "0; ≥ 90 %; ≤ 0.5 / ≤ 2 mm, ≤ 0.05°; 90-99 %; ≤ 3")

    def flatport(self, name, title):
        r = _load(self.runs / name / "result.json")
        if r is None:
            self.missing.append(f"{name} (`runs/{name}`)")
            return
        m, c = r["metrics"], r["tables"]["flatport_calibration"]
        k3 = " --set calibration.k3=true" if name.endswith("_k3") else ""
        self.md.append(f"## {title}\n\n`bench run scenarios/flatport_study.yaml{k3}` (threshold "
                       f"{_fmt(m.get('threshold_px'))} px RMS over the image)\n")
        rows = []
        for i in range(len(c["lens_to_glass_mm"])):
            case = f"d0_{c['lens_to_glass_mm'][i]:g}mm_{c['alignment'][i]}"
            lo, hi = c["polynomial_ok_from_m"][i], c["polynomial_ok_to_m"][i]
            ok = "never" if lo is None or hi is None or not np.isfinite(lo) else f"{_fmt(lo)}-{_fmt(hi)}"
            rows.append([c["alignment"][i], _fmt(c["lens_to_glass_mm"][i]), _fmt(c["calib_rms_px"][i]),
                         _fmt(m.get(f"rms_px_at_0p2m_{case}")), _fmt(m.get(f"rms_px_at_calib_{case}")),
                         _fmt(m.get(f"rms_px_at_3m_{case}")), _fmt(m.get(f"rms_mm_at_3m_{case}")), ok])
        self.md.append(_table(["port", "lens-to-glass (mm)", "calibration RMS (px)", "RMS at 0.2 m (px)",
                               "RMS at the calibration distance (px)", "RMS at 3 m (px)", "RMS at 3 m (mm)",
                               "polynomial model ok (m)"], rows) + "\n")
        self.figure(self.runs / name / "flatport_error_vs_distance.png", f"{name}.png", title)

    # --- output -----------------------------------------------------------------------------------------------------
    def write(self) -> None:
        head = _table(["what", "measured (realistic imaging)", "ideal imaging", "target", "thesis"],
                      self.headline) if self.headline else ""
        missing = ("\n\nNot run yet (`make reproduce` runs them): " + "; ".join(self.missing) + ".") \
            if self.missing else ""
        doc = ("# Results (generated by `make reproduce`; do not edit)\n\n" + head + missing + "\n\n"
               + "\n".join(self.md))
        self.docs.mkdir(parents=True, exist_ok=True)
        (self.docs / "results.md").write_text(doc)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", default="runs", help="the folder make reproduce wrote (default runs)")
    ap.add_argument("--docs", default=str(ROOT / "docs"))
    ap.add_argument("--envelope-locate", default="locate.json",
                    help="the envelope runs' localisation file (relocated/locate.json: tools/relocate_sweep.py)")
    args = ap.parse_args(argv)
    rep = Report(Path(args.runs), Path(args.docs))
    rep.table2()
    rep.tracker()
    rep.insitu(ideal="sweep-insitu-ideal")
    rep.insitu("sweep-insitu-air", "TA-40 in situ, air camera (`camera.preset=air_webcam`)")
    rep.budget()
    rep.xy_table("xy_table_webcam", "5-8")
    rep.xy_table("xy_table_underwater", "11-14")
    rep.camera("camera_calibration_webcam")
    rep.camera("camera_calibration_underwater")
    rep.table3()
    rep.real_webcam()
    rep.envelope(locate=args.envelope_locate)
    rep.flatport("flatport_study", "Flat-port study: the polynomial (Heikkilä) model vs working distance")
    rep.flatport("flatport_study_k3", "Flat-port study with k3")
    rep.write()
    print(f"wrote {Path(args.docs) / 'results.md'}"
          + (f"; not run: {len(rep.missing)} parts" if rep.missing else ""), file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
