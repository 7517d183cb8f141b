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


def test_norm_quantile_against_closed_forms_and_monte_carlo():
    """Isotropic: sigma sqrt(chi2_n^-1(p)); one direction: the normal's two-sided quantile; anisotropic: an
    independent Monte Carlo of |e| (its own draws) within its sampling error."""
    p = 1 - I.INTEGRITY_RISK
    assert I.norm_quantile(np.eye(3) * 4e-6, p) == pytest.approx(2e-3 * np.sqrt(chi2.ppf(p, 3)), rel=0.01)
    assert I.norm_quantile(np.diag([1e-6, 1e-6, 0.0]), p) == pytest.approx(1e-3 * np.sqrt(chi2.ppf(p, 2)), rel=0.01)
    assert I.norm_quantile(np.diag([0.0, 9.0, 0.0]), p) == pytest.approx(3.0 * 3.2905, rel=0.01)
    rng = np.random.default_rng(3)
    cov = _cov(rng, 1e-3, 1e-4)[3:, 3:]
    e = rng.multivariate_normal(np.zeros(3), cov, size=2_000_000)
    assert I.norm_quantile(cov, p) == pytest.approx(np.quantile(np.linalg.norm(e, axis=1), p), rel=0.02)
    assert I.norm_quantile(cov, 0.5) == pytest.approx(np.median(np.linalg.norm(e, axis=1)), rel=0.01)
    # below k sigma_max (the bound it replaces) for an anisotropic covariance
    assert I.norm_quantile(cov, p) < np.sqrt(chi2.ppf(p, 3) * np.linalg.eigvalsh(cov).max())


def test_protection_levels_scale_with_kappa_and_the_inflations():
    rng = np.random.default_rng(0)
    cov = _cov(rng, 1e-3, 1e-4)
    p = 1 - I.INTEGRITY_RISK
    tests = {"inflation_chi2": 1.5, "whiteness_rho": 0.6}
    pr1, pa1 = I.protection_levels(cov, dict(tests), kappa=1.0, floor_mm=0.0, floor_deg=0.0)
    assert pr1 == pytest.approx(1.5 * I.norm_quantile(cov[3:, 3:], p), rel=1e-12)
    assert pa1 == pytest.approx(1.5 * I.norm_quantile(cov[:3, :3], p), rel=1e-12)
    pr2, pa2 = I.protection_levels(cov, dict(tests), kappa=2.5, floor_mm=0.0, floor_deg=0.0)
    assert pr2 == pytest.approx(2.5 * pr1) and pa2 == pytest.approx(2.5 * pa1)
    # the floor and a third of test 2's disagreement beyond a clean run's: in quadrature (not the raw one)
    pr3, _ = I.protection_levels(cov, dict(tests), kappa=1.0, floor_mm=0.5, floor_deg=0.0)
    assert pr3 == pytest.approx(np.hypot(pr1, 0.5e-3))
    pr4, pa4 = I.protection_levels(cov, {**tests, "relative_pose_excess_mm": 30.0, "relative_pose_excess_deg": 0.3,
                                         "relative_pose_mm": 90.0}, kappa=1.0, floor_mm=0.0, floor_deg=0.0)
    assert pr4 == pytest.approx(np.hypot(pr1, 0.01)) and pa4 == pytest.approx(np.hypot(pa1, np.deg2rad(0.1)))
    # whiteness is reported, not applied
    pr5, _ = I.protection_levels(cov, {**tests, "whiteness_rho": 0.0}, kappa=1.0, floor_mm=0.0, floor_deg=0.0)
    assert pr5 == pr1
    t = dict(tests)
    I.protection_levels(cov, t)
    assert t["kappa"] == 1.0 and 1.0 < t["q_factor_pos"] < np.sqrt(chi2.ppf(p, 3))
    assert I.protection_levels(np.full((6, 6), np.nan), {}) == (np.inf, np.inf)


def test_relative_pose_excess_is_the_james_stein_shrinkage_of_the_disagreement():
    """Test 2's disagreement beyond a clean run's: nothing at a clean run's significance, nearly all of a far larger
    one; and, as James-Stein's estimate, closer to the true kinematic error than the raw disagreement in the metric
    of its covariance (a Monte Carlo over correlated noise, the overdispersion its scale)."""
    d = np.r_[np.deg2rad([0.3, 0.0, 0.4]), [0.003, 0.0, 0.004]]  # 0.5 deg and 5 mm
    s2, p = I.RELATIVE_OVERDISPERSION, I.RELATIVE_DOF
    assert I.relative_pose_excess(d, (p - 2) * s2) == (0.0, 0.0)  # as significant as noise: nothing beyond it
    assert I.relative_pose_excess(d, 0.5 * (p - 2) * s2) == (0.0, 0.0)
    mm, deg = I.relative_pose_excess(d, 4 * (p - 2) * s2)
    assert mm == pytest.approx(0.75 * 5.0, rel=1e-12) and deg == pytest.approx(0.75 * 0.5, rel=1e-12)
    assert I.relative_pose_excess(d, np.inf) == pytest.approx((5.0, 0.5), rel=1e-12)
    assert I.relative_pose_excess(d, np.nan) == (0.0, 0.0)
    rng = np.random.default_rng(7)
    A = rng.normal(size=(6, 6))
    C = A @ A.T * 1e-6 + np.diag([1e-6] * 3 + [1e-4] * 3)
    Ci, L = np.linalg.inv(C), np.linalg.cholesky(s2 * C)
    for D in (np.zeros(6), L @ rng.normal(size=6), 4 * L @ rng.normal(size=6)):
        n = rng.normal(size=(4000, 6)) @ L.T
        d = D + n
        m2 = np.einsum("ni,ij,nj->n", d, Ci, d)
        scale = np.clip(1 - (p - 2) * s2 / m2, 0, None)
        assert np.allclose([I.relative_pose_excess(x, m)[0] for x, m in zip(d[:50], m2[:50], strict=True)],
                           scale[:50] * np.linalg.norm(d[:50, 3:], axis=1) * 1e3, rtol=1e-12)
        loss = lambda e: np.mean(np.einsum("ni,ij,nj->n", e, Ci, e))  # noqa: E731
        assert loss(scale[:, None] * d - D) < loss(d - D)


