"""CobotMaster: the whole master chain in lockstep simulated time.

One ``step``: SYNC -> the simulated device samples encoders and load cell -> frames cross the
modelled wire -> the driver decodes them -> the load-cell wrench, its distal handle mass removed,
goes through φ to the tool (eq. 4) -> the reference tool steps -> PID on q_r - q_v (eqs. 18-19)
-> the acceleration back through φ and the device Jacobian (damped least squares) -> joint
velocity commands on the bus -> the device's servos run to the end of the period.

Late or lost feedback: each measurement carries the SYNC counter it answers, and the host keeps the
handle pose its own commands predict for every cycle, so an old measurement is carried forward by
the commanded motion since (a Smith-predictor style estimate) instead of being compared with today's
reference. Frames of the device arrive only through the bus: a user with hardware changes
``interface`` and ``channel`` and runs the driver without the simulator.
"""

from __future__ import annotations

import logging
import math
import time
import uuid

import can
import numpy as np
import pinocchio as pin
from scipy.linalg import lapack

from teleop.can import BusTiming, Capture, CobotDriver, CobotSimulator, FrameDatabase, compute_cycle_load_pct
from teleop.control.admittance import AdmittanceController, AdmittanceGains, Phi
from teleop.control.clutch import Clutch
from teleop.master.cobot import GRAVITY_W, CobotDevice, CobotModel, DeviceParams
from teleop.master.config import CobotConfig
from teleop.master.kernels import (advance_prediction, dls_command, hand_wrench_W, handle_command, host_command,
                                   host_feedback)
from teleop.master.observer import HISTORY, JointObserver


#: damped least squares: no damping above this smallest singular value, up to this damping at 0
DLS_SIGMA0, DLS_LAMBDA0 = 0.05, 0.02


def compute_dls(J: np.ndarray, twist: np.ndarray, sigma0: float = DLS_SIGMA0, lam0: float = DLS_LAMBDA0) -> np.ndarray:
    """Joint rates (6,) for a handle twist (6,) by damped least squares: no damping while the
    smallest singular value exceeds sigma0, then damping rising to lam0 at the singularity."""
    U, S, Vt, info = lapack.dgesvd(J)  # LAPACK directly: numpy's wrapper costs 3x the SVD
    if info != 0:
        raise np.linalg.LinAlgError(f"dgesvd did not converge (info {info})")
    smin = S[-1]
    lam2 = 0.0 if smin >= sigma0 else lam0 * lam0 * (1.0 - (smin / sigma0) ** 2)
    return Vt.T @ ((S / (S * S + lam2)) * (U.T @ twist))


def compute_workspace_limit(joints, qd, hi, lo) -> np.ndarray:
    """qd (6,) with the rates that would drive a joint past hi or lo (6,) zeroed (the reference of
    :func:`~teleop.master.kernels.dls_command`'s last step)."""
    return np.where((joints > hi) & (qd > 0) | (joints < lo) & (qd < 0), 0.0, qd)


def _finite(x) -> np.ndarray:
    """x as a float array with NaN and inf replaced by 0 (an input never poisons the loop)."""
    a = np.asarray(x, dtype=float)
    return a if np.isfinite(a).all() else np.nan_to_num(a, nan=0.0, posinf=0.0, neginf=0.0)


#: python-can interfaces on which the simulated device can share the host's channel
SIMULATED_INTERFACES = ("teleop_lockstep", "virtual")


