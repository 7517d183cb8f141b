"""The calibrated arm as URDF and as MJCF: pure text, for the tools a team already uses (ROS, Pinocchio, MuJoCo).

Input is what calibration produces (:mod:`bench.robot.calibration_file`): the nominal DH model (Eq. 8), the 42
generalized errors in the exact form ``E = Trans(x, y, z) Rz(r) Ry(s) Rx(p)`` (Eq. 9-10) and the camera mount
``T_link5_cam``. Nothing is composed numerically: every DH parameter and every error goes into its own fixed
placement, written with full double precision (``repr``), so the files read like the model and reproduce Eq. 10 to
rounding. The chain, for k = 1..n (``S_k = Tz(d_k) Tx(a_k) Rx(alpha_k)``, so ``A_k = Rz(theta_k) S_k``)::

    base                                     O0, the robot's base frame
    frame0    = base  . E0                   Eq. 10's frame 0
    body<k>   = frame<k-1> . Rz(offset_k) . Rz(q_k)     revolute joint<k> about z (configuration = reading, rad)
    link<k>   = body<k> . S_k                = E0 A1 E1 ... E(k-1) A_k: link k before its error; link5 is Eq. 188
    frame<k>  = link<k> . E_k                = E0 A1 E1 ... A_k E_k: Eq. 10's frame k
    ee        = frame<n> . Trans(p_ee)       the measured point (O6 for the TA-40)
    camera_optical = link5 . T_link5_cam     the calibrated camera, OpenCV optical frame (x right, y down, z ahead)

``body<k>`` is the rigid body turned by joint k (its origin on the joint axis); ``link<k>``, ``frame<k>``, ``ee`` and
``camera_optical`` are fixed frames on it. (The Eq. 10 frames are called ``frame<k>`` as in :mod:`bench.judge` and
the simulator, because ``link5`` is Eq. 188's frame, the one the camera mount refers to.)

* URDF: links for every frame above, fixed joints ``<parent>_to_<child>``, revolute joints named as in the robot file
  (``joint1..joint6``) with the file's limits. URDF's ``rpy="r p y"`` is ``Rz(y) Ry(p) Rx(r)``, so an error's
  rotation is written exactly as ``rpy="p s r"`` and a DH twist as ``rpy="alpha 0 0"``; only the camera mount is
  converted from a matrix (:func:`rpy_from_matrix`, accurate to rounding also at pitch = +-90 deg). URDF requires
  ``effort`` and ``velocity`` on a revolute joint's limit; the robot file has neither: they are written as given, or
  0 with a comment saying they are unknown. No inertias (kinematic model).
* MJCF: bodies ``base``, ``body1..body<n>`` with hinge joints, the fixed placements as nested ``<frame>`` elements
  (``eulerseq="zyx"``: ``euler="r s p"`` is ``Rz(r) Ry(s) Rx(p)``), sites named as the frames above. Kinematic
  model: the visual skeleton has no mass and ``boundmass``/``boundinertia`` give the moving bodies the minimum MuJoCo
  accepts (1 g, 1e-6 kg m^2) - set real inertias before simulating dynamics.

Both carry a small visual skeleton (a cylinder on each joint axis, a rod from each joint to its frame) that does not
collide. This module writes text only: it imports neither MuJoCo nor the simulator (the parity tests load the files
with Pinocchio and MuJoCo).
"""

from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np
import yaml

from bench.errors import ConfigError
from bench.fileio import check_output_file, write_output_file
from bench.geometry.quaternion import matrix_to_quaternion
from bench.geometry.transforms import check_transform, rot_x
from bench.robot.calibration_file import load_calibrated_robot
from bench.robot.model import Robot

FORMATS = ("urdf", "mjcf")
#: link whose Eq. 188 frame carries the camera
CAMERA_LINK = 5
_JOINT_RADIUS, _JOINT_HALF_LENGTH, _ROD_RADIUS = 0.04, 0.06, 0.025  # visual skeleton (m)