def test_an_earlier_locate_json_gets_the_excess_from_its_own_statistics():
    """A locate.json written before relative_pose_excess: its raw disagreement and Mahalanobis square give the same
    figures (one region, and several pooled by their root mean square) at the overdispersion of those versions'
    squares, which had no lab term; nothing is overwritten."""
    rng = np.random.default_rng(11)
    one, pooled = {}, {}
    for name in ("r0", "r1", "r2"):
        d = rng.normal(size=6) * np.r_[[0.005] * 3, [0.004] * 3]
        m2 = float(rng.uniform(20, 400))
        mm, deg = I.relative_pose_excess(d, m2, I.RELATIVE_OVERDISPERSION_FEATURES)
        pooled.update({f"{name}/relative_pose_mm": np.linalg.norm(d[3:]) * 1e3,
                       f"{name}/relative_pose_deg": np.rad2deg(np.linalg.norm(d[:3])),
                       f"{name}/relative_pose_chi2": m2, f"{name}/excess": (mm, deg)})
        one = {"relative_pose_mm": np.linalg.norm(d[3:]) * 1e3, "relative_pose_deg": np.rad2deg(np.linalg.norm(
            d[:3])), "relative_pose_chi2": m2}
    got = I.with_relative_pose_excess(one)
    assert (got["relative_pose_excess_mm"], got["relative_pose_excess_deg"]) == pytest.approx((mm, deg), rel=1e-12)
    assert "relative_pose_excess_mm" not in one  # a copy
    old = {k: v for k, v in pooled.items() if not k.endswith("/excess")}
    got = I.with_relative_pose_excess(old)
    for i, u in enumerate(("mm", "deg")):
        e = [pooled[f"{r}/excess"][i] for r in ("r0", "r1", "r2")]
        assert got[f"relative_pose_excess_{u}"] == pytest.approx(np.sqrt(np.mean(np.square(e))), rel=1e-12)
    kept = I.with_relative_pose_excess({**one, "relative_pose_excess_mm": 7.0, "relative_pose_excess_deg": 0.1})
    assert kept["relative_pose_excess_mm"] == 7.0
    assert I.with_relative_pose_excess({"chi2_ratio": 1.0}) == {"chi2_ratio": 1.0}  # test 2 did not run


def test_smallest_eigenvalue_flags_a_covariance_that_is_not_positive_definite():
    rng = np.random.default_rng(2)
    cov = _cov(rng, 1e-3, 1e-4)
    assert I.smallest_eigenvalue(cov) > 0
    bad = cov.copy()
    bad[3, 4] = bad[4, 3] = 2 * np.sqrt(cov[3, 3] * cov[4, 4])  # a correlation of 2
    assert I.smallest_eigenvalue(bad) < 0
    assert np.isnan(I.smallest_eigenvalue(np.full((6, 6), np.nan)))


def _points_pose_covariance(p, t_base, sigma_m=1e-4):
    """The first-order covariance of a base pose (rotation vector, origin) that the points ``p`` (N, 3) fix, each
    seen with isotropic noise ``sigma_m``: a pose error ``(w, v)`` moves a point by ``w x (p - t) + v``."""
    from bench.geometry.transforms import skew

    info = np.zeros((6, 6))
    for x in p:
        J = np.hstack([-skew(x - t_base), np.eye(3)])
        info += J.T @ J / sigma_m**2
    return np.linalg.inv(info)


def test_pose_condition_is_the_geometry_of_the_points_not_the_lever_arm_or_units():
    rng = np.random.default_rng(5)
    spread = rng.normal(size=(200, 3)) * [0.2, 0.2, 0.2] + [0.3, -0.1, 1.4]  # a cloud 1.4 m ahead
    T_near, T_far = np.eye(4), homogeneous(rotation_vector_to_matrix([0.1, -0.2, 0.3]), [-2.0, 1.0, -1.5])
    c_near = I.pose_condition(_points_pose_covariance(spread, T_near[:3, 3]), T_near, spread)
    c_far = I.pose_condition(_points_pose_covariance(spread, T_far[:3, 3]), T_far, spread)
    assert c_near == pytest.approx(c_far, rel=1e-9)  # the same geometry seen from another base origin
    assert c_near < 10  # an isotropic cloud fixes every direction alike (the rotation at its RMS radius)
    # noise and units: a uniform scale of the covariance changes nothing
    assert I.pose_condition(4 * _points_pose_covariance(spread, T_near[:3, 3]), T_near, spread) == pytest.approx(c_near)
    # degenerate geometry: points nearly collinear give a condition in the thousands and beyond
    line = np.outer(rng.uniform(-0.3, 0.3, 50), [1.0, 0.2, 0.0]) + [0.3, -0.1, 1.4] + rng.normal(size=(50, 3)) * 1e-4
    assert I.pose_condition(_points_pose_covariance(line, T_near[:3, 3]), T_near, line) > 1e4 * c_near
    assert np.isnan(I.pose_condition(np.full((6, 6), np.nan), T_near, spread))
    assert np.isnan(I.pose_condition(np.eye(6), T_near, spread[:2]))


