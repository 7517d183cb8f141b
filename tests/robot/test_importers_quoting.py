"""Importers read their files as CSV: a quoted field may hold the delimiter (a note, a header name)."""

import numpy as np
import pytest

from bench.errors import ConfigError
from bench.robot.importers import import_joints, import_tracker

Q_DEG = np.array([[10.5, 20.25, 30.0, -40.0, 50.0, -60.0],
                  [11.5, 21.25, 31.0, -41.0, 51.0, -61.0],
                  [12.5, 22.25, 32.0, -42.0, 52.0, -62.0]])
P_MM = np.array([[1200.5, -300.25, 450.0], [1800.0, 250.5, 900.75], [2100.25, 600.0, -150.5]])


def _rows(sep, names, *blocks, decimal=".", note=None):
    out = []
    for i, name in enumerate(names):
        cells = [name, *(repr(float(v)).replace(".", decimal) for b in blocks for v in b[i])]
        if note is not None:
            cells.append(note[i])
        out.append(sep.join(cells))
    return "\n".join(out) + "\n"


def _joints_out(path):
    lines = path.read_text().splitlines()
    return [ln.split(",")[0] for ln in lines[1:]], np.array([[float(v) for v in ln.split(",")[1:]] for ln in lines[1:]])


def test_a_quoted_note_holding_the_delimiter_stays_one_field(tmp_path):
    notes = ['"moved, then settled"', "ok", '"re-taught, twice, by hand"']
    src = tmp_path / "log.csv"
    src.write_text("view,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,note\n"
                   + _rows(",", ["v1", "v2", "v3"], Q_DEG, note=notes))
    res = import_joints(src, tmp_path / "joints.csv")
    names, q = _joints_out(res.path)
    assert res.rows == 3 and names == ["v1", "v2", "v3"] and np.array_equal(q, Q_DEG)


def test_quoted_header_names_and_keys_holding_the_delimiter(tmp_path):
    # semicolons between fields, decimal commas, and header names that hold a comma: the quotes tell the delimiter
    head = '"Point, name";"X [mm]";"Y [mm]";"Z [mm]";' + ";".join(f'"J{i} [deg]"' for i in range(1, 7))
    src = tmp_path / "export.csv"
    src.write_text(head + "\n" + _rows(";", ['"P1; left"', "P2", "P3"], P_MM, Q_DEG, decimal=","))
    res = import_tracker(src, tmp_path / "tracker.csv")
    assert res.units == {"length": "mm", "angle": "deg"}
    lines = res.path.read_text().splitlines()
    assert [ln.split(",")[0] for ln in lines[1:]] == ["P1; left", "P2", "P3"]
    got = np.array([[float(v) for v in ln.rsplit(",", 9)[1:]] for ln in lines[1:]])
    assert np.array_equal(got, np.hstack([P_MM, Q_DEG]))


def test_whitespace_separated_with_a_quoted_name(tmp_path):
    src = tmp_path / "log.txt"
    src.write_text("# angle units: deg\n" + _rows("   ", ['"view one"', "v2", "v3"], Q_DEG))
    res = import_joints(src, tmp_path / "joints.csv")
    names, q = _joints_out(res.path)
    assert names == ["view one", "v2", "v3"] and np.array_equal(q, Q_DEG)


def test_a_quoted_field_too_large_is_a_one_line_error(tmp_path):
    src = tmp_path / "log.csv"
    src.write_text("view,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg\n" + _rows(",", ["v1", "v2"], Q_DEG)
                   + 'v3,"' + "x" * 200_000 + '",0,0,0,0,0\n')
    with pytest.raises(ConfigError, match=r"log\.csv: line 4: not a readable row \(field larger than field limit"):
        import_joints(src, tmp_path / "joints.csv")
