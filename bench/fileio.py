"""Safe outputs, shared by every command that writes: atomic writes that honour the umask, and output claims.

Atomic writes
-------------
:func:`atomic_write_text`, :func:`atomic_write_bytes`, :func:`write_table_csv` and :func:`atomic_save_figure` write
a temporary file in the target's folder and rename it over the target, so a reader (or a crash) never sees half a
file. The file gets the permissions a plain ``open(path, "w")`` would give (``0666 & ~umask``, typically 0644), not
:func:`tempfile.mkstemp`'s owner-only 0600.

Output claims: no command deletes or replaces what it did not create
----------------------------------------------------------------------
Every command that writes an output folder (``bench run``, ``sweep``, ``budget``, ``sim render``, ``locate --out``,
``calibrate-camera --out``, ...) claims it first, before any work, with one line::

    out = claim_output_dir(args.out, "run", force=args.force, identity=run_identity(cfg, args.overrides))

and every command that writes one output file (``bench export``, ``export-camera``, ``import-tracker``,
``import-joints``, ...) writes it through::

    write_output_file(args.out, text, "export", force=args.force)   # or check_output_file(...) first, then write

(``check_output_dir`` / ``check_output_file`` make the same decision without creating anything, for a command that
must refuse before a long computation and writes later.) A claimed folder holds a marker, :data:`OUTPUT_MARKER`
(``.bench-output.json``: the command, an identity such as the scenario with its seed and overrides, the time); an
output file has a sidecar ``.NAME.bench-output.json`` with the command and the SHA-256 of what was written. The rules:

* a path that does not exist, or an empty folder, is claimed (folders created, the marker written);
* a previous output of the same command and identity is written into again (a sweep resumes, a run re-runs, a
  file is replaced): today's behaviour for one's own output;
* a previous output of the same command with another identity (a run folder of another scenario, or of the same
  one with another seed or ``--set``), or an output file edited since bench wrote it, is refused unless
  ``force=True``, which replaces it;
* anything else - a non-empty folder bench did not mark, another command's output, a file where a folder is
  expected or a folder where a file is expected - is refused, ``force`` or not: :class:`OutputRefused`, one line
  naming the option, the path and what is in the way;
* a command that finishes records in the marker the entries it wrote: a replacement (``force``, a dataset
  re-rendered whole) is refused while the folder holds anything else (a note the user put there since), which a
  re-run into the folder leaves alone;
* an unmarked folder written by an older version is adopted by its signature (a sweep's ``sweep.sqlite`` with its
  ``runs`` table, a run's ``result.json`` of the same scenario, a ``locate.json`` of the same dataset in a folder
  holding nothing else, ...: :func:`_legacy_output`), so old sweeps resume.

New commands: ``dataset init``-like commands that build a folder whole pass ``command=`` to
:class:`bench.dataset.DatasetWriter`; commands that write a folder step by step use :func:`claimed_output_dir`
(``with claimed_output_dir(args.out, "my-command", force=args.force) as out: ...``: a failure removes what it
created); a command that writes its folder at the very end uses :func:`writing_output_dir`.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import io
import json
import math
import os
import shutil
import tempfile
import time
from pathlib import Path

from bench.errors import BenchError

#: the marker file inside every output folder a bench command created
OUTPUT_MARKER = ".bench-output.json"


class OutputRefused(BenchError):
    """An output path that a command may not write: someone else's folder or file, or the wrong type of path."""


def _umask() -> int:
    """The process's umask, read without changing it where the system allows (Linux: /proc/self/status)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)  # elsewhere: read it by setting it (and put it back at once)
    os.umask(mask)
    return mask


def _mkstemp_like_open(folder: Path, name: str):
    """``(fd, tmp path)`` of a new temporary file next to ``name``, with a plain file's permissions."""
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{name}.", suffix=".tmp")
    try:
        os.fchmod(fd, 0o666 & ~_umask())
    except BaseException:
        os.close(fd)
        Path(tmp).unlink(missing_ok=True)
        raise
    return fd, tmp


