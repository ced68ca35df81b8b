"""The slave follows scripted incisions at 1 kHz under the scalpel and trocar fixtures."""

import numpy as np
import pinocchio as pin
import pytest

from teleop.contact import TissueBlock
from teleop.dynamics import constraints as C
from teleop.dynamics import fixtures
from teleop.slave import SlaveArm, SlaveConfig

DT = 1e-3
PLANE_O = np.array([0.5, 0.0, 0.2])  # tissue surface 0.5 m in front of the Panda, 0.2 m above its base
N = np.array([0.0, 0.0, 1.0])
DEPTH = 0.005
R_CUT = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])  # blade down, cutting +x


def _incision(solver="osqp", curved=False):
    """Cut 50 mm at 10 mm/s, 5 mm deep: straight along x, or along an arc (knife-edge steering)."""
    fx = fixtures.scalpel(plane_origin=PLANE_O, plane_normal=N, depth=DEPTH)
    arm = SlaveArm(SlaveConfig.from_dict({"solver": solver}, "slave"), fx.constraints, DT)
    tissue = TissueBlock.from_dict({"origin_m": PLANE_O.tolist()}, "tissue")
    speed, length, radius = 0.01, 0.05, 0.05
    start = PLANE_O + np.array([-0.05, -0.02, -DEPTH])

    def target(t):
        s = min(speed * t, length)
        v = speed if speed * t < length else 0.0
        if not curved:
            return start + np.array([s, 0, 0]), R_CUT, np.array([v, 0, 0]), np.zeros(3)
        th = s / radius
        p = start + radius * np.array([np.sin(th), 1 - np.cos(th), 0.0])
        R = pin.exp3(np.array([0, 0, th])) @ R_CUT
        return p, R, v * np.array([np.cos(th), np.sin(th), 0]), np.array([0, 0, v / radius])

    p0, R0, _, _ = target(0.0)
    assert arm.reset((p0, R0)) == "ok"
    err, depth_err, dir_err, force, statuses = [], [], [], [], set()
    for k in range(1, int(length / speed / DT) + 1):
        p_t, R_t, v_t, w_t = target(k * DT)
        statuses.add(arm.step(p_t, R_t, v_t, w_t))
        p, R = arm.tool_pose()
        v, w = arm.tool_twist()
        err.append(np.linalg.norm(p - p_t))
        depth_err.append(abs(-(N @ (p - PLANE_O)) - DEPTH))
        dir_err.append(np.arccos(np.clip(R[:, 0] @ R_t[:, 0], -1.0, 1.0)))
        force.append(np.linalg.norm(tissue.wrench(p, R, v, w)[:3]))
        assert np.all(np.isfinite(arm.q)) and np.all(np.abs(arm.qd) <= arm.limits.v_max + 1e-9)
    return dict(rms=float(np.sqrt(np.mean(np.square(err)))), depth=max(depth_err), direction=max(dir_err),
                force=max(force), statuses=statuses, arm=arm)


@pytest.mark.parametrize("curved", [False, True], ids=["straight", "curved"])
def test_incision_accuracy(curved):
    r = _incision(curved=curved)
    assert r["rms"] <= 1e-4, r
    assert r["depth"] <= 5e-5, r
    assert r["direction"] <= 1e-3, r
    assert r["force"] > 0.0
    assert r["statuses"] <= {"ok", "saturated"}, r["statuses"]
    assert np.all(np.isfinite(r["arm"].tau)) and np.all(np.isfinite(r["arm"].fixture_forces))


def test_incision_with_daqp_matches_accuracy():
    r = _incision(solver="daqp")
    assert r["rms"] <= 1e-4 and r["depth"] <= 5e-5 and r["direction"] <= 1e-3


def test_laparoscopic_path_keeps_the_remote_centre():
    """The blade tip draws a 20 mm circle while the shaft pivots about a trocar 80 mm above it."""
    trocar = PLANE_O + np.array([0.0, 0.0, 0.075])
    rcm = C.RemoteCenter(center=trocar, point_B=(0.0, 0.0, 0.0), axis_B=(0.0, 0.0, 1.0), name="trocar")
    arm = SlaveArm(SlaveConfig.from_dict({}, "slave"), (rcm,), DT)
    centre, radius, omega = PLANE_O + np.array([0.0, 0.0, -0.005]), 0.01, 2 * np.pi / 4.0

    def pose(t):
        p = centre + radius * np.array([np.cos(omega * t), np.sin(omega * t), 0.0])
        z = (p - trocar) / np.linalg.norm(p - trocar)
        axis = np.cross(R_CUT[:, 2], z)
        ang = np.arctan2(np.linalg.norm(axis), R_CUT[:, 2] @ z)
        return p, pin.exp3(axis / max(np.linalg.norm(axis), 1e-12) * ang) @ R_CUT

    p0, R0 = pose(0.0)
    assert arm.reset((p0, R0)) == "ok"
    rcm_err, track = [], []
    for k in range(1, 4001):
        t = k * DT
        p_t, R_t = pose(t)
        p_n, R_n = pose(t + DT)
        arm.step(p_t, R_t, (p_n - p_t) / DT, pin.log3(R_n @ R_t.T) / DT)
        p, R = arm.tool_pose()
        rcm_err.append(np.linalg.norm(rcm.residual(p, R)))
        track.append(np.linalg.norm(p - p_t))
    assert max(rcm_err) <= 1e-4, max(rcm_err)
    assert np.sqrt(np.mean(np.square(track))) <= 1e-4