def exported_frames(robot: Robot, with_camera: bool = True) -> list[str]:
    """Names of the frames every export carries (URDF links, MJCF sites), in chain order."""
    names = ["base", "frame0"]
    for k in range(1, robot.n + 1):
        names += [f"body{k}", f"link{k}", f"frame{k}"]
    names.append("ee")
    if with_camera and robot.n >= CAMERA_LINK:
        names.append("camera_optical")
    return names


def rpy_from_matrix(R) -> np.ndarray:
    """URDF angles ``(roll, pitch, yaw)`` (rad) with ``R = Rz(yaw) Ry(pitch) Rx(roll)``.

    Sequential extraction: yaw from the first column, then pitch from ``Rz(yaw)^T R``, then roll from what is left,
    so that rounding in one angle is absorbed by the next and the angles reproduce ``R`` to rounding everywhere,
    including the gimbal lock at ``pitch = +-pi/2`` (where yaw is set to 0 and the roll takes the whole rotation).

    Parameters
    ----------
    R : array_like (3, 3)
        A rotation matrix.
    """
    R = np.asarray(R, dtype=float)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise ValueError(f"R: expected a finite (3, 3) rotation, got shape {R.shape}")
    yaw = np.arctan2(R[1, 0], R[0, 0]) if np.hypot(R[1, 0], R[0, 0]) > 1e-12 else 0.0
    cy, sy = np.cos(yaw), np.sin(yaw)
    Rp = np.array([[cy, sy, 0.0], [-sy, cy, 0.0], [0.0, 0.0, 1.0]]) @ R  # Ry(pitch) Rx(roll)
    pitch = np.arctan2(-Rp[2, 0], Rp[0, 0])
    cp, sp = np.cos(pitch), np.sin(pitch)
    Rr = np.array([[cp, 0.0, -sp], [0.0, 1.0, 0.0], [sp, 0.0, cp]]) @ Rp  # Rx(roll)
    roll = np.arctan2(Rr[2, 1], Rr[1, 1])
    return np.array([roll, pitch, yaw])


def _num(v) -> str:
    """A number as the shortest text that reads back to the same double."""
    v = float(v)
    return str(int(v)) if v.is_integer() and abs(v) < 1e15 else repr(v)


def _vec(values) -> str:
    return " ".join(_num(v) for v in np.ravel(values))


def _comment(text: str) -> str:
    """An XML comment (``--`` is not allowed inside one)."""
    return "<!-- " + str(text).replace("--", "- -") + " -->"


def _check(robot: Robot, eps, T_link5_cam):
    eps = np.zeros(robot.n_errors) if eps is None else np.asarray(eps, dtype=float)
    if eps.shape != (robot.n_errors,) or not np.all(np.isfinite(eps)):
        raise ValueError(f"eps: expected {robot.n_errors} finite generalized errors (m, rad), got shape {eps.shape}")
    if T_link5_cam is not None:
        if robot.n < CAMERA_LINK:
            raise ValueError(f"T_link5_cam: the robot has {robot.n} joints, no link {CAMERA_LINK} to carry a camera")
        T_link5_cam = check_transform(T_link5_cam, "T_link5_cam", tol=1e-9)
        if T_link5_cam.shape != (4, 4):
            raise ValueError(f"T_link5_cam: expected one (4, 4) transform, got shape {T_link5_cam.shape}")
    return eps.reshape(robot.n + 1, 6), T_link5_cam


def _rod_end(robot: Robot, e, k: int) -> np.ndarray:
    """Origin of frame k in body k (m): the translation of ``S_k E_k`` (visual skeleton only)."""
    return np.array([robot.a[k - 1], 0.0, robot.d[k - 1]]) + rot_x(robot.alpha[k - 1]) @ e[k, :3]


