"""The in-process run's heartbeat (teleop.tick.heartbeat, the two-process run's own logic) on a
simulated channel cut mid-cut: each way, and both. The side that hears nothing detects it on the
first tick past ``heartbeat_ms`` of silence and goes to its safe state (master: tool at zero
velocity, remote force dropped; slave: joints held, replies link_lost); the master also when the
slave's replies say link_lost; the run says link_lost."""

import numpy as np
import pytest

from teleop.app.runtime import run_scene
from teleop.scenario.schema import load_scene
from teleop.tick.loop import Hook

DT = 1e-3
CUT_TICK = 400


class Cut(Hook):
    """Cuts the channel's ``ways`` from tick CUT_TICK on and records both sides each tick."""

    def __init__(self, ways):
        self.ways, self.rows = ways, []

    def before_tick(self, i, t_s, loop):
        if i == CUT_TICK:
            loop.link.cut(t_s, self.ways)

    def after_tick(self, i, t_s, loop):
        self.rows.append((i, loop.master_side.heart.lost, loop.slave_side.heart.lost, np.abs(loop.tool.qd).max(),
                          np.abs(loop.feedback_W).max(), np.abs(loop.slave.arm.qd).max(), loop.slave.state.status,
                          np.linalg.norm(loop.slave.state.v)))


def _run(ways):
    scene = load_scene("straight_incision", sets=["duration_s=0.6"])
    hook = Cut(ways)
    result = run_scene(scene, hooks=[hook], simulated_link=True)
    return result, hook.rows


def _first(rows, col):
    return next(r[0] for r in rows if r[col])


@pytest.mark.parametrize("ways", [("command", "feedback"), ("command",), ("feedback",)])
def test_a_cut_link_is_detected_within_the_heartbeat_and_both_sides_hold(ways):
    result, rows = _run(ways)
    hb = result.summary["heartbeat"]
    assert hb["master"]["heartbeat_s"] == pytest.approx(0.02)
    # the last message came at tick CUT_TICK - 1: the first tick past 20 ms of silence is 21 later
    first = CUT_TICK - 1 + 21
    i_m = _first(rows, 1)
    if "feedback" in ways:
        assert i_m == first
    else:  # the master learns it from the slave's replies, the tick after the slave detects
        assert i_m == first + 1
    if "command" in ways:
        assert _first(rows, 2) == first
        assert all(r[6] == "link_lost" for r in rows if r[2])  # the slave says so while lost
    for i, lost_m, lost_s, tool_qd, fb, arm_qd, _, slave_speed in rows:
        assert (i >= i_m) == lost_m  # lost from detection to the end: no message comes back
        if lost_m:
            assert tool_qd == 0.0 and fb == 0.0  # the tool held, the remote force dropped
        if lost_s:
            assert arm_qd == 0.0  # the slave's joints held (no servo lag in this scene)
        if i >= i_m + 30:  # a slave hearing the master's clutch-out commands holds its tool (its QP
            assert slave_speed < 1e-3  # re-targets the pose each tick: it creeps at 0.2 mm/s, below 1 mm/s)
    assert result.summary["status"] == "link_lost"
    assert hb["master"]["lost_events"] == 1 and hb["master"]["detect_latency_s"][0] <= 0.0221


def test_an_intact_channel_never_trips_the_heartbeat():
    scene = load_scene("straight_incision", sets=["duration_s=0.3", "link.round_trip_ms=100", "link.loss=0.05"])
    result = run_scene(scene)
    hb = result.summary["heartbeat"]
    assert hb["master"]["lost_events"] == hb["slave"]["lost_events"] == 0
    assert result.summary["status"] != "link_lost"
