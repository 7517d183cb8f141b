import numpy as np
import pytest

from bench.robot.model import default_robot_path, load_robot


@pytest.fixture(scope="session")
def ta40():
    return load_robot(default_robot_path())


@pytest.fixture
def rng():
    return np.random.default_rng(20261122)

