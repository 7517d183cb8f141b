"""Scene objects as MJCF fragments, and a composer that makes a standalone, renderable MJCF of them.

A :class:`SceneObject` is what every scene generator returns: an MJCF fragment for ``<worldbody>``, one for
``<asset>``, the asset files it references, and its ground-truth ``features`` (3D points, axes, poses, in the
object's own frame, SI units). The robot/scene composer pastes the fragments into its own model; :func:`compose`
does the same for testing a scene alone (lights, a floor-free world, an overview camera, the free camera framed by
``<statistic>``).

Assets (decision): textures live **in memory**. ``files`` maps an asset file name (unique, prefixed by the object
name) to PNG bytes (or to a path, read when composed); :func:`compose` returns ``assets = {name: bytes}`` for
``mujoco.MjModel.from_xml_string(xml, assets=assets)``. Nothing is written to disk unless :func:`save_scene` is
called, which writes the XML and the files side by side so ``mujoco.MjModel.from_xml_path`` works too. This keeps
generation seeded and side-effect free, and a content hash of ``(xml, assets)`` identifies a scene exactly.

Textured faces use small closed box/disc **meshes with explicit texture coordinates** (MuJoCo maps 2D textures on
primitive boxes in ways that are hard to control; with explicit UVs the image's top-left is exactly at the face's
(-x, +y) corner, image rows running down -y, checked by a render test).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from bench.errors import ConfigError
from bench.geometry.quaternion import matrix_to_quaternion
from bench.geometry.transforms import check_transform


@dataclass
class SceneObject:
    """An MJCF fragment with its assets and ground truth.

    Attributes
    ----------
    name : str
        Unique object name; every MJCF name inside the fragment starts with it.
    worldbody_xml : str
        Bodies/geoms to paste into ``<worldbody>`` (in the object frame, which is the world frame unless the
        fragment is wrapped by :func:`place`).
    asset_xml : str
        ``<texture>``, ``<material>`` and ``<mesh>`` elements to paste into ``<asset>``.
    files : dict[str, bytes | str | Path]
        Asset files referenced by ``asset_xml`` (``file="..."``): content bytes or a path to read.
    features : dict
        Ground truth in the object frame (m, unit vectors, 4x4 transforms); documented by each generator.
    """

    name: str
    worldbody_xml: str
    asset_xml: str
    files: dict = field(default_factory=dict)
    features: dict = field(default_factory=dict)


def fmt(values) -> str:
    """Space-separated numbers with full double precision (MJCF attribute text)."""
    return " ".join(f"{float(v):.17g}" for v in np.ravel(values))


def pose_attrs(T) -> str:
    """``pos="..." quat="..."`` attributes of a 4x4 rigid transform (MuJoCo quaternions are scalar first)."""
    T = check_transform(T, "pose")
    return f'pos="{fmt(T[:3, 3])}" quat="{fmt(matrix_to_quaternion(T[:3, :3]))}"'


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


def texture_material_xml(name: str, file_name: str, specular=0.05, shininess=0.05, rgba=None) -> str:
    """A 2D texture from ``file_name`` and a material ``name`` that uses it."""
    color = f' rgba="{fmt(rgba)}"' if rgba is not None else ""
    return (f'<texture name="{name}" type="2d" file="{file_name}"/>\n'
            f'<material name="{name}" texture="{name}" specular="{specular}" shininess="{shininess}"{color}/>\n')


def color_material_xml(name: str, rgba, specular=0.2, shininess=0.2) -> str:
    """An untextured material."""
    return f'<material name="{name}" rgba="{fmt(rgba)}" specular="{specular}" shininess="{shininess}"/>\n'


def box_mesh_xml(name: str, half_sizes, uv_rect=(0.0, 0.0, 1.0, 1.0)) -> str:
    """A closed box mesh centred at the origin whose **+z face** carries the texture rectangle ``uv_rect``.

    ``uv_rect = (u0, v0, u1, v1)``: the face's (-x, +y) corner gets ``(u0, v0)`` (image top-left), the (+x, -y)
    corner ``(u1, v1)``. The side faces repeat the front face's edge texels; the back face is a single texel.
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
    return _mesh_xml(name, verts, uvs, faces)


def disc_mesh_xml(name: str, radius: float, half_thickness: float, segments: int = 48) -> str:
    """A closed cylinder mesh (axis z, centred) whose **+z cap** carries the texture's inscribed circle."""
    if radius <= 0 or half_thickness <= 0 or segments < 8:
        raise ValueError(f"{name}: need radius > 0, half_thickness > 0 and segments >= 8")
    a = 2 * np.pi * np.arange(segments) / segments
    ca, sa = np.cos(a), np.sin(a)
    uv_rim = [(0.5 + 0.5 * c, 0.5 - 0.5 * s) for c, s in zip(ca, sa, strict=True)]
    verts, uvs, faces = [], [], []
    # front cap: centre + rim
    verts.append((0.0, 0.0, half_thickness))
    uvs.append((0.5, 0.5))
    verts += [(radius * c, radius * s, half_thickness) for c, s in zip(ca, sa, strict=True)]
    uvs += uv_rim
    faces += [(0, 1 + i, 1 + (i + 1) % segments) for i in range(segments)]
    # back cap
    k = len(verts)
    verts.append((0.0, 0.0, -half_thickness))
    uvs.append((0.5, 0.5))
    verts += [(radius * c, radius * s, -half_thickness) for c, s in zip(ca, sa, strict=True)]
    uvs += uv_rim
    faces += [(k, k + 1 + (i + 1) % segments, k + 1 + i) for i in range(segments)]
    # side wall: rim vertices front (1..n) and back (k+1..k+n)
    faces += [(1 + i, k + 1 + i, k + 1 + (i + 1) % segments) for i in range(segments)]
    faces += [(1 + i, k + 1 + (i + 1) % segments, 1 + (i + 1) % segments) for i in range(segments)]
    return _mesh_xml(name, verts, uvs, faces)


