"""Protection levels of the in-situ localisation (bench.vision.integrity.protection_levels) and the envelope summary
(tools/integrity_summary.py) on synthetic runs."""

import json
import sqlite3
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.stats import chi2

from bench.geometry.quaternion import rotation_vector_to_matrix
from bench.geometry.transforms import homogeneous
from bench.vision import integrity as I

ROOT = Path(__file__).resolve().parents[2]


def _cov(rng, sig_pos_m, sig_rot_rad):
    A = rng.normal(size=(6, 6))
    Q, _ = np.linalg.qr(A)
    cov = np.zeros((6, 6))
    cov[:3, :3] = np.diag([1.0, 0.5, 0.2]) * sig_rot_rad**2
    cov[3:, 3:] = Q[:3, :3] @ np.diag([1.0, 0.4, 0.1]) * sig_pos_m**2 @ Q[:3, :3].T
    return cov


def test_protection_levels_scale_with_kappa_and_the_inflations():
    rng = np.random.default_rng(0)
    cov = _cov(rng, 1e-3, 1e-4)
    k = np.sqrt(chi2.ppf(1 - I.INTEGRITY_RISK, 3))
    tests = {"inflation_chi2": 1.5, "inflation_whiteness": 2.0}
    pr1, pa1 = I.protection_levels(cov, dict(tests), kappa=1.0, floor_mm=0.0, floor_deg=0.0)
    sig_pos = np.sqrt(np.linalg.eigvalsh(cov[3:, 3:]).max())
    assert pr1 == pytest.approx(k * 3.0 * sig_pos, rel=1e-12)
    assert pa1 == pytest.approx(k * 3.0 * 1e-4, rel=1e-12)
    pr2, pa2 = I.protection_levels(cov, dict(tests), kappa=2.5, floor_mm=0.0, floor_deg=0.0)
    assert pr2 == pytest.approx(2.5 * pr1) and pa2 == pytest.approx(2.5 * pa1)
    pr3, _ = I.protection_levels(cov, dict(tests), kappa=1.0, floor_mm=0.5, floor_deg=0.0)
    assert pr3 == pytest.approx(pr1 + 0.5e-3)
    # test 2's disagreement: a third of it in quadrature
    pr4, pa4 = I.protection_levels(cov, {**tests, "relative_pose_mm": 30.0, "relative_pose_deg": 0.3}, kappa=1.0,
                                   floor_mm=0.0, floor_deg=0.0)
    assert pr4 == pytest.approx(np.hypot(pr1, 0.01)) and pa4 == pytest.approx(np.hypot(pa1, np.deg2rad(0.1)))
    t = dict(tests)
    I.protection_levels(cov, t)
    assert t["kappa"] == I.KAPPA and t["k_factor"] == pytest.approx(k)


def _fake_sweep(tmp_path, rng, n=40, optimism=3.0):
    """A sweep folder with ``n`` runs whose true errors are ``optimism`` times the reported covariance's."""
    out = tmp_path / "sweep"
    db_path = out / "sweep.sqlite"
    out.mkdir()
    db = sqlite3.connect(db_path)
    db.execute("CREATE TABLE runs (run_id TEXT PRIMARY KEY, params TEXT, seed INTEGER, status TEXT, message TEXT, "
               "metrics TEXT, timings TEXT, versions TEXT, result_path TEXT, finished REAL)")
    for i in range(n):
        rid = f"run{i:03d}"
        cov = _cov(rng, 0.4e-3, 2e-5)
        e = rng.multivariate_normal(np.zeros(6), cov * optimism**2)
        T_true = homogeneous(np.eye(3), [0.1, 0.2, 0.0])
        T = homogeneous(rotation_vector_to_matrix(e[:3]), T_true[:3, 3] + e[3:])
        tests = {"inflation_chi2": 1.0, "inflation_whiteness": 1.0}
        pr, pa = I.protection_levels(cov, tests)
        level = "ok" if pr * 1e3 <= I.ALERT_MM else "warning"
        run = out / "runs" / rid
        (run / "dataset" / "truth").mkdir(parents=True)
        (run / "dataset" / "truth" / "truth.yaml").write_text(yaml.safe_dump(
            {"T_world_base_survey": np.eye(4).tolist(), "T_world_base_locate": T_true.tolist()}))
        (run / "locate.json").write_text(json.dumps({
            "success": True, "integrity": level, "integrity_reasons": [], "integrity_tests": tests,
            "protection_radius_mm": pr * 1e3, "protection_angle_deg": float(np.rad2deg(pa)),
            "T_world_base": T.tolist(), "covariance": cov.tolist()}))
        params = {"site.water": ["clear_ocean", "coastal"][i % 2], "site.standoff_m": [0.5, 1.0][(i // 2) % 2],
                  "site.textures": {} if i % 3 else {"backplate": "data/textures/natural_gravel.png"}}
        db.execute("INSERT INTO runs VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                   (rid, json.dumps(params), i, "done", "", "{}", json.dumps({"total_s": 30.0}), "{}", "", 0.0))
    db.commit()
    db.close()
    return out


def test_summary_measures_coverage_silent_failures_and_fits_kappa(tmp_path):
    sys.path.insert(0, str(ROOT / "tools"))
    import integrity_summary as S

    rng = np.random.default_rng(7)
    sweep = _fake_sweep(tmp_path, rng, n=60, optimism=3.0)
    runs = S.load_runs(sweep)
    assert len(runs) == 60 and {r["texture"] for r in runs} == {"procedural", "natural_gravel"}
    nees = np.array([r["nees_pos"] for r in runs])
    assert np.median(nees) == pytest.approx(9 * chi2.median(3), rel=0.5)  # errors 3x the covariance's
    kappa = S.fit_kappa(runs)
    assert 2.0 < kappa < 4.5
    assert np.mean(nees <= S.Q95 * kappa**2) == pytest.approx(0.95, abs=0.03)
    consistent = S.fit_kappa([{**r, "nees_pos": r["nees_pos"] / 9} for r in runs])
    assert consistent < 1.6
    # silent: ok while the error exceeds the radius
    r = dict(runs[0], integrity="ok", err_mm=2.0, pr_mm=1.0, err_deg=0.0, pa_deg=1.0)
    assert S.silent(r) and not S.silent(dict(r, pr_mm=2.5)) and S.silent(dict(r, err_mm=3.5, pr_mm=9.0))
    doc = tmp_path / "integrity.md"
    doc.write_text(f"# x\n\n{S.BEGIN}\nSTALE TEXT\n{S.END}\nafter\n")
    assert S.main([str(sweep), "--doc", str(doc), "--figure", str(tmp_path / "figures" / "stanford.png")]) == 0
    text = doc.read_text()
    assert "STALE TEXT" not in text and text.endswith(f"{S.END}\nafter\n") and "| all | 60 |" in text
    assert (tmp_path / "figures" / "stanford.png").stat().st_size > 1000
    assert S.main([str(tmp_path)]) == 2  # not a sweep folder
    assert S.main([str(sweep), str(tmp_path)]) == 2
