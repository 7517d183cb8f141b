"""Issue 17.7: the cluster path. A Ray head is started as a user would (``ray start --head``, token authentication on,
as Ray 2.5x+ does by default), ``bench sweep --backend ray --address`` runs a small grid through it, and the rows
equal the local backend's; without the token the client is refused in one line and writes nothing. The head runs
in a session of its own and is always stopped - every process of that session, by id - even if the test fails."""

import json
import os
import secrets
import shutil
import signal
import socket
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from bench.scenario.sweep import run_sweep

pytest.importorskip("ray", reason="the cluster extra (pip install -e '.[cluster]') is not installed")

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "scenarios" / "tracker_base_frame.yaml"
TINY = {"monte_carlo.trials": 2, "arcs.spans_deg": [90], "noise.sigmas_mm": [0.05], "outputs.plots": False,
        "arcs.n_points": 6}
GRID = ("noise.default_sigma_mm", [0.02, 0.05])
SEEDS = [0, 1]
RAY = Path(sys.executable).with_name("ray")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _session(sid: int) -> list:
    """Live (not zombie) processes of the session ``sid``."""
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
            except OSError:
                continue
            fields = stat[stat.rindex(")") + 2:].split()  # state, ppid, pgrp, session, ...
            if int(fields[3]) == sid and fields[0] != "Z":
                out.append(int(d.name))
    return out


def _stop(proc) -> None:
    """SIGTERM the head's process group, then SIGKILL whatever of its session is left (by id), and reap it."""
    try:
        os.killpg(proc.pid, signal.SIGTERM)
    except ProcessLookupError:
        pass
    t0 = time.time()
    while _session(proc.pid) and time.time() - t0 < 3:
        time.sleep(0.2)
    for pid in _session(proc.pid):
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        pass
    t0 = time.time()
    while _session(proc.pid) and time.time() - t0 < 5:
        time.sleep(0.2)


@pytest.fixture(scope="module")
def ray_head():
    tmp = Path(tempfile.mkdtemp(prefix="bray", dir="/tmp"))  # short: Ray's socket paths live under it
    port, token = _free_port(), secrets.token_hex(16)
    env = {**os.environ, "HOME": str(tmp), "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": token,
           "PYTHONPATH": str(ROOT)}
    log = open(tmp / "head.log", "w")
    proc = subprocess.Popen([str(RAY), "start", "--head", "--block", "--port", str(port), "--node-ip-address",
                             "127.0.0.1", "--num-cpus", "2", "--include-dashboard", "false", "--temp-dir",
                             str(tmp / "r"), "--disable-usage-stats"], env=env, stdout=log, stderr=subprocess.STDOUT,
                            start_new_session=True)
    try:
        t0 = time.time()
        while "Ray runtime started" not in (tmp / "head.log").read_text():
            if proc.poll() is not None or time.time() - t0 > 60:
                pytest.fail("the Ray head did not start:\n" + (tmp / "head.log").read_text()[-2000:])
            time.sleep(0.2)
        yield {"address": f"127.0.0.1:{port}", "token": token, "home": tmp}
    finally:
        _stop(proc)
        log.close()
        left = _session(proc.pid)
        shutil.rmtree(tmp, ignore_errors=True)
        assert not left, f"Ray processes left running: {left}"


def _rows(db):
    con = sqlite3.connect(db)
    try:
        rows = con.execute("SELECT params, seed, status, metrics FROM runs").fetchall()
    finally:
        con.close()
    return {(p, s): (st, {k: v for k, v in json.loads(m).items() if not k.endswith("_s")}) for p, s, st, m in rows}


def _sweep_cmd(out, address):
    return [sys.executable, "-m", "bench", "sweep", str(SCENARIO),
            "--param", f"{GRID[0]}={','.join(map(str, GRID[1]))}", "--seeds", str(len(SEEDS)),
            "--backend", "ray", "--address", address, "--out", str(out),
            *[a for k, v in TINY.items() for a in ("--set", f"{k}={json.dumps(v)}")]]


def test_sweep_through_a_token_protected_head_equals_the_local_backend(tmp_path, ray_head):
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_")}
    env.update(HOME=str(ray_head["home"]), PYTHONPATH=str(ROOT), RAY_gcs_server_port_wait_time_s="3")
    # without the token: one line, exit 2, nothing written
    r = subprocess.run(_sweep_cmd(tmp_path / "refused", ray_head["address"]), env=env, capture_output=True, text=True,
                       timeout=120)
    last = r.stderr.strip().splitlines()[-1]
    assert r.returncode == 2 and last.startswith("bench: error: --address ") and "authentication token" in last, \
        r.stderr[-2000:]
    assert not (tmp_path / "refused").exists()
    # with it (RAY_AUTH_TOKEN, as the docs say)
    r = subprocess.run(_sweep_cmd(tmp_path / "ray", ray_head["address"]), env={**env, "RAY_AUTH_TOKEN":
                       ray_head["token"]}, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    local = tmp_path / "local"
    run_sweep(SCENARIO, [GRID], SEEDS, local, workers=2, progress=False, fixed=TINY)
    a, b = _rows(local / "sweep.sqlite"), _rows(tmp_path / "ray" / "sweep.sqlite")
    assert len(a) == len(GRID[1]) * len(SEEDS) and all(st == "done" and len(m) > 5 for st, m in a.values())
    assert a == b
