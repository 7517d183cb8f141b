"""The x-y table of thesis section 5.2.2 (and its underwater set-up of section 5.4) with its positioning errors.

Section 5.2: "an x-y table with a movement range of 200mm in x and y directions and a resolution of 0.1mm. A rotary
stage is mounted on top of the x-y table. The rotation axis is perpendicular to the x-y table and the angular
resolution is 0.1 deg." Section 5.2.2: the table moves in x and z, the rotary stage turns about y; the reference
frame's origin is the camera centre with the table at its centre, its axes the table's movement axes; the reference
object stood 700 mm in front (Table 4 poses). Section 5.4: the underwater camera sat 100 mm from the rotation axis
(the left aperture of a support) and the calibration rig 500 mm from the table centre (Table 10 poses).

Table frame ``table`` (OpenCV-like, as the thesis's camera): x along the x travel (to the right), z along the z
travel (towards the reference object), y = z x x down along the rotary axis. Origin: on the rotary axis at the
camera-centre height with both slides at their centres. ``T_world_table`` places it in MuJoCo's z-up world.

Kinematics of the camera mount (true and nominal share it; the nominal one has every error zero)::

    T_table_mount = Trans(x e_x + z e_z') Trans(0, h, 0) Rx(a) Rz(b) Trans(0, -h, 0) Ry(theta) Trans(o)

with ``e_z' = (sin g, 0, cos g)`` the z travel tilted by the orthogonality error ``g``, ``h`` the height of the camera
centre above the rotary platform (the wobble pivot), ``a = w cos(theta + phi)``, ``b = w sin(theta + phi)`` the axis
wobble of amplitude ``w``, and ``o`` the camera offset from the axis ((-100, 0, 0) mm underwater: with this sign
Table 10's displacements are reproduced, see :func:`table_commands_from_camera_poses`). The mount frame
``table_camera_mount`` is the nominal optical frame (x right, y down, z forward) at the camera centre.

Error model (:class:`TableErrors`), applied to the commanded step position ``c`` of each axis::

    true = c (1 + scale) + backlash * (1 - dir) / 2

``dir`` is the sign of the axis's last non-zero move (+1 after homing, which approaches from below): after a
reversal the carriage stops ``backlash`` short. The thesis states only the resolutions; the error magnitudes are
**assumptions** typical of lead-screw laboratory stages and manual/motorised rotary stages (catalogue figures of
the order of: scale/calibration error 1e-4 .. 5e-4 of travel, backlash 10 .. 50 um and 0.01 .. 0.05 deg,
orthogonality 50 .. 200 urad, rotary wobble 20 .. 100 urad); the defaults sit inside these ranges.

What the pipeline sees (``TableRun.read``): the commanded positions quantised to the resolution (0.1 mm, 0.1 deg),
as the table's controller displays them. The truth (``TableRun.true``, ``T_table_mount``) stays with the bench.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from bench.errors import ConfigError
from bench.fileio import csv_number, read_csv_table
from bench.geometry.transforms import check_transform, homogeneous, rot_x, rot_y, rot_z
from bench.sim.scenes.base import SceneObject, add_color_material, add_geom, place, pose

TRAVEL_M = 0.200  # section 5.2: 200 mm movement range (centred: +-100 mm)
RESOLUTION_M = 1e-4  # section 5.2: 0.1 mm
RESOLUTION_RAD = np.deg2rad(0.1)  # section 5.2: 0.1 deg
LAB_REFERENCE_DISTANCE_M = 0.700  # section 5.2.2
UNDERWATER_REFERENCE_DISTANCE_M = 0.500  # section 5.4
UNDERWATER_CAMERA_OFFSET_M = (-0.100, 0.0, 0.0)  # section 5.4: 100 mm from the rotation axis (left aperture)
POST_HEIGHT_M = 0.12  # assumption: camera centre 120 mm above the rotary platform (wobble pivot)

DATA_DIR = Path(__file__).resolve().parents[3] / "scenarios" / "data"
TABLE4_CSV = DATA_DIR / "table4_xy_table_poses.csv"
TABLE10_CSV = DATA_DIR / "table10_xy_table_underwater_poses.csv"

# R_world_table: table x = world x, table y = world -z (down), table z = world y
R_WORLD_TABLE = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
DEFAULT_T_WORLD_TABLE = homogeneous(R_WORLD_TABLE, [0.0, 0.0, 0.4])


@dataclass(frozen=True)
class TableErrors:
    """Positioning errors of the x-y table and its rotary stage (assumed magnitudes, see the module docstring).

    Attributes: ``scale_x``, ``scale_z``, ``scale_rot`` relative scale errors; ``backlash_x_m``, ``backlash_z_m`` (m)
    and ``backlash_rot_rad`` lost motion on reversal; ``orthogonality_rad`` tilt of the z travel towards +x;
    ``wobble_rad`` amplitude and ``wobble_phase_rad`` phase of the rotary axis wobble.
    """

    scale_x: float = 3e-4
    scale_z: float = -2e-4
    scale_rot: float = 2e-4
    backlash_x_m: float = 20e-6
    backlash_z_m: float = 20e-6
    backlash_rot_rad: float = float(np.deg2rad(0.02))
    orthogonality_rad: float = 1e-4
    wobble_rad: float = 5e-5
    wobble_phase_rad: float = 0.0


NO_ERRORS = TableErrors(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def random_table_errors(rng: np.random.Generator) -> TableErrors:
    """Errors drawn uniformly within the typical catalogue ranges of the module docstring (random signs)."""
    sign = lambda: float(rng.choice([-1.0, 1.0]))  # noqa: E731
    return TableErrors(scale_x=sign() * rng.uniform(1e-4, 5e-4), scale_z=sign() * rng.uniform(1e-4, 5e-4),
                       scale_rot=sign() * rng.uniform(1e-4, 5e-4), backlash_x_m=rng.uniform(10e-6, 50e-6),
                       backlash_z_m=rng.uniform(10e-6, 50e-6),
                       backlash_rot_rad=float(np.deg2rad(rng.uniform(0.01, 0.05))),
                       orthogonality_rad=sign() * rng.uniform(50e-6, 200e-6), wobble_rad=rng.uniform(20e-6, 100e-6),
                       wobble_phase_rad=rng.uniform(0, 2 * np.pi))


@dataclass(frozen=True)
class TableRun:
    """Result of :meth:`TableModel.run` for N commanded poses (SI: m, rad).

    ``commanded`` (N, 3) as given ``[x, z, rot]``; ``read`` (N, 3) what the table reports (quantised);
    ``true`` (N, 3) the true joint values (x, z along the true travel axes, rot); ``wobble`` (N, 2) the axis
    tilts ``(a, b)`` (rad); ``T_table_mount`` (N, 4, 4) true; ``T_table_mount_nominal`` (N, 4, 4) from ``read``
    with no errors (what the pipeline may compute); ``qpos`` {joint name: (N,)} for the model of :func:`xy_table`.
    """

    commanded: np.ndarray
    read: np.ndarray
    true: np.ndarray
    wobble: np.ndarray
    T_table_mount: np.ndarray
    T_table_mount_nominal: np.ndarray
    qpos: dict = field(default_factory=dict)


class TableModel:
    """Encoder-like model of the x-y table: ``commanded -> true`` (truth) and ``commanded -> read``.

    Parameters
    ----------
    errors : TableErrors or None
        None: no errors.
    camera_offset_m : (3,)
        Camera centre in the rotary-stage frame (m): 0 in the lab (camera on the axis), (-0.1, 0, 0) underwater.
    travel_m, resolution_m, resolution_rad : float
        Travel (centred) of each slide, slide and rotary resolutions.
    rot_limit_rad : float
        Commands must satisfy ``|rot| <= rot_limit_rad``.
    post_height_m : float
        Camera centre above the rotary platform (the wobble pivot), m.
    name : str
        Prefix of the MuJoCo joint names (``<name>_x``, ``<name>_z``, ``<name>_rot`` ...).
    """

    def __init__(self, errors: TableErrors | None = None, camera_offset_m=(0.0, 0.0, 0.0), travel_m=TRAVEL_M,
                 resolution_m=RESOLUTION_M, resolution_rad=RESOLUTION_RAD, rot_limit_rad=np.pi,
                 post_height_m=POST_HEIGHT_M, name: str = "table"):
        self.errors = errors if errors is not None else NO_ERRORS
        o = np.asarray(camera_offset_m, float)
        if o.shape != (3,) or not np.all(np.isfinite(o)):
            raise ValueError(f"camera_offset_m: expected 3 finite values (m), got {camera_offset_m!r}")
        for k, v in (("travel_m", travel_m), ("resolution_m", resolution_m), ("resolution_rad", resolution_rad),
                     ("rot_limit_rad", rot_limit_rad), ("post_height_m", post_height_m)):
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"{k}: must be a positive finite number, got {v!r}")
        self.camera_offset_m, self.travel_m = o, float(travel_m)
        self.resolution_m, self.resolution_rad = float(resolution_m), float(resolution_rad)
        self.rot_limit_rad, self.post_height_m, self.name = float(rot_limit_rad), float(post_height_m), name

    @property
    def joint_names(self):
        """MuJoCo joint names in qpos order of :func:`xy_table`."""
        return [f"{self.name}_{k}" for k in ("x", "z", "wobble_x", "wobble_z", "rot")]

    def check_commands(self, commands, source="x-y table") -> np.ndarray:
        """Validate commanded poses ``(N, 3)`` or ``(3,)`` ``[x_m, z_m, rot_rad]``; out of travel -> ConfigError."""
        c = np.atleast_2d(np.asarray(commands, dtype=float))
        if c.ndim != 2 or c.shape[1] != 3:
            raise ValueError(f"{source}: commands: expected shape (N, 3) [x_m, z_m, rot_rad], got {np.shape(commands)}")
        half = self.travel_m / 2
        for i, (x, z, r) in enumerate(c):
            if not np.all(np.isfinite((x, z, r))):
                raise ConfigError(source, f"pose {i + 1}", "contains NaN or inf")
            if abs(x) > half + 1e-12 or abs(z) > half + 1e-12:
                raise ConfigError(source, f"pose {i + 1}", f"x = {x * 1e3:.1f} mm, z = {z * 1e3:.1f} mm outside the "
                                                          f"travel of +-{half * 1e3:.0f} mm")
            if abs(r) > self.rot_limit_rad + 1e-12:
                raise ConfigError(source, f"pose {i + 1}", f"rot = {np.rad2deg(r):.1f} deg outside "
                                                          f"+-{np.rad2deg(self.rot_limit_rad):.0f} deg")
        return c

    def read(self, commands) -> np.ndarray:
        """What the table reports: commands quantised to the resolutions, (N, 3) ``[x_m, z_m, rot_rad]``."""
        c = self.check_commands(commands)
        res = np.array([self.resolution_m, self.resolution_m, self.resolution_rad])
        return np.round(c / res) * res

    def _true_axes(self, steps):
        """Scale and backlash applied to the step positions (N, 3), sequence-dependent (module docstring)."""
        e = self.errors
        scale = np.array([e.scale_x, e.scale_z, e.scale_rot])
        backlash = np.array([e.backlash_x_m, e.backlash_z_m, e.backlash_rot_rad])
        out = np.empty_like(steps)
        direction = np.ones(3)  # homed approaching from below
        prev = np.zeros(3)  # homed at the centre
        for i, s in enumerate(steps):
            move = s - prev
            direction = np.where(np.abs(move) > 1e-15, np.sign(move), direction)
            out[i] = s * (1.0 + scale) + backlash * (1.0 - direction) / 2.0
            prev = s
        return out

    def mount_pose(self, joints, wobble=None, orthogonality_rad=0.0):
        """``T_table_mount`` (N, 4, 4) for joint values ``(N, 3)`` ``[x, z, rot]`` and axis tilts ``(N, 2)``."""
        j = np.atleast_2d(np.asarray(joints, float))
        wob = np.zeros((len(j), 2)) if wobble is None else np.atleast_2d(np.asarray(wobble, float))
        g = orthogonality_rad
        p = j[:, :1] * np.array([1.0, 0.0, 0.0]) + j[:, 1:2] * np.array([np.sin(g), 0.0, np.cos(g)])
        h = np.array([0.0, self.post_height_m, 0.0])
        R_w = rot_x(wob[:, 0]) @ rot_z(wob[:, 1])
        R = R_w @ rot_y(j[:, 2])
        t = p + h - np.einsum("nij,j->ni", R_w, h) + np.einsum("nij,j->ni", R, self.camera_offset_m)
        return homogeneous(R, t)

    def run(self, commands) -> TableRun:
        """Commanded poses ``(N, 3)`` in the order they are visited -> :class:`TableRun` (truth and readings)."""
        c = self.check_commands(commands)
        read = self.read(c)
        true = self._true_axes(read)
        e = self.errors
        ang = true[:, 2] + e.wobble_phase_rad
        wobble = np.stack([e.wobble_rad * np.cos(ang), e.wobble_rad * np.sin(ang)], -1)
        if e.wobble_rad == 0.0:
            wobble = np.zeros_like(wobble)
        T_true = self.mount_pose(true, wobble, e.orthogonality_rad)
        T_nom = self.mount_pose(read)
        names = self.joint_names
        qpos = {names[0]: true[:, 0], names[1]: true[:, 1], names[2]: wobble[:, 0], names[3]: wobble[:, 1],
                names[4]: true[:, 2]}
        return TableRun(commanded=c, read=read, true=true, wobble=wobble, T_table_mount=T_true,
                        T_table_mount_nominal=T_nom, qpos=qpos)


def lab_table_model(errors: TableErrors | None = None) -> TableModel:
    """Section 5.2.2: web camera on the rotation axis."""
    return TableModel(errors, camera_offset_m=(0.0, 0.0, 0.0))


def underwater_table_model(errors: TableErrors | None = None) -> TableModel:
    """Section 5.4: underwater camera 100 mm from the rotation axis."""
    return TableModel(errors, camera_offset_m=UNDERWATER_CAMERA_OFFSET_M)


# --------------------------------------------------------------------------------------------- pose tables (CSV)
POSE_COLUMNS = ("position", "theta_x_deg", "theta_y_deg", "theta_z_deg", "dx_mm", "dy_mm", "dz_mm")


def load_pose_table(path) -> dict:
    """Read a transcribed thesis pose table (``#`` comment lines, header ``POSE_COLUMNS``) -> {column: (N,) array}."""
    _, rows = read_csv_table(path, POSE_COLUMNS)
    arr = np.array([[csv_number(path, f"row {k}, {c}", v) for c, v in zip(POSE_COLUMNS, row, strict=True)]
                    for k, row in enumerate(rows, start=1)], float).reshape(-1, len(POSE_COLUMNS))
    out = {c: arr[:, i] for i, c in enumerate(POSE_COLUMNS)}
    out["position"] = out["position"].astype(int)
    return out


def table_commands_from_camera_poses(table: dict, camera_offset_m=(0.0, 0.0, 0.0), source="pose table"):
    """Table commands ``(N, 3)`` ``[x_m, z_m, rot_rad]`` that put the camera at the tabulated displacements.

    The thesis tables give the camera centre's displacement ``d`` and ``theta_y``; with the camera at ``o`` in the
    rotary frame, ``d = p + Ry(theta) o - o`` so ``p = d - (Ry(theta) o - o)`` (x, z of ``p`` are the commands). The
    table cannot produce ``theta_x``, ``theta_z`` or ``dy``: non-zero values are a ConfigError naming the position.
    """
    o = np.asarray(camera_offset_m, float)
    for col in ("theta_x_deg", "theta_z_deg", "dy_mm"):
        bad = np.flatnonzero(np.asarray(table[col]) != 0)
        if bad.size:
            raise ConfigError(source, f"position {int(table['position'][bad[0]])}",
                              f"{col} = {table[col][bad[0]]} cannot be produced by the x-y table")
    theta = np.deg2rad(np.asarray(table["theta_y_deg"], float))
    d = np.stack([table["dx_mm"], table["dy_mm"], table["dz_mm"]], -1) * 1e-3
    lever = np.einsum("nij,j->ni", rot_y(theta), o) - o
    p = d - lever
    return np.stack([p[:, 0], p[:, 2], theta], -1)


def table4_commands() -> np.ndarray:
    """Table 4 as table commands (camera on the axis): ``(21, 3)`` ``[x_m, z_m, rot_rad]``."""
    return table_commands_from_camera_poses(load_pose_table(TABLE4_CSV), source=str(TABLE4_CSV))


def table10_commands() -> np.ndarray:
    """Table 10 as table commands (camera 100 mm off the axis): ``(17, 3)``, before quantisation."""
    return table_commands_from_camera_poses(load_pose_table(TABLE10_CSV), UNDERWATER_CAMERA_OFFSET_M,
                                            source=str(TABLE10_CSV))


# ------------------------------------------------------------------------------------------------------ MjSpec
def reference_pose(reference: SceneObject, distance_m: float, lateral_m: float = 0.0) -> np.ndarray:
    """Default ``T_table_reference``: the reference object faces the camera ``distance_m`` ahead (table z).

    A rig (features with ``corners_board_a``): its common edge vertical at ``(lateral, ., distance)``, the bisector
    of the two boards towards the camera, the patterns' mid-height at the camera height; board A on the left.
    Anything else (a panel): its front face (object z = 0, normal +z) at ``z_table = distance``, upright, centred
    at ``x_table = lateral``.
    """
    if not np.isfinite(distance_m) or distance_m <= 0:
        raise ValueError(f"reference distance: must be positive (m), got {distance_m!r}")
    f = reference.features
    if "corners_board_a" in f:
        r2 = 1 / np.sqrt(2)
        R = np.array([[-r2, r2, 0.0], [0.0, 0.0, -1.0], [-r2, -r2, 0.0]])  # columns x_r, y_r, z_r in table axes
        mid = float(np.mean(f["corners"][:, 2]))
        return homogeneous(R, [lateral_m, mid, distance_m])
    return homogeneous(np.diag([1.0, -1.0, -1.0]), [lateral_m, 0.0, distance_m])


def xy_table(model: TableModel, camera=None, reference: SceneObject | None = None,
             reference_distance_m: float | None = None, T_table_reference=None,
             T_world_table=DEFAULT_T_WORLD_TABLE) -> SceneObject:
    """The x-y table carrying the camera mount, with an optional reference object in front.

    Parameters
    ----------
    model : TableModel
        Gives the joint names, the camera offset and the *true* geometry (the z slide axis is tilted by the
        orthogonality error; wobble hinges are driven by ``TableRun.qpos``).
    camera : callable or None
        ``camera(body)`` adds a camera into the body ``<name>_camera_mount`` (the nominal OpenCV optical frame:
        x right, y down, z forward), e.g. with :func:`bench.sim.camera.add_opencv_camera`.
    reference : SceneObject or None
        E.g. :func:`~bench.sim.scenes.panel.manifold_panel` (lab) or :func:`~bench.sim.scenes.rig.calibration_rig`.
    reference_distance_m : float or None
        Default 0.7 m for a camera on the axis, 0.5 m for an off-axis (underwater) camera.
    T_table_reference : (4, 4) or None
        Overrides :func:`reference_pose`. By default the reference is centred in front of the camera at the table's
        centre position (lateral offset = the camera's x offset). For the underwater set-up this is inferred from
        Table 10: its angles aim every view at x = -95 .. -127 mm (e.g. image 1: camera at x = -180 mm turned 6 deg
        sees x = -180 + 500 tan 6 deg = -127 mm; image 17: -20 - 500 tan 12 deg = -126 mm), i.e. at a rig in front
        of the off-axis camera, not on the rotation axis.
    T_world_table : (4, 4)
        Table frame in the world.

    Returns
    -------
    SceneObject
        ``features``: ``T_world_table``, ``T_table_reference`` (or None), ``reference`` (its features),
        ``joint_names``, ``mount_body``, ``camera_offset_m``.
    """
    n = model.name
    T_wt = check_transform(T_world_table, "T_world_table")
    e = model.errors
    h = model.post_height_m
    half = model.travel_m / 2
    z_axis = [np.sin(e.orthogonality_rad), 0.0, np.cos(e.orthogonality_rad)]
    o = model.camera_offset_m
    grey, dark, delrin = f"{n}_grey", f"{n}_dark", f"{n}_delrin"
    inertial = {"mass": 0.05, "inertia": [1e-5] * 3, "ipos": [0, 0, 0], "explicitinertial": True}
    T_tr = None
    if reference is not None:
        if reference_distance_m is None:
            reference_distance_m = LAB_REFERENCE_DISTANCE_M if np.linalg.norm(o) == 0 else \
                UNDERWATER_REFERENCE_DISTANCE_M
        T_tr = reference_pose(reference, reference_distance_m, float(o[0])) if T_table_reference is None else \
            check_transform(T_table_reference, "T_table_reference")
        placed = place(reference, T_tr, f"{reference.name}_pose")

    def build(spec, parent):
        add_color_material(spec, grey, (0.55, 0.57, 0.6, 1), specular=0.4)
        add_color_material(spec, dark, (0.12, 0.12, 0.13, 1), specular=0.2)
        add_color_material(spec, delrin, (0.9, 0.9, 0.88, 1), specular=0.1)
        table = parent.add_body(name=n, **pose(T_wt))  # geometry: y is down in the table frame, platform top at h
        add_geom(table, f"{n}_base", "box", grey, [half + 0.08, 0.015, half + 0.08], pos=[0, h + 0.075, 0])
        body = table.add_body(name=f"{n}_x_carriage")
        body.add_joint(name=f"{n}_x", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[1, 0, 0],
                       range=[-half - 0.01, half + 0.01])
        add_geom(body, f"{n}_x_plate", "box", dark, [0.1, 0.012, half + 0.05], pos=[0, h + 0.048, 0])
        body = body.add_body(name=f"{n}_z_carriage")
        body.add_joint(name=f"{n}_z", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=z_axis, range=[-half - 0.01, half + 0.01])
        add_geom(body, f"{n}_z_plate", "box", grey, [0.1, 0.012, 0.1], pos=[0, h + 0.024, 0])
        body = body.add_body(name=f"{n}_wobble_x", pos=[0, h, 0], **inertial)
        body.add_joint(name=f"{n}_wobble_x", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[1, 0, 0])
        body = body.add_body(name=f"{n}_wobble_z", **inertial)
        body.add_joint(name=f"{n}_wobble_z", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 0, 1])
        body = body.add_body(name=f"{n}_rotary", pos=[0, -h, 0])
        body.add_joint(name=f"{n}_rot", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 1, 0])
        add_geom(body, f"{n}_platform", "cylinder", dark, [0.09], fromto=[0, h + 0.012, 0, 0, h, 0])
        if np.linalg.norm(o) > 0:  # the delrin support bar carrying the off-axis camera (section 5.4, Figure 54)
            add_geom(body, f"{n}_support", "box", delrin, [max(0.12, abs(o[0]) + 0.03), 0.01, 0.03],
                     pos=[0, o[1] + 0.05, o[2]])
            add_geom(body, f"{n}_post", "cylinder", grey, [0.015], fromto=[0, h, 0, 0, o[1] + 0.06, 0])
        else:
            add_geom(body, f"{n}_post", "cylinder", grey, [0.012], fromto=[0, h, 0, 0, 0.05, 0])
        mount = body.add_body(name=f"{n}_camera_mount", pos=o)
        add_geom(mount, f"{n}_camera_housing", "box", dark, [0.03, 0.025, 0.04], pos=[0, 0, -0.05])
        if camera is not None:
            camera(mount)
        if reference is not None:
            placed.build(spec, table)

    features = {"T_world_table": T_wt, "T_table_reference": T_tr,
                "reference": None if reference is None else reference.features,
                "joint_names": model.joint_names, "mount_body": f"{n}_camera_mount",
                "camera_offset_m": model.camera_offset_m.copy()}
    return SceneObject(name=n, build=build, files={} if reference is None else dict(reference.files),
                       features=features)
