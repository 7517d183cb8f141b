"""Import a laser tracker's point export and a joint log into the dataset's ``tracker.csv`` / ``joints.csv``.

Users bring whatever their tracker software and robot controller wrote: comma, semicolon, tab or space separated,
with or without a header, points in mm or m, joints in degrees or radians. The importers turn that into the
dataset's files (:mod:`bench.dataset`: ``point, x_mm, y_mm, z_mm, q1_deg ... q6_deg`` and ``view, q1_deg ...
q6_deg``), and refuse - one line naming file, line and column - anything they cannot read with certainty.

**The unit is never guessed.** It is stated by the column names (``x_mm``, ``X [m]``, ``q1 (rad)``, ``J3/deg``), by
a declaration line (``# units: mm``, ``# angle unit: rad``) or by the caller (``--units``); two statements that
disagree, or none, are errors. What the stated unit makes of the numbers is then checked for plausibility:

* joint readings beyond one turn (``|q| > 2 pi``, i.e. 360 deg) - degrees given with ``--units rad``, or not
  angles at all; and, in degrees, the dataset's own check (:func:`bench.dataset._check_degrees`: every reading
  within +-pi although the unit is deg - radians given as degrees) is made an error here;
* tracker coordinates beyond a tracker's range (100 m) - millimetres given as metres; or points spanning less than
  10 mm - metres given as millimetres (a kinematic campaign spans the arm's workspace, about 2 m for the TA-40).

Columns: a key (``point``, ``point name``, ``id``, ``name``, ``label``, ``view``, ``target``; else the first column
if its title is none of the following), coordinates ``x, y, z``, joints ``q1..q6`` (also ``j``, ``joint``,
``theta``, ``axis``, ``a`` + 1..6); other columns (uncertainty, ...) are ignored. Without a header the columns are
taken by position: ``[key,] x, y, z[, q1..q6]`` or ``[key,] q1..q6``; rows without a key are named
``point001``/``view001`` in file order. The tracker points need the joint readings they were taken at: from joint
columns in the same file or from a joint log matched by name. Values are carried into the dataset's units directly
(mm stays mm, deg stays deg), so the user's numbers are not rounded; the output is written atomically.
"""

from __future__ import annotations

import csv
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.dataset import JOINT_COLUMNS, TRACKER_COLUMNS, _check_degrees, _csv_text
from bench.errors import ConfigError
from bench.fileio import check_output_file, write_output_file

LENGTH_UNITS = {"mm": 1e-3, "m": 1.0}
ANGLE_UNITS = {"deg": np.pi / 180.0, "rad": 1.0}
#: a joint reading beyond one turn is a unit mistake (rad)
MAX_JOINT_RAD = 2.0 * np.pi
#: tracker coordinates beyond this are a unit mistake (m); a laser tracker measures to some tens of metres
MAX_TRACKER_RANGE_M = 100.0
#: tracker points of a kinematic campaign spanning less than this (bounding-box diagonal, m) are a unit mistake
MIN_TRACKER_SPAN_M = 0.01

_UNIT_WORDS = {"mm": "mm", "millimeter": "mm", "millimeters": "mm", "millimetre": "mm", "millimetres": "mm",
               "m": "m", "meter": "m", "meters": "m", "metre": "m", "metres": "m",
               "deg": "deg", "degree": "deg", "degrees": "deg", "°": "deg",
               "rad": "rad", "radian": "rad", "radians": "rad"}
_KEY_NAMES = ("point", "pointname", "pointid", "name", "id", "label", "view", "target")
_JOINT_RE = re.compile(r"^(?:q|j|joint|theta|axis|a)([1-6])$")
_CELL_RE = re.compile(r"^(?P<name>.*?)\s*(?:[\[(]\s*(?P<u1>[^\])]+?)\s*[\])]|[_/ ]\s*(?P<u2>[a-z°]+))$")
_DECL_RE = re.compile(r"^\s*(?:#|//)?\s*(?P<what>length|angle|joint|coordinate)?s?\s*units?\s*[:=,]\s*"
                      r"(?P<unit>[^\s,;]+)\s*[,;]*\s*$", re.IGNORECASE)


