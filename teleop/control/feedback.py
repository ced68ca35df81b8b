"""The force-feedback path on the master side: the slave's contact wrench, mapped into the master
frame by the registration, then low-passed.

The cutting force is steep in velocity (about 2000 N*s/m below 1 mm/s); fed raw to a light
reference tool integrated explicitly with a one-tick delay it makes a limit cycle (tool and arm
chatter). A first-order low-pass at ``cutoff_hz`` (20 Hz by default) keeps the cut's feel and
removes it; 0 turns the filter off. A tick with no new message holds the last wrench.
"""

from __future__ import annotations

import math

import numpy as np

from teleop.control.mapping import Registration
from teleop.link.messages import ContactFeedback


class FeedbackPath:
    """``update(msg)`` -> the wrench (6,: N, N*m, master world, at the reference tool's origin)
    to add to the operator's at the next tool step."""

    def __init__(self, registration: Registration, cutoff_hz: float, dt_s: float):
        if not (math.isfinite(cutoff_hz) and cutoff_hz >= 0):
            raise ValueError(f"feedback cutoff: expected a number >= 0 Hz, got {cutoff_hz!r}")
        self.reg = registration
        self.alpha = 1.0 - math.exp(-2.0 * math.pi * cutoff_hz * dt_s) if cutoff_hz > 0 else 1.0
        self.wrench_M = np.zeros(6)
        self._target = np.zeros(6)

    def update(self, msg: ContactFeedback | None) -> np.ndarray:
        if msg is not None:
            self._target = self.reg.wrench_to_master(msg.wrench_P)
        self.wrench_M = self.wrench_M + self.alpha * (self._target - self.wrench_M)
        return self.wrench_M
