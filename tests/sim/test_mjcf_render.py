"""The MuJoCo TA-40 against our FK and Pinocchio; the camera convention against the analytic projection."""

import os

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")
mujoco = pytest.importorskip("mujoco")

from bench.camera.presets import load_preset  # noqa: E402
from bench.geometry.transforms import homogeneous, rot_x, rot_y  # noqa: E402
from bench.judge.pinocchio_model import pinocchio_frames  # noqa: E402
from bench.robot.kinematics import link_frames  # noqa: E402
from bench.robot.model import random_errors  # noqa: E402
from bench.robot.orientation import link5_frame  # noqa: E402
from bench.sim.camera import add_opencv_camera, camera_pose_cv  # noqa: E402
from bench.sim.checks import kinematics_check, marker_check  # noqa: E402
from bench.sim.mjcf import robot_spec  # noqa: E402

T_LINK5_CAM = homogeneous(rot_x(0.01) @ rot_y(-0.02), [0.1, 0.02, 0.2])


def _site(m, d, name):
    i = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, name)
    return homogeneous(d.site_xmat[i].reshape(3, 3), d.site_xpos[i])


@pytest.mark.parametrize("perturbed", [False, True])
def test_mujoco_sites_equal_fk_and_pinocchio(ta40, perturbed):
    rng = np.random.default_rng(81)
    eps = random_errors(rng) if perturbed else None
    cam = load_preset("air_webcam")
    m = robot_spec(ta40, eps, np.eye(4), (cam.K, cam.width, cam.height, T_LINK5_CAM)).compile()
    d = mujoco.MjData(m)
    Q = ta40.random_configurations(rng, 200)
    F, P = link_frames(ta40, Q, eps), pinocchio_frames(ta40, Q, eps)
    err_fk = err_pin = 0.0
    for q, f, p in zip(Q, F, P, strict=True):
        d.qpos[:] = q
        mujoco.mj_forward(m, d)
        for k in range(7):
            S = _site(m, d, f"frame{k}")
            err_fk, err_pin = max(err_fk, np.abs(S - f[k]).max()), max(err_pin, np.abs(S - p[k]).max())
        L5 = link5_frame(ta40, q, eps)
        assert np.abs(_site(m, d, "link5") - L5).max() <= 1e-9
        assert np.abs(_site(m, d, "ee")[:3, 3] - (f[6][:3, :3] @ ta40.p_ee + f[6][:3, 3])).max() <= 1e-9
        assert np.abs(camera_pose_cv(m, d, "link5_camera") - L5 @ T_LINK5_CAM).max() <= 1e-9
    assert err_fk <= 1e-9 and err_pin <= 1e-9, (err_fk, err_pin)


def test_model_compiles_and_steps_without_warnings(ta40):
    m = robot_spec(ta40, random_errors(np.random.default_rng(82))).compile()
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, m.key("home").id)
    for _ in range(500):
        mujoco.mj_step(m, d)
    assert all(w.number == 0 for w in d.warning)
    assert np.abs(d.qpos - m.key("home").qpos).max() < 0.05  # the actuators hold the home pose under gravity


@pytest.mark.parametrize("preset", ["air_webcam", "underwater_in_air"])
def test_rendered_markers_land_on_the_analytic_projection(preset):
    res = marker_check(load_preset(preset), supersample=3)
    assert res["markers"] == 25 and res["depth_has_background"]
    assert res["marker_projection_max_px"] <= 0.1 and res["marker_projection_rms_px"] <= 0.06, res


def test_kinematics_check_reports_exact_agreement(ta40):
    rng = np.random.default_rng(83)
    res = kinematics_check(ta40, random_errors(rng), ta40.random_configurations(rng, 20))
    assert res["sim_vs_fk_max_err_m"] <= 1e-9 and res["sim_vs_pinocchio_max_err_m"] <= 1e-9


def test_skew_and_bad_intrinsics_are_refused(ta40):
    K = np.array([[700.0, 1.0, 320.0], [0.0, 700.0, 240.0], [0.0, 0.0, 1.0]])
    with pytest.raises(ValueError, match="skew"):
        add_opencv_camera(mujoco.MjSpec().worldbody, "c", K, 640, 480, np.eye(4))
    with pytest.raises(ValueError, match="fx, fy > 0"):
        add_opencv_camera(mujoco.MjSpec().worldbody, "c", np.diag([-1.0, 1.0, 1.0]), 640, 480, np.eye(4))
    with pytest.raises(ValueError, match="skew"):
        robot_spec(ta40, camera=(K, 640, 480, np.eye(4)))
    with pytest.raises(ValueError, match="eps"):
        robot_spec(ta40, np.zeros(41))
    with pytest.raises(ValueError, match="eps"):
        robot_spec(ta40, np.full(42, np.nan))
