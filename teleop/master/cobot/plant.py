"""The simulated cobot: the physical device in simulated time, on the device's side of the bus.

Velocity servos with a first-order lag and velocity, acceleration and travel limits; quantized
encoders; a noisy, biased load cell that reads the hand's wrench plus the distal handle's weight
and inertia. Only the device simulator (:mod:`.simulator`) drives it; the host never sees it.
SI units: m, rad, N, N*m, s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from teleop.master.cobot.kernels import distal_wrench_H, servo_acceleration, servo_advance
from teleop.master.cobot.model import GRAVITY_W, CobotModel, compute_servo_lag_s


@dataclass(frozen=True)
class DeviceParams:
    """Servo, encoder and load-cell settings (SI)."""

    servo_bandwidth_hz: float = 200.0  #: first-order velocity-loop bandwidth, Hz
    max_velocity: tuple = (0.5, 0.5, 0.5, 10.0, 10.0, 10.0)  #: m/s x3, rad/s x3
    max_acceleration: tuple = (20.0, 20.0, 20.0, 400.0, 400.0, 400.0)  #: m/s^2 x3, rad/s^2 x3
    encoder_m: float = 25e-6  #: gantry encoder resolution, m
    encoder_rad: float = 5e-4  #: wrist resolution, rad (25 um of arc at 50 mm)
    force_noise_N: float = 0.02  #: load-cell noise, std, N
    torque_noise_Nm: float = 0.0005  #: std, N*m
    force_bias_N: tuple = (0.05, -0.03, 0.08)  #: load-cell bias, N, load-cell frame
    torque_bias_Nm: tuple = (0.001, -0.0005, 0.0)  #: N*m


class CobotPlant:
    """The physical device (see the module docstring); ``hand_wrench_W`` (6,: N, N*m at H, world)
    is what the operator's hand puts on the handle."""

    def __init__(self, model: CobotModel, params: DeviceParams, joints0, rng: np.random.Generator):
        self.model, self.params, self.rng = model, params, rng
        self.tau_s = compute_servo_lag_s(params.servo_bandwidth_hz)
        self.vmax = np.array(params.max_velocity, dtype=float)
        self.amax = np.array(params.max_acceleration, dtype=float)
        self.res = np.array([params.encoder_m] * 3 + [params.encoder_rad] * 3)
        self.bias = np.array(list(params.force_bias_N) + list(params.torque_bias_Nm), dtype=float)
        self.noise = np.array([params.force_noise_N] * 3 + [params.torque_noise_Nm] * 3)
        self.joints = np.array(joints0, dtype=float)
        self.qd = np.zeros(6)
        self.qd_cmd = np.zeros(6)
        self.t = 0.0
        self.hand_wrench_W = np.zeros(6)

    def set_command(self, qd_cmd, t: float) -> None:
        """Velocity command (6,) taking effect at time t (s); clipped to the velocity limits."""
        self.advance_to(t)
        self.qd_cmd = np.clip(np.nan_to_num(np.asarray(qd_cmd, float)), -self.vmax, self.vmax)

    def advance_to(self, t: float) -> None:
        """Integrate the servos exactly (:func:`.kernels.servo_advance`) up to time t (s), then the
        hard stops."""
        h = t - self.t
        if h <= 0:
            return
        self.joints, self.qd = servo_advance(self.joints, self.qd, self.qd_cmd, h, self.tau_s, self.amax)
        hit = (self.joints < self.model.lower) | (self.joints > self.model.upper)
        if np.any(hit):
            self.joints = np.clip(self.joints, self.model.lower, self.model.upper)
            self.qd[hit] = 0.0
        self.t = t

    def joint_acceleration(self) -> np.ndarray:
        return servo_acceleration(self.qd_cmd, self.qd, self.tau_s, self.amax)

    def sample_encoders(self) -> np.ndarray:
        """Joint readings (6,): quantized, the wrist angles wrapped to [-pi, pi)."""
        counts = np.round(self.joints / self.res) * self.res
        counts[3:] = np.round(((counts[3:] + np.pi) % (2 * np.pi) - np.pi) / self.res[3:]) * self.res[3:]
        return counts

    def sample_load_cell(self) -> np.ndarray:
        """Load-cell wrench (6,: N, N*m) in the load-cell frame S = H: hand + distal handle mass,
        with bias and noise. The handle's acceleration comes from the servo state via Pinocchio."""
        m = self.model
        q = m.pin_q(self.joints)
        pin.forwardKinematics(m.model, m.data, q, self.qd, self.joint_acceleration())
        X = pin.updateFramePlacement(m.model, m.data, m.fid)
        R = X.rotation
        tw = pin.getFrameVelocity(m.model, m.data, m.fid, pin.LOCAL_WORLD_ALIGNED)
        a = pin.getFrameClassicalAcceleration(m.model, m.data, m.fid, pin.LOCAL_WORLD_ALIGNED)
        distal = distal_wrench_H(R, tw.angular, a.linear, a.angular, m.handle_mass_kg, m.handle_com_H,
                                 m.handle_J_H, GRAVITY_W)
        F = self.hand_wrench_W
        meas = np.concatenate([R.T @ F[:3], R.T @ F[3:]]) + distal
        return meas + self.bias + self.noise * self.rng.standard_normal(6)
