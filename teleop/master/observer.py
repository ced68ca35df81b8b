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
(wrist, unwrapped); rates m/s, rad/s.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

HISTORY = 256  # the SYNC counter's range


@njit(cache=True)
def _predict(x, qd, u_old, u_cmd, bias, vmax, amax, dt, window, tau):
    """Compiled twin of :meth:`JointObserver.predict` (returns x, qd_model, u_new: new arrays)."""
    n = x.shape[0]
    u_new = np.empty(n)
    for i in range(n):
        u_new[i] = min(max(u_cmd[i], -vmax[i]), vmax[i])
    x, qd = x.copy(), qd.copy()
    qd_new = np.empty(n)
    for part in range(2):
        u = u_old if part == 0 else u_new
        h = window if part == 0 else dt - window
        e = math.exp(-h / tau)
        ramp = False
        for i in range(n):
            qd_new[i] = u[i] + (qd[i] - u[i]) * e
            ramp = ramp or abs(qd_new[i] - qd[i]) > amax[i] * h
        for i in range(n):
            if ramp:  # acceleration-limited: a ramp
                dv = amax[i] * h
                q1 = qd[i] + min(max(qd_new[i] - qd[i], -dv), dv)
                x[i] += 0.5 * (qd[i] + q1) * h
                qd[i] = q1
            else:
                x[i] += u[i] * h + (qd[i] - u[i]) * (tau * (1.0 - e))
                qd[i] = qd_new[i]
    for i in range(n):
        x[i] += bias[i] * dt
    return x, qd, u_new


@njit(cache=True)
def _correct(history, x, bias, y, j, k, alpha, beta, dt):
    """Compiled twin of :meth:`JointObserver.correct`: history (HISTORY, n) in place; returns the
    new x and bias."""
    H, n = history.shape
    lag = (k - j) % H
    jj = j % H
    x, bias = x.copy(), bias.copy()
    for i in range(n):
        r = y[i] - history[jj, i]
        dx, db = alpha * r, (beta / dt) * r
        for m in range(1, lag + 1):
            history[(j + m) % H, i] += dx + m * dt * db
        x[i] += dx + db * (lag * dt)
        bias[i] += db
    return x, bias


class JointObserver:
    """Estimate of the 6 joints at each SYNC and of their rates (see the module docstring)."""

    def __init__(self, joints0, dt_s: float, tau_s: float, read_window_s: float, vmax, amax,
                 bandwidth_hz: float = 20.0, compiled: bool = True):
        self.compiled = compiled  # False: the numpy reference below (the kernels are tested against it)
        self.dt, self.tau, self.window = float(dt_s), float(tau_s), float(read_window_s)
        r = math.exp(-2.0 * math.pi * bandwidth_hz * self.dt)
        self.alpha, self.beta = 1.0 - r * r, (1.0 - r) ** 2
        self.vmax, self.amax = np.asarray(vmax, dtype=float), np.asarray(amax, dtype=float)
        self.reset(joints0)

    def reset(self, joints0) -> None:
        self.x = np.array(joints0, dtype=float)  # estimate at the last SYNC
        self.qd_model = np.zeros(6)  # servo-model rate at the last SYNC
        self.bias = np.zeros(6)
        self.u = np.zeros(6)  # the command in force
        self.history = np.tile(self.x, (HISTORY, 1))  # estimate (before correction) per SYNC counter

    @property
    def rates(self) -> np.ndarray:
        """Estimated joint rates (6,) at the last SYNC: servo model plus the encoders' correction."""
        return self.qd_model + self.bias

    def correct(self, y, j: int, k: int) -> None:
        """Fuse an encoder reading y (6,) sampled at SYNC counter j (0..255) into the estimate
        for SYNC k. A late reading (j before k) corrects the estimates of SYNC j+1..k as well, so
        a later reading is compared with the corrected trajectory and no error counts twice."""
        if self.compiled:
            self.x, self.bias = _correct(self.history, self.x, self.bias, np.asarray(y, dtype=float), j, k,
                                         self.alpha, self.beta, self.dt)
            return
        n = (k - j) % HISTORY
        r = y - self.history[j % HISTORY]
        dx = self.alpha * r
        db = (self.beta / self.dt) * r
        if n:
            later = np.arange(1, n + 1)
            self.history[(j + later) % HISTORY] += dx + np.outer(later * self.dt, db)
        self.x = self.x + dx + db * (n * self.dt)
        self.bias = self.bias + db

    def predict(self, k: int, qd_cmd) -> None:
        """Advance from SYNC k to SYNC k + 1 with the command qd_cmd (6,) sent ``read_window_s``
        after SYNC k (the device clips it to vmax)."""
        if self.compiled:
            self.x, self.qd_model, self.u = _predict(self.x, self.qd_model, self.u, np.asarray(qd_cmd, dtype=float),
                                                     self.bias, self.vmax, self.amax, self.dt, self.window, self.tau)
            self.history[(k + 1) % HISTORY] = self.x
            return
        u_new = np.clip(qd_cmd, -self.vmax, self.vmax)
        x, qd = self.x, self.qd_model
        for u, h in ((self.u, self.window), (u_new, self.dt - self.window)):
            e = math.exp(-h / self.tau)
            qd_new = u + (qd - u) * e
            dv_max = self.amax * h
            if np.any(np.abs(qd_new - qd) > dv_max):  # acceleration-limited: a ramp
                qd_new = qd + np.clip(qd_new - qd, -dv_max, dv_max)
                x = x + 0.5 * (qd + qd_new) * h
            else:
                x = x + u * h + (qd - u) * (self.tau * (1.0 - e))
            qd = qd_new
        self.x = x + self.bias * self.dt
        self.qd_model, self.u = qd, u_new
        self.history[(k + 1) % HISTORY] = self.x
