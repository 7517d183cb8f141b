import numpy as np
import pytest

from bench.errors import ConfigError
from bench.geometry.transforms import vee
from bench.robot.jacobian import identification_jacobian
from bench.robot.kinematics import ee_position, error_matrix, forward_kinematics, link_frames
from bench.robot.model import error_names, random_errors, robot_from_dict


def _fd_jacobian(robot, q, eps, form, h=1e-7):
    J = np.zeros(q.shape[:-1] + (6, robot.n_errors))
    T0 = forward_kinematics(robot, q, eps, form)
    for k in range(robot.n_errors):
        e1, e2 = eps.copy(), eps.copy()
        e1[k] += h
        e2[k] -= h
        T1, T2 = forward_kinematics(robot, q, e1, form), forward_kinematics(robot, q, e2, form)
        J[..., :3, k] = (T1[..., :3, :3] @ robot.p_ee + T1[..., :3, 3] - T2[..., :3, :3] @ robot.p_ee
                         - T2[..., :3, 3]) / (2 * h)
        J[..., 3:, k] = vee((T1[..., :3, :3] - T2[..., :3, :3]) / (2 * h) @ np.swapaxes(T0[..., :3, :3], -1, -2))
    return J


def test_names_follow_table2_order():
    names = error_names()
    assert names[:6] == ["x0", "y0", "z0", "s0", "r0", "p0"] and names[-1] == "p6" and len(names) == 42


def test_nominal_fk_matches_table1_home(ta40):
    # q = 0: x' = a1 + a2 + a3 + d4*s23 ... closed form of Appendix A at all-zero angles
    p = ee_position(ta40, np.zeros(6))
    assert np.allclose(p, [0.115 + 0.753 + 0.188, 0.0, -0.747 - 0.360], atol=1e-12)


def test_error_forms_agree_to_first_order(rng):
    e = rng.normal(size=6) * 1e-6
    assert np.abs(error_matrix(e, "exact") - error_matrix(e, "linear")).max() < 1e-11
    assert np.allclose(error_matrix(np.zeros(6), "exact"), np.eye(4))


@pytest.mark.parametrize("form", ["exact", "linear"])
def test_identification_jacobian_matches_finite_differences(ta40, rng, form):
    q = ta40.random_configurations(rng, 8)
    for eps in (np.zeros(42), random_errors(rng)):
        J = identification_jacobian(ta40, q, eps, form, rows="pose")
        Jfd = _fd_jacobian(ta40, q, eps, form)
        assert np.abs(J[..., :3, :] - Jfd[..., :3, :]).max() < 1e-8  # m per unit error
        if form == "exact":
            assert np.abs(J[..., 3:, :] - Jfd[..., 3:, :]).max() < 1e-8
        assert np.allclose(identification_jacobian(ta40, q, eps, form)[..., :, :], J[..., :3, :])


def test_off_axis_point_jacobian(ta40, rng):
    robot = ta40.with_ee_point([0.05, -0.02, 0.1])
    q = robot.random_configurations(rng, 4)
    eps = random_errors(rng)
    assert np.abs(identification_jacobian(robot, q, eps, "exact", "pose") - _fd_jacobian(robot, q, eps,
                                                                                         "exact")).max() < 1e-8


def test_batched_shapes(ta40, rng):
    q = ta40.random_configurations(rng, 12).reshape(3, 4, 6)
    assert link_frames(ta40, q).shape == (3, 4, 7, 4, 4)
    assert identification_jacobian(ta40, q, rows="pose").shape == (3, 4, 6, 42)
    single = forward_kinematics(ta40, q[1, 2])
    assert np.allclose(single, forward_kinematics(ta40, q)[1, 2])


def test_exact_frames_are_rigid(ta40, rng):
    T = link_frames(ta40, ta40.random_configurations(rng, 50), random_errors(rng))
    R = T[..., :3, :3]
    assert np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max() < 1e-12


def test_bad_inputs(ta40):
    with pytest.raises(ValueError, match="NaN"):
        ee_position(ta40, [0, 0, np.nan, 0, 0, 0])
    with pytest.raises(ValueError, match="shape"):
        ee_position(ta40, np.zeros(5))
    with pytest.raises(ValueError, match="degrees"):
        ee_position(ta40, [0, 45, 90, 0, 30, 0])  # degrees given where radians are expected
    with pytest.raises(ValueError, match="eps"):
        ee_position(ta40, np.zeros(6), eps=np.zeros(41))


def _joint(**kw):
    j = {"a_mm": 1.0, "d_mm": 0.0, "alpha_deg": 0.0, "min_deg": -90, "max_deg": 90}
    j.update(kw)
    return j


@pytest.mark.parametrize(
    "data, field",
    [
        ({"name": "x"}, "joints"),
        ({"name": "x", "joints": [_joint()], "colour": 1}, "colour"),
        ({"name": "x", "joints": [{**_joint(), "a": 1.0}]}, "joints[0].a"),
        ({"name": "x", "joints": [_joint(a_mm="big")]}, "joints[0].a_mm"),
        ({"name": "x", "joints": [_joint(min_deg=10, max_deg=0)]}, "joints[0].min_deg"),
        ({"name": "x", "joints": [_joint(alpha_deg=1000)]}, "joints[0].alpha_deg"),
        ({"name": "x", "joints": [_joint()], "units": {"length": "m", "angle": "rad"}}, "units.length"),
        ({"name": "x", "joints": [_joint(type="prismatic")]}, "joints[0].type"),
    ],
)
def test_malformed_robot_file_names_the_field(data, field):
    with pytest.raises(ConfigError) as info:
        robot_from_dict(data, "robot.yaml")
    assert info.value.field == field
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    "edit, field, match",
    [
        (("joints[1]", "a_mm", 0.753), "joints[1].a_mm", "metres given where mm belong"),  # 753 mm in metres
        (("joints[3]", "alpha_deg", -1.5708), "joints[3].alpha_deg", "looks like radians"),
        (("joints[0]", "alpha_deg", 1.571), "joints[0].alpha_deg", "looks like radians"),
        (("joints[2]", "theta_offset_deg", 3.1416), "joints[2].theta_offset_deg", "looks like radians"),
        ("metres", "joints[1].a_mm", "metres given where mm belong"),  # every length in metres
        ("radian limits", "joints[0].min_deg", "radians given where degrees belong"),
    ],
)
def test_wrong_units_in_the_robot_file_are_refused(edit, field, match):
    """Values in the wrong unit under a unit-keyed name (audit: loaded silently before)."""
    import yaml

    from bench.robot.model import default_robot_path

    data = yaml.safe_load(default_robot_path().read_text())
    if edit == "metres":
        for j in data["joints"]:
            j["a_mm"], j["d_mm"] = j["a_mm"] * 1e-3, j["d_mm"] * 1e-3
    elif edit == "radian limits":
        for j in data["joints"]:
            j["min_deg"], j["max_deg"] = np.deg2rad(j["min_deg"]), np.deg2rad(j["max_deg"])
    else:
        where, key, value = edit
        data["joints"][int(where[7])][key] = value
    with pytest.raises(ConfigError, match=match) as info:
        robot_from_dict(data, "ta40.yaml")
    assert info.value.field == field and "\n" not in str(info.value)
    robot_from_dict(yaml.safe_load(default_robot_path().read_text()), "ta40.yaml")  # the real file passes
