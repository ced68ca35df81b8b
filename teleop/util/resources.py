"""Where the shipped scenes and robot descriptions are, in a checkout, an editable install or a wheel.

The repository keeps them at its top level, ``scenarios/`` and ``robots/``; ``teleop/scenarios`` and
``teleop/robots`` are symbolic links to those folders, so they are the package's data: a wheel (or a
non-editable ``pip install .``) carries copies of the files inside ``teleop/``, an editable install
and a plain checkout read them through the links. Code finds them here, through
:mod:`importlib.resources`, and nowhere else.
"""

from __future__ import annotations

from importlib.resources import files
from importlib.resources.abc import Traversable
from pathlib import Path

__all__ = ["robot_dir", "robot_file", "scenario_dir", "scenario_files"]


def _data(name: str) -> Traversable:
    return files("teleop").joinpath(name)


def _on_disk(res: Traversable) -> Path:
    # A checkout, an editable install and a wheel installed into site-packages or a --target folder
    # all put the data on disk, where pinocchio and the scene reader want real paths.
    if not isinstance(res, Path):
        raise RuntimeError(f"teleop's data must be on disk, not inside an archive: {res}")
    return res


def scenario_dir() -> Path:
    """The folder of the shipped scenes (``*.toml``)."""
    return _on_disk(_data("scenarios"))


def scenario_files() -> list[Path]:
    """The shipped scene files, sorted by name."""
    return sorted(scenario_dir().glob("*.toml"))


def robot_dir() -> Path:
    """The folder of the shipped robot descriptions (one sub-folder a robot)."""
    return _on_disk(_data("robots"))


def robot_file(relative: str) -> Path:
    """A file of the shipped robot descriptions, e.g. ``robot_file("cobot/cobot.urdf")``."""
    p = robot_dir().joinpath(relative)
    if not p.is_file():
        raise FileNotFoundError(f"no robot file {relative!r} under {robot_dir()}")
    return p
