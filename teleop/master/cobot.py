"""The cobot device: its model (URDF with Pinocchio) and its physics (servos, encoders, load cell).

Joints x = (gantry x, y, z in m; wrist a, b, c in rad, Z-X-Z axes meeting at the handle origin H).
Frames: M (master base, = W here), H (handle = load-cell frame S). The handle mass is distal to the
load cell: the cell reads the hand's wrench plus the handle's weight and inertia.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from teleop.dynamics.rotations import cross
from teleop.master.kernels import gantry_zxz_pose_jacobian
from teleop.errors import ConfigError
from teleop.resources import robot_file

DEFAULT_URDF = robot_file("cobot/cobot.urdf")
GRAVITY_W = np.array([0.0, 0.0, -9.81])


def handle_inertia_from_urdf(path: Path, link: str = "handle"):
    """(mass kg, COM (3,) m in the handle frame, inertia (3, 3) kg*m^2 about the COM) of ``link``."""
    root = ET.parse(path).getroot()
    for el in root.findall("link"):
        if el.get("name") == link:
            inert = el.find("inertial")
            m = float(inert.find("mass").get("value"))
            c = np.array([float(v) for v in inert.find("origin").get("xyz").split()])
            i = inert.find("inertia").attrib
            J = np.array([[float(i["ixx"]), float(i["ixy"]), float(i["ixz"])],
                          [float(i["ixy"]), float(i["iyy"]), float(i["iyz"])],
                          [float(i["ixz"]), float(i["iyz"]), float(i["izz"])]])
            return m, c, J
    raise ConfigError(f"{path}: no link named {link!r}")


def zxz_angles(R: np.ndarray) -> np.ndarray:
    """Wrist angles (a, b, c) rad with R = Rz(a) Rx(b) Rz(c), b in [0, pi]."""
    b = math.acos(max(-1.0, min(1.0, R[2, 2])))
    if math.sin(b) < 1e-9:  # singular: put everything on a
        return np.array([math.atan2(R[1, 0], R[0, 0]), b, 0.0])
    return np.array([math.atan2(R[0, 2], -R[1, 2]), b, math.atan2(R[2, 0], R[2, 1])])


class CobotModel:
    """Kinematics and inertia of the device (owns a ``pin.Data`` workspace)."""

    def __init__(self, urdf_path: str | Path = DEFAULT_URDF):
        self.urdf_path = Path(urdf_path)
        self.model = pin.buildModelFromUrdf(str(self.urdf_path))
        self.data = self.model.createData()
        if self.model.nv != 6:
            raise ConfigError(f"{urdf_path}: expected 6 joints, got {self.model.nv}")
        self.fid = self.model.getFrameId("handle")
        self.handle_mass_kg, self.handle_com_H, self.handle_J_H = handle_inertia_from_urdf(self.urdf_path)
        self._qslots = [(j.idx_q, j.nq) for j in self.model.joints[1:]]
        self.lower = np.array([-0.4, -0.4, -0.4, -np.inf, 0.05, -np.inf])
        self.upper = np.array([0.4, 0.4, 0.4, np.inf, math.pi - 0.05, np.inf])
        for k, (iq, nq) in enumerate(self._qslots):
            if nq == 1:
                self.lower[k] = self.model.lowerPositionLimit[iq]
                self.upper[k] = self.model.upperPositionLimit[iq]
        self._q = pin.neutral(self.model)
        self.closed_form = self._check_closed_form()

    def pin_q(self, joints) -> np.ndarray:
        q = self._q
        for x, (iq, nq) in zip(joints, self._qslots):
            if nq == 2:
                q[iq], q[iq + 1] = math.cos(x), math.sin(x)
            else:
                q[iq] = x
        return q

    def compute_handle_pose(self, joints):
        """(p (3,) m, R (3, 3)) of H in M."""
        pin.framesForwardKinematics(self.model, self.data, self.pin_q(joints))
        X = self.data.oMf[self.fid]
        return X.translation.copy(), X.rotation.copy()

    def compute_jacobian(self, joints) -> np.ndarray:
        """J (6, 6): joint rates -> handle twist (v m/s, w rad/s) in M; call after the pose."""
        return pin.computeFrameJacobian(self.model, self.data, self.pin_q(joints), self.fid,
                                        pin.LOCAL_WORLD_ALIGNED)

    def _check_closed_form(self, n: int = 8) -> bool:
        """Whether this URDF is the gantry + Z-X-Z wrist of :func:`gantry_zxz_pose_jacobian`:
        checked against Pinocchio at n random joint vectors (1e-12)."""
        rng = np.random.default_rng(0)
        for _ in range(n):
            x = rng.uniform(-1.0, 1.0, 6)
            ref = self._pin_pose_and_jacobian(x)
            got = gantry_zxz_pose_jacobian(x)
            if not all(np.allclose(a, b, rtol=0.0, atol=1e-12) for a, b in zip(got, ref)):
                return False
        return True

    def compute_pose_and_jacobian(self, joints):
        """(p (3,) m, R (3, 3), J (6, 6)) of H in M from one kinematics pass; the Jacobian maps the
        joint rates to the handle twist (v m/s, w rad/s) in M. Closed form (compiled) when the URDF
        is the shipped gantry + Z-X-Z wrist (checked at load), otherwise Pinocchio."""
        if self.closed_form:
            return gantry_zxz_pose_jacobian(np.asarray(joints, dtype=float))
        return self._pin_pose_and_jacobian(joints)

    def _pin_pose_and_jacobian(self, joints):
        m, d = self.model, self.data
        pin.computeJointJacobians(m, d, self.pin_q(joints))
        X = pin.updateFramePlacement(m, d, self.fid)
        J = pin.getFrameJacobian(m, d, self.fid, pin.LOCAL_WORLD_ALIGNED)
        return X.translation.copy(), X.rotation.copy(), J

    def compute_mass_matrix(self, joints) -> np.ndarray:
        """M_m(x) (6, 6): the manipulandum's joint-space inertia (kg, kg*m^2)."""
        return pin.crba(self.model, self.data, self.pin_q(joints)).copy()

    def compute_joints(self, p, R) -> np.ndarray:
        """Inverse kinematics: joints (6,) with the handle at (p m, R)."""
        return np.concatenate([np.asarray(p, dtype=float), zxz_angles(R)])

    def compute_distal_wrench_W(self, R, w, a_o, alpha) -> np.ndarray:
        """Wrench (6,: N, N*m, world, at H) the handle's weight and inertia put on the load cell,
        for handle rotation R, angular velocity w (rad/s), origin acceleration a_o (m/s^2) and
        angular acceleration alpha (rad/s^2), all in the world frame."""
        m = self.handle_mass_kg
        c = R @ self.handle_com_H
        a_c = a_o + cross(alpha, c) + cross(w, cross(w, c))
        f = m * (GRAVITY_W - a_c)
        J_W = R @ self.handle_J_H @ R.T
        tau = cross(c, f) - J_W @ alpha - cross(w, J_W @ w)
        return np.concatenate([f, tau])


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


