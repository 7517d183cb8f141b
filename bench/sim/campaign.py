"""Render the views of a campaign: the TA-40 (true geometry) with its link-5 camera in a scene, through the optics.

:class:`ArmScene` compiles one MuJoCo model (the arm placed at ``T_world_base``, the camera at its true mount, the
scene objects) and renders views at *true* joint angles: a supersampled pinhole render (RGB + depth), then either
the lens stage (:class:`~bench.sim.distortion.DistortionStage`, camera in air) or lens + flat port
(:class:`~bench.sim.flatport.FlatPortStage`, ray-traced through the housing's glass into water), then the medium and
sensor chain (:func:`~bench.sim.medium.apply_medium`: lamp, attenuation and backscatter on the in-water path,
forward scatter, shot and read noise, 8 bit, optional JPEG). Finished images are cached on disk
by a content hash of everything that determines them (the compiled model, exactly; joint angles, camera, optics,
noise seed), so a sweep never renders the same view twice.
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
from bench.sim.imaging import apparent_depth_m, finish_image
from bench.sim.medium import MediumChain, cos_beam, path_length_m
from bench.sim.mjcf import robot_object
from bench.sim.render import SceneRenderer
from bench.sim.scenes.base import compose, place, scene_key

#: Version of the image chain's algorithms, part of every render's cache key: bump it when a change of the code
#: (not of a parameter, which the key already holds) changes the images. 2: sensor noise drawn per row band from
#: child generators (``bench.sim.parallel``); 3: flat-port colour sub-rays stop at a 0.001 px step; 4: shot noise of
#: bright pixels drawn from its normal limit (``bench.sim.medium.SHOT_NOISE_NORMAL_ABOVE_E``).
IMAGE_CHAIN_VERSION = 4


class CachedCamera:
    """A MuJoCo camera rendered through the optics chain, its finished images cached on disk by content hash.

    The stages: a supersampled pinhole render (RGB + depth) -> the lens stage (``port`` None: camera in air) or lens
    + flat port -> the imaging profile's stages, the medium and the sensor (:func:`bench.sim.imaging.finish_image`)
    -> 8-bit RGB. A subclass builds the scene for :attr:`spec` (the render's K and size), then calls
    :meth:`_start_cache` with the compiled model; :meth:`_render` renders a state of it (or reads it from the cache).
    """

    def __init__(self, camera: CameraModel, supersample: int, port=None, z_min: float = 0.3):
        self.camera, self.port = camera, port
        if port is None:
            self.stage = DistortionStage(camera, supersample)
            self.spec = self.stage.render_spec()
        else:
            self.stage = FlatPortStage(camera.K, camera.size, port, supersample, lens=camera)
            self.spec = self.stage.render_spec(z_min)
        # the lens's pixel rays (distortion in) through the pixel centres (H, W, 2)
        uv = np.stack(np.meshgrid(np.arange(camera.width, dtype=float), np.arange(camera.height, dtype=float)), -1)
        self._rays = camera.unproject(uv, normalize=False)
        self._cos = cos_beam(self._rays)
        self._supersample = supersample

    def _start_cache(self, model, chain: MediumChain, imaging, cache_dir) -> None:
        """The cache key of the model, camera and optics (``imaging``: an ImagingProfile; None or ``ideal`` is the
        ideal chain, whose cache keys it leaves unchanged)."""
        import mujoco

        from bench.sim.imaging import ImagingChain

        self.model, self.data, self.chain = model, mujoco.MjData(model), chain
        h = scene_key(model, hashlib.sha256(f"image chain {IMAGE_CHAIN_VERSION}".encode()))  # a new chain: afresh
        h.update(np.ascontiguousarray(self.camera.K).tobytes())
        h.update(np.ascontiguousarray(self.camera.dist).tobytes())
        h.update(repr((self.camera.width, self.camera.height, self._supersample, chain, self.port)).encode())
        self.imaging = None if imaging is None or not imaging.stages else ImagingChain(imaging, self.camera.K,
                                                                                       self.camera.size)
        if self.imaging is not None:
            h.update(imaging.key().encode())
        self._key = h.hexdigest()
        self.cache_dir = Path(cache_dir) if cache_dir else None
        self._renderer = None
        self.render_s: list = []

    def _air_path(self, z):
        """The path length (m) along each pixel's ray to its z-depth ``z`` (camera in air)."""
        return path_length_m(z, self._rays)

    def _render(self, name: str, set_state, state_key, seed: int) -> np.ndarray:
        """RGB uint8 (camera size) of MuJoCo camera ``name`` with the state set by ``set_state(model, data)``;
        cached by ``state_key`` (the values that determine the state) and ``seed`` (the noise)."""
        import mujoco

        h = hashlib.sha256(self._key.encode())
        h.update(np.round(np.asarray(state_key, float), 12).tobytes())
        h.update(str(seed).encode())
        key = h.hexdigest()[:32]
        if self.cache_dir is not None:
            path = self.cache_dir / f"{key}.png"
            if path.is_file():
                img = cv2.imread(str(path), cv2.IMREAD_COLOR)
                if img is not None:
                    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
        t0 = time.perf_counter()
        if self._renderer is None:
            self._renderer = SceneRenderer(self.model, name, self.spec.width, self.spec.height)
        set_state(self.model, self.data)
        mujoco.mj_forward(self.model, self.data)
        rgb, depth = self._renderer.render(self.data)
        if self.port is None:
            img, z = self.stage.apply(rgb, self.spec.K, depth)
            path = self._air_path(z)
        else:
            out = self.stage.apply(rgb, depth, self.spec.K)
            img, path, z = out.image, out.water_path, out.depth
        focus = None if self.imaging is None else apparent_depth_m(self.port, z, path)
        img = finish_image(self.imaging, img, path, focus, np.random.default_rng(seed), self.chain,
                           self._cos if self.chain.light is not None else None)
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


class ArmScene(CachedCamera):
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
                 chain: MediumChain | None = None, cache_dir=None, T_link5_mount=None, port=None, z_min: float = 0.3,
                 imaging=None):
        super().__init__(camera, supersample, port, z_min)
        self.robot = robot
        # path length per unit z-depth along each pixel's ray, |ray| / ray_z (path_length_m, computed once)
        self._path_per_z = path_length_m(np.ones(self._rays.shape[:2]), self._rays)
        arm = robot_object(robot, eps, T_link5_mount, (self.spec.K, self.spec.width, self.spec.height, T_link5_cam))
        self.objects = [place(arm, T_world_base, "ta40")] + list(objects)
        scene = compose(self.objects, offscreen=(self.spec.width, self.spec.height), center=(1.0, 0.0, 0.5),
                        extent=4.0)
        self._start_cache(scene.compile(), chain or MediumChain(), imaging, cache_dir)
        self.qadr = [self.model.jnt_qposadr[self.model.joint(f"joint{k}").id] for k in range(1, robot.n + 1)]

    def _air_path(self, z):
        return z * self._path_per_z  # = path_length_m(z, self._rays)

    def render(self, q_true, seed: int = 0) -> np.ndarray:
        """The RGB image (uint8, camera size) of the view at true joint angles ``q_true`` (rad)."""

        def set_joints(model, data):
            data.qpos[self.qadr] = q_true

        return self._render("link5_camera", set_joints, q_true, seed)

    # --- truth geometry of a view (for checks; the pipeline never sees it) ------------------------------------------
    def camera_pose(self, q_true) -> np.ndarray:
        """True ``T_world_cam`` (OpenCV optical frame, the lens centre) at true joint angles ``q_true`` (rad)."""
        import mujoco

        from bench.sim.camera import camera_pose_cv

        self.data.qpos[self.qadr] = q_true
        mujoco.mj_forward(self.model, self.data)
        return camera_pose_cv(self.model, self.data, "link5_camera")

    def pixel_points(self, q_true) -> np.ndarray:
        """The scene point ``(H, W, 3)`` (m, camera frame) seen by each pixel centre's ray at ``q_true``; inf for the
        background. Renders the depth again (not cached): through the port the point is ``o + lambda w`` of the pixel
        centre's water ray (:attr:`~bench.sim.flatport.FlatPortImage.water_path`), in air the lens ray at the
        pixel's depth."""
        self.camera_pose(q_true)
        if self._renderer is None:
            self._renderer = SceneRenderer(self.model, "link5_camera", self.spec.width, self.spec.height)
        rgb, depth = self._renderer.render(self.data)
        if self.port is None:
            _, z = self.stage.apply(rgb, self.spec.K, depth)
            rays = self._rays / self._rays[..., 2:3]
            pts = rays * z[..., None]
        else:
            out = self.stage.apply(rgb, depth, self.spec.K)
            o, w, _ = self.stage.rays("centre")
            pts = o + np.where(np.isfinite(out.water_path), out.water_path, 0.0)[..., None] * w
        return np.where(np.all(np.isfinite(pts), axis=-1, keepdims=True), pts, np.inf)

    def project(self, p_cam) -> np.ndarray:
        """Pixels ``(..., 2)`` of camera-frame points ``p_cam (..., 3)`` through the lens (and the port); NaN where
        a point cannot be imaged."""
        from bench.camera.flatport import lens_port_projector

        return lens_port_projector(self.camera, self.port)(np.asarray(p_cam, dtype=float))


