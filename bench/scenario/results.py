"""``result.json`` (see ``shared/design.md``) and its tables, written atomically so no half-written file is left."""

from __future__ import annotations

import json
from pathlib import Path

from bench.fileio import _clean, atomic_write_text, write_table_csv  # noqa: F401 - write_table_csv re-exported


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
