"""tools/results_report.py: docs/results.md (its headline table first) comes from the runs, nothing by hand."""

import importlib.util
import json
import sqlite3
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _tool():
    spec = importlib.util.spec_from_file_location("results_report", ROOT / "tools" / "results_report.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_report_from_runs(tmp_path):
    runs = tmp_path / "runs"
    (runs / "table2").mkdir(parents=True)
    (runs / "table2" / "result.json").write_text(json.dumps({"metrics": {
        "max_abs_reduced_error_linear": 2e-14, "mc_heldout_rms_mm_rms": 0.0264, "heldout_rms_bound_mm": 0.0266,
        "mc_seeds": 500}, "tables": {}, "timings_s": {}}))
    sweep = runs / "sweep-insitu"
    sweep.mkdir()
    db = sqlite3.connect(sweep / "sweep.sqlite")
    db.execute("CREATE TABLE runs (params TEXT, seed INT, status TEXT, metrics TEXT, result_path TEXT)")
    for seed, err in enumerate([1.0, 2.0, 3.0]):
        db.execute("INSERT INTO runs VALUES (?, ?, 'done', ?, NULL)",
                   ("{}", seed, json.dumps({"base_pos_err_mm": err, "base_rot_err_deg": err / 100,
                                            "valve_tool_err_mm": err / 4, "base_pos_bound_mm": 1.0,
                                            "base_rot_bound_deg": 0.01, "base_pos_crb_mm": 0.9,
                                            "base_pos_floor_mm": 0.4, "base_rot_crb_deg": 0.009,
                                            "base_rot_floor_deg": 0.004})))
    db.commit()
    db.close()
    tool = _tool()
    assert tool.main(["--runs", str(runs), "--docs", str(tmp_path / "docs")]) == 0
    doc = (tmp_path / "docs" / "results.md").read_text()
    head = doc[:doc.index("\n## ")]  # the headline table, before the first section
    assert head.startswith("# Results") and "| what | measured | target | thesis |" in head
    assert "0.0264 RMS over 500 draws (bound 0.0266)" in head
    assert "2 mm / 0.02° / 0.5 mm" in head  # medians of the three seeds
    assert "Efficiency (RMS bound / RMS error over the seeds): pos: 0.46" in doc  # 1 / sqrt(14 / 3)
    assert "Not run yet" in doc and "xy_table_webcam" in doc
    assert "figures/bound-sweep-insitu.png" in doc
    assert (tmp_path / "docs" / "figures" / "bound-sweep-insitu.png").is_file()
    tool.main(["--runs", str(runs), "--docs", str(tmp_path / "docs")])
    assert (tmp_path / "docs" / "results.md").read_text() == doc  # idempotent
