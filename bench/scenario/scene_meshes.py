"""The simulated scene as triangle meshes for rerun: what MuJoCo renders, read back from the compiled model.

The recordings draw the scene as it is - the TA-40's link meshes, the textured manifold panel, the rig's boards -
rather than polylines. The source of truth is the MuJoCo model the simulator renders: :class:`SceneMeshes` compiles
scene objects (:mod:`bench.sim.scenes`, :func:`bench.sim.mjcf.robot_object`) with :func:`bench.sim.scenes.base.compose`
and turns every visible geom (MJCF ``group`` 0-2; sites are not geoms) into a :class:`MeshPart` in the frame of the
body that carries it:

* mesh geoms keep their triangles (MuJoCo's compiled vertices, i.e. after its re-centring, placed by the geom's
  pose); meshes with texture coordinates keep them and their material's texture (``mjTEXROLE_RGB``), downsampled to
  at most ``max_texture_px`` on a side so that a recording stays small;
* primitives (box, cylinder, sphere, capsule, ellipsoid) become trimesh primitives of the same size;
* vertices are not shared between triangles (flat shading: a face's normal on its three corners), and every
  untextured geom of a body is merged into one part with per-vertex colours (the material's ``rgba``, else the
  geom's).

:meth:`SceneMeshes.body_poses` gives ``T_model_body`` (4 x 4, m) of every body for given joint angles (MuJoCo's own
forward kinematics), so that a recording logs each body's meshes once and its pose per configuration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.geometry.transforms import homogeneous

#: MJCF geom groups drawn (MuJoCo's default visible groups; the arm's and the scenes' visuals use 0 and 1).
VISIBLE_GROUPS = (0, 1, 2)


@dataclass
class MeshPart:
    """Triangles of one body (or one textured geom of it), in the body frame.

    Attributes
    ----------
    name : str
        The geom's name for a textured part, ``"solid"`` for a body's merged untextured geoms.
    vertices : ndarray (3 F, 3) float32
        Triangle corners (m), three per face, not shared.
    normals : ndarray (3 F, 3) float32
        The face normal at each corner (unit).
    colors : ndarray (3 F, 4) uint8 or None
        RGBA per corner (untextured parts).
    texcoords : ndarray (3 F, 2) float32 or None
        Texture coordinates per corner, (0, 0) the texture image's top-left.
    texture : ndarray (H, W, 3) uint8 or None
        The albedo texture (RGB, row 0 at the top).
    """

    name: str
    vertices: np.ndarray
    normals: np.ndarray
    colors: np.ndarray | None = None
    texcoords: np.ndarray | None = None
    texture: np.ndarray | None = None

    @property
    def n_triangles(self) -> int:
        return len(self.vertices) // 3


def _primitive(gtype: int, size, sections: int):
    """A trimesh primitive of MuJoCo geom type ``gtype`` and ``size`` (its own frame), or None (planes, ...)."""
    import mujoco
    import trimesh

    g = mujoco.mjtGeom
    if gtype == g.mjGEOM_BOX:
        return trimesh.creation.box(extents=2 * np.asarray(size[:3]))
    if gtype == g.mjGEOM_CYLINDER:
        return trimesh.creation.cylinder(radius=size[0], height=2 * size[1], sections=sections)
    if gtype == g.mjGEOM_CAPSULE:
        return trimesh.creation.capsule(height=2 * size[1], radius=size[0], count=[sections, sections // 2])
    if gtype in (g.mjGEOM_SPHERE, g.mjGEOM_ELLIPSOID):
        m = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
        m.apply_scale(np.asarray(size[:3]) if gtype == g.mjGEOM_ELLIPSOID else size[0])
        return m
    return None


def _flat(vertices, faces):
    """Unshared corners ``(3F, 3)`` and their face normals."""
    corners = vertices[faces].reshape(-1, 3)
    tri = corners.reshape(-1, 3, 3)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    return corners, np.repeat(n, 3, axis=0)


def _downsample(img: np.ndarray, max_px: int) -> np.ndarray:
    import cv2

    h, w = img.shape[:2]
    s = max_px / max(h, w)
    if s >= 1:
        return img
    return cv2.resize(img, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)


class SceneMeshes:
    """The visible geometry of scene objects, per body (see the module docstring).

    Parameters
    ----------
    objects : list of SceneObject
        Scene objects as :func:`bench.sim.scenes.base.compose` takes them (placed in the model's world).
    max_texture_px : int
        Textures are downsampled to at most this many pixels on their longer side.
    sections : int
        Segments of primitive cylinders and capsules.

    Attributes
    ----------
    parts : dict[str, list[MeshPart]]
        Body name -> its parts (bodies without visible geoms are left out).
    """

    def __init__(self, objects, max_texture_px: int = 1024, sections: int = 20):
        import mujoco

        from bench.sim.scenes.base import compose

        if max_texture_px < 8:
            raise ValueError(f"max_texture_px: expected >= 8 px, got {max_texture_px}")
        self.model = compose(list(objects), offscreen=(64, 64)).compile()
        self.data = mujoco.MjData(self.model)
        self.parts = self._parts(max_texture_px, sections)

    def _texture(self, matid: int, cache: dict, max_px: int):
        m = self.model
        if matid < 0:
            return None
        tex = int(m.mat_texid[matid, 1])  # mjTEXROLE_RGB
        if tex < 0:
            tex = int(m.mat_texid[matid, 8])  # mjTEXROLE_RGBA
        if tex < 0 or int(m.tex_type[tex]) != 0:  # 2D textures only
            return None
        if tex not in cache:
            w, h, c = int(m.tex_width[tex]), int(m.tex_height[tex]), int(m.tex_nchannel[tex])
            a = int(m.tex_adr[tex])
            img = m.tex_data[a:a + w * h * c].reshape(h, w, c)[..., :3]
            cache[tex] = _downsample(np.ascontiguousarray(img), max_px)
        return cache[tex]

    def _parts(self, max_px: int, sections: int) -> dict:
        import mujoco

        m = self.model
        out: dict = {}
        solid: dict = {}
        textures: dict = {}
        for g in range(m.ngeom):
            if int(m.geom_group[g]) not in VISIBLE_GROUPS:
                continue
            matid = int(m.geom_matid[g])
            rgba = m.mat_rgba[matid] if matid >= 0 else m.geom_rgba[g]
            if rgba[3] <= 0:
                continue
            R = np.zeros(9)
            mujoco.mju_quat2Mat(R, m.geom_quat[g])
            R, p = R.reshape(3, 3), m.geom_pos[g]
            body = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, int(m.geom_bodyid[g])) or "world"
            uv = tex = None
            if int(m.geom_type[g]) == mujoco.mjtGeom.mjGEOM_MESH:
                k = int(m.geom_dataid[g])
                va, vn, fa, fn = (int(x[k]) for x in (m.mesh_vertadr, m.mesh_vertnum, m.mesh_faceadr, m.mesh_facenum))
                faces = m.mesh_face[fa:fa + fn]
                corners, normals = _flat(m.mesh_vert[va:va + vn].astype(float), faces)
                tex = self._texture(matid, textures, max_px)
                if tex is not None and int(m.mesh_texcoordnum[k]) > 0:
                    ta = int(m.mesh_texcoordadr[k])
                    tc = m.mesh_texcoord[ta:ta + int(m.mesh_texcoordnum[k])]
                    # MuJoCo's texture rows and v both run from the image's top, as rerun's do (checked on a render)
                    uv = tc[m.mesh_facetexcoord[fa:fa + fn].reshape(-1)].astype(np.float32)
                else:
                    tex = None
            else:
                prim = _primitive(int(m.geom_type[g]), m.geom_size[g], sections)
                if prim is None:
                    continue
                corners, normals = _flat(np.asarray(prim.vertices, float), np.asarray(prim.faces))
            corners = corners @ R.T + p
            normals = normals @ R.T
            if tex is not None:
                name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom{g}"
                out.setdefault(body, []).append(MeshPart(name, corners.astype(np.float32),
                                                         normals.astype(np.float32), None, uv, tex))
            else:
                col = np.tile(np.round(np.clip(rgba, 0, 1) * 255).astype(np.uint8), (len(corners), 1))
                solid.setdefault(body, []).append((corners, normals, col))
        for body, items in solid.items():
            v, n, c = (np.concatenate(x) for x in zip(*items, strict=True))
            out.setdefault(body, []).insert(0, MeshPart("solid", v.astype(np.float32), n.astype(np.float32), c))
        return out

    def body_poses(self, qpos: dict | None = None) -> dict:
        """``{body: T_model_body (4, 4)}`` for every body with parts, at joint angles ``qpos`` ``{joint: rad}``."""
        import mujoco

        m, d = self.model, self.data
        d.qpos[:] = m.qpos0
        for joint, value in (qpos or {}).items():
            d.qpos[m.jnt_qposadr[m.joint(joint).id]] = value
        mujoco.mj_kinematics(m, d)
        out = {}
        for body in self.parts:
            b = m.body(body).id if body != "world" else 0
            out[body] = homogeneous(d.xmat[b].reshape(3, 3), d.xpos[b])
        return out

    def merged(self, qpos: dict | None = None) -> list:
        """The whole scene in the model frame at joint angles ``qpos``: one ``"solid"`` :class:`MeshPart` of every
        untextured part (vertex colours kept), then each textured part on its own (a rigid object drawn many times,
        e.g. the rig at every view's pose, is then one mesh with instance poses)."""
        solid, textured = [], []
        for body, T in self.body_poses(qpos).items():
            R, p = T[:3, :3], T[:3, 3]
            for part in self.parts[body]:
                moved = MeshPart(part.name, (part.vertices @ R.T + p).astype(np.float32),
                                 (part.normals @ R.T).astype(np.float32), part.colors, part.texcoords, part.texture)
                (textured if part.texture is not None else solid).append(moved)
        out = []
        if solid:
            v, n, c = (np.concatenate(x) for x in zip(*((p.vertices, p.normals, p.colors) for p in solid),
                                                       strict=True))
            out.append(MeshPart("solid", v, n, c))
        return out + textured

    @property
    def n_triangles(self) -> int:
        return sum(p.n_triangles for ps in self.parts.values() for p in ps)