@dataclass(frozen=True)
class Table:
    """Rows read from a user's file, values in the file's own unit.

    Attributes
    ----------
    source : Path
    names : list of str
        Row keys (point or view names), in file order.
    lines : list of int
        File line (1-based) of each row.
    values : ndarray (n, k)
        The group's columns, in ``unit``.
    columns : tuple of str
        The file's name for each column (for messages).
    unit : str
        ``mm``/``m`` or ``deg``/``rad``.
    """

    source: Path
    names: list
    lines: list
    values: np.ndarray
    columns: tuple
    unit: str

    def where(self, i: int, j: int) -> str:
        return f"line {self.lines[i]}, column {self.columns[j]}"


@dataclass(frozen=True)
class ImportResult:
    """What an importer wrote: the file, the number of rows and the units it read them in."""

    path: Path
    rows: int
    units: dict


def _unit_word(text: str) -> str | None:
    return _UNIT_WORDS.get(text.strip().lower().rstrip("."))


def _parse_cell(cell: str):
    """``(role, index, unit)`` of a header cell: role ``key``/``coord``/``joint``/``None``, unit or ``None``."""
    text = cell.strip().strip('"').strip().lower()
    name, unit = text, None
    m = _CELL_RE.match(text)
    if m:
        u = _unit_word(m.group("u1") or m.group("u2"))
        if u is not None:
            name, unit = m.group("name"), u
    name = re.sub(r"[\s_\-]+", "", name)
    if name in ("x", "y", "z"):
        return "coord", "xyz".index(name), unit
    jm = _JOINT_RE.match(name)
    if jm:
        return "joint", int(jm.group(1)) - 1, unit
    if name in _KEY_NAMES:
        return "key", 0, unit
    return None, 0, unit


def _delimiter(rows) -> str | None:
    """``,``, ``;`` or tab as :class:`csv.Sniffer` finds it in the first rows (a quoted field may hold another of
    them), else in the first row alone (a later row cut short); ``None``: separated by whitespace."""
    for sample in ("\n".join(ln for _, ln in rows[:10]), rows[0][1]):
        try:
            return csv.Sniffer().sniff(sample, delimiters=",;\t").delimiter
        except csv.Error:
            pass
    return None


def _split(path: Path, no: int, line: str, delim: str | None) -> list[str]:
    """The stripped fields of one line, read by :func:`csv.reader` (double quotes around a field that holds the
    delimiter); one or more spaces separate them when ``delim`` is ``None``."""
    try:
        fields = next(csv.reader([line if delim else line.strip()], delimiter=delim or " ", skipinitialspace=True), [])
    except csv.Error as exc:
        raise ConfigError(path, f"line {no}", f"not a readable row ({exc})") from None
    return [f.strip() for f in fields]


def _number(text: str, decimal_comma: bool) -> float:
    return float(text.replace(",", ".") if decimal_comma else text)


def _is_number(text: str, decimal_comma: bool) -> bool:
    try:
        _number(text, decimal_comma)
    except ValueError:
        return False
    return True


def _read_lines(path: Path) -> list[tuple[int, str]]:
    if not path.is_file():
        raise ConfigError(path, "<file>", "not found")
    try:
        text = path.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError:
        raise ConfigError(path, "<file>", "not a UTF-8 text file") from None
    if "\x00" in text:
        raise ConfigError(path, "<file>", "not a text file (NUL bytes)")
    lines = [(i, ln.rstrip("\r")) for i, ln in enumerate(text.split("\n"), start=1) if ln.strip()]
    if not lines:
        raise ConfigError(path, "<file>", "empty")
    return lines


def _declared_units(path: Path, lines) -> tuple[dict, list]:
    """Unit declarations (``# units: mm``) by kind, and the remaining non-comment lines."""
    declared, rest = {}, []
    for no, ln in lines:
        m = _DECL_RE.match(ln)
        if m:
            unit = _unit_word(m.group("unit"))
            if unit is None:
                raise ConfigError(path, f"line {no}", f"unknown unit {m.group('unit')!r} (mm, m, deg or rad)")
            kind = "length" if unit in LENGTH_UNITS else "angle"
            if declared.get(kind, (unit,))[0] != unit:
                raise ConfigError(path, f"line {no}", f"declares {unit} after {declared[kind][0]} (line "
                                                      f"{declared[kind][1]})")
            declared[kind] = (unit, no)
        elif not ln.lstrip().startswith(("#", "//")):
            rest.append((no, ln))
    if not rest:
        raise ConfigError(path, "<file>", "no data rows")
    return declared, rest


