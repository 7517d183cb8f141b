"""The located base's tilt against the vehicle's INS (bench.vision.tilt, test 7): the simulator's file read back, the
disagreement exact on exact readings and blind to heading, its covariance against a Monte Carlo of the simulator's
own readings, and the verdict."""

import numpy as np
import pytest

from bench.errors import ConfigError
from bench.geometry.quaternion import matrix_to_rotation_vector, rotation_vector_to_matrix
from bench.geometry.transforms import homogeneous, rot_x, rot_y, rot_z
from bench.sim.ins import down_in_base, vehicle_yaml_text
from bench.vision.integrity import Integrity
from bench.vision.tilt import VehicleTilt, check, read_vehicle_yaml, tilt_covariance, tilt_disagreement

DEG = np.pi / 180


def _parkings(rng):
    """Two base poses in the world (z up) as the in-situ kind draws them: yaw, a little roll and pitch."""
    R1 = rot_z(rng.uniform(-10, 10) * DEG) @ rot_x(rng.uniform(-2, 2) * DEG) @ rot_y(rng.uniform(-2, 2) * DEG)
    T1 = homogeneous(R1, rng.uniform(-0.3, 0.3, 3))
    T2 = T1 @ homogeneous(rot_z(rng.uniform(-5, 5) * DEG) @ rot_x(rng.uniform(-1, 1) * DEG), rng.uniform(-0.1, 0.1, 3))
    return T1, T2


def test_the_simulators_file_reads_back(tmp_path):
    rng = np.random.default_rng(1)
    T1, T2 = _parkings(rng)
    (tmp_path / "vehicle.yaml").write_text(vehicle_yaml_text(T1, T2, 0.01, 0.05, rng))
    tilt = read_vehicle_yaml(tmp_path / "vehicle.yaml")
    assert tilt.tilt_sigma_rad == pytest.approx(0.01 * DEG) and tilt.alignment_sigma_rad == pytest.approx(0.05 * DEG)
    assert abs(np.linalg.norm(tilt.down_survey) - 1) < 1e-12 and abs(np.linalg.norm(tilt.down_locate) - 1) < 1e-12
    # within a few tenths of a degree of the truth (noise 0.01 deg, alignment 0.05 deg per axis)
    assert np.arccos(tilt.down_survey @ (T1[:3, :3].T @ [0, 0, -1])) < 0.3 * DEG


@pytest.mark.parametrize("text, field", [
    ("tilt_sigma_deg: 0.01\nalignment_sigma_deg: 0.05\nheading: 3\ndown_in_base: {survey: [0,0,-1], locate: [0,0,-1]}",
     "heading"),
    ("tilt_sigma_deg: 0\nalignment_sigma_deg: 0.05\ndown_in_base: {survey: [0,0,-1], locate: [0,0,-1]}",
     "tilt_sigma_deg"),
    ("tilt_sigma_deg: 0.01\nalignment_sigma_deg: .nan\ndown_in_base: {survey: [0,0,-1], locate: [0,0,-1]}",
     "alignment_sigma_deg"),
    ("tilt_sigma_deg: 0.01\nalignment_sigma_deg: 0.05\ndown_in_base: {survey: [0,0,-9.81], locate: [0,0,-1]}",
     "down_in_base.survey"),
    ("tilt_sigma_deg: 0.01\nalignment_sigma_deg: 0.05\ndown_in_base: {survey: [0,0,-1]}", "down_in_base"),
    ("- 1\n- 2\n", "<top>"),
])
def test_bad_files_are_one_line_errors_naming_the_field(tmp_path, text, field):
    (tmp_path / "vehicle.yaml").write_text(text)
    with pytest.raises(ConfigError, match=f"vehicle.yaml: {field}"):
        read_vehicle_yaml(tmp_path / "vehicle.yaml")


