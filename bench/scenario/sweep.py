"""``bench sweep``: a grid of scenario runs (keys x values x seeds), resumable, one SQLite row per finished run.

* Each run is ``bench run`` of the scenario with ``--set key=value`` overrides and a seed, in its own folder
  ``DIR/runs/<run_id>/``; ``run_id`` is a hash of the scenario file's content, the overrides and the seed, so a
  finished run is recognised whatever the order of the grid.
* Rows go into ``DIR/sweep.sqlite`` (table ``runs``: ``run_id`` primary key, parameters, seed, metrics, timings,
  versions, status) in one transaction per finished run, written by the parent process only. SQLite's atomic commit
  means a sweep killed at any moment - SIGKILL included - loses at most the runs in flight and never leaves a
  partial or duplicate row; the next ``bench sweep`` with the same arguments skips the finished run ids.
* Backends: ``local`` (a process pool, default ``os.cpu_count()`` workers) and ``ray`` (the same work function as
  Ray tasks, on a local instance or ``--address`` of a cluster; needs the ``cluster`` extra).
* Every grid point is validated before any run starts: the kind's model (unknown keys, types, ranges, choices) and,
  for kinds whose module offers ``validate(cfg)``, the checks that need the robot, optics or files (too few poses) -
  a bad value in the grid is a one-line error and nothing is run or written.
* At the end: a summary table (median and spread per grid point and metric) as CSV and a plot per metric against
  the first swept key.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import itertools
import json
import os
import platform
import signal
import sqlite3
import sys
import threading
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path

import numpy as np
import yaml

from bench.errors import BenchError, ConfigError
from bench.fileio import atomic_save_figure, headless_pyplot, read_only_sqlite

_SCHEMA = """
CREATE TABLE IF NOT EXISTS runs (
    run_id TEXT PRIMARY KEY,
    params TEXT NOT NULL,
    seed INTEGER NOT NULL,
    status TEXT NOT NULL,
    message TEXT,
    metrics TEXT,
    timings TEXT,
    versions TEXT,
    result_path TEXT,
    finished_at REAL
)
"""


def parse_param(spec: str, source: str = "--param") -> tuple:
    """``"key=v1,v2,..."`` -> ``(key, [values parsed as YAML])``; a YAML list after ``=`` is accepted too."""
    if "=" not in spec:
        raise ConfigError(source, spec, "expected KEY=V1,V2,...")
    key, raw = spec.split("=", 1)
    key = key.strip()
    if not key:
        raise ConfigError(source, spec, "empty key")
    if not raw.strip() or any(not item.strip() for item in raw.split(",")) and not raw.strip().startswith("["):
        raise ConfigError(source, key, f"an empty value in {raw!r} (expected V1,V2,...)")
    try:
        parsed = yaml.safe_load(raw)
    except yaml.YAMLError:
        parsed = None
    if isinstance(parsed, list):
        values = parsed
    else:
        values = []
        for item in raw.split(","):
            try:
                values.append(yaml.safe_load(item))
            except yaml.YAMLError:
                raise ConfigError(source, key, f"value {item!r} is not valid YAML") from None
    if not values:
        raise ConfigError(source, key, "no values")
    return key, values


def grid(params: list, seeds: list) -> list:
    """Every combination as ``(overrides dict, seed)``, params varying slowest-first as given."""
    keys = [k for k, _ in params]
    return [(dict(zip(keys, combo, strict=True)), int(seed)) for combo in itertools.product(*[v for _, v in params])
            for seed in seeds]


def run_id(scenario_text: str, overrides: dict, seed: int) -> str:
    text = scenario_text + json.dumps(overrides, sort_keys=True, default=str) + str(seed)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@functools.lru_cache(maxsize=1)
def code_version() -> str:
    """The code a run used: ``git describe --always --dirty`` of the checkout ``bench`` is imported from (a commit;
    with uncommitted changes ``-dirty-`` and a hash of them: ``git diff HEAD`` and the untracked files under
    ``bench/`` and ``models/``, so two different edits of one commit are told apart), or ``bench <version>`` outside
    a git checkout. Read once per process: its modules, once imported, are the code it runs whatever is edited
    later."""
    import subprocess

    import bench

    root = Path(bench.__file__).resolve().parents[1]
    # GIT_OPTIONAL_LOCKS=0: --dirty refreshes the index without writing it, so concurrent workers never meet each
    # other's index.lock
    env = {**os.environ, "GIT_OPTIONAL_LOCKS": "0"}

    def git(*args, text=True):
        try:
            out = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=text, timeout=20, env=env)
        except (OSError, subprocess.TimeoutExpired):
            return None
        return out.stdout if out.returncode == 0 else None

    described = (git("describe", "--always", "--dirty", "--abbrev=12") or "").strip()
    if not described:
        return f"bench {bench.__version__}"
    if described.endswith("-dirty"):
        h = hashlib.sha256(git("diff", "HEAD", "--binary", text=False) or b"")
        for name in sorted((git("ls-files", "--others", "--exclude-standard", "--", "bench", "models") or "").split()):
            path = root / name
            h.update(name.encode() + (path.read_bytes() if path.is_file() else b""))
        described += "-" + h.hexdigest()[:8]
    return described


def versions() -> dict:
    """Versions of the interpreter, the libraries a result depends on, and the code (``bench``, see
    :func:`code_version`)."""
    out = {"python": platform.python_version(), "bench": code_version()}
    for mod in ("numpy", "scipy", "cv2", "mujoco", "pinocchio"):
        try:
            out[mod] = __import__(mod).__version__
        except Exception:  # noqa: BLE001 - a missing optional library is recorded as absent
            out[mod] = None
    return out


def run_one(scenario: str, overrides: dict, seed: int, out_dir: str) -> dict:
    """Run one grid point (in a worker process or a Ray task); returns the row's content."""
    from bench.scenario.runner import run_scenario_file

    t0 = time.perf_counter()
    sets = [f"{k}={json.dumps(v)}" for k, v in overrides.items()]
    try:
        path = run_scenario_file(scenario, out=out_dir, seed=seed, overrides=sets, verbose=False, quiet=True)
        doc = json.loads(Path(path).read_text())
        return {"status": "done", "message": "", "metrics": doc.get("metrics", {}),
                "timings": {**doc.get("timings_s", {}), "wall_s": time.perf_counter() - t0},
                "result_path": str(path), "versions": versions()}
    except BenchError as exc:
        return {"status": "error", "message": str(exc), "metrics": {}, "timings": {"wall_s": time.perf_counter() - t0},
                "result_path": None, "versions": versions()}


