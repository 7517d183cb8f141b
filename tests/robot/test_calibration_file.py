import numpy as np
import pytest
import yaml

from bench.errors import ConfigError
from bench.geometry.transforms import random_transform
from bench.robot.calibration_file import load_calibrated_robot, write_calibrated_robot
from bench.robot.model import default_robot_path, load_robot, random_errors


def test_round_trip(tmp_path, ta40):
    rng = np.random.default_rng(61)
    eps, T = random_errors(rng), random_transform(rng, scale=0.1)
    path = write_calibrated_robot(tmp_path / "robot.yaml", default_robot_path(), ta40, eps, T, notes="lab, 100 poses")
    robot, eps2, T2 = load_calibrated_robot(path)
    assert np.abs(eps2 - eps).max() <= 1e-15 and np.abs(T2 - T).max() <= 1e-12
    assert np.array_equal(robot.a, ta40.a) and load_robot(path).n == 6  # still a valid nominal robot file
    nominal, e0, t0 = load_calibrated_robot(default_robot_path())
    assert not e0.any() and t0 is None


@pytest.mark.parametrize("edit, match", [
    (lambda c: c["errors"].update({"x0": 1.0}), r"calibration.errors.x0: unknown key \(did you mean x0_mm\?\)"),
    (lambda c: c["errors"].update({"s1_rad": 30.0}), "not a plausible error"),
    (lambda c: c["errors"].update({"y2_mm": "abc"}), "calibration.errors.y2_mm: expected a finite number"),
    (lambda c: c["camera_mount"].update({"quaternion_wxyz": [1, 1, 0, 0]}), "unit quaternion"),
    (lambda c: c.update({"colour": 1}), "calibration.colour: unknown key"),
])
def test_bad_calibration_entries(tmp_path, ta40, edit, match):
    path = write_calibrated_robot(tmp_path / "robot.yaml", default_robot_path(), ta40, np.zeros(42), np.eye(4))
    data = yaml.safe_load(path.read_text())
    edit(data["calibration"])
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=match):
        load_calibrated_robot(path)
