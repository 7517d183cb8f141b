"""Scene objects built with MuJoCo's model-editing API (``mujoco.MjSpec``), and a composer of standalone scenes.

A :class:`SceneObject` is what every scene generator returns: a ``build(spec, parent)`` function that adds the
object's assets (meshes, textures, materials) to an ``MjSpec`` and its bodies/geoms/sites/cameras/lights into a
parent body (in the object's own frame), the asset files it references, and its ground-truth ``features`` (3D
points, axes, poses, in the object frame, SI units). Generation draws every random number and renders every texture
once; ``build`` only adds elements, so one object can be built into any number of models. :func:`place` poses an
object under a body of its own; :func:`compose` makes a standalone scene of objects (lights, visual settings, the
free camera framed by the statistic, an ``overview`` camera) and returns its ``MjSpec``; ``spec.compile()`` gives
the ``MjModel``. MuJoCo's compiler refuses repeated names, so two objects cannot clash silently.

Assets (decision): textures live **in memory**. ``files`` maps an asset file name (unique, prefixed by the object
name) to PNG bytes (or to a path, read when composed); :func:`compose` puts them in ``spec.assets``. Nothing is
written to disk unless :func:`save_scene` is called, which writes ``spec.to_xml()`` and the files side by side so
``mujoco.MjModel.from_xml_path`` works too (MuJoCo writes 6 significant digits: a saved scene is for looking at).
This keeps generation seeded and side-effect free, and a hash of the compiled model (:func:`scene_key`, MuJoCo's
exact binary format) identifies a scene exactly.

Textured faces use small closed box/disc **meshes with explicit texture coordinates** (MuJoCo maps 2D textures on
primitive boxes in ways that are hard to control; with explicit UVs the image's top-left is exactly at the face's
(-x, +y) corner, image rows running down -y, checked by a render test).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import mujoco
import numpy as np

from bench.errors import ConfigError
from bench.geometry.quaternion import matrix_to_quaternion
from bench.geometry.transforms import check_transform


@dataclass
class SceneObject:
    """A buildable scene object with its assets and ground truth.

    Attributes
    ----------
    name : str
        Unique object name; every MuJoCo name the object adds starts with it.
    build : callable
        ``build(spec, parent)``: adds the assets to the ``mujoco.MjSpec`` ``spec`` and the elements into the body
        ``parent`` (in the object frame, which is the world frame unless the object is wrapped by :func:`place`).
    files : dict[str, bytes | str | Path]
        Asset files the assets reference (``file=``): content bytes or a path to read.
    features : dict
        Ground truth in the object frame (m, unit vectors, 4x4 transforms); documented by each generator.
    """

    name: str
    build: Callable
    files: dict = field(default_factory=dict)
    features: dict = field(default_factory=dict)


def pose(T) -> dict:
    """``pos`` and ``quat`` keyword arguments of a 4x4 rigid transform (MuJoCo quaternions are scalar first)."""
    T = check_transform(T, "pose")
    return {"pos": T[:3, 3].copy(), "quat": matrix_to_quaternion(T[:3, :3])}


def frame_from_axis(axis, origin=(0.0, 0.0, 0.0), roll=0.0):
    """A transform whose z axis is the unit vector ``axis`` (3,), rotated by ``roll`` (rad) about it, at ``origin``."""
    z = np.asarray(axis, float)
    n = np.linalg.norm(z)
    if z.shape != (3,) or not np.isfinite(n) or n < 1e-12:
        raise ValueError(f"axis: expected a finite non-zero 3-vector, got {axis!r}")
    z = z / n
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c, s = np.cos(roll), np.sin(roll)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2] = c * x + s * y, -s * x + c * y, z
    T[:3, 3] = origin
    return T


def add_geom(parent, name: str | None, kind: str, material: str, size=(), euler=None, **kw):
    """A geom of type ``kind`` (``"box"``, ``"cylinder"``, ``"mesh"`` with ``meshname=`` ...) in ``parent``.

    ``size`` may be shorter than 3 (the rest is zero, as in MJCF); ``euler`` (rad, xyz) orients it instead of
    ``quat``; further keyword arguments are ``MjsGeom`` fields (``pos``, ``quat``, ``fromto``, ``contype`` ...).
    """
    size = np.r_[np.asarray(size, float), np.zeros(3 - len(size))]
    geom = parent.add_geom(name=name or "", type=getattr(mujoco.mjtGeom, f"mjGEOM_{kind.upper()}"),
                           material=material, size=size, **kw)
    if euler is not None:
        geom.alt.type, geom.alt.euler = mujoco.mjtOrientation.mjORIENTATION_EULER, euler
    return geom


def add_texture_material(spec, name: str, file_name: str, specular=0.05, shininess=0.05) -> str:
    """A 2D texture ``name`` from the asset file ``file_name`` and a material ``name`` using it; returns ``name``."""
    spec.add_texture(name=name, type=mujoco.mjtTexture.mjTEXTURE_2D, file=file_name)
    mat = spec.add_material(name=name, specular=specular, shininess=shininess)
    mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = name
    return name


def add_color_material(spec, name: str, rgba, specular=0.2, shininess=0.2) -> str:
    """An untextured material; returns ``name``."""
    spec.add_material(name=name, rgba=rgba, specular=specular, shininess=shininess)
    return name


def box_mesh(name: str, half_sizes, uv_rect=(0.0, 0.0, 1.0, 1.0)) -> dict:
    """A closed box mesh centred at the origin whose **+z face** carries the texture rectangle ``uv_rect``.

    ``uv_rect = (u0, v0, u1, v1)``: the face's (-x, +y) corner gets ``(u0, v0)`` (image top-left), the (+x, -y)
    corner ``(u1, v1)``. The side faces repeat the front face's edge texels; the back face is a single texel.
    Returns the ``spec.add_mesh`` keyword arguments (:func:`mesh`).
    """
    hx, hy, hz = (float(v) for v in half_sizes)
    if min(hx, hy, hz) <= 0:
        raise ValueError(f"{name}: box half sizes must be positive, got {half_sizes!r}")
    u0, v0, u1, v1 = uv_rect
    front = [(-hx, -hy, hz), (hx, -hy, hz), (hx, hy, hz), (-hx, hy, hz)]
    back = [(-hx, -hy, -hz), (hx, -hy, -hz), (hx, hy, -hz), (-hx, hy, -hz)]
    uv_front = [(u0, v1), (u1, v1), (u1, v0), (u0, v0)]
    verts, uvs, faces = [], [], []

    def quad(vs, us):
        k = len(verts)
        verts.extend(vs)
        uvs.extend(us)
        faces.extend([(k, k + 1, k + 2), (k, k + 2, k + 3)])

    quad(front, uv_front)
    quad([back[1], back[0], back[3], back[2]], [uv_front[0]] * 4)
    for a, b in ((0, 1), (1, 2), (2, 3), (3, 0)):  # sides, counter-clockwise seen from outside
        quad([back[a], back[b], front[b], front[a]], [uv_front[a], uv_front[b], uv_front[b], uv_front[a]])
    return mesh(name, verts, faces, uvs)


def disc_mesh(name: str, radius: float, half_thickness: float, segments: int = 48) -> dict:
    """A closed cylinder mesh (axis z, centred) whose **+z cap** carries the texture's inscribed circle."""
    if radius <= 0 or half_thickness <= 0 or segments < 8:
        raise ValueError(f"{name}: need radius > 0, half_thickness > 0 and segments >= 8")
    a = 2 * np.pi * np.arange(segments) / segments
    ca, sa = np.cos(a), np.sin(a)
    uv_rim = [(0.5 + 0.5 * c, 0.5 - 0.5 * s) for c, s in zip(ca, sa, strict=True)]
    verts, uvs = [], []
    for z in (half_thickness, -half_thickness):  # front cap, then back cap: centre + rim
        verts += [(0.0, 0.0, z)] + [(radius * c, radius * s, z) for c, s in zip(ca, sa, strict=True)]
        uvs += [(0.5, 0.5)] + uv_rim
    k = segments + 1  # the back cap's centre
    faces = [(0, 1 + i, 1 + (i + 1) % segments) for i in range(segments)]
    faces += [(k, k + 1 + (i + 1) % segments, k + 1 + i) for i in range(segments)]
    # side wall: rim vertices front (1..n) and back (k+1..k+n)
    faces += [(1 + i, k + 1 + i, k + 1 + (i + 1) % segments) for i in range(segments)]
    faces += [(1 + i, k + 1 + (i + 1) % segments, 1 + (i + 1) % segments) for i in range(segments)]
    return mesh(name, verts, faces, uvs)


