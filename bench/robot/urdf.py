"""Read the serial chain between two links of a URDF file (kinematics only: meshes, inertias and transmissions are
not read). Plain XML (``xml.etree``): the pipeline does not depend on Pinocchio, which the tests use as the
independent judge of the forward kinematics.

URDF conventions: a joint's ``<origin xyz rpy>`` places the joint frame in its parent link's frame with
``R = Rz(yaw) Ry(pitch) Rx(roll)``; revolute and continuous joints rotate about ``<axis>`` (default x), prismatic
ones translate along it; fixed joints are folded into the next placement. Floating and planar joints are refused.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from bench.errors import ConfigError
from bench.geometry.transforms import homogeneous, rot_x, rot_y, rot_z
from bench.robot.chain import SerialChain


def _floats(src, where, text, n, default):
    if text is None:
        return np.array(default, dtype=float)
    try:
        v = np.array([float(x) for x in text.split()])
    except ValueError:
        raise ConfigError(src, where, f"expected {n} numbers, got {text!r}") from None
    if v.shape != (n,) or not np.all(np.isfinite(v)):
        raise ConfigError(src, where, f"expected {n} finite numbers, got {text!r}")
    return v


def _origin(src, joint, name):
    o = joint.find("origin")
    xyz = _floats(src, f"joint {name!r} origin xyz", None if o is None else o.get("xyz"), 3, [0, 0, 0])
    rpy = _floats(src, f"joint {name!r} origin rpy", None if o is None else o.get("rpy"), 3, [0, 0, 0])
    return homogeneous(rot_z(rpy[2]) @ rot_y(rpy[1]) @ rot_x(rpy[0]), xyz)


def load_urdf_chain(path, base_link: str, tip_link: str) -> SerialChain:
    """The chain of moving joints from ``base_link`` to ``tip_link`` (see the module docstring).

    Raises
    ------
    ConfigError
        Missing or malformed file, unknown link (the known ones are listed when few), a tip that is not below the
        base, a chain without moving joints, an unsupported joint type, a zero axis.
    """
    path = Path(path)
    src = str(path)
    if not path.is_file():
        raise ConfigError(src, "<file>", "not found")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise ConfigError(src, "<file>", f"not valid XML ({exc})") from None
    if root.tag != "robot":
        raise ConfigError(src, "<robot>", f"not a URDF file (root element <{root.tag}>)")
    links = {lk.get("name") for lk in root.findall("link")}
    for opt, lk in (("--base-link", base_link), ("--tip-link", tip_link)):
        if lk not in links:
            hint = f" (links: {', '.join(sorted(links))})" if len(links) <= 12 else f" ({len(links)} links)"
            raise ConfigError(src, opt, f"no link named {lk!r}{hint}")
    by_child = {}
    for j in root.findall("joint"):
        child, parent = j.find("child"), j.find("parent")
        if child is None or parent is None:
            raise ConfigError(src, f"joint {j.get('name')!r}", "needs <parent link=...> and <child link=...>")
        by_child[child.get("link")] = j
    path_joints, link = [], tip_link
    while link != base_link:
        j = by_child.get(link)
        if j is None:
            raise ConfigError(src, "--tip-link", f"{tip_link!r} is not below {base_link!r} in the kinematic tree")
        path_joints.append(j)
        link = j.find("parent").get("link")
    path_joints.reverse()
    names, types, F, axes, lo, hi = [], [], [], [], [], []
    pending = np.eye(4)
    for j in path_joints:
        name, jtype = j.get("name"), j.get("type")
        T = pending @ _origin(src, j, name)
        if jtype == "fixed":
            pending = T
            continue
        if jtype not in ("revolute", "continuous", "prismatic"):
            raise ConfigError(src, f"joint {name!r}", f"type {jtype!r} is not supported in a serial chain "
                                                      "(revolute, continuous, prismatic, fixed)")
        ax = j.find("axis")
        a = _floats(src, f"joint {name!r} axis", None if ax is None else ax.get("xyz"), 3, [1, 0, 0])
        if np.linalg.norm(a) < 1e-9:
            raise ConfigError(src, f"joint {name!r} axis", "zero vector")
        limit = j.find("limit")
        if jtype == "continuous" or limit is None:
            if jtype == "prismatic":
                raise ConfigError(src, f"joint {name!r} limit", "a prismatic joint needs <limit lower upper>")
            lower, upper = -np.pi, np.pi
        else:
            try:
                lower, upper = float(limit.get("lower", 0.0)), float(limit.get("upper", 0.0))
            except ValueError:
                raise ConfigError(src, f"joint {name!r} limit", "lower/upper must be numbers") from None
            if not lower < upper:
                raise ConfigError(src, f"joint {name!r} limit", f"lower ({lower}) must be < upper ({upper})")
        names.append(name)
        types.append("prismatic" if jtype == "prismatic" else "revolute")
        F.append(T)
        axes.append(a / np.linalg.norm(a))
        lo.append(lower)
        hi.append(upper)
        pending = np.eye(4)
    if not names:
        raise ConfigError(src, "--tip-link", f"no moving joint between {base_link!r} and {tip_link!r}")
    mass, com = _bodies(src, root, path_joints)
    return SerialChain(str(root.get("name", path.stem)), base_link, tip_link, tuple(names), tuple(types),
                       np.array(F), np.array(axes), pending, np.array(lo), np.array(hi), mass, com)


def _bodies(src, root, path_joints):
    """Lumped mass (kg) and centre of mass (m, in the child frame of each moving joint) of what each moving joint of
    the chain carries up to the next one: its child link, links fixed to it along the chain and every side branch
    (at zero joint positions). ``(None, None)`` when no link has an ``<inertial>`` mass."""
    children = {}
    for j in root.findall("joint"):
        children.setdefault(j.find("parent").get("link"), []).append(j)
    inertial = {}
    for lk in root.findall("link"):
        m_el = lk.find("inertial/mass")
        if m_el is not None:
            try:
                m = float(m_el.get("value", 0.0))
            except ValueError:
                raise ConfigError(src, f"link {lk.get('name')!r} inertial mass", "not a number") from None
            o = lk.find("inertial/origin")
            c = _floats(src, f"link {lk.get('name')!r} inertial origin", None if o is None else o.get("xyz"), 3,
                        [0, 0, 0])
            inertial[lk.get("name")] = (m, c)
    if not any(m > 0 for m, _ in inertial.values()):
        return None, None
    moving = [j for j in path_joints if j.get("type") != "fixed"]
    stop = {id(j) for j in moving}
    masses, coms = [], []
    for j in moving:
        total, moment = 0.0, np.zeros(3)
        stack = [(j.find("child").get("link"), np.eye(4))]
        while stack:
            link, T = stack.pop()
            m, c = inertial.get(link, (0.0, np.zeros(3)))
            total += m
            moment += m * (T[:3, :3] @ c + T[:3, 3])
            for cj in children.get(link, []):
                if id(cj) not in stop:
                    stack.append((cj.find("child").get("link"), T @ _origin(src, cj, cj.get("name"))))
        masses.append(total)
        coms.append(moment / total if total > 0 else np.zeros(3))
    return np.array(masses), np.array(coms)
