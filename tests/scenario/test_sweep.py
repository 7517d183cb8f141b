import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
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


def _check_store(db):
    """The store after a kill: intact (SQLite integrity), one row per run id, every row finished and complete."""
    con = sqlite3.connect(db)
    try:
        assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        assert con.execute("SELECT COUNT(*) = COUNT(DISTINCT run_id) FROM runs").fetchone()[0] == 1
    except sqlite3.OperationalError:  # killed before the table was created
        return {}
    finally:
        con.close()
    rows = {r[0]: r for r in _rows(db)}
    for r in rows.values():
        assert r[3] == "done" and len(json.loads(r[4])) > 5, r  # the row (with its message) if not
    return rows


def test_sigkill_resume_keeps_every_finished_row_once(tmp_path):
    """Issue 6: a sweep killed with SIGKILL at random moments (>= 10 times) resumes with every finished row intact
    and none duplicated. Every third launch is killed after a drawn delay (interpreter start, store creation, the
    first rows); the others right after a row appeared (a commit just finished while the other worker is mid-run),
    so the kills land mid-sweep however fast the machine (at least five with some rows done and some not). Finally
    a launch over the finished grid (only the summary left to write) is killed too."""
    out = tmp_path / "sw"
    db = out / "sweep.sqlite"
    tiny = {**SMALL, "monte_carlo.trials": 2, "arcs.n_points": 6}
    cmd = [sys.executable, "-m", "bench", "sweep", str(SCENARIO), "--param",
           "noise.default_sigma_mm=0.02,0.05,0.1,0.2", "--seeds", "6", "--workers", "2", "--out", str(out),
           *[a for k, v in tiny.items() for a in ("--set", f"{k}={json.dumps(v)}")]]
    total = 4 * 6
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    rng = np.random.default_rng(20261122)

    def launch(delay=None):
        """Run the sweep until `delay` seconds passed (or, without one, until a new row appeared); SIGKILL it then.
        Returns whether it was killed and the store checked afterwards."""
        before = len(_rows(db)) if db.exists() else 0
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                start_new_session=True)
        t0 = time.time()
        while proc.poll() is None:
            grown = delay is None and db.exists() and len(_rows(db)) > before
            if grown or (delay is not None and time.time() - t0 >= delay) or time.time() - t0 > 60:
                os.killpg(proc.pid, signal.SIGKILL)
                break
            time.sleep(0.01)
        killed = proc.wait() == -signal.SIGKILL
        return killed, (_check_store(db) if db.exists() else {})

    seen, kills, mid_sweep, launches = {}, 0, 0, 0
    while (kills < 10 or mid_sweep < 5) and launches < 40:
        launches += 1
        killed, rows = launch(rng.uniform(0.2, 1.5) if launches % 3 == 1 else None)
        kills += killed
        mid_sweep += killed and 0 < len(rows) < total
        for rid, row in seen.items():  # every row finished before this kill is untouched
            assert rows.get(rid) == row
        seen = rows
    assert kills >= 10 and mid_sweep >= 5, f"{kills} kills ({mid_sweep} mid-sweep) in {launches} launches"
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    rows = _check_store(db)
    assert len(rows) == total and len(_rows(db)) == total
    for rid, row in seen.items():
        assert rows[rid] == row
    (out / "summary.csv").unlink()
    killed, after = launch(rng.uniform(0.5, 1.5))  # the finished grid: only the summary is written
    assert after == rows
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert _check_store(db) == rows
    for r in rows.values():  # each row's result file is complete
        con = sqlite3.connect(db)
        path = con.execute("SELECT result_path FROM runs WHERE run_id = ?", (r[0],)).fetchone()[0]
        con.close()
        assert json.loads(Path(path).read_text())["metrics"] == json.loads(r[4])
    assert (out / "summary.csv").is_file()


