"""Arm kinematics and structural calibration (thesis chapters 2 and 4). Pipeline side: pure numpy."""

from bench.robot.model import PARAM_KINDS, Robot, error_names, load_robot

__all__ = ["PARAM_KINDS", "Robot", "error_names", "load_robot"]
