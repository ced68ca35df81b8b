"""Viewers of both sides of the teleoperator: a Meshcat page, or nothing (headless runs, tests).

    from teleop.viz import VizScene, VizFrame, make_view
    with make_view("meshcat", VizScene("sphere", {"radius_m": 0.05}, "scalpel"), record=True) as view:
        view.publish(VizFrame(t=0.0, reference_pose=(p, R)))
        view.save_html("run.html")
"""

from __future__ import annotations

from teleop.util.errors import ConfigError
from teleop.viz.frames import FIXTURE_TYPES, TOOL_SHAPES, VizFrame, VizScene
from teleop.viz.null_view import NullView

VIEWS = ("meshcat", "null")


def make_view(kind: str, scene: VizScene, record: bool = False, open_browser: bool = False, **options):
    """A view by name: "meshcat" (starts a meshcat server; close() stops it; ``host=`` the address
    its web server binds, 127.0.0.1 by default) or "null"."""
    if kind == "null":
        return NullView(scene, record=record, open_browser=open_browser)
    if kind == "meshcat":
        from teleop.viz.meshcat_view import MeshcatView

        return MeshcatView(scene, record=record, open_browser=open_browser, **options)
    raise ConfigError(f"make_view: unknown view {kind!r}; choose one of {VIEWS}")


__all__ = ["FIXTURE_TYPES", "TOOL_SHAPES", "VIEWS", "NullView", "VizFrame", "VizScene", "make_view"]
