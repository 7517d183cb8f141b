"""docs/tutorial_real_data.md runs as written: its ``sh`` blocks, line by line, in a fresh folder; then its outputs.

The folder holds links to the repository's ``scenarios/`` and ``models/`` (the tutorial is run from the repository's
root) and nothing else; ``bench`` is the installed command of this interpreter's environment.
"""

import json
import os
import re
import shlex
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
TUTORIAL = ROOT / "docs" / "tutorial_real_data.md"


def tutorial_commands() -> list[str]:
    """The command lines of the tutorial's ```sh blocks, in order."""
    blocks = re.findall(r"^```sh\n(.*?)^```", TUTORIAL.read_text(), re.M | re.S)
    return [ln.strip() for b in blocks for ln in b.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]


def test_tutorial_commands_are_the_pipeline():
    cmds = tutorial_commands()
    firsts = [" ".join(shlex.split(c)[:2]) for c in cmds]
    assert firsts == ["bench sim", "bench sim", "bench dataset", "bench calibrate-robot", "bench calibrate-camera",
                      "bench locate", "bench export", "bench export-camera"]
    assert all(shlex.split(c)[0] == "bench" for c in cmds)


def test_tutorial_runs_as_written(tmp_path):
    for name in ("scenarios", "models"):
        (tmp_path / name).symlink_to(ROOT / name)
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}",
               MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    for cmd in tutorial_commands():
        r = subprocess.run(cmd, shell=True, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, f"{cmd}\n{r.stdout[-2000:]}\n{r.stderr[-2000:]}"
    t = tmp_path / "tutorial"
    # the raw files are what real equipment writes: no truth, JPEG photos, degrees in the joint log
    assert not list((t / "raw").rglob("truth*"))
    assert {p.suffix for p in (t / "raw" / "photos").iterdir()} == {".jpg"}
    assert "A1 [deg]" in (t / "raw" / "robot_log.csv").read_text().splitlines()[0]
    # the dataset holds the photos byte for byte
    photo = sorted((t / "raw" / "photos").iterdir())[0]
    assert (t / "dive" / "images" / photo.name).read_bytes() == photo.read_bytes()
    # the calibrations, scored against the simulator's truth (read here only, never by the commands)
    truth = yaml.safe_load((t / "sim" / "truth" / "truth.yaml").read_text())
    # one of the 10 requested rig views (azimuth -25 deg) is beyond the joint limits: reported, not silently dropped
    checks = json.loads((t / "sim" / "truth" / "sim_checks.json").read_text())
    assert checks["rig_views_unreachable"] == 1
    assert sum(v["role"] == "rig" for v in truth["views"].values()) == 9
    arm = json.loads((t / "arm" / "calibration.json").read_text())
    assert arm["rms_mm"] < 0.3 and arm["n_postures"] == 40
    cam = json.loads((t / "camera" / "calibration.json").read_text())
    assert cam["reproj_rms_px"] < 1.0 and len(cam["views_used"]) >= 6
    mount = np.array(cam["mount"]["T_link5_cam"])
    # the mount's position along the optical axis is the weakly determined part of AX = XB from 9 rig views at 0.9 m
    # (measured 3 mm and 16 mm off on two renders); the base below is what it is for
    assert np.linalg.norm(mount[:3, 3] - np.array(truth["T_link5_cam_effective"])[:3, 3]) < 0.025  # m
    assert cam["mount"]["rms_trans_mm"] < 1.0 and cam["mount"]["rms_rot_deg"] < 0.1
    loc = json.loads((t / "located" / "locate.json").read_text())
    T_true = np.linalg.inv(np.array(truth["T_world_base_survey"])) @ np.array(truth["T_world_base_locate"])
    T = np.array(loc["T_world_base"])
    assert np.linalg.norm(T[:3, 3] - T_true[:3, 3]) * 1e3 < 5.0
    cos = (np.trace(T[:3, :3].T @ T_true[:3, :3]) - 1) / 2
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))) < 0.2
    assert loc["tasks"] and all(task["success"] for task in loc["tasks"].values())
    # the exported files: a URDF with the camera frame, a ROS camera_info with the calibrated intrinsics
    urdf = ET.parse(t / "ta40_calibrated.urdf").getroot()
    assert "camera_optical" in {link.get("name") for link in urdf.iter("link")}
    info = yaml.safe_load((t / "camera_info.yaml").read_text())
    assert np.allclose(np.array(info["camera_matrix"]["data"]).reshape(3, 3), np.array(cam["K"]), rtol=1e-6)
