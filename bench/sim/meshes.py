"""Visual meshes of the TA-40, generated with trimesh from the DH dimensions (deterministic).

Each mesh is expressed in the frame of the MuJoCo body that carries it (see :mod:`bench.sim.mjcf`): body ``k`` is
frame ``k−1`` turned by joint ``k`` (its z axis is the joint axis), and frame ``k`` sits at ``S_k = Tz(d_k) Tx(a_k)
Rx(α_k)`` in it. The shapes are those of a hydraulic work-class arm of about 1.95 m reach: a base turret, a
shoulder yoke, a box-section upper arm with its lift cylinder, an elbow housing, a round forearm with its cylinder,
a wrist and a parallel-jaw gripper. Visual only: they carry no inertia and no collisions.
"""

from __future__ import annotations

import io

import numpy as np
import trimesh
from trimesh.creation import box, cylinder

from bench.geometry.transforms import homogeneous
from bench.robot.model import Robot


def _cyl(p0, p1, radius, sections=32):
    """A cylinder between two points."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    return cylinder(radius=radius, segment=np.stack([p0, p1]), sections=sections)


def _box(centre, extents, R=None):
    return box(extents=extents, transform=homogeneous(np.eye(3) if R is None else R, centre))


def _dh_S(robot: Robot, k: int) -> np.ndarray:
    """``S_k = Tz(d_k) Tx(a_k) Rx(alpha_k)`` of joint k (1-based)."""
    d, a, al = robot.d[k - 1], robot.a[k - 1], robot.alpha[k - 1]
    c, s = np.cos(al), np.sin(al)
    return np.array([[1, 0, 0, a], [0, c, -s, 0], [0, s, c, d], [0, 0, 0, 1.0]])


def link_meshes(robot: Robot) -> dict:
    """``{body name: trimesh.Trimesh}`` for ``base`` and ``link1`` .. ``link6`` (TA-40 structure assumed)."""
    a1, a2, a3 = robot.a[0], robot.a[1], robot.a[2]
    d4, d6 = robot.d[3], robot.d[5]
    out = {}
    # base turret below the base frame, around joint 1 (z)
    out["base"] = trimesh.util.concatenate([
        _cyl([0, 0, -0.32], [0, 0, -0.08], 0.16),
        _cyl([0, 0, -0.36], [0, 0, -0.32], 0.22),
        _box([0.0, 0.0, -0.34], [0.5, 0.3, 0.04]),
    ])
    # link 1: turntable and shoulder yoke carrying joint 2 (axis along S1's z at (a1, 0, 0))
    z2 = _dh_S(robot, 1)[:3, 2]
    p2 = np.array([a1, 0.0, 0.0])
    out["link1"] = trimesh.util.concatenate([
        _cyl([0, 0, -0.08], [0, 0, 0.02], 0.15),
        _box([a1 / 2, 0, 0.0], [a1 + 0.18, 0.22, 0.12]),
        _cyl(p2 - 0.13 * z2, p2 + 0.13 * z2, 0.09),
    ])
    # link 2: box-section upper arm along x to joint 3, lift cylinder underneath, elbow boss
    out["link2"] = trimesh.util.concatenate([
        _box([a2 / 2, 0, 0], [a2, 0.13, 0.11]),
        _cyl([0, 0, -0.1], [0, 0, 0.1], 0.085),
        _cyl([a2, 0, -0.09], [a2, 0, 0.09], 0.075),
        _cyl([0.12, -0.1, 0.0], [0.55 * a2, -0.1, 0.0], 0.04),  # hydraulic cylinder barrel
        _cyl([0.55 * a2, -0.1, 0.0], [0.8 * a2, -0.1, 0.0], 0.018),  # rod
    ])
    # link 3: elbow housing from joint 3 to the forearm root (x to a3, then the forearm axis z3 = S3's z)
    z4 = _dh_S(robot, 3)[:3, 2]
    p4 = np.array([a3, 0.0, 0.0])
    out["link3"] = trimesh.util.concatenate([
        _box([a3 / 2, 0, 0], [a3 + 0.12, 0.12, 0.12]),
        _cyl(p4, p4 + 0.12 * z4, 0.07),
    ])
    # link 4: forearm along z (joint 4 axis) to the wrist at d4, with a wrist-pitch cylinder alongside
    out["link4"] = trimesh.util.concatenate([
        _cyl([0, 0, 0.12], [0, 0, d4 - 0.07], 0.06),
        _cyl([0.075, 0, 0.2], [0.075, 0, 0.55 * d4], 0.03),
        _cyl([0.075, 0, 0.55 * d4], [0.075, 0, 0.8 * d4], 0.012),
        _cyl([0, -0.07, d4], [0, 0.07, d4], 0.06),  # wrist-pitch boss (joint 5 axis lies along y of this body)
    ])
    # link 5: wrist housing around the joint-5 axis, extending along the joint-6 axis (S5's z)
    z6 = _dh_S(robot, 5)[:3, 2]
    out["link5"] = trimesh.util.concatenate([
        _cyl([0, 0, -0.065], [0, 0, 0.065], 0.055),
        _cyl(0.02 * z6, 0.16 * z6, 0.05),
    ])
    # link 6: wrist roll and parallel-jaw gripper ending near O6 (d6 along z)
    out["link6"] = trimesh.util.concatenate([
        _cyl([0, 0, 0.16], [0, 0, d6 - 0.12], 0.045),
        _box([0, 0, d6 - 0.1], [0.16, 0.06, 0.04]),
        _box([0.06, 0, d6 - 0.04], [0.02, 0.05, 0.1]),
        _box([-0.06, 0, d6 - 0.04], [0.02, 0.05, 0.1]),
    ])
    return out


def camera_housing_mesh() -> trimesh.Trimesh:
    """The subsea camera's pressure housing in its optical frame (z forward): a cylinder with a flat port."""
    return trimesh.util.concatenate([_cyl([0, 0, -0.14], [0, 0, -0.005], 0.035), _cyl([0, 0, -0.005], [0, 0, 0.0],
                                                                                        0.03)])


def stl_bytes(mesh: trimesh.Trimesh) -> bytes:
    """Binary STL of a mesh (what MuJoCo loads)."""
    buf = io.BytesIO()
    mesh.export(buf, file_type="stl")
    return buf.getvalue()