def _header(robot: Robot, source: str, notes: str, model: str) -> list[str]:
    lines = [_comment(f"{robot.name}: calibrated kinematic model ({model}) written by 'bench export'"
                      + (f" from {source}" if source else "")),
             _comment("T_base_k = E0 A1 E1 ... Ak Ek (thesis Eq. 10), A = Rz(theta) Tz(d) Tx(a) Rx(alpha) (Eq. 8), "
                      "E = Trans(x, y, z) Rz(r) Ry(s) Rx(p) (exact form); SI units (m, rad)"),
             _comment("frames: base, frame0, body<k> (turned by joint k), link<k> = body<k> S_k (link5 = Eq. 188), "
                      "frame<k> = link<k> E_k (Eq. 10), ee (measured point), camera_optical (OpenCV: x right, "
                      "y down, z ahead)")]
    if notes:
        lines.append(_comment(f"calibration notes: {' '.join(str(notes).split())}"))
    return lines


# ------------------------------------------------------------------------------------------------------------- URDF


def _urdf_origin(xyz, rpy) -> str:
    return f'<origin xyz="{_vec(xyz)}" rpy="{_vec(rpy)}"/>'


def _urdf_fixed(parent: str, child: str, xyz, rpy, note: str = "") -> list[str]:
    return [f'  <link name="{child}"/>',
            f'  <joint name="{parent}_to_{child}" type="fixed">{_comment(note) if note else ""}',
            f'    <parent link="{parent}"/><child link="{child}"/>{_urdf_origin(xyz, rpy)}',
            "  </joint>"]


def _urdf_cylinder(xyz, rpy, radius, length, material) -> str:
    return (f'    <visual>{_urdf_origin(xyz, rpy)}<geometry><cylinder radius="{_num(radius)}" length="{_num(length)}"/>'
            f'</geometry><material name="{material}"/></visual>')


def _urdf_rod(end) -> str:
    """A cylinder from the body origin to ``end`` (visual), or ``""`` for a zero-length rod."""
    length = float(np.linalg.norm(end))
    if length < 1e-9:
        return ""
    z = end / length
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    R = np.column_stack([x, np.cross(z, x), z])
    return _urdf_cylinder(end / 2, rpy_from_matrix(R), _ROD_RADIUS, length, "ta40_yellow")