def keypoint_reliability(scene: ArmScene, q_a, q_b, image_a, image_b, tol_px: float = 2.0) -> dict:
    """How many SIFT keypoints two views of ``scene`` share, and how many of their matches are true.

    The pipeline's detector and matcher (:func:`bench.vision.features.detect_sift`, Lowe's ratio test, mutual) run
    on ``image_a`` and ``image_b`` (rendered at true joint angles ``q_a``, ``q_b``); each keypoint of view a is
    carried to 3D with the truth (the point its pixel sees, :meth:`ArmScene.pixel_points`, bilinearly interpolated
    where all four neighbours see the same surface within 1 cm) and projected into view b through the true camera
    poses and optics (:meth:`ArmScene.project`). A match is true when it lies within ``tol_px`` of that projection.

    Returns
    -------
    dict
        ``keypoints_a``, ``keypoints_b``, ``matches``, ``true_matches``, ``true_positive_rate`` (of the matches with
        a known truth), ``median_error_px`` (of the true matches), ``matches_with_truth`` and ``error_px`` (the
        distance of each of those matches from the truth, px).
    """
    import cv2

    from bench.geometry.transforms import invert, transform_points
    from bench.vision.features import detect_sift, match_descriptors

    fa, fb = detect_sift(image_a, channel_order="rgb"), detect_sift(image_b, channel_order="rgb")
    m = match_descriptors(fa, fb, mutual=True) if len(fa) and len(fb) else None
    out = {"keypoints_a": len(fa), "keypoints_b": len(fb), "matches": 0 if m is None else len(m)}
    if m is None or len(m) == 0:
        return {**out, "true_matches": 0, "true_positive_rate": float("nan"), "median_error_px": float("nan")}
    pts = scene.pixel_points(q_a)
    T_a, T_b = scene.camera_pose(q_a), scene.camera_pose(q_b)
    uv = fa.uv[m.i1].astype(np.float32)
    chans = [cv2.remap(np.where(np.isfinite(pts[..., k]), pts[..., k], 1e6).astype(np.float32), uv[:, :1],
                       uv[:, 1:], cv2.INTER_LINEAR) for k in range(3)]
    p_a = np.concatenate(chans, axis=1).astype(float)
    # reject keypoints on depth edges (the four neighbours see surfaces more than 1 cm apart): no single truth
    u0 = np.clip(np.floor(uv[:, 0]).astype(int), 0, pts.shape[1] - 2)
    v0 = np.clip(np.floor(uv[:, 1]).astype(int), 0, pts.shape[0] - 2)
    nb = np.stack([pts[v0, u0], pts[v0, u0 + 1], pts[v0 + 1, u0], pts[v0 + 1, u0 + 1]], axis=1)
    with np.errstate(invalid="ignore"):
        known = np.all(np.isfinite(nb), axis=(1, 2)) & (np.ptp(nb[..., 2], axis=1) < 0.01)
    p_b = transform_points(invert(T_b) @ T_a, p_a[known])
    err = np.linalg.norm(scene.project(p_b) - fb.uv[m.i2[known]], axis=1)
    err = np.where(np.isfinite(err), err, np.inf)
    true = err <= tol_px
    return {**out, "true_matches": int(true.sum()), "true_positive_rate": float(true.mean()) if known.any() else
            float("nan"), "median_error_px": float(np.median(err[true])) if true.any() else float("nan"),
            "matches_with_truth": int(known.sum()), "error_px": err}
