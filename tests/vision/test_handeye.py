import numpy as np
import pytest

from bench.geometry.transforms import homogeneous, invert, random_transform, rot_y, rotation_angle, transform_points
from bench.vision.features import Features
from bench.vision.handeye import METHODS, hand_eye_axxb, mount_rotation, search_mount_rotation
from bench.vision.insitu import ViewObservation

DEG = np.pi / 180


def _axxb_data(rng, n=12, sigma_rot=0.0, sigma_t=0.0):
    X = homogeneous(mount_rotation(*(rng.uniform(-3, 3, 3) * DEG)) @ rot_y(0.3), [0.1, -0.03, 0.2])
    T_bt = random_transform(rng, scale=1.0)
    A = random_transform(rng, size=n, scale=0.5)
    B = invert(X) @ invert(A) @ T_bt
    if sigma_rot or sigma_t:
        for k in range(n):
            w = rng.normal(0, sigma_rot, 3)
            th = np.linalg.norm(w)
            K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]) / th
            B[k, :3, :3] = (np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K) @ B[k, :3, :3]
            B[k, :3, 3] += rng.normal(0, sigma_t, 3)
    return A, B, X, T_bt


@pytest.mark.parametrize("method", METHODS)
def test_axxb_noise_free_exact(method):
    A, B, X, T_bt = _axxb_data(np.random.default_rng(51))
    res = hand_eye_axxb(A, B, method=method)
    assert res.success, res.message
    assert np.abs(res.T_mount_cam - X).max() <= 1e-9 and np.abs(res.T_base_target - T_bt).max() <= 1e-9
    assert res.rms_trans_m <= 1e-9


def test_axxb_noisy_and_degenerate():
    A, B, X, _ = _axxb_data(np.random.default_rng(52), n=20, sigma_rot=0.5 * DEG, sigma_t=0.5e-3)
    res = hand_eye_axxb(A, B)
    assert res.success and np.linalg.norm(res.T_mount_cam[:3, 3] - X[:3, 3]) < 5e-3
    assert rotation_angle(res.T_mount_cam[:3, :3].T @ X[:3, :3]) < 0.5 * DEG
    # every motion a rotation about one fixed axis: X is not determined
    A1 = np.stack([homogeneous(rot_y(a), [0.1 * a, 0, 0]) for a in np.linspace(0, 1, 6)])
    bad = hand_eye_axxb(A1, invert(X) @ invert(A1))
    assert not bad.success and "single axis" in bad.message
    assert not hand_eye_axxb(A[:2], B[:2]).success
    with pytest.raises(ValueError, match="method"):
        hand_eye_axxb(A, B, method="magic")
    with pytest.raises(ValueError, match="T_cam_target"):
        hand_eye_axxb(A, B[:, :3])


def test_thesis_search_finds_the_mount_rotation():
    """x-y table of section 5.2.2 (Table 4 pattern): translations along x with small turns about y."""
    rng = np.random.default_rng(53)
    ty0, tz0 = 2.0 * DEG, -1.5 * DEG
    t_mc = np.array([0.0, 0.0, 0.0])
    X = homogeneous(mount_rotation(0.0, ty0, tz0), t_mc)
    n_pts = 300
    p = np.column_stack([rng.uniform(-0.3, 0.3, n_pts), rng.uniform(-0.2, 0.2, n_pts), rng.uniform(0.6, 0.8, n_pts)])
    desc = rng.normal(size=(n_pts, 128)).astype(np.float32)
    poses = [homogeneous(rot_y(-dx * 0.08), [dx, 0, 0]) for dx in np.linspace(-0.1, 0.1, 11)]  # about Table 4

    def obs(T_base_mount):
        pc = transform_points(invert(T_base_mount @ X), p)
        x = pc[:, :2] / pc[:, 2:3]
        f = Features(x * 1000, np.zeros(n_pts), np.ones(n_pts), np.ones(n_pts), desc)
        return ViewObservation("v", f, x, np.eye(4))

    ref_pose = poses[5]
    others = [k for k in range(11) if k != 5]
    res = search_mount_rotation(obs(ref_pose), [obs(poses[k]) for k in others], ref_pose,
                                np.stack([poses[k] for k in others]), t_mc, np.arange(-4, 4.01, 0.5) * DEG,
                                np.arange(-3, 3.01, 0.1) * DEG)
    assert abs(res.theta_y0 - ty0) <= 0.25 * DEG, res.message
    assert abs(res.theta_z0 - tz0) <= 0.05 * DEG, res.message
    assert res.curve_z[1].max() > res.curve_z[1][0]


@pytest.mark.skipif(not hasattr(__import__("cv2"), "calibrateHandEye"), reason="opencv-python 5.0.0.93 lacks the "
                    "calibrateHandEye binding (opencv/opencv#29565)")
def test_axxb_matches_opencv():
    import cv2

    A, B, X, _ = _axxb_data(np.random.default_rng(54), n=15)  # noise-free: both exact, whatever pairs they use
    R, t = cv2.calibrateHandEye(A[:, :3, :3], A[:, :3, 3], B[:, :3, :3], B[:, :3, 3],
                                method=cv2.CALIB_HAND_EYE_PARK)
    ours = hand_eye_axxb(A, B, method="park", refine=False)
    assert np.abs(ours.T_mount_cam[:3, :3] - R).max() < 1e-9
    assert np.abs(ours.T_mount_cam[:3, 3] - t.ravel()).max() < 1e-9
