"""Re-targeting a taught tool pose after the base has moved: the reason for the whole in-situ calibration.

The thesis's motivation (chapter 1, §6.1): a task such as turning a valve is programmed once; every time the ROV
parks, the arm's base sits somewhere new and the pre-programmed joint positions miss. Here a task is *taught* at a
site: the operator drives the tool onto the handle and the joint readings ``q_taught`` are stored. In the site frame
(the survey base frame, where the in-situ map ¹p lives, §3.9) the taught tool pose is::

    T_site_ee = T_site_base_taught · T(ε̂, q_taught)                         (Eq. 10 with the identified errors)

After the ROV has parked again and the in-situ localisation has found ``T_site_base`` (Eq. 165-166 + §3.7), the
same tool pose in the new base frame is ``T_site_base⁻¹ · T_site_ee``, and the compensated inverse kinematics on the
calibrated model (§4.5, :func:`bench.robot.ik.compensated_ik`) gives the joint readings to command.

Estimated: nothing here (it composes earlier estimates). Fixed: the identified errors ε̂ (generalized errors of
§2.4, 42-vector, SI), the located base pose, the taught readings.
"""

from __future__ import annotations

import numpy as np

from bench.geometry.transforms import check_transform, invert
from bench.robot.ik import IKResult, compensated_ik
from bench.robot.kinematics import forward_kinematics
from bench.robot.model import Robot


def taught_pose(robot: Robot, eps, q_taught, T_site_base_taught=None) -> np.ndarray:
    """Tool pose ``T_site_ee`` (4, 4) of a taught configuration: Eq. 10 with errors ``eps`` at readings ``q_taught``.

    Parameters
    ----------
    robot : Robot
    eps : array_like (42,) or None
        Identified generalized errors (m, rad); None = nominal model.
    q_taught : array_like (6,)
        Joint readings (rad) recorded while the tool was on the target.
    T_site_base_taught : array_like (4, 4), optional
        Base pose in the site frame when the task was taught (default identity: the site frame is that base frame).
    """
    q = robot.check_q(q_taught, "q_taught")
    if q.shape != (robot.n,):
        raise ValueError(f"q_taught: expected shape ({robot.n},), got {q.shape}")
    T_sb = np.eye(4) if T_site_base_taught is None else check_transform(T_site_base_taught, "T_site_base_taught")
    return T_sb @ forward_kinematics(robot, q, eps)


def retarget_taught_pose(robot: Robot, eps, q_taught, T_site_base, T_site_base_taught=None, q_seed=None,
                         position_only: bool = True) -> IKResult:
    """Joint readings that put the tool back on a taught target after the base moved to ``T_site_base``.

    Parameters
    ----------
    robot : Robot
    eps : array_like (42,) or None
        Identified generalized errors (m, rad) of the calibrated arm.
    q_taught : array_like (6,)
        Readings (rad) of the taught configuration.
    T_site_base : array_like (4, 4)
        The base's new pose in the site frame (from the in-situ localisation), m.
    T_site_base_taught : array_like (4, 4), optional
        The base pose when the task was taught (default identity).
    q_seed : array_like (6,), optional
        Current readings; selects the IK branch (default the taught readings).
    position_only : bool
        Reach the measured point O6 exactly and the orientation as a secondary objective (default): the
        identification of §2.5-2.7 fixes only the errors that a point measurement sees, so the orientation of the
        calibrated model is not trustworthy to the same degree (§4.6).

    Returns
    -------
    IKResult
        ``success`` False with the reason if the target is out of reach or beyond a joint limit from the new base.
    """
    T_sb = check_transform(T_site_base, "T_site_base")
    T_site_ee = taught_pose(robot, eps, q_taught, T_site_base_taught)
    seed = np.asarray(q_taught, dtype=float) if q_seed is None else q_seed
    return compensated_ik(robot, eps, invert(T_sb) @ T_site_ee, q_seed=seed, position_only=position_only)