def test_conditioning_weighs_the_joint_bundles_pose_not_its_start():
    from types import SimpleNamespace

    def run(condition, pose_condition):
        tests, refuse = {}, []
        warn = I._conditioning(SimpleNamespace(condition=condition, pose_condition=pose_condition), tests, refuse)
        return warn, refuse, tests

    # the joint bundle refined the pose: its own condition decides, the start's (2e4, beyond the thesis's limit) not
    assert run(2e4, 50.0)[:2] == ([], [])
    warn, refuse, tests = run(10.0, 5e4)
    assert refuse == [] and len(warn) == 1 and "joint bundle" in warn[0] and tests["pose_condition"] == 5e4
    assert run(10.0, 1e9)[1] and run(10.0, float("inf"))[1]  # points collinear, or a singular covariance
    # the thesis estimator alone (no joint bundle): its own condition, with its own limits
    assert run(2e4, float("nan"))[0] and not run(2e4, float("nan"))[1]
    assert run(2e8, float("nan"))[1]
    assert run(50.0, float("nan"))[:2] == ([], []) and "pose_condition" not in run(50.0, float("nan"))[2]

def test_kappa_of_the_estimators():
    assert I.kappa_of("joints") == I.KAPPA["joints"]
    assert I.kappa_of("bundle") == I.KAPPA["bundle"]
    assert I.kappa_of("pose") == I.kappa_of("joints", pnp=True) == I.KAPPA_UNMEASURED == max(I.KAPPA.values())
    # the joint bundle over several regions has its own (their feature errors do not average out); one is "joints"
    assert I.kappa_of("joints", regions=4) == I.KAPPA["joints_regions"] > I.KAPPA["joints"]
    assert I.kappa_of("joints", regions=1) == I.KAPPA["joints"]
    assert I.kappa_of("bundle", regions=4) == I.KAPPA["bundle"]
    assert I.kappa_of("joints", pnp=True, regions=4) == I.KAPPA_UNMEASURED
    # aligned keypoints (bench.vision.patch_align): their own, measured for the joint bundle; unmeasured otherwise
    assert I.kappa_of("joints", keypoints="aligned") == I.KAPPA["joints_aligned"]
    assert I.kappa_of("joints", regions=4, keypoints="aligned") == I.KAPPA["joints_regions_aligned"]
    assert I.kappa_of("bundle", keypoints="aligned") == I.KAPPA_UNMEASURED
    # SIFT's twins weighed as what they are worth: measured for one region's joint bundle; unmeasured otherwise
    assert I.kappa_of("joints", twins="weighted") == I.KAPPA["joints_weighted"]
    assert I.kappa_of("joints", regions=4, twins="weighted") == I.KAPPA_UNMEASURED
    assert I.kappa_of("joints", keypoints="aligned", twins="weighted") == I.KAPPA_UNMEASURED


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
        tests = {"inflation_chi2": 1.0}
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
    doc.write_text(f"{S.BEGIN}\n{S.END}\n")  # --seeds: only those runs (a sweep resumed with fewer seeds)
    assert S.main([str(sweep), "--seeds", "0,1,2", "--doc", str(doc)]) == 0 and "| all | 3 |" in doc.read_text()
    assert S.main([str(sweep), "--seeds", "one"]) == 2
    assert S.main([str(tmp_path)]) == 2  # not a sweep folder
    assert S.main([str(sweep), str(tmp_path)]) == 2
    assert S.main([str(sweep), "--locate", "nosuch/locate.json"]) == 2  # no run has it: not a table of failures
    # --locate: each run's localisation from another file of its folder (tools/relocate_sweep.py)
    for run in (sweep / "runs").iterdir():
        (run / "relocated").mkdir()
        (run / "relocated" / "locate.json").write_text((run / "locate.json").read_text())
    (next((sweep / "runs").iterdir()) / "locate.json").unlink()  # the old file is not read
    again = S.report(S.load_runs(sweep, "relocated/locate.json"), None, "relocated/locate.json")
    assert "Localised again" in again and "| all | 60 |" in again
    # the warnings by reason, in integrity.py's own words
    alert = "protection radius 3.9 mm / 0.1 deg exceeds the alert limit 3 mm / 0.15 deg"
    test2 = "the locate views' relative pose from the images differs from the joint readings' by 9 mm and 0.5 deg"
    warned = [{"integrity": "warning", "reasons": [alert]}, {"integrity": "warning", "reasons": [test2, alert]},
              {"integrity": "ok", "reasons": []}]
    assert S.warning_reasons(warned) == ("The 2 warnings by reason (a run may have several): the alert limit 2, test 2 "
                                         "(relative pose) 1; the alert limit alone: 1.")
    assert S.warning_reasons(warned[2:]) == "No warnings."


def test_relocate_sweep_refuses_what_it_cannot_redo(tmp_path, capsys):
    sys.path.insert(0, str(ROOT / "tools"))
    import relocate_sweep as R

    with pytest.raises(SystemExit, match="not a bench sweep folder"):
        R.main([str(tmp_path), str(ROOT / "scenarios" / "ta40_envelope.yaml")])
    sweep = _fake_sweep(tmp_path, np.random.default_rng(1), n=2, optimism=1.0)
    with pytest.raises(SystemExit, match="expected in_situ"):
        R.main([str(sweep), str(ROOT / "scenarios" / "xy_table_webcam.yaml")])
    for bad in ("dataset", "..", "a/b"):
        with pytest.raises(SystemExit, match="--name"):
            R.main([str(sweep), str(ROOT / "scenarios" / "ta40_envelope.yaml"), "--name", bad])
    envelope = str(ROOT / "scenarios" / "ta40_envelope.yaml")

    def set_params(params):
        db = sqlite3.connect(sweep / "sweep.sqlite")
        db.execute("UPDATE runs SET params = ?", (json.dumps(params),))
        db.commit()
        db.close()

    for key, value in (("pipeline.refine", "bundle"), ("sources.camera", "perfect")):
        set_params({key: value})
        with pytest.raises(SystemExit, match=key):
            R.main([str(sweep), envelope])
    set_params({})  # a run of another scenario
    for run in (sweep / "runs").iterdir():
        (run / "dataset").mkdir(exist_ok=True)
        (run / "result.json").write_text(json.dumps({"scenario": "ta40_in_situ_manifold"}))
    with pytest.raises(SystemExit, match="a run of scenario 'ta40_in_situ_manifold'"):
        R.main([str(sweep), envelope])
    set_params({"pipeline.method": "horn"})  # redone with --set giving it the run's value: past that check
    with pytest.raises(SystemExit, match="a run of scenario 'ta40_in_situ_manifold'"):
        R.main([str(sweep), envelope, "--set", "pipeline.method=horn"])
    with pytest.raises(SystemExit, match="pipeline.method='horn'"):
        R.main([str(sweep), envelope, "--set", "pipeline.method=svd"])


