"""The real TIAGo session (issue 16's development session, tests/data/tiago_mocap/): ``bench calibrate-robot --urdf``
with its defaults and ``bench check-robot`` on real motion-capture data. Needs the TIAGo URDF of the installed
``example-robot-data`` package (in the ``dev`` group: ``make test`` installs it); without it the tests fail, naming
it."""

import json
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest

from bench.cli import main
from bench.robot.marker_calibration import identify, parse_points, predict, read_measurements
from bench.robot.urdf import load_urdf_chain

SESSION = Path(__file__).resolve().parents[1] / "data" / "tiago_mocap" / "qualisys_2021-11-30_static_postures.csv"


def _urdf():
    try:
        files = metadata.files("example-robot-data") or []
    except metadata.PackageNotFoundError:
        pytest.fail("example-robot-data not installed (pip install -e '.[dev]'): no nominal TIAGo model")
    for f in files:
        if str(f).endswith("tiago_description/robots/tiago.urdf"):
            return Path(f.locate())
    pytest.fail("example-robot-data has no tiago_description/robots/tiago.urdf")


def test_cli_defaults_on_the_real_session(tmp_path, capsys):
    urdf = _urdf()
    argv = ["calibrate-robot", "--urdf", str(urdf), "--base-link", "base_footprint", "--tip-link",
            "wrist_ft_tool_link", "--measurements", str(SESSION), "--points", "x1,y1,z1", "--units", "m",
            "--joint-units", "rad", "--out", str(tmp_path / "cal")]
    assert main(argv) == 0
    rep = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    assert rep["n_postures"] == 37 and 3.2 < rep["rms_nominal_mm"] < 3.5  # registration on the nominal URDF
    assert rep["rms_mm"] < 1.4 and set(rep["compliance_rad_per_nm"]) >= {"arm_2_joint", "arm_4_joint"}
    assert main(["check-robot", "--robot", str(tmp_path / "cal" / "robot.yaml"), "--measurements", str(SESSION),
                 "--out", str(tmp_path / "chk")]) == 0
    chk = json.loads((tmp_path / "chk" / "check.json").read_text())
    assert abs(chk["rms_mm"] - rep["rms_mm"]) < 1e-9  # everything frozen: the same model
    # the plate: four markers, their geometry estimated (rigid: the fitted offsets keep the measured distances)
    assert main(argv[:-2] + ["--points", "x2,y2,z2", "--points", "x3,y3,z3", "--points", "x4,y4,z4",
                             "--out", str(tmp_path / "plate")]) == 0
    plate = json.loads((tmp_path / "plate" / "calibration.json").read_text())
    assert plate["n_markers"] == 4 and plate["rms_mm"] < 2.5
    assert main(["check-robot", "--robot", str(tmp_path / "plate" / "robot.yaml"), "--measurements", str(SESSION),
                 "--points", "x1,y1,z1", "--out", str(tmp_path / "chk1")]) == 0  # marker 1 of the plate alone
    chk1 = json.loads((tmp_path / "chk1" / "check.json").read_text())
    assert chk1["n_markers"] == 1 and abs(chk1["rms_mm"] - plate["rms_first_marker_mm"]) < 1e-9
    import yaml

    U = np.array([m["offset_mm"] for m in yaml.safe_load((tmp_path / "plate" / "robot.yaml").read_text())[
        "calibration"]["markers"]])
    chain = load_urdf_chain(urdf, "base_footprint", "wrist_ft_tool_link")
    P = read_measurements(SESSION, chain, parse_points(["x1,y1,z1", "x2,y2,z2", "x3,y3,z3", "x4,y4,z4"])).P * 1e3
    for a, b in ((0, 1), (0, 2), (1, 3), (2, 3)):
        measured = np.linalg.norm(P[:, a] - P[:, b], axis=-1).mean()
        assert abs(np.linalg.norm(U[a] - U[b]) - measured) < 1.0  # mm
    capsys.readouterr()


def test_three_fold_cross_validation_beats_the_geometric_model():
    """Held-out postures (3 folds of 12-13): the default model (2 mm / 1 deg prior + compliance under gravity) errs
    less than hard elimination of the unidentifiable errors without compliance (FIGAROH's kind of model)."""
    urdf = _urdf()
    chain = load_urdf_chain(urdf, "base_footprint", "wrist_ft_tool_link")
    meas = read_measurements(SESSION, chain, parse_points(["x1,y1,z1"]))
    folds = np.array_split(np.random.default_rng(16).permutation(len(meas.q)), 3)
    rms = {}
    for label, kw in {"reduced": {"model": "reduced"}, "default": {"model": "prior", "compliance": True}}.items():
        err = []
        for f in folds:
            cal = identify(chain, meas.subset(np.setdiff1d(np.arange(len(meas.q)), f)), weights="none", **kw)
            err += list(np.linalg.norm(predict(chain, meas.q[f], cal.eps, cal.T_meas_base, cal.U, cal.compliance)
                                       - meas.P[f], axis=-1)[:, 0])
        rms[label] = float(np.sqrt(np.mean(np.square(err))))
    assert rms["default"] < 0.8 * rms["reduced"], rms
