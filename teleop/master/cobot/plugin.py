"""The simulated cobot as a python-can interface plugin: ``can.Bus(interface="teleop_cobot")``.

Registered under python-can's ``can.interface`` entry-point group (pyproject.toml), so any
python-can program, ``python -m can.viewer`` included, can talk to the virtual device as it would
to an adapter with the real one behind it. The plant (:mod:`teleop.master.cobot.plant`) and its link
(:class:`~teleop.master.cobot.simulator.CobotSimulator`: bus timing, faults, heartbeats, timeouts) run in
simulated time, which advances only while the caller waits: each ``recv`` that finds no frame
advances the device by ``step_s`` (s) and looks again, so a lockstep host stays deterministic.
Frame timestamps are simulated seconds. The bus reports CAN FD (``bus.protocol`` is
``can.CanProtocol.CAN_FD``): every frame of the protocol is a CAN FD frame.
"""

from __future__ import annotations

import uuid

import can
import numpy as np

from teleop.master.cobot.model import CobotModel
from teleop.master.cobot.plant import CobotPlant, DeviceParams
from teleop.master.cobot.simulator import CobotSimulator
from teleop.master.config import FaultSettings
from teleop.util.errors import ConfigError, FieldError
from teleop.util.typed import build


class CobotBus(can.BusABC):
    """channel: a name (cosmetic); seed: RNG seed of the device's sensor noise; step_s: simulated
    time (s) one empty poll advances; joints0 (6,): the start joints (m x3, rad x3); faults: a
    :class:`~teleop.can.faults.Faults` or a table of fault settings."""

    def __init__(self, channel=None, seed: int = 0, step_s: float = 1e-4, joints0=None, faults=None,
                 **kwargs):
        if isinstance(faults, dict):  # the one validator (teleop.util.typed), as for a scene's [cobot.faults]
            try:
                faults = build(FaultSettings, faults, "faults")
            except FieldError as e:
                raise ConfigError(f"{e.key}: {e.reason}") from None
        self.step_s = float(step_s)
        private = f"teleop-cobot-plugin-{uuid.uuid4().hex}"
        self._host = can.Bus(interface="virtual", channel=private, fd=True, preserve_timestamps=True)
        self._device_bus = can.Bus(interface="virtual", channel=private, fd=True, preserve_timestamps=True)
        rng = np.random.default_rng(seed)
        joints0 = np.array([0.0, 0.0, 0.0, 0.0, np.pi / 2, 0.0] if joints0 is None else joints0, dtype=float)
        self.plant = CobotPlant(CobotModel(), DeviceParams(), joints0, rng)
        self.sim = CobotSimulator(self._device_bus, self.plant, rng, faults=faults)
        self.t = 0.0
        self.channel_info = f"teleop simulated cobot {channel or private}"
        kwargs.pop("fd", None)  # always CAN FD
        super().__init__(channel=channel, **kwargs)
        self._can_protocol = can.CanProtocol.CAN_FD

    def send(self, msg: can.Message, timeout=None) -> None:
        """Put a host frame on the simulated wire at the current simulated time."""
        self._host.send(can.Message(timestamp=self.t, arbitration_id=msg.arbitration_id, data=msg.data,
                                    is_extended_id=msg.is_extended_id, is_fd=msg.is_fd,
                                    bitrate_switch=msg.bitrate_switch, dlc=msg.dlc))

    def _recv_internal(self, timeout):
        msg = self._host.recv(timeout=0.0)
        if msg is None:
            self.t += self.step_s
            self.sim.advance_to(self.t)
            msg = self._host.recv(timeout=0.0)
        return msg, False

    def shutdown(self) -> None:
        super().shutdown()
        self._host.shutdown()
        self._device_bus.shutdown()
