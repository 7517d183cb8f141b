"""Render the views of a campaign: the TA-40 (true geometry) with its link-5 camera in a scene, through the optics.

:class:`ArmScene` compiles one MuJoCo model (the arm placed at ``T_world_base``, the camera at its true mount, the
scene objects) and renders views at *true* joint angles: a supersampled pinhole render (RGB + depth), then either
the lens stage (:class:`~bench.sim.distortion.DistortionStage`, camera in air) or lens + flat port
(:class:`~bench.sim.flatport.FlatPortStage`, ray-traced through the housing's glass into water), then the medium and
sensor chain (:func:`~bench.sim.medium.apply_medium`: lamp, attenuation and backscatter on the in-water path,
forward scatter, shot and read noise, 8 bit, optional JPEG). Finished images are cached on disk
by a content hash of everything that determines them (model XML and assets, joint angles, camera, optics, noise seed),
so a sweep never renders the same view twice.
"""

from __future__ import annotations

import hashlib
import time
from pathlib import Path

import cv2
import numpy as np

from bench.camera.model import CameraModel
from bench.sim.distortion import DistortionStage
from bench.sim.flatport import FlatPortStage
from bench.sim.medium import MediumChain, apply_medium, cos_beam, path_length_m
from bench.sim.mjcf import robot_object
from bench.sim.render import SceneRenderer
from bench.sim.scenes.base import compose, place

#: Version of the image chain's algorithms, part of every render's cache key: bump it when a change of the code
#: (not of a parameter, which the key already holds) changes the images. 2: sensor noise drawn per row band from
#: child generators (``bench.sim.parallel``).
IMAGE_CHAIN_VERSION = 2


class ArmScene:
    """The arm with its camera in a scene, ready to render views.

    Parameters
    ----------
    robot, eps : the nominal model and the TRUE generalized errors (exact form).
    T_world_base : (4, 4) the true base pose.
    T_link5_cam : (4, 4) the TRUE camera mount.
    camera : CameraModel, the TRUE camera (intrinsics and lens distortion; the lens inside the housing if ``port``).
    objects : list of SceneObject (already placed in the world).
    supersample : int
    chain : MediumChain, the medium and sensor stages (default: noise-free 8 bit).
    port : FlatPort or None, the housing's flat port (None: the lens sees the scene directly).
    cache_dir : path or None
    z_min : float, nearest scene depth the flat-port render must cover (m).
    """

    def __init__(self, robot, eps, T_world_base, T_link5_cam, camera: CameraModel, objects, supersample: int = 2,
                 chain: MediumChain | None = None, cache_dir=None, T_link5_mount=None, port=None, z_min: float = 0.3):
        import mujoco

        self.robot, self.camera = robot, camera
        self.port = port
        if port is None:
            self.stage = DistortionStage(camera, supersample)
            self.spec = self.stage.render_spec()
        else:
            self.stage = FlatPortStage(camera.K, camera.size, port, supersample, lens=camera)
            self.spec = self.stage.render_spec(z_min)
        grid = _pixel_grid(camera)
        self._rays = camera.unproject(grid, normalize=False)  # the lens's pixel rays (distortion included)
        self._cos = cos_beam(self._rays)
        # path length per unit z-depth along each pixel's ray, |ray| / ray_z (path_length_m, computed once)
        self._path_per_z = path_length_m(np.ones(self._rays.shape[:2]), self._rays)
        arm = robot_object(robot, eps, T_link5_mount, (self.spec.K, self.spec.width, self.spec.height, T_link5_cam))
        self.objects = [place(arm, T_world_base, "ta40")] + list(objects)
        xml, assets = compose(self.objects, offscreen=(self.spec.width, self.spec.height), center=(1.0, 0.0, 0.5),
                              extent=4.0)
        self.model = mujoco.MjModel.from_xml_string(xml, assets=assets)
        self.data = mujoco.MjData(self.model)
        self.qadr = [self.model.jnt_qposadr[self.model.joint(f"joint{k}").id] for k in range(1, robot.n + 1)]
        self.chain = chain or MediumChain()
        h = hashlib.sha256(f"image chain {IMAGE_CHAIN_VERSION}".encode())
        h.update(xml.encode())
        for k in sorted(assets):
            h.update(k.encode())
            h.update(hashlib.sha256(assets[k]).digest())
        h.update(np.ascontiguousarray(camera.K).tobytes())
        h.update(np.ascontiguousarray(camera.dist).tobytes())
        h.update(repr((camera.width, camera.height, supersample, self.chain, port)).encode())
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
        rgb, depth = self._renderer.render(self.data)
        rng = np.random.default_rng(seed)
        if self.port is None:
            img, z = self.stage.apply(rgb, self.spec.K, depth)
            path = z * self._path_per_z  # = path_length_m(z, self._rays)
        else:
            out = self.stage.apply(rgb, depth, self.spec.K)
            img, path = out.image, out.water_path
        img = apply_medium(img, path, rng, self.chain, self._cos if self.chain.light is not None else None)
        if img.dtype != np.uint8:
            img = np.clip(np.round(img * 255.0), 0, 255).astype(np.uint8)
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


def _pixel_grid(camera: CameraModel) -> np.ndarray:
    """Pixel centres ``(H, W, 2)`` of the camera's image."""
    u, v = np.meshgrid(np.arange(camera.width, dtype=float), np.arange(camera.height, dtype=float))
    return np.stack([u, v], axis=-1)
