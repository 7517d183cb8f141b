"""tools/xy_table_vs_thesis.py: medians over a sweep's seeds, ratio to the thesis, the 2.5x test, the doc block."""

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from bench.errors import BenchError
from bench.scenario.sweep import SweepStore

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("xy_table_vs_thesis", ROOT / "tools" / "xy_table_vs_thesis.py")
tool = importlib.util.module_from_spec(spec)
spec.loader.exec_module(tool)

THESIS = {("lms_ratio", 40.0): (5.0, 4.6, 7.1), ("lms_ratio", 100.0): (4.2, 2.7, 1.5),
          ("quaternion", 20.0): (44.0, 25.4, 15.6), ("quaternion", 100.0): (9.7, 8.1, 2.1)}


def fake_sweep(folder: Path, errors: dict, scenario="xy_table_webcam", status="done", imaging=None) -> Path:
    """A sweep store with one run per seed; ``errors[seed][(method, d)] = (x, y, z)`` mm (None: failed cell)."""
    store = SweepStore(folder / "sweep.sqlite")
    for seed, cells in errors.items():
        keys = sorted(cells)
        table = {"method": [k[0] for k in keys], "d_mm": [k[1] for k in keys],
                 "thesis_table": [8 if k[0] == "lms_ratio" else 5 for k in keys]}
        for i, a in enumerate("xyz"):
            table[f"err_{a}_mm"] = [None if cells[k] is None else cells[k][i] for k in keys]
            table[f"thesis_err_{a}_mm"] = [THESIS[k][i] for k in keys]
        run_dir = folder / "runs" / f"r{seed}"
        run_dir.mkdir(parents=True)
        (run_dir / "result.json").write_text(json.dumps({"scenario": scenario, "seed": seed, "metrics": {},
                                                         "tables": {"position_error_vs_intraocular": table}}))
        im = imaging.get(seed) if isinstance(imaging, dict) else imaging
        params = {} if im is None else {"sim.imaging": im}
        store.add(f"r{seed}", params, seed, {"status": status, "message": "", "metrics": {}, "timings": {},
                                         "versions": {}, "result_path": str(run_dir / "result.json")})
    store.close()
    return folder


def test_medians_ratios_and_factor(tmp_path):
    rng = np.random.default_rng(5)
    real, ideal = {}, {}
    for seed in (1, 2, 3):
        real[seed] = {k: tuple(v * rng.uniform(0.9, 1.1) * (0.5 if k[0] == "lms_ratio" else 0.1) for v in th)
                      for k, th in THESIS.items()}
        ideal[seed] = {k: (0.1, 0.2, 0.3) for k in THESIS}
    real[3][("lms_ratio", 100.0)] = None  # a failed cell: the median is over the two other seeds
    r = tool.load_sweep(fake_sweep(tmp_path / "real", real))
    i = tool.load_sweep(fake_sweep(tmp_path / "ideal", ideal, imaging="ideal"))
    assert r["imaging"] == "realistic" and i["imaging"] == "ideal"
    with pytest.raises(BenchError, match="folders swapped"):
        tool.compare(i, r)
    rows = tool.compare(r, i, min_d_mm=40.0, factor=2.5)
    assert {(x["method"], x["d_mm"]) for x in rows} == {("lms_ratio", 40.0), ("lms_ratio", 100.0),
                                                         ("quaternion", 100.0)}  # d_o = 20 left out
    by = {(x["method"], x["d_mm"], x["axis"]): x for x in rows}
    row = by[("lms_ratio", 100.0, "z")]
    expect = np.median([real[s][("lms_ratio", 100.0)][2] for s in (1, 2)])
    assert row["realistic_mm"] == pytest.approx(expect) and row["seeds_realistic"] == 2
    assert row["ideal_mm"] == pytest.approx(0.3) and row["seeds_ideal"] == 3
    assert row["thesis_mm"] == 1.5 and row["ratio"] == pytest.approx(expect / 1.5) and row["table"] == 8
    assert all(x["within"] for x in rows if x["method"] == "lms_ratio")  # ratio ~0.5
    assert not any(x["within"] for x in rows if x["method"] == "quaternion")  # ratio ~0.1 < 1 / 2.5
    assert all(x["within"] for x in tool.compare(r, i, min_d_mm=40.0, factor=11.0))
    text = tool.markdown("webcam", rows, 2.5)
    assert "within 2.5x: 6 of 9 axis cells" in text and "| 5 quaternion | 100 |" in text
    assert "yes yes yes" in text and "**no** **no** **no**" in text