class CobotDevice:
    """The physical device in simulated time: velocity servos with a first-order lag and velocity,
    acceleration and travel limits; quantized encoders; a noisy, biased load cell."""

    def __init__(self, model: CobotModel, params: DeviceParams, joints0, rng: np.random.Generator):
        self.model, self.params, self.rng = model, params, rng
        self.tau_s = 1.0 / (2.0 * math.pi * params.servo_bandwidth_hz)
        self.vmax = np.array(params.max_velocity, dtype=float)
        self.amax = np.array(params.max_acceleration, dtype=float)
        self.res = np.array([params.encoder_m] * 3 + [params.encoder_rad] * 3)
        self.bias = np.array(list(params.force_bias_N) + list(params.torque_bias_Nm), dtype=float)
        self.noise = np.array([params.force_noise_N] * 3 + [params.torque_noise_Nm] * 3)
        self.joints = np.array(joints0, dtype=float)
        self.qd = np.zeros(6)
        self.qd_cmd = np.zeros(6)
        self.t = 0.0
        self.hand_wrench_W = np.zeros(6)  # the operator's hand on the handle (N, N*m at H, world)

    def set_command(self, qd_cmd, t: float) -> None:
        """Velocity command (6,) taking effect at time t (s); clipped to the velocity limits."""
        self.advance_to(t)
        self.qd_cmd = np.clip(np.nan_to_num(np.asarray(qd_cmd, float)), -self.vmax, self.vmax)

    def advance_to(self, t: float) -> None:
        """Integrate the servos exactly (first-order lag) up to time t (s)."""
        h = t - self.t
        if h <= 0:
            return
        e = math.exp(-h / self.tau_s)
        qd_new = self.qd_cmd + (self.qd - self.qd_cmd) * e
        if np.any(np.abs(qd_new - self.qd) > self.amax * h):  # acceleration-limited: ramp
            qd_new = self.qd + np.clip(qd_new - self.qd, -self.amax * h, self.amax * h)
            self.joints = self.joints + 0.5 * (self.qd + qd_new) * h
        else:
            self.joints = self.joints + self.qd_cmd * h + (self.qd - self.qd_cmd) * self.tau_s * (1.0 - e)
        self.qd = qd_new
        hit = (self.joints < self.model.lower) | (self.joints > self.model.upper)
        if np.any(hit):  # hard stops
            self.joints = np.clip(self.joints, self.model.lower, self.model.upper)
            self.qd[hit] = 0.0
        self.t = t

    def joint_acceleration(self) -> np.ndarray:
        return np.clip((self.qd_cmd - self.qd) / self.tau_s, -self.amax, self.amax)

    def sample_encoders(self) -> np.ndarray:
        """Joint readings (6,): quantized, the wrist angles wrapped to [-pi, pi)."""
        counts = np.round(self.joints / self.res) * self.res
        counts[3:] = np.round(((counts[3:] + np.pi) % (2 * np.pi) - np.pi) / self.res[3:]) * self.res[3:]
        return counts

    def sample_load_cell(self) -> np.ndarray:
        """Load-cell wrench (6,: N, N*m) in the load-cell frame S = H: hand + distal handle mass."""
        m = self.model
        p, R = m.compute_handle_pose(self.joints)
        J = m.compute_jacobian(self.joints)
        qdd = self.joint_acceleration()
        tw = J @ self.qd
        # handle acceleration (origin and angular) from the servo state, via Pinocchio
        a = pin.getFrameClassicalAcceleration(*self._accel(qdd), m.fid, pin.LOCAL_WORLD_ALIGNED)
        F_W = self.hand_wrench_W + m.compute_distal_wrench_W(R, tw[3:], a.linear, a.angular)
        meas = np.concatenate([R.T @ F_W[:3], R.T @ F_W[3:]])
        return meas + self.bias + self.noise * self.rng.standard_normal(6)

    def _accel(self, qdd):
        m = self.model
        pin.forwardKinematics(m.model, m.data, m.pin_q(self.joints), self.qd, qdd)
        pin.updateFramePlacements(m.model, m.data)
        return m.model, m.data
