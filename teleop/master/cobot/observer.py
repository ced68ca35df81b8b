"""Joint observer: the cobot's joint rates from its quantized, possibly late encoders.

The encoders resolve 25 µm (gantry) and 0.5 mrad (wrist) and are sampled on SYNC, once per period:
differentiating them gives rates in steps of 25 mm/s. The observer is model-aided, a steady-state
Kalman filter of the alpha-beta family per joint:

* predict: the host knows the velocity u it commands; the servo model (first-order lag tau, the
  device's velocity and acceleration limits, the old command until the new one is sent
  ``read_window_s`` after SYNC) turns it into the joint rate qd_m, integrated exactly over the
  period; a rate bias b (m/s, rad/s) carries what the model misses (a real servo, a hard stop, a
  lost command frame): x += motion of qd_m + b dt.
* correct: a reading y taken at SYNC j is compared with the estimate the observer had for that
  same SYNC (kept per counter); with the innovation r = y - x_j, x += alpha r and
  b += (beta / dt) r. A late reading (j before k) moves the estimates of SYNC j+1..k as well (by
  the bias correction over the periods since j), so a later reading is compared with the
  corrected trajectory and no error counts twice.

The rate estimate is qd_m + b. Gains: critically damped at ``bandwidth_hz``
(r = exp(-2 pi f dt): alpha = 1 - r^2, beta = (1 - r)^2). Units: joints m x3 (gantry), rad x3
(wrist, unwrapped); rates m/s, rad/s. The arithmetic is in :mod:`.kernels` (``predict_kernel``,
``correct_kernel``); the host's fused command kernel runs the prediction on this object's state.
"""

from __future__ import annotations

import math

import numpy as np

from teleop.master.cobot.kernels import HISTORY, correct_kernel, predict_kernel
from teleop.util.views import view


class JointObserver:
    """Estimate of the 6 joints at each SYNC and of their rates (see the module docstring).

    dt_s: period, s; tau_s: servo lag, s; read_window_s: delay of the command after SYNC, s;
    vmax (6,), amax (6,): the servos' velocity and acceleration limits; bandwidth_hz: the filter's.
    state (4, 6), history (HISTORY, 6): where to keep the estimate (rows x, qd_model, u, bias) and
    the estimates per SYNC counter, written in place (the host passes views of its state record,
    which its compiled period updates); None: the observer's own arrays.
    """

    def __init__(self, joints0, dt_s: float, tau_s: float, read_window_s: float, vmax, amax,
                 bandwidth_hz: float = 20.0, state=None, history=None):
        self.dt, self.tau, self.window = float(dt_s), float(tau_s), float(read_window_s)
        r = math.exp(-2.0 * math.pi * bandwidth_hz * self.dt)
        self.alpha, self.beta = 1.0 - r * r, (1.0 - r) ** 2
        self.vmax, self.amax = np.asarray(vmax, dtype=float), np.asarray(amax, dtype=float)
        self.state = np.zeros((4, 6)) if state is None else state
        self.history = np.zeros((HISTORY, 6)) if history is None else history
        self.reset(joints0)

    # the estimate's rows, read as views and assigned in place
    x = view("state", 0, "estimate (6,) at the last SYNC")
    qd_model = view("state", 1, "servo-model rate (6,) at the last SYNC")
    u = view("state", 2, "the command in force (6,)")
    bias = view("state", 3, "rate bias (6,)")

    def reset(self, joints0) -> None:
        self.state[:] = 0.0
        self.x = np.asarray(joints0, dtype=float)
        self.history[:] = self.x  # estimate (before correction) per SYNC counter

    @property
    def rates(self) -> np.ndarray:
        """Estimated joint rates (6,) at the last SYNC: servo model plus the encoders' correction."""
        return self.qd_model + self.bias

    def correct(self, y, j: int, k: int) -> None:
        """Fuse an encoder reading y (6,) sampled at SYNC counter j (0..255) into the estimate
        for SYNC k. A late reading (j before k) corrects the estimates of SYNC j+1..k as well, so
        a later reading is compared with the corrected trajectory and no error counts twice."""
        self.x, self.bias = correct_kernel(self.history, self.x, self.bias, np.asarray(y, dtype=float), j, k,
                                           self.alpha, self.beta, self.dt)

    def predict(self, k: int, qd_cmd) -> None:
        """Advance from SYNC k to SYNC k + 1 with the command qd_cmd (6,) sent ``read_window_s``
        after SYNC k (the device clips it to vmax)."""
        self.x, self.qd_model, self.u = predict_kernel(self.x, self.qd_model, self.u, np.asarray(qd_cmd, dtype=float),
                                                       self.bias, self.vmax, self.amax, self.dt, self.window, self.tau)
        self.history[(k + 1) % HISTORY] = self.x
