import numpy as np
import pytest

from bench.robot.model import random_errors
from bench.sim.views import camera_frames, look_at, look_at_configuration, surrounding_eyes

DEG = np.pi / 180
T_LINK5_CAM = np.array([[1.0, 0, 0, 0.1], [0, 1, 0, 0], [0, 0, 1, 0.2], [0, 0, 0, 1]])


def test_views_around_a_reference_are_reached_with_the_same_roll(ta40):
    rng = np.random.default_rng(7)
    eps = random_errors(rng)
    q_ref = np.array([30, 40, 60, 10, 80, 0]) * DEG
    T_ref = camera_frames(ta40, q_ref, T_LINK5_CAM, eps)
    target = T_ref[:3, 3] + 1.0 * T_ref[:3, 2]
    for eye in surrounding_eyes(T_ref, [[0.05, 0.0], [0.0, 0.05], [0.04, -0.04]]):
        sol = look_at_configuration(ta40, eye, target, T_LINK5_CAM, eps=eps, q_seed=q_ref)
        assert sol.success, sol.message
        T = camera_frames(ta40, sol.q, T_LINK5_CAM, eps)
        assert np.linalg.norm(T[:3, 3] - eye) < 1e-6
        view = (target - eye) / np.linalg.norm(target - eye)
        assert np.arccos(np.clip(T[:3, 2] @ view, -1, 1)) < 1e-6
        assert T[:3, 1] @ T_ref[:3, 1] > 0.9  # image not turned over: the roll stays near the reference's
        assert np.all(sol.q >= ta40.q_min) and np.all(sol.q <= ta40.q_max)


def test_surrounding_eyes_lie_in_the_image_plane():
    T = look_at([0.0, 0.0, 0.0], [1.0, 0.0, 0.0])
    eyes = surrounding_eyes(T, [[0.1, 0.0], [0.0, -0.2]])
    assert np.allclose(eyes @ T[:3, 2], 0.0, atol=1e-15)
    assert np.allclose(np.linalg.norm(eyes, axis=1), [0.1, 0.2])
    assert np.allclose(T[:3, :3].T @ T[:3, :3], np.eye(3)) and np.isclose(np.linalg.det(T[:3, :3]), 1.0)
    assert T[2, 1] < 0  # image down = world down (default)


def test_unreachable_view_is_a_result_not_an_exception(ta40):
    sol = look_at_configuration(ta40, [5.0, 0.0, 0.0], [6.0, 0.0, 0.0], T_LINK5_CAM, n_starts=3)
    assert not sol.success and "not reachable" in sol.message and sol.position_error_m > 1.0


@pytest.mark.parametrize("kw, match", [
    ({"eye_base": [np.nan, 0, 0]}, "eye_base"),
    ({"target_base": [1.0, 1.0, 1.0], "eye_base": [1.0, 1.0, 1.0]}, "coincides"),
    ({"q_seed": np.full(6, 100.0)}, "degrees"),
])
def test_bad_input(ta40, kw, match):
    args = {"eye_base": [1.0, 0.5, 1.0], "target_base": [2.0, 0.5, 1.0]} | kw
    with pytest.raises(ValueError, match=match):
        look_at_configuration(ta40, args.pop("eye_base"), args.pop("target_base"), T_LINK5_CAM, **args)
