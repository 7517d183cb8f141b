"""Procedural, seeded scenes as MJCF fragments: manifold panel, calibration rig, x-y table (issue 3, item 5)."""

from bench.sim.scenes.base import SceneObject, compose, look_at_camera_xml, place, save_scene
from bench.sim.scenes.panel import manifold_panel

__all__ = ["SceneObject", "compose", "look_at_camera_xml", "place", "save_scene", "manifold_panel"]
