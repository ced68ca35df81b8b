"""The public Python API in one import: compose and run a teleoperation session.

    from teleop.api import ReferenceTool, RigidBody, IdealMaster, SlaveArm, SlaveSide, Session, ...

The two sides of the tick (:class:`MasterSide`, :class:`SlaveSide`) are what every runner
composes: :class:`BilateralLoop` in one process, :mod:`teleop.app.netrun` in two;
:func:`build_master` / :func:`build_slave` make them from a scene.

See the README's "Python API" section for a whole run with a constraint and a fixture type of the
user's own. Everything here is also importable from its own module; this module only gathers them.
"""

from teleop.app.assembly import build_master, build_slave
from teleop.app.runtime import run_scene
from teleop.app.session import RunResult, Session
from teleop.contact import TissueBlock
from teleop.control.mapping import Registration
from teleop.dynamics.body import RigidBody
from teleop.dynamics.constraints import Constraint
from teleop.dynamics.effects import AngularDamper, Gravity, LinearDamper, Spring
from teleop.dynamics.fixtures import Fixture
from teleop.dynamics.registry import FrameMap, register_fixture
from teleop.dynamics.tool import ReferenceTool
from teleop.link.base import LockstepLink
from teleop.master.base import Master
from teleop.master.ideal import IdealMaster
from teleop.scenario.operators import Operator
from teleop.scenario.schema import load_scene, parse_scene
from teleop.slave import SlaveArm, SlaveConfig
from teleop.tick.feedback import FeedbackPath
from teleop.tick.loop import BilateralLoop
from teleop.tick.master_side import MasterSide, SetWrench
from teleop.tick.messages import ContactFeedback, ToolCommand
from teleop.tick.ports import Hook, ToolState
from teleop.tick.slave_side import SlaveSide
from teleop.tick.verdict import run_summary, verdict

__all__ = [
    "AngularDamper", "BilateralLoop", "Constraint", "ContactFeedback", "FeedbackPath", "Fixture", "FrameMap",
    "Gravity", "Hook", "IdealMaster", "LinearDamper", "LockstepLink", "Master", "MasterSide", "Operator",
    "ReferenceTool", "Registration", "RigidBody", "RunResult", "Session", "SetWrench", "SlaveArm",
    "SlaveConfig", "SlaveSide", "Spring", "TissueBlock", "ToolCommand", "ToolState", "build_master",
    "build_slave", "load_scene", "parse_scene", "register_fixture", "run_scene", "run_summary", "verdict",
]