def urdf_text(robot: Robot, eps=None, T_link5_cam=None, name: str | None = None, source: str = "", notes: str = "",
              velocity: float | None = None, effort: float | None = None) -> str:
    """The URDF of the calibrated arm (see the module docstring for the frames).

    Parameters
    ----------
    robot : Robot
        Nominal DH model, joint limits and measured point (SI).
    eps : array_like (6 (n + 1),), optional
        Generalized errors, exact form, frame-major ``x, y, z, s, r, p`` (m, rad); zero if omitted.
    T_link5_cam : array_like (4, 4), optional
        Camera optical frame in link 5 (Eq. 188), m; no ``camera_optical`` link if omitted.
    name : str, optional
        ``<robot name>``; the robot file's name if omitted.
    source, notes : str
        Written as comments (the calibrated file's path, its calibration notes).
    velocity, effort : float, optional
        Joint speed (rad/s) and effort (N m) limits for every joint; URDF requires them and the robot file has
        neither, so they are written as 0 (with a comment) when not given.

    Returns
    -------
    str
    """
    e, T_cam = _check(robot, eps, T_link5_cam)
    for key, val in (("velocity", velocity), ("effort", effort)):
        if val is not None and not (np.isfinite(val) and val > 0):
            raise ValueError(f"{key}: expected a positive number, got {val!r}")
    out = ['<?xml version="1.0"?>', *_header(robot, source, notes, "URDF"),
           f"<robot name={quoteattr(name or robot.name)}>",
           '  <material name="ta40_yellow"><color rgba="0.95 0.7 0.1 1"/></material>',
           '  <material name="ta40_steel"><color rgba="0.55 0.57 0.6 1"/></material>',
           '  <link name="base"/>']
    limits_note = "" if velocity is not None and effort is not None else _comment(
        "effort/velocity: required by URDF, not known to the robot file (0 = unknown)")
    out += _urdf_fixed("base", "frame0", e[0, :3], e[0, [5, 3, 4]], "E0")
    for k in range(1, robot.n + 1):
        out.append(f'  <link name="body{k}">')
        out.append(_urdf_cylinder((0, 0, 0), (0, 0, 0), _JOINT_RADIUS, 2 * _JOINT_HALF_LENGTH, "ta40_steel"))
        rod = _urdf_rod(_rod_end(robot, e, k))
        if rod:
            out.append(rod)
        out.append("  </link>")
        out += [f"  <joint name={quoteattr(robot.joint_names[k - 1])} type=\"revolute\">{limits_note}",
                f'    <parent link="frame{k - 1}"/><child link="body{k}"/>'
                f'{_urdf_origin((0, 0, 0), (0, 0, robot.theta_offset[k - 1]))}<axis xyz="0 0 1"/>',
                f'    <limit lower="{_num(robot.q_min[k - 1])}" upper="{_num(robot.q_max[k - 1])}" '
                f'effort="{_num(effort or 0.0)}" velocity="{_num(velocity or 0.0)}"/>',
                "  </joint>"]
        out += _urdf_fixed(f"body{k}", f"link{k}", (robot.a[k - 1], 0.0, robot.d[k - 1]),
                           (robot.alpha[k - 1], 0.0, 0.0), f"S{k} = Tz(d{k}) Tx(a{k}) Rx(alpha{k})")
        out += _urdf_fixed(f"link{k}", f"frame{k}", e[k, :3], e[k, [5, 3, 4]], f"E{k}")
        if k == CAMERA_LINK and T_cam is not None:
            out += _urdf_fixed(f"link{k}", "camera_optical", T_cam[:3, 3], rpy_from_matrix(T_cam[:3, :3]),
                               "T_link5_cam (OpenCV optical frame)")
    out += _urdf_fixed(f"frame{robot.n}", "ee", robot.p_ee, (0, 0, 0), "measured point")
    out.append("</robot>")
    return "\n".join(out) + "\n"


# ------------------------------------------------------------------------------------------------------------- MJCF


def _mj_frame(indent: str, xyz, euler=None, axisangle=None, note: str = "") -> str:
    rot = f' euler="{_vec(euler)}"' if euler is not None else f' axisangle="{_vec(axisangle)}"'
    return f'{indent}<frame pos="{_vec(xyz)}"{rot}>{_comment(note) if note else ""}'