def frustum_mesh(name: str, r_front: float, r_back: float, length: float, segments: int = 40) -> dict:
    """A closed truncated cone along z: the front (+z) rim of radius ``r_front`` at ``z = length``, the back at 0."""
    if min(r_front, r_back, length) <= 0 or segments < 8:
        raise ValueError(f"{name}: frustum radii and length must be positive")
    a = 2 * np.pi * np.arange(segments) / segments
    verts = [(r_front * np.cos(t), r_front * np.sin(t), length) for t in a]
    verts += [(r_back * np.cos(t), r_back * np.sin(t), 0.0) for t in a]
    verts += [(0.0, 0.0, length), (0.0, 0.0, 0.0)]
    n, cf, cb = segments, 2 * segments, 2 * segments + 1
    faces = [(cf, i, (i + 1) % n) for i in range(n)] + [(cb, n + (i + 1) % n, n + i) for i in range(n)]
    faces += [(i, n + i, n + (i + 1) % n) for i in range(n)] + [(i, n + (i + 1) % n, (i + 1) % n) for i in range(n)]
    return mesh(name, verts, faces)


def mesh(name: str, verts, faces, uvs=None) -> dict:
    """``spec.add_mesh`` keyword arguments of a mesh: vertices (n, 3) m, triangles (m, 3), optional per-vertex
    texture coordinates (n, 2). Add it with ``spec.add_mesh(**mesh(...))``."""
    kw = {"name": name, "uservert": np.ravel(np.asarray(verts, float)), "userface": np.ravel(np.asarray(faces, int))}
    if uvs is not None:
        kw["usertexcoord"] = np.ravel(np.asarray(uvs, float))
    return kw


