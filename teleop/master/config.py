"""CobotConfig: every setting of the simulated cobot master, validated on creation (SI units)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

from teleop.can.faults import Faults
from teleop.errors import ConfigError, check_table

PREFIX = "cobot"


def _num(v, key, lo=-math.inf, hi=math.inf, lo_open=False):
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise ConfigError(f"{PREFIX}.{key}: expected a number, got {v!r}") from None
    if math.isnan(x) or x < lo or x > hi or (lo_open and x == lo):
        raise ConfigError(f"{PREFIX}.{key}: expected a value in {'(' if lo_open else '['}{lo}, {hi}], got {x}")
    return x


def _vec(v, key, n, lo=-math.inf, positive=False):
    a = np.asarray(v, dtype=float) if not isinstance(v, str) else np.array([np.nan])
    if a.ndim == 0:
        a = np.full(n, float(a))
    if a.shape != (n,) or not np.all(np.isfinite(a)) or np.any(a < lo) or (positive and np.any(a <= 0)):
        raise ConfigError(f"{PREFIX}.{key}: expected {'a positive' if positive else 'a'} scalar or {n} finite values, got {v!r}")
    return tuple(float(x) for x in a)


@dataclass(frozen=True)
class CobotConfig:
    """Settings of :class:`teleop.master.CobotMaster`; ``from_dict({}, "master")`` gives defaults."""

    scale: float = 1.0  #: motion scale s: p_V = offset + s R_off p_H
    offset_m: tuple = (0.0, 0.0, 0.0)  #: φ position offset, m
    offset_rotvec_rad: tuple = (0.0, 0.0, 0.0)  #: φ rotation offset as a rotation vector, rad
    kp: object = 40000.0  #: 1/s^2, scalar or 6-vector (x y z, rx ry rz)
    ki: object = 400000.0  #: 1/s^3
    kd: object = 400.0  #: 1/s
    integral_limit: object = 2e-6  #: anti-windup clamp of the error integral, m*s / rad*s
    servo_bandwidth_hz: float = 200.0  #: velocity servo bandwidth (first-order lag), Hz
    max_velocity: tuple = (0.5, 0.5, 0.5, 10.0, 10.0, 10.0)  #: joint velocity limits, m/s, rad/s
    max_acceleration: tuple = (20.0, 20.0, 20.0, 400.0, 400.0, 400.0)  #: m/s^2, rad/s^2
    encoder_m: float = 25e-6  #: gantry encoder resolution, m (the paper's 25 um)
    encoder_rad: float = 5e-4  #: wrist encoder resolution, rad (25 um of arc at 50 mm)
    force_noise_N: float = 0.02  #: load-cell noise std, N
    torque_noise_Nm: float = 0.0005  #: load-cell noise std, N*m
    force_bias_N: tuple = (0.05, -0.03, 0.08)  #: load-cell bias, N (removed by the start-up tare)
    torque_bias_Nm: tuple = (0.001, -0.0005, 0.0)  #: N*m
    max_force_N: float = 100.0  #: saturation of the sensed hand force, N
    max_torque_Nm: float = 5.0  #: saturation of the sensed hand torque, N*m
    workspace_margin_m: float = 0.005  #: commands into a travel limit stop this close to it, m / rad
    fd: bool = True  #: CAN FD (the 1 kHz cycle needs it; classic CAN does not fit 60 %)
    bitrate_bps: float = 1_000_000.0  #: nominal bit rate, bit/s
    data_bitrate_bps: float = 5_000_000.0  #: CAN FD data-phase bit rate, bit/s
    #: python-can interface of the host bus. The simulated ones (SIMULATED_INTERFACES) put the
    #: simulated device on the same channel: "teleop_lockstep" (teleop.can.lockstep, the default)
    #: or python-can's "virtual"; any other name is real hardware, driven without the simulator.
    interface: str = "teleop_lockstep"
    channel: str | None = None  #: python-can channel; None: a fresh private channel
    read_window_s: float = 3e-4  #: host reads feedback and sends commands this long after SYNC, s
    stale_cycles: int = 3  #: cycles without fresh feedback that trip the watchdog
    #: |q_r - q_v| that latches the fault "tracking_error" (the device has lost the reference tool:
    #: zero velocity, the tool held), m and rad in the virtual tool's space
    tracking_fault_m: float = 0.02
    tracking_fault_rad: float = 0.35
    heartbeat_period_s: float = 0.01  #: host and device heartbeat period, s
    heartbeat_timeout_s: float = 0.05  #: device heartbeat timeout at the host, s
    tare_cycles: int = 20  #: start-up cycles averaged to tare the load cell
    free_damping: tuple = (20.0, 20.0, 20.0, 1.0, 1.0, 1.0)  #: clutch-released admittance, N*s/m, N*m*s/rad
    capture_path: str | None = None  #: record the wire to .log / .asc / .blf
    realtime: bool = False  #: pace step() to the wall clock
    observer_bandwidth_hz: float = 20.0  #: joint observer bandwidth (teleop/master/observer.py), Hz
    faults: Faults = field(default_factory=Faults)

    def __post_init__(self):
        s = object.__setattr__
        s(self, "scale", _num(self.scale, "scale", 0.0, 100.0, lo_open=True))
        for key, n in (("offset_m", 3), ("offset_rotvec_rad", 3), ("force_bias_N", 3), ("torque_bias_Nm", 3)):
            s(self, key, _vec(getattr(self, key), key, n))
        for key in ("kp", "ki", "kd", "integral_limit"):
            s(self, key, _vec(getattr(self, key), key, 6, lo=0.0))
        for key in ("max_velocity", "max_acceleration", "free_damping"):
            s(self, key, _vec(getattr(self, key), key, 6, positive=True))
        s(self, "servo_bandwidth_hz", _num(self.servo_bandwidth_hz, "servo_bandwidth_hz", 0.0, 1e4, lo_open=True))
        for key in ("encoder_m", "encoder_rad"):
            s(self, key, _num(getattr(self, key), key, 0.0, 1e-2, lo_open=True))
        for key in ("tracking_fault_m", "tracking_fault_rad"):
            s(self, key, _num(getattr(self, key), key, 0.0, 100.0, lo_open=True))
        for key in ("force_noise_N", "torque_noise_Nm", "workspace_margin_m"):
            s(self, key, _num(getattr(self, key), key, 0.0, 10.0))
        for key in ("max_force_N", "max_torque_Nm"):
            s(self, key, _num(getattr(self, key), key, 0.0, 1e3, lo_open=True))
        s(self, "observer_bandwidth_hz", _num(self.observer_bandwidth_hz, "observer_bandwidth_hz", 0.0,
                                              100.0, lo_open=True))
        for key in ("bitrate_bps", "data_bitrate_bps"):
            s(self, key, _num(getattr(self, key), key, 0.0, 20e6, lo_open=True))
        for key in ("read_window_s", "heartbeat_period_s", "heartbeat_timeout_s"):
            s(self, key, _num(getattr(self, key), key, 0.0, 10.0, lo_open=True))
        for key in ("stale_cycles", "tare_cycles"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v <= 10000:
                raise ConfigError(f"{PREFIX}.{key}: expected an integer in [1, 10000], got {v!r}")
        for key in ("fd", "realtime"):
            if not isinstance(getattr(self, key), bool):
                raise ConfigError(f"{PREFIX}.{key}: expected true or false, got {getattr(self, key)!r}")
        if not self.fd:
            raise ConfigError(f"{PREFIX}.fd: the 1 kHz cycle needs CAN FD; classic CAN at 1 Mbit/s is "
                              "87.5 % loaded with worst-case stuffing (robots/cobot/README.md)")
        if not isinstance(self.interface, str) or not self.interface:
            raise ConfigError(f"{PREFIX}.interface: expected a python-can interface name, got {self.interface!r}")
        if self.capture_path is not None and not isinstance(self.capture_path, str):
            raise ConfigError(f"{PREFIX}.capture_path: expected a file path or none, got {self.capture_path!r}")
        if self.heartbeat_timeout_s <= self.heartbeat_period_s:
            raise ConfigError(f"{PREFIX}.heartbeat_timeout_s: must exceed heartbeat_period_s")
        if isinstance(self.faults, dict):
            s(self, "faults", Faults.from_dict(self.faults, f"{PREFIX}.faults"))
        elif not isinstance(self.faults, Faults):
            raise ConfigError(f"{PREFIX}.faults: expected a table of fault settings")

    @classmethod
    def from_dict(cls, d: dict, where: str = "cobot") -> "CobotConfig":
        """Build from a scene's table; unknown keys and bad values raise ConfigError naming
        ``f"{where}.{key}"`` and the reason."""
        check_table(d, where, {f.name for f in fields(cls)}, "setting")
        kw = dict(d)
        if "faults" in kw:
            kw["faults"] = Faults.from_dict(kw["faults"], f"{where}.faults")
        try:
            return cls(**kw)
        except ConfigError as e:
            msg = str(e)
            raise ConfigError(where + msg[len(PREFIX):] if msg.startswith(PREFIX + ".") else msg) from None
