"""Pinocchio model of a DH arm with generalized errors: the bench's independent reference kinematics.

Built from the nominal DH parameters (Eq. 8) and the exact form of the generalized errors (Eq. 9-10) with
Pinocchio's own SE(3) and rotation utilities, **without** importing :mod:`bench.robot.kinematics` or
:mod:`bench.robot.jacobian`, so that agreement between the two is evidence, not a tautology.

The chain ``T_base_k = E0 A1 E1 ... Ak Ek`` (Eq. 10) with ``A_i = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)`` (Eq. 8),
``theta_i = q_i + theta_offset_i`` and ``E = Trans(x, y, z) Rz(r) Ry(s) Rx(p)`` is regrouped around Pinocchio's
revolute joints ``Rz(q_i)``. Writing ``S_i = Tz(d_i) Tx(a_i) Rx(alpha_i)`` (the part of ``A_i`` after the joint
rotation) and ``S_0 = I``::

    jointPlacements[i] = S_(i-1) E_(i-1) Rz(theta_offset_i)       i = 1..n   (joint i, revolute about its z)
    frame "frame0"     = E0 on the universe
    frame "frame<k>"   = S_k E_k on joint k                         k = 1..n   (the DH frame k after E_k)
    frame "link5"      = frame 5 (the camera's link);  "ee_point" = S_n E_n Trans(p_ee) on joint n

so that Pinocchio's world frame is the robot's base frame O0 and its configuration is the joint readings ``q`` (rad).

Pinocchio's kinematic regressor (``computeFrameKinematicRegressor``) differentiates a frame's placement with
respect to a *right* perturbation of every joint placement by a local twist ``xi = (v, w)``:
``jointPlacements[i] -> jointPlacements[i] exp(xi)``. Because ``jointPlacements[i]`` ends with
``E_(i-1) Rz(theta_offset_i)``, a change ``d e`` of the six errors of frame ``i-1`` is exactly such a perturbation with
``xi = Ad(Rz(-theta_offset_i)) X(e) d e`` (see :func:`error_twist_map`); at ``e = 0`` and zero offset ``X`` is the
permutation ``(x, y, z, s, r, p) -> (v_x, v_y, v_z, w_y, w_z, w_x)``. The regressor therefore covers the errors of
frames 0..n-1 (columns ``0 .. 6n-1`` of the identification Jacobian); the last frame's ``E_n`` sits in the frame
placement of ``"ee_point"`` and is outside its scope.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from bench.geometry.transforms import check_vectors
from bench.robot.model import Robot

#: Operational frames of the model, in the order returned by :func:`pinocchio_frames` (frame k = index k).
FRAME_NAMES = tuple(f"frame{k}" for k in range(7))

_REFERENCE = {"LOCAL": pin.ReferenceFrame.LOCAL, "WORLD": pin.ReferenceFrame.WORLD,
              "LOCAL_WORLD_ALIGNED": pin.ReferenceFrame.LOCAL_WORLD_ALIGNED}


def _check_eps(robot: Robot, eps) -> np.ndarray:
    """Validated errors as an ``(n + 1, 6)`` array (m, rad)."""
    n_err = 6 * (robot.n + 1)
    if eps is None:
        return np.zeros((robot.n + 1, 6))
    eps = np.asarray(eps, dtype=float)
    if eps.shape != (n_err,):
        raise ValueError(f"eps: expected shape ({n_err},) (x, y, z, s, r, p per frame 0..{robot.n}), got {eps.shape}")
    if not np.all(np.isfinite(eps)):
        raise ValueError("eps: contains NaN or inf")
    return eps.reshape(robot.n + 1, 6)


def _check_q(robot: Robot, q) -> np.ndarray:
    """Validated joint readings ``(..., n)`` (rad)."""
    return check_vectors(q, "q", robot.n, " joint readings in rad")


def error_placement(e6) -> pin.SE3:
    """Exact generalized-error transform ``E = Trans(x, y, z) Rz(r) Ry(s) Rx(p)`` (Eq. 9, exact form) as a pin.SE3.

    ``e6 = (x, y, z, s, r, p)``: m, m, m, rad about y, rad about z, rad about x.
    """
    x, y, z, s, r, p = (float(v) for v in e6)
    return pin.SE3(pin.rpy.rpyToMatrix(p, s, r), np.array([x, y, z]))  # rpyToMatrix(rx, ry, rz) = Rz Ry Rx


def dh_after_joint(d: float, a: float, alpha: float) -> pin.SE3:
    """``S = Tz(d) Tx(a) Rx(alpha)``: the part of the DH matrix (Eq. 8) after the joint rotation ``Rz(theta)``."""
    return pin.SE3(pin.utils.rotate("x", float(alpha)), np.array([float(a), 0.0, float(d)]))


def build_pinocchio_model(robot: Robot, eps=None) -> pin.Model:
    """Pinocchio model of the arm with generalized errors ``eps`` in the exact form (Eq. 10).

    Parameters
    ----------
    robot : Robot
        Nominal DH parameters (SI), joint limits and measured point ``p_ee`` (m, frame n).
    eps : array_like (6 (n + 1),), optional
        Generalized errors, frame-major ``x, y, z, s, r, p`` (m, rad); zero if omitted.

    Returns
    -------
    pin.Model
        Revolute-z joints ``joint1 .. joint<n>`` (configuration = joint readings, rad; the offsets sit in the
        placements), operational frames ``frame0 .. frame<n>`` (``T_base_k``), ``link5`` and ``ee_point``.
    """
    e = _check_eps(robot, eps)
    model = pin.Model()
    model.name = f"{robot.name} (generalized errors, exact form)"
    model.addFrame(pin.Frame("frame0", 0, 0, error_placement(e[0]), pin.FrameType.OP_FRAME))
    before = pin.SE3.Identity()  # S_(i-1), identity for joint 1
    parent = 0
    for i in range(1, robot.n + 1):
        placement = before * error_placement(e[i - 1]) * pin.SE3(pin.utils.rotate("z", robot.theta_offset[i - 1]),
                                                                  np.zeros(3))
        parent = model.addJoint(parent, pin.JointModelRZ(), placement, f"joint{i}",
                                np.full(1, 1e3), np.full(1, 1e3), robot.q_min[i - 1: i], robot.q_max[i - 1: i])
        model.addJointFrame(parent)
        before = dh_after_joint(robot.d[i - 1], robot.a[i - 1], robot.alpha[i - 1])
        frame_k = before * error_placement(e[i])  # S_i E_i: DH frame i after its error matrix
        model.addFrame(pin.Frame(f"frame{i}", parent, frame_k, pin.FrameType.OP_FRAME))
        if i == 5:
            model.addFrame(pin.Frame("link5", parent, frame_k, pin.FrameType.OP_FRAME))
        if i == robot.n:
            model.addFrame(pin.Frame("ee_point", parent, frame_k * pin.SE3(np.eye(3), np.asarray(robot.p_ee, float)),
                                     pin.FrameType.OP_FRAME))
    return model


class PinocchioArm:
    """A built Pinocchio model with its data and frame ids, for repeated evaluation.

    Parameters
    ----------
    robot : Robot
    eps : array_like (6 (n + 1),), optional
        Generalized errors (m, rad), exact form.
    """

    def __init__(self, robot: Robot, eps=None):
        self.robot = robot
        self.model = build_pinocchio_model(robot, eps)
        self.data = self.model.createData()
        self.frame_ids = [self.model.getFrameId(f"frame{k}") for k in range(robot.n + 1)]
        self.ee_id = self.model.getFrameId("ee_point")

    def _update(self, qi):
        pin.forwardKinematics(self.model, self.data, qi)
        pin.updateFramePlacements(self.model, self.data)

    def _each(self, q, shape: tuple, value) -> np.ndarray:
        """``value()`` (an array of ``shape``) at every configuration of ``q (..., n)`` (rad), the kinematics and frame
        placements updated for each: shape ``(...,) + shape``."""
        q = _check_q(self.robot, q)
        flat = q.reshape(-1, self.robot.n)
        out = np.empty((flat.shape[0],) + shape)
        for j, qi in enumerate(flat):
            self._update(qi)
            out[j] = value()
        return out.reshape(q.shape[:-1] + shape)

    def frames(self, q) -> np.ndarray:
        """``T_base_k`` for k = 0..n from Pinocchio, shape (..., n + 1, 4, 4); ``q (..., n)`` in rad."""
        return self._each(q, (len(self.frame_ids), 4, 4),
                          lambda: [self.data.oMf[fid].homogeneous for fid in self.frame_ids])

    def ee_position(self, q) -> np.ndarray:
        """The measured point ``p_base`` (m) from the ``ee_point`` frame, shape (..., 3)."""
        return self._each(q, (3,), lambda: self.data.oMf[self.ee_id].translation)

    def regressor(self, q, frame="ee_point", reference="LOCAL_WORLD_ALIGNED") -> np.ndarray:
        """Pinocchio's frame kinematic regressor, shape (..., 6, 6n), rows ``(v, w)``.

        Column block ``i - 1`` is the derivative of the frame's velocity ``(v, w)`` (in ``reference``) with respect
        to the local twist ``xi`` of ``jointPlacements[i] exp(xi)``.
        """
        if reference not in _REFERENCE:
            raise ValueError(f"reference: expected one of {sorted(_REFERENCE)}, got {reference!r}")
        if not self.model.existFrame(frame):
            raise ValueError(f"frame: unknown frame {frame!r} (have frame0..frame{self.robot.n}, link5, ee_point)")
        fid = self.model.getFrameId(frame)
        return self._each(q, (6, 6 * self.robot.n),
                          lambda: pin.computeFrameKinematicRegressor(self.model, self.data, fid, _REFERENCE[reference]))


def pinocchio_frames(robot: Robot, q, eps=None) -> np.ndarray:
    """``T_base_k`` for k = 0..n (Eq. 10) from Pinocchio (forwardKinematics + updateFramePlacements).

    Parameters
    ----------
    robot : Robot
    q : array_like (..., n)
        Joint readings (rad).
    eps : array_like (6 (n + 1),), optional
        Generalized errors (m, rad), exact form.

    Returns
    -------
    ndarray (..., n + 1, 4, 4)
    """
    return PinocchioArm(robot, eps).frames(q)


def pinocchio_ee_position(robot: Robot, q, eps=None) -> np.ndarray:
    """The measured point ``p_ee`` carried by frame n, in the base frame (m), from Pinocchio; shape (..., 3)."""
    return PinocchioArm(robot, eps).ee_position(q)


def error_twist_map(e6, theta_offset: float = 0.0) -> np.ndarray:
    """Local twist of a joint placement caused by a change of the errors of the frame before it, (6, 6).

    ``jointPlacements[i] = S E(e) Rz(theta_offset)``; ``d/de_k`` of it equals ``jointPlacements[i] [xi_k]`` with
    ``xi_k = Ad(Rz(-theta_offset)) (E^-1 dE/de_k)^vee``. For ``E = Trans(t) Rz(r) Ry(s) Rx(p)``:
    translations give ``v = R^T e_axis``; rotations give ``w = e_x`` (p), ``Rx(p)^T e_y`` (s),
    ``(Ry(s) Rx(p))^T e_z`` (r).

    Parameters
    ----------
    e6 : array_like (6,)
        ``(x, y, z, s, r, p)`` of the frame before the joint (m, rad).
    theta_offset : float
        The joint's DH angle offset (rad).

    Returns
    -------
    ndarray (6, 6)
        Rows ``(v, w)`` in Pinocchio's motion order, columns ``(x, y, z, s, r, p)``.
    """
    _, _, _, s, r, p = (float(v) for v in e6)
    Rx, Ry, Rz = pin.utils.rotate("x", p), pin.utils.rotate("y", s), pin.utils.rotate("z", r)
    R = Rz @ Ry @ Rx
    X = np.zeros((6, 6))
    X[:3, :3] = R.T
    X[3:, 3] = Rx.T @ [0.0, 1.0, 0.0]
    X[3:, 4] = (Ry @ Rx).T @ [0.0, 0.0, 1.0]
    X[3:, 5] = [1.0, 0.0, 0.0]
    Ad = pin.SE3(pin.utils.rotate("z", -float(theta_offset)), np.zeros(3)).action
    return Ad @ X


def regressor_error_jacobian(robot: Robot, q, eps=None) -> np.ndarray:
    """Identification Jacobian (pose rows, Eq. 12) for the errors of frames 0..n-1, from Pinocchio's regressor.

    Rows: ``dp`` of the measured point (m per unit error) then the base-frame rotation vector ``w``
    (``dR R^T = [w]x``) - Pinocchio's LOCAL_WORLD_ALIGNED velocity of the ``ee_point`` frame. Columns: the errors
    ``x0 .. p_(n-1)`` (indices ``0 .. 6n-1`` of the error vector); block ``i - 1`` of the regressor (joint i) times
    :func:`error_twist_map` of frame ``i - 1``. The last frame's errors (``E_n``, in the frame placement) are outside
    the regressor's scope.

    Returns
    -------
    ndarray (..., 6, 6n)
    """
    e = _check_eps(robot, eps)
    arm = PinocchioArm(robot, eps)
    K = arm.regressor(q, "ee_point", "LOCAL_WORLD_ALIGNED")
    out = np.empty_like(K)
    for i in range(1, robot.n + 1):
        blk = slice(6 * (i - 1), 6 * i)
        out[..., blk] = K[..., blk] @ error_twist_map(e[i - 1], robot.theta_offset[i - 1])
    return out
