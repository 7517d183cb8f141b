"""MuJoCo model (``mujoco.MjSpec``) of the TA-40 from ``models/ta40.yaml`` and a vector of generalized errors
(exact SE(3) form).

Body chain (the perturbed geometry lives in the body placements, Eq. 10 regrouped)::

    base                        the robot base O0 (placed in the world by the scene)
      link1   at E0 Rz(off1)    hinge joint1 about z; frame 1 = S1 E1 in it
        link2 at S1 E1 Rz(off2) hinge joint2 about z; ...
          ...
            link6                frame 6 = S6 E6; site ee = p_ee in frame 6

with ``S_k = Tz(d_k) Tx(a_k) Rx(alpha_k)``, so that ``T_base_k = E0 A1 E1 ... Ak Ek`` with ``A_k = Rz(theta_k) S_k``
exactly. Sites: ``frame0`` .. ``frame6`` (the DH frames), ``ee``, ``link5`` (Eq. 188: frame 4 times ``A5``, i.e.
``S5`` in body link5, *before* E5), ``camera_mount`` (the nominal mount on link 5). The camera ``link5_camera`` sits
at the *true* mount (nominal composed with the unknown bias) with the intrinsics of :mod:`bench.sim.camera`.
Visual meshes come from :mod:`bench.sim.meshes` (in-memory STL assets); bodies carry simple inertias and position
actuators so the model steps; visuals do not collide.

Composition (the interface with the scenes): :func:`robot_object` returns the arm as a
:class:`~bench.sim.scenes.base.SceneObject` (a ``build(spec, parent)`` function and in-memory STL ``files``), the
same type every scene generator returns; :func:`scene_spec` places it at ``T_world_base`` with
:func:`~bench.sim.scenes.base.place` among further scene objects with :func:`~bench.sim.scenes.base.compose`;
:func:`robot_spec` is the scene-free model (actuators, ``home`` keyframe; ``spec.to_xml()`` is the committed
``models/ta40/ta40.xml``). :func:`camera_mount_with_bias` makes the true mount from the nominal one.
"""

from __future__ import annotations

import mujoco
import numpy as np

from bench.geometry.transforms import homogeneous, rot_x, rot_y, rot_z
from bench.robot.kinematics import _check_eps
from bench.robot.model import Robot
from bench.sim.camera import add_opencv_camera, mujoco_camera_attributes
from bench.sim.meshes import camera_housing_mesh, link_meshes, stl_bytes
from bench.sim.scenes.base import SceneObject, compose, place, pose

#: The nominal camera mount on link 5 (Eq. 188 frame): the optical axis along the joint-6 axis (the approach
#: direction), 120 mm to the side and 300 mm ahead of the wrist centre (clear of the jaws), rolled 180 deg so that
#: forward views come out about upright. An assumption: the thesis mounts the camera on link 5 without offsets.
NOMINAL_T_LINK5_CAM = homogeneous(rot_z(np.pi), [0.12, 0.0, 0.30])

#: Link masses (kg) and joint gains for the position actuators: rough figures for a 1.95 m hydraulic arm.
_MASS = (40.0, 25.0, 20.0, 8.0, 12.0, 4.0, 3.0)
_KP = (8000.0, 12000.0, 8000.0, 1500.0, 1500.0, 500.0)


def error_transform(e6) -> np.ndarray:
    """Exact generalized-error matrix ``Trans(x, y, z) Rz(r) Ry(s) Rx(p)`` of one frame (Eq. 9, exact form)."""
    x, y, z, s, r, p = np.asarray(e6, dtype=float)
    return homogeneous(rot_z(r) @ rot_y(s) @ rot_x(p), [x, y, z])


def dh_static(robot: Robot, k: int) -> np.ndarray:
    """``S_k = Tz(d_k) Tx(a_k) Rx(alpha_k)`` (the part of ``A_k`` after the joint rotation), k = 1..n."""
    return homogeneous(rot_x(robot.alpha[k - 1]), [robot.a[k - 1], 0.0, robot.d[k - 1]])


