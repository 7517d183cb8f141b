"""Pinocchio as the independent judge of our kinematics (issue 2, items 4 and 11).

The Pinocchio model (bench.judge.pinocchio_model) is built from the DH table and the exact error form with
Pinocchio's own SE(3) tools; here it is compared, live, with bench.robot.kinematics (FK), bench.robot.jacobian
(identification Jacobian, against Pinocchio's kinematic regressor) and bench.robot.identification (the identified
model, checked against a Pinocchio-simulated truth).
"""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from bench.judge.pinocchio_model import (
    FRAME_NAMES,
    PinocchioArm,
    build_pinocchio_model,
    error_twist_map,
    pinocchio_ee_position,
    pinocchio_frames,
    regressor_error_jacobian,
)
from bench.robot.identifiability import closed_form_reduction
from bench.robot.identification import identify_iterative
from bench.robot.jacobian import identification_jacobian
from bench.robot.kinematics import ee_position, link_frames
from bench.robot.model import random_errors
from bench.scenario.kinematic_identification import from_thesis_units, load_error_table

TABLE2 = "scenarios/data/table2_thesis.csv"
SIGMA = 0.05e-3  # tracker noise per axis (m)


def _table2_eps():
    path = Path(__file__).resolve().parents[2] / TABLE2
    return from_thesis_units(np.array(load_error_table(path)["full"]))


def _error_sets():
    return {"nominal": None, "random": random_errors(np.random.default_rng(11)), "table2": _table2_eps()}


def _variant_robot(ta40):
    """The TA-40 with non-zero DH angle offsets and an off-axis measured point: exercises every placement term."""
    return replace(ta40, theta_offset=np.deg2rad([5.0, -90.0, 30.0, 0.0, 12.0, -45.0])).with_ee_point(
        [0.05, -0.02, 0.1])


# ---------------------------------------------------------------------------------------------------------------- FK

@pytest.mark.parametrize("errors", ["nominal", "random", "table2"])
def test_fk_agrees_with_pinocchio(ta40, errors):
    eps = _error_sets()[errors]
    q = ta40.random_configurations(np.random.default_rng(101), 1000)
    T_pin = pinocchio_frames(ta40, q, eps)
    T_ours = link_frames(ta40, q, eps, form="exact")
    assert T_pin.shape == (1000, 7, 4, 4)
    assert np.abs(T_pin[..., :3, 3] - T_ours[..., :3, 3]).max() <= 1e-9  # m, frames 0..6
    assert np.abs(T_pin[..., :3, :3] - T_ours[..., :3, :3]).max() <= 1e-9  # rotation entries
    assert np.abs(pinocchio_ee_position(ta40, q, eps) - ee_position(ta40, q, eps, form="exact")).max() <= 1e-9
    if eps is not None:  # the comparison is not blind to the errors: they move the frames by millimetres
        assert np.abs(T_pin[..., :3, 3] - link_frames(ta40, q)[..., :3, 3]).max() > 1e-3


def test_fk_agrees_with_offsets_and_off_axis_point(ta40):
    robot = _variant_robot(ta40)
    eps = random_errors(np.random.default_rng(12))
    q = robot.random_configurations(np.random.default_rng(102), 200).reshape(10, 20, 6)  # any leading shape
    T_pin = pinocchio_frames(robot, q, eps)
    assert T_pin.shape == (10, 20, 7, 4, 4)
    assert np.abs(T_pin - link_frames(robot, q, eps)).max() <= 1e-9
    p_pin = pinocchio_ee_position(robot, q, eps)
    assert p_pin.shape == (10, 20, 3)
    assert np.abs(p_pin - ee_position(robot, q, eps)).max() <= 1e-9


def test_model_structure(ta40):
    eps = random_errors(np.random.default_rng(13))
    model = build_pinocchio_model(ta40, eps)
    assert model.nq == model.nv == 6
    assert [model.names[i] for i in range(1, 7)] == [f"joint{i}" for i in range(1, 7)]
    assert np.allclose(model.lowerPositionLimit, ta40.q_min) and np.allclose(model.upperPositionLimit, ta40.q_max)
    for name in (*FRAME_NAMES, "link5", "ee_point"):
        assert model.existFrame(name)
    # link5 is frame 5; ee_point is p_ee on frame 6; frame0 is E0 whatever the configuration
    data = model.createData()
    q = ta40.random_configurations(np.random.default_rng(103), 1)[0]
    pin.framesForwardKinematics(model, data, q)
    oMf = {name: data.oMf[model.getFrameId(name)] for name in ("frame0", "frame5", "link5", "frame6", "ee_point")}
    assert np.abs(oMf["link5"].homogeneous - oMf["frame5"].homogeneous).max() == 0.0
    assert np.abs(oMf["ee_point"].translation - oMf["frame6"].act(ta40.p_ee)).max() <= 1e-12
    assert np.abs(oMf["frame0"].homogeneous - link_frames(ta40, q, eps)[0]).max() <= 1e-15


