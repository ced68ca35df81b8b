"""The cobot's model: kinematics and inertia from its URDF (Pinocchio), shared by the host and the
simulated plant (:mod:`.plant`).

Joints x = (gantry x, y, z in m; wrist a, b, c in rad, Z-X-Z axes meeting at the handle origin H).
Frames: M (master base, = W here), H (handle = load-cell frame S). The handle mass is distal to the
load cell: the cell reads the hand's wrench plus the handle's weight and inertia.
"""

from __future__ import annotations

import math
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pinocchio as pin
from scipy.spatial.transform import Rotation

from teleop.master.cobot.kernels import distal_wrench_H, gantry_zxz_pose_jacobian
from teleop.util.errors import ConfigError
from teleop.util.resources import robot_file

DEFAULT_URDF = robot_file("cobot/cobot.urdf")
GRAVITY_W = np.array([0.0, 0.0, -9.81])


def handle_inertia_from_urdf(path: Path, link: str = "handle"):
    """(mass kg, COM (3,) m in the link's frame, inertia (3, 3) kg*m^2 about the COM) of ``link``;
    a link without ``<inertial>`` is massless, as URDF has it.

    Read from the URDF itself, not from Pinocchio's model: Pinocchio merges a link on a fixed joint
    into its parent joint's body (the wrist's last joint holds the wrist link, the load cell and the
    handle together: 0.25 kg, the handle alone 0.15 kg) and leaves the link's frame without an
    inertia, so the handle's own is not in the model. The test holds the parse to the model: the
    links' inertias placed at their frames sum to Pinocchio's merged body."""
    root = ET.parse(path).getroot()
    for el in root.findall("link"):
        if el.get("name") == link:
            inert = el.find("inertial")
            if inert is None:
                return 0.0, np.zeros(3), np.zeros((3, 3))
            m = float(inert.find("mass").get("value"))
            c = np.array([float(v) for v in inert.find("origin").get("xyz").split()])
            i = inert.find("inertia").attrib
            J = np.array([[float(i["ixx"]), float(i["ixy"]), float(i["ixz"])],
                          [float(i["ixy"]), float(i["iyy"]), float(i["iyz"])],
                          [float(i["ixz"]), float(i["iyz"]), float(i["izz"])]])
            return m, c, J
    raise ConfigError(f"{path}: no link named {link!r}")


def zxz_angles(R: np.ndarray) -> np.ndarray:
    """Wrist angles (a, b, c) rad with R = Rz(a) Rx(b) Rz(c), b in [0, pi] (scipy's intrinsic
    "ZXZ" Euler angles; at b = 0 or pi, gimbal lock, everything on a and c = 0, scipy's warning
    silenced: the start pose is still reached exactly)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return Rotation.from_matrix(np.asarray(R, dtype=float)).as_euler("ZXZ")


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
        angular acceleration alpha (rad/s^2), all in the world frame (:func:`.kernels.distal_wrench_H`
        turned into the world)."""
        R = np.asarray(R, dtype=float)
        F_H = distal_wrench_H(R, np.asarray(w, dtype=float), np.asarray(a_o, dtype=float),
                              np.asarray(alpha, dtype=float), self.handle_mass_kg, self.handle_com_H,
                              self.handle_J_H, GRAVITY_W)
        return np.concatenate([R @ F_H[:3], R @ F_H[3:]])


def compute_servo_lag_s(bandwidth_hz: float) -> float:
    """Time constant (s) of a first-order velocity servo of bandwidth ``bandwidth_hz`` (Hz)."""
    return 1.0 / (2.0 * math.pi * bandwidth_hz)