def mjcf_text(robot: Robot, eps=None, T_link5_cam=None, name: str | None = None, source: str = "",
              notes: str = "") -> str:
    """The MJCF of the calibrated arm (see the module docstring); arguments as for :func:`urdf_text`."""
    e, T_cam = _check(robot, eps, T_link5_cam)
    out = ['<?xml version="1.0"?>', *_header(robot, source, notes, "MJCF"),
           f"<mujoco model={quoteattr(name or robot.name)}>",
           '  <compiler angle="radian" eulerseq="zyx" boundmass="0.001" boundinertia="1e-06"/>',
           "  " + _comment("kinematic model: no inertias in the robot file; boundmass/boundinertia make it compile"),
           "  <default>",
           '    <geom contype="0" conaffinity="0" group="1" mass="0" rgba="0.95 0.7 0.1 1"/>',
           '    <site size="0.01" group="3" rgba="0.9 0.2 0.2 0.6"/>',
           "  </default>",
           "  <worldbody>",
           '    <body name="base">',
           '      <site name="base"/>']
    closing = ["    </body>"]
    ind = "      "
    out.append(_mj_frame(ind, e[0, :3], e[0, [4, 3, 5]], note="E0"))
    closing.append(f"{ind}</frame>")
    ind += "  "
    out.append(f'{ind}<site name="frame0"/>')
    for k in range(1, robot.n + 1):
        lo, hi = robot.q_min[k - 1], robot.q_max[k - 1]
        out.append(f'{ind}<body name="body{k}" axisangle="0 0 1 {_num(robot.theta_offset[k - 1])}">')
        closing.append(f"{ind}</body>")
        ind += "  "
        out.append(f"{ind}<joint name={quoteattr(robot.joint_names[k - 1])} type=\"hinge\" axis=\"0 0 1\" "
                   f'range="{_num(lo)} {_num(hi)}"/>')
        out.append(f'{ind}<geom type="cylinder" size="{_num(_JOINT_RADIUS)} {_num(_JOINT_HALF_LENGTH)}" '
                   'rgba="0.55 0.57 0.6 1"/>')
        end = _rod_end(robot, e, k)
        if np.linalg.norm(end) >= 1e-9:
            out.append(f'{ind}<geom type="capsule" fromto="0 0 0 {_vec(end)}" size="{_num(_ROD_RADIUS)}"/>')
        out.append(_mj_frame(ind, (robot.a[k - 1], 0.0, robot.d[k - 1]), axisangle=(1, 0, 0, robot.alpha[k - 1]),
                             note=f"S{k} = Tz(d{k}) Tx(a{k}) Rx(alpha{k})"))
        out.append(f'{ind}  <site name="link{k}"/>')
        if k == CAMERA_LINK and T_cam is not None:
            q = matrix_to_quaternion(T_cam[:3, :3])
            out.append(f'{ind}  <site name="camera_optical" pos="{_vec(T_cam[:3, 3])}" quat="{_vec(q)}" '
                       'rgba="0.2 0.2 0.9 0.8"/>' + _comment("T_link5_cam (OpenCV optical frame)"))
        out.append(_mj_frame(ind + "  ", e[k, :3], e[k, [4, 3, 5]], note=f"E{k}"))
        closing += [f"{ind}</frame>", f"{ind}  </frame>"]
        ind += "    "
        out.append(f'{ind}<site name="frame{k}"/>')
    out.append(f'{ind}<site name="ee" pos="{_vec(robot.p_ee)}" rgba="0.9 0.9 0.2 0.8"/>')
    out += reversed(closing)
    out += ["  </worldbody>", "</mujoco>"]
    return "\n".join(out) + "\n"


def export_robot(robot_file, fmt: str, out, name: str | None = None, velocity: float | None = None,
                 effort: float | None = None, force: bool = False) -> Path:
    """Read a (calibrated) robot file and write its URDF or MJCF to ``out`` atomically; returns the path.

    Parameters
    ----------
    robot_file : path-like
        ``robot.yaml`` with an optional ``calibration`` section (:mod:`bench.robot.calibration_file`).
    fmt : {"urdf", "mjcf"}
    out : path-like
    name : str, optional
        Model name in the file (default: the robot file's name).
    velocity, effort : float, optional
        URDF joint limits (rad/s, N m); see :func:`urdf_text`.
    force : bool
        Replace an earlier output of ``bench export`` edited since (never another file: see
        :func:`bench.fileio.check_output_file`).
    """
    check_output_file(out, "export", force=force)
    if fmt not in FORMATS:
        raise ConfigError("--format", fmt, f"expected one of {', '.join(FORMATS)}")
    for key, val in (("velocity", velocity), ("effort", effort)):
        if val is not None and not (np.isfinite(val) and val > 0):
            raise ConfigError("export", key, f"expected a positive limit, got {val!r}")
    robot, eps, T_link5_cam = load_calibrated_robot(robot_file)
    cal = (yaml.safe_load(Path(robot_file).read_text()) or {}).get("calibration") or {}
    notes = str(cal.get("notes", ""))
    text = (urdf_text(robot, eps, T_link5_cam, name, str(robot_file), notes, velocity, effort) if fmt == "urdf" else
            mjcf_text(robot, eps, T_link5_cam, name, str(robot_file), notes))
    return write_output_file(out, text, "export", force=force)
