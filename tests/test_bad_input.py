"""Bad input on the CLI and the API (issue 6, deliverable 5): every case must end in a one-line error naming the file
or field (``bench: error: ...``, exit 2; a ``ValueError`` for API misuse) or in a result with ``success=False`` and
the reason (exit 1) - never a traceback, never silent garbage, never a half-written output (the output folder is
checked after every failure).

The dataset cases mutate a copy of a small, geometrically exact in-situ dataset (``tests/vision/planar_scene.py``:
a textured panel imaged through homographies, no MuJoCo) on which ``bench locate`` succeeds. The number of cases is
printed by :func:`test_case_count` (``pytest -s``) and reported in the README.
"""

import json
import math
import re
import shutil
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from bench.cli import main
from bench.geometry.transforms import homogeneous, rot_z

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "scenarios"


# ------------------------------------------------------------------------------------------------ the good dataset


@pytest.fixture(scope="module")
def good_dataset(tmp_path_factory, ta40):
    from tests.vision.planar_scene import write_planar_dataset

    root = tmp_path_factory.mktemp("bad_input") / "good"
    truth = write_planar_dataset(root, ta40, homogeneous(rot_z(np.deg2rad(4.0)), [0.08, -0.05, 0.02]), seed=7)
    return root, truth


def test_the_good_dataset_is_located(good_dataset, tmp_path, capsys):
    root, truth = good_dataset
    assert main(["locate", str(root), "--out", str(tmp_path / "out")]) == 0, capsys.readouterr().err
    rep = json.loads((tmp_path / "out" / "locate.json").read_text())
    assert rep["success"] and np.linalg.norm(np.array(rep["T_world_base"])[:3, 3] - truth["T_world_base"][:3, 3]) < 5e-3
    assert "WARNING" not in rep["message"], rep["message"]  # survey and locate baselines pass Eq. 199 at f = 800 px


# ------------------------------------------------------------------------------------------------ mutations


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def _png_header(width, height) -> bytes:
    return b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))


def _huge_header(p):
    """A PNG whose header claims 20000 x 20000 (400 Mpx, 400 MB decoded) with a little data."""
    p.write_bytes(_png_header(20000, 20000) + _png_chunk(b"IDAT", zlib.compress(b"\0" * 4096))
                  + _png_chunk(b"IEND", b""))


def _corrupt_idat(p):
    """Valid header and end, 40 bytes of the compressed data overwritten: the IDAT chunk fails its CRC."""
    b = bytearray(p.read_bytes())
    i = b.index(b"IDAT")
    b[i + 20:i + 60] = b"x" * 40
    p.write_bytes(bytes(b))


def _sparse(p, size, head=b"", tail=b""):
    """A ``size``-byte file (sparse: no disk or memory used for the hole)."""
    with p.open("wb") as f:
        f.write(head)
        f.truncate(size - len(tail))
        f.seek(size - len(tail))
        f.write(tail)


def _edit_joints(root, fn):
    path = root / "joints.csv"
    lines = path.read_text().splitlines()
    path.write_text("\n".join(fn(lines)) + "\n")


def _set_cell(lines, row, col, value):
    cells = lines[row].split(",")
    cells[col] = value
    lines[row] = ",".join(cells)
    return lines


def _edit_yaml(path, fn):
    data = yaml.safe_load(path.read_text())
    fn(data)
    path.write_text(yaml.safe_dump(data, sort_keys=False))


def _uniform_images(root):
    for p in (root / "images").glob("*.png"):
        cv2.imwrite(str(p), np.full((480, 640), 128, np.uint8))


def _same_locate_view(root):
    """Both locate views the same (same image, same joint readings): zero baseline."""
    shutil.copy(root / "images" / "loc0.png", root / "images" / "loc1.png")

    def fn(lines):
        loc0 = next(ln for ln in lines if ln.startswith("loc0,"))
        return [("loc1," + loc0.split(",", 1)[1]) if ln.startswith("loc1,") else ln for ln in lines]

    _edit_joints(root, fn)


