"""EVALUATOR SIDE: known surface points of a rendered scene and where each camera sees them, by ray casting.

For a scene whose surfaces are not one known plane (the x-y table's desk robot in its lab corner), the
``true_projection`` features need 3-D points that lie on what the cameras see. :class:`SceneRays` builds the
MuJoCo model of a :class:`~bench.sim.scenes.base.SceneObject` at its pose and casts rays with ``mujoco.mj_ray``
(exact intersection with every geom, meshes included):

* :meth:`SceneRays.surface_points` - the first surface hit by the rays of ``n`` pixels drawn uniformly over a camera's
  image (the true lens's rays, through its flat port if it has one): points that camera sees;
* :meth:`SceneRays.first_hits` - where given rays (origins, unit directions) first meet a surface;
* :meth:`SceneRays.visible` - whether a camera centre sees each point, i.e. nothing lies between them (occlusion by
  the arm, the toolbox, the arm's own links).

Frames: the object is placed at ``T_frame_object`` in a world that is the caller's frame (the x-y table's), so the
points and the camera poses are in that frame. Nothing here is visible to the pipeline.
"""

from __future__ import annotations

import numpy as np

#: a point is visible when the ray from the camera reaches it within this distance (m) of its range
VISIBLE_TOL_M = 1e-3
#: rays start this far ahead of the camera centre (m): nothing in the scene is closer
NEAR_M = 0.02


class SceneRays:
    """Ray casting in ``obj`` placed at ``T_frame_object`` (4, 4) (see the module docstring)."""

    def __init__(self, obj, T_frame_object):
        import mujoco

        from bench.sim.scenes.base import compose, place

        self.model = compose([place(obj, T_frame_object)]).compile()
        self.data = mujoco.MjData(self.model)
        mujoco.mj_forward(self.model, self.data)
        self._geomid = np.zeros(1, np.int32)

    def _cast(self, origin, direction) -> float:
        """Distance (m) along the unit ``direction`` from ``origin`` to the first surface; inf if none."""
        import mujoco

        d = mujoco.mj_ray(self.model, self.data, np.asarray(origin, float), np.asarray(direction, float), None, 1, -1,
                          self._geomid)
        return np.inf if d < 0 else float(d)

    def surface_points(self, T_frame_cam, lens, port, n: int, rng) -> np.ndarray:
        """``(M, 3)`` points (frame) where the rays of ``n`` uniformly drawn pixels of the camera at ``T_frame_cam``
        first meet a surface (``M <= n``: rays that leave the scene are dropped)."""
        uv = np.c_[rng.uniform(0, lens.width - 1, n), rng.uniform(0, lens.height - 1, n)]
        dirs = lens.unproject(uv)
        origins = np.zeros_like(dirs)
        if port is not None:
            from bench.camera.flatport import trace_rays

            origins, dirs, _ = trace_rays(dirs, port)
            dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
        R, t = T_frame_cam[:3, :3], T_frame_cam[:3, 3]
        hits = self.first_hits(origins @ R.T + t, dirs @ R.T)
        return hits[np.all(np.isfinite(hits), axis=1)]

    def first_hits(self, origins, directions) -> np.ndarray:
        """``(N, 3)`` points (frame) where the rays from ``origins (N, 3)`` along the unit ``directions (N, 3)`` first
        meet a surface beyond :data:`NEAR_M`; NaN rows for rays that leave the scene."""
        out = np.full((len(origins), 3), np.nan)
        for i, (o, d) in enumerate(zip(np.asarray(origins, float), np.asarray(directions, float), strict=True)):
            s = self._cast(o + NEAR_M * d, d)
            if np.isfinite(s):
                out[i] = o + (NEAR_M + s) * d
        return out

    def visible(self, points, centre) -> np.ndarray:
        """``(N,)`` bool: nothing lies between ``centre`` (3,) and each of ``points (N, 3)`` (frame)."""
        c = np.asarray(centre, float)
        out = np.zeros(len(points), bool)
        for i, p in enumerate(np.asarray(points, float)):
            v = p - c
            r = np.linalg.norm(v)
            if r <= NEAR_M:
                continue
            d = v / r
            out[i] = self._cast(c + NEAR_M * d, d) >= r - NEAR_M - VISIBLE_TOL_M
        return out
