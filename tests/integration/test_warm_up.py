"""A two-process side's warm-up (teleop.app.netrun.warm_up) loads every compiled kernel the run
will call, so that none loads mid-run: a numba kernel loads once per argument type signature, 5-130
ms each from the cache, and one loaded on the slave's first tick without a command (a stand-in
array writable where a command's is read-only) stalled it 22 ms at 2 kHz, past the master's 20 ms
heartbeat (``link_lost`` in two of three Zenoh runs).

The run after the warm-up is the same two sides in one process over a channel that delays, loses
in bursts (ticks without a command, replies without contact news, both heartbeats lost and
regained) and jitters, on a cut, on a stiff wall rendered model-mediated and on the CAN cobot with
its faults (its held ticks once passed the device's controller read-only twists): no kernel may
gain a signature."""

import pytest

from teleop.app import netrun
from teleop.app.runtime import run_scene
from teleop.scenario.schema import load_scene
from teleop.util.numba_cache import compiled_kernels

ROUGH_LINK = ["link.round_trip_ms=6.0", "link.jitter_ms=1.0", "link.loss=0.05", "link.burst_enter=0.01",
              "link.burst_exit=0.02", "link.passivity='tdpa'"]


def _signatures() -> dict[str, set]:
    """Every compiled kernel of the package's loaded modules: its signatures so far."""
    return {name: set(kernel.signatures) for name, kernel in compiled_kernels().items()}


@pytest.mark.parametrize(("scene", "sets"), [("straight_incision", []),
                                             ("stiff_contact", ["tissue.stiffness=30000.0"]),
                                             ("can_faults_incision", ["dt_s=0.001"])])
def test_no_kernel_loads_after_the_warm_up(scene, sets):
    sc = load_scene(scene, sets=["dt_s=0.0005", "duration_s=1.5", *sets, *ROUGH_LINK])  # sets may set dt_s again
    netrun.warm_up(sc, "master", cached=False)  # the twin alone: the cache may hold anything
    netrun.warm_up(sc, "slave", cached=False)
    before = _signatures()
    assert before, "no compiled kernel found: the check would assert nothing"
    run = run_scene(sc).summary
    heart = run["heartbeat"]
    assert heart["master"]["lost_events"] > 0 and heart["slave"]["lost_events"] > 0  # the hold paths ran too
    after = _signatures()
    new = {k: sorted(map(str, after[k] - before.get(k, set()))) for k in after if after[k] - before.get(k, set())}
    assert not new, f"kernels loaded mid-run, after the warm-up: {new}"
