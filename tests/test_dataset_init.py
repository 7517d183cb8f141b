"""``bench dataset init``: raw files -> a dataset folder; every user mistake refused in one line, nothing written."""

import math

import cv2
import numpy as np
import pytest

from bench.camera.io import write_camera_yaml
from bench.camera.model import CameraModel
from bench.cli import main
from bench.dataset import load_dataset
from bench.robot.model import default_robot_path

ROLES = ["--role", "rig=rig*", "--role", "reference=ref", "--role", "surround=survey*", "--role", "locate=locate*",
         "--role", "task=task_*"]
TARGET = ["--target", "chessboard", "--inner", "9x6", "--square-mm", "25"]
VIEWS = ["rig01", "rig02", "ref", "survey01", "locate0", "locate1"]


def _raw(root, rng):
    """Photos (JPEG and PNG), a ;-separated joint log in degrees naming photos by file name, a tracker export."""
    photos = root / "photos"
    photos.mkdir(parents=True)
    for i, v in enumerate(VIEWS):
        img = rng.integers(0, 256, (48, 64, 3)).astype(np.uint8)
        cv2.imwrite(str(photos / f"{v}.{'png' if i % 2 else 'jpg'}"), img)
    q = rng.uniform([5, 20, 40, -90, -60, -90], [60, 80, 120, 90, 60, 90], (len(VIEWS) + 1, 6))
    names = [f"{v}.{'png' if i % 2 else 'jpg'}" for i, v in enumerate(VIEWS)] + ["task_valve"]
    rows = ["frame;A1 [deg];A2 [deg];A3 [deg];A4 [deg];A5 [deg];A6 [deg]"]
    rows += [";".join([n, *(f"{x:.4f}" for x in qq)]) for n, qq in zip(names, q, strict=True)]
    (root / "log.csv").write_text("\n".join(rows) + "\n")
    p = rng.uniform(-1.5, 1.5, (12, 3))
    qt = rng.uniform([5, 20, 40, -90, -60, -90], [60, 80, 120, 90, 60, 90], (12, 6))
    tr = ["Point ID\tX [m]\tY [m]\tZ [m]\tq1 [deg]\tq2 [deg]\tq3 [deg]\tq4 [deg]\tq5 [deg]\tq6 [deg]"]
    tr += ["\t".join([f"P{i}", *(f"{x:.6f}" for x in pp), *(f"{x:.4f}" for x in qq)])
           for i, (pp, qq) in enumerate(zip(p, qt, strict=True))]
    (root / "tracker.txt").write_text("\n".join(tr) + "\n")
    write_camera_yaml(root / "camera.yaml", CameraModel(64, 48, np.array([[60.0, 0, 32], [0, 60, 24], [0, 0, 1]]),
                                                        np.zeros(5)))
    return q, p


def _argv(root, out, log=None, photos=None, extra=()):
    return ["dataset", "init", "--out", str(out), "--images", str(photos or root / "photos"), "--joints",
            str(log or root / "log.csv"), "--tracker", str(root / "tracker.txt"), "--robot", str(default_robot_path()),
            "--camera", str(root / "camera.yaml"), *ROLES, *TARGET, *extra]


def test_init_builds_a_dataset_from_raw_files(tmp_path, capsys):
    rng = np.random.default_rng(170)
    q, p = _raw(tmp_path, rng)
    (tmp_path / "ds").mkdir()  # an empty folder is fine
    assert main(_argv(tmp_path, tmp_path / "ds")) == 0, capsys.readouterr().err
    ds = load_dataset(tmp_path / "ds")
    assert ds.kind == "in_situ" and [v.name for v in ds.views] == sorted([*VIEWS, "task_valve"])
    roles = {v.name: v.role for v in ds.views}
    assert roles["rig01"] == "rig" and roles["ref"] == "reference" and roles["locate1"] == "locate"
    assert roles["task_valve"] == "task" and ds.view("task_valve").image_path is None
    for i, v in enumerate(VIEWS):  # photos byte for byte, readings exact
        src = tmp_path / "photos" / f"{v}.{'png' if i % 2 else 'jpg'}"
        assert ds.view(v).image_path.read_bytes() == src.read_bytes()
        assert np.allclose(np.rad2deg(ds.view(v).q), np.round(q[i], 4), atol=1e-12)
    assert np.allclose(ds.tracker["p"], np.round(p, 6), atol=1e-12)
    assert (tmp_path / "ds" / "target.yaml").read_text().count("inner: [9, 6]") == 1
    from bench.camera.calibrate_dataset import load_target

    assert load_target(tmp_path / "ds" / "target.yaml").n_corners == 54


def test_init_names_the_regions_of_a_survey(tmp_path, capsys):
    """--region NAME=PATTERN: every posed view of the survey gets its region; one matching none, or two, is refused."""
    _raw(tmp_path, np.random.default_rng(170))
    regions = ["--region", "a=ref", "--region", "a=survey*", "--region", "a=locate*"]
    assert main(_argv(tmp_path, tmp_path / "ds", extra=regions)) == 0, capsys.readouterr().err
    ds = load_dataset(tmp_path / "ds")
    assert {v.name: v.region for v in ds.views} == {"rig01": "", "rig02": "", "ref": "a", "survey01": "a",
                                                    "locate0": "a", "locate1": "a", "task_valve": ""}
    assert main(_argv(tmp_path, tmp_path / "ds2", extra=["--region", "a=ref", "--region", "b=survey*"])) == 2
    err = capsys.readouterr().err
    assert "locate0: matches no --region pattern (a=ref, b=survey*)" in err and not (tmp_path / "ds2").exists()
    assert main(_argv(tmp_path, tmp_path / "ds3", extra=["--region", "a=*", "--region", "b=ref"])) == 2
    assert "ref: matches the patterns of several regions (a, b)" in capsys.readouterr().err
    assert main(_argv(tmp_path, tmp_path / "ds4", extra=["--region", "=ref"])) == 2
    assert "expected NAME=PATTERN" in capsys.readouterr().err


