"""URDF/MJCF export of the calibrated arm: reloaded live by Pinocchio and MuJoCo, every frame against our FK."""

import math

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from bench.cli import main
from bench.geometry.transforms import (
    homogeneous,
    random_rotation,
    random_transform,
    rot_x,
    rot_y,
    rot_z,
    rotation_angle,
)
from bench.robot.calibration_file import load_calibrated_robot, write_calibrated_robot
from bench.robot.export import export_robot, exported_frames, mjcf_text, rpy_from_matrix, urdf_text
from bench.robot.kinematics import dh_transform, link_frames
from bench.robot.model import default_robot_path, random_errors
from bench.robot.orientation import link5_frame

N_CONFIGS = 200
TOL_M, TOL_RAD = 1e-9, 1e-9


def reference_frames(robot, q, eps, T_link5_cam):
    """Every exported frame from the pipeline's FK (Eq. 10, 188), ``{name: (N, 4, 4)}``."""
    F = link_frames(robot, q, eps)
    out = {"base": np.broadcast_to(np.eye(4), F.shape[:1] + (4, 4)), "frame0": F[:, 0]}
    for k in range(1, robot.n + 1):
        th = q[:, k - 1] + robot.theta_offset[k - 1]
        out[f"body{k}"] = F[:, k - 1] @ homogeneous(rot_z(th), np.zeros(3))
        out[f"link{k}"] = F[:, k - 1] @ dh_transform(th, robot.d[k - 1], robot.a[k - 1], robot.alpha[k - 1])
        out[f"frame{k}"] = F[:, k]
    out["ee"] = F[:, -1] @ homogeneous(np.eye(3), robot.p_ee)
    assert np.abs(out["link5"] - link5_frame(robot, q, eps)).max() < 1e-15  # link5 is Eq. 188
    if T_link5_cam is not None:
        out["camera_optical"] = out["link5"] @ T_link5_cam
    return out


def pose_errors(T_a, T_b):
    """Position (m) and rotation (rad) differences of two poses."""
    return np.abs(T_a[:3, 3] - T_b[:3, 3]).max(), float(rotation_angle(T_a[:3, :3].T @ T_b[:3, :3]))


CASES = {
    "nominal": lambda rng: (np.zeros(42), None),
    "nominal_with_mount": lambda rng: (np.zeros(42), homogeneous(rot_z(np.pi), [0.12, 0.0, 0.30])),
    "random_errors_and_mount": lambda rng: (random_errors(rng), random_transform(rng, scale=0.3)),
    "large_errors_gimbal_mount": lambda rng: (random_errors(rng, trans=0.02, rot=0.2),
                                              homogeneous(rot_z(0.4) @ rot_y(np.pi / 2) @ rot_x(-1.1),
                                                          [0.05, -0.2, 0.3])),
}


@pytest.fixture(params=list(CASES))
def calibrated(request, tmp_path, ta40):
    rng = np.random.default_rng(sum(map(ord, request.param)))
    eps, T = CASES[request.param](rng)
    path = write_calibrated_robot(tmp_path / "robot.yaml", default_robot_path(), ta40, eps, T, notes="test")
    robot, eps, T = load_calibrated_robot(path)  # what the file holds (mount through its quaternion)
    q = robot.random_configurations(rng, N_CONFIGS)
    q[0] = robot.q_min
    q[1] = robot.q_max
    return request.param, path, robot, eps, T, q


def test_urdf_reloaded_by_pinocchio_matches_fk(calibrated, tmp_path):
    case, path, robot, eps, T, q = calibrated
    urdf = export_robot(path, "urdf", tmp_path / "ta40.urdf")
    model = pin.buildModelFromUrdf(str(urdf))
    data = model.createData()
    assert model.nq == robot.n and [model.names[i] for i in range(1, model.njoints)] == list(robot.joint_names)
    assert np.array_equal(model.lowerPositionLimit, robot.q_min)
    assert np.array_equal(model.upperPositionLimit, robot.q_max)
    names = exported_frames(robot, T is not None)
    ids = {n: model.getFrameId(n, pin.FrameType.BODY) for n in names}
    assert all(i < model.nframes for i in ids.values())
    ref = reference_frames(robot, q, eps, T)
    worst_p = worst_r = 0.0
    for i, qi in enumerate(q):
        pin.framesForwardKinematics(model, data, qi)
        for n in names:
            dp, dr = pose_errors(ref[n][i], data.oMf[ids[n]].homogeneous)
            worst_p, worst_r = max(worst_p, dp), max(worst_r, dr)
    print(f"parity URDF/Pinocchio [{case}]: {worst_p:.2e} m, {worst_r:.2e} rad over {len(q)} "
          f"configurations x {len(names)} frames")
    assert worst_p <= TOL_M and worst_r <= TOL_RAD, (worst_p, worst_r)


