"""The master port passive by construction (issue 23, item 1), with ``guard_slows_motion``: the
guard scales the tool's velocity after each step so that its observer never goes below zero,
whatever the force, the remote energy and the motion; checked on the port alone over random
sequences, and on a running stiff contact over random walls and channels (hypothesis); with
model-mediated contact, both ports and the run's status."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop.control.passivity import MasterPassivity, TdpaParams

DT = 1e-3
floats = st.floats(-50.0, 50.0, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(steps=st.lists(st.tuples(st.lists(floats, min_size=6, max_size=6), st.lists(floats, min_size=6, max_size=6),
                                st.floats(0.0, 1e-3)), min_size=1, max_size=60))
def test_the_ports_observer_never_goes_below_zero(steps):
    port = MasterPassivity(TdpaParams(dt_s=DT, slows_motion=True))
    E_remote = np.zeros(6)
    for f, v, gain in steps:
        v_after = np.asarray(v) * 0.01  # m/s: the tool's twist after the step under the force rendered last
        sigma = port.motion_scale(v_after)
        assert 0.0 <= sigma <= 1.0
        E_remote = E_remote + gain  # the slave's input energy only grows
        port.step(np.asarray(f), sigma * v_after, E_remote)
        assert float(port.W.min()) >= -1e-12


@settings(max_examples=6, deadline=None)
@given(k=st.sampled_from([1e3, 1e4, 3e4, 1e5]), rt_ms=st.sampled_from([0.0, 10.0, 100.0, 500.0]),
       loss=st.sampled_from([0.0, 0.05, 0.1]), burst=st.sampled_from([0.0, 0.02]))
def test_a_stiff_contact_keeps_the_master_port_passive_over_random_walls_and_channels(k, rt_ms, loss, burst):
    from teleop.app.runtime import run_scene
    from teleop.scenario.schema import load_scene

    sets = [f"tissue.stiffness={k}", f"link.round_trip_ms={rt_ms}", f"link.loss={loss}",
            f"link.burst_enter={burst}", 'link.passivity="tdpa"', "link.guard_slows_motion=true", "duration_s=1.5"]
    s = run_scene(load_scene("stiff_contact", sets=sets)).summary
    assert s["nan"] is False
    assert s["passivity"]["W_master_min_J"] >= -1e-9


@settings(max_examples=6, deadline=None)
@given(k=st.sampled_from([1e3, 1e4, 3e4, 1e5]), rt_ms=st.sampled_from([0.0, 10.0, 250.0, 1000.0, 2000.0]),
       loss=st.sampled_from([0.0, 0.05, 0.1]), burst=st.sampled_from([0.0, 0.02]))
def test_model_mediated_contact_keeps_both_ports_passive_and_the_wall_held(k, rt_ms, loss, burst):
    """Model-mediated (the wall rendered at the master, updated passively, the slave pressing no
    harder) with the motion scaled: both ports' observers never below -1e-9 J, and the run ok."""
    from teleop.app.runtime import run_scene
    from teleop.scenario.schema import load_scene

    sets = [f"tissue.stiffness={k}", f"link.round_trip_ms={rt_ms}", f"link.loss={loss}",
            f"link.burst_enter={burst}", 'link.passivity="tdpa"', "link.guard_slows_motion=true",
            "link.model_mediated=true", "duration_s=2.5"]
    s = run_scene(load_scene("stiff_contact", sets=sets)).summary
    assert s["status"] == "ok", s["status_reason"]
    assert s["passivity"]["W_master_min_J"] >= -1e-9 and s["passivity"]["W_slave_min_J"] >= -1e-9
