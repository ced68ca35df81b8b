"""CobotConfig: every setting of the simulated cobot master, validated on creation (SI units).

The rules sit beside each field (teleop.util.typed.setting); ``teleop.util.typed.validate`` checks a scene's
``[cobot]`` table against them, and ``CobotConfig(...)`` built from Python checks the same rules.
"""

from __future__ import annotations

from dataclasses import dataclass

from teleop.can.faults import Faults
from teleop.util.errors import FieldError
from teleop.util.typed import Checked, setting, validate

Vec = tuple[float, ...]


def _fd_only(fd: bool) -> str | None:
    return None if fd else ("the 1 kHz cycle needs CAN FD; classic CAN at 1 Mbit/s is 87.5 % loaded with "
                            "worst-case stuffing (robots/cobot/README.md)")


@dataclass(frozen=True)
class FaultSettings(Checked, Faults):
    """CAN faults the simulated device injects (the scene's ``[cobot.faults]``): see teleop.can.faults."""

    loss_pct: float = setting(0.0, ge=0.0, le=100.0, doc="% of frames dropped")
    latency_ms: float = setting(0.0, ge=0.0, le=1000.0, doc="ms added to every device frame")
    jitter_ms: float = setting(0.0, ge=0.0, le=1000.0, doc="ms, uniform extra delay in [0, jitter]")
    corrupt_pct: float = setting(0.0, ge=0.0, le=100.0, doc="% of frames with one payload bit flipped")
    silent_after_s: float | None = setting(None, ge=0.0, doc="s after which the device stops sending")
    bus_off_at_s: float | None = setting(None, ge=0.0, doc="s at which the device goes bus-off")


