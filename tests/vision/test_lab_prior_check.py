"""tools/lab_prior_check.py: the lab's error under its priors - exact on a constructed lab, the squares' algebra,
and one-line refusals."""

import sys
from pathlib import Path

import numpy as np
import pytest

from bench.geometry.quaternion import rotation_vector_to_matrix
from bench.geometry.transforms import homogeneous
from bench.robot.model import default_robot_path, load_robot, random_errors

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tools"))
import lab_prior_check as L  # noqa: E402


def test_lab_error_is_the_calibration_minus_the_truth():
    rng = np.random.default_rng(3)
    robot = load_robot(default_robot_path())
    eps = random_errors(rng)
    K_t = np.array([[800.0, 0, 320], [0, 790, 240], [0, 0, 1]])
    d_t = np.array([-0.1, 0.05, 1e-3, -1e-3, 0.0])
    M_t = homogeneous(rotation_vector_to_matrix([0.0, 0.0, np.pi]), [0.12, 0.0, 0.3])
    views = {f"v{i}": {"role": r, "q_true": rng.uniform(-1, 1, 6).tolist()}
             for i, r in enumerate(["reference", "surround", "locate", "rig"])}
    truth = {"camera_K": K_t.tolist(), "camera_dist": d_t.tolist(), "T_link5_cam": M_t.tolist(),
             "errors": eps.tolist(), "views": views}
    e = np.r_[3.0, -2.0, 1.5, 0.5, 0.01, -0.02, 1e-4, 2e-4, 1e-3, -2e-3, 5e-4, 4e-3, -2e-3, 6e-3]
    K = K_t.copy()
    K[0, 0], K[1, 1], K[0, 2], K[1, 2] = K_t[0, 0] + e[0], K_t[1, 1] + e[1], K_t[0, 2] + e[2], K_t[1, 2] + e[3]
    M_cal = M_t @ homogeneous(rotation_vector_to_matrix(e[8:11]), e[11:])  # calibrated = true exp(e)
    got = L.lab_error(truth, K, d_t + np.r_[e[4:8], 0.0], robot, eps, M_cal, 14)
    assert np.allclose(got, e, atol=1e-12)
    assert np.allclose(L.lab_error(truth, K, d_t, robot, eps, M_cal, 10), np.r_[e[:4], e[8:]], atol=1e-12)
    A = rng.normal(size=(14, 14))
    C = A @ A.T + 14 * np.eye(14)
    sq = L.squares(e, C)
    assert sq["all"] == pytest.approx(e @ np.linalg.solve(C, e), rel=1e-12)
    assert sq["intrinsics"] + sq["lens"] + sq["mount"] == pytest.approx(sq["blocks apart"], rel=1e-12)


def test_lab_prior_check_refuses_what_it_cannot_check(tmp_path, capsys):
    assert L.main([str(tmp_path)]) == 2
    assert "not a bench sweep folder" in capsys.readouterr().err
    run = tmp_path / "runs" / "r1"
    (run / "dataset" / "truth").mkdir(parents=True)
    (run / "calibrated").mkdir()
    (run / "calibrated" / "calibration_priors.yaml").write_text("{}\n")
    (run / "dataset" / "truth" / "truth.yaml").write_text("water: coastal\n")  # in water: no truth to check
    assert L.check_run(run) is None
    assert L.main([str(tmp_path)]) == 2
    assert "camera in air" in capsys.readouterr().err