def place(obj: SceneObject, T_world_obj, name: str | None = None, mocap: bool = False) -> SceneObject:
    """Wrap ``obj`` in a body at the pose ``T_world_obj`` (4x4, m).

    Returns a new :class:`SceneObject` (same assets); ``features["T_world_obj"]`` records the pose. ``name`` names
    the wrapping body (default ``<obj.name>_pose``); ``mocap`` makes it a mocap body (posed per frame through
    ``MjData.mocap_pos``/``mocap_quat``). The features stay in the object frame.
    """
    T = check_transform(T_world_obj, f"{obj.name}: T_world_obj")
    body_name = name or f"{obj.name}_pose"

    def build(spec, parent):
        obj.build(spec, parent.add_body(name=body_name, mocap=mocap, **pose(T)))

    return replace(obj, build=build, features={**obj.features, "T_world_obj": T.copy()})


def add_look_at_camera(parent, name: str, eye, target, fovy_deg: float = 45.0, up=(0.0, 0.0, 1.0)):
    """A fixed camera at ``eye`` (m, in ``parent``'s frame) looking at ``target``, image "up" towards ``up``.

    MuJoCo cameras look along their local -z with +y up; their x (right) and y (up) axes are given (``xyaxes``).
    """
    eye, target, up = (np.asarray(v, float) for v in (eye, target, up))
    fwd = target - eye
    if np.linalg.norm(fwd) < 1e-9:
        raise ValueError(f"camera {name}: eye and target coincide")
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, up)
    if np.linalg.norm(right) < 1e-9:
        raise ValueError(f"camera {name}: viewing direction parallel to up")
    right /= np.linalg.norm(right)
    cam = parent.add_camera(name=name, pos=eye, fovy=float(fovy_deg))
    cam.alt.type = mujoco.mjtOrientation.mjORIENTATION_XYAXES
    cam.alt.xyaxes = np.r_[right, np.cross(right, fwd)]
    return cam


