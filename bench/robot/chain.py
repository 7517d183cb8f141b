"""A serial chain of revolute and prismatic joints in URDF form, with the generalized error model (Eq. 9-10).

Where the DH arm of :mod:`bench.robot.model` writes link ``i`` as ``A_i = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``,
a URDF writes each joint as a fixed placement ``F_k`` (the joint's ``<origin>``, with every fixed joint since the
previous moving one folded in) followed by the motion ``M_k(q_k)`` about or along its axis. The generalized error
model of the thesis (Eq. 10, ``T = E0 A1 E1 ... An En``) puts one error matrix on every frame in which a joint axis
is fixed; here that frame is joint k's, right before its motion::

    T_base_tip(q) = F_1 E_0 M_1(q_1) F_2 E_1 M_2(q_2) ... F_n E_(n-1) M_n(q_n) F_tip E_n

so ``E_(k-1)`` plays the role of the thesis's ``E_(k-1)`` (which sits in frame O_(k-1), whose z axis is joint k's) and
``E_n`` the tool frame's. ``E`` is the exact form ``Trans(x, y, z) Rz(r) Ry(s) Rx(p)`` of Eq. 9 (6 per frame, Table 2
order), so ``6 (n + 1)`` errors in all. Units: SI (m, rad); a prismatic joint's reading is in m.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.geometry.quaternion import axis_angle_to_matrix, matrix_to_quaternion, quaternion_to_matrix
from bench.geometry.transforms import check_vectors, homogeneous, vee
from bench.robot.kinematics import error_matrix, error_matrix_derivatives

JOINT_TYPES = ("revolute", "prismatic")


@dataclass(frozen=True)
class SerialChain:
    """A serial chain between a base link and a tip link.

    Attributes
    ----------
    name : str
    base_link, tip_link : str
    joint_names : tuple of str (n,)
    joint_types : tuple of str (n,)
        ``"revolute"`` (URDF revolute or continuous) or ``"prismatic"``.
    F : ndarray (n, 4, 4)
        Fixed placement of joint k in the frame of the previous joint's child (or the base link), m.
    axes : ndarray (n, 3)
        Unit joint axes in the joint frames.
    F_tip : ndarray (4, 4)
        Tip link in the last joint's child frame.
    q_min, q_max : ndarray (n,)
        Limits (rad or m).
    body_mass : ndarray (n,), optional
        Mass (kg) moved by joint k and not by joint k+1 (its child link, the links fixed to it and the side
        branches at their zero position), from the URDF's ``<inertial>``; None when the file has none.
    body_com : ndarray (n, 3), optional
        Centre of that mass in joint k's child frame (m).
    """

    name: str
    base_link: str
    tip_link: str
    joint_names: tuple
    joint_types: tuple
    F: np.ndarray
    axes: np.ndarray
    F_tip: np.ndarray
    q_min: np.ndarray
    q_max: np.ndarray
    body_mass: np.ndarray | None = None
    body_com: np.ndarray | None = None

    @property
    def n(self) -> int:
        """Number of moving joints."""
        return len(self.joint_names)

    @property
    def n_errors(self) -> int:
        """``6 (n + 1)`` generalized errors."""
        return 6 * (self.n + 1)

    @property
    def reach(self) -> float:
        """Sum of the placements' lengths and the prismatic strokes (m): a scale for rotations."""
        stroke = sum(max(abs(lo), abs(hi)) for lo, hi, t in zip(self.q_min, self.q_max, self.joint_types, strict=True)
                     if t == "prismatic")
        return float(np.linalg.norm(self.F[:, :3, 3], axis=1).sum() + np.linalg.norm(self.F_tip[:3, 3]) + stroke)

    def random_configurations(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """``n`` joint vectors uniform within the limits, (n, dof)."""
        return rng.uniform(self.q_min, self.q_max, size=(n, self.n))

    def check_q(self, q, name: str = "q") -> np.ndarray:
        """Validate readings ``q (..., n)`` (rad / m); one-line ``ValueError`` naming ``name`` otherwise."""
        return check_vectors(q, name, self.n)


def chain_from_dh(robot) -> SerialChain:
    """The DH arm ``robot`` (:class:`bench.robot.model.Robot`) as a chain whose error frames are the thesis's:
    ``F_1 = I``, ``F_(k+1) = Rz(theta_offset_k) Tz(d_k) Tx(a_k) Rx(alpha_k)``, axes z, so that
    ``F_1 E_0 M_1 F_2 E_1 ... = E_0 A_1 E_1 ...`` (Eq. 10) with the same 6 (n + 1) errors in the same order. The
    measured point ``p_ee`` is not part of the chain (a marker offset)."""
    from bench.geometry.transforms import rot_x, rot_z

    X = [homogeneous(rot_z(robot.theta_offset[k]), [0.0, 0.0, 0.0])
         @ homogeneous(np.eye(3), [robot.a[k], 0.0, robot.d[k]]) @ homogeneous(rot_x(robot.alpha[k]), [0.0] * 3)
         for k in range(robot.n)]
    F = np.array([np.eye(4)] + X[:-1])
    return SerialChain(robot.name, "base", "link_n", tuple(robot.joint_names), ("revolute",) * robot.n, F,
                       np.tile([0.0, 0.0, 1.0], (robot.n, 1)), X[-1], np.asarray(robot.q_min, float),
                       np.asarray(robot.q_max, float))


def motion(chain: SerialChain, k: int, qk):
    """Joint motion ``M_k(q_k)``, shape ``qk.shape + (4, 4)``: rotation by ``q_k`` rad about the axis (exp map) or
    translation by ``q_k`` m along it."""
    qk = np.asarray(qk, dtype=float)
    a = chain.axes[k]
    if chain.joint_types[k] == "prismatic":
        return homogeneous(np.broadcast_to(np.eye(3), qk.shape + (3, 3)), qk[..., None] * a)
    return homogeneous(axis_angle_to_matrix(a, qk), np.zeros(qk.shape + (3,)))


def _eps(chain: SerialChain, eps):
    if eps is None:
        return np.zeros((chain.n + 1, 6))
    eps = np.asarray(eps, dtype=float)
    if eps.shape != (chain.n_errors,):
        raise ValueError(f"eps: expected shape ({chain.n_errors},), got {eps.shape}")
    return eps.reshape(chain.n + 1, 6)


def tip_frames(chain: SerialChain, q, eps=None):
    """``T_base_tip (..., 4, 4)`` of the chain with errors ``eps (6 (n + 1),)`` at readings ``q (..., n)``."""
    q = chain.check_q(q)
    e = _eps(chain, eps)
    T = np.broadcast_to(np.eye(4), q.shape[:-1] + (4, 4))
    for k in range(chain.n):
        T = T @ chain.F[k]
        if np.any(e[k]):
            T = T @ error_matrix(e[k])
        T = T @ motion(chain, k, q[..., k])
    T = T @ chain.F_tip
    return T @ error_matrix(e[chain.n]) if np.any(e[chain.n]) else T


def points_and_jacobian(chain: SerialChain, q, u, eps=None):
    """Points ``u`` fixed on the tip link, in the base frame, and their derivatives by the errors.

    Parameters
    ----------
    q : ndarray (m, n)
    u : ndarray (k, 3)
        Points in the tip link frame (m).
    eps : ndarray (6 (n + 1),), optional

    Returns
    -------
    p : ndarray (m, k, 3)
        Points in the base frame (m).
    J : ndarray (m, k, 3, 6 (n + 1))
        ``dp / d eps`` (exact form: column ``R_B dt + (R_B w) x (p - o)`` for frame origin ``o`` after its error).
    T_tip : ndarray (m, 4, 4)
    """
    q = chain.check_q(q)
    u = np.asarray(u, dtype=float).reshape(-1, 3)
    e = _eps(chain, eps)
    lead = q.shape[:-1]
    RB, O = [], []
    T = np.broadcast_to(np.eye(4), lead + (4, 4))
    for k in range(chain.n + 1):
        B = T @ (chain.F[k] if k < chain.n else chain.F_tip)
        T = B @ error_matrix(e[k]) if np.any(e[k]) else B
        RB.append(B[..., :3, :3])
        O.append(T[..., :3, 3])
        if k < chain.n:
            T = T @ motion(chain, k, q[..., k])
    p = np.einsum("...ij,kj->...ki", T[..., :3, :3], u) + T[..., None, :3, 3]
    J = np.empty(lead + (len(u), 3, chain.n_errors))
    for k in range(chain.n + 1):
        E = error_matrix(e[k])
        dE = error_matrix_derivatives(e[k])
        W = vee(dE[:, :3, :3] @ E[:3, :3].T).T  # (3, 6) local angular velocities
        Dt = dE[:, :3, 3].T
        Wb = RB[k] @ W  # (..., 3, 6)
        Tb = RB[k] @ Dt
        r = p - O[k][..., None, :]  # (..., k, 3)
        cross = np.cross(Wb[..., None, :, :], r[..., :, :, None], axis=-2)  # (..., k, 3, 6)
        J[..., 6 * k: 6 * k + 6] = Tb[..., None, :, :] + cross
    return p, J, T


def gravity_torques(chain: SerialChain, q, g_base=(0.0, 0.0, -9.81)):
    """Static joint loads of the nominal chain under gravity, ``(m, n)``: N m about a revolute axis, N along a
    prismatic one (the load that the joint's compliance answers to; the payload beyond the URDF is not known).

    ``g_base``: gravity in the base frame (m/s^2); URDF bases are z-up (REP 103)."""
    if chain.body_mass is None:
        raise ValueError(f"{chain.name}: the URDF has no <inertial> masses on the chain: no gravity model")
    q = chain.check_q(q)
    g = np.asarray(g_base, dtype=float)
    T = np.broadcast_to(np.eye(4), q.shape[:-1] + (4, 4))
    origins, axes, coms = [], [], []
    for k in range(chain.n):
        T = T @ chain.F[k]
        origins.append(T[..., :3, 3])
        axes.append(T[..., :3, :3] @ chain.axes[k])
        T = T @ motion(chain, k, q[..., k])
        coms.append(T[..., :3, :3] @ chain.body_com[k] + T[..., :3, 3])
    tau = np.zeros(q.shape)
    for k in range(chain.n):
        f = np.zeros(q.shape[:-1] + (3,))
        mom = np.zeros(q.shape[:-1] + (3,))
        for b in range(k, chain.n):
            fb = chain.body_mass[b] * g
            f = f + fb
            mom = mom + np.cross(coms[b] - origins[k], fb)
        tau[..., k] = np.sum(axes[k] * (f if chain.joint_types[k] == "prismatic" else mom), axis=-1)
    return tau


def joint_jacobian(chain: SerialChain, q, u, eps=None):
    """``dp / dq`` of points ``u (k, 3)`` on the tip link, ``(m, k, 3, n)`` (m per rad, or per m if prismatic)."""
    q = chain.check_q(q)
    u = np.asarray(u, dtype=float).reshape(-1, 3)
    e = _eps(chain, eps)
    T = np.broadcast_to(np.eye(4), q.shape[:-1] + (4, 4))
    origins, axes = [], []
    for k in range(chain.n):
        T = T @ chain.F[k]
        if np.any(e[k]):
            T = T @ error_matrix(e[k])
        origins.append(T[..., :3, 3])
        axes.append(T[..., :3, :3] @ chain.axes[k])
        T = T @ motion(chain, k, q[..., k])
    T = T @ chain.F_tip
    if np.any(e[chain.n]):
        T = T @ error_matrix(e[chain.n])
    p = np.einsum("...ij,kj->...ki", T[..., :3, :3], u) + T[..., None, :3, 3]
    J = np.empty(p.shape + (chain.n,))
    for k in range(chain.n):
        a = np.broadcast_to(axes[k][..., None, :], p.shape)
        J[..., k] = a if chain.joint_types[k] == "prismatic" else np.cross(a, p - origins[k][..., None, :])
    return J


def chain_to_dict(chain: SerialChain) -> dict:
    """The chain as a YAML-ready mapping (mm and degrees, units in the keys)."""
    def placement(T):
        return {"xyz_mm": [float(v) for v in T[:3, 3] * 1e3],
                "quaternion_wxyz": [float(v) for v in matrix_to_quaternion(T[:3, :3])]}

    joints = []
    for k in range(chain.n):
        lim = (np.rad2deg([chain.q_min[k], chain.q_max[k]]) if chain.joint_types[k] == "revolute"
               else np.array([chain.q_min[k], chain.q_max[k]]) * 1e3)
        unit = "deg" if chain.joint_types[k] == "revolute" else "mm"
        joints.append({"name": chain.joint_names[k], "type": chain.joint_types[k], "origin": placement(chain.F[k]),
                       "axis": [float(v) for v in chain.axes[k]], f"min_{unit}": float(lim[0]),
                       f"max_{unit}": float(lim[1])})
        if chain.body_mass is not None:
            joints[-1]["body_mass_kg"] = float(chain.body_mass[k])
            joints[-1]["body_com_mm"] = [float(v) for v in chain.body_com[k] * 1e3]
    return {"name": chain.name, "base_link": chain.base_link, "tip_link": chain.tip_link, "joints": joints,
            "tip_origin": placement(chain.F_tip)}


def chain_from_dict(data, source: str = "<chain>") -> SerialChain:
    """Inverse of :func:`chain_to_dict`; one-line :class:`ConfigError` naming the key on bad input."""
    from bench.errors import ConfigError

    def numbers(value, n, where):
        if not isinstance(value, list) or len(value) != n or any(
                isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) for v in value):
            raise ConfigError(source, where, f"expected a list of {n} finite numbers, got {value!r}")
        return np.array(value, dtype=float)

    def placement(d, where):
        if not isinstance(d, dict) or set(d) != {"xyz_mm", "quaternion_wxyz"}:
            raise ConfigError(source, where, "expected a mapping with xyz_mm and quaternion_wxyz")
        qw = numbers(d["quaternion_wxyz"], 4, f"{where}.quaternion_wxyz")
        if abs(np.linalg.norm(qw) - 1.0) > 1e-6:
            raise ConfigError(source, f"{where}.quaternion_wxyz", "must be a unit quaternion")
        return homogeneous(quaternion_to_matrix(qw), numbers(d["xyz_mm"], 3, f"{where}.xyz_mm") * 1e-3)

    if not isinstance(data, dict):
        raise ConfigError(source, "chain", "expected a mapping")
    for key in ("name", "base_link", "tip_link", "joints", "tip_origin"):
        if key not in data:
            raise ConfigError(source, f"chain.{key}", "missing")
    if not isinstance(data["joints"], list) or not data["joints"]:
        raise ConfigError(source, "chain.joints", "expected a non-empty list")
    names, types, F, axes, lo, hi, mass, com = [], [], [], [], [], [], [], []
    for i, j in enumerate(data["joints"]):
        where = f"chain.joints[{i}]"
        if not isinstance(j, dict):
            raise ConfigError(source, where, "expected a mapping")
        t = j.get("type")
        if t not in JOINT_TYPES:
            raise ConfigError(source, f"{where}.type", f"expected one of {JOINT_TYPES}, got {t!r}")
        unit, scale = ("deg", np.pi / 180) if t == "revolute" else ("mm", 1e-3)
        for key in ("name", "origin", "axis", f"min_{unit}", f"max_{unit}"):
            if key not in j:
                raise ConfigError(source, f"{where}.{key}", "missing")
        a = numbers(j["axis"], 3, f"{where}.axis")
        if abs(np.linalg.norm(a) - 1.0) > 1e-6:
            raise ConfigError(source, f"{where}.axis", f"must be a unit vector, got {j['axis']}")
        names.append(str(j["name"]))
        types.append(t)
        F.append(placement(j["origin"], f"{where}.origin"))
        axes.append(a)
        lo.append(numbers([j[f"min_{unit}"]], 1, f"{where}.min_{unit}")[0] * scale)
        hi.append(numbers([j[f"max_{unit}"]], 1, f"{where}.max_{unit}")[0] * scale)
        if "body_mass_kg" in j:
            mass.append(numbers([j["body_mass_kg"]], 1, f"{where}.body_mass_kg")[0])
            com.append(numbers(j.get("body_com_mm"), 3, f"{where}.body_com_mm") * 1e-3)
    if mass and len(mass) != len(names):
        raise ConfigError(source, "chain.joints", "body_mass_kg given for some joints only")
    return SerialChain(str(data["name"]), str(data["base_link"]), str(data["tip_link"]), tuple(names), tuple(types),
                       np.array(F), np.array(axes), placement(data["tip_origin"], "chain.tip_origin"),
                       np.array(lo), np.array(hi), np.array(mass) if mass else None,
                       np.array(com) if com else None)
