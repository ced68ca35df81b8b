"""The slave arm: Pinocchio model with the tool frame E, the QP follower, its limits and solvers."""

from teleop.slave.arm import SlaveConfig, build_model
from teleop.slave.limits import JointLimits
from teleop.slave.projection import project_onto_fixture
from teleop.slave.qp import STATUSES, FollowerQP, SlaveArm, compute_target_twist
from teleop.slave.solvers import installed_solvers, make_solver

__all__ = [
    "STATUSES", "FollowerQP", "JointLimits", "SlaveArm", "SlaveConfig", "build_model", "compute_target_twist",
    "installed_solvers", "make_solver", "project_onto_fixture",
]