def test_relocate_cuts_a_survey_to_the_named_regions(tmp_path):
    """--regions: the manifest's views and the joint log's rows of the named regions (and the views without a
    region) only, their images the same files, no truth; a region the survey lacks, or a folder that is not an
    earlier cut, is a one-line error and nothing of it is removed."""
    sys.path.insert(0, str(ROOT / "tools"))
    import relocate_sweep as R

    from bench.dataset import DatasetWriter, load_dataset
    from bench.errors import BenchError, ConfigError

    rng = np.random.default_rng(5)
    src = tmp_path / "dataset"
    with DatasetWriter(src, kind="in_situ") as w:
        for region in ("r0", "r1", "r2"):
            for role, name in (("reference", "ref"), ("surround", "s0"), ("locate", "l0"), ("locate", "l1")):
                w.add_view(f"{region}_{name}", rng.integers(0, 255, (8, 8), dtype=np.uint8),
                           q=rng.uniform(-1, 1, 6), role=role, region=region)
        w.add_view("task", None, q=rng.uniform(-1, 1, 6), role="task")
        w.write_text("truth/truth.yaml", "secret: 1\n")
        w.write_text("vehicle.yaml", "tilt_sigma_deg: 0.01\n")
    cut = R.cut_regions(src, ["r0", "r2"], tmp_path / "cut" / "dataset")
    ds, full = load_dataset(cut), load_dataset(src)
    assert [v.name for v in ds.views] == [v.name for v in full.views if v.region in ("r0", "r2", "")]
    assert len(ds.views) == 9 and not (cut / "truth").exists() and (cut / "vehicle.yaml").is_file()
    for v in ds.views:  # the same images and readings
        np.testing.assert_array_equal(v.q, full.view(v.name).q)
        if v.image_path is not None:
            assert v.image_path.read_bytes() == full.view(v.name).image_path.read_bytes()
    assert R.cut_regions(src, ["r1"], cut) == cut  # an earlier cut is replaced
    assert {v.region for v in load_dataset(cut).views} == {"r1", ""}
    with pytest.raises(ConfigError, match=r"manifest.yaml: views\[\].region: no region 'r7' \(the survey's regions: "
                                          r"r0, r1, r2\)"):
        R.cut_regions(src, ["r7"], tmp_path / "other")
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep me")
    with pytest.raises(BenchError, match="non-empty folder that bench did not write"):
        R.cut_regions(src, ["r0"], mine)
    assert (mine / "notes.txt").read_text() == "keep me"


def test_summary_pairs_two_localisations_of_the_same_runs(tmp_path):
    """--against: the runs paired by id with another localisation of their datasets; one 2 mm worse everywhere is
    the less precise in every run, and a pairing with itself is precise to the same digit."""
    sys.path.insert(0, str(ROOT / "tools"))
    import integrity_summary as S

    sweep = _fake_sweep(tmp_path, np.random.default_rng(3), n=12, optimism=1.0)
    for run in (sweep / "runs").iterdir():
        rep = json.loads((run / "locate.json").read_text())
        T = np.array(rep["T_world_base"])
        T[:3, 3] += [0.002, 0.0, 0.0]  # 2 mm off in x: further from the truth than a sub-mm error is
        (run / "worse").mkdir()
        (run / "worse" / "locate.json").write_text(json.dumps({**rep, "T_world_base": T.tolist(), "integrity":
                                                               "warning"}))
    runs, worse = S.load_runs(sweep), S.load_runs(sweep, "worse/locate.json")
    text = S.paired(runs, worse, "worse/locate.json")
    row = next(ln for ln in text.splitlines() if ln.startswith("| all |"))
    assert row.endswith("| 12 of 12 |") and "| 0 / 12 / 0 |" in row
    assert "| 0.5 m | 6 |" in text and "| 1 m | 6 |" in text
    same = next(ln for ln in S.paired(runs, runs, "x").splitlines() if ln.startswith("| all |"))
    med = np.median([r["err_mm"] for r in runs])
    assert same.endswith("| 0 of 12 |") and f"| {med:.2f} / {med:.2f} |" in same
    assert S.main([str(sweep), "--against", "worse/locate.json"]) == 0
    assert S.main([str(sweep), "--against", "nosuch/locate.json"]) == 2


def _panel_map(rng, n=150, spread_m=0.0):
    from bench.vision.insitu import KeypointMap

    p = np.c_[rng.uniform(-0.4, 0.4, n), rng.uniform(-0.3, 0.3, n), 0.7 + rng.uniform(-0.05, 0.05, n)]
    return KeypointMap(p, p.copy(), None, np.full(n, 3), np.full(n, spread_m), np.eye(4))


