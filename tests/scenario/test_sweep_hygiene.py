"""Issue 17.2: a sweep's workers end when its process dies, whatever the signal - SIGKILL of the parent alone (not
its process group) leaves no orphan running or hung on a pipe - and the sweep resumes to exactly the rows of an
uninterrupted run. Ctrl-C (SIGINT to the whole group, as a terminal sends it) stops the sweep promptly too."""

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bench.scenario.sweep import run_sweep

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "scenarios" / "tracker_base_frame.yaml"
TINY = {"monte_carlo.trials": 2, "arcs.spans_deg": [90], "noise.sigmas_mm": [0.05], "outputs.plots": False,
        "arcs.n_points": 6}
GRID = ("noise.default_sigma_mm", [0.02, 0.1])
SEEDS = 10  # 20 runs: seconds of work left after the first row, even on a fast idle machine (3 raced to the end)


def _cmd(out):
    return [sys.executable, "-m", "bench", "sweep", str(SCENARIO), "--param",
            f"{GRID[0]}={','.join(map(str, GRID[1]))}", "--seeds", str(SEEDS), "--workers", "2", "--out", str(out),
            *[a for k, v in TINY.items() for a in ("--set", f"{k}={json.dumps(v)}")]]


def _rows(db):
    con = sqlite3.connect(db)
    try:
        rows = con.execute("SELECT params, seed, status, metrics FROM runs").fetchall()
    except sqlite3.OperationalError:
        rows = []
    finally:
        con.close()
    return {(p, s): (st, {k: v for k, v in json.loads(m).items() if not k.endswith("_s")}) for p, s, st, m in rows}


def _group(pgid) -> list:
    """Live (not zombie) processes of the process group ``pgid``."""
    alive = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()  # state, ppid, pgrp, ...
        if int(fields[2]) == pgid and fields[0] != "Z":
            alive.append(int(d.name))
    return alive


def _launch_and_wait_for_rows(out, n_rows):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    # its own process group (pgid == proc.pid), and Ctrl-C's default action even when the suite itself runs with
    # SIGINT ignored (a background job of a non-interactive shell: the child would inherit SIG_IGN)
    proc = subprocess.Popen(_cmd(out), env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    db = out / "sweep.sqlite"
    t0 = time.time()
    while time.time() - t0 < 120:
        if proc.poll() is not None:
            pytest.fail(f"the sweep ended (code {proc.returncode}) before it could be interrupted")
        if db.exists() and len(_rows(db)) >= n_rows:
            return proc
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)
    pytest.fail("no row after 120 s")


def _assert_group_ends(pgid, within_s=10.0):
    t0 = time.time()
    while time.time() - t0 < within_s:
        if not _group(pgid):
            return time.time() - t0
        time.sleep(0.1)
    left = _group(pgid)
    for pid in left:  # do not leave them behind for the rest of the suite
        os.kill(pid, signal.SIGKILL)
    pytest.fail(f"{len(left)} process(es) of the sweep still alive {within_s} s after the parent died: {left}")


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("ref") / "sw"
    run_sweep(SCENARIO, [GRID], list(range(SEEDS)), out, workers=2, progress=False, fixed=TINY)
    rows = _rows(out / "sweep.sqlite")
    assert len(rows) == len(GRID[1]) * SEEDS and all(st == "done" for st, _ in rows.values())
    return rows


def test_sigkill_of_the_parent_alone_ends_the_workers_and_resume_is_exact(tmp_path, reference):
    out = tmp_path / "sw"
    proc = _launch_and_wait_for_rows(out, 1)
    assert len(_group(proc.pid)) >= 2  # the parent and its workers are running
    os.kill(proc.pid, signal.SIGKILL)  # the parent only, not the group
    assert proc.wait(timeout=10) == -signal.SIGKILL
    _assert_group_ends(proc.pid)
    interrupted = _rows(out / "sweep.sqlite")
    assert 0 < len(interrupted) < len(reference)
    done = subprocess.run(_cmd(out), env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    assert _rows(out / "sweep.sqlite") == reference


def test_ctrl_c_stops_the_sweep_and_its_workers(tmp_path, reference):
    out = tmp_path / "sw"
    proc = _launch_and_wait_for_rows(out, 1)
    os.killpg(proc.pid, signal.SIGINT)  # what a terminal's Ctrl-C does
    assert proc.wait(timeout=20) == 130  # bench: interrupted (not the whole grid run to the end)
    _assert_group_ends(proc.pid)
    rows = _rows(out / "sweep.sqlite")
    assert 0 < len(rows) < len(reference)  # stopped, not run to the end
    assert all(reference[k] == v for k, v in rows.items())  # and what it recorded is exact