class SweepStore:
    """The SQLite file of a sweep; every write is one committed transaction."""

    def __init__(self, path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.db = sqlite3.connect(self.path, timeout=30)
        self.db.execute("PRAGMA journal_mode=WAL")
        self.db.execute("PRAGMA synchronous=FULL")
        self.db.execute(_SCHEMA)
        self.db.commit()

    def finished(self) -> set:
        return {r[0] for r in self.db.execute("SELECT run_id FROM runs WHERE status = 'done'")}

    def code_versions(self) -> dict:
        """``{code version: finished runs}`` (rows written before versions named the code count as ``unknown``)."""
        counts = {}
        for (text,) in self.db.execute("SELECT versions FROM runs WHERE status = 'done'"):
            try:
                code = (json.loads(text or "{}") or {}).get("bench") or "unknown"
            except (json.JSONDecodeError, AttributeError):
                code = "unknown"
            counts[code] = counts.get(code, 0) + 1
        return counts

    def add(self, rid: str, overrides: dict, seed: int, row: dict) -> None:
        with self.db:
            self.db.execute(
                "INSERT OR REPLACE INTO runs VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (rid, json.dumps(overrides, sort_keys=True), seed, row["status"], row["message"],
                 json.dumps(row["metrics"]), json.dumps(row["timings"]), json.dumps(row["versions"]),
                 row["result_path"], time.time()))

    def rows(self) -> list:
        return _row_dicts(self.db, "")

    def close(self) -> None:
        self.db.close()


