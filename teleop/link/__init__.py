"""Master <-> slave messages and the links that carry them (in-process lockstep by default).

``ZenohLink`` lives in :mod:`teleop.link.zenoh_link` (imports zenoh); the wire format in
:mod:`teleop.link.wire`."""

from teleop.link.base import Link, LockstepLink, Mailbox
from teleop.link.channel import ChannelSpec, SimulatedChannel
from teleop.control.passivity import MasterPassivity, PortLog, SlavePassivity, TdpaParams, compute_port_energy
from teleop.tick.messages import SLAVE_STATUSES, ContactFeedback, MessageError, ToolCommand

__all__ = ["Link", "LockstepLink", "Mailbox", "ChannelSpec", "SimulatedChannel",
           "TdpaParams", "MasterPassivity", "SlavePassivity", "PortLog", "compute_port_energy", "ToolCommand", "ContactFeedback", "MessageError", "SLAVE_STATUSES"]
