"""Link faults the simulator injects, as one frozen settings record.

loss and corruption act on both directions (a lost frame never reaches the wire; a corrupted one
arrives with a flipped payload bit, caught by the checksum); latency and jitter delay the device's
frames on their way to the host (a slow adapter or gateway); ``silent_after_s`` mutes the device;
``bus_off_at_s`` makes every transmission of the device fail from then on: 32 error frames (its
TEC to 256, :mod:`teleop.can.confinement`), then it is bus-off and silent.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from teleop.util.errors import ConfigError, check_table


@dataclass(frozen=True)
class Faults:
    loss_pct: float = 0.0  #: % of frames dropped
    latency_ms: float = 0.0  #: ms added to every device frame
    jitter_ms: float = 0.0  #: ms, uniform extra delay in [0, jitter]
    corrupt_pct: float = 0.0  #: % of frames with one payload bit flipped
    silent_after_s: float | None = None  #: s of simulated time after which the device stops sending
    bus_off_at_s: float | None = None  #: s of simulated time at which the device goes bus-off

    def __post_init__(self):
        self._check("loss_pct", 0.0, 100.0)
        self._check("corrupt_pct", 0.0, 100.0)
        self._check("latency_ms", 0.0, 1000.0)
        self._check("jitter_ms", 0.0, 1000.0)
        for key in ("silent_after_s", "bus_off_at_s"):
            v = getattr(self, key)
            if v is not None:
                self._check(key, 0.0, math.inf)

    def _check(self, key: str, lo: float, hi: float, where: str = "faults") -> None:
        v = getattr(self, key)
        try:
            v = float(v)
        except (TypeError, ValueError):
            raise ConfigError(f"{where}.{key}: expected a number, got {v!r}") from None
        if not (lo <= v <= hi) or math.isnan(v):
            raise ConfigError(f"{where}.{key}: expected a value in [{lo}, {hi}], got {v}")
        object.__setattr__(self, key, v)

    @classmethod
    def from_dict(cls, d: dict, where: str = "faults") -> Faults:
        check_table(d, where, {f.name for f in fields(cls)}, "fault", "a table of fault settings")
        try:
            return cls(**d)
        except ConfigError as e:
            raise ConfigError(str(e).replace("faults.", f"{where}.", 1)) from None

    @property
    def any(self) -> bool:
        return bool(self.loss_pct or self.latency_ms or self.jitter_ms or self.corrupt_pct
                    or self.silent_after_s is not None or self.bus_off_at_s is not None)