def test_disagreement_is_exact_and_blind_to_heading():
    """Exact readings and the true rotation: zero (1e-12); the rotation off by a turn about a horizontal axis: that
    angle's sine; about the vertical: nothing."""
    rng = np.random.default_rng(2)
    T1, T2 = _parkings(rng)
    exact = VehicleTilt(down_in_base(T1, 0.0, np.eye(3), rng), down_in_base(T2, 0.0, np.eye(3), rng), 1e-4, 1e-4)
    R = T1[:3, :3].T @ T2[:3, :3]  # the locate base in the survey base frame
    assert np.linalg.norm(tilt_disagreement(R, exact)) < 1e-12
    d = exact.down_survey
    h = np.cross(d, [1.0, 0, 0])
    h /= np.linalg.norm(h)
    for angle in (0.05 * DEG, 0.5 * DEG):
        assert np.linalg.norm(tilt_disagreement(rotation_vector_to_matrix(angle * h) @ R, exact)) == \
            pytest.approx(np.sin(angle), rel=1e-9)
        assert np.linalg.norm(tilt_disagreement(rotation_vector_to_matrix(angle * d) @ R, exact)) < 1e-12


def test_covariance_against_the_simulators_readings():
    """The Mahalanobis squares of the simulator's INS readings (noise and alignment drawn afresh, the true rotation,
    an exact pose) over :func:`tilt_covariance` are chi-square with 2 degrees of freedom: 1 % (+-0.4 % over 4000
    draws) beyond its 0.99 quantile, mean 2 (+-5 %); a pose covariance adds its horizontal part only."""
    from scipy.stats import chi2

    rng = np.random.default_rng(3)
    T1, T2 = _parkings(rng)
    T2 = T2 @ homogeneous(rot_z(15 * DEG), np.zeros(3))  # a large turn: the alignment matters
    R = T1[:3, :3].T @ T2[:3, :3]
    sig, ali = 0.01 * DEG, 0.05 * DEG
    m2 = []
    for _ in range(4000):
        A = rotation_vector_to_matrix(rng.normal(0, ali, 3))
        t = VehicleTilt(down_in_base(T1, sig, A, rng), down_in_base(T2, sig, A, rng), sig, ali)
        e = tilt_disagreement(R, t)
        m2.append(e @ np.linalg.pinv(tilt_covariance(R, np.zeros((3, 3)), t), rcond=1e-9) @ e)
    assert np.mean(np.array(m2) > chi2.ppf(0.99, 2)) == pytest.approx(0.01, abs=0.004)
    assert np.mean(m2) == pytest.approx(2.0, rel=0.05)
    d = t.down_survey
    C = tilt_covariance(R, np.outer(d, d) * 1e-6, t) - tilt_covariance(R, np.zeros((3, 3)), t)
    assert np.abs(C).max() < 1e-18  # a rotation about the vertical does not tilt


def test_check_refuses_a_tilt_the_covariance_and_the_ins_do_not_explain():
    rng = np.random.default_rng(4)
    T1, T2 = _parkings(rng)
    tilt = VehicleTilt(down_in_base(T1, 0.0, np.eye(3), rng), down_in_base(T2, 0.0, np.eye(3), rng), 0.01 * DEG,
                       0.05 * DEG)
    T = np.linalg.inv(T1) @ T2
    cov = np.diag(np.r_[np.full(3, (0.02 * DEG) ** 2), np.full(3, 1e-6)])
    ok = check(Integrity("ok", [], 2e-3, 0.08 * DEG, {}), T, cov, tilt)
    assert ok.level == "ok" and ok.tests["tilt_disagreement_deg"] < 1e-9 and ok.tests["tilt_mahalanobis_sq"] < 1e-12
    assert ok.tests["tilt_limit_sq"] == pytest.approx(13.8155, rel=1e-4)
    h = np.cross(tilt.down_survey, [0, 1.0, 0])
    knocked = homogeneous(rotation_vector_to_matrix(0.2 * DEG * h / np.linalg.norm(h)), np.zeros(3)) @ T
    bad = check(Integrity("warning", ["w"], 2e-3, 0.08 * DEG, {}), knocked, cov, tilt)
    assert bad.level == "refused" and "INS" in bad.reasons[0] and bad.reasons[1] == "w"
    assert bad.protection_radius_m == np.inf and bad.tests["tilt_disagreement_deg"] == pytest.approx(0.2, rel=1e-3)
    # the same turn inside a covariance that allows it (test 3's inflation counted): not refused
    wide = check(Integrity("ok", [], 2e-3, 0.3 * DEG, {"inflation_chi2": 4.0}), knocked, cov, tilt)
    assert wide.level == "ok"
    refused = Integrity("refused", ["r"], np.inf, np.inf, {})
    assert check(refused, knocked, cov, tilt) is refused and "tilt_disagreement_deg" not in refused.tests


