"""camera.yaml: OpenCV FileStorage compatibility, round trips and bad files."""

import cv2
import numpy as np
import pytest

from bench.camera.io import camera_yaml_text, read_camera_yaml, write_camera_yaml
from bench.camera.model import CameraModel, random_camera_model
from bench.camera.presets import load_preset
from bench.errors import ConfigError


@pytest.mark.parametrize("preset", ["air_webcam", "underwater_in_air", "underwater_in_water"])
def test_round_trip_is_exact(tmp_path, preset):
    cam = load_preset(preset)
    path = write_camera_yaml(tmp_path / "camera.yaml", cam, extra={"reprojection_rms_px": 0.123, "note": "sim"})
    back, extra = read_camera_yaml(path, with_extra=True)
    assert np.array_equal(back.K, cam.K) and np.array_equal(back.dist, cam.dist)
    assert (back.width, back.height, back.name, back.model, back.pixel_pitch) == \
        (cam.width, cam.height, cam.name, cam.model, cam.pixel_pitch)
    assert extra == {"reprojection_rms_px": 0.123, "note": "sim"}


def test_opencv_reads_what_we_write(tmp_path):
    cam = random_camera_model(np.random.default_rng(31), k3=True)
    path = write_camera_yaml(tmp_path / "camera.yaml", cam)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    assert np.array_equal(fs.getNode("camera_matrix").mat(), cam.K)
    assert np.array_equal(fs.getNode("dist_coeffs").mat().ravel(), cam.dist)
    assert int(fs.getNode("image_width").real()) == cam.width and int(fs.getNode("image_height").real()) == cam.height
    assert fs.getNode("model").string() == "heikkila"
    fs.release()


def test_we_read_what_opencv_writes(tmp_path):
    K = np.array([[812.5, 0.0, 319.2], [0.0, 810.1, 241.7], [0.0, 0.0, 1.0]])
    dist = np.array([[-0.21, 0.07, 1e-3, -5e-4, 0.01]])
    path = tmp_path / "opencv.yml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("calibration_time", "today")  # as OpenCV's calibration sample writes
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", dist)
    fs.write("avg_reprojection_error", 0.21)
    fs.release()
    cam = read_camera_yaml(path)
    assert np.array_equal(cam.K, K) and np.array_equal(cam.dist, dist.ravel()) and cam.size == (640, 480)
    assert cam.model == "heikkila" and cam.name == tmp_path.name


def test_text_has_the_thesis_blocks():
    text = camera_yaml_text(load_preset("underwater_in_air"))
    for key in ("camera_matrix: !!opencv-matrix", "dist_coeffs:", "image_width: 640", "model: heikkila",
                "intrinsics_eq50:", "heikkila_eq75:", "k1_per_mm2: 0.0138", "f_px: 510.06", "pixels_per_mm: 100."):
        assert key in text


def _write(tmp_path, text):
    path = tmp_path / "camera.yaml"
    path.write_text(text)
    return path


def _good_text():
    return camera_yaml_text(load_preset("underwater_in_air"))


def test_bad_files(tmp_path):
    with pytest.raises(ConfigError, match="camera.yaml: file: not found"):
        read_camera_yaml(tmp_path / "camera.yaml")
    cases = [
        (_good_text().replace("image_width: 640\n", ""), "image_width: missing"),
        (_good_text().replace("image_width: 640", "image_width: -640"), "image_width: expected a positive integer"),
        (_good_text().replace("model: heikkila", "model: fisheye"), "model: expected one of"),
        (_good_text().replace("model: heikkila", "model: radial"), "model: 'radial' cannot hold"),
        (_good_text().replace("name: underwater_in_air", "name: x\nfocal: 3"), "focal: unknown key"),
        (_good_text().replace("k1_per_mm2: 0.0138", "k1_per_mm2: 0.0139"), "heikkila_eq75.k1_per_mm2: 0.0139 disag"),
        (_good_text().replace("   s_u:", "   s_v: 1\n   s_u:"), "heikkila_eq75.s_v: unknown key"),
        (_good_text().replace("rows: 3\n   cols: 3", "rows: 1\n   cols: 9"), "camera_matrix: expected 3x3"),
        (_good_text().replace("data: [ 541.17365999999993", "data: [ .nan"), "camera_matrix: contains NaN"),
        (_good_text().replace("data: [ 541.17365999999993", "data: [ -541.17365999999993"),
         "camera_matrix: focal lengths"),
        ("%YAML 1.2\n---\ncamera_matrix: [[1, 0, 0], [0, 1]\n", "file: not a readable"),
    ]
    for text, message in cases:
        with pytest.raises(ConfigError, match=message) as info:
            read_camera_yaml(_write(tmp_path, text))
        assert "\n" not in str(info.value) and str(info.value).startswith(str(tmp_path / "camera.yaml"))


def test_plain_yaml_lists_are_accepted(tmp_path):
    path = _write(tmp_path, "%YAML:1.0\n---\ncamera_matrix: [[500, 0, 320], [0, 500, 240], [0, 0, 1]]\n"
                            "dist_coeffs: [0.1, 0, 0, 0]\nimage_width: 640\nimage_height: 480\n")
    cam = read_camera_yaml(path)
    assert cam == cam and cam.model == "radial" and cam.fx == 500.0


def test_extra_values_are_checked(tmp_path):
    cam = CameraModel(640, 480, np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]))
    with pytest.raises(ValueError, match="extra.rms: expected a finite number"):
        write_camera_yaml(tmp_path / "camera.yaml", cam, extra={"rms": float("nan")})
    assert not (tmp_path / "camera.yaml").exists()
