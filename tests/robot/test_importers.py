"""Importers of laser-tracker exports and joint logs: units stated, checked, and every bad file a one-line error."""

import numpy as np
import pytest

from bench.cli import main
from bench.dataset import DatasetWriter, load_dataset
from bench.errors import ConfigError
from bench.robot.importers import import_joints, import_tracker

RNG = np.random.default_rng(404)
Q_DEG = RNG.uniform([-10, 0, 10, -180, -105, -180], [90, 110, 170, 180, 105, 180], (5, 6)).round(4)
P_MM = RNG.uniform([800, -900, -200], [2600, 900, 1800], (5, 3)).round(3)
NAMES = [f"T{i}" for i in range(1, 6)]


def write(path, text):
    path.write_text(text)
    return path


def csv_rows(names, *blocks, sep=",", fmt=repr):
    return "".join(sep.join([n, *(fmt(float(v)) for b in blocks for v in b[i])]) + "\n"
                   for i, n in enumerate(names))


def test_tracker_in_metres_with_joint_log_in_radians_round_trips_through_the_dataset(tmp_path):
    rows = "".join(f"A,{n},{x / 1e3},{y / 1e3},{z / 1e3},0.01\n" for n, (x, y, z) in zip(NAMES, P_MM.tolist(),
                                                                                         strict=True))
    trk = write(tmp_path / "leica.csv", "# tracker software export\nCollection,Point Name,X,Y,Z,Sigma\n" + rows)
    log = write(tmp_path / "log.csv", "name;J1 [rad];J2 [rad];J3 [rad];J4 [rad];J5 [rad];J6 [rad]\n"
                + csv_rows(NAMES[::-1], np.deg2rad(Q_DEG[::-1]), sep=";", fmt=lambda v: repr(v).replace(".", ",")))
    res = import_tracker(trk, tmp_path / "out" / "tracker.csv", units="m", joints=log)
    assert res.rows == 5 and res.units == {"length": "m", "angle": "rad"}
    with DatasetWriter(tmp_path / "ds", kind="kinematic") as w:
        w.write_text("tracker.csv", res.path.read_text())
    tr = load_dataset(tmp_path / "ds").tracker
    assert tr["point"] == NAMES
    assert np.abs(tr["p"] - P_MM * 1e-3).max() <= 1e-15 and np.abs(tr["q"] - np.deg2rad(Q_DEG)).max() <= 1e-15


def test_units_in_column_names_and_joints_in_the_same_file(tmp_path):
    header = "point,x_mm,y_mm,z_mm," + ",".join(f"q{i}_deg" for i in range(1, 7)) + "\n"
    trk = write(tmp_path / "t.csv", header + csv_rows(NAMES, P_MM, Q_DEG))
    res = import_tracker(trk, tmp_path / "tracker.csv")
    assert res.units == {"length": "mm", "angle": "deg"}
    assert res.path.read_text() == trk.read_text()  # already in the dataset's units: numbers carried unchanged


def test_headerless_files_and_declared_units(tmp_path):
    trk = write(tmp_path / "t.txt", "# units: mm\n# angle units: deg\n" +
                csv_rows(NAMES, P_MM, Q_DEG, sep="\t"))
    import_tracker(trk, tmp_path / "tracker.csv")
    log = write(tmp_path / "j.txt", "".join(" ".join(repr(float(v)) for v in q) + "\n" for q in Q_DEG))
    res = import_joints(log, tmp_path / "joints.csv", units="deg")
    lines = res.path.read_text().splitlines()
    assert lines[0] == "view,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg" and lines[1].startswith("view001,")
    with DatasetWriter(tmp_path / "ds", kind="in_situ") as w:
        for i in range(5):
            w.add_view(f"view{i + 1:03d}", np.zeros((4, 4, 3), np.uint8))
        w.write_text("joints.csv", res.path.read_text())
    ds = load_dataset(tmp_path / "ds")
    assert np.abs(ds.joint_readings() - np.deg2rad(Q_DEG)).max() <= 1e-15


JH = ",".join(f"q{i}" for i in range(1, 7))
GOOD_J = "view," + JH + "\n" + csv_rows(NAMES, Q_DEG)
GOOD_T = "point,x,y,z\n" + csv_rows(NAMES, P_MM)

