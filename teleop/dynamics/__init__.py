"""The paper's reference tool (§II): rigid body, constraints, effects, integrators."""

from teleop.dynamics.body import RigidBody
from teleop.dynamics.fixtures import Fixture
from teleop.dynamics.integrators import INTEGRATORS
from teleop.dynamics.tool import ReferenceTool

__all__ = ["INTEGRATORS", "Fixture", "ReferenceTool", "RigidBody"]
