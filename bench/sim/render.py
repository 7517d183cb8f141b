"""Headless rendering of a MuJoCo scene from a named camera: RGB and metric depth.

* :func:`check_gl` - creates and frees a tiny OpenGL context; when that fails (typically ``MUJOCO_GL=egl`` without
  Mesa's EGL) it raises a one-line :class:`~bench.errors.BenchError` naming the Debian packages to install.
* :class:`SceneRenderer` - RGB and depth of the current ``MjData`` from one camera at the framebuffer size.
* :class:`Renderer` - the bench's renderer: sets the *true* joint angles, renders an ``s``-times supersampled frame
  and returns the pinhole image of the camera's own ``K`` (box filter over each pixel's footprint) and the metric
  depth (the nearest surface within each pixel's footprint; never averaged across edges).

``MUJOCO_GL=egl`` is set by :mod:`bench.sim` before MuJoCo is imported unless the user chose a backend.
"""

from __future__ import annotations

import os
import time

import numpy as np

from bench.errors import BenchError

EGL_HINT = ("could not create an OpenGL context for headless rendering (MUJOCO_GL={gl}): {err}. "
            "Set MUJOCO_GL=egl before mujoco is imported; on Debian/Ubuntu install Mesa's EGL: "
            "apt-get install libegl1 libgl1-mesa-dri")


def _gl_error(exc: Exception) -> BenchError:
    lines = str(exc).strip().splitlines() or [type(exc).__name__]
    return BenchError(EGL_HINT.format(gl=os.environ.get("MUJOCO_GL"), err=lines[0]))


def check_gl() -> None:
    """Create and free a 1 x 1 OpenGL context with the backend of ``MUJOCO_GL``; :class:`BenchError` if impossible."""
    try:
        import mujoco

        if mujoco.GLContext is None:  # no backend could be loaded at import time
            raise RuntimeError("MuJoCo found no usable OpenGL backend")
        ctx = mujoco.GLContext(1, 1)
        ctx.make_current()
        ctx.free()
    except Exception as exc:  # noqa: BLE001 - any GL failure becomes the one-line hint
        raise _gl_error(exc) from None