def _robot_joint(root, i, key, value):
    def fn(data):
        data["joints"][i][key] = value

    _edit_yaml(root / "robot.yaml", fn)


# (name, mutation, expected exit code, regex on the one error line (exit 2) or on the result message (exit 1))
LOCATE_CASES = [
    ("no dataset folder", lambda r: shutil.rmtree(r), 2, r"good: <folder>: dataset folder not found"),
    ("no manifest", lambda r: (r / "manifest.yaml").unlink(), 2, r"manifest.yaml: <file>: not found"),
    ("corrupt manifest", lambda r: (r / "manifest.yaml").write_text("views: [unclosed\n"), 2,
     r"manifest.yaml: <file>: not valid YAML"),
    ("binary manifest", lambda r: (r / "manifest.yaml").write_bytes(b"\xff\xfe\x00\x01" * 64), 2,
     r"manifest.yaml: <file>: not valid YAML"),
    ("unknown manifest key", lambda r: _edit_yaml(r / "manifest.yaml", lambda d: d.update(colour="red")), 2,
     r"manifest.yaml: colour: unknown key"),
    ("missing image", lambda r: (r / "images" / "s0.png").unlink(), 2, r"s0.png: <file>: image of view 's0' not found"),
    ("empty image", lambda r: (r / "images" / "s0.png").write_bytes(b""), 2, r"s0.png: <file>: .*'s0': empty file"),
    ("corrupt image", lambda r: (r / "images" / "s1.png").write_bytes(np.random.default_rng(0).bytes(5000)), 2,
     r"s1.png: <header>: .*not a PNG file"),
    ("corrupt image data", lambda r: _corrupt_idat(r / "images" / "s1.png"), 2,
     r"s1.png: <file>: .*PNG file corrupt: broken PNG file \(bad header checksum in b'IDAT'\)$"),
    ("truncated image", lambda r: (r / "images" / "s2.png").write_bytes((r / "images" / "s2.png").read_bytes()[:9000]),
     2, r"s2.png: <file>: .*PNG cut short"),
    ("huge image header", lambda r: _huge_header(r / "images" / "s3.png"), 2,
     r"s3.png: <size>: .*20000x20000 = 400 Mpx, more than 100 Mpx: refused before decoding"),
    ("100 MB image", lambda r: _sparse(r / "images" / "s4.png", 100 * 2**20, _png_header(640, 480),
                                       _png_chunk(b"IEND", b"")), 2, r"s4.png: <file>: .*100.0 MB for a 640x480 image"),
    ("100 MB of zeros", lambda r: _sparse(r / "images" / "loc0.png", 100 * 2**20), 2,
     r"loc0.png: <header>: .*not a PNG file"),
    ("image size vs camera", lambda r: cv2.imwrite(str(r / "images" / "ref.png"), np.zeros((240, 320), np.uint8)), 2,
     r"ref.png: <size>: .*image is 320x240, the camera file says 640x480"),
    ("camera size vs images", lambda r: (r / "camera.yaml").write_text(
        (r / "camera.yaml").read_text().replace("image_width: 640", "image_width: 800")), 2,
     r"<size>: .*image is 640x480, the camera file says 800x480"),
    ("corrupt camera file", lambda r: (r / "camera.yaml").write_text("%YAML:1.0\ncamera_matrix: [1, 2\n"), 2,
     r"camera.yaml: "),
    ("missing robot file", lambda r: (r / "robot.yaml").unlink(), 2,
     r"manifest.yaml: robot: file 'robot.yaml' not found"),
    ("robot a_mm in metres", lambda r: _robot_joint(r, 1, "a_mm", 0.753), 2,
     r"robot.yaml: joints\[1\].a_mm: 0.753 mm beside links of 747 mm: metres given where mm belong"),
    ("robot alpha_deg in radians", lambda r: _robot_joint(r, 3, "alpha_deg", -1.5708), 2,
     r"robot.yaml: joints\[3\].alpha_deg: -1.5708 looks like radians"),
    ("robot limits in radians", lambda r: _edit_yaml(r / "robot.yaml", lambda d: [j.update(
        min_deg=math.radians(j["min_deg"]), max_deg=math.radians(j["max_deg"])) for j in d["joints"]]), 2,
     r"robot.yaml: joints\[0\].min_deg: every joint limit lies within \+-2 pi"),
    ("empty joints.csv", lambda r: (r / "joints.csv").write_text(""), 2, r"joints.csv: <file>: empty"),
    ("truncated joints.csv", lambda r: (r / "joints.csv").write_text((r / "joints.csv").read_text()[:-40]), 2,
     r"joints.csv: line 9: 5 values for the 7 columns"),
    ("non-numeric joint", lambda r: _edit_joints(r, lambda ls: _set_cell(ls, 3, 2, "abc")), 2,
     r"joints.csv: line 4 \(s1\).q2_deg: not a number: 'abc'"),
    ("NaN joint", lambda r: _edit_joints(r, lambda ls: _set_cell(ls, 2, 4, "nan")), 2,
     r"joints.csv: line 3 \(s0\).q4_deg: NaN or inf"),
    ("inf joint", lambda r: _edit_joints(r, lambda ls: _set_cell(ls, 5, 6, "-inf")), 2,
     r"joints.csv: line 6 \(s3\).q6_deg: NaN or inf"),
    ("extra value in a row", lambda r: _edit_joints(r, lambda ls: _set_cell(ls, 4, 6, ls[4].split(",")[6] + ",1.0")),
     2, r"joints.csv: line 5: 8 values for the 7 columns"),
    ("unknown joint column", lambda r: _edit_joints(r, lambda ls: [ls[0] + ",q7_deg"] + [ln + ",0" for ln in ls[1:]]),
     2, r"joints.csv: q7_deg: unknown column"),
    ("missing joint column", lambda r: _edit_joints(r, lambda ls: [",".join(ln.split(",")[:6]) for ln in ls]), 2,
     r"joints.csv: q6_deg: missing column"),
    ("radians in degree columns", lambda r: _edit_joints(r, lambda ls: [ls[0]] + [
        ",".join([ln.split(",")[0]] + [repr(math.radians(float(v))) for v in ln.split(",")[1:]]) for ln in ls[1:]]), 2,
     r"joints.csv: q1_deg \.\.\. q6_deg: every reading lies within \+-pi .* radians written where degrees belong"),
    ("joint beyond 720 deg", lambda r: _edit_joints(r, lambda ls: _set_cell(ls, 2, 1, "1000")), 2,
     r"joints.csv: s0\.q1_deg: \|angle\| 1000.0 > 720 deg: not degrees"),
    ("joint outside its limits", lambda r: _edit_joints(r, lambda ls: _set_cell(ls, 2, 1, "120")), 2,
     r"joints.csv: s0: joint readings outside the joint limits"),
    ("view without a joints row", lambda r: _edit_joints(r, lambda ls: [ln for ln in ls if not ln.startswith("s2,")]),
     2, r"joints.csv: s2: no joint readings for this view"),
    ("joints row of an unknown view", lambda r: _edit_joints(r, lambda ls: ls + ["ghost" + ls[1][3:]]), 2,
     r"joints.csv: ghost: readings for a view that the manifest does not list"),
    ("duplicate joints row", lambda r: _edit_joints(r, lambda ls: ls + [ls[2]]), 2,
     r"joints.csv: line 10: duplicate view 's0'"),
    ("no texture: < 3 matches", _uniform_images, 1, r"the map has 0 points; at least 3 are needed"),
    ("zero baseline", _same_locate_view, 1, r"the two views are 0.000 mm apart: no baseline to triangulate"),
]


