"""CobotMaster: the host controller of the cobot behind the master interface (sense / command).

A period, in lockstep simulated time: ``sense`` sends SYNC, lets the bus run to the read window,
reads the device's frames, corrects the joint observer and computes the load-cell wrench, its
distal handle mass removed, through φ (eq. 4); the caller steps the reference tool; ``command``
runs PID on q_r - q_v (eqs. 18-19), maps the acceleration back through φ and the device Jacobian
(damped least squares), puts joint velocities on the bus, and the bus runs to the period's end.

The host reaches the device only through the bus (:class:`.driver.CobotDriver`). On a simulated
interface the device's side is a :class:`.simulator.CobotSimulator` playing the plant; the host only
advances its clock (lockstep), lets the hand push its handle and reads the true handle for the
simulated hand (:meth:`CobotMaster.hand_state`). Late or lost feedback: each measurement carries the
SYNC counter it answers, and the host keeps the handle pose its own commands predict for every
cycle, so an old measurement is carried forward by the commanded motion since (a Smith-predictor
style estimate). A user with hardware changes ``interface`` and ``channel``.
"""

from __future__ import annotations

import logging
import time
import uuid

import can
import numpy as np
import pinocchio as pin

from teleop.can import BusTiming, Capture, compute_cycle_load_pct
from teleop.control.admittance import AdmittanceController, AdmittanceGains, Phi
from teleop.control.clutch import Clutch
from teleop.control.stability import LoopParams, critical_mass
from teleop.master.base import Master
from teleop.master.cobot.database import FrameDatabase
from teleop.master.cobot.driver import CobotDriver
from teleop.master.cobot.kernels import HOST_CONSTS, HOST_STATE, advance_prediction, host_command, host_sense
from teleop.master.cobot.model import GRAVITY_W, CobotModel, compute_servo_lag_s
from teleop.master.cobot.observer import JointObserver
from teleop.master.cobot.plant import CobotPlant, DeviceParams
from teleop.master.cobot.simulator import CobotSimulator
from teleop.master.config import CobotConfig
from teleop.util.errors import ConfigError

#: damped least squares: no damping above this smallest singular value, up to this damping at 0
DLS_SIGMA0, DLS_LAMBDA0 = 0.05, 0.02
#: python-can interfaces on which the simulated device can share the host's channel
SIMULATED_INTERFACES = ("teleop_lockstep", "virtual")
_ZERO6 = np.zeros(6)


def _finite(x) -> np.ndarray:
    """x as a float (6,) array with NaN and inf replaced by 0 (an input never poisons the loop)."""
    a = np.asarray(x, dtype=float)
    if a.shape != (6,):
        return np.zeros(6)
    return a if np.isfinite(a).all() else np.nan_to_num(a, nan=0.0, posinf=0.0, neginf=0.0)


def open_simulated_device(cfg: CobotConfig, channel: str, model: CobotModel, joints0, rng, db, timing, capture):
    """The device's side of a simulated bus: a plant with ``cfg``'s servo and sensor settings, played
    by a :class:`CobotSimulator` on its own bus on ``channel`` (owned: closed with it)."""
    params = DeviceParams(cfg.servo_bandwidth_hz, cfg.max_velocity, cfg.max_acceleration, cfg.encoder_m,
                          cfg.encoder_rad, cfg.force_noise_N, cfg.torque_noise_Nm, cfg.force_bias_N,
                          cfg.torque_bias_Nm)
    bus = can.Bus(interface=cfg.interface, channel=channel, fd=True, preserve_timestamps=True)
    return CobotSimulator(bus, CobotPlant(model, params, joints0, rng), rng, db, timing, cfg.faults, capture,
                          heartbeat_period_s=cfg.heartbeat_period_s, own_bus=True)


