"""tools/results_report.py: docs/results.md (its headline table first) comes from the runs, nothing by hand."""

import importlib.util
import json
from pathlib import Path

from bench.scenario.sweep import SweepStore

ROOT = Path(__file__).resolve().parents[1]


def _tool():
    spec = importlib.util.spec_from_file_location("results_report", ROOT / "tools" / "results_report.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _sweep(folder: Path, metrics: list) -> None:
    store = SweepStore(folder / "sweep.sqlite")  # the sweep's own writer, so the schema is the real one
    for seed, m in enumerate(metrics):
        store.add(f"r{seed}", {}, seed, {"status": "done", "message": "", "metrics": m, "timings": {},
                                         "versions": {}, "result_path": None})
    store.close()


def _insitu(err, scale=1.0, integrity=None):
    m = {"base_pos_err_mm": err * scale, "base_rot_err_deg": err * scale / 100, "valve_tool_err_mm": err / 4,
         "base_pos_bound_mm": 1.0, "base_rot_bound_deg": 0.01, "base_pos_crb_mm": 0.9, "base_pos_floor_mm": 0.4,
         "base_rot_crb_deg": 0.009, "base_rot_floor_deg": 0.004}
    if integrity:
        ok, refused, radius = integrity
        m.update({"integrity_ok": ok, "integrity_refused": refused, "protection_radius_mm": radius,
                  "protection_angle_deg": None if radius is None else radius / 10})
    return m


def test_report_from_runs(tmp_path):
    runs = tmp_path / "runs"
    (runs / "table2").mkdir(parents=True)
    (runs / "table2" / "result.json").write_text(json.dumps({"metrics": {
        "max_abs_reduced_error_linear": 2e-14, "mc_heldout_rms_mm_rms": 0.0264, "heldout_rms_bound_mm": 0.0266,
        "mc_seeds": 500}, "tables": {}, "timings_s": {}}))
    # realistic: ok, warning, refused; the warning's 2 mm error lies outside its 1.5 mm radius
    _sweep(runs / "sweep-insitu", [_insitu(1.0, integrity=(1, 0, 4.0)), _insitu(2.0, integrity=(0, 0, 1.5)),
                                   _insitu(3.0, integrity=(0, 1, None))])
    _sweep(runs / "sweep-insitu-ideal", [_insitu(e, 0.5) for e in (1.0, 2.0, 3.0, 4.0)])
    t3 = {"thesis_table3_alpha_std_px": 4.64, "thesis_table3_beta_std_px": 6.30}
    _sweep(runs / "sweep-camera_calibration_webcam",
           [{**t3, "table3_chi_mean_px": c, "table3_alpha_std_px": 4.0, "table3_beta_std_px": 5.0} for c in (.2, .4)])
    _sweep(runs / "sweep-real_webcam_replica", [{"real_rms_px": 0.5, "sim_rms_px": s, "rms_ratio": s / 0.5}
                                                for s in (0.4, 0.5)])
    tool = _tool()
    assert tool.main(["--runs", str(runs), "--docs", str(tmp_path / "docs")]) == 0
    doc = (tmp_path / "docs" / "results.md").read_text()
    head = doc[:doc.index("\n## ")]  # the headline table, before the first section
    assert head.startswith("# Results")
    assert "| what | measured (realistic imaging) | ideal imaging | target | thesis |" in head
    assert "0.0264 RMS over 500 draws (bound 0.0266)" in head
    # medians of the three realistic seeds, the four ideal ones beside them
    assert "| 2 mm / 0.02° / 0.5 mm | 1.25 mm / 0.0125° / 0.625 mm (4 seeds) |" in head
    assert "Efficiency (RMS bound / RMS error over the seeds): pos: 0.46" in doc  # 1 / sqrt(14 / 3)
    assert "| pos: 0.46, rot: 0.46 | pos: 0.73, rot: 0.73 |" in head  # ideal: 1 / sqrt(0.25 * 30 / 4)
    assert "| 1 / 1 / 1; radius / error 2.4; 1 outside their protection level |" in head  # median(4, 0.75)
    assert "| 0.3; 4 / 5 |" in head and "| 0.443; 4.6 / 6.3 |" in head  # Table 3: chi median of 0.2, 0.4
    assert "| 0.45 vs 0.5 (× 0.90) |" in head
    assert "Not run yet" in doc and "xy_table_webcam" in doc
    assert "figures/bound-sweep-insitu.png" in doc
    assert (tmp_path / "docs" / "figures" / "bound-sweep-insitu.png").is_file()
    tool.main(["--runs", str(runs), "--docs", str(tmp_path / "docs")])
    assert (tmp_path / "docs" / "results.md").read_text() == doc  # idempotent


def test_budget_section_names_its_method_and_closure(tmp_path):
    """The budget section says how its shares were measured (the paired displacement where the runs carry the signed
    errors), gives the difference of mean squares beside them, the closure, and the plot."""
    import numpy as np

    from bench.scenario.budget import _plot, budget_from_rows

    rng = np.random.default_rng(3)
    floor, a, b = (rng.normal(0, s, (8, 3)) for s in (0.2, 1.0, 0.3))

    def rows(v):
        return [{"seed": k, "metrics": {"err_mm": float(np.linalg.norm(v[k])),
                                        **{f"err_{x}_mm": float(v[k][i]) for i, x in enumerate("xyz")}}}
                for k in range(8)]

    data = {"full": rows(floor + a + b), "features": rows(floor + b), "encoders": rows(floor + a),
            "none": rows(floor)}
    table, budget, metrics = budget_from_rows(data, ["features", "encoders"], ["err_mm"],
                                              {"err_mm": ("err_x_mm", "err_y_mm", "err_z_mm")})
    folder = tmp_path / "runs" / "budget-insitu"
    folder.mkdir(parents=True)
    _plot(budget, ["err_mm"], table, folder / "budget.png", "test")
    (folder / "result.json").write_text(json.dumps({"metrics": metrics, "tables": {"variants": table,
                                                                                    "budget": budget}}))
    tool = _tool()
    assert tool.main(["--runs", str(tmp_path / "runs"), "--docs", str(tmp_path / "docs")]) == 0
    doc = (tmp_path / "docs" / "results.md").read_text()
    section = doc[doc.index("## Error budget"):]
    section = section[:section.index("\n## ", 4)] if "\n## " in section[4:] else section
    assert "`sqrt(mean |e_full − e_without|²)`" in section
    assert f"| features | {metrics['budget_features_mm']:.3g} [" in section
    assert "Beside it, the difference of the mean squares" in section
    assert f"Closure, `sqrt(Σ shares² + RMS_none²) / RMS_full` (1 when the shares add up): err_mm " \
           f"{metrics['budget_closure_err_mm']:.3g}" in section
    assert "figures/budget-insitu.png" in section and (tmp_path / "docs" / "figures" / "budget-insitu.png").is_file()
    assert "_method" not in section and "_difference" not in section  # bookkeeping columns are not shares