def _read_table(path, kind: str, units: str | None = None, joint_units: str | None = None) -> dict:
    """Parse a tracker export (``kind="tracker"``) or a joint log (``kind="joints"``) into :class:`Table` groups.

    Returns ``{"coord": Table or None, "joint": Table or None}`` (for ``joints`` only ``joint``).
    """
    path = Path(path)
    lines = _read_lines(path)
    declared, rows = _declared_units(path, lines)
    first_no, first = rows[0]
    delim = _delimiter(rows)
    decimal_comma = delim != ","
    cells = _split(path, first_no, first, delim)
    numeric = [_is_number(c, decimal_comma) for c in cells]
    layout = {}  # role -> {index: column position}; key -> position
    col_units = {"coord": {}, "joint": {}}
    names_of = {}
    if all(numeric) or (len(cells) > 1 and not numeric[0] and all(numeric[1:]) and
                        _parse_cell(cells[0])[0] is None):
        has_key = not numeric[0]
        n_val = len(cells) - has_key
        want = {"tracker": {3: ("coord",), 9: ("coord", "joint")}, "joints": {6: ("joint",)}}[kind]
        if n_val not in want:
            expect = "[name,] x, y, z[, q1..q6]" if kind == "tracker" else "[name,] q1..q6"
            raise ConfigError(path, f"line {first_no}", f"{len(cells)} fields and no header: expected {expect}; "
                                                        "add a header naming the columns")
        pos = int(has_key)
        if has_key:
            layout["key"] = 0
            names_of[0] = "name"
        for role in want[n_val]:
            n = 3 if role == "coord" else 6
            layout[role] = {i: pos + i for i in range(n)}
            names_of.update({pos + i: ("xyz"[i] if role == "coord" else f"q{i + 1}") for i in range(n)})
            pos += n
        header_cells = None
    else:
        header_cells = cells
        for j, cell in enumerate(cells):
            role, idx, unit = _parse_cell(cell)
            if role is None:
                continue
            if role == "key":
                if "key" not in layout:
                    layout["key"], names_of[j] = j, cell
                continue
            group = layout.setdefault(role, {})
            if idx in group:
                raise ConfigError(path, f"line {first_no}, column {cell!r}", f"duplicate of column "
                                                                             f"{cells[group[idx]]!r}")
            group[idx] = j
            names_of[j] = cell
            if unit is not None:
                col_units[role][cell] = unit
        if "key" not in layout and _parse_cell(cells[0])[0] is None:
            layout["key"], names_of[0] = 0, cells[0] or "column 1"  # a first column of names under another title
        rows = rows[1:]
        if not rows:
            raise ConfigError(path, "<file>", "a header but no data rows")
    for role, n in (("coord", 3), ("joint", 6)):
        group = layout.get(role)
        if group is not None and len(group) != n:
            missing = [("xyz"[i] if role == "coord" else f"q{i + 1}") for i in range(n) if i not in group]
            raise ConfigError(path, f"line {first_no}", f"column {missing[0]} missing (found "
                                                        f"{', '.join(names_of[p] for p in group.values())})")
    need = "coord" if kind == "tracker" else "joint"
    if need not in layout:
        cols = ", ".join(header_cells or [])
        what = "x, y, z" if need == "coord" else "q1 .. q6"
        raise ConfigError(path, f"line {first_no}", f"no {what} columns (header: {cols})")
    if kind == "joints":
        layout.pop("coord", None)

    # units: column suffixes, declarations and the caller must agree
    resolved = {}
    for role, kind_u, given, table in (("coord", "length", units if kind == "tracker" else None, LENGTH_UNITS),
                                       ("joint", "angle", joint_units if kind == "tracker" else units, ANGLE_UNITS)):
        if role not in layout:
            continue
        stated = {}
        for cell, u in col_units[role].items():
            if u not in table:
                raise ConfigError(path, f"column {cell!r}", f"{u} is not a unit of {kind_u} ({', '.join(table)})")
            stated.setdefault(u, f"column {cell!r}")
        if len(stated) > 1:
            raise ConfigError(path, f"line {first_no}", "columns in different units: " +
                              ", ".join(f"{w} in {u}" for u, w in stated.items()))
        if kind_u in declared:
            u, no = declared[kind_u]
            stated.setdefault(u, f"line {no}")
        if given is not None:
            if given not in table:
                raise ConfigError("--units" if role == need else "--joint-units", given,
                                  f"expected one of {', '.join(table)}")
            stated.setdefault(given, "--units" if role == need else "--joint-units")
        if len(stated) > 1:
            raise ConfigError(path, "units", "stated twice and differently: " +
                              ", ".join(f"{u} ({w})" for u, w in stated.items()))
        if not stated:
            opt = "--units" if role == need else "--joint-units"
            ex = "x_mm, y_mm, z_mm" if role == "coord" else "q1_deg .. q6_deg"
            raise ConfigError(path, "units", f"the {kind_u} unit is not stated: pass {opt} "
                                             f"{'|'.join(table)} or name the columns like {ex}")
        resolved[role] = next(iter(stated))

    n_fields = len(header_cells) if header_cells is not None else len(cells)
    key_pos = layout.get("key")
    names, line_nos, vals = [], [], {r: [] for r in resolved}
    seen = {}
    prefix = "point" if kind == "tracker" else "view"
    for r, (no, ln) in enumerate(rows):
        fields = _split(path, no, ln, delim)
        if len(fields) > n_fields:
            ref = "header" if header_cells else "first row"
            raise ConfigError(path, f"line {no}", f"{len(fields)} fields, the {ref} has {n_fields}")
        for role in resolved:
            row = []
            for i in range(len(layout[role])):
                p = layout[role][i]
                col = names_of[p]
                if p >= len(fields) or fields[p] == "":
                    raise ConfigError(path, f"line {no}, column {col}", f"missing (truncated row: {len(fields)} of "
                                                                        f"{n_fields} fields)")
                try:
                    v = _number(fields[p], decimal_comma)
                except ValueError:
                    raise ConfigError(path, f"line {no}, column {col}", f"not a number: {fields[p]!r}") from None
                if not np.isfinite(v):
                    raise ConfigError(path, f"line {no}, column {col}", "NaN or inf")
                row.append(v)
            vals[role].append(row)
        if key_pos is not None:
            name = fields[key_pos] if key_pos < len(fields) else ""
            if not name:
                raise ConfigError(path, f"line {no}, column {names_of[key_pos]}", "empty name")
        else:
            name = f"{prefix}{r + 1:03d}"
        if name in seen:
            raise ConfigError(path, f"line {no}", f"duplicate name {name!r} (first on line {seen[name]})")
        seen[name] = no
        names.append(name)
        line_nos.append(no)
    return {role: Table(path, names, line_nos, np.array(vals[role], dtype=float),
                        tuple(names_of[layout[role][i]] for i in range(len(layout[role]))), unit)
            for role, unit in resolved.items()}