def _edit_log(root, fn):
    lines = (root / "log.csv").read_text().splitlines()
    (root / "bad.csv").write_text("\n".join(fn(lines)) + "\n")
    return root / "bad.csv"


def _rad_as_deg(lines):
    out = [lines[0]]
    for r in lines[1:]:
        f = r.split(";")
        out.append(";".join([f[0], *(f"{math.radians(float(x)):.6f}" for x in f[1:])]))
    return out


CASES = {
    "photo missing": (lambda r: (r / "photos" / "ref.jpg").unlink(), None, r"line 4: view 'ref': no photo ref"),
    "row missing": (None, lambda ls: [x for x in ls if not x.startswith("locate1")],
                    r"locate1.png: no row for view 'locate1' in the joint log"),
    "row cut short": (None, lambda ls: ls[:3] + [ls[3].rsplit(";", 1)[0]] + ls[4:],
                      r"line 4, column A6 \[deg\]: missing \(truncated row"),
    "no unit": (None, lambda ls: [ls[0].replace(" [deg]", "")] + ls[1:], r"angle unit is not stated: pass "
                                                                         r"--joint-units"),
    "radians as degrees": (None, _rad_as_deg, r"every reading lies within \+-pi although the unit is deg"),
    "degrees as radians": (None, lambda ls: [ls[0].replace("[deg]", "[rad]")] + ls[1:],
                           r"more than one turn \(2 pi rad\): degrees given as radians"),
    "beyond a joint limit": (None, lambda ls: ls[:2] + [";".join(ls[2].split(";")[:1] + ["95.0"] +
                                                                 ls[2].split(";")[2:])] + ls[3:],
                             r"line 3 \(rig02\), q1: 95 deg is outside joint 1's limits \[-10, 90\]"),
    "duplicate row": (None, lambda ls: ls + [ls[1]], r"duplicate name 'rig01.jpg'"),
    "photo of another size": (lambda r: cv2.imwrite(str(r / "photos" / "survey01.jpg"),
                                                    np.zeros((60, 80, 3), np.uint8)), None,
                              r"survey01.jpg: <size>: 80x60 px, locate0.jpg is 64x48 px"),
    "photo matching no role": (lambda r: (r / "photos" / "rig02.png").rename(r / "photos" / "extra.png"),
                               lambda ls: [x.replace("rig02.png", "extra.png") for x in ls],
                               r"extra: matches no --role pattern"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_init_refuses_user_mistakes(tmp_path, capsys, case):
    rng = np.random.default_rng(171)
    _raw(tmp_path, rng)
    edit_files, edit_log, pattern = CASES[case]
    if edit_files:
        edit_files(tmp_path)
    log = _edit_log(tmp_path, edit_log) if edit_log else None
    assert main(_argv(tmp_path, tmp_path / "ds", log)) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert __import__("re").search(pattern, err), err
    assert not (tmp_path / "ds").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".ds")]  # no temporary folder left


def test_init_never_writes_over_a_folder(tmp_path, capsys):
    _raw(tmp_path, np.random.default_rng(172))
    (tmp_path / "ds").mkdir()
    (tmp_path / "ds" / "notes.txt").write_text("mine")
    assert main(_argv(tmp_path, tmp_path / "ds")) == 2
    assert "non-empty folder (holds 'notes.txt')" in capsys.readouterr().err
    assert (tmp_path / "ds" / "notes.txt").read_text() == "mine" and len(list((tmp_path / "ds").iterdir())) == 1
    (tmp_path / "file").write_text("x")
    assert main(_argv(tmp_path, tmp_path / "file")) == 2
    assert (tmp_path / "file").read_text() == "x"


def test_init_needs_the_target_for_rig_views_and_a_camera_of_the_photos_size(tmp_path, capsys):
    _raw(tmp_path, np.random.default_rng(173))
    argv = _argv(tmp_path, tmp_path / "ds")
    i = argv.index("--target")
    assert main(argv[:i] + argv[i + 6:]) == 2
    assert "role rig need the calibration target" in capsys.readouterr().err
    write_camera_yaml(tmp_path / "camera.yaml", CameraModel(640, 480, np.eye(3) * [600, 600, 1] + [[0, 0, 320],
                                                                                                     [0, 0, 240],
                                                                                                     [0, 0, 0]],
                                                            np.zeros(5)))
    assert main(argv) == 2
    assert "the camera file says 640x480" in capsys.readouterr().err
    assert not (tmp_path / "ds").exists()


def test_urdf_export_without_effort_and_velocity_warns(tmp_path, capsys):
    """URDF needs effort and velocity limits that the robot file does not know: 0 is never written silently."""
    out = tmp_path / "a.urdf"
    assert main(["export", str(default_robot_path()), "--format", "urdf", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "warning: URDF joint limits" in err and "--velocity-deg-s" in err
    assert 'effort="0"' in out.read_text() and "0 = unknown" in out.read_text()
    out2 = tmp_path / "b.urdf"
    assert main(["export", str(default_robot_path()), "--format", "urdf", "--out", str(out2), "--velocity-deg-s",
                 "30", "--effort-nm", "2000"]) == 0
    assert "warning" not in capsys.readouterr().err
    assert 'effort="2000"' in out2.read_text() and 'effort="0"' not in out2.read_text()
