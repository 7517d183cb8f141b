"""``bench calibrate-camera`` on a dataset of synthetic planar-board views (exact pinhole images, no simulator)."""

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from bench.camera.io import read_camera_yaml
from bench.dataset import DatasetWriter
from bench.errors import ConfigError
from bench.geometry.transforms import homogeneous, rot_x, rot_y, rot_z

K_TRUE = np.array([[800.0, 0, 321.3], [0, 805.0, 238.7], [0, 0, 1]])
SQUARE = 0.03


def _board_view(T_cam_board, size=(640, 480), ss=4):
    """An anti-aliased 8x8-square board (7x7 inner corners) seen by K_TRUE: exact homography warp, supersampled."""
    tex_px = 40
    n = 8
    tex = np.kron((np.indices((n, n)).sum(0) % 2).astype(np.uint8) * 255, np.ones((tex_px, tex_px), np.uint8))
    tex = cv2.copyMakeBorder(tex, tex_px, tex_px, tex_px, tex_px, cv2.BORDER_CONSTANT, value=255)
    # texture pixel (i + 0.5 centre convention) -> board metres: corner (0,0) of the inner grid at texture 2*tex_px
    S = np.array([[SQUARE / tex_px, 0, -(2 * tex_px - 0.5) * SQUARE / tex_px],
                  [0, SQUARE / tex_px, -(2 * tex_px - 0.5) * SQUARE / tex_px], [0, 0, 1]])
    H = K_TRUE @ np.column_stack([T_cam_board[:3, 0], T_cam_board[:3, 1], T_cam_board[:3, 3]]) @ S
    Hs = np.diag([ss, ss, 1.0]) @ np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1]]) @ H
    Hs = np.array([[1, 0, -0.5], [0, 1, -0.5], [0, 0, 1]]) @ Hs
    big = cv2.warpPerspective(tex, Hs, (size[0] * ss, size[1] * ss), flags=cv2.INTER_LINEAR, borderValue=128)
    img = cv2.resize(big, size, interpolation=cv2.INTER_AREA)
    return np.repeat(img[..., None], 3, axis=2)


def _dataset(root, n_views=8, target="planar", tolerance=""):
    rng = np.random.default_rng(71)
    with DatasetWriter(root, kind="camera_calibration") as w:
        for k in range(n_views):
            R = rot_z(rng.uniform(-0.3, 0.3)) @ rot_x(rng.uniform(-0.5, 0.5)) @ rot_y(rng.uniform(-0.5, 0.5))
            t = np.array([rng.uniform(-0.11, -0.07), rng.uniform(-0.11, -0.07), rng.uniform(0.5, 0.65)])
            w.add_view(f"rig{k:02d}", _board_view(homogeneous(R, t)))
        w.write_text("target.yaml", f"type: {target}\ninner: [7, 7]\nsquare_mm: {SQUARE * 1e3}\n{tolerance}")


@pytest.mark.parametrize("extractor", ["opencv", "thesis"])
def test_calibrates_synthetic_board(tmp_path, extractor):
    _dataset(tmp_path / "ds")
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "bench", "calibrate-camera", str(tmp_path / "ds"), "--out", str(out),
                        "--model", "pinhole", "--extractor", extractor], capture_output=True, text=True,
                       cwd=Path(__file__).resolve().parents[2])
    assert r.returncode == 0, r.stderr
    cam = read_camera_yaml(out / "camera.yaml")
    rep = json.loads((out / "calibration.json").read_text())
    assert rep["reproj_rms_px"] < 0.1 and len(rep["views_used"]) >= 6
    assert abs(cam.fx / K_TRUE[0, 0] - 1) < 2e-3 and abs(cam.cy - K_TRUE[1, 2]) < 1.5
    assert rep["reproj_rms_px"] <= rep["opencv_rms_px"] + 1e-6
    assert (out / "per_view.csv").is_file() and (out / "residuals.png").is_file()


def test_bad_target_file(tmp_path):
    from bench.camera.calibrate_dataset import calibrate_dataset

    _dataset(tmp_path / "ds", n_views=1, target="hexagonal")
    with pytest.raises(ConfigError, match="target.yaml: type: expected"):
        calibrate_dataset(tmp_path / "ds", tmp_path / "out", verbose=False)


def test_stated_tolerance_widens_the_standard_errors(tmp_path):
    """A target.yaml that states the print's tolerances: the reported standard errors carry them (the same
    detections calibrated against 48 drawn boards), and say so; without it they are the pixel noise's alone."""
    from bench.camera.calibrate_dataset import TOLERANCE_DRAWS, calibrate_dataset

    _dataset(tmp_path / "ds", n_views=5)
    _, plain = calibrate_dataset(tmp_path / "ds", tmp_path / "out", model="pinhole", verbose=False)
    _dataset(tmp_path / "ds_tol", n_views=5,
             tolerance="tolerance:\n  flatness_rms_mm: 0.4\n  print_rms_mm: [0.05, 0.09]\n")
    _, tol = calibrate_dataset(tmp_path / "ds_tol", tmp_path / "out_tol", model="pinhole", verbose=False)
    assert plain["tolerance_draws"] == 0 and tol["tolerance_draws"] == TOLERANCE_DRAWS
    assert tol["K"] == plain["K"]  # the estimate is the same; only its uncertainty grows
    for k in ("fx", "fy", "cx", "cy"):
        assert tol["standard_errors"][k] > 3 * plain["standard_errors"][k], k