def _free(kmap, T_ref_view, x_n, idx):
    import cv2

    ok, rvec, tvec = cv2.solvePnP(kmap.p_ref[idx], x_n, np.eye(3), None, flags=cv2.SOLVEPNP_ITERATIVE)
    T = homogeneous(cv2.Rodrigues(rvec)[0], tvec.ravel())
    return {"T_free": np.linalg.inv(T), "map_idx": idx, "x_n": x_n}


def test_relative_pose_disagreement_is_exact_without_noise_and_chi2_6_with_it():
    """Noise-free: d = 0 to 1e-9 for the true kinematic T_a_b, and the disagreement of a perturbed T_a_b is that
    perturbation; with keypoint noise (an exact map) the Mahalanobis square follows chi2_6 (mean 6, 95th
    percentile 12.6) over 300 trials; with map depth errors that the pooled sigma describes it stays at or below it."""
    rng = np.random.default_rng(11)
    T_ref_a = homogeneous(rotation_vector_to_matrix([0.02, -0.05, 0.01]), [0.03, -0.02, 0.01])
    T_ref_b = homogeneous(rotation_vector_to_matrix([-0.03, 0.08, 0.0]), [0.25, 0.01, -0.02])
    T_a_b = np.linalg.inv(T_ref_a) @ T_ref_b

    def views(kmap, sigma, p_true=None):
        out = []
        for T in (T_ref_a, T_ref_b):
            X = (np.linalg.inv(T) @ np.c_[kmap.p_ref if p_true is None else p_true, np.ones(len(kmap))].T).T[:, :3]
            x = X[:, :2] / X[:, 2:] + rng.normal(0, sigma, (len(X), 2))
            out.append(_free(kmap, T, x, np.arange(len(X))))
        return out

    kmap = _panel_map(rng)
    a, b = views(kmap, 0.0)
    d, _ = I.relative_pose_disagreement(kmap, {**a, "T_free": T_ref_a}, {**b, "T_free": T_ref_b}, T_a_b)
    assert np.abs(d).max() < 1e-9
    delta = homogeneous(rotation_vector_to_matrix([0.0, 0.01, 0.0]), [0.002, 0.0, 0.0])
    d, _ = I.relative_pose_disagreement(kmap, {**a, "T_free": T_ref_a}, {**b, "T_free": T_ref_b}, T_a_b @ delta)
    assert np.allclose(d[:3], [0.0, -0.01, 0.0], atol=1e-9)
    m2 = np.array([I.relative_pose_disagreement(kmap, *views(kmap, 3e-4), T_a_b)[1] for _ in range(300)])
    assert np.mean(m2) == pytest.approx(6.0, rel=0.15)
    assert np.mean(m2 <= chi2.ppf(0.95, 6)) == pytest.approx(0.95, abs=0.04)
    # map depth errors of 2 mm along the reference rays, known to the map through its spread
    sig = 2e-3
    kmap = _panel_map(rng, spread_m=sig * np.sqrt(2))  # spread^2 n/(n-1) / n = sigma^2 for n = 3
    ray = kmap.p_ref / np.linalg.norm(kmap.p_ref, axis=1, keepdims=True)
    z = kmap.p_ref[:, 2]
    assert np.allclose(I.map_point_sigma(kmap), sig * z**2 * np.sqrt(np.mean(z**-4.0)), rtol=1e-9)  # pooled as z^2
    m2 = []
    for _ in range(200):
        p_true = kmap.p_ref + ray * rng.normal(0, 1, (len(kmap), 1)) * I.map_point_sigma(kmap)[:, None]
        m2.append(I.relative_pose_disagreement(kmap, *views(kmap, 3e-4, p_true), T_a_b)[1])
    # conservative, not optimistic: the residual variance also holds the map error the pose sees (counted twice)
    assert 1.5 < np.mean(m2) < 6.6


