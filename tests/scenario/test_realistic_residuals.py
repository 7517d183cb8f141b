"""CI check of issue 12: the realistic imaging profile's calibration residuals have the real webcam photos'
statistics, within loose bounds. ``tools/real_webcam_sim.py`` renders the real photos' board at their 19 poses
through the realistic chain (their calibrated camera, a printed 8 x 8-square board with the realistic target
errors); the real photos and the renders are detected, calibrated (Heikkilä) and summarised by the same code
(``tools/real_camera_stats.residual_statistics``): RMS (px), the neighbour correlation of residual vectors along a
board row (lag 1: the real photos' residual is row-correlated, 0.68) and the per-view RMS spread (std / mean).
Measured (5 seeds, supersample 3, docs/realistic_imaging.md): RMS 0.25-0.42 px against the real 0.557 px, row
correlation 0.80-0.95 against 0.68."""

import importlib.util
from pathlib import Path

import pytest

pytest.importorskip("mujoco")

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("real_webcam_sim", ROOT / "tools" / "real_webcam_sim.py")
rws = importlib.util.module_from_spec(spec)
spec.loader.exec_module(rws)


@pytest.fixture(scope="module")
def real():
    return rws.real_calibration()[0]


def test_board_poses_put_the_sim_corners_where_the_calibration_has_the_real_ones(real):
    import numpy as np

    from bench.sim.scenes.rig import planar_board

    res = real
    s = 0.025
    corners = planar_board(8, 8, s).features["corners"]  # sim board frame, m
    obj = np.zeros((49, 3))
    obj[:, :2] = np.mgrid[0:7, 0:7].T.reshape(-1, 2)  # the calibration's unit squares
    for T_cb, T_ct in zip(rws.board_poses(res, s), res.T_cam_target, strict=True):
        a = corners @ T_cb[:3, :3].T + T_cb[:3, 3]
        b = (obj @ T_ct[:3, :3].T + T_ct[:3, 3]) * s
        assert np.allclose(a, b, atol=1e-12)


def test_realistic_residual_statistics_resemble_the_real_photos(real):
    res = real
    real = rws.rcs.residual_statistics(res.residuals_px, rws.PATTERN)
    assert real["rms_px"] == pytest.approx(0.557, abs=0.005) and real["row_corr_lag1"] == pytest.approx(0.68, abs=0.02)
    sim = rws.simulate(res, seed=1, square_m=0.025, supersample=2)
    assert sim["views"] == 19
    # loose bounds: magnitude within a factor 3, the row correlation within 0.3, the per-view spread within 4x
    assert real["rms_px"] / 3 < sim["rms_px"] < real["rms_px"] * 3, sim["rms_px"]
    assert abs(sim["row_corr_lag1"] - real["row_corr_lag1"]) < 0.3, sim["row_corr_lag1"]
    assert real["per_view_rms_cv"] / 4 < sim["per_view_rms_cv"] < real["per_view_rms_cv"] * 4, sim["per_view_rms_cv"]
