import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bench.errors import ConfigError
from bench.scenario.sweep import grid, parse_param, run_sweep

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "scenarios" / "tracker_base_frame.yaml"
SMALL = {"monte_carlo.trials": 3, "arcs.spans_deg": [90], "noise.sigmas_mm": [0.05], "outputs.plots": False}
SMALL_ARGS = [a for k, v in SMALL.items() for a in ("--set", f"{k}={json.dumps(v)}")]


def _rows(db):
    con = sqlite3.connect(db)
    try:
        return con.execute("SELECT run_id, params, seed, status, metrics, finished_at FROM runs").fetchall()
    except sqlite3.OperationalError:  # the sweep has created the file but not yet its table
        return []
    finally:
        con.close()


def test_parse_and_grid():
    assert parse_param("a.b=1,2,3") == ("a.b", [1, 2, 3])
    assert parse_param("m=[x, y]") == ("m", ["x", "y"])
    g = grid([("a", [1, 2]), ("b", ["u"])], [0, 1])
    assert g == [({"a": 1, "b": "u"}, 0), ({"a": 1, "b": "u"}, 1), ({"a": 2, "b": "u"}, 0), ({"a": 2, "b": "u"}, 1)]
    with pytest.raises(ConfigError, match="expected KEY=V1"):
        parse_param("nokey")


def test_unknown_key_fails_before_any_run(tmp_path):
    with pytest.raises(ConfigError, match="noise.sigma_typo: unknown key"):
        run_sweep(SCENARIO, [("noise.sigma_typo", [1.0])], [0], tmp_path / "sw", progress=False)
    assert not (tmp_path / "sw" / "runs").exists()


def test_sigkill_resume_keeps_every_finished_row_once(tmp_path):
    out = tmp_path / "sw"
    cmd = [sys.executable, "-m", "bench", "sweep", str(SCENARIO), "--param", "noise.default_sigma_mm=0.02,0.05,0.1",
           "--seeds", "2", "--workers", "2", "--out", str(out), *SMALL_ARGS]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    kills = 0
    for _ in range(3):  # kill as soon as a new row has landed, three times
        before = len(_rows(out / "sweep.sqlite")) if (out / "sweep.sqlite").exists() else 0
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                start_new_session=True)
        t0 = time.time()
        while proc.poll() is None and time.time() - t0 < 120:
            if (out / "sweep.sqlite").exists() and len(_rows(out / "sweep.sqlite")) > before:
                os.killpg(proc.pid, signal.SIGKILL)
                kills += 1
                break
            time.sleep(0.05)
        proc.wait()
    snapshot = {r[0]: r for r in _rows(out / "sweep.sqlite")}
    assert kills >= 1 and 0 < len(snapshot) < 6
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    rows = _rows(out / "sweep.sqlite")
    ids = [r[0] for r in rows]
    assert len(rows) == 6 and len(set(ids)) == 6 and all(r[3] == "done" for r in rows)
    for rid, row in snapshot.items():  # rows finished before the kills are untouched
        assert next(r for r in rows if r[0] == rid) == row
    assert (out / "summary.csv").is_file()


def test_ray_backend_gives_the_same_rows(tmp_path):
    pytest.importorskip("ray")
    params = [("noise.default_sigma_mm", [0.02, 0.05])]
    local = run_sweep(SCENARIO, params, [0, 1], tmp_path / "local", workers=2, progress=False, fixed=SMALL)
    ray = run_sweep(SCENARIO, params, [0, 1], tmp_path / "ray", backend="ray", progress=False, fixed=SMALL)
    assert local["rows"] == ray["rows"] == 4

    def accuracy(db):  # every metric but the timings (names ending in _s) must be identical
        return {(r[1], r[2]): {k: v for k, v in json.loads(r[4]).items() if not k.endswith("_s")} for r in _rows(db)}

    a, b = accuracy(tmp_path / "local" / "sweep.sqlite"), accuracy(tmp_path / "ray" / "sweep.sqlite")
    assert a == b and all(len(m) > 5 for m in a.values())