def test_mjcf_reloaded_by_mujoco_matches_fk(calibrated, tmp_path):
    case, path, robot, eps, T, q = calibrated
    xml = export_robot(path, "mjcf", tmp_path / "ta40.xml")
    m = mujoco.MjModel.from_xml_path(str(xml))
    d = mujoco.MjData(m)
    assert m.nq == robot.n and np.array_equal(m.jnt_range, np.column_stack([robot.q_min, robot.q_max]))
    names = exported_frames(robot, T is not None)
    bodies = {n for n in names if n.startswith("body")}
    ids = {n: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY if n in bodies else mujoco.mjtObj.mjOBJ_SITE, n)
           for n in names}
    assert min(ids.values()) >= 0
    ref = reference_frames(robot, q, eps, T)
    worst_p = worst_r = 0.0
    for i, qi in enumerate(q):
        d.qpos[:] = qi
        mujoco.mj_kinematics(m, d)
        for n in names:
            pos, mat = (d.xpos, d.xmat) if n in bodies else (d.site_xpos, d.site_xmat)
            dp, dr = pose_errors(ref[n][i], homogeneous(mat[ids[n]].reshape(3, 3), pos[ids[n]]))
            worst_p, worst_r = max(worst_p, dp), max(worst_r, dr)
    print(f"parity MJCF/MuJoCo [{case}]: {worst_p:.2e} m, {worst_r:.2e} rad over {len(q)} "
          f"configurations x {len(names)} frames")
    assert worst_p <= TOL_M and worst_r <= TOL_RAD, (worst_p, worst_r)


def test_the_export_is_not_a_tautology(ta40):
    """A wrong error in the file moves Pinocchio's frames: the parity above is evidence."""
    rng = np.random.default_rng(3)
    eps = random_errors(rng)
    q = ta40.random_configurations(rng, 5)
    bad = eps.copy()
    bad[9] += 1e-6  # s1, 1 urad
    model = pin.buildModelFromXML(urdf_text(ta40, bad))
    data = model.createData()
    fid = model.getFrameId("ee", pin.FrameType.BODY)
    ref = reference_frames(ta40, q, eps, None)["ee"]
    diffs = []
    for i, qi in enumerate(q):
        pin.framesForwardKinematics(model, data, qi)
        diffs.append(np.abs(data.oMf[fid].translation - ref[i][:3, 3]).max())
    assert min(diffs) > 1e-8


def test_exact_parameters_are_written_verbatim(ta40):
    """Each DH parameter and error sits in its own placement, at full precision (no composed matrices)."""
    eps = random_errors(np.random.default_rng(4))
    text = urdf_text(ta40, eps)
    x3, y3, z3, s3, r3, p3 = (float(v) for v in eps[18:24])
    assert f'<origin xyz="{x3!r} {y3!r} {z3!r}" rpy="{p3!r} {s3!r} {r3!r}"/>' in text
    assert '<origin xyz="0 0 0.747" rpy="-1.5707963267948966 0 0"/>' in text  # S4 = Tz(747 mm) Rx(-90 deg)
    mj = mjcf_text(ta40, eps)
    assert f'euler="{r3!r} {s3!r} {p3!r}"' in mj and 'eulerseq="zyx"' in mj


@pytest.mark.parametrize("R", [np.eye(3), rot_y(np.pi / 2), rot_y(-np.pi / 2), rot_z(np.pi) @ rot_y(np.pi / 2 - 1e-9),
                               rot_x(np.pi), rot_z(-np.pi) @ rot_x(np.pi / 2), rot_y(np.pi / 2) @ rot_x(0.3)])
def test_rpy_round_trip_special(R):
    r, p, y = rpy_from_matrix(R)
    assert np.abs(rot_z(y) @ rot_y(p) @ rot_x(r) - R).max() <= 2e-16 * 8


def test_rpy_round_trip_random():
    Rs = random_rotation(np.random.default_rng(5), 500)
    err = max(np.abs(rot_z(y) @ rot_y(p) @ rot_x(r) - R).max() for R in Rs for r, p, y in [rpy_from_matrix(R)])
    assert err <= 2e-15


def test_cli_export_and_bad_inputs(tmp_path, ta40, capsys):
    good = write_calibrated_robot(tmp_path / "robot.yaml", default_robot_path(), ta40, np.zeros(42), np.eye(4))
    assert main(["export", str(good), "--format", "urdf", "--out", str(tmp_path / "a.urdf"),
                 "--velocity-deg-s", "30", "--effort-nm", "2000"]) == 0
    text = (tmp_path / "a.urdf").read_text()
    assert f'effort="2000" velocity="{math.radians(30.0)!r}"' in text and "unknown" not in text
    broken = tmp_path / "broken.yaml"
    broken.write_text("name: [unclosed\n")
    bad_units = tmp_path / "bad_units.yaml"
    bad_units.write_text(good.read_text().replace("a_mm: 753.0", "a: 753.0"))
    bad_mount = tmp_path / "bad_mount.yaml"
    bad_mount.write_text(good.read_text().replace("quaternion_wxyz:\n    - 1.0", "quaternion_wxyz:\n    - 2.0"))
    cases = [([str(tmp_path / "missing.yaml")], "missing.yaml: <file>: not found"),
             ([str(broken)], "broken.yaml: <file>: not valid YAML"),
             ([str(bad_units)], "bad_units.yaml: joints[1].a: unknown key"),
             ([str(bad_mount)], "bad_mount.yaml: calibration.camera_mount.quaternion_wxyz"),
             ([str(good), "--effort-nm", "-1"], "--effort-nm: expected a positive limit")]
    for args, msg in cases:
        out = tmp_path / "never.urdf"
        assert main(["export", *args, "--format", "urdf", "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert msg in err and len(err.splitlines()) == 1, err
        assert not out.exists()