def camera_mount_with_bias(T_link5_mount, theta_x0: float = 0.0, theta_y0: float = 0.0, theta_z0: float = 0.0,
                           t_bias=(0.0, 0.0, 0.0)) -> np.ndarray:
    """The true camera mount ``T_link5_cam``: the nominal mount composed with an unknown bias (thesis §5.2.2).

    ``T_link5_cam = T_link5_mount @ [R0 | t_bias]`` with ``R0 = Ry(theta_y0) Rx(theta_x0) Rz(theta_z0)`` (Eq. 197,
    factors as labelled - see :mod:`bench.vision.handeye` for the printed label swap): the bias acts in the nominal
    optical frame, ``theta_z0`` is the roll in the image plane, ``theta_y0`` the pan, ``theta_x0`` the tilt.

    Parameters
    ----------
    T_link5_mount : array_like (4, 4)
        Nominal mount: the OpenCV optical frame in the link-5 frame of Eq. 188 (m).
    theta_x0, theta_y0, theta_z0 : float
        Bias rotations (rad).
    t_bias : array_like (3,)
        Bias translation in the nominal optical frame (m).
    """
    from bench.geometry.transforms import check_transform

    T = check_transform(T_link5_mount, "T_link5_mount")
    angles = np.array([theta_x0, theta_y0, theta_z0], dtype=float)
    t = np.asarray(t_bias, dtype=float)
    if T.shape != (4, 4):
        raise ValueError(f"T_link5_mount: expected one (4, 4) transform, got shape {T.shape}")
    if not np.all(np.isfinite(angles)) or np.abs(angles).max() > np.pi:
        raise ValueError(f"theta_x0, theta_y0, theta_z0: expected finite angles within +-pi rad, got {angles.tolist()}")
    if t.shape != (3,) or not np.all(np.isfinite(t)):
        raise ValueError(f"t_bias: expected a finite 3-vector (m), got {np.asarray(t_bias).tolist()}")
    R0 = rot_y(theta_y0) @ rot_x(theta_x0) @ rot_z(theta_z0)  # Eq. 197 (as labelled)
    return T @ homogeneous(R0, t)


def _site(body, name, T, size=0.01, rgba=(0.9, 0.2, 0.2, 0.6)):
    site = body.add_site(name=name, rgba=rgba, group=3, **pose(T))
    site.size[0] = size


def robot_object(robot: Robot, eps=None, T_link5_mount=None, camera=None, name: str = "ta40") -> SceneObject:
    """The arm as a scene object (base frame = object frame; place it with :func:`bench.sim.scenes.base.place`).

    Parameters
    ----------
    robot : Robot
        Nominal DH model (TA-40 structure).
    eps : array_like (6 (n + 1),), optional
        Generalized errors of the true arm (m, rad), exact form; zero if omitted.
    T_link5_mount : array_like (4, 4), optional
        The nominal camera mount on link 5 (site ``camera_mount``); identity if omitted.
    camera : tuple, optional
        ``(K, width, height, T_link5_cam)``: a camera ``link5_camera`` rendering the skew-free ``K`` at the true
        mount ``T_link5_cam`` (OpenCV optical frame in the link-5 frame of Eq. 188).
    """
    if robot.n != 6:
        raise ValueError(f"robot: the MuJoCo model builds a 6-joint arm, got {robot.n} joints")
    E = _check_eps(robot, eps).reshape(robot.n + 1, 6)
    meshes = link_meshes(robot)
    files = {f"{name}_{k}.stl": stl_bytes(m) for k, m in meshes.items()}
    files[f"{name}_camera.stl"] = stl_bytes(camera_housing_mesh())
    Tm = np.eye(4) if T_link5_mount is None else np.asarray(T_link5_mount, float)
    if camera is not None:
        mujoco_camera_attributes(*camera[:3])  # bad intrinsics are refused now, not when built

    def build(spec, parent):
        spec.add_material(name="ta40_yellow", rgba=[0.95, 0.7, 0.1, 1], specular=0.3, shininess=0.3)
        spec.add_material(name="ta40_steel", rgba=[0.55, 0.57, 0.6, 1], specular=0.6, shininess=0.6)
        for k in [*meshes, "camera"]:
            spec.add_mesh(name=f"{name}_{k}", file=f"{name}_{k}.stl")

        def body(parent, body_name, k, T=None):
            return parent.add_body(name=body_name, mass=_MASS[k], inertia=[_MASS[k] * 0.02] * 3, ipos=[0, 0, 0],
                                   explicitinertial=True, **({} if T is None else pose(T)))

        def geom(b, k, mat="ta40_yellow", **kw):
            b.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname=f"{name}_{k}", material=mat, contype=0,
                       conaffinity=0, group=1, mass=0, **kw)

        b = body(parent, f"{name}_base", 0)
        geom(b, "base", "ta40_steel")
        _site(b, "frame0", error_transform(E[0]))
        T_parent = error_transform(E[0])  # placement of link1 in the base body (before the joint offset)
        for k in range(1, robot.n + 1):
            S_k = dh_static(robot, k)
            b = body(b, f"link{k}", k, T_parent @ homogeneous(rot_z(robot.theta_offset[k - 1]), np.zeros(3)))
            b.add_joint(name=f"joint{k}", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 0, 1], damping=200, armature=1,
                        range=[robot.q_min[k - 1], robot.q_max[k - 1]])  # rad (compiler angle radian)
            geom(b, f"link{k}", "ta40_steel" if k in (5, 6) else "ta40_yellow")
            F_k = S_k @ error_transform(E[k])
            _site(b, f"frame{k}", F_k)
            if k == 5:
                _site(b, "link5", S_k, 0.015, (0.2, 0.9, 0.2, 0.6))  # Eq. 188: before E5
                _site(b, "camera_mount", S_k @ Tm, 0.012, (0.2, 0.2, 0.9, 0.6))
                if camera is not None:
                    K, width, height, T_link5_cam = camera
                    T_body_cam = S_k @ np.asarray(T_link5_cam, float)
                    add_opencv_camera(b, "link5_camera", K, width, height, T_body_cam)
                    geom(b, "camera", "ta40_steel", **pose(T_body_cam))
            if k == robot.n:
                _site(b, "ee", F_k @ homogeneous(np.eye(3), robot.p_ee), 0.015, (0.9, 0.9, 0.2, 0.8))
            T_parent = F_k

    features = {"joint_names": [f"joint{k}" for k in range(1, robot.n + 1)], "eps": E.ravel().copy()}
    return SceneObject(name=name, build=build, files=files, features=features)


