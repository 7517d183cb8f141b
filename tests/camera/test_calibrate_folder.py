"""``bench calibrate-camera`` on a plain folder of photos (the real webcam photos), ``--k3``, target.yaml's checks,
and the camera mount without a mount guess (symmetric target labellings resolved from the motions)."""

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from bench.camera.calibrate_dataset import parse_target, target_spec, target_symmetries
from bench.camera.corners import planar_board, two_plane_rig
from bench.camera.io import read_camera_yaml
from bench.cli import main
from bench.errors import ConfigError
from bench.geometry.quaternion import rotation_vector_to_matrix
from bench.geometry.transforms import homogeneous, invert
from bench.vision.handeye import hand_eye_axxb, resolve_target_symmetry_screw

WEBCAM = Path(__file__).resolve().parents[1] / "data" / "real_webcam_chessboard"  # see its PROVENANCE.md
CHESS = ["--target", "chessboard", "--inner", "7x7", "--square-mm", "1"]


def test_plain_folder_of_real_photos(tmp_path, capsys):
    assert len(list(WEBCAM.glob("*.jpg"))) == 19, f"{WEBCAM}: the 19 real webcam photos"
    out = tmp_path / "cam"
    assert main(["calibrate-camera", str(WEBCAM), *CHESS, "--out", str(out)]) == 0
    rep = json.loads((out / "calibration.json").read_text())
    cam = read_camera_yaml(out / "camera.yaml")
    assert len(rep["views_used"]) == 19 and rep["photos"] == str(WEBCAM)
    assert rep["reproj_rms_px"] < 0.6 and rep["reproj_rms_px"] <= rep["opencv_rms_px"] + 1e-6  # measured 0.523
    assert cam.size == (640, 480) and cam.dist[4] == 0.0 and (out / "per_view.csv").is_file()
    # --k3: the fifth coefficient is fitted (and matches OpenCV's on the same detections)
    out3 = tmp_path / "cam3"
    assert main(["calibrate-camera", str(WEBCAM), *CHESS, "--k3", "--out", str(out3)]) == 0
    rep3 = json.loads((out3 / "calibration.json").read_text())
    cam3 = read_camera_yaml(out3 / "camera.yaml")
    assert rep3["k3"] and cam3.dist[4] != 0.0 and abs(cam3.dist[4] - rep3["opencv_dist"][4]) < 1e-3
    assert rep3["reproj_rms_px"] <= rep["reproj_rms_px"] + 1e-9  # one more parameter never fits worse
    # the k3 calibration would overwrite the first one's files: refused, naming what differs, without --force
    capsys.readouterr()
    first = (out / "camera.yaml").read_bytes()
    assert main(["calibrate-camera", str(WEBCAM), *CHESS, "--k3", "--out", str(out)]) == 2
    assert "with other settings: k3 False (this call: True)" in capsys.readouterr().err
    assert (out / "camera.yaml").read_bytes() == first
    # a folder of photos without a target, or a target with a wrong flag, is refused in one line
    assert main(["calibrate-camera", str(WEBCAM), "--out", str(tmp_path / "x")]) == 2
    assert "give --target chessboard --inner WxH --square-mm S" in capsys.readouterr().err
    assert main(["calibrate-camera", str(WEBCAM), *CHESS, "--size-mm", "5",
                 "--out", str(tmp_path / "x")]) == 2
    assert "--size-mm: not a flag of this target" in capsys.readouterr().err
    assert not (tmp_path / "x").exists() or not any((tmp_path / "x").iterdir())


