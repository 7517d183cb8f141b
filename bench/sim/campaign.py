"""Render the views of a campaign: the TA-40 (true geometry) with its link-5 camera in a scene, through the optics.

:class:`ArmScene` compiles one MuJoCo model (the arm placed at ``T_world_base``, the camera at its true mount, the
scene objects) and renders views at *true* joint angles: a supersampled pinhole render (RGB + depth), the lens stage
(:class:`~bench.sim.distortion.DistortionStage`), then the sensor (noise, 8 bit). Finished images are cached on disk
by a content hash of everything that determines them (model XML and assets, joint angles, camera, optics, noise seed),
so a sweep never renders the same view twice.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from bench.camera.model import CameraModel
from bench.sim.distortion import DistortionStage
from bench.sim.mjcf import robot_object
from bench.sim.render import SceneRenderer
from bench.sim.scenes.base import compose, place


@dataclass(frozen=True)
class SensorModel:
    """Image sensor: Gaussian read noise (grey levels, std) on the 8-bit image; 0 = noise-free."""

    read_noise_dn: float = 0.0

    def apply(self, img: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        if self.read_noise_dn <= 0:
            return img
        noisy = img.astype(float) + rng.normal(0.0, self.read_noise_dn, img.shape)
        return np.clip(np.round(noisy), 0, 255).astype(np.uint8)


class ArmScene:
    """The arm with its camera in a scene, ready to render views.

    Parameters
    ----------
    robot, eps : the nominal model and the TRUE generalized errors (exact form).
    T_world_base : (4, 4) the true base pose.
    T_link5_cam : (4, 4) the TRUE camera mount.
    camera : CameraModel, the TRUE camera (intrinsics and lens distortion).
    objects : list of SceneObject (already placed in the world).
    supersample : int
    cache_dir : path or None
    """

    def __init__(self, robot, eps, T_world_base, T_link5_cam, camera: CameraModel, objects, supersample: int = 2,
                 sensor: SensorModel | None = None, cache_dir=None, T_link5_mount=None):
        import mujoco

        self.robot, self.camera = robot, camera
        self.stage = DistortionStage(camera, supersample)
        self.spec = self.stage.render_spec()
        arm = robot_object(robot, eps, T_link5_mount, (self.spec.K, self.spec.width, self.spec.height, T_link5_cam))
        self.objects = [place(arm, T_world_base, "ta40")] + list(objects)
        xml, assets = compose(self.objects, offscreen=(self.spec.width, self.spec.height), center=(1.0, 0.0, 0.5),
                              extent=4.0)
        self.model = mujoco.MjModel.from_xml_string(xml, assets=assets)
        self.data = mujoco.MjData(self.model)
        self.qadr = [self.model.jnt_qposadr[self.model.joint(f"joint{k}").id] for k in range(1, robot.n + 1)]
        self.sensor = sensor or SensorModel()
        h = hashlib.sha256(xml.encode())
        for k in sorted(assets):
            h.update(k.encode())
            h.update(hashlib.sha256(assets[k]).digest())
        h.update(np.ascontiguousarray(camera.K).tobytes())
        h.update(np.ascontiguousarray(camera.dist).tobytes())
        h.update(repr((camera.width, camera.height, supersample, self.sensor)).encode())
        self._key = h.hexdigest()
        self.cache_dir = Path(cache_dir) if cache_dir else None
        self._renderer = None
        self.render_s: list = []

    def _view_key(self, q, seed) -> str:
        h = hashlib.sha256(self._key.encode())
        h.update(np.round(np.asarray(q, float), 12).tobytes())
        h.update(str(seed).encode())
        return h.hexdigest()[:32]

    def render(self, q_true, seed: int = 0) -> np.ndarray:
        """The RGB image (uint8, camera size) of the view at true joint angles ``q_true`` (rad)."""
        import mujoco

        key = self._view_key(q_true, seed)
        if self.cache_dir is not None:
            path = self.cache_dir / f"{key}.png"
            if path.is_file():
                img = cv2.imread(str(path), cv2.IMREAD_COLOR)
                if img is not None:
                    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
        t0 = time.perf_counter()
        if self._renderer is None:
            self._renderer = SceneRenderer(self.model, "link5_camera", self.spec.width, self.spec.height)
        self.data.qpos[self.qadr] = q_true
        mujoco.mj_forward(self.model, self.data)
        rgb, _ = self._renderer.render(self.data)
        img = self.stage.warp_image(rgb, self.spec.K)
        img = self.sensor.apply(img, np.random.default_rng(seed))
        self.render_s.append(time.perf_counter() - t0)
        if self.cache_dir is not None:
            self.cache_dir.mkdir(parents=True, exist_ok=True)
            tmp = self.cache_dir / f".{key}.{time.time_ns()}.png"
            cv2.imwrite(str(tmp), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
            tmp.replace(self.cache_dir / f"{key}.png")
        return img

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