def test_ray_backend_gives_the_same_rows(tmp_path):
    pytest.importorskip("ray")
    params = [("noise.default_sigma_mm", [0.02, 0.05])]
    local = run_sweep(SCENARIO, params, [1], tmp_path / "local", workers=2, progress=False, fixed=SMALL)
    ray = run_sweep(SCENARIO, params, [1], tmp_path / "ray", backend="ray", progress=False, fixed=SMALL)
    assert local["rows"] == ray["rows"] == 2

    def accuracy(db):  # every metric but the timings (names ending in _s) must be identical
        return {(r[1], r[2]): {k: v for k, v in json.loads(r[4]).items() if not k.endswith("_s")} for r in _rows(db)}

    a, b = accuracy(tmp_path / "local" / "sweep.sqlite"), accuracy(tmp_path / "ray" / "sweep.sqlite")
    assert a == b and all(len(m) > 5 for m in a.values())


def test_summary_efficiency_bound_on_plots_and_recording(tmp_path):
    """summarise: RMS-based efficiency of every (x_err_y, x_bound_y) pair, and sweep.rrd holds the medians over the
    swept key (read back with rerun's reader)."""
    from bench.scenario.recording import load_entities
    from bench.scenario.sweep import summarise

    rows = []
    for d in (20, 50):
        for err, bound in ((3.0, 1.0), (4.0, 2.0), (5.0, 1.0)):
            rows.append({"params": {"d_mm": d}, "metrics": {"pos_err_mm": err * 20 / d, "pos_bound_mm": bound}})
    res = summarise(rows, ["d_mm"], tmp_path)
    t = res["table"]
    assert t["d_mm"] == [20, 50] and t["pos_err_mm_median"] == [4.0, 1.6]
    assert t["pos_err_mm_efficiency"][0] == pytest.approx(np.sqrt(2.0) / np.sqrt(50 / 3))
    e = load_entities(res["recording"])
    assert [v[0] for v in e["/metrics/pos_err_mm"]["Scalars:scalars"]] == pytest.approx([4.0, 1.6])
    assert [v[0] for v in e["/metrics/pos_bound_mm"]["Scalars:scalars"]] == pytest.approx([1.0, 1.0])
    assert (tmp_path / "sweep_pos_err_mm.png").is_file()


def test_rows_name_the_code_and_a_resume_over_other_code_says_so(tmp_path, capsys):
    """Every row's versions name the code (`git describe --dirty` of the checkout bench runs from), so a figure can
    be traced to the commit that made it; resuming a sweep whose finished runs another version of the code made
    keeps them but prints one warning naming how many and which version."""
    import shutil

    from bench.scenario.sweep import code_version

    git = shutil.which("git")
    expected = subprocess.run([git, "-C", str(ROOT), "rev-parse", "--short=12", "HEAD"], capture_output=True,
                              text=True).stdout.strip() if git else ""
    now = code_version()
    if expected:
        assert now.startswith(expected) or expected in now, now
    out = tmp_path / "sw"
    run_sweep(SCENARIO, [], [0], out, workers=1, progress=False, fixed=SMALL)
    con = sqlite3.connect(out / "sweep.sqlite")
    (text,) = con.execute("SELECT versions FROM runs").fetchone()
    assert json.loads(text)["bench"] == now
    capsys.readouterr()
    run_sweep(SCENARIO, [], [0, 1], out, workers=1, progress=False, fixed=SMALL)  # same code: no warning
    assert "other code" not in capsys.readouterr().err
    con.execute("UPDATE runs SET versions = ? WHERE seed = 0", (json.dumps({"bench": "0123456789ab"}),))
    con.commit()
    con.close()
    run_sweep(SCENARIO, [], [0, 1, 2], out, workers=1, progress=False, fixed=SMALL)
    err = capsys.readouterr().err
    assert "1 by 0123456789ab" in err and now in err and len(err.strip().splitlines()) == 1
    con = sqlite3.connect(out / "sweep.sqlite")
    assert con.execute("SELECT COUNT(*) FROM runs WHERE status = 'done'").fetchone()[0] == 3  # kept, not re-run
    con.close()


