"""``result.json`` (see ``shared/design.md``) and its tables, written atomically so no half-written file is left."""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path

from bench.fileio import atomic_write_text


def _clean(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if hasattr(value, "item"):
        return _clean(value.item())
    return value


def write_table_csv(path, table: dict) -> None:
    """Write ``{column: [values]}`` as CSV."""
    buf = io.StringIO()
    w = csv.writer(buf)
    cols = list(table)
    w.writerow(cols)
    for row in zip(*(table[c] for c in cols), strict=True):
        w.writerow([_clean(v) for v in row])
    atomic_write_text(path, buf.getvalue())


def write_result(out_dir, scenario: str, seed: int, metrics: dict, tables: dict, timings_s: dict,
                 artifacts: dict) -> Path:
    """Write ``out_dir/result.json`` with the contract's keys; non-finite numbers become ``null``."""
    doc = {
        "scenario": scenario,
        "seed": int(seed),
        "metrics": {k: _clean(float(v)) for k, v in metrics.items()},
        "tables": {name: {c: [_clean(v) for v in vals] for c, vals in t.items()} for name, t in tables.items()},
        "timings_s": {k: _clean(float(v)) for k, v in timings_s.items()},
        "artifacts": {k: str(v) for k, v in artifacts.items()},
    }
    path = Path(out_dir) / "result.json"
    atomic_write_text(path, json.dumps(doc, indent=2) + "\n")
    return path