@pytest.mark.parametrize("name, mutate, code, pattern", LOCATE_CASES, ids=[c[0] for c in LOCATE_CASES])
def test_bench_locate_bad_dataset(good_dataset, tmp_path, capsys, monkeypatch, name, mutate, code, pattern):
    root = tmp_path / "good"
    shutil.copytree(good_dataset[0], root)
    mutate(root)
    decoded = []
    real_imread = cv2.imread
    monkeypatch.setattr(cv2, "imread", lambda p, *a: decoded.append(Path(p).name) or real_imread(p, *a))
    out = tmp_path / "out"
    assert main(["locate", str(root), "--out", str(out)]) == code
    captured = capsys.readouterr()
    if code == 2:
        err = captured.err.strip()
        assert err.count("\n") == 0 and err.startswith("bench: error: "), err
        assert re.search(pattern, err), err
        assert not out.exists()  # nothing written
    else:
        assert re.search(pattern, captured.out.strip().splitlines()[-1]), captured.out
        assert sorted(p.name for p in out.iterdir()) == [".bench-output.json", "locate.json"]  # and the marker
        rep = json.loads((out / "locate.json").read_text())
        assert rep["success"] is False and re.search(pattern, rep["message"])
    if name == "huge image header":
        assert "s3.png" not in decoded  # refused from the header, never decoded


