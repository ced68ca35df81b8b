"""The device model: kinematics, Jacobian, inertia, load cell, servos, encoders."""

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from teleop.master.cobot.model import DEFAULT_URDF, CobotModel, handle_inertia_from_urdf, zxz_angles
from teleop.master.cobot.plant import CobotPlant, DeviceParams


@pytest.fixture(scope="module")
def model():
    return CobotModel()


def test_ik_fk_round_trip(model):
    rng = np.random.default_rng(3)
    for _ in range(20):
        joints = np.concatenate([rng.uniform(-0.3, 0.3, 3), rng.uniform(-3, 3, 1), rng.uniform(0.2, 2.9, 1),
                                 rng.uniform(-3, 3, 1)])
        p, R = model.compute_handle_pose(joints)
        assert np.allclose(p, joints[:3])
        back = model.compute_joints(p, R)
        assert np.allclose(model.compute_handle_pose(back)[1], R, atol=1e-12)
        assert np.allclose(zxz_angles(R), joints[3:], atol=1e-9)


@pytest.mark.parametrize("b", [0.0, np.pi])
def test_ik_at_the_wrist_singularity_reaches_the_pose(model, b):
    """Gimbal lock (b = 0 or pi): a and c are not separable; the angles found put the handle on
    the pose exactly, with c = 0."""
    R = pin.exp3(np.array([0.0, 0.0, 0.7])) @ pin.exp3(np.array([b, 0.0, 0.0])) @ pin.exp3(np.array([0, 0, -0.2]))
    joints = model.compute_joints(np.zeros(3), R)
    assert joints[5] == 0.0 and joints[4] == pytest.approx(b, abs=1e-12)
    assert np.allclose(model.compute_handle_pose(joints)[1], R, atol=1e-12)


def test_jacobian_matches_finite_differences(model):
    joints = np.array([0.1, -0.05, 0.02, 0.4, 1.2, -0.7])
    J = model.compute_jacobian(joints)
    p0, R0 = model.compute_handle_pose(joints)
    h = 1e-7
    for i in range(6):
        d = joints.copy()
        d[i] += h
        p1, R1 = model.compute_handle_pose(d)
        assert np.allclose((p1 - p0) / h, J[:3, i], atol=1e-6)
        assert np.allclose(pin.log3(R1 @ R0.T) / h, J[3:, i], atol=1e-6)


def test_mass_matrix_and_handle_inertia(model):
    M = model.compute_mass_matrix(np.array([0, 0, 0, 0, 1.57, 0]))
    assert np.allclose(M, M.T) and np.linalg.eigvalsh(M).min() > 0
    assert M[0, 0] == pytest.approx(4.0 + 3.0 + 2.0 + 0.4 + 0.3 + 0.1 + 0.15)  # everything rides on x
    assert model.handle_mass_kg == 0.15 and np.allclose(model.handle_com_H, [0, 0, 0.03])


def test_distal_wrench_static_is_the_handle_weight(model):
    R = np.eye(3)
    F = model.compute_distal_wrench_W(R, np.zeros(3), np.zeros(3), np.zeros(3))
    assert np.allclose(F[:3], [0, 0, -0.15 * 9.81])
    assert np.allclose(F[3:], 0.0)  # COM straight above the cell: no moment
    F = model.compute_distal_wrench_W(pin.exp3(np.array([np.pi / 2, 0, 0])), np.zeros(3), np.zeros(3), np.zeros(3))
    assert np.allclose(F[3:], np.cross([0, -0.03, 0], [0, 0, -0.15 * 9.81]))


def test_servo_lag_limits_and_encoder_quantum(model):
    p = DeviceParams(servo_bandwidth_hz=100.0, force_noise_N=0, torque_noise_Nm=0)
    dev = CobotPlant(model, p, np.array([0, 0, 0, 0, 1.5, 0]), np.random.default_rng(0))
    dev.set_command([0.01, 0, 0, 0, 0, 0], 0.0)  # a step small enough to stay under 20 m/s^2
    tau = 1 / (2 * np.pi * 100.0)
    dev.advance_to(tau)
    assert dev.qd[0] == pytest.approx(0.01 * (1 - np.exp(-1)), rel=1e-9)
    dev.advance_to(0.1)
    assert dev.qd[0] == pytest.approx(0.01) and dev.joints[0] == pytest.approx(0.01 * (0.1 - tau), rel=1e-4)
    dev.set_command([9.0, 0, 0, 0, 0, 0], 0.1)
    assert dev.qd_cmd[0] == p.max_velocity[0]
    dev.advance_to(0.101)  # acceleration-limited: at most 20 m/s^2 * 1 ms
    assert dev.qd[0] - 0.01 == pytest.approx(p.max_acceleration[0] * 1e-3)
    dev.joints[:] = [1.234567e-3, 0, 0, 0, 1.5, 3.2]
    enc = dev.sample_encoders()
    assert enc[0] == pytest.approx(1.225e-3) and -np.pi <= enc[5] < np.pi
    assert abs(enc[5] - (3.2 - 2 * np.pi)) <= 2.5e-4


def test_load_cell_bias_noise_seeded(model):
    def reading(seed):
        dev = CobotPlant(model, DeviceParams(), np.array([0, 0, 0, 0, 1.5, 0]), np.random.default_rng(seed))
        return dev.sample_load_cell()
    assert np.array_equal(reading(4), reading(4)) and not np.array_equal(reading(4), reading(5))


def test_closed_form_kinematics_match_pinocchio_and_other_urdfs_fall_back(tmp_path):
    """The compiled gantry + Z-X-Z kinematics serve the shipped URDF; a URDF with another
    geometry (a handle offset from the wrist centre) is detected and runs on Pinocchio."""
    from teleop.master.cobot.model import DEFAULT_URDF, CobotModel

    model = CobotModel()
    assert model.closed_form
    rng = np.random.default_rng(3)
    for _ in range(20):
        x = rng.uniform(-2.0, 2.0, 6)
        for a, b in zip(model.compute_pose_and_jacobian(x), model._pin_pose_and_jacobian(x)):
            np.testing.assert_allclose(a, b, atol=1e-12)
    text = DEFAULT_URDF.read_text().replace(
        '<parent link="load_cell"/><child link="handle"/><origin xyz="0 0 0"/>',
        '<parent link="load_cell"/><child link="handle"/><origin xyz="0 0 0.05"/>')
    other = tmp_path / "cobot_offset.urdf"
    other.write_text(text)
    shifted = CobotModel(other)
    assert not shifted.closed_form
    p, _R, _ = shifted.compute_pose_and_jacobian(np.zeros(6))
    np.testing.assert_allclose(p, [0.0, 0.0, 0.05], atol=1e-12)


def test_the_handle_inertia_parsed_from_the_urdf_sums_to_pinocchios_merged_wrist_body():
    """Pinocchio merges the links on the wrist's fixed joints into its last joint's body; the
    links' own inertias, read from the URDF and placed at Pinocchio's frames, must sum to it."""
    model = pin.buildModelFromUrdf(str(DEFAULT_URDF))
    joint = model.frames[model.getFrameId("handle")].parentJoint
    total = pin.Inertia.Zero()
    for f in model.frames:
        if f.type == pin.FrameType.BODY and f.parentJoint == joint:
            mass, com, J = handle_inertia_from_urdf(Path(DEFAULT_URDF), f.name)
            total += f.placement.act(pin.Inertia(mass, com, J))
    np.testing.assert_allclose(total.matrix(), model.inertias[joint].matrix(), atol=1e-12)
    assert handle_inertia_from_urdf(Path(DEFAULT_URDF))[0] == 0.15
