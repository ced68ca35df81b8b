"""Master <-> slave messages and the links that carry them (in-process lockstep by default).

``ZenohLink`` lives in :mod:`teleop.link.zenoh_link` (imports zenoh); the wire format in
:mod:`teleop.link.wire`."""

from teleop.control.passivity import MasterPassivity, PortLog, SlavePassivity, TdpaParams, compute_port_energy
from teleop.link.base import Link, LockstepLink, Mailbox
from teleop.link.channel import ChannelSpec, SimulatedChannel
from teleop.tick.messages import SLAVE_STATUSES, ContactFeedback, MessageError, ToolCommand

__all__ = [
    "SLAVE_STATUSES", "ChannelSpec", "ContactFeedback", "Link", "LockstepLink", "Mailbox", "MasterPassivity",
    "MessageError", "PortLog", "SimulatedChannel", "SlavePassivity", "TdpaParams", "ToolCommand",
    "compute_port_energy",
]
