"""Procedural, seeded scenes built with ``mujoco.MjSpec``: manifold panel, calibration rig, x-y table, desk robot."""

from bench.sim.scenes.base import SceneObject, add_look_at_camera, compose, place, save_scene
from bench.sim.scenes.panel import manifold_panel
from bench.sim.scenes.rig import calibration_rig, planar_board
from bench.sim.scenes.xy_table import (
    TableErrors,
    TableModel,
    TableRun,
    lab_table_model,
    load_pose_table,
    random_table_errors,
    table4_commands,
    table10_commands,
    underwater_table_model,
    xy_table,
)

__all__ = ["SceneObject", "add_look_at_camera", "compose", "place", "save_scene", "manifold_panel",
           "calibration_rig", "planar_board", "TableErrors", "TableModel", "TableRun", "lab_table_model",
           "load_pose_table", "random_table_errors", "table4_commands", "table10_commands", "underwater_table_model",
           "xy_table"]
