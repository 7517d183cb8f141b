"""Self-checks of the simulator, reported as metrics by ``bench sim render`` and asserted by the tests.

* :func:`kinematics_check` - MuJoCo's frames of the generated arm against our exact error-model FK and against
  Pinocchio (``sim_vs_fk_max_err_m``, ``sim_vs_pinocchio_max_err_m``).
* :func:`marker_check` - small emissive markers at known points, rendered through the full lens chain, found by
  their intensity centroids and compared with the analytic projection (``marker_projection_rms_px``).
* :func:`distortion_roundtrip` - distort -> undistort over the whole image (``distortion_roundtrip_max_px``).
"""

from __future__ import annotations

import numpy as np

from bench.camera.model import CameraModel, distort, from_pixels, to_pixels, undistort
from bench.geometry.transforms import homogeneous, invert, rot_x, transform_points
from bench.robot.kinematics import link_frames
from bench.robot.model import Robot
from bench.robot.orientation import link5_frame


def _site(mujoco, m, d, name):
    i = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, name)
    return homogeneous(d.site_xmat[i].reshape(3, 3), d.site_xpos[i])


def kinematics_check(robot: Robot, eps, q) -> dict:
    """Largest difference (m, and rotation-matrix entries) between MuJoCo's sites and FK / Pinocchio over ``q``."""
    import mujoco

    from bench.judge.pinocchio_model import pinocchio_frames
    from bench.sim.mjcf import robot_spec

    m = robot_spec(robot, eps).compile()
    d = mujoco.MjData(m)
    q = np.atleast_2d(q)
    F, P = link_frames(robot, q, eps), pinocchio_frames(robot, q, eps)
    L5 = link5_frame(robot, q, eps)
    e_fk = e_pin = 0.0
    for qi, f, p, l5 in zip(q, F, P, L5, strict=True):
        d.qpos[:] = qi
        mujoco.mj_kinematics(m, d)
        for k in range(robot.n + 1):
            S = _site(mujoco, m, d, f"frame{k}")
            e_fk, e_pin = max(e_fk, np.abs(S - f[k]).max()), max(e_pin, np.abs(S - p[k]).max())
        e_fk = max(e_fk, np.abs(_site(mujoco, m, d, "link5") - l5).max())
    return {"sim_vs_fk_max_err_m": float(e_fk), "sim_vs_pinocchio_max_err_m": float(e_pin)}


def marker_check(camera: CameraModel, supersample: int = 3, radius_m: float = 0.0015) -> dict:
    """Render a 5 x 5 grid of markers (corners included) through the lens stage; centroid vs projection (px)."""
    import mujoco

    from bench.sim.camera import add_opencv_camera
    from bench.sim.distortion import DistortionStage
    from bench.sim.render import SceneRenderer
    from bench.sim.scenes.base import SceneObject, add_geom, compose

    stage = DistortionStage(camera, supersample)
    spec = stage.render_spec()
    T_world_cam = homogeneous(rot_x(-1.2), [0.0, -1.0, 0.6])
    w, h = camera.width, camera.height
    uv = np.array([[u, v] for u in np.linspace(0.04 * w, 0.96 * w, 5) for v in np.linspace(0.05 * h, 0.95 * h, 5)])
    depth = np.linspace(0.7, 1.1, len(uv))
    p_world = transform_points(T_world_cam, camera.unproject(uv, normalize=False) * depth[:, None])

    def markers(scene, parent):
        scene.add_material(name="glow", rgba=[1, 1, 1, 1], emission=1)
        for p in p_world:
            add_geom(parent, None, "sphere", "glow", [radius_m], pos=p, contype=0, conaffinity=0)

    def probe(scene):
        add_opencv_camera(scene.worldbody, "probe", spec.K, spec.width, spec.height, T_world_cam)

    m = compose([SceneObject("markers", markers)], probe, offscreen=(spec.width, spec.height)).compile()
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    with SceneRenderer(m, "probe", spec.width, spec.height) as r:
        rgb, depth_map = r.render(d)
    img, _ = stage.apply(rgb, spec.K, depth_map)
    grey = img.astype(float).sum(axis=2)
    background = np.median(grey)
    pred = camera.project(transform_points(invert(T_world_cam), p_world))
    err = []
    for u, v in pred:
        u0, v0 = int(round(u)), int(round(v))
        vv, uu = np.mgrid[v0 - 5:v0 + 6, u0 - 5:u0 + 6]
        win = np.clip(grey[v0 - 5:v0 + 6, u0 - 5:u0 + 6] - background, 0, None)
        err.append([(uu * win).sum() / win.sum() - u, (vv * win).sum() / win.sum() - v])
    err = np.array(err)
    return {"marker_projection_rms_px": float(np.sqrt(np.mean(np.sum(err**2, axis=1)))),
            "marker_projection_max_px": float(np.abs(err).max()), "markers": len(err),
            "depth_has_background": bool(np.isinf(depth_map).any())}


def distortion_roundtrip(camera: CameraModel, step_px: float = 1.0) -> float:
    """Largest |undistort(distort(x)) - x| over a pixel grid covering the image (px)."""
    u, v = np.meshgrid(np.arange(-0.5, camera.width, step_px), np.arange(-0.5, camera.height, step_px))
    uv = np.stack([u.ravel(), v.ravel()], axis=1)
    x_d = from_pixels(uv, camera.K)
    back = to_pixels(distort(undistort(x_d, camera.dist), camera.dist), camera.K)
    return float(np.nanmax(np.linalg.norm(back - uv, axis=1)))