def _row_dicts(db, where: str) -> list:
    cur = db.execute("SELECT run_id, params, seed, status, message, metrics, timings, result_path FROM runs "
                     f"{where} ORDER BY run_id")
    return [{"run_id": r[0], "params": json.loads(r[1]), "seed": r[2], "status": r[3], "message": r[4],
             "metrics": json.loads(r[5] or "{}"), "timings": json.loads(r[6] or "{}"), "result_path": r[7]}
            for r in cur]


def read_runs(folder, finished_only: bool = True) -> list:
    """The runs of the sweep in ``folder`` as :meth:`SweepStore.rows` gives them, from its database opened read-only
    (tools that read a sweep must not change its rows); [] when the folder holds no ``sweep.sqlite``.
    ``finished_only``: only the runs whose status is ``done``."""
    path = Path(folder) / "sweep.sqlite"
    if not path.is_file():
        return []
    db = read_only_sqlite(path)
    try:
        return _row_dicts(db, "WHERE status = 'done'" if finished_only else "")
    finally:
        db.close()


class _Progress:
    def __init__(self, total: int, done: int, stream=None):
        self.total, self.done, self.t0, self.new = total, done, time.perf_counter(), 0
        self.stream = sys.stderr if stream is None else stream  # the current stderr, not the one at import

    def step(self, ok: bool = True) -> None:
        self.done += 1
        self.new += 1
        frac = self.done / max(self.total, 1)
        rate = (time.perf_counter() - self.t0) / self.new
        eta = rate * (self.total - self.done)
        bar = "#" * int(30 * frac) + "." * (30 - int(30 * frac))
        self.stream.write(f"\r[{bar}] {self.done}/{self.total} runs, eta {eta:5.0f} s{'' if ok else ' (error)'}")
        self.stream.flush()
        if self.done == self.total:
            self.stream.write("\n")


PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def _end_with_parent(parent_pid: int, period_s: float = 1.0) -> None:
    """Worker initializer: this worker ends when the sweep's process dies, whatever the signal (SIGKILL included).

    Linux: ``prctl(PR_SET_PDEATHSIG, SIGKILL)`` has the kernel kill the worker when its parent goes; everywhere, a
    watchdog thread checks ``os.getppid()`` every ``period_s`` (an orphan is re-parented). Ctrl-C is left to the
    parent (SIGINT ignored here), which stops the workers itself: a run in flight is then lost, not half-recorded,
    and the next sweep re-runs it.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):  # no prctl: the watchdog alone
            pass
    if os.getppid() != parent_pid:  # the parent died before the prctl took effect
        os._exit(1)

    def watch():
        while os.getppid() == parent_pid:
            time.sleep(period_s)
        os.kill(os.getpid(), signal.SIGKILL)

    threading.Thread(target=watch, name="bench-sweep-parent-watchdog", daemon=True).start()


def _local_backend(tasks, workers):
    """Yield ``(task, row)`` as runs finish in a pool of ``workers`` processes. If the consumer stops early (an
    exception, Ctrl-C), the workers are terminated and the queued runs dropped instead of being run to the end."""
    pool = ProcessPoolExecutor(max_workers=workers, initializer=_end_with_parent, initargs=(os.getpid(),))
    pending = {}
    try:
        pending = {pool.submit(run_one, *t[1:]): t for t in tasks}
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                yield pending.pop(fut), fut.result()
    finally:
        stop_pool(pool, bool(pending))


def stop_pool(pool: ProcessPoolExecutor, unfinished: bool) -> None:
    """Shut a worker pool down; with ``unfinished`` work (an exception, Ctrl-C) its running tasks are terminated and
    the queued ones dropped instead of being run to the end."""
    if unfinished:
        for proc in list((getattr(pool, "_processes", None) or {}).values()):  # running tasks: stop them
            proc.terminate()
        pool.shutdown(wait=True, cancel_futures=True)
    else:
        pool.shutdown(wait=True)


RAY_HELP = "see docs/sweeps.md, 'Running on a Ray cluster'"


def _ray_connect(address) -> bool:
    """Connect to the Ray cluster at ``address`` (``None``: start a private local instance); returns whether this
    call started the connection (and so must end it). One-line :class:`BenchError` if Ray is missing or the cluster
    cannot be reached or refuses the connection.

    Token authentication (Ray >= 2.5x enables it on clusters by default): Ray itself uses a token for an explicit
    address only when ``RAY_AUTH_MODE=token``; a token given explicitly - ``RAY_AUTH_TOKEN`` or
    ``RAY_AUTH_TOKEN_PATH`` set - is taken as that intent here. A token in the default file ``~/.ray/auth_token``
    alone is not sent to an address the user typed (as in Ray).
    """
    token_given = bool(address and "RAY_AUTH_MODE" not in os.environ
                       and (os.environ.get("RAY_AUTH_TOKEN") or os.environ.get("RAY_AUTH_TOKEN_PATH")))
    imported = "ray" in sys.modules
    if token_given:
        os.environ["RAY_AUTH_MODE"] = "token"  # read by Ray when it is imported ...
    try:
        import ray
    except ImportError:
        raise BenchError("--backend ray needs Ray: pip install -e '.[cluster]'") from None
    if ray.is_initialized():
        return False
    if token_given and imported:  # ... so refresh its configuration if it was imported before (as Ray itself does)
        try:
            from ray._raylet import Config

            Config.initialize("")
        except (ImportError, AttributeError):
            pass
    try:
        ray.init(address=address, include_dashboard=False, log_to_driver=False, ignore_reinit_error=True)
    except Exception as exc:  # noqa: BLE001 - Ray raises ConnectionError, RuntimeError, AuthenticationError, ...
        if address is None:
            raise
        reason = " ".join(str(exc).split(".")[0].split()) or type(exc).__name__
        cause = exc.__cause__ or exc.__context__
        if cause is not None and "uthenticat" in str(cause) + reason:
            reason = "authentication token missing or wrong"
        if "uthenticat" in reason:
            reason += ("; set RAY_AUTH_TOKEN (or RAY_AUTH_TOKEN_PATH) to the cluster's token, or RAY_AUTH_MODE=token "
                       "to use ~/.ray/auth_token")
        raise BenchError(f"--address {address}: cannot connect to the Ray cluster ({reason}); {RAY_HELP}") from None
    return True


def _ray_backend(tasks, started: bool):
    """Yield ``(task, row)`` as Ray tasks finish (Ray connected by :func:`_ray_connect`; disconnected at the end if
    ``started``, also when the consumer stops early - the cluster cancels the tasks of a driver that leaves)."""
    import ray

    try:
        remote = ray.remote(run_one)
        refs = {remote.remote(*t[1:]): t for t in tasks}
        while refs:
            ready, _ = ray.wait(list(refs), num_returns=1)
            for ref in ready:
                yield refs.pop(ref), ray.get(ref)
    finally:
        if started:
            ray.shutdown()


def check_seeds_and_workers(seeds: list, workers, backend: str = "local", address=None) -> None:
    """Refuse, before anything is created, seeds that are not non-negative integers, a worker count below 1
    (``None`` = one worker per core) and options of the other backend; the messages name the command-line options."""
    if backend == "local" and address:
        raise BenchError(f"--address {address}: a Ray cluster's address; add --backend ray (or drop --address)")
    if backend == "ray" and workers is not None:
        raise BenchError("--workers: the local backend's process count; Ray runs on the cluster's CPUs")
    if not len(seeds):
        raise BenchError("--seeds: must be >= 1, got no seeds")
    for s in seeds:
        if isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 0:
            raise BenchError(f"--seed: expected a non-negative integer (the first seed), got {s!r}")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, (int, np.integer))
                                or workers < 1):
        raise BenchError(f"--workers: must be >= 1 (omit it for one per core), got {workers!r}")


def check_resume(out: Path, scenario_text: str, fixed: dict, swept: set) -> None:
    """Refuse to resume the sweep in ``out`` with other settings, whose runs its summary would pool with the new ones:
    a finished or failed run made with other fixed overrides (``--set``), without one of the keys now swept, or from
    another text of the scenario file (its run id, which hashes the text, no longer matches). More seeds and more
    values of the swept keys extend the sweep. One line (:class:`~bench.fileio.OutputRefused`); ``--force`` starts
    the sweep afresh."""
    from bench.fileio import OutputRefused

    rows = read_runs(out, finished_only=False)
    for r in rows:
        given = {k: v for k, v in r["params"].items() if k not in swept}
        if given != fixed:
            diff = ", ".join(f"{k}={json.dumps(given[k]) if k in given else '(not set)'} (this call: "
                             f"{json.dumps(fixed[k]) if k in fixed else '(not set)'})"
                             for k in sorted(set(given) | set(fixed)) if given.get(k) != fixed.get(k))
            raise OutputRefused(f"--out {out}: its sweep ran with other --set overrides: {diff}; --force starts it "
                                "afresh, or choose another folder")
        missing = sorted(swept - set(r["params"]))
        if missing:
            raise OutputRefused(f"--out {out}: its sweep did not sweep {missing[0]} (its runs have no value of it); "
                                "--force starts it afresh, or choose another folder")
    changed = [r for r in rows if run_id(scenario_text, r["params"], r["seed"]) != r["run_id"]]
    if changed:
        raise OutputRefused(f"--out {out}: {len(changed)} of its {len(rows)} runs were made from another text of the "
                            "scenario file (it changed since); --force starts the sweep afresh, or choose another "
                            "folder")


def _link_render_cache(link: Path, shared: Path) -> None:
    """``link`` (a sweep's render cache) made a link to the ``shared`` folder, unless it exists already (a cache the
    sweep filled itself is kept)."""
    if link.exists() or link.is_symlink():
        return
    shared.mkdir(parents=True, exist_ok=True)
    link.parent.mkdir(parents=True, exist_ok=True)
    link.symlink_to(shared.resolve(), target_is_directory=True)


def run_sweep(scenario, params: list, seeds: list, out, backend: str = "local", address=None, workers=None,
              progress: bool = True, fixed: dict | None = None, force: bool = False, render_cache=None) -> dict:
    """Run (or resume) a sweep; returns ``{"store": path, "summary": path, "plots": [...], "rows": n}``.

    ``params`` is a list of ``(key, values)`` (the grid); ``fixed`` overrides every run (``--set``);
    ``render_cache``, a folder that other sweeps share, becomes the runs' render cache (``out/runs/.render_cache``
    links to it, unless the sweep already has a cache of its own). Everything is
    checked before ``out`` is touched; ``out`` is then claimed (:func:`bench.fileio.claim_output_dir`, command
    ``sweep``, identity the scenario file's name): a new or empty folder, or a previous sweep of the same scenario
    (resumed); ``force`` starts a previous sweep of the same scenario afresh (or replaces one of another scenario).
    """
    fixed = dict(fixed or {})
    clash = set(fixed) & {k for k, _ in params}
    if clash:
        raise ConfigError("--set", sorted(clash)[0], "is also swept with --param")
    scenario = Path(scenario)
    if not scenario.is_file():
        raise ConfigError(scenario, "<file>", "not found")
    if backend not in ("local", "ray"):
        raise ConfigError("--backend", backend, "expected 'local' or 'ray'")
    check_seeds_and_workers(seeds, workers, backend, address)
    if render_cache is not None and Path(render_cache).exists() and not Path(render_cache).is_dir():
        raise ConfigError("--render-cache", str(render_cache), "is not a folder")
    from bench.fileio import check_output_dir, claim_output_dir, foreign_entries, record_output_entries
    from bench.scenario.runner import load_scenario

    for overrides, seed in grid(params, seeds[:1]):  # validate every value before launching anything
        load_scenario(scenario, seed, [f"{k}={json.dumps(v)}" for k, v in {**fixed, **overrides}.items()])
    out = Path(out)
    check_output_dir(out, "sweep", force=force, identity=scenario.name)
    text = scenario.read_text()
    if not force:
        check_resume(out, text, fixed, {k for k, _ in params})
    started = _ray_connect(address) if backend == "ray" else False  # a cluster that refuses: nothing written
    before = foreign_entries(out)  # a user's file in an earlier sweep's folder stays the user's
    try:
        claim_output_dir(out, "sweep", force=force, identity=scenario.name)
        store = SweepStore(out / "sweep.sqlite")
        if render_cache is not None:
            _link_render_cache(out / "runs" / ".render_cache", Path(render_cache))
    except BaseException:
        if started:
            import ray

            ray.shutdown()
        raise
    todo, all_tasks = [], grid(params, seeds)
    finished = store.finished()
    for overrides, seed in all_tasks:
        full = {**fixed, **overrides}
        rid = run_id(text, full, seed)
        if rid not in finished:
            todo.append((rid, str(scenario.resolve()), full, seed, str((out / "runs" / rid).resolve())))
    _warn_mixed_code(store.code_versions())
    bar = _Progress(len(all_tasks), len(all_tasks) - len(todo)) if progress else None
    stream = _local_backend(todo, workers or os.cpu_count()) if backend == "local" else _ray_backend(todo, started)
    for task, row in stream:
        store.add(task[0], task[2], task[3], row)
        if bar:
            bar.step(row["status"] == "done")
    rows = [r for r in store.rows() if r["status"] == "done"]
    errors = [r for r in store.rows() if r["status"] != "done"]
    store.close()
    summary = summarise(rows, [k for k, _ in params], out, scenario.stem)
    summary["errors"] = [f"{r['params']} seed {r['seed']}: {r['message']}" for r in errors]
    record_output_entries(out, exclude=before)
    return summary


def _warn_mixed_code(finished: dict, stream=None) -> None:
    """A resumed sweep whose finished runs other code made than this one: say so (one line on stderr, also when
    nothing is left to run, since the summary then pools them; the finished runs are kept, since the user may want
    them - ``--force`` starts afresh)."""
    now = code_version()
    other = {v: n for v, n in finished.items() if v != now}
    if other:
        made = ", ".join(f"{n} by {v}" for v, n in sorted(other.items()))
        print(f"bench sweep: warning: resuming over finished runs made by other code ({made}); this code is {now}. "
              "Their rows are kept; --force re-runs everything", file=stream or sys.stderr)


def summarise(rows: list, keys: list, out: Path, scenario: str = "") -> dict:
    """Median and spread (min, max, 25 %, 75 %) per grid point and metric -> CSV, and one plot per metric
    (``scenario``: its name, for the recording)."""
    from bench.scenario.results import write_table_csv

    groups = {}
    for r in rows:
        groups.setdefault(tuple(json.dumps(r["params"].get(k)) for k in keys), []).append(r)
    metrics = sorted({m for r in rows for m in r["metrics"]})
    table = {**{k: [] for k in keys}, "runs": [], **{f"{m}_{s}": [] for m in metrics for s in _STATS}}
    order = sorted(groups, key=lambda g: [_sort_key(json.loads(v)) for v in g])
    for g in order:
        for k, v in zip(keys, g, strict=True):
            table[k].append(json.loads(v))
        rs = groups[g]
        table["runs"].append(len(rs))
        for m in metrics:
            vals = _values(rs, m)
            stats = (np.median(vals), *np.percentile(vals, [25, 75]), vals.min(), vals.max()) if len(vals) else \
                (np.nan,) * 5
            for s, v in zip(_STATS, stats, strict=True):
                table[f"{m}_{s}"].append(float(v))
        for m, b in _bound_pairs(metrics):  # efficiency: RMS bound / RMS achieved error over the seeds
            err, bnd = _values(rs, m), _values(rs, b)
            eff = np.sqrt(np.mean(bnd**2)) / np.sqrt(np.mean(err**2)) if len(err) and len(bnd) else np.nan
            table.setdefault(f"{m}_rms", []).append(float(np.sqrt(np.mean(err**2))) if len(err) else np.nan)
            table.setdefault(f"{b}_rms", []).append(float(np.sqrt(np.mean(bnd**2))) if len(bnd) else np.nan)
            table.setdefault(f"{m}_efficiency", []).append(float(eff))
    write_table_csv(out / "summary.csv", table)
    plots, recording = [], None
    if keys and metrics and all(_is_number(v) for v in table[keys[0]]):
        from bench.scenario.sweep_recording import record_sweep

        plots = _plot(table, keys, metrics, out)
        # sweep.rrd: the median of every metric (and its bound) over the first swept key, with a blueprint
        recording = str(record_sweep(out / "sweep.rrd", table, keys, metrics, _bound_pairs(metrics), scenario))
    return {"store": str(out / "sweep.sqlite"), "summary": str(out / "summary.csv"), "plots": plots,
            "recording": recording, "rows": len(rows), "table": table}


_STATS = ("median", "q25", "q75", "min", "max")


def _values(rows, m) -> np.ndarray:
    """The values of metric ``m`` in the runs ``rows`` that have it."""
    return np.array([r["metrics"][m] for r in rows if r["metrics"].get(m) is not None], dtype=float)


def _bound_pairs(metrics) -> list:
    """``(error metric, its bound)`` pairs by name: ``x_err_y`` and ``x_bound_y`` (e.g. ``base_pos_err_mm``)."""
    names = set(metrics)
    return [(m, m.replace("_err_", "_bound_", 1)) for m in metrics if "_err_" in m
            and m.replace("_err_", "_bound_", 1) in names]


def _sort_key(v):
    return (0, v, "") if _is_number(v) else (1, 0, str(v))


def _is_number(v):
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _plot(table, keys, metrics, out):
    plt = headless_pyplot()

    x = np.array(table[keys[0]], dtype=float)
    others = list(zip(*(table[k] for k in keys[1:]), strict=True)) if len(keys) > 1 else [()] * len(x)
    paths = []
    bounds = dict(_bound_pairs(metrics))
    for m in metrics:
        fig, ax = plt.subplots(figsize=(6, 4))
        for label in sorted(set(others), key=str):
            sel = np.array([o == label for o in others])
            idx = np.argsort(x[sel])
            xs = x[sel][idx]
            med, lo, hi = (np.array(table[f"{m}_{s}"])[sel][idx] for s in ("median", "q25", "q75"))
            name = ", ".join(f"{k}={v}" for k, v in zip(keys[1:], label, strict=True)) or "median"
            line, = ax.plot(xs, med, "o-", label=name)
            ax.fill_between(xs, lo, hi, alpha=0.2, color=line.get_color())
            bound = bounds.get(m)
            if bound:  # the lower bound from the simulation's noise, beside the achieved error
                ax.plot(xs, np.array(table[f"{bound}_median"])[sel][idx], "--", color=line.get_color(),
                        label=f"{name}: bound ({bound})")
        ax.set(xlabel=keys[0], ylabel=m, title=f"{m}: median and interquartile range over seeds")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
        fig.tight_layout()
        path = out / f"sweep_{m}.png"
        atomic_save_figure(fig, path, dpi=110)
        paths.append(str(path))
    return paths
