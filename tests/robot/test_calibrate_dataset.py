"""``bench calibrate-robot DATASET --out DIR``: the TA-40 tracker campaign of a dataset folder."""

import json
import shutil

import numpy as np
import pytest

from bench.cli import main
from bench.dataset import DatasetWriter
from bench.robot.calibration_file import load_calibrated_robot
from bench.robot.identifiability import closed_form_reduction
from bench.robot.kinematics import ee_position
from bench.robot.model import default_robot_path, random_errors


def _dataset(path, robot, rng, n=60, sigma=0.0, robot_file=True):
    eps = random_errors(rng)
    eps[36:] = 0.0  # Table 2: no errors in frame 6 (the 25-parameter model is then exact)
    q = robot.random_configurations(rng, n)
    p = ee_position(robot, q, eps) + rng.normal(0.0, sigma, (n, 3)) if sigma else ee_position(robot, q, eps)
    with DatasetWriter(path, kind="kinematic") as w:
        w.add_view("dummy", None, q=np.zeros(6))
        w.write_tracker([f"p{i:03d}" for i in range(n)], p, q)
        if robot_file:
            shutil.copyfile(default_robot_path(), w.path("robot.yaml"))
    return eps


def test_noise_free_campaign_reproduces_the_arm_on_heldout_postures(tmp_path, ta40, rng, capsys):
    eps = _dataset(tmp_path / "ds", ta40, rng)
    assert main(["calibrate-robot", str(tmp_path / "ds"), "--out", str(tmp_path / "cal")]) == 0
    assert "60 postures, 25 parameters" in capsys.readouterr().out
    rep = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    assert rep["n_postures"] == 60 and rep["n_parameters"] == 25 and len(rep["kept"]) == 25
    assert rep["rms_mm"] < 1e-6 and rep["rms_nominal_mm"] > 1.0
    assert np.array(rep["covariance"]).shape == (25, 25)
    assert set(rep["merged"]) == {n for n in (f"{k}{i}" for i in range(7) for k in "xyzsrp")} - {
        k["name"] for k in rep["kept"]}
    # the calibrated file: nominal model + errors, loadable as bench locate / bench export load it
    robot, eps_hat, mount = load_calibrated_robot(tmp_path / "cal" / "robot.yaml")
    assert mount is None
    qh = ta40.random_configurations(rng, 200)
    err = np.linalg.norm(ee_position(robot, qh, eps_hat) - ee_position(ta40, qh, eps), axis=1)
    assert err.max() < 1e-9
    red = closed_form_reduction(ta40)
    assert np.abs(red.reduce(eps_hat) - red.reduce(eps)).max() < 5e-4  # first order, Table 2's 25 parameters
    assert main(["export", str(tmp_path / "cal" / "robot.yaml"), "--format", "urdf",
                 "--out", str(tmp_path / "arm.urdf")]) == 0


def test_default_robot_is_the_ta40_and_noise_gives_a_consistent_chi2(tmp_path, ta40, rng):
    _dataset(tmp_path / "ds", ta40, rng, n=100, sigma=5e-5, robot_file=False)
    assert main(["calibrate-robot", str(tmp_path / "ds"), "--out", str(tmp_path / "cal"), "--sigma-mm", "0.05"]) == 0
    rep = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    assert rep["nominal_robot"].endswith("ta40.yaml")
    assert 0.7 < rep["chi2_per_dof"] < 1.3
    assert 0.07 < rep["rms_mm"] < 0.095  # 3D distance: sqrt(3 (1 - 25 / 300)) * 0.05 mm = 0.083 mm
    assert len(rep["per_posture"]) == 100


