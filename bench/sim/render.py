"""Headless rendering of a MuJoCo scene from a named camera: RGB and metric depth.

``MUJOCO_GL=egl`` is set by :mod:`bench.sim` before MuJoCo is imported unless the user chose a backend. If an
OpenGL context cannot be created, the error is one line naming the Debian packages that provide Mesa's software EGL.
"""

from __future__ import annotations

import os

import numpy as np

from bench.errors import BenchError

EGL_HINT = ("could not create an OpenGL context for headless rendering (MUJOCO_GL={gl}): {err}. "
            "On Debian/Ubuntu install Mesa's EGL: apt-get install libegl1 libgl1-mesa-dri")


class SceneRenderer:
    """Render RGB and depth from camera ``camera`` of ``model`` at ``width x height`` px.

    The offscreen framebuffer of the model (``<visual><global offwidth offheight>``) must be at least that large.
    Depth is the distance along the camera's optical axis (m); pixels that see nothing are ``inf``.
    """

    def __init__(self, model, camera: str, width: int, height: int):
        import mujoco

        self.model, self.camera, self.width, self.height = model, camera, int(width), int(height)
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera) < 0:
            raise BenchError(f"camera {camera!r}: not in the scene model")
        if model.vis.global_.offwidth < self.width or model.vis.global_.offheight < self.height:
            raise BenchError(f"render size {self.width}x{self.height} exceeds the model's offscreen buffer "
                             f"{model.vis.global_.offwidth}x{model.vis.global_.offheight}")
        try:
            self._rgb = mujoco.Renderer(model, self.height, self.width)
            self._depth = mujoco.Renderer(model, self.height, self.width)
        except Exception as exc:  # noqa: BLE001 - any GL failure becomes the one-line hint
            raise BenchError(EGL_HINT.format(gl=os.environ.get("MUJOCO_GL"), err=str(exc).splitlines()[0])) from None
        self._depth.enable_depth_rendering()
        self.zfar = model.vis.map.zfar * model.stat.extent

    def render(self, data) -> tuple:
        """``(rgb uint8 (H, W, 3), depth float64 (H, W) m)`` for the current ``data`` (after ``mj_forward``)."""
        self._rgb.update_scene(data, self.camera)
        rgb = self._rgb.render().copy()
        self._depth.update_scene(data, self.camera)
        depth = self._depth.render().astype(np.float64)
        depth[depth >= 0.99 * self.zfar] = np.inf  # the far plane (float32 depth buffer: ~0.1 % short of zfar)
        return rgb, depth

    def close(self) -> None:
        self._rgb.close()
        self._depth.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
