import subprocess
import sys
from pathlib import Path

import pytest

mujoco = pytest.importorskip("mujoco")
ROOT = Path(__file__).resolve().parents[2]


def test_committed_models_are_up_to_date():
    r = subprocess.run([sys.executable, str(ROOT / "tools" / "generate_models.py"), "--check"], capture_output=True,
                       text=True)
    assert r.returncode == 0, r.stdout + r.stderr


def test_scene_includes_the_robot_and_steps():
    m = mujoco.MjModel.from_xml_path(str(ROOT / "models" / "ta40" / "scene.xml"))
    d = mujoco.MjData(m)
    names = {m.joint(i).name for i in range(m.njnt)}
    sites = {m.site(i).name for i in range(m.nsite)}
    assert names == {f"joint{k}" for k in range(1, 7)}
    assert {"ee", "link5", "camera_mount", "frame0", "frame6"} <= sites and m.camera("link5_camera")
    mujoco.mj_resetDataKeyframe(m, d, m.key("home").id)
    for _ in range(200):
        mujoco.mj_step(m, d)
    assert all(w.number == 0 for w in d.warning)