class CobotMaster:
    """The simulated cobot behind the runtime's master interface (see module docstring).

    compiled: while the clutch is engaged, run a period's math as two fused kernels
    (:func:`~teleop.master.kernels.host_feedback` before the reference tool's step,
    :func:`~teleop.master.kernels.host_command` after it); False runs it piece by piece (observer,
    kinematics, load cell, φ, PID, DLS, prediction), the reference the fused path is tested against.
    The fused path needs the closed-form kinematics and the compiled controller and observer; it
    falls back to the pieces otherwise.
    """

    def __init__(self, tool, cfg: CobotConfig, dt_s: float, rng: np.random.Generator, compiled: bool = True):
        self.tool, self.cfg, self.dt, self.rng = tool, cfg, float(dt_s), rng
        self.compiled = compiled
        self.log = logging.getLogger(__name__)
        self.model = CobotModel()
        R_off = pin.exp3(np.array(cfg.offset_rotvec_rad))
        self.clutch = Clutch(Phi(cfg.scale, np.array(cfg.offset_m), R_off))
        gains = AdmittanceGains(cfg.kp, cfg.ki, cfg.kd, cfg.integral_limit,
                                max_velocity=self._virtual_velocity_limit(cfg))
        self.ctrl = AdmittanceController(gains, self.dt)
        p_r, R_r = tool.pose()
        p_H, R_H = self.clutch.phi.compute_handle_pose(p_r, R_r)
        joints0 = self.model.compute_joints(p_H, R_H)
        self._warn_end_stops(joints0)
        self._warn_light_tool(tool)
        params = DeviceParams(cfg.servo_bandwidth_hz, cfg.max_velocity, cfg.max_acceleration, cfg.encoder_m,
                              cfg.encoder_rad, cfg.force_noise_N, cfg.torque_noise_Nm, cfg.force_bias_N,
                              cfg.torque_bias_Nm)
        self.device = CobotDevice(self.model, params, joints0, rng)
        self.tau_s = self.device.tau_s
        self.vmax = np.array(cfg.max_velocity)
        self.timing = BusTiming(cfg.bitrate_bps, cfg.data_bitrate_bps, cfg.fd)
        self.db = FrameDatabase()
        self.budget_load_pct = compute_cycle_load_pct(
            self.timing, [(2, True, 1), (16, True, 1), (16, True, 1), (16, True, 1),
                          (3, True, round(cfg.heartbeat_period_s / dt_s)), (4, True, round(cfg.heartbeat_period_s / dt_s))],
            self.dt)
        channel = cfg.channel or f"teleop-cobot-{uuid.uuid4().hex}"
        simulated = cfg.interface in SIMULATED_INTERFACES
        extra = {"preserve_timestamps": True} if simulated else {}
        self.host_bus = can.Bus(interface=cfg.interface, channel=channel, fd=True, **extra)
        self.dev_bus = can.Bus(interface=cfg.interface, channel=channel, fd=True, **extra) if simulated else None
        self.capture = Capture(cfg.capture_path) if cfg.capture_path else None
        self.t = 0.0  # simulated time of the link, s
        self.driver = CobotDriver(self.host_bus, self.db, clock=lambda: self.t, stale_cycles=cfg.stale_cycles,
                                  heartbeat_period_s=cfg.heartbeat_period_s,
                                  heartbeat_timeout_s=cfg.heartbeat_timeout_s, own_bus=True)
        self.sim = None if self.dev_bus is None else CobotSimulator(
            self.dev_bus, self.device, rng, self.db, self.timing, cfg.faults, self.capture,
            heartbeat_period_s=cfg.heartbeat_period_s)
        self.joints0 = joints0
        self.bias_S = np.zeros(6)
        self.observer = JointObserver(joints0, self.dt, self.tau_s, cfg.read_window_s, self.vmax,
                                      cfg.max_acceleration, cfg.observer_bandwidth_hz)
        self.nu_H_cmd = np.zeros(6)
        self.accel_H_cmd = np.zeros(6)
        self.pred_p = np.zeros((HISTORY, 3))  # handle pose the commands predict, per SYNC counter
        self.pred_R = np.tile(np.eye(3), (HISTORY, 1, 1))
        self.p_H_est, self.R_H_est = p_H, R_H
        self.counter = 0
        self.status = "ok"
        self.err_max = (0.0, 0.0)  # tracking error maxima (m, rad)
        self._ws_hi = self._ws_lo = None
        self._fused_key = self._fused_consts = None
        self.steps = 0
        self.closed = self.entered = False
        self._wall0 = None

    @staticmethod
    def _virtual_velocity_limit(cfg):
        v = np.array(cfg.max_velocity)
        return tuple(np.concatenate([v[:3] * cfg.scale, v[3:]]))

    # -- life cycle ---------------------------------------------------------------------------------
    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc):
        self.close()

    def start(self) -> None:
        """Open the link, wait for the first feedback and tare the load cell (tare_cycles periods)."""
        if self.entered:
            return
        self.entered = True
        self.driver.start(self.joints0)
        samples = []
        for _ in range(self.cfg.tare_cycles + 200):
            self._link_cycle_begin()
            if self.driver.fresh_wrench:
                samples.append(self.driver.wrench_S.copy())
            self.driver.fresh_joints = self.driver.fresh_wrench = False
            self.driver.send_command(np.zeros(6))
            self._link_cycle_end()
            if len(samples) >= self.cfg.tare_cycles:
                break
        if len(samples) < self.cfg.tare_cycles:
            self.status = "startup_timeout"
            return
        p_H, R_H = self.model.compute_handle_pose(self.driver.joints_rad_m)
        static = self.model.compute_distal_wrench_W(R_H, np.zeros(3), np.zeros(3), np.zeros(3))
        self.bias_S = np.mean(samples, axis=0) - np.concatenate([R_H.T @ static[:3], R_H.T @ static[3:]])
        self.driver.cycles_since_joints = self.driver.cycles_since_wrench = 0
        self.observer.reset(self.driver.joints_rad_m)
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
            self.sim.advance_to(self.t + self.dt)
        if self.dev_bus is not None:
            self.dev_bus.shutdown()
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
        self.t += self.dt - self.cfg.read_window_s
        if self.sim is not None:
            self.sim.advance_to(self.t)
        if self.cfg.realtime and self._wall0 is not None:
            lag = self._wall0 + (self.steps + 1) * self.dt - time.perf_counter()
            if lag > 0:
                time.sleep(lag)

    # -- one period ---------------------------------------------------------------------------------
    def step(self, hand_wrench_W, contact_wrench_W=None) -> str:
        """One control period (see the module docstring); never raises. Returns "ok" or a fault."""
        try:
            return self._step(hand_wrench_W, contact_wrench_W)
        except Exception as e:  # the loop must survive anything: hold the device, report
            self.log.exception("cobot master step failed")
            self.status = f"internal_error:{type(e).__name__}"
            self.driver.fault = self.driver.fault or "internal_error"
            self.driver.send_command(np.zeros(6))
            return self.status

    def _step(self, hand_wrench_W, contact_wrench_W) -> str:
        if self.status != "ok" and self.status.startswith(("startup", "internal")):
            return self.status
        phi, drv = self.clutch.phi, self.driver
        if self.sim is not None:  # the hand on the simulated handle
            self.device.hand_wrench_W = phi.wrench_to_handle(_finite(hand_wrench_W))
        k = self._link_cycle_begin()
        obs = self.observer
        fused = self._fused(phi) if self.compiled and self.clutch.engaged else None
        if fused is not None:
            return self._step_fused(k, drv, obs, fused, contact_wrench_W)
        if drv.fresh_joints:  # a reading of SYNC joints_counter (this one, or late)
            obs.correct(drv.joints_rad_m, drv.joints_counter, k)
        fault = drv.end_cycle()
        if fault is not None:
            return self._fault(k, fault)
        joints = drv.joints_rad_m
        p_m, R_m, J = self.model.compute_pose_and_jacobian(joints)
        # carry the measurement (cycle j) forward by the commanded motion since
        j = drv.joints_counter
        if j == k:  # a reading of this very SYNC: nothing to carry forward
            self.p_H_est, self.R_H_est = p_m, R_m
        else:
            self.p_H_est = p_m + self.pred_p[k] - self.pred_p[j]
            self.R_H_est = self.pred_R[k] @ self.pred_R[j].T @ R_m
        F_hand_W = self._hand_wrench_W(R_m)
        self._workspace()
        if self.clutch.engaged:
            nu_V, a_V, st, e_p, e_r = self._admittance(phi, F_hand_W, contact_wrench_W)
            st = self._track(e_p, e_r, st)
            nu_H, a_H, qd = handle_command(J, phi.twist_map_to_handle, nu_V, a_V, self.tau_s, joints,
                                           self._ws_hi, self._ws_lo, DLS_SIGMA0, DLS_LAMBDA0)
        else:
            nu_H = np.clip(F_hand_W / np.array(self.cfg.free_damping), -self.vmax, self.vmax)
            a_H, st = (nu_H - self.nu_H_cmd) / self.dt, "ok"
            qd = dls_command(J, nu_H + self.tau_s * a_H, joints, self._ws_hi, self._ws_lo, DLS_SIGMA0,
                             DLS_LAMBDA0)
        drv.send_command(qd, self.vmax)
        obs.predict(k, qd)
        self._advance_prediction(k, nu_H)
        self.nu_H_cmd, self.accel_H_cmd = nu_H, a_H
        self._link_cycle_end()
        self.steps += 1
        self.status = st
        return st

    def _track(self, e_p: float, e_r: float, st: str) -> str:
        """Keep the maxima of the tracking error |q_r - q_v| (e_p m, e_r rad), and latch
        "tracking_error" beyond ``tracking_fault_m`` / ``_rad``: the device cannot render the tool
        (an end stop, a limit cycle). This period's command still goes out; from the next one the
        device holds at zero velocity. Returns the period's status."""
        self.err_max = (max(self.err_max[0], e_p), max(self.err_max[1], e_r))
        cfg = self.cfg
        if st == "ok" and (e_p > cfg.tracking_fault_m or e_r > cfg.tracking_fault_rad):
            self.driver.latch_fault("tracking_error", f"|q_r - q_v| = {e_p:.4g} m, {e_r:.4g} rad, beyond "
                                    f"{cfg.tracking_fault_m} m / {cfg.tracking_fault_rad} rad")
            return "tracking_error"
        return st

    def _fault(self, k: int, fault: str) -> str:
        """A latched link fault: zero velocity, the observer and the prediction follow it."""
        self.driver.send_command(np.zeros(6))
        self.observer.predict(k, np.zeros(6))
        self._advance_prediction(k, np.zeros(6))
        self._link_cycle_end()
        self.status = fault
        return fault

    def _workspace(self) -> None:
        if self._ws_hi is None:
            m = self.cfg.workspace_margin_m
            self._ws_hi, self._ws_lo = self.model.upper - m, self.model.lower + m

    def _fused(self, phi):
        """The constants of the fused kernels for φ ``phi`` and the current gains and observer
        limits (rebuilt when one of them is replaced), or None where the fused path does not apply."""
        ctrl, obs = self.ctrl, self.observer
        if not (self.model.closed_form and ctrl.compiled and obs.compiled):
            return None
        key = self._fused_key
        if (key is None or phi is not key[0] or ctrl.gains is not key[1] or obs.vmax is not key[2]
                or obs.amax is not key[3] or self.cfg is not key[4]):
            key = (phi, ctrl.gains, obs.vmax, obs.amax, self.cfg)
            self._workspace()
            g, m, cfg = ctrl.gains, self.model, self.cfg
            self._fused_key = key
            self._fused_consts = (
                (m.handle_mass_kg, m.handle_com_H, m.handle_J_H, GRAVITY_W, cfg.max_force_N, cfg.max_torque_Nm,
                 phi.wrench_map_to_virtual, phi.offset_p, phi.scale, phi.offset_R),
                np.array([g.kp, g.ki, g.kd, g.integral_limit, g.max_accel, g.max_velocity]),
                np.array([self._ws_hi, self._ws_lo]),
                np.array([obs.vmax, obs.amax]),
                phi.twist_map_to_handle)
        return self._fused_consts

    def _step_fused(self, k: int, drv, obs, fused, contact_wrench_W) -> str:
        """The engaged period of :meth:`_step` with its math in the two fused kernels."""
        if drv.fresh_joints:  # a reading of SYNC joints_counter (this one, or late)
            obs.correct(drv.joints_rad_m, drv.joints_counter, k)
        fault = drv.end_cycle()
        if fault is not None:
            return self._fault(k, fault)
        feedback, gains, ws, obs_lim, to_handle = fused
        joints, tool, ctrl = drv.joints_rad_m, self.tool, self.ctrl
        J, self.p_H_est, self.R_H_est, f_v, p_v, R_v = host_feedback(
            joints, k, drv.joints_counter, self.pred_p, self.pred_R, drv.wrench_S, self.bias_S, self.accel_H_cmd,
            self.nu_H_cmd, *feedback)
        if contact_wrench_W is not None:
            f_v = f_v + _finite(contact_wrench_W)
        p_r, R_r = tool.pose()
        v_r, w_r = tool.twist()
        st = tool.step(self.dt, f_v)
        (ctrl.nu_cmd, ctrl.accel_cmd, ctrl.error, ctrl.integral, nu_H, a_H, qd, obs.x, obs.qd_model, obs.u,
         e_p, e_r) = host_command(p_r, R_r, v_r, w_r, tool.acceleration_W, p_v, R_v, gains, ctrl.dt, ctrl.integral,
                                  ctrl.nu_cmd, to_handle, self.tau_s, J, joints, ws, DLS_SIGMA0, DLS_LAMBDA0, k,
                                  self.pred_p, self.pred_R, self.dt, obs.x, obs.qd_model, obs.u, obs.bias, obs_lim,
                                  obs.dt, obs.window, obs.tau, obs.history)
        st = self._track(e_p, e_r, st)
        drv.send_command(qd, self.vmax)
        self.nu_H_cmd, self.accel_H_cmd = nu_H, a_H
        self._link_cycle_end()
        self.steps += 1
        self.status = st
        return st

    def _hand_wrench_W(self, R_H) -> np.ndarray:
        """The hand's wrench at H (world): load cell minus tare, minus the distal handle's weight
        and inertia (at the commanded motion), saturated (kernel of :func:`compute_hand_wrench_W`)."""
        m, cfg = self.model, self.cfg
        return hand_wrench_W(self.driver.wrench_S, self.bias_S, R_H, self.accel_H_cmd, self.nu_H_cmd[3:],
                             m.handle_mass_kg, m.handle_com_H, m.handle_J_H, GRAVITY_W,
                             cfg.max_force_N, cfg.max_torque_Nm)

    def _admittance(self, phi, F_hand_W, contact_wrench_W):
        tool = self.tool
        f_v = phi.wrench_to_virtual(F_hand_W)  # eq. 4
        if contact_wrench_W is not None:
            f_v = f_v + _finite(contact_wrench_W)
        p_r, R_r = tool.pose()
        v_r, w_r = tool.twist()
        p_v, R_v = phi.compute_virtual_pose(self.p_H_est, self.R_H_est)
        st = tool.step(self.dt, f_v)
        nu_V, a_V = self.ctrl.step(p_r, R_r, np.concatenate([v_r, w_r]), tool.acceleration_W, p_v, R_v)
        ex, ey, ez, rx, ry, rz = self.ctrl.error.tolist()  # q_r - q_v before the step
        return nu_V, a_V, st, math.sqrt(ex * ex + ey * ey + ez * ez), math.sqrt(rx * rx + ry * ry + rz * rz)

    def _advance_prediction(self, k: int, nu_H) -> None:
        """The handle pose at SYNC k+1 that the command nu_H (6,) predicts (compiled)."""
        advance_prediction(self.pred_p, self.pred_R, k, nu_H, self.dt)

    # -- clutch -------------------------------------------------------------------------------------
    def set_clutch(self, engaged: bool) -> None:
        """Release: the tool holds, the handle follows the hand. Engage: φ re-indexed, no jump."""
        if not engaged:
            self.clutch.release()
            return
        if not self.clutch.engaged:
            p_r, R_r = self.tool.pose()
            self.clutch.engage(self.p_H_est, self.R_H_est, p_r, R_r)
            v, w = self.tool.twist()
            self.ctrl.reset(np.concatenate([v, w]))

    # -- read-outs ----------------------------------------------------------------------------------
    def _virtual_state(self, joints, rates):
        """(p, R, v, w) through φ of the handle at ``joints`` moving at ``rates`` (m, -, m/s,
        rad/s): one kinematics pass (the compiled closed form when the URDF allows)."""
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
        the observer estimates from the encoders (:mod:`teleop.master.observer`), through φ."""
        return self._virtual_state(self.observer.x, self.observer.rates)[2:]

    def virtual_estimate(self):
        """(p, R, v, w) of the virtual tool from the joint observer: its pose and twist (m, -, m/s,
        rad/s) estimated below the encoders' 25 µm / 0.5 mrad resolution, for the slave's target.
        The raw read-outs (:meth:`virtual_pose`) stay what the metrics use, as in the paper."""
        return self._virtual_state(self.observer.x, self.observer.rates)

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

    def _warn_light_tool(self, tool) -> None:
        """Log a warning when the rendered tool is lighter than the handle behind the load cell.
        The load cell feels that handle's inertia, compensated from the commanded motion; below it,
        what the compensation misses outweighs the tool, and the loop is stable only with a hand's
        damping on the handle (a scripted force alone ends on the tracking fault)."""
        m_tool, m_handle = getattr(getattr(tool, "body", None), "mass_kg", None), self.model.handle_mass_kg
        s2 = self.cfg.scale ** 2  # p_V = s p_H: the tool's mass m appears at the handle as s^2 m
        if m_tool is not None and m_tool * s2 < m_handle:
            self.log.warning(
                "cobot: the tool renders %.4g kg at the handle, lighter than the %.4g kg of handle behind the "
                "load cell; it is stable only with a hand's damping on the handle. Render at least %.4g kg "
                "(tool.mass_kg)", m_tool * s2, m_handle, m_handle / s2)

    def hand_state(self):
        """(p, R, v, w) of the handle the operator's hand holds, through φ into the virtual tool's
        space (m, -, m/s, rad/s). On the simulated device it is the handle's true state, so that a
        simulated hand's stiffness and damping act on the physical handle as a real hand's do
        (through the host's encoder estimate they would add its quantization and lag to the hand);
        on hardware, where a real hand needs no model, the encoder read-outs."""
        if self.sim is None:
            return (*self.virtual_pose(), *self.virtual_twist())
        return self._virtual_state(self.device.joints, self.device.qd)

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