def _lab_scene(rng, cov, sigma_px=0.3, n=120, dist=None, port=None):
    """A survey and two locate views of a panel through a lab calibration off by a draw of ``cov`` (fx fy cx cy px,
    with a lens ``dist`` also k1 k2 p1 p2, then mount [w, v]): the map triangulated from the surrounding views'
    kinematic poses (Eq. 162), the locate views' free poses against it, and the kinematic T_a_b - all through the
    lab's intrinsics, lens and mount, the keypoints through the true ones. Behind a flat ``port`` the camera is
    refractive: ``cov``'s intrinsics and lens are its virtual pinhole's (the lens's scaled by the port's
    magnification m, as ``bench.scenario.in_situ_lab`` writes the priors), and the keypoints are the lab camera's
    coordinates at its working range of the true camera's pixels."""
    from bench.camera.model import CameraModel, distort, undistort
    from bench.camera.refractive import RefractiveCamera, with_lens_parameters
    from bench.vision.insitu import KeypointMap

    K_lab = np.array([800.0, 790.0, 320.0, 240.0])
    dist_lab = np.zeros(5) if dist is None else np.asarray(dist, float)
    e = rng.multivariate_normal(np.zeros(len(cov)), cov)
    if port is not None:  # the lens's error from the virtual pinhole's
        m = port.n_water / port.n_air
        e = e.copy()
        e[:2] /= m
        if len(cov) == 14:
            e[4:8] /= [m**2, m**4, m, m]
    K_true = K_lab + e[:4]
    dist_true = dist_lab + (np.r_[e[4:8], 0.0] if len(cov) == 14 else 0.0)
    if port is not None:
        lens = CameraModel(640, 480, np.array([[K_lab[0], 0, K_lab[2]], [0, K_lab[1], K_lab[3]], [0, 0, 1]]),
                           dist_lab)
        cam_lab = RefractiveCamera(lens, port, 0.7)
        cam_true = RefractiveCamera(with_lens_parameters(lens, np.r_[K_true, dist_true[:4]]), port, 0.7)
    X_lab = homogeneous(rotation_vector_to_matrix([0.0, 0.0, np.pi]), [0.12, 0.0, 0.3])
    X_true = X_lab @ homogeneous(rotation_vector_to_matrix(e[-6:-3]), e[-3:])
    cams = {"ref": np.eye(4)}  # true camera poses in the reference camera's frame
    for name, w, t in (("s0", [0.0, 0.15, 0.0], [-0.1, 0.0, 0.0]), ("s1", [0.0, -0.15, 0.02], [0.1, 0.0, 0.01]),
                       ("s2", [0.12, 0.0, 0.0], [0.0, -0.1, 0.0]), ("a", [0.05, 0.2, 0.1], [-0.12, 0.03, 0.05]),
                       ("b", [-0.1, -0.25, -0.3], [0.15, -0.05, -0.03])):
        cams[name] = homogeneous(rotation_vector_to_matrix(w), t)
    p = np.c_[rng.uniform(-0.3, 0.3, n), rng.uniform(-0.2, 0.2, n), 0.7 + rng.uniform(-0.05, 0.05, n)]

    def keypoints(T):  # the pipeline's normalized keypoints: true pixels, lab intrinsics and lens
        X = (np.linalg.inv(T) @ np.c_[p, np.ones(n)].T).T[:, :3]
        if port is not None:
            return cam_lab.normalised(cam_true.project(X) + rng.normal(0, sigma_px, (n, 2)))
        uv = K_true[:2] * distort(X[:, :2] / X[:, 2:], dist_true) + K_true[2:] + rng.normal(0, sigma_px, (n, 2))
        return undistort((uv - K_lab[2:]) / K_lab[:2], dist_lab)

    def kinematic(T):  # the camera pose its link 5 gives through the lab's mount
        return T @ np.linalg.inv(X_true) @ X_lab

    x = {k: keypoints(T) for k, T in cams.items()}
    T_views = np.array([np.linalg.inv(kinematic(cams["ref"])) @ kinematic(cams[k]) for k in ("s0", "s1", "s2")])
    obs = [(np.arange(3), np.array([x[k][i] for k in ("s0", "s1", "s2")])) for i in range(n)]
    kmap = KeypointMap(np.zeros((n, 3)), np.zeros((n, 3)), None, np.full(n, 3), np.zeros(n), np.eye(4),
                       x_ref=x["ref"], T_ref_views=T_views, observations=obs)
    each = [I._map_points(KeypointMap(np.zeros((n, 3)), np.zeros((n, 3)), None, np.full(n, 1), np.zeros(n), np.eye(4),
                                      x_ref=x["ref"], T_ref_views=T_views[[k]],
                                      observations=[(np.zeros(1, int), o[1][[k]]) for o in obs]),
                          x["ref"], np.array([o[1][k] for o in obs]), T_views[[k]]) for k in range(3)]
    kmap.p_ref = np.mean(each, axis=0)
    kmap.spread_m = np.sqrt(np.mean([np.sum((q - kmap.p_ref) ** 2, axis=1) for q in each], axis=0))
    T_a_b = np.linalg.inv(kinematic(cams["a"])) @ kinematic(cams["b"])
    frees = [_free(kmap, None, x[k], np.arange(n)) for k in ("a", "b")]
    if port is not None:
        v = cam_lab.virtual_camera()
        return kmap, frees, T_a_b, I.LabPrior(cov, v.K, v.dist, refractive=cam_lab)
    K = np.array([[K_lab[0], 0.0, K_lab[2]], [0.0, K_lab[1], K_lab[3]], [0.0, 0.0, 1.0]])
    return kmap, frees, T_a_b, I.LabPrior(cov, K, dist_lab)


_LENS = (-0.3, 0.12, 0.001, -0.002, 0.0)


@pytest.mark.parametrize("lens, port", [(None, None), (_LENS, None), (_LENS, "flat")],
                         ids=["pinhole", "lens", "refractive"])
def test_relative_pose_disagreement_holds_the_lab_calibrations_errors(lens, port):
    """With the lab's intrinsics (and lens) and mount off by draws of their covariance, the disagreement of clean
    views is chi2_6 or a little below when the covariance is given (over 200 trials: mean 4.9 against 6 without a
    lens, 4.6 with one, 5.5 behind a flat port, as the map's spread and the poses' residuals also hold the lab's
    errors, which the lab term counts again; the lab term alone gives 6.0), and is overdispersed hundreds of times
    without it; the map rebuilt from the survey (Eq. 162) is the map to 1e-12. Behind the port the keypoints move
    through lens and port (the paraxial view of the virtual pinhole gives mean 6.3 here, coverage 0.94)."""
    from bench.camera.flatport import FlatPort

    if port is not None:
        port = FlatPort(d0=0.02, t=0.012, n_air=1.0, n_glass=1.52, n_water=1.34, tilt=[0.015, -0.012])
    rng = np.random.default_rng(5)
    lens_sd = [] if lens is None else [0.01, 0.02, 5e-4, 5e-4]
    A = rng.normal(size=(10 + len(lens_sd), 10 + len(lens_sd))) * 0.3
    D = np.diag([8.0, 8.0, 4.0, 4.0, *lens_sd, *np.deg2rad([0.4] * 3), 4e-3, 4e-3, 4e-3])
    cov = D @ (A @ A.T / len(A) + np.eye(len(A))) @ D  # correlated, every block's scale like a lab calibration's
    kmap, frees, T_a_b, lab = _lab_scene(rng, cov, dist=lens, port=port)
    x_obs = np.concatenate([o[1] for o in kmap.observations])
    assert np.abs(I._map_points(kmap, kmap.x_ref, x_obs, kmap.T_ref_views) - kmap.p_ref).max() < 1e-12
    with_lab, without = [], []
    for _ in range(200):
        kmap, frees, T_a_b, lab = _lab_scene(rng, cov, dist=lens, port=port)
        with_lab.append(I.relative_pose_disagreement(kmap, *frees, T_a_b, lab)[1])
        without.append(I.relative_pose_disagreement(kmap, *frees, T_a_b)[1])
    with_lab, without = np.array(with_lab), np.array(without)
    assert 4.0 < np.mean(with_lab) < 6.6  # conservative by the double count, never optimistic
    assert 0.94 <= np.mean(with_lab <= chi2.ppf(0.95, 6)) <= 0.995
    assert np.median(without) > 100 * chi2.median(6)
    with pytest.raises(ValueError, match="the map's survey"):  # a map without its survey has no lab term to give
        I.relative_pose_disagreement(_panel_map(rng), *frees, T_a_b, lab)