# ----------------------------------------------------------------------------------------------- kinematic regressor

def test_regressor_convention_is_right_perturbation_of_joint_placement(ta40):
    """What Pinocchio's regressor is, checked on Pinocchio alone: block i-1 (LOCAL_WORLD_ALIGNED) is the derivative
    of the ee frame's (v, w) w.r.t. xi in ``jointPlacements[i] -> jointPlacements[i] exp6(xi)``."""
    arm = PinocchioArm(ta40, random_errors(np.random.default_rng(14)))
    q = ta40.random_configurations(np.random.default_rng(104), 1)[0]
    K = arm.regressor(q)
    fid, h = arm.ee_id, 1e-6

    def ee_pose(model):
        data = model.createData()
        pin.framesForwardKinematics(model, data, q)
        return data.oMf[fid].copy()

    for i in range(1, 7):
        for k in range(6):
            poses = []
            for sign in (1.0, -1.0):
                model = arm.model.copy()
                xi = np.zeros(6)
                xi[k] = sign * h
                model.jointPlacements[i] = model.jointPlacements[i] * pin.exp6(xi)
                poses.append(ee_pose(model))
            v = (poses[0].translation - poses[1].translation) / (2 * h)
            W = (poses[0].rotation - poses[1].rotation) / (2 * h) @ poses[0].rotation.T
            w = np.array([W[2, 1] - W[1, 2], W[0, 2] - W[2, 0], W[1, 0] - W[0, 1]]) / 2
            col = K[:, 6 * (i - 1) + k]
            assert np.abs(col - np.concatenate([v, w])).max() <= 1e-8, (i, k)


def test_twist_map_at_zero_is_the_se3_basis():
    """At e = 0 and zero joint offset, d E / d(x, y, z, s, r, p) is the se3 basis (v, w) with w = (p, s, r)."""
    P = np.zeros((6, 6))
    for col, row in enumerate([0, 1, 2, 4, 5, 3]):  # x->v_x, y->v_y, z->v_z, s->w_y, r->w_z, p->w_x
        P[row, col] = 1.0
    assert np.array_equal(error_twist_map(np.zeros(6)), P)


@pytest.mark.parametrize("errors", ["nominal", "random", "table2"])
@pytest.mark.parametrize("variant", [False, True])
def test_regressor_equals_identification_jacobian(ta40, errors, variant):
    """Columns 0..35 (errors of frames 0..5, i.e. E_(i-1) = the end of joint i's placement) of our analytic pose
    Jacobian equal Pinocchio's regressor of the ``ee_point`` frame mapped by the error twist map; the last frame's
    six columns (E6, inside the frame placement) are outside the regressor's scope - see the finite-difference test."""
    robot = _variant_robot(ta40) if variant else ta40
    eps = _error_sets()[errors]
    q = robot.random_configurations(np.random.default_rng(105), 50)
    J = identification_jacobian(robot, q, eps, form="exact", rows="pose")
    J_pin = regressor_error_jacobian(robot, q, eps)
    assert J_pin.shape == (50, 6, 36)
    assert np.abs(J[..., :36] - J_pin).max() <= 1e-9


def test_regressor_reference_frames(ta40):
    """The three reference frames of the regressor, converted to ours (point velocity and base rotation vector):
    LOCAL_WORLD_ALIGNED is ours directly; WORLD is the spatial velocity at the base origin (v_p = v + w x p);
    LOCAL is expressed in the ee frame (rotate by R_base_ee)."""
    eps = random_errors(np.random.default_rng(15))
    arm = PinocchioArm(ta40, eps)
    q = ta40.random_configurations(np.random.default_rng(106), 20)
    K = {ref: arm.regressor(q, "ee_point", ref) for ref in ("LOCAL_WORLD_ALIGNED", "WORLD", "LOCAL")}
    T = link_frames(ta40, q, eps)[:, 6]
    p = ee_position(ta40, q, eps)
    R = T[:, :3, :3]
    world_v = K["WORLD"][:, :3] + np.cross(K["WORLD"][:, 3:], p[:, :, None], axisa=1, axisb=1, axisc=1)
    local_v, local_w = R @ K["LOCAL"][:, :3], R @ K["LOCAL"][:, 3:]
    lwa = K["LOCAL_WORLD_ALIGNED"]
    assert np.abs(world_v - lwa[:, :3]).max() <= 1e-9 and np.abs(K["WORLD"][:, 3:] - lwa[:, 3:]).max() <= 1e-9
    assert np.abs(local_v - lwa[:, :3]).max() <= 1e-9 and np.abs(local_w - lwa[:, 3:]).max() <= 1e-9