def _random_covariance(rng, rot_deg=0.02, pos_mm=1.0):
    """A pose covariance (6, 6) with the size and correlation of a located base's: rotation and the origin tied
    through a lever arm of ~1.7 m."""
    w = rng.normal(0, rot_deg * DEG, (200, 3))
    lever = rng.normal(0, 0.3, 3) + [1.7, 0, 0]
    v = np.cross(w, lever) + rng.normal(0, pos_mm * 1e-3 / 3, (200, 3))
    return np.cov(np.hstack([w, v]).T)


def test_fuse_is_the_information_form_update():
    """The gain form of the update equals its information form (1e-9 relative): the covariance
    ``(C^-1 + H^T S^-1 H)^-1`` and the correction ``-(C^-1 + H^T S^-1 H)^-1 H^T S^-1 z``; the update touches
    nothing the tilt does not see (a heading-only covariance is unchanged); test 3's inflation weighs the pose
    but comes back out of the returned covariance."""
    from bench.vision.tilt import fuse, tilt_update

    rng = np.random.default_rng(5)
    T1, T2 = _parkings(rng)
    tilt = VehicleTilt(down_in_base(T1, 0.01 * DEG, np.eye(3), rng), down_in_base(T2, 0.01 * DEG, np.eye(3), rng),
                       0.01 * DEG, 0.05 * DEG)
    T = np.linalg.inv(T1) @ T2 @ homogeneous(rotation_vector_to_matrix(rng.normal(0, 0.02 * DEG, 3)),
                                             rng.normal(0, 1e-3, 3))
    C = _random_covariance(rng)
    upd = tilt_update(T[:3, :3], C, tilt)
    info = np.linalg.inv(C) + upd.H.T @ np.linalg.solve(upd.S, upd.H)
    Cf = np.linalg.inv(info)
    assert np.abs(upd.covariance(C) - Cf).max() < 1e-9 * np.abs(Cf).max()
    T_f, C_f, dx = fuse(T, C, tilt)
    B = np.linalg.svd(np.eye(3) - np.outer(tilt.down_survey, tilt.down_survey))[0][:, :2]
    z = B.T @ tilt_disagreement(T[:3, :3], tilt)
    assert np.allclose(dx, -Cf @ upd.H.T @ np.linalg.solve(upd.S, z), rtol=1e-9, atol=1e-15)
    assert np.allclose(T_f[:3, 3], T[:3, 3] + dx[3:], atol=1e-15) and np.abs(C_f - Cf).max() < 1e-9 * np.abs(Cf).max()
    # the fused pose's tilt agrees with the INS better than the images' did (most of z is the pose's error)
    assert np.linalg.norm(tilt_disagreement(T_f[:3, :3], tilt)) < 0.5 * np.linalg.norm(z)
    # inflation: the pose weighed by f^2 C, the covariance returned in C's scale
    T_i, C_i, _ = fuse(T, C, tilt, inflation=3.0)
    assert np.abs(C_i - tilt_update(T[:3, :3], 9 * C, tilt).covariance(9 * C) / 9).max() < 1e-12 * np.abs(C).max()
    # a pose uncertain only about the vertical: the tilt adds nothing (exact: its information is horizontal)
    d = tilt.down_survey
    C_v = np.zeros((6, 6))
    C_v[:3, :3], C_v[3:, 3:] = np.outer(d, d) * (0.05 * DEG) ** 2, np.eye(3) * 1e-6
    assert np.abs(tilt_update(T[:3, :3], C_v, tilt).covariance(C_v) - C_v).max() < 1e-9 * np.abs(C_v).max()