def test_too_large_ratio_fails(tmp_path):
    real = {1: {k: tuple(3.0 * v for v in th) for k, th in THESIS.items()}}
    r = tool.load_sweep(fake_sweep(tmp_path / "real", real))
    rows = tool.compare(r, {**r, "imaging": "ideal"}, factor=2.5)
    assert rows and not any(x["within"] for x in rows) and all(x["ratio"] == pytest.approx(3.0) for x in rows)


def test_bad_inputs_are_one_line_errors(tmp_path):
    with pytest.raises(BenchError, match="no sweep.sqlite"):
        tool.load_sweep(tmp_path)
    with pytest.raises(BenchError, match="no finished run"):
        tool.load_sweep(fake_sweep(tmp_path / "failed", {1: {("quaternion", 100.0): (1, 1, 1)}}, status="error"))
    a = tool.load_sweep(fake_sweep(tmp_path / "a", {1: {("quaternion", 100.0): (1, 1, 1)}}))
    b = tool.load_sweep(fake_sweep(tmp_path / "b", {1: {("quaternion", 100.0): (1, 1, 1)}}, "xy_table_underwater"))
    mixed = {1: {("quaternion", 100.0): (1, 1, 1)}, 2: {("quaternion", 100.0): (1, 1, 1)}}
    with pytest.raises(BenchError, match="different sim.imaging"):
        tool.load_sweep(fake_sweep(tmp_path / "mixed", mixed, imaging={1: "ideal", 2: None}))
    with pytest.raises(BenchError, match="not the same scenario"):
        tool.compare(a, b)
    with pytest.raises(BenchError, match="must be > 1"):
        tool.compare(a, {**a, "imaging": "ideal"}, factor=0.5)
    assert tool.main(["--setup", "w", str(tmp_path / "nowhere"), str(tmp_path / "a")]) == 2


def test_doc_block_replaced_between_markers_only(tmp_path):
    page = tmp_path / "page.md"
    page.write_text(f"head\n{tool.BEGIN}\nold\n{tool.END}\ntail\n")
    assert tool.write_doc(page, "new\n")
    assert page.read_text() == f"head\n{tool.BEGIN}\nnew\n{tool.END}\ntail\n"
    plain = tmp_path / "plain.md"
    plain.write_text("no markers\n")
    assert not tool.write_doc(plain, "new\n") and plain.read_text() == "no markers\n"


def test_keypoint_noise_wrapper_adds_seeded_gaussian_noise():
    from bench.vision.features import Features

    spec2 = importlib.util.spec_from_file_location("kn", ROOT / "tools" / "xy_table_keypoint_noise.py")
    kn = importlib.util.module_from_spec(spec2)
    spec2.loader.exec_module(kn)
    rng = np.random.default_rng(3)
    uv = rng.uniform(0, 640, (4000, 2))
    k = len(uv)
    clean = {"p01": Features(uv, np.zeros(k), np.full(k, 4.0), np.ones(k), np.zeros((k, 128), np.float32))}

    def original(truth, names, n_points, rng):
        return clean

    a = kn.noisy_features(original, 1.0, seed=7)(None, ["p01"], 0, None)["p01"]
    b = kn.noisy_features(original, 1.0, seed=7)(None, ["p01"], 0, None)["p01"]
    c = kn.noisy_features(original, 1.0, seed=8)(None, ["p01"], 0, None)["p01"]
    d = a.uv - uv
    assert np.array_equal(a.uv, b.uv) and not np.array_equal(a.uv, c.uv)
    assert np.std(d) == pytest.approx(1.0, rel=0.05) and abs(np.mean(d)) < 0.05
    assert np.array_equal(a.descriptors, clean["p01"].descriptors)
    assert np.array_equal(kn.noisy_features(original, 0.0, seed=7)(None, ["p01"], 0, None)["p01"].uv, uv)
    assert kn.main(["--sigmas", "-1"]) == 2
