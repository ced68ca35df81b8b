"""CAN fault confinement (ISO 11898-1, 12.1.4): a node's transmit and receive error counters and
the state they put it in. No single error frame latches anything; the counters do:

* a transmit error adds 8 to TEC, a receive error adds 1 to REC (a receiver that detects the
  error first, with its own error flag, adds 8; a host that only sees error frames counts 1);
* a frame sent without error takes 1 off TEC, a frame received without error takes 1 off REC
  (from above 127 REC drops back to 127, within the 119..127 the standard allows);
* error-active while TEC and REC are both below 128; error-passive at 128 or more on either;
  bus-off when TEC reaches 256 (recovery, 128 x 11 recessive bits, is a restart: not modelled).

A controller that reports its own counters (SocketCAN error frames with ``CAN_ERR_CNT``: TEC in
data[6], REC in data[7]) overrides the count: :meth:`ErrorCounters.set`.
"""

from __future__ import annotations

ERROR_ACTIVE, ERROR_PASSIVE, BUS_OFF = "error_active", "error_passive", "bus_off"
PASSIVE_LIMIT, BUS_OFF_LIMIT = 128, 256


class ErrorCounters:
    """TEC and REC of one node and its state (see the module docstring)."""

    def __init__(self):
        self.tec = self.rec = 0

    @property
    def state(self) -> str:
        if self.tec >= BUS_OFF_LIMIT:
            return BUS_OFF
        if self.tec >= PASSIVE_LIMIT or self.rec >= PASSIVE_LIMIT:
            return ERROR_PASSIVE
        return ERROR_ACTIVE

    def tx_error(self) -> str:
        if self.state != BUS_OFF:
            self.tec = min(self.tec + 8, BUS_OFF_LIMIT)
        return self.state

    def rx_error(self, first_to_flag: bool = False) -> str:
        if self.state != BUS_OFF:
            self.rec += 8 if first_to_flag else 1
        return self.state

    def tx_ok(self) -> None:
        if self.state != BUS_OFF and self.tec > 0:
            self.tec -= 1

    def rx_ok(self) -> None:
        if self.rec > 127:
            self.rec = 127
        elif self.rec > 0:
            self.rec -= 1

    def set(self, tec: int, rec: int) -> str:
        """The controller's own counters (0..255 each; a bus-off controller reports it with the
        bus-off flag, :meth:`bus_off`)."""
        if self.state != BUS_OFF:
            self.tec, self.rec = int(tec), int(rec)
        return self.state

    def bus_off(self) -> str:
        self.tec = BUS_OFF_LIMIT
        return self.state