def test_lab_term_moves_refractive_keypoints_through_lens_and_port():
    """A refractive camera's keypoint Jacobian against the keypoints themselves: the lens moved by a small step of the
    virtual pinhole's prior (focal lengths / m, k1 / m^2, k2 / m^4, p1 p2 / m) and the true pixels normalised again
    agree with ``J step`` to second order; the paraxial view (no camera given) has k2's column 40-50 % low at the
    image corners."""
    from dataclasses import replace

    from bench.camera.flatport import FlatPort
    from bench.camera.model import CameraModel
    from bench.camera.refractive import RefractiveCamera, lens_parameters, with_lens_parameters

    lens = CameraModel(640, 480, np.array([[540.0, 0, 318.0], [0, 512.0, 236.0], [0, 0, 1]]), np.array(_LENS))
    port = FlatPort(d0=0.02, t=0.012, n_air=1.0, n_glass=1.52, n_water=1.34, tilt=[0.015, -0.012])
    cam = RefractiveCamera(lens, port, 0.8)
    m = port.n_water / port.n_air
    uv = np.array([[600.0, 400.0], [40.0, 40.0], [620.0, 460.0], [30.0, 450.0], [480.0, 240.0]])
    x_n = cam.normalised(uv)
    v = cam.virtual_camera()
    lab = I.LabPrior(np.eye(14), v.K, v.dist, refractive=cam)
    J = lab.keypoint_jacobian(x_n)
    step = np.array([0.5, -0.4, 0.3, 0.2, 2e-3, -3e-3, 1e-4, -1e-4])  # in the prior's (virtual) terms
    moved = replace(cam, lens=with_lens_parameters(lens, lens_parameters(lens)
                                                   + step / [m, m, 1, 1, m**2, m**4, m, m]))
    dx = moved.normalised(uv) - x_n
    assert np.abs(J @ step - dx).max() < 1e-3 * np.abs(dx).max()
    paraxial = replace(lab, refractive=None).keypoint_jacobian(x_n)
    ratio = np.linalg.norm(paraxial[:4, :, 5], axis=1) / np.linalg.norm(J[:4, :, 5], axis=1)  # k2 at the corners
    assert np.all(ratio < 0.85) and np.all(ratio > 0.4)
    assert lab.keypoint_jacobian(x_n[:0]).shape == (0, 2, 8)


def test_lab_term_of_a_central_lens_with_the_labs_k3():
    """A central camera's keypoint Jacobian with the lab's k3 in the prior (15 parameters: fx fy cx cy k1 k2 p1 p2 k3,
    then the mount): each of its nine columns against central differences of the normalised keypoints with that
    parameter moved; the first eight are the 14-parameter prior's."""
    from bench.camera.model import undistort

    K = np.array([[540.0, 0, 318.0], [0, 512.0, 236.0], [0, 0, 1]])
    dist = np.array([-0.3, 0.12, 0.001, -0.002, 0.05])
    uv = np.array([[600.0, 400.0], [40.0, 40.0], [620.0, 460.0], [30.0, 450.0], [480.0, 240.0]])

    def normalised(theta):  # the pixels held, the camera's nine parameters moved
        f, c = theta[:2], theta[2:4]
        return undistort((uv - c) / f, theta[4:9])

    theta0 = np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], dist]
    x_n = normalised(theta0)
    J = I.LabPrior(np.eye(15), K, dist).keypoint_jacobian(x_n)
    assert J.shape == (5, 2, 9)
    for i, h in enumerate([1e-3] * 4 + [1e-6] * 5):
        e = np.zeros(9)
        e[i] = h
        d = (normalised(theta0 + e) - normalised(theta0 - e)) / (2 * h)
        assert np.allclose(J[:, :, i], d, rtol=1e-5, atol=1e-9), i
    assert np.allclose(I.LabPrior(np.eye(14), K, dist).keypoint_jacobian(x_n), J[:, :, :8], rtol=1e-12)


def test_joint_offset_probe_names_a_missing_file(tmp_path, capsys):
    sys.path.insert(0, str(ROOT / "tools"))
    import joint_offset_probe as P

    (tmp_path / "ds" / "truth").mkdir(parents=True)
    (tmp_path / "ds" / "truth" / "truth.yaml").write_text("{}\n")
    assert P.main([str(tmp_path / "ds"), "--lab", str(tmp_path / "lab")]) == 2
    assert "camera.yaml: missing" in capsys.readouterr().err


def test_joint_bundle_counts_a_point_only_where_two_views_keep_it():
    from bench.vision.bundle import seen_twice

    point = np.array([0, 0, 1, 1, 1, 2])
    keep = np.array([True, False, True, True, False, True])
    assert seen_twice(point, keep, 3).tolist() == [False, False, True, True, False, False]


