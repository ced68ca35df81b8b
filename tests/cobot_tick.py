"""The master side of the bilateral tick for the master tests: the same MasterSide every run
composes (hand -> sense -> tool step -> command), driven with a wrench the test sets and, if
given, a contact wrench fed to the tool as the slave's would be."""

import weakref

import numpy as np

from teleop.master import CobotConfig, CobotMaster
from teleop.tick.master_side import MasterSide, SetWrench

_SIDES: "weakref.WeakKeyDictionary[CobotMaster, MasterSide]" = weakref.WeakKeyDictionary()


class _Contact:
    """Stands in for the feedback path: renders the contact wrench the test gives, as it is."""

    refused = 0

    def __init__(self):
        self.W = np.zeros(6)

    def render(self, channel, tool, f_other, dt, state=None, gain=1.0):
        return self.W


def make_cobot(tool, cfg: CobotConfig, dt_s: float, rng) -> CobotMaster:
    """A cobot master for ``tool`` (its start pose and mass)."""
    return CobotMaster(cfg, dt_s, rng, *tool.pose(), tool.body.mass_kg)


def tick(master, tool, hand_wrench_W, contact_wrench_W=None) -> str:
    """One period of the master side; returns its status (the tool's if it is not "ok", else the
    master's)."""
    side = _SIDES.get(master)
    if side is None or side.tool is not tool:
        side = _SIDES[master] = MasterSide(tool, master, SetWrench(), master.dt_s, feedback=_Contact())
    side.operator.W = np.asarray(hand_wrench_W, dtype=float)
    side.feedback.W = np.zeros(6) if contact_wrench_W is None else np.asarray(contact_wrench_W, dtype=float)
    return side.tick(0, tool.t)