@dataclass(frozen=True)
class CobotConfig(Checked):
    """Settings of :class:`teleop.master.CobotMaster`; ``CobotConfig()`` gives defaults."""

    scale: float = setting(1.0, gt=0.0, le=100.0, doc="motion scale s: p_V = offset + s R_off p_H")
    offset_m: Vec = setting((0.0, 0.0, 0.0), n=3, doc="phi position offset, m")
    offset_rotvec_rad: Vec = setting((0.0, 0.0, 0.0), n=3, doc="phi rotation offset as a rotation vector, rad")
    kp: Vec = setting(40000.0, n=6, broadcast=True, ge=0.0, doc="1/s^2, scalar or 6-vector (x y z, rx ry rz)")
    ki: Vec = setting(400000.0, n=6, broadcast=True, ge=0.0, doc="1/s^3")
    kd: Vec = setting(400.0, n=6, broadcast=True, ge=0.0, doc="1/s")
    integral_limit: Vec = setting(2e-6, n=6, broadcast=True, ge=0.0,
                                  doc="anti-windup clamp of the error integral, m*s / rad*s")
    servo_bandwidth_hz: float = setting(200.0, gt=0.0, le=1e4, doc="velocity servo bandwidth (first-order lag), Hz")
    max_velocity: Vec = setting((0.5, 0.5, 0.5, 10.0, 10.0, 10.0), n=6, broadcast=True, gt=0.0,
                                doc="joint velocity limits, m/s, rad/s")
    max_acceleration: Vec = setting((20.0, 20.0, 20.0, 400.0, 400.0, 400.0), n=6, broadcast=True, gt=0.0,
                                    doc="m/s^2, rad/s^2")
    encoder_m: float = setting(25e-6, gt=0.0, le=1e-2, doc="gantry encoder resolution, m (the paper's 25 um)")
    encoder_rad: float = setting(5e-4, gt=0.0, le=1e-2, doc="wrist encoder resolution, rad")
    force_noise_N: float = setting(0.02, ge=0.0, le=10.0, doc="load-cell noise std, N")
    torque_noise_Nm: float = setting(0.0005, ge=0.0, le=10.0, doc="load-cell noise std, N*m")
    force_bias_N: Vec = setting((0.05, -0.03, 0.08), n=3, doc="load-cell bias, N (removed by the start-up tare)")
    torque_bias_Nm: Vec = setting((0.001, -0.0005, 0.0), n=3, doc="N*m")
    #: the fastest a load-cell reading can change, per axis (N/s x3, N*m/s x3). The host refuses a
    #: reading that changed by more than this times the time since the last applied one, plus six
    #: noise deviations and two quanta of the wire (``wrench_jump``, the last reading kept; 50 N
    #: and 3 N*m a SYNC at 1 kHz). Forces: the fastest wrench a hand puts on a handle is an impact,
    #: whose force rises at the contact's stiffness times the closing speed: a palm (about 25
    #: kN/m once compressed) striking at 2 m/s gives 50 kN/s; a voluntary push builds at most a
    #: tenth of that (a few kN/s), and the handle's own inertia adds its mass times the servos'
    #: jerk (0.15 kg x 20 m/s^2 / 0.8 ms = 3.75 kN/s). Torques: that force rate at the middle of
    #: the 120 mm grip (60 mm from the load cell): 3 kN*m/s. So 0 to the cell's 160 N takes 4
    #: SYNCs at 1 kHz, and a one-SYNC jump to full scale is refused.
    wrench_rate_max: Vec = setting((50_000.0,) * 3 + (3_000.0,) * 3, n=6, broadcast=True, gt=0.0,
                                   doc="fastest load-cell change (plausibility check), N/s x3, N*m/s x3")
    max_force_N: float = setting(100.0, gt=0.0, le=1e3, doc="saturation of the sensed hand force, N")
    max_torque_Nm: float = setting(5.0, gt=0.0, le=1e3, doc="saturation of the sensed hand torque, N*m")
    workspace_margin_m: float = setting(0.005, ge=0.0, le=10.0,
                                        doc="commands stop this close to a travel limit, m / rad")
    fd: bool = setting(True, check=_fd_only, doc="CAN FD (the 1 kHz cycle needs it; classic CAN does not fit 60 %)")
    bitrate_bps: float = setting(1_000_000.0, gt=0.0, le=20e6, doc="nominal bit rate, bit/s")
    data_bitrate_bps: float = setting(5_000_000.0, gt=0.0, le=20e6, doc="CAN FD data-phase bit rate, bit/s")
    #: python-can interface of the host bus. The simulated ones (SIMULATED_INTERFACES) put the
    #: simulated device on the same channel: "teleop_lockstep" (teleop.can.lockstep, the default)
    #: or python-can's "virtual"; any other name is real hardware, driven without the simulator.
    interface: str = setting("teleop_lockstep", check=lambda s: None if s else "expected a python-can interface name",
                             doc="python-can interface of the host bus")
    channel: str | None = setting(None, doc="python-can channel; none: a fresh private channel")
    read_window_s: float = setting(3e-4, gt=0.0, le=10.0, doc="host reads feedback this long after SYNC, s")
    stale_cycles: int = setting(3, ge=1, le=10000, doc="cycles without fresh feedback that trip the watchdog")
    #: |q_r - q_v| that latches the fault "tracking_error" (the device has lost the reference tool:
    #: zero velocity, the tool held), m and rad in the virtual tool's space
    tracking_fault_m: float = setting(0.02, gt=0.0, le=100.0, doc="tracking fault threshold, m")
    tracking_fault_rad: float = setting(0.35, gt=0.0, le=100.0, doc="tracking fault threshold, rad")
    heartbeat_period_s: float = setting(0.01, gt=0.0, le=10.0, doc="host and device heartbeat period, s")
    heartbeat_timeout_s: float = setting(0.05, gt=0.0, le=10.0, doc="device heartbeat timeout at the host, s")
    tare_cycles: int = setting(20, ge=1, le=10000, doc="start-up cycles averaged to tare the load cell")
    free_damping: Vec = setting((20.0, 20.0, 20.0, 1.0, 1.0, 1.0), n=6, broadcast=True, gt=0.0,
                                doc="clutch-released admittance, N*s/m, N*m*s/rad")
    capture_path: str | None = setting(None, doc="record the wire to .log / .asc / .blf")
    realtime: bool = setting(False, doc="pace step() to the wall clock")
    observer_bandwidth_hz: float = setting(20.0, gt=0.0, le=100.0, doc="joint observer bandwidth, Hz")
    #: how the host removes the handle's inertia from the load cell: "servo_model", the servo
    #: model's acceleration at the reading's SYNC (renders tools lighter than the handle, issue 15);
    #: "commanded", the acceleration commanded the period before
    inertia_compensation: str = setting("servo_model", check=lambda s: None if s in ("servo_model", "commanded") else
                                        "expected 'servo_model' or 'commanded'",
                                        doc="handle inertia compensation: 'servo_model' or 'commanded'")
    faults: FaultSettings = setting(factory=FaultSettings, doc="CAN faults of the simulated device")

    def __post_init__(self):
        super().__post_init__()
        if self.heartbeat_timeout_s <= self.heartbeat_period_s:
            raise FieldError("heartbeat_timeout_s", "must exceed heartbeat_period_s")

    @classmethod
    def from_dict(cls, d: dict, where: str = "cobot") -> CobotConfig:
        """Build from a plain table through the one validator (errors name ``where.key``)."""
        return validate(cls, d, "", where)