def test_read_runs_reads_a_sweep_without_its_writer(tmp_path):
    """The tools' read-only view of a sweep: the finished runs (or all), as the store's own rows (with their result
    files); nothing for a folder without a database."""
    from bench.scenario.sweep import SweepStore, read_runs

    store = SweepStore(tmp_path / "sweep.sqlite")
    for rid, status in (("b", "done"), ("a", "failed"), ("c", "done")):
        store.add(rid, {"x": 1}, 3, {"status": status, "message": "", "metrics": {"m": 1.0}, "timings": {"total_s": 2},
                                     "versions": {}, "result_path": f"runs/{rid}/result.json"})
    rows = store.rows()
    store.close()
    assert [r["run_id"] for r in read_runs(tmp_path)] == ["b", "c"]
    assert read_runs(tmp_path, finished_only=False) == rows
    assert read_runs(tmp_path)[0]["result_path"] == "runs/b/result.json" and read_runs(tmp_path / "none") == []


def test_a_resume_with_other_settings_is_refused(tmp_path):
    """A sweep folder's summary pools all its runs by the swept keys: resuming it with other --set overrides, without
    a key it swept, sweeping a key its runs lack, or after the scenario file changed would pool runs of two settings.
    Each is refused in one line naming it, before anything runs; more seeds and more values extend the sweep;
    --force starts it afresh."""
    from bench.fileio import OutputRefused
    from bench.scenario.sweep import SweepStore, check_resume, run_id

    text = SCENARIO.read_text()
    out = tmp_path / "sw"
    store = SweepStore(out / "sweep.sqlite")
    for sigma in ([0.05], [0.1]):
        params = {**SMALL, "noise.sigmas_mm": sigma}
        store.add(run_id(text, params, 0), params, 0, {"status": "done", "message": "", "metrics": {}, "timings": {},
                                                      "versions": {}, "result_path": ""})
    store.close()
    fixed = {k: v for k, v in SMALL.items() if k != "noise.sigmas_mm"}
    check_resume(out, text, fixed, {"noise.sigmas_mm"})  # the same grid: more seeds or values extend it
    with pytest.raises(OutputRefused, match=r'--set overrides: monte_carlo.trials=3 \(this call: 4\); --force'):
        check_resume(out, text, {**fixed, "monte_carlo.trials": 4}, {"noise.sigmas_mm"})
    with pytest.raises(OutputRefused, match=r"noise.sigmas_mm=\[0.(05|1)\] \(this call: \(not set\)\)"):
        check_resume(out, text, fixed, set())  # the swept key no longer swept (nor set)
    with pytest.raises(OutputRefused, match="did not sweep arcs.n_points"):
        check_resume(out, text, fixed, {"noise.sigmas_mm", "arcs.n_points"})
    with pytest.raises(OutputRefused, match="2 of its 2 runs were made from another text of the scenario file"):
        check_resume(out, text + "\n# edited\n", fixed, {"noise.sigmas_mm"})
    with pytest.raises(OutputRefused, match="its sweep ran with other --set overrides"):  # refused before any run
        run_sweep(SCENARIO, [("noise.sigmas_mm", [[0.05]])], [0], out, workers=1, progress=False,
                  fixed={**fixed, "monte_carlo.trials": 4})
    assert len(_rows(out / "sweep.sqlite")) == 2


def test_render_cache_flag_links_a_shared_cache_and_refuses_a_file(tmp_path):
    """``bench sweep --render-cache DIR``: the sweep's runs take their renders from DIR (its ``runs/.render_cache``
    a link to it); a file there is a one-line error before anything is written."""
    from bench.cli import main

    shared = tmp_path / "shared_cache"
    assert main(["sweep", str(SCENARIO), "--seeds", "1", "--out", str(tmp_path / "sw"), "--render-cache",
                 str(shared), *SMALL_ARGS]) == 0
    link = tmp_path / "sw" / "runs" / ".render_cache"
    assert link.is_symlink() and link.resolve() == shared.resolve() and shared.is_dir()
    (tmp_path / "a_file").write_text("x")
    with pytest.raises(ConfigError, match="--render-cache.*not a folder"):
        run_sweep(SCENARIO, [], [0], tmp_path / "sw2", progress=False, render_cache=tmp_path / "a_file")
    assert not (tmp_path / "sw2").exists()