def atomic_write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` via a temporary file in the same folder and an atomic rename; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = _mkstemp_like_open(path.parent, path.name)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def atomic_write_text(path, text: str) -> Path:
    """Write ``text`` to ``path`` via a temporary file in the same folder and an atomic rename; returns the path."""
    return atomic_write_bytes(path, text.encode())


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path next to ``path`` for a writer that wants a file name (a plot, a recording); renamed
    to ``path`` when the block ends without an exception, deleted otherwise. The suffix is kept (``.x.png.tmp.png``)
    so that writers choosing the format from the name still do."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = _mkstemp_like_open(path.parent, path.name)
    os.close(fd)
    tmp_named = Path(tmp).with_name(Path(tmp).name + path.suffix)
    os.replace(tmp, tmp_named)
    try:
        yield tmp_named
        os.replace(tmp_named, path)
    finally:
        tmp_named.unlink(missing_ok=True)


def atomic_save_figure(fig, path, **kwargs) -> Path:
    """``fig.savefig(path, **kwargs)`` written atomically (matplotlib figure), then the figure closed; returns the
    path."""
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=path.suffix.lstrip(".") or None, **kwargs)
    headless_pyplot().close(fig)
    return path


def headless_pyplot():
    """``matplotlib.pyplot`` on the non-interactive Agg backend (the bench only writes figures to files), imported
    when a plot is made."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt




def fix_mkdtemp_mode(path) -> Path:
    """Give a folder from :func:`tempfile.mkdtemp` (0700) a plain folder's permissions before it is renamed into
    place."""
    os.chmod(path, 0o777 & ~_umask())
    return Path(path)


def read_yaml(path, missing: str = "not found"):
    """The parsed content of the YAML file ``path`` (any type: the caller checks its shape); one-line
    :class:`bench.errors.ConfigError` naming the file when it is missing (the problem ``missing``), unreadable text or
    not valid YAML."""
    import yaml

    from bench.errors import ConfigError

    path = Path(path)
    if not path.is_file():
        raise ConfigError(path, "<file>", missing)
    try:
        return yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ConfigError(path, "<file>", f"not valid YAML ({str(exc).splitlines()[0]})") from None


def read_csv_table(path, columns=None) -> tuple[list, list]:
    """``(header, rows)`` of a CSV table transcribed or written by hand (blank and ``#`` comment lines skipped, the
    header's names stripped); one-line :class:`bench.errors.ConfigError` naming the file when it is missing, has no
    header or not ``columns`` (in order), or a row (``row N``: the N-th data row) has another number of values."""
    from bench.errors import ConfigError

    path = Path(path)
    if not path.is_file():
        raise ConfigError(path, "<file>", "not found")
    lines = [ln for ln in path.read_text().splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    rows = list(csv.reader(lines))
    header = [c.strip() for c in rows[0]] if rows else []
    if not header or columns is not None and tuple(header) != tuple(columns):
        raise ConfigError(path, "<header>", f"expected columns {', '.join(columns)}" if columns else "empty")
    for i, row in enumerate(rows[1:], start=1):
        if len(row) != len(header):
            raise ConfigError(path, f"row {i}", f"expected {len(header)} values, got {len(row)}")
    return header, rows[1:]


def csv_number(path, where: str, text) -> float:
    """``float(text)`` of a finite number; a one-line :class:`bench.errors.ConfigError` naming ``path`` and ``where``
    otherwise."""
    from bench.errors import ConfigError

    try:
        x = float(text)
    except (TypeError, ValueError):
        raise ConfigError(path, where, f"not a number: {text!r}") from None
    if not math.isfinite(x):
        raise ConfigError(path, where, "must be finite")
    return x


def _clean(value):
    if hasattr(value, "item"):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_table_csv(path, table: dict) -> None:
    """Write ``{column: [values]}`` as CSV (atomically)."""
    buf = io.StringIO()
    w = csv.writer(buf)
    cols = list(table)
    w.writerow(cols)
    for row in zip(*(table[c] for c in cols), strict=True):
        w.writerow([_clean(v) for v in row])
    atomic_write_text(path, buf.getvalue())


# ------------------------------------------------------------------------------------------------ output claims


def _read_json(path: Path):
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) and isinstance(doc.get("command"), str) else None


def _listing(names: list) -> str:
    shown = ", ".join(repr(n) for n in names[:3])
    return shown + (f" and {len(names) - 3} more" if len(names) > 3 else "")


def output_marker(path):
    """The marker of a bench output folder (``{"command", "identity", "created_at"}``), or ``None``."""
    return _read_json(Path(path) / OUTPUT_MARKER)


def _check_parent_folder(path: Path, option: str) -> None:
    """Refuse a path whose nearest existing ancestor is a file (``--out notes.txt/sub``)."""
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise OutputRefused(f"{option} {path}: {parent} is a file, not a folder")
            return


def check_output_dir(path, command: str, *, force: bool = False, identity: str | None = None,
                     option: str = "--out") -> str:
    """Decide whether ``command`` may write the folder ``path`` (creates nothing; see the module docstring).

    Returns ``"new"`` (absent), ``"empty"`` (an empty folder), ``"own"`` (a previous output of the same command and
    identity: write into it again) or ``"replace"`` (a previous output of the same command that ``force`` replaces);
    raises :class:`OutputRefused` otherwise.
    """
    path = Path(path)
    if not path.exists():
        if path.is_symlink():
            raise OutputRefused(f"{option} {path}: is a dangling symbolic link; choose another folder")
        _check_parent_folder(path, option)
        return "new"
    if not path.is_dir():
        raise OutputRefused(f"{option} {path}: is a file, not a folder (bench {command} writes a folder); "
                            "choose a new or empty folder")
    names = sorted(p.name for p in path.iterdir())
    if not [n for n in names if not _atomic_temporary(n)]:
        return "empty"  # nothing, or only a temporary file of a write killed before its rename (e.g. the marker's)
    marker = output_marker(path)
    if marker is None:  # written before markers existed: adopted by its signature, or refused below
        marker = _legacy_marker(path, command, identity)
    if marker is None:
        extra = f" (--force only replaces a previous output of bench {command})" if force else ""
        raise OutputRefused(f"{option} {path}: a non-empty folder that bench did not write (holds {_listing(names)}); "
                            f"choose a new or empty folder{extra}")
    if marker["command"] != command:
        raise OutputRefused(f"{option} {path}: holds the output of bench {marker['command']}, not of bench {command}; "
                            "choose another folder")
    recorded = _recorded_identity(marker.get("identity"), identity, path)
    if identity is not None and recorded not in (None, identity) and not force:
        diff = _settings_difference(recorded, identity)
        what = (f"with other settings: {diff}" if diff else
                f"for {recorded!r}, not {identity!r}")
        raise OutputRefused(f"{option} {path}: holds the output of bench {command} {what}; --force replaces it, "
                            "or choose another folder")
    if force:  # another identity, or the same one written afresh
        check_replaceable(path, option)
        return "replace"
    return "own"


def _atomic_temporary(name: str) -> bool:
    """Whether a folder entry is the temporary file of one of this module's atomic writes (``.NAME.xxxx.tmp``)."""
    return name.startswith(".") and name.endswith(".tmp")


def _ours(name: str, entries) -> bool:
    """Whether a top-level entry is one the command recorded: the name itself, a companion of it (``x.sqlite-wal``
    of ``x.sqlite``) or an atomic write's temporary file (``.x.1234.tmp...``)."""
    return (name == OUTPUT_MARKER or name in entries or any(name.startswith(e + "-") for e in entries)
            or (name.startswith(".") and ".tmp" in name))


def foreign_entries(path) -> list:
    """Top-level entries of a marked output folder that its command did not record as written (e.g. a note the user
    put there since); ``[]`` when the command never finished and so recorded nothing (then it is all its own)."""
    path = Path(path)
    marker = output_marker(path) or {}
    entries = marker.get("entries")
    if not isinstance(entries, list):
        return []
    return sorted(p.name for p in path.iterdir() if not _ours(p.name, entries))


def prepare_output_dir(path, command: str) -> Path:
    """The output folder of ``command``, created; refused (:class:`OutputRefused`, one line) when it is a file, a
    non-empty folder that bench did not write or another command's output (:func:`check_output_dir`). The CLI also
    marks it as the command's output (:func:`writing_output_dir`)."""
    path = Path(path)
    check_output_dir(path, command)
    path.mkdir(parents=True, exist_ok=True)
    return path


def settings_identity(paths: dict, **settings) -> str:
    """An output folder's identity made of what it was computed from: the input files ``paths`` (name -> path or
    None; resolved, so a relative path names the same file from anywhere) and the other ``settings`` (JSON, keys
    sorted). A re-run with the same writes into the folder again; other settings are refused unless ``force``
    (:func:`check_output_dir`), the refusal naming each setting that differs."""
    files = {k: None if v is None else str(Path(v).resolve()) for k, v in paths.items()}
    return json.dumps({**files, **settings}, sort_keys=True, default=str)


def _json_field(identity, key):
    """Field ``key`` of a :func:`settings_identity` string; the identity itself when it is a plain name (as older
    versions recorded), None when it is neither."""
    try:
        doc = json.loads(identity)
    except (TypeError, ValueError):
        return identity if isinstance(identity, str) else None
    return doc.get(key) if isinstance(doc, dict) else None


def _recorded_identity(have, want, path: Path):
    """The identity a folder's marker recorded, comparable with this call's ``want``. A run marked by an older
    version recorded only the scenario's name (``have`` a plain name, ``want`` a :func:`settings_identity` naming
    that scenario): it is read as this call's settings with the seed of the folder's result.json, so a re-run with
    the same seed adopts it and one with another seed is refused by name; its overrides were not recorded."""
    if not isinstance(have, str) or not isinstance(want, str) or have == want or _json_field(want, "name") != have:
        return have  # a settings identity of its own (or none): compared as it is
    try:
        seed = json.loads((path / "result.json").read_text()).get("seed")
    except (OSError, ValueError, AttributeError):
        seed = None
    doc = json.loads(want)
    if seed is not None:
        doc["seed"] = seed
    return json.dumps(doc, sort_keys=True, default=str)


def _settings_difference(have, want) -> str | None:
    """``"seed 1 (this call: 0), ..."`` for two :func:`settings_identity` strings; None if either is not one."""
    try:
        a, b = json.loads(have), json.loads(want)
    except (TypeError, ValueError):
        return None
    if not (isinstance(a, dict) and isinstance(b, dict)):
        return None

    def shown(v):
        return "not given" if v is None else v

    return ", ".join(f"{k} {shown(a.get(k))} (this call: {shown(b.get(k))})" for k in sorted(set(a) | set(b))
                     if a.get(k) != b.get(k))


def check_replaceable(path, option: str = "--out") -> None:
    """Refuse to replace a marked output folder that holds something its command did not write."""
    foreign = foreign_entries(path)
    if foreign:
        raise OutputRefused(f"{option} {path}: holds {_listing(foreign)}, which bench did not write there; move "
                            "it away first (bench replaces only its own output)")


def record_output_entries(path, exclude=()) -> None:
    """Record in the marker the top-level entries the command has written (done when it finishes; ``exclude``: the
    foreign entries that were there before it started), so that a later replacement can tell a file put there by
    someone else (:func:`foreign_entries`)."""
    path = Path(path)
    marker = output_marker(path)
    if marker is None:
        return
    marker["entries"] = sorted(p.name for p in path.iterdir() if p.name != OUTPUT_MARKER and p.name not in exclude)
    atomic_write_text(path / OUTPUT_MARKER, json.dumps(marker, indent=2) + "\n")


def _legacy_marker(path: Path, command: str, identity) -> dict | None:
    """The marker an unmarked folder is adopted with when it is recognisably an output of ``command`` written before
    output markers existed (so that a sweep started by an older version still resumes), else None. A run's marker
    holds the scenario's name, as older versions recorded it (:func:`_recorded_identity` reads it with the seed of
    its result.json); the others hold this call's ``identity``."""
    if not _legacy_output(path, command, identity):
        return None
    return {"command": command, "identity": _json_field(identity, "name") if command == "run" else identity}


def _legacy_output(path: Path, command: str, identity) -> bool:
    """Whether an unmarked folder is recognisably an output of ``command`` written before output markers existed:
    its signature file, and for a run or a budget the scenario's name in its result.json and every artifact it names
    there (a copy of a result.json alone, e.g. kept by hand beside one's notes, is not a run's folder)."""
    def doc(name):
        try:
            return json.loads((path / name).read_text())
        except (OSError, ValueError):
            return None

    def artifacts_present(res) -> bool:
        arts = res.get("artifacts") or {}
        return isinstance(arts, dict) and all(isinstance(a, str) and (path / a).exists() for a in arts.values())

    if command == "sweep":
        db = path / "sweep.sqlite"
        if not db.is_file():
            return False
        import sqlite3

        try:
            with contextlib.closing(read_only_sqlite(db)) as con:
                return con.execute("SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'runs'").fetchone() \
                    is not None
        except sqlite3.Error:
            return False
    if command == "run":
        res = doc("result.json")
        return (isinstance(res, dict) and identity is not None and res.get("scenario") == _json_field(identity, "name")
                and artifacts_present(res))
    if command == "budget":
        res = doc("result.json")
        if not isinstance(res, dict):
            return False
        name = str(res.get("scenario", ""))
        return (name.startswith("budget:") and (identity is None or name == f"budget:{Path(identity).stem}")
                and artifacts_present(res))
    if command == "sim render":
        try:
            import yaml

            man = yaml.safe_load((path / "manifest.yaml").read_text())
        except Exception:  # noqa: BLE001 - not a readable manifest: not a dataset bench rendered
            return False
        return isinstance(man, dict) and str(man.get("created_by", "")).startswith("bench sim render")
    if command in ("locate", "calibrate-camera"):
        res = doc(_LEGACY_REPORT[command][0])
        names = {p.name for p in path.iterdir() if not _atomic_temporary(p.name)}
        return (isinstance(res, dict) and set(_LEGACY_REPORT[command][1]) <= set(res)
                and names <= set(_LEGACY_REPORT[command][2]) and _same_dataset(res, identity))
    return False


#: an unmarked ``bench locate`` / ``calibrate-camera`` output: its report, keys every report of it has, and every
#: entry the command may write (a folder holding anything else, e.g. one's notes beside a copied report, is not one)
_LEGACY_REPORT = {
    "locate": ("locate.json", ("dataset", "success", "map_points", "timings_s"), ("locate.json",)),
    "calibrate-camera": ("calibration.json", ("views_used", "success", "reproj_rms_px", "timings_s"),
                         ("calibration.json", "camera.yaml", "per_view.csv", "residuals.png", "robot.yaml")),
}


def _same_dataset(report: dict, identity) -> bool:
    """Whether an unmarked report was computed from the dataset this call names (its identity's ``dataset``);
    True when either does not say."""
    try:
        want = json.loads(identity).get("dataset") if identity else None
    except (TypeError, ValueError, AttributeError):
        return True
    have = report.get("dataset", report.get("photos"))
    return want is None or have is None or str(Path(str(have)).resolve()) == want


def read_only_sqlite(path):
    """``sqlite3`` connection to the database file ``path``, read-only (its URI percent-encoded: a folder named
    ``run#2`` or ``a?b`` is a path, not a URI's fragment or query)."""
    import sqlite3

    return sqlite3.connect(f"{Path(path).resolve().as_uri()}?mode=ro", uri=True)


def mark_output_dir(path, command: str, identity: str | None = None) -> Path:
    """Write the marker into the folder ``path`` (which must exist): it is the output of ``command``."""
    doc = {"command": command, "identity": identity, "created_at": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
    return atomic_write_text(Path(path) / OUTPUT_MARKER, json.dumps(doc, indent=2) + "\n")


def claim_output_dir(path, command: str, *, force: bool = False, identity: str | None = None,
                     option: str = "--out") -> Path:
    """Make ``path`` the output folder of ``command`` before any work, or refuse (:class:`OutputRefused`).

    A new or empty folder is created and marked; a previous output of the same command and identity is returned as
    it is (the command writes into it again, e.g. a sweep resumes); with ``force``, a previous output of the same
    command is emptied and marked afresh. Everything else is refused (see the module docstring). Returns the path.
    """
    path = Path(path)
    decision = check_output_dir(path, command, force=force, identity=identity, option=option)
    if decision == "own":
        if output_marker(path) is None:  # an adopted output of an older version
            mark_output_dir(path, command, identity)
        return path
    if decision == "replace":
        shutil.rmtree(path)
    path.mkdir(parents=True, exist_ok=True)
    mark_output_dir(path, command, identity)
    return path


def _sidecar(path: Path) -> Path:
    return path.with_name(f".{path.name}{OUTPUT_MARKER}")


def check_output_file(path, command: str, *, force: bool = False, option: str = "--out") -> str:
    """Decide whether ``command`` may write the file ``path`` (creates nothing).

    Returns ``"new"``, ``"own"`` (written by the same command and unchanged since: replaced) or ``"replace"`` (written
    by the same command but edited since, and ``force`` given); raises :class:`OutputRefused` otherwise.
    """
    path = Path(path)
    if path.is_dir():
        raise OutputRefused(f"{option} {path}: is a folder; bench {command} writes a file (give a file name)")
    _check_parent_folder(path, option)
    if not path.exists():
        if path.is_symlink():
            raise OutputRefused(f"{option} {path}: is a dangling symbolic link; choose another name")
        return "new"
    side = _read_json(_sidecar(path))
    if side is None or side["command"] != command:
        by = f"bench {side['command']}" if side else "someone else"
        raise OutputRefused(f"{option} {path}: exists and was written by {by}, not by bench {command}; remove it "
                            "or choose another name")
    if side.get("sha256") == hashlib.sha256(path.read_bytes()).hexdigest():
        return "own"
    if not force:
        raise OutputRefused(f"{option} {path}: changed since bench {command} wrote it; --force replaces it")
    return "replace"


def write_output_file(path, data, command: str, *, force: bool = False, option: str = "--out") -> Path:
    """Write the output file ``path`` of ``command`` atomically (``data``: str or bytes) after
    :func:`check_output_file`, and record it in its sidecar ``.NAME.bench-output.json``; returns the path."""
    path = Path(path)
    check_output_file(path, command, force=force, option=option)
    raw = data.encode() if isinstance(data, str) else bytes(data)
    doc = {"command": command, "sha256": hashlib.sha256(raw).hexdigest(),
           "created_at": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
    atomic_write_text(_sidecar(path), json.dumps(doc, indent=2) + "\n")  # first: a crash between leaves "changed"
    return atomic_write_bytes(path, raw)


@contextlib.contextmanager
def writing_output_dir(path, command: str, *, force: bool = False, identity: str | None = None,
                       option: str = "--out"):
    """For a command that writes its folder only at the end (``bench locate --out``): refuse now, as
    :func:`claim_output_dir` would, but create nothing unless the command writes; yields the path.

    A refused or failed command that wrote nothing leaves nothing behind; whatever it wrote is marked as its output
    when the block ends (even by an exception). With ``force``, a previous output of the same command is removed
    first."""
    path = Path(path)
    decision = check_output_dir(path, command, force=force, identity=identity, option=option)
    before = foreign_entries(path) if decision == "own" else []
    if decision == "replace":
        shutil.rmtree(path)
    try:
        yield path
    finally:
        if path.is_dir() and any(path.iterdir()) and output_marker(path) is None:  # new, or adopted from before
            mark_output_dir(path, command, identity)
        if output_marker(path) is not None:
            record_output_entries(path, exclude=before)


@contextlib.contextmanager
def claimed_output_dir(path, command: str, *, force: bool = False, identity: str | None = None,
                       option: str = "--out"):
    """:func:`claim_output_dir` for the duration of a command: yields the claimed folder; if the block raises (a
    refusal found late, a crash, Ctrl-C), a folder this call created is removed again - everything in it was the
    command's - and an empty folder it was given is left empty. A previous output written into again is left as
    the command left it."""
    path = Path(path)
    decision = check_output_dir(path, command, force=force, identity=identity, option=option)
    before = foreign_entries(path) if decision == "own" else []
    claim_output_dir(path, command, force=force, identity=identity, option=option)
    try:
        yield path
    except BaseException:
        if decision != "own":
            shutil.rmtree(path, ignore_errors=True)
            if decision == "empty":
                path.mkdir(exist_ok=True)
        raise
    record_output_entries(path, exclude=before)
