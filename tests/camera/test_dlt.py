"""DLT (Eq. 55-58), decomposition (Eq. 59-66) and the planar Zhang path on noise-free synthetic data."""

import cv2
import numpy as np
import pytest
import scipy.linalg

from bench.camera import dlt
from bench.geometry.transforms import homogeneous, rot_x, rot_y, rot_z, transform_points


def rig_points(n=6, pitch=0.03):
    """The thesis's rig: two perpendicular chessboard planes (x-z and y-z), corners off the common edge (m)."""
    g = (np.arange(n) + 1) * pitch
    a, b = np.meshgrid(g, g)
    a, b = a.ravel(), b.ravel()
    z = np.zeros_like(a)
    return np.vstack([np.column_stack([a, z, b]), np.column_stack([z, a, b])])


def board_points(n=7, pitch=0.03):
    g = np.arange(n) * pitch
    a, b = np.meshgrid(g, g)
    return np.column_stack([a.ravel(), b.ravel(), np.zeros(a.size)])


def camera_looking_at(rng, X, distance=0.6, tilt=0.3):
    """Random ``T_cam_world`` that looks at the centroid of ``X`` from about ``distance`` (m)."""
    R = rot_x(np.pi + rng.normal(0, tilt)) @ rot_y(rng.normal(0, tilt)) @ rot_z(rng.uniform(-np.pi, np.pi))
    return homogeneous(R, -R @ X.mean(axis=0) + [rng.normal(0, 0.01), rng.normal(0, 0.01), distance])


def project(K, T, X):
    p = transform_points(T, X) @ K.T
    return p[:, :2] / p[:, 2:]


@pytest.fixture
def truth():
    K = dlt.intrinsic_matrix(812.0, 795.0, np.radians(89.6), 331.5, 238.25)
    return K


@pytest.mark.parametrize("normalize,solver", [(True, "svd"), (True, "eig"), (False, "svd")])
def test_dlt_and_decomposition_recover_truth(truth, normalize, solver):
    rng = np.random.default_rng(11)
    X = rig_points()
    for _ in range(5):
        T = camera_looking_at(rng, X, tilt=0.5)
        uv = project(truth, T, X)
        M = dlt.dlt_projection_matrix(X, uv, normalize=normalize, solver=solver)
        d = dlt.decompose_projection(M, X)
        assert np.abs(d.K - truth).max() / truth[0, 0] < 1e-9
        assert np.abs(d.R_cam_world - T[:3, :3]).max() < 1e-9
        assert np.abs(d.t_cam_world - T[:3, 3]).max() / np.linalg.norm(T[:3, 3]) < 1e-9
        alpha, beta, theta, u0, v0 = dlt.thesis_parameters(truth)
        assert d.alpha == pytest.approx(alpha, rel=1e-9) and d.beta == pytest.approx(beta, rel=1e-9)
        assert d.theta == pytest.approx(theta, rel=1e-9)
        assert (d.u0, d.v0) == pytest.approx((u0, v0), rel=1e-9)
        assert dlt.reprojection_rms(M, X, uv) < 1e-9


def test_normalisation_conditions_the_observation_matrix(truth):
    # Eq. 58 on raw pixels and metres squares a badly conditioned L_o; Hartley's normalisation repairs it
    rng = np.random.default_rng(12)
    X = rig_points()
    uv = project(truth, camera_looking_at(rng, X), X)
    def cond(L):  # noise-free L_o has an exact null vector: condition of the rest
        sv = np.linalg.svd(L, compute_uv=False)
        return sv[0] / sv[-2]

    raw = cond(dlt.observation_matrix(X, uv))
    T2, T3 = dlt.normalization_matrix(uv), dlt.normalization_matrix(X)
    Xn = X @ T3[:3, :3].T + T3[:3, 3]
    uvn = uv @ T2[:2, :2].T + T2[:2, 2]
    normalised = cond(dlt.observation_matrix(Xn, uvn))
    assert normalised < 1e-3 * raw


def test_decomposition_invariant_to_scale_and_sign_and_matches_rq(truth):
    rng = np.random.default_rng(13)
    X = rig_points()
    T = camera_looking_at(rng, X)
    M = dlt.compose_projection(truth, T)
    for c in (1.0, -3.7, 1e-4):
        d = dlt.decompose_projection(c * M, X)
        assert np.abs(d.K - truth).max() < 1e-9 * truth[0, 0]
        assert np.abs(d.T_cam_world - T).max() < 1e-9
        assert np.linalg.det(d.R_cam_world) == pytest.approx(1.0, abs=1e-12)
    # independent references: scipy's RQ and OpenCV's decomposeProjectionMatrix
    Kq, Rq = scipy.linalg.rq(M[:, :3])
    S = np.diag(np.sign(np.diag(Kq)))
    Kq = Kq @ S
    Kq /= Kq[2, 2]
    assert np.abs(Kq - truth).max() < 1e-9 * truth[0, 0]
    Kcv = cv2.decomposeProjectionMatrix(M)[0]
    assert np.abs(Kcv / Kcv[2, 2] - truth).max() < 1e-8 * truth[0, 0]


