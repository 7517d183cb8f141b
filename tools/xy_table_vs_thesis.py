"""The x-y table sweeps (realistic and ideal imaging) against the thesis's Tables 5-8 / 11-14 (issue 12).

    .venv/bin/python tools/xy_table_vs_thesis.py \\
        --setup webcam runs/sweep-xy-webcam-realistic runs/sweep-xy-webcam-ideal \\
        [--setup underwater runs/sweep-xy-underwater-realistic runs/sweep-xy-underwater-ideal] \\
        [--min-d-mm 40] [--factor 2.5] [--doc docs/realistic_imaging.md]

Each sweep folder is a ``bench sweep`` output of an ``xy_table`` scenario (``sweep.sqlite``,
:class:`bench.scenario.sweep.SweepStore`); every finished run's ``result.json`` holds
``tables.position_error_vs_intraocular``: per method and d_o the RMS error over the pair combinations per axis
(``err_{x,y,z}_mm``) and the thesis's printed value beside it (``thesis_err_{x,y,z}_mm``, from
``scenarios/data/thesis_tables_*.csv``). For each of the thesis's estimators (quaternion, LMS, each without and with
error-ratio elimination), each d_o >= ``--min-d-mm`` and each axis the tool tabulates the median over the seeds under
realistic and under ideal imaging, the thesis's value, the ratio realistic / thesis and whether it lies within
``[1 / factor, factor]``. The table goes between ``<!-- xy_table_vs_thesis:begin -->`` and
``<!-- xy_table_vs_thesis:end -->`` of ``--doc``; without the markers the page is left alone and the table printed.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.errors import BenchError  # noqa: E402

BEGIN, END = "<!-- xy_table_vs_thesis:begin -->", "<!-- xy_table_vs_thesis:end -->"
METHODS = ("quaternion", "quaternion_ratio", "lms", "lms_ratio")
LABELS = {"quaternion": "quaternion", "quaternion_ratio": "quaternion + error ratio", "lms": "LMS",
          "lms_ratio": "LMS + error ratio"}
AXES = ("x", "y", "z")


def load_sweep(folder) -> dict:
    """Per-seed tables of one sweep folder.

    Parameters
    ----------
    folder : path of a ``bench sweep`` output (``sweep.sqlite`` inside).

    Returns
    -------
    dict with ``scenario`` (str), ``imaging`` (the runs' ``sim.imaging`` override, ``realistic`` - the kind's
    default - when not overridden) and ``runs``: ``{seed: {(method, d_mm): {"err_x_mm": ..., "thesis_err_x_mm": ...,
    "table": int}}}`` for every finished run (errors in mm; NaN where every estimate of that cell failed).
    """
    from bench.scenario.sweep import SweepStore

    folder = Path(folder)
    db = folder / "sweep.sqlite"
    if not db.is_file():
        raise BenchError(f"{folder}: no sweep.sqlite (not a bench sweep output folder)")
    store = SweepStore(db)
    try:
        rows = [r for r in store.rows() if r["status"] == "done"]
        paths = {r["run_id"]: p for r, p in zip(rows, _result_paths(store, rows, folder), strict=True)}
    finally:
        store.close()
    if not rows:
        raise BenchError(f"{db}: no finished run")
    imaging = {str(r["params"].get("sim.imaging", "realistic")) for r in rows}
    if len(imaging) != 1:
        raise BenchError(f"{db}: runs with different sim.imaging ({', '.join(sorted(imaging))}); one profile per sweep")
    runs, scenario = {}, None
    for r in rows:
        path = paths[r["run_id"]]
        try:
            result = json.loads(Path(path).read_text())
        except (OSError, ValueError) as e:
            raise BenchError(f"{path}: cannot read the run's result.json ({e})") from None
        table = result.get("tables", {}).get("position_error_vs_intraocular")
        if table is None:
            raise BenchError(f"{path}: no tables.position_error_vs_intraocular (not an xy_table run)")
        if scenario not in (None, result.get("scenario")):
            raise BenchError(f"{folder}: runs of two scenarios ({scenario}, {result.get('scenario')})")
        scenario = result.get("scenario")
        cells = {}
        for i, (m, d) in enumerate(zip(table["method"], table["d_mm"], strict=True)):
            cell = {f"err_{a}_mm": _num(table[f"err_{a}_mm"][i]) for a in AXES}
            cell.update({f"thesis_err_{a}_mm": _num(table[f"thesis_err_{a}_mm"][i]) for a in AXES})
            cell["table"] = _num(table["thesis_table"][i])
            cells[(m, float(d))] = cell
        runs[int(r["seed"])] = cells
    return {"scenario": scenario, "imaging": imaging.pop(), "runs": runs}


def _result_paths(store, rows, folder: Path) -> list:
    """The stored result paths; a moved sweep folder is found again through ``runs/<run_id>/result.json``."""
    cur = store.db.execute("SELECT run_id, result_path FROM runs")
    stored = dict(cur.fetchall())
    out = []
    for r in rows:
        p = Path(stored.get(r["run_id"]) or "")
        out.append(p if p.is_file() else folder / "runs" / r["run_id"] / "result.json")
    return out


def _num(v) -> float:
    return float("nan") if v is None else float(v)


def compare(realistic: dict, ideal: dict, min_d_mm: float = 40.0, factor: float = 2.5) -> list:
    """One row per (method, d_o, axis) with d_o >= ``min_d_mm`` where the thesis prints a value.

    Parameters
    ----------
    realistic, ideal : :func:`load_sweep` outputs of the same scenario.
    min_d_mm : smallest intraocular distance compared, mm.
    factor : the accepted ratio: ``1 / factor <= realistic / thesis <= factor``.

    Returns
    -------
    list of dicts: ``method``, ``table``, ``d_mm``, ``axis``, ``realistic_mm`` / ``ideal_mm`` (medians over the
    seeds, NaN-ignoring), ``seeds_realistic`` / ``seeds_ideal`` (seeds with a finite value), ``thesis_mm``,
    ``ratio`` (realistic / thesis) and ``within`` (bool).
    """
    if realistic["scenario"] != ideal["scenario"]:
        raise BenchError(f"realistic sweep is {realistic['scenario']}, ideal sweep is {ideal['scenario']}: "
                         "not the same scenario")
    for sweep, want in ((realistic, "realistic"), (ideal, "ideal")):
        if sweep.get("imaging", want) != want:
            raise BenchError(f"the {want} sweep's runs have sim.imaging={sweep['imaging']} (folders swapped?)")
    if not factor > 1.0:
        raise BenchError(f"--factor {factor}: must be > 1")
    keys = sorted({k for cells in realistic["runs"].values() for k in cells},
                  key=lambda k: (METHODS.index(k[0]) if k[0] in METHODS else len(METHODS), k[1]))
    out = []
    for m, d in keys:
        if m not in METHODS or d < min_d_mm - 1e-9:
            continue
        for a in AXES:
            col = f"err_{a}_mm"
            th = _first_finite(realistic["runs"], (m, d), f"thesis_{col}")
            if not math.isfinite(th):
                continue
            real = _values(realistic["runs"], (m, d), col)
            ide = _values(ideal["runs"], (m, d), col)
            med_r = float(np.median(real)) if real.size else float("nan")
            med_i = float(np.median(ide)) if ide.size else float("nan")
            ratio = med_r / th if th > 0 else float("nan")
            out.append({"method": m, "table": int(_first_finite(realistic["runs"], (m, d), "table")), "d_mm": d,
                        "axis": a, "realistic_mm": med_r, "ideal_mm": med_i, "seeds_realistic": int(real.size),
                        "seeds_ideal": int(ide.size), "thesis_mm": th, "ratio": ratio,
                        "within": bool(math.isfinite(ratio) and 1.0 / factor <= ratio <= factor)})
    return out


def _values(runs: dict, key, col) -> np.ndarray:
    v = np.array([cells[key][col] for cells in runs.values() if key in cells], float)
    return v[np.isfinite(v)]


def _first_finite(runs: dict, key, col) -> float:
    return next((cells[key][col] for cells in runs.values() if key in cells and math.isfinite(cells[key][col])),
                float("nan"))


def markdown(name: str, rows: list, factor: float) -> str:
    """The comparison of one setup as a markdown table: a row per (method, d_o), per axis realistic / ideal / thesis /
    ratio, and the count of axes within the factor."""
    if not rows:
        return f"**{name}**: no cell with a thesis value to compare.\n"
    seeds_r = sorted({r["seeds_realistic"] for r in rows})
    seeds_i = sorted({r["seeds_ideal"] for r in rows})
    n_in = sum(r["within"] for r in rows)
    lines = [f"**{name}** (medians over {_span(seeds_r)} realistic / {_span(seeds_i)} ideal seeds; mm; ratio = "
             f"realistic / thesis; within {factor:g}x: {n_in} of {len(rows)} axis cells)", ""]
    head = "| thesis table, method | d_o (mm) |" + "".join(f" {a} realistic | {a} ideal | {a} thesis | {a} ratio |"
                                                         for a in AXES)
    lines += [head + f" within {factor:g}x (x y z) |", "|" + "---|" * (2 + 4 * len(AXES) + 1)]
    by_cell: dict = {}
    for r in rows:
        by_cell.setdefault((r["method"], r["d_mm"]), {})[r["axis"]] = r
    for (m, d), axes in by_cell.items():
        first = next(iter(axes.values()))
        line = f"| {first['table']} {LABELS[m]} | {d:g} |"
        marks = []
        for a in AXES:
            if a not in axes:
                line += " | | | |"
                marks.append("-")
                continue
            r = axes[a]
            line += (f" {_fmt(r['realistic_mm'])} | {_fmt(r['ideal_mm'])} | {_fmt(r['thesis_mm'])} |"
                     f" {_fmt(r['ratio'], 2)} |")
            marks.append("yes" if r["within"] else "**no**")
        lines.append(line + " " + " ".join(marks) + " |")
    lines.append("")
    summary = []
    for m in METHODS:
        for a in AXES:
            sel = [r for r in rows if r["method"] == m and r["axis"] == a]
            if sel:
                ratios = np.array([r["ratio"] for r in sel], float)
                summary.append(f"{LABELS[m]} {a}: {sum(r['within'] for r in sel)}/{len(sel)}, median ratio "
                               f"{_fmt(float(np.nanmedian(ratios)), 2)}")
    lines.append("Per estimator and axis (cells within, median ratio): " + "; ".join(summary) + ".")
    return "\n".join(lines) + "\n"


def _span(values) -> str:
    return f"{values[0]}" if len(values) == 1 else f"{values[0]}-{values[-1]}"


def _fmt(v: float, digits: int = 1) -> str:
    return "n/a" if not math.isfinite(v) else f"{v:.{digits}f}" if abs(v) >= 0.095 else f"{v:.2f}"


def write_doc(page: Path, block: str) -> bool:
    """Replace the text between the markers of ``page`` by ``block``; False (page untouched) without markers."""
    text = page.read_text()
    if BEGIN not in text or END not in text or text.index(END) < text.index(BEGIN):
        return False
    page.write_text(text[:text.index(BEGIN)] + BEGIN + "\n" + block + END + text[text.index(END) + len(END):])
    return True


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--setup", nargs=3, action="append", required=True, metavar=("NAME", "REALISTIC", "IDEAL"),
                    help="a name and the realistic and the ideal sweep folders of one xy_table scenario")
    ap.add_argument("--min-d-mm", type=float, default=40.0, help="smallest d_o compared, mm (default 40)")
    ap.add_argument("--factor", type=float, default=2.5, help="accepted ratio to the thesis (default 2.5)")
    ap.add_argument("--doc", type=Path, help="markdown page with the markers (default: print only)")
    ap.add_argument("--json", type=Path, help="also write every row as JSON")
    args = ap.parse_args(argv)
    cmd = "`.venv/bin/python tools/xy_table_vs_thesis.py " + " ".join(
        f"--setup {n} {r} {i}" for n, r, i in args.setup) + f" --min-d-mm {args.min_d_mm:g} --factor {args.factor:g}`"
    try:
        parts, everything = [f"*{cmd}*\n"], {}
        for name, real_dir, ideal_dir in args.setup:
            real, ideal = load_sweep(real_dir), load_sweep(ideal_dir)
            rows = compare(real, ideal, args.min_d_mm, args.factor)
            everything[name] = rows
            parts.append(markdown(f"{name} ({real['scenario']})", rows, args.factor))
        block = "\n".join(parts)
        if args.doc is not None and not args.doc.is_file():
            raise BenchError(f"--doc {args.doc}: no such file")
    except BenchError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(block)
    if args.json is not None:
        args.json.write_text(json.dumps(everything, indent=1))
    if args.doc is not None and not write_doc(args.doc, block):
        print(f"{args.doc}: no {BEGIN} ... {END} block; not updated", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