class CobotMaster(Master):
    """The cobot behind the master interface (see the module docstring).

    cfg: the cobot's settings; dt_s: the period, s; rng: the run's generator (sensor noise, faults);
    p0 (3,) m, R0 (3, 3): the reference tool's start pose (the device starts at φ^-1 of it);
    tool_mass_kg: the tool's mass, for the light-tool warning (None: no check).
    """

    def __init__(self, cfg: CobotConfig, dt_s: float, rng: np.random.Generator, p0, R0,
                 tool_mass_kg: float | None = None, reference=None):
        self.cfg, self.dt_s, self.rng = cfg, float(dt_s), rng
        #: the reference tool (pose(), twist()) whose state goes to the slave, or None: the observer's
        #: estimate of the device (see virtual_estimate)
        self.reference = reference
        self.log = logging.getLogger(__name__)
        self.model = CobotModel()
        #: joints -> (p, R, J) of the handle: the compiled closed form for the shipped gantry + Z-X-Z
        #: wrist, Pinocchio for any other URDF (chosen once, see CobotModel.compute_pose_and_jacobian)
        self.closed_form = self.model.closed_form
        #: the host's state between periods, one record the compiled period updates in place (see
        #: kernels.HOST_STATE); the attributes below, the controller's and the observer's are views
        self._hs = np.zeros(1, HOST_STATE)
        self._hc = np.zeros(1, HOST_CONSTS)
        hs = self._hs
        self.clutch = Clutch(Phi(cfg.scale, np.array(cfg.offset_m), pin.exp3(np.array(cfg.offset_rotvec_rad))))
        gains = AdmittanceGains(cfg.kp, cfg.ki, cfg.kd, cfg.integral_limit,
                                max_velocity=self._virtual_velocity_limit(cfg))
        self.ctrl = AdmittanceController(gains, self.dt_s, state=hs["ctrl"][0])
        p_H, R_H = self.clutch.phi.compute_handle_pose(np.asarray(p0, float), np.asarray(R0, float))
        self.joints0 = self.model.compute_joints(p_H, R_H)
        self._warn_end_stops(self.joints0)
        self._warn_light_tool(tool_mass_kg)
        self.tau_s = compute_servo_lag_s(cfg.servo_bandwidth_hz)
        self.vmax = np.array(cfg.max_velocity)
        self.timing = BusTiming(cfg.bitrate_bps, cfg.data_bitrate_bps, cfg.fd)
        self.db = FrameDatabase()
        if not self.dt_s > cfg.read_window_s:
            raise ConfigError(f"dt_s: the cobot's period ({self.dt_s:g} s) must be longer than its read window "
                              f"cobot.read_window_s ({cfg.read_window_s:g} s): the host reads the device's "
                              f"answer to SYNC that long after sending it")
        hb = max(1, round(cfg.heartbeat_period_s / dt_s))
        length = {m.name: m.length for m in self.db.db.messages}
        self.budget_load_pct = compute_cycle_load_pct(
            self.timing, [(length[n], True, 1) for n in ("SYNC", "HOST_CMD", "DEV_JOINTS", "DEV_WRENCH")]
            + [(length[n], True, hb) for n in ("HOST_HEARTBEAT", "DEV_HEARTBEAT")], self.dt_s)
        if self.budget_load_pct >= 100.0:
            raise ConfigError(f"dt_s: a {self.dt_s:g} s period needs {self.budget_load_pct:.0f} % of the CAN bus "
                              f"({cfg.bitrate_bps:g} / {cfg.data_bitrate_bps:g} bit/s); lengthen the period or "
                              f"raise the bit rates")
        # the most a joint reading can change between two SYNCs: the velocity limit over a period
        # (with half again for the servo's timing) plus two encoder counts, m x3, rad x3
        counts = np.array([cfg.encoder_m] * 3 + [cfg.encoder_rad] * 3)
        step_max = 1.5 * np.array(cfg.max_velocity) * self.dt_s + 2.0 * counts
        # the most a load-cell reading can change between two SYNCs: its rate limit over a period
        # plus six noise deviations and two quanta of the wire, N x3, N*m x3 (cfg.wrench_rate_max)
        quanta = np.array([abs(s.conversion.scale) for s in self.db.codecs["DEV_WRENCH"].signals[:6]])
        noise = np.array([cfg.force_noise_N] * 3 + [cfg.torque_noise_Nm] * 3)
        wrench_step_max = np.array(cfg.wrench_rate_max) * self.dt_s + 6.0 * noise + 2.0 * quanta
        channel = cfg.channel or f"teleop-cobot-{uuid.uuid4().hex}"
        simulated = cfg.interface in SIMULATED_INTERFACES
        extra = {"preserve_timestamps": True} if simulated else {}
        self.t = 0.0  # simulated time of the link, s
        self.driver = CobotDriver(can.Bus(interface=cfg.interface, channel=channel, fd=True, **extra), self.db,
                                  clock=lambda: self.t, stale_cycles=cfg.stale_cycles,
                                  heartbeat_period_s=cfg.heartbeat_period_s,
                                  heartbeat_timeout_s=cfg.heartbeat_timeout_s, own_bus=True,
                                  encoder_step_max=step_max, wrench_step_max=wrench_step_max)
        self.capture = Capture(cfg.capture_path) if cfg.capture_path else None
        self.sim = open_simulated_device(cfg, channel, self.model, self.joints0, rng, self.db, self.timing,
                                         self.capture) if simulated else None
        self.bias_S = np.zeros(6)
        self.observer = JointObserver(self.joints0, self.dt_s, self.tau_s, cfg.read_window_s, self.vmax,
                                      cfg.max_acceleration, cfg.observer_bandwidth_hz, state=hs["obs"][0],
                                      history=hs["obs_hist"][0])
        self.nu_H_cmd, self.accel_H_cmd = hs["nu_H"][0], hs["a_H"][0]  # the handle's commanded twist, acceleration
        self.accel_H_model = hs["accel_model"][0]  # the servo model's handle acceleration per SYNC
        self.pred_p, self.pred_R = hs["pred_p"][0], hs["pred_R"][0]  # handle pose the commands predict, per SYNC
        self.pred_R[:] = np.eye(3)
        self.p_H_est, self.R_H_est = hs["p_est"][0], hs["R_est"][0]
        self.p_H_est[:], self.R_H_est[:] = p_H, R_H
        self._p_v, self._R_v = hs["p_v"][0], hs["R_v"][0]  # φ(estimate) of this period
        self._p_v[:], self._R_v[:] = self.clutch.phi.compute_virtual_pose(p_H, R_H)
        self.F_hand_W = hs["F_hand"][0]  # the hand's wrench at H (world) of this period's feedback
        self.J = hs["J"][0]
        self.J[:] = np.eye(6)
        self.counter = 0  # this period's SYNC counter
        self.status = "ok"
        self._qd_cmd, self._f_v = hs["qd"][0], hs["f_v"][0]  # views read every period
        self._err_max = hs["err_max"][0]
        m = cfg.workspace_margin_m
        self.ws = np.array([self.model.upper - m, self.model.lower + m])
        self._consts = self._consts_key = None
        self._reengage = False
        self.steps = 0
        self.closed = self.entered = False
        self._wall0 = None

    @staticmethod
    def _virtual_velocity_limit(cfg):
        v = np.array(cfg.max_velocity)
        return tuple(np.concatenate([v[:3] * cfg.scale, v[3:]]))

    # -- life cycle ---------------------------------------------------------------------------------
    def start(self) -> None:
        """Open the link, wait for the first feedback and tare the load cell (tare_cycles periods);
        idempotent. Without feedback the status latches "startup_timeout"."""
        if self.entered:
            return
        self.entered = True
        drv = self.driver
        drv.start(self.joints0)
        samples = []
        for _ in range(self.cfg.tare_cycles + 200):
            self._link_cycle_begin()
            if drv.fresh_wrench:
                samples.append(drv.wrench_S.copy())
            drv.fresh_joints = drv.fresh_wrench = False
            drv.send_command(_ZERO6)
            self._link_cycle_end()
            if len(samples) >= self.cfg.tare_cycles:
                break
        if len(samples) < self.cfg.tare_cycles:
            self.status = "startup_timeout"
            return
        p_H, R_H = self.model.compute_handle_pose(drv.joints_rad_m)
        static = self.model.compute_distal_wrench_W(R_H, _ZERO6[:3], _ZERO6[:3], _ZERO6[:3])
        self.bias_S = np.mean(samples, axis=0) - np.concatenate([R_H.T @ static[:3], R_H.T @ static[3:]])
        drv.cycles_since_joints = drv.cycles_since_wrench = 0
        self.observer.reset(drv.joints_rad_m)
        self.pred_p[:], self.pred_R[:] = p_H, R_H
        self._wall0 = time.perf_counter()
        self.steps = 0

    def close(self) -> None:
        """Zero velocity and release the buses and the capture; safe to call twice."""
        if self.closed:
            return
        self.closed = True
        self.driver.close()
        if self.sim is not None:
            self.sim.advance_to(self.t + self.dt_s)
            self.sim.close()
        if self.capture is not None:
            self.capture.close()

    # -- the lockstep link --------------------------------------------------------------------------
    def _link_cycle_begin(self) -> int:
        c = self.driver.send_sync()
        self.driver.send_heartbeat()
        self.t += self.cfg.read_window_s
        if self.sim is not None:
            self.sim.advance_to(self.t)
        self.driver.read()
        return c

    def _link_cycle_end(self) -> None:
        self.t += self.dt_s - self.cfg.read_window_s
        if self.sim is not None:
            self.sim.advance_to(self.t)
        if self.cfg.realtime and self._wall0 is not None:
            lag = self._wall0 + (self.steps + 1) * self.dt_s - time.perf_counter()
            if lag > 0:
                time.sleep(lag)

    # -- one period ---------------------------------------------------------------------------------
    def sense(self, hand_wrench_W) -> np.ndarray:
        """The period's first half: the hand's wrench (6,: N, N*m, world, virtual space) onto the
        simulated handle, SYNC, read, the load cell through φ (eq. 4). Returns f_v (6,), the wrench
        the master applies to the reference tool: zeros when clutched out or faulted (a latched link
        or tracking fault keeps the bus running at zero velocity). Never raises."""
        try:
            if self.status == "ok":
                return self._sense(hand_wrench_W)
            if self.entered and not self.closed and not self.status.startswith(("startup", "internal")):
                self.counter = self._link_cycle_begin()
                self.driver.end_cycle()
                self._hold()
        except Exception as e:  # the loop must survive anything: hold the device, report
            self._internal_error(e)
        return _ZERO6

    def _sense(self, hand_wrench_W) -> np.ndarray:
        drv = self.driver
        if self.sim is not None:
            self.sim.apply_hand_wrench(self.clutch.phi.wrench_to_handle(_finite(hand_wrench_W)))
        k = self.counter = self._link_cycle_begin()
        drv.check_heartbeat()
        if drv.fault is None and not self.closed_form:  # Pinocchio's kinematics for any other URDF
            hs = self._hs
            hs["p_m"][0], hs["R_m"][0], hs["J"][0] = self.model.compute_pose_and_jacobian(drv.joints_rad_m)
        # the observer's correction by a fresh reading, the feedback aged a cycle, the load cell
        # through φ (eq. 4) unless a fault is latched or the feedback is stale
        stale = host_sense(self._hs, self._constants(), drv._ds, k, self.bias_S, drv.stale_cycles, drv.fault is None,
                           self.closed_form)
        if stale:
            drv.trip_stale()
        fault = drv.fault
        if fault is not None:
            self.status = fault
            self._hold()
            return _ZERO6
        return self._f_v.copy() if self.clutch.engaged and not self._reengage else _ZERO6

    def command(self, p_r, R_r, nu_r, a_r) -> str:
        """The period's second half, from the reference tool's pose and twist before its step
        (p_r (3,) m, R_r (3, 3), nu_r (6,: m/s, rad/s, world)) and the acceleration the step
        produced (a_r (6,)): eqs. 18-19, DLS, joint velocities on the bus, the device runs to the
        period's end, the tracking-fault check. Clutched out, the handle follows the hand's wrench
        through ``free_damping``. Returns the status; never raises."""
        if self.status != "ok":
            return self.status
        try:
            return self._command(p_r, R_r, nu_r, a_r)
        except Exception as e:
            self._internal_error(e)
            return self.status

    def _command(self, p_r, R_r, nu_r, a_r) -> str:
        drv, ctrl, k = self.driver, self.ctrl, self.counter
        p_r, R_r, nu_r, a_r = (np.asarray(p_r, dtype=float), np.asarray(R_r, dtype=float),
                               np.asarray(nu_r, dtype=float), np.asarray(a_r, dtype=float))
        if self._reengage:  # φ re-indexed on the tool's pose: φ(x) = q_r exactly, no jump
            self._reengage = False
            self.clutch.engage(self.p_H_est, self.R_H_est, p_r, R_r)
            ctrl.reset(nu_r)
            self._p_v[:], self._R_v[:] = self.clutch.phi.compute_virtual_pose(self.p_H_est, self.R_H_est)
            self._constants()  # the new φ (sense refreshed the rest)
        engaged = self.clutch.engaged  # else the handle follows the hand: an admittance of free_damping
        e_p, e_r = host_command(self._hs, self._hc, p_r, R_r, nu_r, a_r, drv.joints_rad_m, k, engaged)
        cfg = self.cfg
        if engaged and (e_p > cfg.tracking_fault_m or e_r > cfg.tracking_fault_rad):
            self._track_fault(e_p, e_r)
        drv.send_command(self._qd_cmd, self.vmax)
        self._link_cycle_end()
        self.steps += 1
        return self.status

    @property
    def err_max(self) -> tuple[float, float]:
        """The maxima of the tracking error |q_r - q_v| while engaged (m, rad)."""
        return float(self._err_max[0]), float(self._err_max[1])

    def _track_fault(self, e_p: float, e_r: float) -> None:
        """Latch "tracking_error": the tracking error |q_r - q_v| (e_p m, e_r rad) is beyond
        ``tracking_fault_m`` / ``_rad``: the device cannot render the tool (an end stop, a limit
        cycle). This period's command still goes out (zero velocity, since the driver holds after a
        fault); from the next period the master senses nothing."""
        cfg = self.cfg
        self.driver.latch_fault("tracking_error", f"|q_r - q_v| = {e_p:.4g} m, {e_r:.4g} rad, beyond "
                                f"{cfg.tracking_fault_m} m / {cfg.tracking_fault_rad} rad")
        self.status = "tracking_error"

    def _hold(self) -> None:
        """A latched fault: zero velocity, the observer and the prediction follow it, the bus runs
        to the period's end."""
        self.driver.send_command(_ZERO6)
        self.observer.predict(self.counter, _ZERO6)
        advance_prediction(self.pred_p, self.pred_R, self.counter, _ZERO6, self.dt_s)
        self._link_cycle_end()

    def _internal_error(self, e: Exception) -> None:
        self.log.exception("cobot master period failed")
        self.status = f"internal_error:{type(e).__name__}"
        self.driver.fault = self.driver.fault or "internal_error"
        self.driver.send_command(_ZERO6)

    def _constants(self):
        """The kernels' constant record (:data:`.kernels.HOST_CONSTS`) for the current φ, gains,
        observer limits and settings, refilled when one of them is replaced (the handle's inertia
        is read then too)."""
        phi, g, obs, m, cfg = self.clutch.phi, self.ctrl.gains, self.observer, self.model, self.cfg
        key = self._consts_key
        if (key is None or phi is not key[0] or g is not key[1] or obs.vmax is not key[2] or obs.amax is not key[3]
                or cfg is not key[4]):
            self._consts_key = (phi, g, obs.vmax, obs.amax, cfg)
            c = self._hc[0]
            c["gains"] = np.array([g.kp, g.ki, g.kd, g.integral_limit, g.max_accel, g.max_velocity])
            c["obs_lim"] = np.array([obs.vmax, obs.amax])
            c["ws"], c["sigma0"], c["lam0"] = self.ws, DLS_SIGMA0, DLS_LAMBDA0
            c["mass"], c["com"], c["inertia"], c["gravity"] = m.handle_mass_kg, m.handle_com_H, m.handle_J_H, GRAVITY_W
            c["max_force"], c["max_torque"] = cfg.max_force_N, cfg.max_torque_Nm
            c["wrench_map"], c["to_handle"] = phi.wrench_map_to_virtual, phi.twist_map_to_handle
            c["off_p"], c["scale"], c["off_R"] = phi.offset_p, phi.scale, phi.offset_R
            c["tau"], c["dt"], c["dt_ctrl"] = self.tau_s, self.dt_s, self.ctrl.dt
            c["obs_dt"], c["obs_window"], c["obs_tau"] = obs.dt, obs.window, obs.tau
            c["alpha"], c["beta"] = obs.alpha, obs.beta
            c["servo_model"] = cfg.inertia_compensation == "servo_model"
            c["vmax"], c["free_damping"] = self.vmax, np.broadcast_to(np.asarray(cfg.free_damping, float), 6)
        return self._hc

    # -- clutch -------------------------------------------------------------------------------------
    def set_clutch(self, engaged: bool) -> None:
        """Release: the tool gets no hand wrench, the handle follows the hand. Engage: from the next
        ``command``, φ re-indexed so that φ(x) equals the tool's pose then (no jump)."""
        if not engaged:
            self.clutch.release()
            self._reengage = False
        elif not self.clutch.engaged:
            self._reengage = True

    # -- read-outs ----------------------------------------------------------------------------------
    def _virtual_state(self, joints, rates):
        """(p, R, v, w) through φ of the handle at ``joints`` moving at ``rates`` (m, -, m/s, rad/s)."""
        p_H, R_H, J = self.model.compute_pose_and_jacobian(joints)
        phi = self.clutch.phi
        nu = phi.twist_to_virtual(J @ rates)
        return (*phi.compute_virtual_pose(p_H, R_H), nu[:3], nu[3:])

    def virtual_pose(self):
        """q_v = φ(x) from the encoder readings: (p (3,) m, R (3, 3))."""
        p_H, R_H, _ = self.model.compute_pose_and_jacobian(self.driver.joints_rad_m)
        return self.clutch.phi.compute_virtual_pose(p_H, R_H)

    def virtual_twist(self):
        """(v (3,) m/s, w (3,) rad/s) of the virtual tool: the device Jacobian times the joint rates
        the observer estimates from the encoders (:mod:`.observer`), through φ."""
        return self._virtual_state(self.observer.x, self.observer.rates)[2:]

    def virtual_estimate(self):
        """(p, R, v, w) for the slave's target (m, -, m/s, rad/s): the admittance model's output,
        the reference tool's state after this period's step, when the master was given it
        (``reference``); otherwise the virtual tool from the joint observer (its pose and twist
        estimated below the encoders' 25 µm / 0.5 mrad resolution). The observer's estimate carries
        the device loop's corrections (PID on quantized encoders, its own 20 Hz filter); fed to the
        slave, the cut's steep stick closed a loop through them and limit-cycled the tool at 6-9 Hz
        (README, "the slave behind the cobot"). The raw read-outs (:meth:`virtual_pose`) stay what
        the metrics use, as in the paper."""
        if self.reference is not None:
            return (*self.reference.pose(), *self.reference.twist())
        return self._virtual_state(self.observer.x, self.observer.rates)

    def hand_state(self):
        """(p, R, v, w) of the handle the operator's hand holds, through φ into the virtual tool's
        space (m, -, m/s, rad/s). On the simulated device it is the handle's true state, so that a
        simulated hand's stiffness and damping act on the physical handle as a real hand's do; on
        hardware, where a real hand needs no model, the encoder read-outs."""
        if self.sim is None:
            return (*self.virtual_pose(), *self.virtual_twist())
        return self._virtual_state(*self.sim.handle_state())

    def joints(self) -> np.ndarray:
        """The device's joint read-out (6,: m x3, rad x3, unwrapped), as the host decoded it."""
        return self.driver.joints_rad_m.copy()

    def stats(self) -> dict:
        out = {"can_bus_load_pct": 0.0, "can_frames_lost": 0}
        if self.sim is not None:
            out.update(self.sim.stats())
        out.update(self.driver.stats())
        out.update({
            "can_bus_load_budget_pct": self.budget_load_pct,
            "master_steps": self.steps,
            "tracking_error_max_m": float(self.err_max[0]),
            "tracking_error_max_rad": float(self.err_max[1]),
            "master_status": self.status,
        })
        return out

    # -- start-up warnings --------------------------------------------------------------------------
    def _warn_end_stops(self, joints0) -> None:
        """Log a warning when the tool's start pose puts a device joint outside its travel: the
        device starts on its end stop and renders that pose off by the excess (m or rad)."""
        lo, hi = self.model.lower, self.model.upper
        for i in np.flatnonzero((joints0 < lo) | (joints0 > hi)):
            self.log.warning(
                "cobot: the tool's start pose needs device joint %d at %.4g, outside its travel [%.4g, %.4g]; "
                "the device starts on its end stop. Move the tool with cobot.offset_m, or turn it with "
                "cobot.offset_rotvec_rad (a tool pointing straight down: [1.5708, 0, 0])",
                i, joints0[i], lo[i], hi[i])

    def _warn_light_tool(self, m_tool) -> None:
        """Log a warning when the rendered tool (m_tool kg, s² m at the handle with φ's scale s) is
        lighter than the lightest mass the loop renders stably without a hand on the handle, by the
        linearized loop (:func:`teleop.control.stability.critical_mass`, on the x axis's gains and
        this device's period, servo and inertia compensation). With "commanded" compensation that is
        about 0.04 kg for the shipped 0.15 kg handle; with "servo_model", below a gram (issue 15)."""
        if m_tool is None:
            return
        cfg, s2 = self.cfg, self.cfg.scale ** 2
        m_min = critical_mass(LoopParams(
            mass=1.0, handle_mass=self.model.handle_mass_kg, dt_s=self.dt_s, servo_bandwidth_hz=cfg.servo_bandwidth_hz,
            read_window_s=min(cfg.read_window_s, 0.99 * self.dt_s), kp=cfg.kp[0], ki=cfg.ki[0], kd=cfg.kd[0],
            compensation=cfg.inertia_compensation))
        if m_tool * s2 < m_min:
            self.log.warning(
                "cobot: the tool renders %.4g kg at the handle, below the %.4g kg this loop renders stably with no "
                "hand on the %.4g kg handle (%s inertia compensation); it is stable only with a hand's damping. "
                "Render at least %.4g kg (tool.mass_kg)", m_tool * s2, m_min, self.model.handle_mass_kg,
                cfg.inertia_compensation, m_min / s2)
