"""tools/table3_distance_fit.py: the rig distance fitted to Table 3's spread finds a known distance on sweeps built
with known power laws, χ is read there, and bad arguments are one-line errors."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from bench.scenario.sweep import SweepStore

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tools"))
import table3_distance_fit as F  # noqa: E402

THESIS = {"alpha_px": [977.7, 969.4, 984.0, 973.6, 972.3, 974.3, 975.7],
          "beta_px": [974.5, 969.7, 987.2, 971.2, 969.4, 978.7, 976.4],
          "u0_px": [327.3, 325.9, 330.0, 328.7, 331.6, 330.0, 331.4],
          "v0_px": [232.9, 233.0, 237.6, 238.0, 241.0, 235.0, 240.7]}


def _sweep(folder: Path, dist_mm: float, true_mm: float, rng, seeds=12):
    """A sweep whose seeds' spreads follow ``std = thesis std (dist / true)^2`` exactly (the seven values scaled
    about their mean) and χ = 0.4 (true / dist)^0.8; a random share of the seeds has twice the spread, so the
    median - not the mean - is what the tool must take."""
    folder.mkdir(parents=True)
    store = SweepStore(folder / "sweep.sqlite")
    for s in range(seeds):
        scale = (dist_mm / true_mm) ** 2 * (2.0 if s < seeds // 3 else 1.0)
        table = {}
        for k, v in THESIS.items():
            v = np.array(v)
            table[k] = (v.mean() + (v - v.mean()) * scale)[rng.permutation(7)].tolist() + [float(v.mean())]
            table[f"thesis_{k}"] = list(THESIS[k]) + [float(np.mean(THESIS[k]))]
        table["chi_px"] = [0.0] * 7 + [0.4 * (true_mm / dist_mm) ** 0.8]
        path = folder / f"r{s}.json"
        path.write_text(json.dumps({"tables": {"table3": table}}))
        store.add(f"r{s}", {}, s, {"status": "done", "message": "", "metrics": {}, "timings": {}, "versions": {},
                                   "result_path": str(path)})
    store.close()


def test_finds_the_distance_whose_spread_is_table_3s(tmp_path, capsys):
    rng = np.random.default_rng(7)
    args = []
    for d in (750.0, 900.0, 1000.0):
        _sweep(tmp_path / f"d{d:.0f}", d, 820.0, rng)
        args.append(f"{d:.0f}={tmp_path / f'd{d:.0f}'}")
    assert F.main([*args, "--bootstrap", "50"]) == 0
    out = capsys.readouterr().out
    fitted = float(out.split("fitted to alpha_px, beta_px: ")[1].split(" mm")[0])
    assert abs(fitted - 820.0) <= 0.5  # the grid's step is 0.3 mm
    chi = float(out.rsplit("chi there (power law through the medians) ", 1)[1].split()[0])
    assert chi == pytest.approx(0.4, abs=1e-3)
    data = {d: F.seed_rows([tmp_path / f"d{d:.0f}"])[0] for d in (750.0, 900.0, 1000.0)}
    thesis = F.seed_rows([tmp_path / "d750"])[1]
    assert thesis["alpha_px"] == pytest.approx(4.642, abs=1e-3)  # Table 3's own spread, ddof 1
    assert F.fit_distance(data, thesis, F.STATS) == pytest.approx(820.0, abs=0.5)


def test_bad_arguments_are_one_line_errors(tmp_path, capsys):
    _sweep(tmp_path / "d800", 800.0, 800.0, np.random.default_rng(1), seeds=3)
    (tmp_path / "other").mkdir()  # a sweep of another kind: results without Table 3
    (tmp_path / "other" / "r.json").write_text(json.dumps({"tables": {"views": {}}}))
    store = SweepStore(tmp_path / "other" / "sweep.sqlite")
    store.add("r", {}, 1, {"status": "done", "message": "", "metrics": {}, "timings": {}, "versions": {},
                           "result_path": str(tmp_path / "other" / "r.json")})
    store.close()
    for argv, msg in ((["x"], "x: expected DISTANCE_MM=SWEEP"), (["nan=x"], "positive number of mm"),
                      ([f"800={tmp_path / 'none'}"], "no finished run"),
                      ([f"800={tmp_path / 'd800'}"], "at least two distances"),
                      ([f"800={tmp_path / 'd800'}", "--stats", "gamma"], "--stats: unknown ['gamma']"),
                      ([f"800={tmp_path / 'd800'}", "--bootstrap", "0"], "at least 1 resample"),
                      ([f"800={tmp_path / 'd800'}", f"800={tmp_path / 'd800'}"], "800 mm given twice"),
                      ([f"800={tmp_path / 'other'}", f"900={tmp_path / 'd800'}"], "no Table 3 table")):
        with pytest.raises(SystemExit):
            F.main(argv)
        assert msg in capsys.readouterr().err