def box_filter(image, s: int) -> np.ndarray:
    """Mean of each ``s x s`` pixel block of ``image (s H, s W, 3) uint8``, rounded: ``(H, W, 3) uint8``.

    ``cv2.resize(..., INTER_AREA)`` on float32 at an integer factor is the exact block mean (to float32 rounding);
    five times faster than a numpy reduction.
    """
    import cv2

    h, w = image.shape[0] // s, image.shape[1] // s
    mean = cv2.resize(image.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
    return np.clip(np.round(mean), 0, 255).astype(np.uint8)


def nearest_surface(depth, s: int) -> np.ndarray:
    """Minimum of each ``s x s`` block of ``depth (s H, s W)``: the nearest surface in each pixel footprint (m)."""
    return depth.reshape(depth.shape[0] // s, s, depth.shape[1] // s, s).min(axis=(1, 3))


class SceneRenderer:
    """Render RGB and depth from camera ``camera`` of ``model`` at ``width x height`` px.

    The offscreen framebuffer of the model (``<visual><global offwidth offheight>``) must be at least that large.
    Depth is the distance along the camera's optical axis (m); pixels that see nothing are ``inf``.

    One OpenGL context, scene and MuJoCo render context per instance, created once and reused for every frame. The
    depth buffer is converted to metric z exactly as ``mujoco.Renderer`` does (reversed-z, float64 arithmetic on the
    float32 buffer, rounded to float32). Without multisampling (``<quality offsamples="0"/>``) each frame is
    rasterised once and colour and depth are read from that pass - bit for bit what ``mujoco.Renderer``'s separate
    colour and depth passes give (tested). With multisampling the resolved depth of the lit pass would be one of the
    MSAA samples at edges rather than the pixel centre, so the depth then comes from a second, unlit pass with
    MuJoCo's segmentation flags (which renders without multisampling), as ``mujoco.Renderer`` does.
    """

    def __init__(self, model, camera: str, width: int, height: int):
        import mujoco

        self.model, self.camera, self.width, self.height = model, camera, int(width), int(height)
        self._con = self._ctx = None
        cid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
        if cid < 0:
            raise BenchError(f"camera {camera!r}: not in the scene model")
        if model.vis.global_.offwidth < self.width or model.vis.global_.offheight < self.height:
            raise BenchError(f"render size {self.width}x{self.height} exceeds the model's offscreen buffer "
                             f"{model.vis.global_.offwidth}x{model.vis.global_.offheight}")
        try:
            if mujoco.GLContext is None:
                raise RuntimeError("MuJoCo found no usable OpenGL backend")
            self._ctx = mujoco.GLContext(self.width, self.height)
            self._ctx.make_current()
            self._con = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
            mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._con)
            self._con.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        except Exception as exc:  # noqa: BLE001 - any GL failure becomes the one-line hint
            self.close()
            raise _gl_error(exc) from None
        self._scene = mujoco.MjvScene(model, maxgeom=10000)
        self._option = mujoco.MjvOption()
        self._cam = mujoco.MjvCamera()
        self._cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._cam.fixedcamid = cid
        self._rect = mujoco.MjrRect(0, 0, self.width, self.height)
        self._msaa = int(model.vis.quality.offsamples) > 0  # the framebuffer's samples, fixed at context creation
        self._rgb = np.empty((self.height, self.width, 3), dtype=np.uint8)
        self._zbuf = np.empty((self.height, self.width), dtype=np.float32)
        self.zfar = model.vis.map.zfar * model.stat.extent
        # glFrustum's reversed-z coefficients in float32, as mujoco.Renderer computes them
        zfar, znear = np.float32(self.zfar), np.float32(model.vis.map.znear * model.stat.extent)
        c = -(zfar + znear) / (zfar - znear)
        d = -(np.float32(2) * zfar * znear) / (zfar - znear)
        self._c, self._d = float(np.float32(-0.5) * c - np.float32(0.5)), float(np.float32(-0.5) * d)

    def render(self, data) -> tuple:
        """``(rgb uint8 (H, W, 3), depth float64 (H, W) m)`` for the current ``data`` (after ``mj_forward``)."""
        import mujoco

        if self._con is None:
            raise RuntimeError("SceneRenderer: render() after close()")
        self._ctx.make_current()
        mujoco.mjv_updateScene(self.model, data, self._option, None, self._cam, mujoco.mjtCatBit.mjCAT_ALL,
                               self._scene)
        mujoco.mjr_render(self._rect, self._scene, self._con)
        if not self._msaa:
            mujoco.mjr_readPixels(self._rgb, self._zbuf, self._rect, self._con)
        else:
            mujoco.mjr_readPixels(self._rgb, None, self._rect, self._con)
            flags = self._scene.flags.copy()
            self._scene.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = True
            self._scene.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = True
            try:
                mujoco.mjr_render(self._rect, self._scene, self._con)
                mujoco.mjr_readPixels(None, self._zbuf, self._rect, self._con)
            finally:
                np.copyto(self._scene.flags, flags)
        rgb = self._rgb[::-1].copy()  # OpenGL rows run bottom-up
        depth = self._d / (self._zbuf[::-1].astype(np.float64) + self._c)
        # mujoco.Renderer rounds the metric depth to float32: keep its values bit for bit
        depth = depth.astype(np.float32).astype(np.float64)
        depth[depth >= 0.99 * self.zfar] = np.inf  # the far plane (float32 depth buffer: ~0.1 % short of zfar)
        return rgb, depth

    def close(self) -> None:
        if self._con is not None:
            self._ctx.make_current()
            self._con.free()
            self._con = None
        if self._ctx is not None:
            self._ctx.free()
            self._ctx = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


class Renderer:
    """RGB and metric depth from a camera of a model at given true joint angles, supersampled.

    Parameters
    ----------
    model : mujoco.MjModel
        A compiled scene (e.g. of :func:`bench.sim.mjcf.scene_spec`). Its offscreen buffer is enlarged if it is smaller
        than the supersampled frame.
    camera : str
        Camera name (default the arm's ``link5_camera``).
    supersample : int
        ``s`` in 1..16: the frame is rendered at ``s W x s H`` and box-filtered down.
    width, height : int, optional
        Output size (px); default the camera's ``resolution``.
    joints : sequence of str, optional
        Joints set by :meth:`render` (default ``joint1`` .. ``joint6``).

    Attributes
    ----------
    K : ndarray (3, 3)
        OpenCV intrinsics of the output image (:func:`bench.sim.camera.opencv_intrinsics`).
    render_s : list of float
        Wall time of each :meth:`render` call (s).
    """

    def __init__(self, model, camera: str = "link5_camera", supersample: int = 1, width: int | None = None,
                 height: int | None = None, joints=None):
        import mujoco

        from bench.sim.camera import _camera_id, opencv_intrinsics
        from bench.sim.distortion import check_supersample

        self.model, self.camera = model, camera
        self.supersample = s = check_supersample(supersample)
        try:
            cid = _camera_id(model, camera)
        except ValueError as exc:
            raise BenchError(str(exc)) from None
        res = model.cam_resolution[cid]
        self.width = int(res[0] if width is None else width)
        self.height = int(res[1] if height is None else height)
        if self.width <= 0 or self.height <= 0 or (width is None and self.width * self.height == 1):
            raise ValueError(f"camera {camera!r}: give width and height (the camera has no resolution attribute)")
        self.K = opencv_intrinsics(model, camera, self.width, self.height)
        names = [f"joint{k}" for k in range(1, 7)] if joints is None else list(joints)
        ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n) for n in names]
        missing = [n for n, i in zip(names, ids, strict=True) if i < 0]
        if missing:
            raise BenchError(f"joints: {missing} not in the model")
        self.joints = names
        self._qadr = np.array([model.jnt_qposadr[i] for i in ids], dtype=int)
        self._range = np.array([model.jnt_range[i] for i in ids], dtype=float)
        self._limited = np.array([bool(model.jnt_limited[i]) for i in ids])
        check_gl()
        g = model.vis.global_
        g.offwidth, g.offheight = max(g.offwidth, s * self.width), max(g.offheight, s * self.height)
        self.data = mujoco.MjData(model)
        self._scene = SceneRenderer(model, camera, s * self.width, s * self.height)
        self.render_s: list = []

    def set_joints(self, q_true) -> None:
        """Set the true joint angles ``q_true (n,)`` (rad) and update the kinematics."""
        import mujoco

        q = np.asarray(q_true, dtype=float)
        if q.shape != (len(self.joints),) or not np.all(np.isfinite(q)):
            raise ValueError(f"q_true: expected {len(self.joints)} finite joint angles (rad), got shape {q.shape}")
        lo, hi = self._range[:, 0], self._range[:, 1]
        bad = self._limited & ((q < lo - 1e-9) | (q > hi + 1e-9))
        if bad.any():
            k = int(np.argmax(bad))
            raise ValueError(f"q_true: {self.joints[k]} = {q[k]:.6g} rad is outside its range "
                             f"[{lo[k]:.6g}, {hi[k]:.6g}] rad")
        self.data.qpos[self._qadr] = q
        mujoco.mj_forward(self.model, self.data)

    def render(self, q_true=None) -> tuple:
        """``(rgb uint8 (H, W, 3), depth float64 (H, W) m)`` at the true joint angles ``q_true`` (rad).

        ``q_true=None`` renders the current state. RGB is the mean of each pixel's ``s x s`` sub-samples (in the
        8-bit encoded values, rounded); depth is the distance along the optical axis of the nearest surface among
        them, ``inf`` where nothing is seen.
        """
        t0 = time.perf_counter()
        if q_true is not None:
            self.set_joints(q_true)
        rgb, depth = self._scene.render(self.data)
        s = self.supersample
        if s > 1:
            rgb, depth = box_filter(rgb, s), nearest_surface(depth, s)
        self.render_s.append(time.perf_counter() - t0)
        return rgb, depth

    def close(self) -> None:
        self._scene.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
