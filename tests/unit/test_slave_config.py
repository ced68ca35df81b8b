"""SlaveConfig parsing, model building, solver registry and joint-limit bounds."""

from pathlib import Path

import numpy as np
import pytest

from teleop.slave import JointLimits, SlaveConfig, build_model, installed_solvers, make_solver
from teleop.slave.arm import SCALPEL_URDF
from teleop.util.errors import ConfigError, SolverError


def test_defaults_build_a_panda_with_the_scalpel_frame():
    cfg = SlaveConfig.from_dict({}, "slave")
    am = build_model(cfg)
    assert am.model.nv == 7 and am.model.frames[am.frame_E].name == "E"
    # the tool frame sits 0.1 m beyond the grasp point along the hand's z axis
    import pinocchio as pin

    d = am.model.createData()
    pin.framesForwardKinematics(am.model, d, am.q0)
    tcp = d.oMf[am.model.getFrameId("panda_hand_tcp")]
    E = d.oMf[am.frame_E]
    assert np.allclose(tcp.actInv(E).translation, [0, 0, 0.1]) and np.allclose(tcp.rotation, E.rotation)


def test_ur5_and_urdf_arms_load():
    am = build_model(SlaveConfig.from_dict({"arm": "ur5"}, "slave"))
    assert am.model.nv == 6 and am.model.existFrame("E")
    import example_robot_data as erd

    path = erd.load("ur5").urdf if hasattr(erd.load("ur5"), "urdf") else None
    if path is None:
        from example_robot_data.robots_loader import UR5Loader

        path = UR5Loader().df_path
    cfg = SlaveConfig.from_dict({"arm": {"urdf": path, "flange": "tool0"},
                                 "tool": {"urdf": str(SCALPEL_URDF), "tip": "scalpel_tip"}}, "s")
    assert build_model(cfg).model.nv == 6


@pytest.mark.parametrize("d, key", [
    ({"bogus": 1}, "slave.bogus"),
    ({"arm": "kuka"}, "slave.arm"),
    ({"tool": "saw"}, "slave.tool"),
    ({"solver": "gurobi"}, "slave.solver"),
    ({"eps": -1}, "slave.eps"),
    ({"weight_position": "x"}, "slave.weight_position"),
    ({"servo_lag_s": -0.1}, "slave.servo_lag_s"),
    ({"fallback": "panic"}, "slave.fallback"),
    ({"kkt_shortcut": "yes"}, "slave.kkt_shortcut"),
    ({"q0": [0, 0, 0]}, "slave.q0"),
    ({"arm": {"urdf": "/nope.urdf", "flange": "x"}}, "slave.arm.urdf"),
])
def test_bad_settings_name_the_key(d, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        build_model(SlaveConfig.from_dict(d, "slave"))


def test_config_is_frozen():
    cfg = SlaveConfig.from_dict({}, "slave")
    with pytest.raises(AttributeError):
        cfg.eps = 1.0


def test_unknown_solver_lists_installed():
    with pytest.raises(SolverError) as exc:
        make_solver("cplex", 3, 1)
    for name in installed_solvers():
        assert name in str(exc.value)
    assert set(installed_solvers()) >= {"osqp", "daqp", "quadprog", "proxqp"}


def test_a_supported_solver_that_is_not_installed_says_how_to_install_it(monkeypatch):
    import teleop.slave.arm as arm

    monkeypatch.setattr(arm, "installed_solvers", lambda: ("osqp",))
    with pytest.raises(ConfigError, match=r"^slave\.solver: QP solver 'proxqp' is supported but not installed "
                                          r"\(pip install proxsuite\); installed: \['osqp'\]$"):
        SlaveConfig.from_dict({"solver": "proxqp"}, "slave")


def test_shipped_scenes_run_on_the_base_install():
    """The README's first command installs no test extras: a shipped scene may only name the QP
    solver of the base dependencies (OSQP; daqp, proxqp, quadprog come with the test extras)."""
    from teleop.scenario.schema import list_scenes, load_scene

    for name in list_scenes():
        slave = load_scene(name).slave
        assert slave is None or slave.solver == "osqp", name


def test_scene_errors_name_the_key_once(tmp_path):
    from teleop.scenario.schema import load_scene
    from teleop.tick.slave_side import SlaveSide
    from teleop.util.errors import SceneError

    text = (Path(load_scene("straight_incision").path).read_text()
            .replace('arm = "panda"', 'arm = "panda"\nsolver = "gurobi"'))
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(SceneError) as exc:
        SlaveSide(load_scene(str(path)), 10)
    assert str(exc.value) == f"{path}: slave.solver: unknown QP solver 'gurobi'; installed: {list(installed_solvers())}"


def test_limits_bounds():
    lim = JointLimits([-1, -1], [1, 1], [2, 2], [10, 10])
    lb, ub = lim.compute_velocity_bounds(np.array([0.0, 0.999]), np.zeros(2), 1e-3)
    # at rest: the acceleration limit a*dt = 0.01 rad/s binds on both joints
    assert np.allclose(lb, [-0.01, -0.01]) and np.allclose(ub, [0.01, 0.01])
    # 5e-5 rad from the limit at 0.05 rad/s: braking bound sqrt(2 a d) = 0.0316 rad/s lies below the
    # acceleration box [0.04, 0.06], so the position limit wins and the box collapses onto it
    lb, ub = lim.compute_velocity_bounds(np.array([0.0, 1.0 - 5e-5]), np.array([0.0, 0.05]), 1e-3)
    assert np.isclose(ub[1], np.sqrt(2 * 10 * 5e-5)) and lb[1] == ub[1]
    # beyond the limit, only motion back inside is allowed
    lb, ub = lim.compute_velocity_bounds(np.array([0.0, 1.01]), np.zeros(2), 1e-3)
    assert ub[1] == 0.0 and lb[1] < 0.0
    with pytest.raises(ConfigError, match="v_max"):
        JointLimits([-1], [1], [0.0], [1.0])
    with pytest.raises(ConfigError, match="q_min"):
        JointLimits([1], [-1], [1.0], [1.0])
