"""CI check of issue 12: the realistic imaging profile's calibration residuals have the real webcam photos'
statistics, within loose bounds. The same code computes both: ``tools/real_camera_stats.residual_statistics`` on the
multi-view Heikkilä calibration of (a) the 19 real photos (tests/data/real_webcam_chessboard, 7 x 7 corners) and (b)
a small realistic ``camera_calibration_webcam`` run (seven rig views; each 6 x 6-corner board of each view is one
grid, rows along the printed rows). The statistics: RMS (px), the neighbour correlation of residual vectors along a
board row (lag 1: the real photos' residual is row-correlated, 0.68), and the per-view RMS spread (std / mean)."""

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mujoco")

from bench.camera.calibrate_dataset import detect_dataset_corners  # noqa: E402
from bench.camera.calibration import calibrate_camera  # noqa: E402
from bench.scenario.runner import run_scenario_file  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("real_camera_stats", ROOT / "tools" / "real_camera_stats.py")
stats = importlib.util.module_from_spec(spec)
spec.loader.exec_module(stats)
WEBCAM = ROOT / "scenarios" / "camera_calibration_webcam.yaml"


def rig_grids(X, r) -> list:
    """The residuals ``(72, 2)`` of one rig view as two row-major ``(36, 2)`` board grids: board A (rig y = 0) and
    board B (rig x = 0), rows by height (rig z, top first), then across the board."""
    X, r = np.asarray(X, float), np.asarray(r, float)
    out = []
    for axis in (1, 0):
        on = np.isclose(X[:, axis], 0.0, atol=1e-9)
        order = np.lexsort((X[on, 1 - axis], -X[on, 2]))
        out.append(r[on][order])
    return out


def test_rig_grids_orders_rows_and_columns():
    from bench.sim.scenes.rig import calibration_rig

    X = calibration_rig().features["corners"]
    grids = rig_grids(X, X[:, [0, 2]] + X[:, [1, 2]])  # a "residual" (x + y, 2 z) that encodes the position
    for g in grids:
        g = g.reshape(6, 6, 2)
        assert np.all(np.diff(g[:, 0, 1]) < 0)  # rows: height decreases
        assert np.all(np.diff(g[0, :, 0]) > 0)  # along a row: across the board
        assert np.allclose(g[:, :, 1], g[:, :1, 1])  # one height per row


def test_realistic_residual_statistics_resemble_the_real_photos(tmp_path):
    views = stats.detect(sorted((ROOT / "tests" / "data" / "real_webcam_chessboard").glob("*.jpg")), (7, 7))
    res, _ = stats.calibrate(views, (7, 7))
    real = stats.residual_statistics(res.residuals_px, (7, 7))
    assert real["rms_px"] == pytest.approx(0.557, abs=0.005) and real["row_corr_lag1"] == pytest.approx(0.68, abs=0.02)

    path = run_scenario_file(WEBCAM, out=tmp_path / "run", seed=1, verbose=False, quiet=True,
                             overrides=["camera.supersample=2", "pipeline.compare_extractors=false",
                                        "outputs.plots=false", "outputs.rerun=false", "outputs.cache=false"])
    assert json.loads(Path(path).read_text())["metrics"]["reproj_rms_px"] > 0.1  # realistic: not the ideal 0.01
    det = detect_dataset_corners(tmp_path / "run" / "dataset", "opencv")
    cal = calibrate_camera(det.object_points, det.image_points, det.image_size, "heikkila")
    assert cal.success, cal.message
    grids = [g for X, r in zip(det.object_points, cal.residuals_px, strict=True) for g in rig_grids(X, r)]
    sim = stats.residual_statistics(grids, (6, 6))
    # loose bounds: magnitude within a factor 3, the row correlation within 0.3, the per-view spread within 4x
    assert real["rms_px"] / 3 < sim["rms_px"] < real["rms_px"] * 3, sim["rms_px"]
    assert abs(sim["row_corr_lag1"] - real["row_corr_lag1"]) < 0.3, sim["row_corr_lag1"]
    assert real["per_view_rms_cv"] / 4 < sim["per_view_rms_cv"] < real["per_view_rms_cv"] * 4, sim["per_view_rms_cv"]
    # the ideal chain's residual is neither large nor row-correlated like a real camera's: the check can fail
    assert sim["row_corr_lag1"] > 0.4