def test_bench_locate_missing_override_files(good_dataset, tmp_path, capsys):
    for opt in ("--robot", "--camera"):
        assert main(["locate", str(good_dataset[0]), opt, str(tmp_path / "nope.yaml")]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "nope.yaml" in err and "not found" in err


def test_bench_locate_files_given_in_each_others_place(good_dataset, tmp_path, capsys):
    """A user's swapped or wrong files: each is one short line naming the file and what it is not - a robot file as
    the camera, an OpenCV camera file or a CSV as the priors, a CSV as the robot (not its whole text), a corrupt
    encoders.yaml."""
    import shutil

    root = tmp_path / "ds"
    shutil.copytree(good_dataset[0], root)
    (root / "encoders.yaml").write_text("noise_deg: 0.002\nresolution_deg: 0.001\n")
    camera, robot, joints = root / "camera.yaml", root / "robot.yaml", root / "joints.csv"
    priors = tmp_path / "priors.yaml"
    priors.write_text("[1, 2]\n")
    cases = [(["--camera", str(robot)], "not a camera file: a YAML mapping of"),
             (["--refine", "joints", "--priors", str(camera)], "camera.yaml: <file>: not valid YAML"),
             (["--refine", "joints", "--priors", str(priors)], "expected a mapping of covariances, got list"),
             (["--robot", str(joints)], "joints.csv: <top>: expected a mapping, got str")]
    for extra, pattern in cases:
        assert main(["locate", str(root), *extra]) == 2, extra
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and pattern in err and len(err) < 300, err
    (root / "encoders.yaml").write_text("noise_deg: [1\n")
    assert main(["locate", str(root), "--refine", "joints"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "encoders.yaml: <file>: not valid YAML" in err, err
    run = tmp_path / "run"  # a run's folder, or the dataset's images folder, given for the dataset: the hint
    shutil.copytree(good_dataset[0], run / "dataset")
    for wrong in (run, run / "dataset" / "images"):
        assert main(["locate", str(wrong)]) == 2
        assert f"not a dataset folder (did you mean {run / 'dataset'}?)" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------ scenarios


RUN_CASES = [
    ("missing scenario", ["run", "nope.yaml"], r"nope.yaml: <file>: not found"),
    ("unknown scenario key", ["run", "tracker_base_frame.yaml", "--set", "noise.sigma_mm=0.1"],
     r"noise.sigma_mm: unknown key"),
    ("mistyped value", ["run", "tracker_base_frame.yaml", "--set", "monte_carlo.trials=many"],
     r"monte_carlo.trials: expected int"),
    ("--set without =", ["run", "tracker_base_frame.yaml", "--set", "noise.default_sigma_mm"],
     r"noise.default_sigma_mm: --set expects KEY=VALUE"),
    ("negative tracker noise", ["run", "tracker_base_frame.yaml", "--set", "noise.default_sigma_mm=-0.05"],
     r"noise.default_sigma_mm"),
    ("negative identification noise",
     ["run", "table2_kinematic_identification.yaml", "--set", "realistic.tracker_sigma_mm=-0.05"],
     r"realistic.tracker_sigma_mm: must be > 0"),
    ("noise in um, not mm",
     ["run", "table2_kinematic_identification.yaml", "--set", "realistic.tracker_sigma_mm=50.5"],
     r"realistic.tracker_sigma_mm: 50.5 mm is implausible"),
    ("too few identification poses", ["run", "table2_kinematic_identification.yaml", "--set", "realistic.n_poses=5"],
     r"realistic.n_poses: 5 poses give 15 equations for 25 identifiable errors"),
    ("too few rank poses", ["run", "table2_kinematic_identification.yaml", "--set", "identifiability.n_poses=2"],
     r"identifiability.n_poses: 2 poses give 6 rows"),
    ("negative in-situ noise", ["run", "ta40_in_situ_manifold.yaml", "--set", "lab.tracker_sigma_mm=-1"],
     r"lab.tracker_sigma_mm"),
    ("unknown kind", ["run", "KIND"], r"kind: unknown scenario kind 'levitation'"),
    ("sweep: negative noise", ["sweep", "tracker_base_frame.yaml", "--param", "noise.default_sigma_mm=0.05,-0.1"],
     r"noise.default_sigma_mm"),
    ("sweep: unknown key", ["sweep", "tracker_base_frame.yaml", "--param", "noise.sigma=0.05"],
     r"noise.sigma: unknown key"),
    ("sweep: no seeds", ["sweep", "tracker_base_frame.yaml", "--seeds", "0"], r"--seeds: must be >= 1"),
    # issue 17.3: refused before anything renders or a store is created, naming the user's key, value and unit
    ("in-situ: too few tracker poses", ["run", "ta40_in_situ_manifold.yaml", "--set", "lab.tracker_poses=3"],
     r"lab.tracker_poses: 3 poses give 9 equations for 25 identifiable errors; need at least 9"),
    ("in-situ: two rig views", ["run", "ta40_in_situ_manifold.yaml", "--set", "lab.rig_views=2"],
     r"lab.rig_views: 2 views; the camera calibration needs the rig in at least 3"),
    ("in-situ: negative encoder noise", ["run", "ta40_in_situ_manifold.yaml", "--set", "encoders.noise_deg=-1"],
     r"encoders.noise_deg: must be >= 0 deg, got -1"),
    ("in-situ: encoder noise of 30 deg", ["run", "ta40_in_situ_manifold.yaml", "--set", "encoders.noise_deg=30"],
     r"encoders.noise_deg: 30.0 deg is implausible"),
    ("in-situ: no RANSAC iterations", ["run", "ta40_in_situ_manifold.yaml", "--set", "pipeline.ransac_iterations=0"],
     r"pipeline.ransac_iterations: must be >= 1, got 0"),
    ("camera calibration: rig distance", ["run", "camera_calibration_webcam.yaml", "--set", "rig.distance_mm=-1"],
     r"rig.distance_mm: expected 300..5000 mm, got -1"),
    ("run: negative seed", ["run", "tracker_base_frame.yaml", "--seed", "-5"],
     r"--seed: expected a non-negative integer, got -5"),
    ("sweep: negative seed", ["sweep", "tracker_base_frame.yaml", "--seed", "-5"],
     r"--seed: expected a non-negative integer.*, got -5"),
    ("sweep: --workers -1", ["sweep", "tracker_base_frame.yaml", "--workers", "-1"], r"--workers: must be >= 1.*-1"),
    ("sweep: --workers 0", ["sweep", "tracker_base_frame.yaml", "--workers", "0"], r"--workers: must be >= 1.*got 0"),
    ("sweep: --address without Ray", ["sweep", "tracker_base_frame.yaml", "--address", "10.0.0.1:6379"],
     r"--address 10.0.0.1:6379: a Ray cluster's address; add --backend ray"),
    ("sweep: empty value", ["sweep", "tracker_base_frame.yaml", "--param", "noise.default_sigma_mm=0.1,,0.2"],
     r"noise.default_sigma_mm: an empty value"),
    ("sweep: bad grid value of in-situ", ["sweep", "ta40_in_situ_manifold.yaml", "--param", "lab.tracker_poses=100,4"],
     r"lab.tracker_poses: 4 poses give 12 equations"),
    ("budget: --workers 0", ["budget", "ta40_in_situ_manifold.yaml", "--workers", "0"], r"--workers: must be >= 1"),
    ("budget: negative seed", ["budget", "ta40_in_situ_manifold.yaml", "--seed", "-1"], r"--seed: expected a non-neg"),
]


@pytest.mark.parametrize("name, argv, pattern", RUN_CASES, ids=[c[0] for c in RUN_CASES])
def test_bench_run_and_sweep_bad_scenario(tmp_path, capsys, name, argv, pattern):
    argv = list(argv)
    if argv[1] == "KIND":
        (tmp_path / "k.yaml").write_text("name: k\nkind: levitation\n")
        argv[1] = str(tmp_path / "k.yaml")
    else:
        argv[1] = str(SCENARIOS / argv[1]) if (SCENARIOS / argv[1]).is_file() else str(tmp_path / argv[1])
    out = tmp_path / "out"
    assert main(argv + ["--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("bench: error: ") and re.search(pattern, err), err
    # nothing half-written: no result, no sweep store, no run folder (the runner may leave the empty folder)
    assert not out.exists() or not any(out.rglob("*")), sorted(out.rglob("*"))


# ------------------------------------------------------------------------------------------------ the API


def _api_cases():
    """``(name, call, expected)``: ``expected`` a ``ValueError`` regex (``"raise:..."``) or a ``success=False`` regex
    (``"fail:..."``)."""
    from bench.geometry.lines import closest_points_between_lines
    from bench.robot.identifiability import closed_form_reduction, numeric_identifiability
    from bench.robot.identification import identify_iterative, identify_linear
    from bench.robot.ik import analytic_ik, compensated_ik
    from bench.robot.kinematics import ee_position
    from bench.robot.model import default_robot_path, load_robot
    from bench.vision.absolute_orientation import absolute_orientation
    from bench.vision.handeye import hand_eye_axxb
    from bench.vision.ransac import ransac_absolute_orientation
    from bench.vision.triangulation import required_baseline, stereo_sensitivity, triangulate_optimal

    robot = load_robot(default_robot_path())
    red = closed_form_reduction(robot)
    rng = np.random.default_rng(3)
    q = robot.random_configurations(rng, 30)
    p = ee_position(robot, q) + rng.normal(scale=5e-5, size=(30, 3))
    line = np.outer(np.linspace(-1, 1, 8), [0.3, -0.2, 0.9])
    pts = rng.normal(size=(8, 3))
    q_nan = q.copy()
    q_nan[4, 2] = np.nan
    far = homogeneous(np.eye(3), [5.0, 0.0, 0.0])
    one_axis = np.stack([homogeneous(rot_z(a), [0.1 * a, 0, 0]) for a in np.linspace(0, 1, 6)])
    return [
        ("AO: collinear points", lambda: absolute_orientation(line + 1.0, line), "fail:collinear or coincident"),
        ("AO: 2 points", lambda: absolute_orientation(pts[:2], pts[:2]), "fail:>= 3 points"),
        ("AO: duplicated point", lambda: absolute_orientation(np.ones((5, 3)), np.ones((5, 3))), "fail:coincident"),
        ("AO: NaN", lambda: absolute_orientation(pts, np.where(pts > 1.5, np.nan, pts)), "raise:p2: contains NaN"),
        ("RANSAC: 2 matches", lambda: ransac_absolute_orientation(pts[:2], pts[:2]), "fail:"),
        ("RANSAC: collinear", lambda: ransac_absolute_orientation(line, line + 0.5), "fail:"),
        ("triangulation: zero baseline", lambda: triangulate_optimal(np.stack([np.eye(4)] * 2),
                                                                     np.full((2, 3, 2), 0.1)), "invalid"),
        ("lines: zero direction", lambda: closest_points_between_lines(np.zeros(3), np.zeros(3), np.ones(3),
                                                                       [0, 1.0, 0]), "raise:d1: zero-length"),
        ("Eq. 123: zero baseline", lambda: stereo_sensitivity(1, 1, 0, 0, 800.0, 800.0, 0.0, 1.0),
         "raise:d_int, alpha and beta must be > 0"),
        ("Eq. 199: zero resolution", lambda: required_baseline(1.0, 800.0, 0.0), "raise:must be > 0"),
        ("IK: unreachable", lambda: analytic_ik(robot, far), "fail:out of reach"),
        ("IK: compensated, unreachable", lambda: compensated_ik(robot, np.zeros(42), far), "fail:"),
        ("FK: degrees for radians", lambda: ee_position(robot, [0, 45, 90, 0, 30, 0]), "raise:degrees"),
        ("identification: NaN joints", lambda: identify_linear(robot, q_nan, p, red), "raise:q: contains NaN"),
        ("identification: points in mm", lambda: identify_linear(robot, q, p * 1e3, red, sigma=5e-5),
         "fail:mm given as m\\?"),
        ("identification: points in mm (LM)", lambda: identify_iterative(robot, q, p * 1e3, red, sigma=5e-5),
         "fail:mm given as m\\?"),
        ("identification: negative sigma", lambda: identify_linear(robot, q, p, red, sigma=-5e-5), "raise:sigma"),
        ("identification: 5 poses", lambda: identify_linear(robot, q[:5], p[:5], red), "fail:5 poses give 15"),
        ("identifiability: 2 poses", lambda: numeric_identifiability(robot, rng, 2), "raise:n_poses: 2 poses"),
        ("hand-eye: one rotation axis", lambda: hand_eye_axxb(one_axis, one_axis), "fail:single axis"),
    ]


API_CASE_NAMES = [c[0] for c in _api_cases()]


@pytest.mark.parametrize("index", range(len(API_CASE_NAMES)), ids=API_CASE_NAMES)
def test_api_bad_input(index):
    name, call, expected = _api_cases()[index]
    kind, _, pattern = expected.partition(":")
    if kind == "raise":
        with pytest.raises(ValueError, match=pattern) as info:
            call()
        assert "\n" not in str(info.value)
    elif kind == "invalid":  # a Triangulation: every point flagged and NaN
        tri = call()
        assert not tri.valid.any() and np.isnan(tri.points).all() and np.isnan(tri.rms).all()
    else:
        res = call()
        assert res.success is False or res.success is np.False_, name
        assert re.search(pattern, res.message), res.message


def test_case_count():
    """The count reported for issue 6 (``pytest tests/test_bad_input.py -s`` prints it)."""
    n = len(LOCATE_CASES) + 1 + len(RUN_CASES) + len(API_CASE_NAMES)
    print(f"\nbad-input cases: {len(LOCATE_CASES) + 1} dataset/CLI locate, {len(RUN_CASES)} scenario/sweep CLI, "
          f"{len(API_CASE_NAMES)} API = {n}")
    assert n >= 60