@pytest.mark.parametrize("variant", [False, True])
def test_last_frame_columns_by_finite_differences_of_pinocchio(ta40, variant):
    """E6 (the ``ee_point`` frame placement) is outside the regressor's scope: its six columns of our Jacobian are
    checked against central differences of Pinocchio FK (models rebuilt at eps +- h). Translations enter linearly
    (error ~ roundoff eps_mach / h ~ 1e-11); rotations have truncation ~ h^2 |p - o6| / 6 ~ 1e-11 at h = 1e-5."""
    robot = _variant_robot(ta40) if variant else ta40
    eps = random_errors(np.random.default_rng(16))
    q = robot.random_configurations(np.random.default_rng(107), 20)
    J = identification_jacobian(robot, q, eps, form="exact", rows="pose")
    h = 1e-5
    for k in range(36, 42):
        out = []
        for sign in (1.0, -1.0):
            e = eps.copy()
            e[k] += sign * h
            arm = PinocchioArm(robot, e)
            out.append((arm.ee_position(q), arm.frames(q)[:, 6, :3, :3]))
        dp = (out[0][0] - out[1][0]) / (2 * h)
        W = (out[0][1] - out[1][1]) / (2 * h) @ np.swapaxes(PinocchioArm(robot, eps).frames(q)[:, 6, :3, :3], -1, -2)
        w = np.stack([W[:, 2, 1] - W[:, 1, 2], W[:, 0, 2] - W[:, 2, 0], W[:, 1, 0] - W[:, 0, 1]], axis=-1) / 2
        assert np.abs(J[:, :3, k] - dp).max() <= 1e-9, k
        assert np.abs(J[:, 3:, k] - w).max() <= 1e-9, k
    if not variant:  # O6 is frame 6's origin: its rotations cannot move the measured point (Eq. 23)
        assert np.abs(J[:, :3, 39:42]).max() == 0.0


# ----------------------------------------------------------------------------------- identified model, Pinocchio truth

def _on_axis_truth(rng):
    """Random errors with x6 = y6 = 0: the measured point stays on the joint-6 axis, as Eq. 167 assumes."""
    eps = random_errors(rng)
    eps[36:38] = 0.0
    return eps


@pytest.fixture(scope="module")
def identification_setup(ta40):
    rng = np.random.default_rng(2024)
    eps_true = _on_axis_truth(rng)
    truth = PinocchioArm(ta40, eps_true)
    q, q_held = ta40.random_configurations(rng, 100), ta40.random_configurations(rng, 500)
    return {"rng": rng, "eps_true": eps_true, "q": q, "q_held": q_held, "p": truth.ee_position(q),
            "p_held": truth.ee_position(q_held), "reduction": closed_form_reduction(ta40)}


def _predicted_sq(robot, q_held, result, reduction):
    """Propagated covariance of the held-out points: tr(G C G^T) per point (m^2)."""
    G = identification_jacobian(robot, q_held, result.eps)[..., reduction.kept]
    return np.einsum("nij,jk,nik->n", G, result.covariance, G)


def test_identified_model_noise_free_is_exact_on_pinocchio_truth(ta40, identification_setup):
    s = identification_setup
    res = identify_iterative(ta40, s["q"], s["p"], s["reduction"], sigma=SIGMA)
    assert res.success, res.message
    p_id = pinocchio_ee_position(ta40, s["q_held"], res.eps)
    assert np.abs(p_id - ee_position(ta40, s["q_held"], res.eps)).max() <= 1e-9
    assert np.linalg.norm(p_id - s["p_held"], axis=-1).max() <= 1e-9  # 1e-6 mm, the noise-free target


def test_identified_model_checked_by_pinocchio(ta40, identification_setup):
    """One noisy campaign (sigma = 0.05 mm): (a) Pinocchio of the identified eps equals our FK of it; (b) the
    held-out distance to the Pinocchio truth is bounded by the propagated covariance: RMS <= 3 x predicted RMS, where
    predicted MS = mean tr(G C G^T) (a 3x excess of a chi-square-like quadratic form with ~25 dof is improbable)."""
    s = identification_setup
    rng = np.random.default_rng(77)
    p_meas = s["p"] + rng.normal(0.0, SIGMA, s["p"].shape)
    res = identify_iterative(ta40, s["q"], p_meas, s["reduction"], sigma=SIGMA)
    assert res.success, res.message
    p_id = pinocchio_ee_position(ta40, s["q_held"], res.eps)
    assert np.abs(p_id - ee_position(ta40, s["q_held"], res.eps)).max() <= 1e-9  # (a)
    rms = np.sqrt(np.mean(np.sum((p_id - s["p_held"]) ** 2, axis=-1)))
    rms_pred = np.sqrt(np.mean(_predicted_sq(ta40, s["q_held"], res, s["reduction"])))
    assert rms <= 3.0 * rms_pred, (rms, rms_pred)  # (b)
    rms_uncal = np.sqrt(np.mean(np.sum((ee_position(ta40, s["q_held"]) - s["p_held"]) ** 2, axis=-1)))
    assert rms < rms_uncal / 50  # calibration removes the millimetre-level errors