def frustum_mesh_xml(name: str, r_front: float, r_back: float, length: float, segments: int = 40) -> str:
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
    return _mesh_xml(name, verts, None, faces)


def _mesh_xml(name, verts, uvs, faces) -> str:
    tex = f' texcoord="{fmt(uvs)}"' if uvs is not None else ""
    idx = " ".join(str(int(i)) for f in faces for i in f)
    return f'<mesh name="{name}" vertex="{fmt(verts)}"{tex} face="{idx}"/>\n'


def place(obj: SceneObject, T_world_obj, name: str | None = None) -> SceneObject:
    """Wrap ``obj``'s fragment in a body at the pose ``T_world_obj`` (4x4, m).

    Returns a new :class:`SceneObject` (same assets); ``features["T_world_obj"]`` records the pose. ``name`` names
    the wrapping body (default ``<obj.name>_pose``); the features stay in the object frame.
    """
    T = check_transform(T_world_obj, f"{obj.name}: T_world_obj")
    body = name or f"{obj.name}_pose"
    xml = f'<body name="{body}" {pose_attrs(T)}>\n{obj.worldbody_xml}</body>\n'
    return replace(obj, worldbody_xml=xml, features={**obj.features, "T_world_obj": T.copy()})


def look_at_camera_xml(name: str, eye, target, fovy_deg: float = 45.0, up=(0.0, 0.0, 1.0)) -> str:
    """A fixed MJCF ``<camera>`` at ``eye`` (m, world) looking at ``target``, image "up" towards ``up``.

    MJCF cameras look along their local -z with +y up; ``xyaxes`` gives their x (right) and y (up) axes.
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
    cam_up = np.cross(right, fwd)
    return f'<camera name="{name}" pos="{fmt(eye)}" xyaxes="{fmt(np.r_[right, cam_up])}" fovy="{float(fovy_deg)!r}"/>\n'


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


def compose(objects, extra_worldbody: str = "", offscreen=(1280, 960), center=(0.0, 0.0, 0.5), extent=2.0,
            model_name: str = "scene"):
    """A complete standalone MJCF of ``objects`` with lights and cameras, and its assets.

    Parameters
    ----------
    objects : iterable of SceneObject
    extra_worldbody : str
        More ``<worldbody>`` XML (cameras from :func:`look_at_camera_xml`, markers ...).
    offscreen : (int, int)
        Offscreen framebuffer width, height (px): the largest image a ``mujoco.Renderer`` may render.
    center, extent : (3,), float
        ``<statistic>``: frames MuJoCo's free camera (``mjCAMERA_FREE``, the default of ``Renderer.update_scene``)
        on the scene; an ``overview`` fixed camera looks at ``center`` from the same distance.

    Returns
    -------
    xml : str
    assets : dict[str, bytes]
        For ``mujoco.MjModel.from_xml_string(xml, assets=assets)``.
    """
    objects = list(objects)
    names = [o.name for o in objects]
    if len(set(names)) != len(names):
        raise ValueError(f"scene object names must be unique, got {names}")
    assets = _read_files(objects)
    center = np.asarray(center, float)
    eye = center + extent * np.array([0.35, -1.0, 0.45])
    w, h = (int(v) for v in offscreen)
    key_dir = np.array([0.3, 0.6, -1.0]) / np.linalg.norm([0.3, 0.6, -1.0])
    fill_dir = np.array([-0.5, 0.8, -0.3]) / np.linalg.norm([-0.5, 0.8, -0.3])
    xml = f"""<mujoco model="{model_name}">
<compiler angle="radian"/>
<visual>
  <global offwidth="{w}" offheight="{h}"/>
  <quality shadowsize="2048" offsamples="4"/>
  <headlight ambient="0.25 0.25 0.25" diffuse="0.35 0.35 0.35" specular="0.05 0.05 0.05"/>
  <map znear="0.005" zfar="200"/>
</visual>
<statistic center="{fmt(center)}" extent="{float(extent)!r}"/>
<asset>
{"".join(o.asset_xml for o in objects)}</asset>
<worldbody>
<light name="key" directional="true" pos="0 0 5" dir="{fmt(key_dir)}"
       diffuse="0.55 0.55 0.55" specular="0.05 0.05 0.05" castshadow="true"/>
<light name="fill" directional="true" pos="0 0 5" dir="{fmt(fill_dir)}"
       diffuse="0.25 0.25 0.25" specular="0 0 0" castshadow="false"/>
{look_at_camera_xml("overview", eye, center, 45.0)}{"".join(o.worldbody_xml for o in objects)}{extra_worldbody}
</worldbody>
</mujoco>
"""
    return xml, assets


def save_scene(xml: str, assets: dict, folder, file_name: str = "scene.xml") -> Path:
    """Write ``xml`` and its asset files into ``folder`` (created); returns the XML path (loadable by path)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for fname, content in assets.items():
        (folder / fname).write_bytes(content)
    path = folder / file_name
    path.write_text(xml)
    return path