def test_fused_errors_follow_the_fused_covariance():
    """4000 draws of the images' error from C and of the simulator's INS (noise, alignment afresh): the fused errors'
    Mahalanobis squares over the fused covariance are chi-square with 6 degrees of freedom (1 % +- 0.4 % beyond its
    0.99 quantile, mean 6 +- 5 %), and the horizontal rotation's RMS falls below both the images' and the INS's."""
    from scipy.stats import chi2

    from bench.vision.tilt import fuse

    rng = np.random.default_rng(6)
    T1, T2 = _parkings(rng)
    T_true = np.linalg.inv(T1) @ T2
    C = _random_covariance(rng, rot_deg=0.03)
    L = np.linalg.cholesky(C)
    sig, ali = 0.01 * DEG, 0.05 * DEG
    m2, before, after = [], [], []
    for _ in range(4000):
        e = L @ rng.normal(size=6)
        T = homogeneous(rotation_vector_to_matrix(e[:3]) @ T_true[:3, :3], T_true[:3, 3] + e[3:])
        A = rotation_vector_to_matrix(rng.normal(0, ali, 3))
        tilt = VehicleTilt(down_in_base(T1, sig, A, rng), down_in_base(T2, sig, A, rng), sig, ali)
        T_f, C_f, _ = fuse(T, C, tilt)
        w = matrix_to_rotation_vector(T_f[:3, :3] @ T_true[:3, :3].T)
        ef = np.r_[w, T_f[:3, 3] - T_true[:3, 3]]
        m2.append(ef @ np.linalg.solve(C_f, ef))
        P = np.eye(3) - np.outer(tilt.down_survey, tilt.down_survey)
        before.append(np.linalg.norm(P @ e[:3]))
        after.append(np.linalg.norm(P @ w))
    m2 = np.array(m2)
    assert np.mean(m2 > chi2.ppf(0.99, 6)) == pytest.approx(0.01, abs=0.004)
    assert np.mean(m2) == pytest.approx(6.0, rel=0.05)
    rms = lambda a: float(np.sqrt(np.mean(np.square(a))))  # noqa: E731
    assert rms(after) < 0.6 * rms(before) and rms(after) < np.sqrt(2) * sig * np.sqrt(2)


def test_relevel_follows_the_new_covariance():
    """The protection levels from a new covariance: the alert limits' warning goes when they fall within them, the
    other reasons stay, a refusal is untouched."""
    from bench.vision.integrity import ALERT_DEG, protection_levels, relevel

    wide = np.diag(np.r_[np.full(3, (0.06 * DEG) ** 2), np.full(3, (1.2e-3) ** 2)])
    narrow = wide / 9
    tests = {"inflation_chi2": 1.0}
    pr, pa = protection_levels(wide, dict(tests))
    assert np.rad2deg(pa) > ALERT_DEG  # the wide covariance is beyond the alert limits
    from bench.vision.integrity import _alert

    integ = relevel(Integrity("warning", ["w", _alert(pr, pa)], pr, pa, dict(tests)), narrow)
    assert integ.level == "warning" and integ.reasons == ["w"] and integ.protection_angle_rad < pa
    assert relevel(Integrity("warning", [_alert(pr, pa)], pr, pa, dict(tests)), narrow).level == "ok"
    back = relevel(Integrity("ok", [], *protection_levels(narrow, dict(tests)), dict(tests)), wide)
    assert back.level == "warning" and "alert limit" in back.reasons[0]
    refused = Integrity("refused", ["r"], np.inf, np.inf, dict(tests))
    assert relevel(refused, narrow) is refused and refused.protection_radius_m == np.inf