# (case, importer, file text, kwargs, expected message after "<file>: ")
BAD = [
    ("rad_holding_degrees", "joints", "view," + JH + "\n" + csv_rows(NAMES, Q_DEG), {"units": "rad"},
     r"line 2, column q1: .* rad is more than one turn .*degrees given as radians"),
    ("deg_holding_radians", "joints", GOOD_J.replace(GOOD_J.split("\n", 1)[1], csv_rows(NAMES, np.deg2rad(Q_DEG))),
     {"units": "deg"}, r"columns q1, .*q6: every reading lies within \+-pi .* radians given as degrees"),
    ("deg_beyond_a_turn", "joints", GOOD_J.replace(repr(float(Q_DEG[2, 3])), "1234.5"), {"units": "deg"},
     r"line 4, column q4: 1234.5 deg is more than one turn"),
    ("m_holding_mm", "tracker", GOOD_T, {"units": "m"},
     r"line 2, column x: .* m is beyond a laser tracker's range .*millimetres given as metres"),
    ("mm_holding_m", "tracker", "point,x,y,z\n" + csv_rows(NAMES, P_MM / 1e3), {"units": "mm"},
     r"lines 2-6, columns x, y, z: the 5 points span only .* mm .*metres given as millimetres"),
    ("nan_value", "joints", GOOD_J.replace(repr(float(Q_DEG[1, 4])), "nan"), {"units": "deg"},
     r"line 3, column q5: NaN or inf"),
    ("inf_value", "tracker", GOOD_T.replace(repr(float(P_MM[3, 2])), "-inf"), {"units": "mm"},
     r"line 5, column z: NaN or inf"),
    ("text_value", "tracker", GOOD_T.replace(repr(float(P_MM[0, 1])), "12O4.5"), {"units": "mm"},
     r"line 2, column y: not a number: '12O4.5'"),
    ("truncated_row", "joints", GOOD_J.rsplit(",", 2)[0] + "\n", {"units": "deg"},
     r"line 6, column q5: missing \(truncated row: 5 of 7 fields\)"),
    ("extra_field", "joints", GOOD_J.replace("\nT3,", "\nT3,0.5,"), {"units": "deg"},
     r"line 4: 8 fields, the header has 7"),
    ("unit_not_stated", "joints", GOOD_J, {}, r"units: the angle unit is not stated: pass --units deg\|rad"),
    ("unit_stated_twice", "tracker", GOOD_T.replace("x,y,z", "x_mm,y_mm,z_mm"), {"units": "m"},
     r"units: stated twice and differently: mm \(column 'x_mm'\), m \(--units\)"),
    ("mixed_column_units", "tracker", GOOD_T.replace("x,y,z", "x_mm,y_m,z_mm"), {},
     r"line 1: columns in different units"),
    ("length_unit_on_a_joint", "joints", GOOD_J.replace("q3", "q3_mm"), {},
     r"column 'q3_mm': mm is not a unit of angle"),
    ("unknown_declared_unit", "tracker", "# units: inch\n" + GOOD_T, {}, r"line 1: unknown unit 'inch'"),
    ("duplicate_name", "tracker", GOOD_T.replace("T4,", "T2,"), {"units": "mm"},
     r"line 5: duplicate name 'T2' \(first on line 3\)"),
    ("empty_name", "joints", GOOD_J.replace("T5,", ","), {"units": "deg"}, r"line 6, column view: empty name"),
    ("missing_column", "tracker", GOOD_T.replace("x,y,z", "x,y,height"), {"units": "mm"},
     r"line 1: column z missing"),
    ("duplicate_column", "joints", GOOD_J.replace("q6", "q5"), {"units": "deg"},
     r"line 1, column 'q5': duplicate of column 'q5'"),
    ("no_joint_readings", "tracker", GOOD_T, {"units": "mm"}, r"<header>: no joint readings .*--joints"),
    ("headerless_wrong_count", "joints", "1,2,3,4,5\n", {"units": "deg"}, r"line 1: 5 fields and no header"),
    ("header_only", "joints", "view," + JH + "\n", {"units": "deg"}, r"<file>: a header but no data rows"),
    ("empty_file", "tracker", "\n \n", {"units": "mm"}, r"<file>: empty"),
    ("comments_only", "tracker", "# units: mm\n", {}, r"<file>: no data rows"),
]


@pytest.mark.parametrize("case, kind, text, kwargs, message", BAD, ids=[b[0] for b in BAD])
def test_bad_input_is_a_one_line_error_naming_file_row_and_column(tmp_path, case, kind, text, kwargs, message):
    src = write(tmp_path / f"{case}.csv", text)
    out = tmp_path / "out.csv"
    fn = import_tracker if kind == "tracker" else import_joints
    with pytest.raises(ConfigError, match=f"^{src}: {message}") as exc:
        fn(src, out, **kwargs)
    assert "\n" not in str(exc.value) and not out.exists()


def test_bad_files_and_joint_logs(tmp_path):
    out = tmp_path / "out.csv"
    with pytest.raises(ConfigError, match=r"missing\.csv: <file>: not found"):
        import_joints(tmp_path / "missing.csv", out, "deg")
    binary = tmp_path / "binary.csv"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\xff\xfe")
    with pytest.raises(ConfigError, match=r"binary\.csv: <file>: not a UTF-8 text file"):
        import_joints(binary, out, "deg")
    trk = write(tmp_path / "t.csv", GOOD_T)
    log = write(tmp_path / "log.csv", "view," + JH + "\n" + csv_rows(NAMES[:3], Q_DEG[:3]))
    with pytest.raises(ConfigError, match=r"log\.csv: point 'T4': no reading for the point on line 5 of .*t\.csv "
                                          r"\(2 of 5 points unmatched\)"):
        import_tracker(trk, out, "mm", joints=log, joint_units="deg")
    both = write(tmp_path / "both.csv", "point,x,y,z," + JH + "\n" + csv_rows(NAMES, P_MM, Q_DEG))
    with pytest.raises(ConfigError, match=r"both\.csv: columns q1, .*: joint readings both in the file and in"):
        import_tracker(both, out, "mm", joints=log, joint_units="deg")
    assert not out.exists()


def test_cli_imports_and_reports_one_line(tmp_path, capsys):
    trk = write(tmp_path / "t.csv", GOOD_T)
    log = write(tmp_path / "log.csv", GOOD_J)
    assert main(["import-tracker", str(trk), "--units", "mm", "--joints", str(log), "--joint-units", "deg",
                 "--out", str(tmp_path / "tracker.csv")]) == 0
    assert main(["import-joints", str(log), "--units", "deg", "--out", str(tmp_path / "joints.csv")]) == 0
    assert "wrote" in capsys.readouterr().out
    assert main(["import-joints", str(log), "--units", "rad", "--out", str(tmp_path / "bad.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"bench: error: {log}: line 2, column q1:") and len(err.splitlines()) == 1
    assert not (tmp_path / "bad.csv").exists()
