"""A link lost and restored mid-cut (issue 21): each side holds in its own safe state, resumes
when messages come again, and the force the master renders from the slave never steps: it fades
out while the tool is held and ramps back in from zero after the resume, in one process and over
the simulated channel alike (the same MasterSide and SlaveSide)."""

import numpy as np

from teleop.app.runtime import run_scene
from teleop.scenario.schema import load_scene
from teleop.tick.ports import Hook

CUT, RESTORE = 1500, 1600
STEP_MAX_N = 0.5


class CutAndRestore(Hook):
    """Cuts both ways of the channel at tick CUT, restores them at RESTORE; records the felt force
    and both sides' heartbeats every tick."""

    def __init__(self):
        self.felt, self.lost_m, self.lost_s = [], [], []

    def before_tick(self, i, t_s, loop):
        if i == CUT:
            loop.link.cut(t_s)
        if i == RESTORE:
            loop.link.restore(t_s)

    def after_tick(self, i, t_s, loop):
        self.felt.append(np.array(loop.felt_W))
        self.lost_m.append(loop.master_side.heart.lost)
        self.lost_s.append(loop.slave_side.heart.lost)


class Felt(Hook):
    def __init__(self):
        self.felt = []

    def after_tick(self, i, t_s, loop):
        self.felt.append(np.array(loop.felt_W))


def _steps(felt):
    return np.linalg.norm(np.diff(np.asarray(felt)[:, :3], axis=0), axis=1)


def test_the_felt_force_ramps_after_a_lost_link_and_never_steps():
    _check(["duration_s=2.2"], STEP_MAX_N)


def test_over_a_delayed_channel_the_resume_adds_no_step_to_what_the_delay_itself_makes():
    """With 4 ms of round trip the cut's stick makes steps of its own (about 0.8 N) whether or not
    the link is lost; the loss and the resume add none beyond STEP_MAX_N to them."""
    sets = ["duration_s=2.2", "link.round_trip_ms=4", "link.jitter_ms=1"]
    intact = Felt()
    run_scene(load_scene("straight_incision", sets=sets), hooks=[intact], simulated_link=True)
    _check(sets, STEP_MAX_N + _steps(intact.felt).max())


def _check(sets, bound):
    scene = load_scene("straight_incision", sets=sets)
    hook = CutAndRestore()
    result = run_scene(scene, hooks=[hook], simulated_link=True)
    felt = np.array(hook.felt)
    lost = np.array(hook.lost_m)
    assert lost[CUT + 25] and not lost[RESTORE + 30] and not lost[:CUT].any()  # lost, then resumed
    assert np.abs(felt[CUT - 1, :3]).max() > 2.0  # the cut was pressing when the link went
    steps = _steps(felt)
    assert steps.max() <= bound, f"felt force stepped {steps.max():.3f} N at tick {steps.argmax() + 1}"
    hb = result.summary["heartbeat"]
    assert hb["master"]["resumed"] == 1 and hb["slave"]["resumed"] == 1
    assert np.abs(felt[-1, :3]).max() > 2.0  # the contact is felt again at the end
    assert result.summary["status"] == "link_lost"  # the run says what happened