def test_relocate_passes_every_estimator_setting(tmp_path, monkeypatch):
    """relocate_sweep.locate_run localises with the scenario's estimator as the in_situ kind does: the joint bundle's
    settings and the single-view PnP variant reach locate_dataset."""
    sys.path.insert(0, str(ROOT / "tools"))
    import relocate_sweep as R

    import bench.vision.locate_dataset as L

    seen = {}
    monkeypatch.setattr(L, "locate_dataset", lambda *a, **kw: seen.update(kw) or (None, None))
    base = {"method": "svd", "ransac_iterations": 100, "d_r_mm": 20.0, "r_lim": 0.1}
    R.locate_run(tmp_path, 3, {**base, "refine": "none", "locate": "pnp"})
    assert seen["pnp"] and seen["refine"] == "none" and seen["seed"] == 3
    R.locate_run(tmp_path, 3, {**base, "refine": "joints", "map_points": "located", "loss": "huber",
                               "guided": True})
    assert not seen["pnp"] and seen["map_points"] == "located" and seen["loss"] == "huber" and seen["guided"]


def test_point_protection_radius_carries_the_base_covariance_to_the_point():
    """At the base origin it is protection_levels' position radius; at a point the base carries it is the quantile
    of |w x (p - t) + v| - checked against a Monte Carlo of base poses moved through the exact transform; a rotation
    error makes it grow with the lever arm; the floor and test 2's third add in quadrature; a covariance with NaN
    gives inf."""
    from bench.geometry.transforms import transform_points

    rng = np.random.default_rng(7)
    cov = _cov(rng, 1e-3, 4e-4)
    T = homogeneous(rotation_vector_to_matrix([0.1, -0.2, 0.3]), [0.4, -0.3, 0.2])
    tests = {"inflation_chi2": 1.2}
    pr, _ = I.protection_levels(cov, dict(tests), floor_mm=0.0, floor_deg=0.0)
    assert I.point_protection_radius(cov, tests, T, T[:3, 3], floor_mm=0.0) == pytest.approx(pr, rel=1e-12)
    p_site = T[:3, 3] + np.array([1.5, 0.6, -0.4])  # a tool tip 1.65 m from the base origin
    r = I.point_protection_radius(cov, {}, T, p_site, floor_mm=0.0)
    x_b = transform_points(np.linalg.inv(T), p_site)  # the tip in the base frame: moved with every drawn pose
    d = rng.multivariate_normal(np.zeros(6), cov, size=400_000)
    moved = np.array([transform_points(homogeneous(rotation_vector_to_matrix(w) @ T[:3, :3], T[:3, 3] + v), x_b)
                      for w, v in zip(d[:4000, :3], d[:4000, 3:], strict=True)])
    # first order: the second-order term is ~|w|^2 |p - t| ~ 3e-7 m here, against errors of ~1e-3 m
    assert np.allclose(moved - p_site, np.cross(d[:4000, :3], p_site - T[:3, 3]) + d[:4000, 3:], atol=2e-6)
    lin = np.linalg.norm(np.cross(d[:, :3], p_site - T[:3, 3]) + d[:, 3:], axis=1)
    assert r == pytest.approx(np.quantile(lin, 1 - I.INTEGRITY_RISK), rel=0.03)
    no_rot = cov.copy()
    no_rot[:3, :] = no_rot[:, :3] = 0.0  # the rotation's share at the lever arm is all the difference
    assert I.point_protection_radius(no_rot, {}, T, p_site, floor_mm=0.0) == pytest.approx(
        I.protection_levels(no_rot, {}, floor_mm=0.0, floor_deg=0.0)[0], rel=1e-12)
    assert r > 1.1 * I.point_protection_radius(no_rot, {}, T, p_site, floor_mm=0.0)
    assert I.point_protection_radius(cov, {"relative_pose_excess_mm": 3.0}, T, p_site, floor_mm=0.5) == pytest.approx(
        np.sqrt(r**2 + 0.5e-3**2 + 1e-3**2), rel=1e-9)
    assert I.point_protection_radius(np.full((6, 6), np.nan), {}, T, p_site) == float("inf")


def test_summary_carries_the_error_to_the_panel_centre():
    """tools/integrity_summary.py's lever-arm table: a base located with a pure rotation error about the panel
    centre errs there by nothing and at the base origin by the rotation times the lever arm; a pure translation errs
    alike at both; the covariance's largest standard deviation at the centre is exact for a rotation-only one."""
    sys.path.insert(0, str(ROOT / "tools"))
    import integrity_summary as S

    from bench.geometry.transforms import invert, transform_points

    T_ws = homogeneous(rotation_vector_to_matrix([0.0, 0.0, 0.2]), [0.3, -0.1, 0.0])
    T_wp = homogeneous(np.eye(3), [2.0, 0.5, 1.0])
    T_true = homogeneous(rotation_vector_to_matrix([0.0, 0.0, 0.1]), [0.2, 0.1, 0.0])  # locate base in the site
    truth = {"T_world_base_survey": T_ws.tolist(), "T_world_panel": T_wp.tolist()}
    c = transform_points(invert(T_ws), T_wp[:3, 3])
    w = np.array([0.0, 1e-3, 0.0])
    about_c = homogeneous(rotation_vector_to_matrix(w), c - rotation_vector_to_matrix(w) @ c)
    cov = np.diag([0.0, 1e-6, 0.0, 0.0, 0.0, 0.0])
    r = S._at_panel_centre(truth, about_c @ T_true, T_true, cov)
    assert r["err_centre_mm"] < 1e-9 and r["lever_m"] == pytest.approx(np.linalg.norm(c - T_true[:3, 3]), rel=1e-3)
    assert r["sigma_rot_deg"] == pytest.approx(np.rad2deg(1e-3)) and r["sigma_centre_mm"] > 0.5 * r["lever_m"]
    shift = homogeneous(np.eye(3), [1e-3, 0.0, 0.0])
    assert S._at_panel_centre(truth, shift @ T_true, T_true, cov)["err_centre_mm"] == pytest.approx(1.0, rel=1e-9)
