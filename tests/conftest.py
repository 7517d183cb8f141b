import os

import numpy as np
import pytest

from bench.robot.model import default_robot_path, load_robot

os.environ.setdefault("MUJOCO_GL", "egl")  # headless rendering (Mesa EGL) before any mujoco import


@pytest.fixture(scope="session")
def ta40():
    return load_robot(default_robot_path())


@pytest.fixture
def rng():
    return np.random.default_rng(20261122)