def test_identified_model_error_matches_covariance_monte_carlo(ta40, identification_setup):
    """Over 30 noise draws the mean held-out squared error (Pinocchio truth) agrees with the propagated covariance.
    For d = G delta, delta ~ N(0, C): Q = mean_j |G_j delta|^2 = delta^T H delta, E[Q] = tr(HC),
    Var[Q] = 2 tr((HC)^2); the mean of N draws must lie within 4 standard errors of tr(HC)."""
    s = identification_setup
    rng = np.random.default_rng(78)
    n_draws, red, qh = 30, s["reduction"], s["q_held"]
    Q = []
    for _ in range(n_draws):
        res = identify_iterative(ta40, s["q"], s["p"] + rng.normal(0.0, SIGMA, s["p"].shape), red, sigma=SIGMA)
        assert res.success, res.message
        Q.append(np.mean(np.sum((PinocchioArm(ta40, res.eps).ee_position(qh) - s["p_held"]) ** 2, axis=-1)))
    G = identification_jacobian(ta40, qh, res.eps)[..., red.kept]
    H = np.einsum("nij,nik->jk", G, G) / len(qh)
    HC = H @ res.covariance
    mean_pred, sd_pred = np.trace(HC), np.sqrt(2 * np.trace(HC @ HC) / n_draws)
    assert abs(np.mean(Q) - mean_pred) <= 4 * sd_pred, (np.mean(Q), mean_pred, sd_pred)


def test_point_off_joint6_axis_leaves_a_second_order_model_error(ta40):
    """A finding the judge exposes: with x6, y6 != 0 the true measured point is off the joint-6 axis, so Eq. 167's
    merges (s5 -> x5, y5 -> p5) are exact only to first order. The identified model's joint-6 axis is tilted by
    phi = |(s5*, y5*/d6)| (Eq. 21 values s5* = s5 + r4, y5* = y5 + z4) relative to the truth, so the offset
    rho = |(x6, y6)| circling that axis leaves an error of length rho phi whose out-of-plane part varies as
    cos(theta6): held-out RMS = rho phi / sqrt(2) (noise-free), not zero."""
    rng = np.random.default_rng(31)
    eps = random_errors(rng)
    q, qh = ta40.random_configurations(rng, 100), ta40.random_configurations(rng, 500)
    truth = PinocchioArm(ta40, eps)
    res = identify_iterative(ta40, q, truth.ee_position(q), closed_form_reduction(ta40), sigma=SIGMA)
    assert res.success, res.message
    rms = np.sqrt(np.mean(np.sum((pinocchio_ee_position(ta40, qh, res.eps) - truth.ee_position(qh)) ** 2, -1)))
    e4, e5 = eps[24:30], eps[30:36]
    phi = np.hypot(e5[3] + e4[4], (e5[1] + e4[2]) / ta40.d[5])
    predicted = np.hypot(eps[36], eps[37]) * phi / np.sqrt(2)
    assert 0.9 * predicted <= rms <= 1.15 * predicted, (rms, predicted)


# ------------------------------------------------------------------------------------------------------- bad input

@pytest.mark.parametrize("call, match", [
    (lambda r: pinocchio_frames(r, np.zeros(5)), r"^q: expected shape \(\.\.\., 6\)"),
    (lambda r: pinocchio_frames(r, np.zeros((3, 7))), r"^q: expected shape"),
    (lambda r: pinocchio_frames(r, 0.0), r"^q: expected shape"),
    (lambda r: pinocchio_ee_position(r, np.full(6, np.nan)), r"^q: contains NaN"),
    (lambda r: pinocchio_frames(r, np.zeros(6), np.zeros(41)), r"^eps: expected shape \(42,\)"),
    (lambda r: build_pinocchio_model(r, np.full(42, np.inf)), r"^eps: contains NaN"),
    (lambda r: regressor_error_jacobian(r, np.zeros(6), np.zeros((7, 6))), r"^eps: expected shape"),
    (lambda r: PinocchioArm(r).regressor(np.zeros(6), frame="tool"), r"^frame: unknown frame 'tool'"),
    (lambda r: PinocchioArm(r).regressor(np.zeros(6), reference="BASE"), r"^reference: expected one of"),
])
def test_bad_input_is_a_one_line_error(ta40, call, match):
    with pytest.raises(ValueError, match=match) as info:
        call(ta40)
    assert "\n" not in str(info.value)
