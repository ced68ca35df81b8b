"""Fixture types by name: the built-in ones and a user's own, so that a scene can name them.

A fixture type is a frozen dataclass of its parameters (SI units in the field names, written in
the patient frame, where the tissue is) with one method, ``build(frame) -> Fixture``, that places
every point, direction and length it uses through ``frame`` (a :class:`FrameMap`). The same
definition then builds the slave's fixture (``FrameMap.identity()``) and the master's (the
registration's map into the master workspace): the mapping is written once, here.

    @register_fixture("groove")
    @dataclass(frozen=True)
    class Groove:
        depth_m: float = 0.002
        def build(self, frame):
            return Fixture("groove", (PointDepth(frame.point((0, 0, 0)), frame.direction((0, 0, 1)),
                                                 frame.length(self.depth_m)),), None)

An installed package adds types through the entry-point group ``teleop.fixtures`` (each entry
point names such a class; its name is the type's name).
"""

from __future__ import annotations

import dataclasses
from importlib.metadata import entry_points

import numpy as np

from teleop.util.errors import ConfigError

ENTRY_POINT_GROUP = "teleop.fixtures"


@dataclasses.dataclass(frozen=True, eq=False)
class FrameMap:
    """A similarity x -> scale * (R x + p): where patient-frame geometry lands in another frame.
    ``R`` (3, 3) a rotation, ``p`` (3,) m, ``scale`` > 0 (lengths multiply by it)."""

    R: np.ndarray
    p: np.ndarray
    scale: float = 1.0

    @staticmethod
    def identity() -> FrameMap:
        return FrameMap(np.eye(3), np.zeros(3), 1.0)

    def point(self, x) -> np.ndarray:
        """A point (m) of the patient frame, in this frame."""
        return self.scale * (self.R @ np.asarray(x, dtype=float) + self.p)

    def direction(self, n) -> np.ndarray:
        """A direction of the patient frame, in this frame (rotated, not scaled)."""
        return self.R @ np.asarray(n, dtype=float)

    def length(self, x: float) -> float:
        """A length (m) of the patient frame, in this frame."""
        return float(x) * self.scale

    def body_point(self, x) -> np.ndarray:
        """A point fixed in the tool (m, tool frame): scaled, not rotated."""
        return self.scale * np.asarray(x, dtype=float)


class FixtureRegistry:
    """Name -> fixture type. One per process is enough; a test may make its own."""

    def __init__(self):
        self._types: dict[str, type] = {}
        self._loaded = False

    def register(self, name: str, cls: type) -> type:
        if not name.isidentifier():
            raise ConfigError(f"fixture type name {name!r}: use letters, digits and underscores")
        if not (dataclasses.is_dataclass(cls) and callable(getattr(cls, "build", None))):
            raise ConfigError(f"fixture type {name!r}: expected a dataclass with a build(frame) method")
        self._types[name] = cls
        return cls

    def _load_entry_points(self) -> None:
        if self._loaded:
            return
        self._loaded = True
        for ep in entry_points(group=ENTRY_POINT_GROUP):
            if ep.name not in self._types:
                try:
                    self.register(ep.name, ep.load())
                except Exception as e:  # a broken plug-in must not stop the others: say which
                    raise ConfigError(f"fixture plug-in {ep.name!r} ({ep.value}): {type(e).__name__}: {e}") from None

    def get(self, name: str) -> type | None:
        self._load_entry_points()
        return self._types.get(name)

    def names(self) -> list[str]:
        self._load_entry_points()
        return sorted(self._types)


#: the process's registry of user fixture types (built-in types are the scene format's own)
FIXTURE_TYPES = FixtureRegistry()


def register_fixture(name: str):
    """Class decorator: make ``cls`` a fixture type a scene can name (see the module docstring)."""

    def deco(cls):
        return FIXTURE_TYPES.register(name, cls)

    return deco