def _check_joints(t: Table) -> np.ndarray:
    """The readings in degrees (dataset unit) after the plausibility checks (see the module docstring)."""
    q_rad = t.values * ANGLE_UNITS[t.unit]
    bad = np.argwhere(np.abs(q_rad) > MAX_JOINT_RAD)
    if bad.size:
        i, j = bad[0]
        hint = "degrees given as radians?" if t.unit == "rad" else "not a joint reading in degrees"
        raise ConfigError(t.source, t.where(i, j), f"{t.values[i, j]:g} {t.unit} is more than one turn (2 pi rad): "
                                                   f"{hint}")
    q_deg = t.values if t.unit == "deg" else np.rad2deg(t.values)
    if t.unit == "deg":
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            _check_degrees(t.source, dict(zip(t.names, q_deg, strict=True)), JOINT_COLUMNS)
        if caught:
            raise ConfigError(t.source, f"columns {', '.join(t.columns)}", "every reading lies within +-pi although "
                              "the unit is deg: radians given as degrees? (state rad)")
    return q_deg


def _check_points(t: Table) -> np.ndarray:
    """The points in mm (dataset unit) after the plausibility checks (see the module docstring)."""
    p_m = t.values * LENGTH_UNITS[t.unit]
    bad = np.argwhere(np.abs(p_m) > MAX_TRACKER_RANGE_M)
    if bad.size:
        i, j = bad[0]
        raise ConfigError(t.source, t.where(i, j), f"{t.values[i, j]:g} {t.unit} is beyond a laser tracker's range "
                          f"({MAX_TRACKER_RANGE_M:g} m): millimetres given as metres?")
    span = float(np.linalg.norm(p_m.max(axis=0) - p_m.min(axis=0)))
    if len(p_m) >= 3 and span < MIN_TRACKER_SPAN_M:
        raise ConfigError(t.source, f"lines {t.lines[0]}-{t.lines[-1]}, columns {', '.join(t.columns)}",
                          f"the {len(p_m)} points span only {span * 1e3:.3g} mm (read as {t.unit}): metres given "
                          "as millimetres? (a kinematic campaign spans the arm's workspace)")
    return t.values if t.unit == "mm" else t.values * 1e3