def test_points_behind_the_camera_are_reported(truth):
    rng = np.random.default_rng(14)
    X = rig_points()
    T = camera_looking_at(rng, X)
    uv = project(truth, T, X)
    # mirrored target frame: same pixels, points reflected through the world y-z plane
    X_mirror = X * [-1.0, 1.0, 1.0]
    M = dlt.dlt_projection_matrix(X_mirror, uv)
    with pytest.raises(ValueError, match="behind the camera"):
        dlt.decompose_projection(M, X_mirror)


def test_degenerate_inputs_fail_clearly(truth):
    rng = np.random.default_rng(15)
    X = rig_points()
    uv = project(truth, camera_looking_at(rng, X), X)
    board = board_points()
    uvb = project(truth, camera_looking_at(rng, board), board)
    with pytest.raises(ValueError, match="one plane.*degenerate"):
        dlt.dlt_projection_matrix(board, uvb)
    line = np.outer(np.arange(10.0), [0.01, 0.02, 0.03]) + [0, 0, 1]
    with pytest.raises(ValueError, match="collinear"):
        dlt.dlt_projection_matrix(line, uv[:10])
    bad = uv.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="uv: contains NaN"):
        dlt.dlt_projection_matrix(X, bad)
    with pytest.raises(ValueError, match="at least 6"):
        dlt.dlt_projection_matrix(X[:5], uv[:5])
    with pytest.raises(ValueError, match=r"expected shape \(N, 2\)"):
        dlt.dlt_projection_matrix(X, uv[:, :1])
    with pytest.raises(ValueError, match="singular"):
        dlt.decompose_projection(np.hstack([np.ones((3, 3)), np.ones((3, 1))]))


def test_zhang_planar_path_recovers_truth(truth):
    rng = np.random.default_rng(16)
    board = board_points()
    Hs, Ts = [], []
    for _ in range(4):
        T = camera_looking_at(rng, board, tilt=0.4)
        Hs.append(dlt.homography_dlt(board[:, :2], project(truth, T, board)))
        Ts.append(T)
    K = dlt.intrinsics_from_homographies(Hs)
    assert np.abs(K - truth).max() < 1e-9 * truth[0, 0]
    for H, T in zip(Hs, Ts, strict=True):
        assert np.abs(dlt.pose_from_homography(K, H) - T).max() < 1e-9
    # zero-skew camera: three views with the zero-skew constraint
    K0 = truth.copy()
    K0[0, 1] = 0.0
    Hs0 = [dlt.homography_dlt(board[:, :2], project(K0, T, board)) for T in Ts[:3]]
    assert np.abs(dlt.intrinsics_from_homographies(Hs0, skew=False) - K0).max() < 1e-9 * K0[0, 0]
    with pytest.raises(ValueError, match="image_size"):
        dlt.intrinsics_from_homographies(Hs[:1])
    with pytest.raises(ValueError, match="collinear"):
        dlt.homography_dlt(np.column_stack([np.arange(6.0), np.arange(6.0)]), project(truth, Ts[0], board)[:6])


def test_pose_from_projection_and_plane_frame(truth):
    rng = np.random.default_rng(17)
    X = rig_points()
    T = camera_looking_at(rng, X)
    M = dlt.compose_projection(truth, T) * -2.5
    assert np.abs(dlt.pose_from_projection(truth, M) - T).max() < 1e-12
    board = transform_points(homogeneous(rot_y(0.3) @ rot_x(1.0), [0.1, 0.2, 0.3]), board_points())
    F = dlt.plane_frame(board)
    local = transform_points(np.linalg.inv(F), board)
    assert np.abs(local[:, 2]).max() < 1e-12 and np.linalg.det(F[:3, :3]) == pytest.approx(1.0)
    assert dlt.is_planar(board) and not dlt.is_planar(X)


def test_homography_from_exactly_four_points():
    """8 equations, 9 unknowns: the null vector must come from the full SVD (a thin one drops it)."""
    rng = np.random.default_rng(7)
    H = np.array([[1.1, 0.1, 5.0], [0.05, 0.9, -3.0], [1e-3, 2e-3, 1.0]])
    xy = rng.uniform(-1, 1, (4, 2))
    p = np.c_[xy, np.ones(4)] @ H.T
    Hh = dlt.homography_dlt(xy, p[:, :2] / p[:, 2:])
    assert np.abs(Hh / Hh[2, 2] - H).max() <= 1e-9