@pytest.mark.parametrize("text, field, problem", [
    ("type: chessboard\ninner: [9, 6]\n", "square_mm", "missing"),
    ("type: chessboard\ninner: [9, 6]\nsquare_mm: -3\n", "square_mm", "> 0"),
    ("type: chessboard\ninner: [9]\nsquare_mm: 3\n", "inner", "[inner corners per row, rows]"),
    ("type: chessboard\ninner: [9, 1]\nsquare_mm: 3\n", "inner", "both >= 2"),
    ("type: chessboard\ninner: [9, 6]\nsquare_mm: 3\nsize_mm: 3\n", "size_mm", "a key of type two_plane_rig"),
    ("type: two_plane_rig\nsquares: 7\n", "size_mm", "missing"),
    ("type: two_plane_rig\nsize_mm: 197\nsquares: 2\n", "squares", "integer >= 3"),
    ("type: two_plane_rig\nsize_mm: 197\nmargin_mm: -1\n", "margin_mm", ">= 0"),
    ("type: two_plane_rig\nsize_mm: '197'\n", "size_mm", "expected float, got str '197'"),
    ("type: checkerboard\n", "type", "expected 'chessboard' or 'two_plane_rig'"),
    ("[1, 2]\n", "<top>", "expected a mapping"),
])
def test_target_yaml_is_checked_key_by_key(text, field, problem):
    with pytest.raises(ConfigError) as e:
        parse_target(yaml.safe_load(text), "target.yaml")
    assert e.value.field == field and problem in e.value.problem and "\n" not in str(e.value)


def test_target_yaml_good_forms():
    assert parse_target({"type": "chessboard", "inner": [9, 6], "square_mm": 25}, "t").n_corners == 54
    assert parse_target({"type": "planar", "inner": [7, 7], "square_mm": 1}, "t").n_corners == 49  # old name
    assert parse_target({"type": "two_plane_rig", "size_mm": 197, "margin_mm": 20}, "t").n_corners == 72
    assert target_spec("chessboard", "9x6", 25) == {"type": "chessboard", "inner": [9, 6], "square_mm": 25}


@pytest.mark.parametrize("geometry", [two_plane_rig(7, 0.197, 0.02), planar_board((7, 7), 0.03),
                                      planar_board((9, 6), 0.025)], ids=["rig", "square board", "9x6 board"])
def test_mount_from_symmetric_labellings_without_a_guess(geometry):
    """Views labelled by random symmetries of the target: the screw invariants pick consistent labellings, AX = XB
    then finds the mount exactly (noise-free)."""
    rng = np.random.default_rng(174)
    X = homogeneous(rotation_vector_to_matrix(rng.normal(0, 1.0, 3)), rng.normal(0, 0.2, 3))
    T_bt = homogeneous(rotation_vector_to_matrix(rng.normal(0, 1.0, 3)), rng.normal(0, 1.0, 3))
    A = np.stack([homogeneous(rotation_vector_to_matrix(rng.normal(0, 0.4, 3)), rng.normal(0, 0.3, 3))
                  for _ in range(8)])
    B_true = np.stack([invert(a @ X) @ T_bt for a in A])
    S = target_symmetries(geometry)
    labels = rng.integers(0, len(S) + 1, len(A))
    labels[0] = 0
    B_seen = np.stack([b @ (np.eye(4) if k == 0 else S[k - 1]) for b, k in zip(B_true, labels, strict=True)])
    assert labels.any()  # some views are mislabelled
    B, choice, worst = resolve_target_symmetry_screw(A, B_seen, S)
    assert worst < 1e-9
    assert np.allclose(B, B_true, atol=1e-9)
    he = hand_eye_axxb(A, B)
    assert he.success and np.allclose(he.T_mount_cam, X, atol=1e-9)
    # the symmetries are the target's: its corners map onto its corners
    P = geometry.object_points()
    for s in S:
        Q = P @ s[:3, :3].T + s[:3, 3]
        assert np.max(np.min(np.linalg.norm(Q[:, None] - P[None], axis=2), axis=1)) < 1e-12


def test_the_photo_tools_read_every_photo_suffix_in_any_case(tmp_path):
    """tools/real_camera_stats, fit_camera_processing and webcam_calibration listed only ``*.jpg`` and ``*.png``
    (a camera's ``IMG_0001.JPG`` or a ``.jpeg`` was not a photo to them); they list photos as ``bench.dataset`` does."""
    import pytest

    from bench.camera.photo_stats import photo_paths

    for name in ("a.JPG", "b.jpeg", "c.png", "notes.txt"):
        (tmp_path / name).write_bytes(b"")
    assert [p.split("/")[-1] for p in photo_paths(tmp_path)] == ["a.JPG", "b.jpeg", "c.png"]
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no photos"):
        photo_paths(tmp_path / "empty")
    with pytest.raises(ValueError, match="not a folder"):
        photo_paths(tmp_path / "missing")