def test_bad_inputs_are_one_line_errors(tmp_path, ta40, rng, capsys):
    _dataset(tmp_path / "ds", ta40, rng, n=30)
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / "notes.txt").write_text("mine")
    (tmp_path / "file").write_text("x")
    cases = [
        ([str(tmp_path / "ds"), "--out", str(tmp_path / "foreign")], "notes.txt"),
        ([str(tmp_path / "ds"), "--out", str(tmp_path / "file")], "file"),
        ([str(tmp_path / "ds"), "--out", str(tmp_path / "o1"), "--sigma-mm", "0"], "--sigma-mm"),
        ([str(tmp_path / "nope"), "--out", str(tmp_path / "o2")], "nope"),
        ([str(tmp_path / "ds"), "--points", "x1,y1,z1", "--out", str(tmp_path / "o2")], "--urdf mode"),
    ]
    for argv, word in cases:
        assert main(["calibrate-robot", *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and word in err, err
    assert (tmp_path / "foreign" / "notes.txt").read_text() == "mine"
    # a dataset without a tracker campaign; tracker points in mm where the file says... metres (x1000)
    with DatasetWriter(tmp_path / "nt", kind="kinematic") as w:
        w.add_view("v", None, q=np.zeros(6))
    assert main(["calibrate-robot", str(tmp_path / "nt"), "--out", str(tmp_path / "o3")]) == 2
    assert "tracker.csv" in capsys.readouterr().err
    q = ta40.random_configurations(rng, 30)
    with DatasetWriter(tmp_path / "big", kind="kinematic") as w:
        w.add_view("v", None, q=np.zeros(6))
        w.write_tracker([f"p{i}" for i in range(30)], ee_position(ta40, q) * 1e3, q)
    assert main(["calibrate-robot", str(tmp_path / "big"), "--out", str(tmp_path / "o4")]) == 2
    err = capsys.readouterr().err
    assert "tracker.csv" in err and "mm given as m" in err
    # an earlier output of the command may be overwritten
    assert main(["calibrate-robot", str(tmp_path / "ds"), "--out", str(tmp_path / "o5")]) == 0
    assert main(["calibrate-robot", str(tmp_path / "ds"), "--out", str(tmp_path / "o5")]) == 0


@pytest.mark.parametrize("n", [5])
def test_too_few_postures_is_refused(tmp_path, ta40, rng, capsys, n):
    _dataset(tmp_path / "ds", ta40, rng, n=n)
    assert main(["calibrate-robot", str(tmp_path / "ds"), "--out", str(tmp_path / "cal")]) == 2
    assert "need at least 9 poses" in capsys.readouterr().err


def test_tracker_frame_estimated_from_any_rotation(tmp_path, ta40, rng, capsys):
    """tracker.csv in the tracker's own frame (turned by a random rotation, 3 m away): --tracker-frame estimate finds
    it with the errors; noise-free, the calibrated file and T_tracker_base reproduce held-out tracker points."""
    from bench.geometry.quaternion import quaternion_to_matrix
    from bench.geometry.transforms import homogeneous, random_rotation
    from bench.robot.chain import chain_from_dh
    from bench.robot.marker_calibration import identifiable_errors

    kept, _ = identifiable_errors(chain_from_dh(ta40), ta40.p_ee[None])
    eps = random_errors(rng)
    mask = np.zeros(ta40.n_errors, bool)
    mask[kept] = True
    eps[~mask] = 0.0  # truth in the identifiable set (as Table 2 draws none in frame 6)
    T = homogeneous(random_rotation(rng), rng.uniform(-3, 3, 3))
    q = ta40.random_configurations(rng, 60)
    with DatasetWriter(tmp_path / "ds", kind="kinematic") as w:
        w.add_view("dummy", None, q=np.zeros(6))
        w.write_tracker([f"p{i:03d}" for i in range(60)], ee_position(ta40, q, eps) @ T[:3, :3].T + T[:3, 3], q)
    assert main(["calibrate-robot", str(tmp_path / "ds"), "--out", str(tmp_path / "base")]) == 2  # not base frame
    assert "tracker.csv" in capsys.readouterr().err
    assert main(["calibrate-robot", str(tmp_path / "ds"), "--tracker-frame", "estimate", "--out",
                 str(tmp_path / "cal")]) == 0
    rep = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    # 25 of Table 2 less the base frame's 6 (now in T_tracker_base) and frame 6's 3 (the point): 16
    assert rep["rms_mm"] < 1e-6 and rep["n_parameters"] == 9 + len(kept) and len(kept) == 16
    fr = rep["T_tracker_base"]
    T_hat = homogeneous(quaternion_to_matrix(fr["quaternion_wxyz"]), np.array(fr["translation_mm"]) * 1e-3)
    robot, eps_hat, _ = load_calibrated_robot(tmp_path / "cal" / "robot.yaml")
    qh = ta40.random_configurations(rng, 100)
    pred = ee_position(robot, qh, eps_hat) @ T_hat[:3, :3].T + T_hat[:3, 3]
    assert np.abs(pred - (ee_position(ta40, qh, eps) @ T[:3, :3].T + T[:3, 3])).max() < 1e-9
