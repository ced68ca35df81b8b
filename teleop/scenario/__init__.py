"""Scenes: the file format, loading and validation, scripted operators and metrics."""

from teleop.scenario.schema import Scene, list_scenes, load_scene

__all__ = ["Scene", "list_scenes", "load_scene"]
