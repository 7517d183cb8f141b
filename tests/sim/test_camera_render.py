"""The link-5 camera: MuJoCo's projection (raw and supersampled) against the analytic OpenCV pinhole, the renderer."""

import os

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")
mujoco = pytest.importorskip("mujoco")

from bench.errors import BenchError  # noqa: E402
from bench.geometry.quaternion import matrix_to_quaternion  # noqa: E402
from bench.geometry.transforms import homogeneous, invert, rot_x, rot_z, transform_points  # noqa: E402
from bench.robot.model import random_errors  # noqa: E402
from bench.robot.orientation import link5_frame  # noqa: E402
from bench.sim.camera import mujoco_camera_attributes, opencv_intrinsics  # noqa: E402
from bench.sim.mjcf import NOMINAL_T_LINK5_CAM, camera_mount_with_bias, home_configuration, scene_spec  # noqa: E402
from bench.sim.render import Renderer, check_gl  # noqa: E402
from bench.sim.scenes.base import SceneObject, add_geom  # noqa: E402
from bench.vision.handeye import mount_rotation  # noqa: E402

W, H = 640, 480
#: non-square pixels and an off-centre principal point (with fractional parts), so every convention term shows
K = np.array([[612.0, 0.0, 301.3], [0.0, 588.0, 252.6], [0.0, 0.0, 1.0]])
T_WORLD_BASE = homogeneous(rot_z(0.3) @ rot_x(0.02), [0.4, -0.2, 0.1])
MARKER_RADIUS_PX = 4.0


class MarkerScene:
    """The perturbed arm with its biased link-5 camera and 5 x 5 fronto-parallel emissive discs (corners included)."""

    def __init__(self, robot):
        rng = np.random.default_rng(301)
        self.eps = random_errors(rng)
        self.q = home_configuration(robot)
        self.T_link5_cam = camera_mount_with_bias(NOMINAL_T_LINK5_CAM, 0.012, -0.021, 0.017, [0.003, -0.002, 0.004])
        # the analytic camera pose: our FK (Eq. 188 frame), not MuJoCo's
        self.T_world_cam = T_WORLD_BASE @ link5_frame(robot, self.q, self.eps) @ self.T_link5_cam
        u = np.linspace(8.0, W - 9.0, 5) + rng.uniform(-0.5, 0.5, 5)
        v = np.linspace(8.0, H - 9.0, 5) + rng.uniform(-0.5, 0.5, 5)
        uv = np.array([[a, b] for b in v for a in u])
        self.z = rng.uniform(0.6, 1.0, len(uv))
        x_n = np.c_[(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(uv))]
        self.p_world = transform_points(self.T_world_cam, x_n * self.z[:, None])
        # a disc parallel to the image plane projects to a circle centred on the projection of its centre
        quat = matrix_to_quaternion(self.T_world_cam[:3, :3])
        radius = MARKER_RADIUS_PX * self.z / K[0, 0]

        def build(spec, parent):
            spec.add_material(name="marker_glow", rgba=[1, 1, 1, 1], emission=1)
            for p, r in zip(self.p_world, radius, strict=True):
                add_geom(parent, None, "cylinder", "marker_glow", [r, 0.0002], pos=p, quat=quat, contype=0,
                         conaffinity=0)

        markers = SceneObject("marker", build)
        self.model = scene_spec(robot, self.eps, T_WORLD_BASE, [markers], camera=(K, W, H, self.T_link5_cam)).compile()

    def analytic_uv(self):
        """The OpenCV pinhole projection of the marker centres (px)."""
        p_cam = transform_points(invert(self.T_world_cam), self.p_world)
        return (K @ (p_cam / p_cam[:, 2:]).T).T[:, :2]


def centroid_errors(img, uv_pred, half=7):
    grey = img.astype(float).sum(axis=2)
    background = np.median(grey)
    err = []
    for u, v in uv_pred:
        u0, v0 = int(round(u)), int(round(v))
        vv, uu = np.mgrid[v0 - half:v0 + half + 1, u0 - half:u0 + half + 1]
        win = np.clip(grey[v0 - half:v0 + half + 1, u0 - half:u0 + half + 1] - background, 0, None)
        assert win.shape == vv.shape and win.sum() > 0
        err.append([(uu * win).sum() / win.sum() - u, (vv * win).sum() / win.sum() - v])
    return np.array(err)