def _read_files(objects) -> dict:
    assets = {}
    for obj in objects:
        for fname, content in obj.files.items():
            if fname in assets:
                raise ValueError(f"asset file name {fname!r} used by two scene objects")
            if isinstance(content, (bytes, bytearray)):
                assets[fname] = bytes(content)
            else:
                p = Path(content)
                if not p.is_file():
                    raise ConfigError(str(p), f"{obj.name}: {fname}", "asset file not found")
                assets[fname] = p.read_bytes()
    return assets


def compose(objects, extra=None, offscreen=(1280, 960), center=(0.0, 0.0, 0.5), extent=2.0,
            model_name: str = "scene") -> mujoco.MjSpec:
    """A complete standalone scene of ``objects`` with lights and cameras, as an ``MjSpec`` holding its assets.

    Parameters
    ----------
    objects : iterable of SceneObject
    extra : callable or None
        ``extra(spec)`` adds more to the world after the objects (cameras from :func:`add_look_at_camera`,
        markers ...).
    offscreen : (int, int)
        Offscreen framebuffer width, height (px): the largest image a ``mujoco.Renderer`` may render.
    center, extent : (3,), float
        The statistic: frames MuJoCo's free camera (``mjCAMERA_FREE``, the default of ``Renderer.update_scene``)
        on the scene; an ``overview`` fixed camera looks at ``center`` from the same distance.

    Returns
    -------
    mujoco.MjSpec
        With the asset files in ``spec.assets``; ``spec.compile()`` gives the ``MjModel``.
    """
    objects = list(objects)
    names = [o.name for o in objects]
    if len(set(names)) != len(names):
        raise ValueError(f"scene object names must be unique, got {names}")
    spec = mujoco.MjSpec()
    spec.modelname = model_name
    spec.compiler.degree = False
    spec.assets = _read_files(objects)
    center = np.asarray(center, float)
    vis = spec.visual
    vis.global_.offwidth, vis.global_.offheight = (int(v) for v in offscreen)
    vis.quality.shadowsize, vis.quality.offsamples = 2048, 4
    vis.headlight.ambient, vis.headlight.diffuse, vis.headlight.specular = [0.25] * 3, [0.35] * 3, [0.05] * 3
    vis.map.znear, vis.map.zfar = 0.005, 200.0
    spec.stat.center, spec.stat.extent = center, float(extent)
    world = spec.worldbody
    for name, direction, diffuse, specular, shadow in (("key", (0.3, 0.6, -1.0), 0.55, 0.05, True),
                                                       ("fill", (-0.5, 0.8, -0.3), 0.25, 0.0, False)):
        world.add_light(name=name, type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL, pos=[0, 0, 5],
                        dir=np.array(direction) / np.linalg.norm(direction), diffuse=[diffuse] * 3,
                        specular=[specular] * 3, castshadow=shadow)
    add_look_at_camera(world, "overview", center + extent * np.array([0.35, -1.0, 0.45]), center, 45.0)
    for obj in objects:
        obj.build(spec, world)
    if extra is not None:
        extra(spec)
    return spec


def scene_key(model, h=None):
    """``h`` (default a new ``hashlib.sha256``) fed with the compiled ``model`` in MuJoCo's binary format (MJB).

    The MJB holds every number of the model exactly, names, meshes and texture pixels included, so equal keys mean
    equal models. (``MjSpec.to_xml()`` would not do: it writes 6 significant digits.)
    """
    h = h or hashlib.sha256()
    buf = np.empty(mujoco.mj_sizeModel(model), np.uint8)
    mujoco.mj_saveModel(model, None, buf)
    h.update(buf.tobytes())
    return h


def save_scene(spec, folder, file_name: str = "scene.xml") -> Path:
    """Write ``spec.to_xml()`` and its asset files into ``folder`` (created); returns the XML path (loadable)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for fname, content in spec.assets.items():
        (folder / fname).write_bytes(content)
    path = folder / file_name
    path.write_text(spec.to_xml())
    return path
