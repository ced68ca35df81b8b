"""The guard's drift on the cut at 1 s round trip: reported, and paid back by the end. The
slave's target falls behind while the delayed master does not yet feel the cut; the drift spring
reflected to the master makes the hand pay for the catch-up. Before the spring the cut ended
19 mm short at 1 s (4.3 mm at 200 ms); with it 0.009 mm. Since the contact's damping is rendered at
the master the drift is smaller (0.9 mm at most at 200 ms, 6.7 mm at 1 s), so the test takes the
1 s point, where the drift is large: held back by more than 3 mm, paid back to under 0.05 mm
(0.003 mm measured), and the fixtures still hold the depth."""

import numpy as np
import pytest

from teleop.app.runtime import run_scene
from teleop.scenario.schema import load_scene


@pytest.mark.long  # the whole 7 s cut: ~20 s on this machine
def test_cut_drift_is_paid_back_at_1s():
    scene = load_scene("straight_incision", sets=["link.round_trip_ms=1000", 'link.passivity="tdpa"'])
    r = run_scene(scene)
    s, m = r.summary, r.summary["metrics"]
    assert s["status"] == "ok" and not s["nan"]
    assert m["link_drift_max_m"] > 3e-3  # the guard did hold the slave back (reported)
    assert m["link_drift_final_m"] < 5e-5  # and it was taken back
    assert m["cut_depth_error_max_m"] <= 50e-6
    drift = np.linalg.norm(r.log["tdpa_drift_M"][:, :3], axis=1) / scene.mapping.registration().scale
    assert drift[-1] == m["link_drift_final_m"] and drift.max() == m["link_drift_max_m"]
    assert s["passivity"]["W_slave_min_J"] > -1e-6  # the slave's observer after its controller
