"""Camera export: OpenCV FileStorage YAML and ROS camera_info, reloaded by their peers and projected by OpenCV."""

import cv2
import numpy as np
import pytest
import yaml

from bench.camera.export import SKEW_TOLERANCE_PX, camera_info_text, export_camera, skew_shift_px
from bench.camera.io import write_camera_yaml
from bench.camera.model import CameraModel, random_camera_model
from bench.camera.presets import load_preset
from bench.cli import main
from bench.errors import ConfigError

TOL_PX = 1e-6
N_POINTS = 2000


def cameras():
    rng = np.random.default_rng(77)
    out = {p: load_preset(p) for p in ("air_webcam", "underwater_in_air", "underwater_in_water")}
    for model in ("pinhole", "radial", "heikkila"):
        name = f"random_{model}" + ("_k3" if model != "pinhole" else "")
        out[name] = random_camera_model(rng, 800, 600, model=model, skew=False, k3=model != "pinhole", name=name)
    return out


CAMERAS = cameras()


def visible_points(camera, rng, n=N_POINTS):
    """Points (m) in front of the camera that image inside the frame, corners included, at 0.2-8 m."""
    uv = np.vstack([rng.uniform([-0.5, -0.5], [camera.width - 0.5, camera.height - 0.5], (n - 4, 2)),
                    [[-0.5, -0.5], [camera.width - 0.5, -0.5], [-0.5, camera.height - 0.5],
                     [camera.width - 0.5, camera.height - 0.5]]])
    return camera.unproject(uv, normalize=False) * rng.uniform(0.2, 8.0, (n, 1))


def opencv_pixels(p_cam, K, dist):
    uv, _ = cv2.projectPoints(p_cam.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, dist)
    return uv.reshape(-1, 2)


def ros_matrix(info, key):
    m = info[key]
    return np.array(m["data"], dtype=float).reshape(m["rows"], m["cols"])


@pytest.mark.parametrize("name", list(CAMERAS))
def test_opencv_filestorage_export_projects_like_the_model(tmp_path, name):
    camera = CAMERAS[name]
    src = write_camera_yaml(tmp_path / "camera.yaml", camera)
    out = export_camera(src, "opencv", tmp_path / "opencv.yaml")
    fs = cv2.FileStorage(str(out), cv2.FILE_STORAGE_READ)
    K, dist = fs.getNode("camera_matrix").mat(), fs.getNode("dist_coeffs").mat()
    size = int(fs.getNode("image_width").real()), int(fs.getNode("image_height").real())
    fs.release()
    assert size == camera.size
    p = visible_points(camera, np.random.default_rng(1))
    diff = np.abs(opencv_pixels(p, K, dist) - camera.project(p)).max()
    print(f"parity opencv FileStorage [{name}]: {diff:.2e} px over {len(p)} points")
    assert diff <= TOL_PX


@pytest.mark.parametrize("name", list(CAMERAS))
def test_ros_camera_info_export_projects_like_the_model(tmp_path, name):
    camera = CAMERAS[name]
    src = write_camera_yaml(tmp_path / "camera.yaml", camera)
    out = export_camera(src, "ros", tmp_path / "camera_info.yaml")
    info = yaml.safe_load(out.read_text())
    assert set(info) == {"image_width", "image_height", "camera_name", "camera_matrix", "distortion_model",
                         "distortion_coefficients", "rectification_matrix", "projection_matrix"}
    assert (info["image_width"], info["image_height"]) == camera.size and info["camera_name"] == camera.name
    assert info["distortion_model"] == "plumb_bob"
    K, D = ros_matrix(info, "camera_matrix"), ros_matrix(info, "distortion_coefficients")
    R, P = ros_matrix(info, "rectification_matrix"), ros_matrix(info, "projection_matrix")
    assert np.array_equal(K, camera.K) and np.array_equal(D.ravel(), camera.dist)
    assert np.array_equal(R, np.eye(3)) and np.array_equal(P, np.hstack([K, np.zeros((3, 1))]))
    p = visible_points(camera, np.random.default_rng(2))
    uv = camera.project(p)
    diff = np.abs(opencv_pixels(p, K, D) - uv).max()
    # what image_proc does with R and P: the rectified pixel of a point is P applied to its ideal ray
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-15)
    rect = cv2.undistortPoints(uv.reshape(-1, 1, 2), K, D, R=R, P=P, criteria=crit).reshape(-1, 2)
    ideal = (p @ K.T)[:, :2] / p[:, 2:]
    rect_diff = np.abs(rect - ideal).max()
    print(f"parity ROS camera_info [{name}]: {diff:.2e} px over {len(p)} points; rectified (R, P) {rect_diff:.2e} px")
    assert diff <= TOL_PX and rect_diff <= 1e-6


def test_skew_is_refused_not_dropped(tmp_path):
    skewed = random_camera_model(np.random.default_rng(8), skew=True, name="skewed")
    assert skew_shift_px(skewed) > 0.01
    src = write_camera_yaml(tmp_path / "camera.yaml", skewed)
    for fmt in ("opencv", "ros"):
        with pytest.raises(ConfigError, match=r"camera\.yaml: camera_matrix\[0\]\[1\]: skew .* have no skew"):
            export_camera(src, fmt, tmp_path / f"out_{fmt}.yaml")
        assert not (tmp_path / f"out_{fmt}.yaml").exists()
    # a skew far below a pixel's millionth is harmless and written as 0
    base = load_preset("underwater_in_water")
    K = base.K.copy()
    K[0, 1] = 1e-9
    tiny = CameraModel(base.width, base.height, K, base.dist, name="tiny_skew")
    assert skew_shift_px(tiny) < SKEW_TOLERANCE_PX
    info = yaml.safe_load(camera_info_text(tiny))
    assert info["camera_matrix"]["data"][1] == 0.0


def test_cli_export_camera_and_bad_inputs(tmp_path, capsys):
    good = write_camera_yaml(tmp_path / "camera.yaml", load_preset("underwater_in_air"))
    assert main(["export-camera", str(good), "--format", "ros", "--out", str(tmp_path / "info.yaml")]) == 0
    assert yaml.safe_load((tmp_path / "info.yaml").read_text())["image_width"] == 640
    garbage = tmp_path / "garbage.yaml"
    garbage.write_text("camera_matrix: [1, 2\n")
    nan_k = tmp_path / "nan_k.yaml"
    nan_k.write_text(good.read_text().replace("image_width: 640", "image_width: -640"))
    skewed = write_camera_yaml(tmp_path / "skewed.yaml", random_camera_model(np.random.default_rng(9), skew=True))
    cases = [(tmp_path / "missing.yaml", "missing.yaml: file: not found"),
             (garbage, "garbage.yaml: file: not a readable OpenCV YAML"),
             (nan_k, "nan_k.yaml: image_width: expected a positive integer"),
             (skewed, "skewed.yaml: camera_matrix[0][1]: skew")]
    for src, msg in cases:
        out = tmp_path / "never.yaml"
        assert main(["export-camera", str(src), "--format", "opencv", "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert msg in err and len(err.splitlines()) == 1, err
        assert not out.exists()
