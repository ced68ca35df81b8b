"""Model-mediated contact (``[link] model_mediated``, issue 23) on the stiff contact: the master
renders the slave's estimated surface as a wall of its own and the slave presses no harder than
that wall. Walls of 30 and 100 kN/m at 250 ms and 1 s round trip with 5 % loss stay ok, settle
(no motion above 0.01 m/s) and peak within twice the undelayed force; what the slave presses is
what the master renders once both have settled; the cut is left to its damping model."""

import numpy as np
import pytest

from teleop.app.assembly import model_mediated
from teleop.app.runtime import run_scene
from teleop.scenario.schema import load_scene

SETTLED = slice(-1000, None)  # the last second


def _run(wall, delay_ms, loss, seconds=4.0):
    scene = load_scene("stiff_contact", sets=[f"tissue.stiffness={wall}", f"link.round_trip_ms={delay_ms}",
                                              f"link.loss={loss}", f"duration_s={seconds}", "link.model_mediated=true"])
    r = run_scene(scene)
    return scene, r


def _settled_speed(scene, r):
    tip = np.asarray(r.log["slave_tip"])[SETTLED]
    v_slave = np.linalg.norm(np.diff(tip, axis=0), axis=1) / scene.dt_s
    return float(max(v_slave.max(), np.asarray(r.log["m_speed_m_s"])[SETTLED].max()))


@pytest.mark.parametrize("wall,delay_ms", [(30_000.0, 250.0), (100_000.0, 1000.0)])
def test_a_stiff_wall_behind_a_long_lossy_link_is_held(wall, delay_ms):
    _, r0 = _run(wall, 0.0, 0.0)
    scene, r = _run(wall, delay_ms, 0.05)
    assert r0.summary["status"] == "ok" and r.summary["status"] == "ok", r.summary["status_reason"]
    F0, F = np.asarray(r0.log["slave_contact_N"]), np.asarray(r.log["slave_contact_N"])
    assert F.max() <= 2.0 * F0.max()
    assert _settled_speed(scene, r) <= 0.01
    assert np.all(np.isfinite(F)) and r.summary["pressed_less_ticks"] > 0  # the slave's bound did the holding


def test_what_the_slave_presses_is_what_the_master_renders():
    _, r = _run(10_000.0, 100.0, 0.05)
    assert r.summary["status"] == "ok"
    felt = np.linalg.norm(np.asarray(r.log["felt_W"])[SETTLED, :3], axis=1).mean()
    pressed = np.asarray(r.log["slave_contact_N"])[SETTLED].mean()
    assert pressed == pytest.approx(felt, rel=0.1)
    # the master's wall sits where it found the surface: its offset from the slave's is reported
    assert r.summary["metrics"]["link_wall_offset_final_m"] > 0.0


def test_the_cut_keeps_its_damping_model():
    scene = load_scene("straight_incision", sets=["link.model_mediated=true"])
    assert not model_mediated(scene)
    assert model_mediated(load_scene("stiff_contact", sets=["link.model_mediated=true"]))


@pytest.mark.long
def test_a_stiff_wall_behind_a_delay_is_held_through_the_cobot():
    """The same through the simulated CAN cobot (its renderable stiffness is ~3.9e5 N/m on the
    probe, robots/cobot and the scene's note): 100 kN/m at 1 s round trip with 5 % loss."""
    scene = load_scene("stiff_contact", sets=["tissue.stiffness=100000.0", "link.round_trip_ms=1000.0",
                                              "link.loss=0.05", 'master="cobot"'])
    r = run_scene(scene)
    assert r.summary["status"] == "ok", r.summary["status_reason"]
    assert np.asarray(r.log["slave_contact_N"]).max() < 5.0 and _settled_speed(scene, r) <= 0.01