@pytest.fixture(scope="module")
def scene(ta40):
    return MarkerScene(ta40)


@pytest.fixture(scope="module")
def renderers(scene):
    out = {s: Renderer(scene.model, "link5_camera", supersample=s) for s in (1, 3)}
    yield out
    for r in out.values():
        r.close()


@pytest.mark.parametrize("supersample", [1, 3])
def test_link5_markers_land_on_the_opencv_projection(scene, renderers, supersample):
    r = renderers[supersample]
    assert np.abs(r.K - K).max() <= 1e-5  # read back as given (MuJoCo stores the intrinsics as float32: ~1e-6 px)
    rgb, depth = r.render(scene.q)
    assert rgb.shape == (H, W, 3) and rgb.dtype == np.uint8 and depth.shape == (H, W)
    uv = scene.analytic_uv()
    assert uv.min() < 9 and uv[:, 0].max() > W - 10 and uv[:, 1].max() > H - 10  # the image corners are covered
    err = centroid_errors(rgb, uv)
    rms = float(np.sqrt(np.mean(np.sum(err**2, axis=1))))
    print(f"marker_projection_rms_px (supersample {supersample}): {rms:.4f}, max {np.abs(err).max():.4f}")
    assert len(err) == 25 and np.abs(err).max() <= 0.1, err
    assert abs(err[:, 0].mean()) < 0.02 and abs(err[:, 1].mean()) < 0.02  # no half-pixel or principal-point bias
    # metric depth at the disc centres (the nearest surface of the footprint), background at infinity
    iu, iv = np.round(uv).astype(int).T
    assert np.abs(depth[iv, iu] - scene.z).max() < 2e-3
    assert np.isinf(depth[H // 2 + 15, W // 2 + 30]) or depth[H // 2 + 15, W // 2 + 30] > 1.5


def test_mujoco_camera_pose_is_the_fk_pose(scene, renderers):
    from bench.sim.camera import camera_pose_cv

    r = renderers[1]
    r.set_joints(scene.q)
    assert np.abs(camera_pose_cv(r.model, r.data, "link5_camera") - scene.T_world_cam).max() <= 1e-9


def test_renderer_supersampling_is_a_box_filter_of_the_fine_render(scene, renderers):
    """The 3x image is the pixel-block mean of a 3x-finer raw render of the same camera (its K_s scaled)."""
    fine = Renderer(scene.model, "link5_camera", supersample=1, width=3 * W, height=3 * H)
    try:
        K_s = K.copy()
        K_s[:2] *= 3
        K_s[:2, 2] += 1.0  # c_s = s (c + 1/2) - 1/2
        assert np.abs(fine.K - K_s).max() <= 1e-5  # float32 intrinsics in MjModel
        rgb_f, depth_f = fine.render(scene.q)
    finally:
        fine.close()
    rgb, depth = renderers[3].render(scene.q)
    box = rgb_f.reshape(H, 3, W, 3, 3).mean(axis=(1, 3))
    assert np.abs(rgb.astype(float) - box).max() <= 0.5 + 1e-4  # rounded mean (float32 accumulation)
    assert np.array_equal(depth, depth_f.reshape(H, 3, W, 3).min(axis=(1, 3)))


@pytest.mark.parametrize("samples", [0, 4])
def test_scene_renderer_equals_mujoco_renderer_bit_for_bit(scene, samples):
    """One reused context and (without MSAA) a single pass give exactly mujoco.Renderer's colour and depth passes."""
    import copy

    from bench.sim.render import SceneRenderer

    model = copy.copy(scene.model)
    model.vis.quality.offsamples = samples
    data = mujoco.MjData(model)
    data.qpos[:6] = scene.q
    rgb_r, depth_r = mujoco.Renderer(model, 240, 320), mujoco.Renderer(model, 240, 320)
    depth_r.enable_depth_rendering()
    try:
        with SceneRenderer(model, "link5_camera", 320, 240) as r:
            for dq in (0.0, 0.05):  # the context is reused: a second pose renders just as well
                data.qpos[:6] = scene.q + dq
                mujoco.mj_forward(model, data)
                rgb, depth = r.render(data)
                rgb_r.update_scene(data, "link5_camera")
                depth_r.update_scene(data, "link5_camera")
                ref_depth = depth_r.render().astype(np.float64)
                ref_depth[ref_depth >= 0.99 * r.zfar] = np.inf
                assert np.array_equal(rgb, rgb_r.render()) and np.array_equal(depth, ref_depth)
                assert np.isinf(depth).any() and np.isfinite(depth).any()
    finally:
        rgb_r.close()
        depth_r.close()


def test_mount_bias_is_eq197_in_the_nominal_optical_frame():
    T = camera_mount_with_bias(NOMINAL_T_LINK5_CAM, 0.01, -0.02, 0.03, [0.001, 0.002, -0.003])
    dT = invert(NOMINAL_T_LINK5_CAM) @ T
    assert np.abs(dT[:3, :3] - mount_rotation(0.01, -0.02, 0.03)).max() <= 1e-15  # the pipeline's Eq. 197
    assert np.abs(dT[:3, 3] - [0.001, 0.002, -0.003]).max() <= 1e-15
    assert np.array_equal(camera_mount_with_bias(NOMINAL_T_LINK5_CAM), NOMINAL_T_LINK5_CAM)


def test_camera_attributes_convention():
    a = mujoco_camera_attributes(K, W, H)
    assert a["resolution"] == [640, 480] and a["sensor_size"] == [640, 480] and a["focal_length"] == [612, 588]
    assert np.allclose(a["principal_length"], [W / 2 - 0.5 - 301.3, H / 2 - 0.5 - 252.6])
    m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><camera name="c" fovy="45"/></worldbody></mujoco>')
    Kf = opencv_intrinsics(m, "c", W, H)  # a fovy camera: square pixels, centred principal point
    assert np.allclose(Kf, [[240 / np.tan(np.pi / 8), 0, 319.5], [0, 240 / np.tan(np.pi / 8), 239.5], [0, 0, 1]])


def test_gl_failure_is_one_line_naming_the_packages(monkeypatch):
    check_gl()  # works here (Mesa EGL)

    class Broken:
        def __init__(self, *a):
            raise RuntimeError("eglInitialize failed\nsecond line")

    monkeypatch.setattr(mujoco, "GLContext", Broken)
    with pytest.raises(BenchError, match=r"libegl1 libgl1-mesa-dri") as info:
        check_gl()
    assert "\n" not in str(info.value) and "eglInitialize failed" in str(info.value)


def test_bad_input_is_refused(scene, renderers):
    r = renderers[1]
    q = scene.q.copy()
    q[1] = -0.5  # joint 2 >= 0 (thesis §4.5)
    with pytest.raises(ValueError, match="joint2"):
        r.set_joints(q)
    with pytest.raises(ValueError, match="q_true"):
        r.set_joints(np.zeros(5))
    with pytest.raises(ValueError, match="supersample"):
        Renderer(scene.model, "link5_camera", supersample=0)
    with pytest.raises(BenchError, match="nope"):
        Renderer(scene.model, "nope")
    with pytest.raises(ValueError, match="fx, fy > 0"):
        mujoco_camera_attributes(np.diag([600.0, 0.0, 1.0]), W, H)
    with pytest.raises(ValueError, match="skew"):
        mujoco_camera_attributes(K + [[0, 0.5, 0], [0, 0, 0], [0, 0, 0]], W, H)
    with pytest.raises(ValueError, match="image size"):
        mujoco_camera_attributes(K, 0, H)
    with pytest.raises(ValueError, match="t_bias"):
        camera_mount_with_bias(NOMINAL_T_LINK5_CAM, t_bias=[0.0, np.nan, 0.0])
    with pytest.raises(ValueError, match="theta"):
        camera_mount_with_bias(NOMINAL_T_LINK5_CAM, 5.0)
