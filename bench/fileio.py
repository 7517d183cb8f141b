"""Atomic file writing shared by the pipeline and the bench: a temporary file in the same folder, then a rename."""

from __future__ import annotations

import csv
import io
import math
import os
import tempfile
from pathlib import Path


def atomic_write_text(path, text: str) -> None:
    """Write ``text`` to ``path`` via a temporary file in the same folder and an atomic rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _clean(value):
    if hasattr(value, "item"):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
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
