import numpy as np
import pytest

from bench.robot.model import default_robot_path, load_robot


@pytest.fixture(scope="session")
def ta40():
    return load_robot(default_robot_path())


@pytest.fixture
def rng():
    return np.random.default_rng(20261122)


def random_errors(rng, n_frames=7, trans=2e-3, rot=np.pi / 180):
    """Generalized errors uniform in +-trans (m) and +-rot (rad), as in thesis section 4.6."""
    e = np.empty((n_frames, 6))
    e[:, :3] = rng.uniform(-trans, trans, size=(n_frames, 3))
    e[:, 3:] = rng.uniform(-rot, rot, size=(n_frames, 3))
    return e.ravel()