def add_actuators(spec, robot: Robot) -> None:
    """Position actuators ``act1`` .. ``act6`` on joint1..joint6 (so the model holds a pose under gravity)."""
    for k in range(1, robot.n + 1):
        act = spec.add_actuator(name=f"act{k}", target=f"joint{k}", trntype=mujoco.mjtTrn.mjTRN_JOINT,
                                ctrlrange=[robot.q_min[k - 1], robot.q_max[k - 1]])
        act.set_to_position(kp=_KP[k - 1], kv=_KP[k - 1] / 5)


def home_configuration(robot: Robot) -> np.ndarray:
    """The ``home`` keyframe (rad): arm raised, forearm forward, wrist level, inside every joint range."""
    q = np.deg2rad([30.0, 40.0, 60.0, 0.0, 50.0, 0.0])
    return np.clip(q, robot.q_min, robot.q_max)


def robot_spec(robot: Robot, eps=None, T_link5_mount=None, camera=None, model_name: str = "ta40",
               mesh_dir: str | None = None) -> mujoco.MjSpec:
    """The scene-free robot model as an ``MjSpec`` (``spec.compile()`` gives the ``MjModel``).

    Base at the world origin; position actuators; a ``home`` keyframe. The STL meshes are in-memory assets
    (``spec.assets``), or, with ``mesh_dir``, files relative to that folder (for the committed
    ``models/ta40/ta40.xml``; ``spec.assets`` then still holds them for compiling in memory).
    """
    obj = robot_object(robot, eps, T_link5_mount, camera)
    spec = mujoco.MjSpec()
    spec.modelname = model_name
    spec.compiler.degree = False
    if mesh_dir:
        spec.meshdir = mesh_dir
    spec.option.timestep = 0.002
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.assets = dict(obj.files)
    obj.build(spec, spec.worldbody)
    add_actuators(spec, robot)
    q = home_configuration(robot)
    spec.add_key(name="home", qpos=q, ctrl=q)
    return spec


def scene_spec(robot: Robot, eps=None, T_world_base=None, objects=(), T_link5_mount=None, camera=None,
               offscreen=(1280, 960), center=(1.0, 0.0, 0.5), extent=4.0, actuators: bool = False) -> mujoco.MjSpec:
    """The arm placed at ``T_world_base`` (body ``ta40``) among scene objects, as an ``MjSpec``.

    Parameters
    ----------
    robot, eps, T_link5_mount, camera
        As for :func:`robot_object` (``camera = (K, width, height, T_link5_cam)``, the TRUE mount).
    T_world_base : array_like (4, 4), optional
        The robot base frame O0 in the world (m); identity if omitted.
    objects : iterable of SceneObject
        Further scene objects, already placed in the world (``bench.sim.scenes.base.place``); names must be
        unique.
    offscreen, center, extent
        Passed to :func:`bench.sim.scenes.base.compose` (framebuffer size; free/overview camera framing).
    actuators : bool
        Add the position actuators ``act1`` .. ``act6`` (for stepping; rendering sets joint angles directly).
    """
    T = np.eye(4) if T_world_base is None else T_world_base
    arm = place(robot_object(robot, eps, T_link5_mount, camera), T, "ta40")
    spec = compose([arm, *objects], offscreen=offscreen, center=center, extent=extent)
    if actuators:
        add_actuators(spec, robot)
    return spec