def import_joints(path, out, units: str | None = None, force: bool = False) -> ImportResult:
    """Convert a joint log into the dataset's ``joints.csv`` (``view, q1_deg ... q6_deg``).

    Parameters
    ----------
    path : path-like
        The log (see the module docstring for what is understood).
    out : path-like
        The ``joints.csv`` to write (atomically).
    units : {"deg", "rad"}, optional
        The log's angle unit, unless its columns or a declaration line state it (then they must agree).
    force : bool
        Replace an earlier output of ``bench import-joints`` edited since (never another file: see
        :func:`bench.fileio.check_output_file`).
    """
    check_output_file(out, "import-joints", force=force)
    t = _read_table(path, "joints", units)["joint"]
    q_deg = _check_joints(t)
    write_output_file(out, _csv_text(["view", *JOINT_COLUMNS], [[n, *q] for n, q in zip(t.names, q_deg, strict=True)]),
                      "import-joints", force=force)
    return ImportResult(Path(out), len(t.names), {"angle": t.unit})


def import_tracker(path, out, units: str | None = None, joints=None, joint_units: str | None = None,
                   force: bool = False) -> ImportResult:
    """Convert a laser-tracker export into the dataset's ``tracker.csv`` (``point, x_mm, y_mm, z_mm, q1_deg ...``).

    Parameters
    ----------
    path : path-like
        The tracker's point export, with the joint readings as columns or not.
    out : path-like
        The ``tracker.csv`` to write (atomically).
    units : {"mm", "m"}, optional
        The coordinates' unit, unless stated in the file (then they must agree).
    joints : path-like, optional
        A joint log with a reading for every point, matched by name (when the export has no joint columns).
    joint_units : {"deg", "rad"}, optional
        The readings' unit (of the joint columns, or of ``joints``), unless stated in the file.
    force : bool
        Replace an earlier output of ``bench import-tracker`` edited since (never another file).
    """
    check_output_file(out, "import-tracker", force=force)
    groups = _read_table(path, "tracker", units, joint_units)
    pts = groups["coord"]
    p_mm = _check_points(pts)
    if "joint" in groups:
        if joints is not None:
            raise ConfigError(path, "columns " + ", ".join(groups["joint"].columns),
                              f"joint readings both in the file and in {joints}: give one")
        q_deg = _check_joints(groups["joint"])
    else:
        if joints is None:
            raise ConfigError(path, "<header>", "no joint readings (q1..q6 columns): tracker.csv needs the "
                                                "readings each point was taken at; pass a joint log (--joints)")
        jt = _read_table(joints, "joints", joint_units)["joint"]
        by_name = dict(zip(jt.names, _check_joints(jt), strict=True))
        missing = [(n, ln) for n, ln in zip(pts.names, pts.lines, strict=True) if n not in by_name]
        if missing:
            n, ln = missing[0]
            raise ConfigError(joints, f"point {n!r}", f"no reading for the point on line {ln} of {pts.source} "
                                                      f"({len(missing)} of {len(pts.names)} points unmatched)")
        q_deg = np.array([by_name[n] for n in pts.names])
    rows = [[n, *p, *q] for n, p, q in zip(pts.names, p_mm, q_deg, strict=True)]
    write_output_file(out, _csv_text(["point", *TRACKER_COLUMNS, *JOINT_COLUMNS], rows), "import-tracker", force=force)
    angle = groups["joint"].unit if "joint" in groups else jt.unit
    return ImportResult(Path(out), len(rows), {"length": pts.unit, "angle": angle})
