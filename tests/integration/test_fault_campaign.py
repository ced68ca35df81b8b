"""The fault-injection campaign (tools/fault_campaign.py), cobot master: each single fault at a
seeded random time is detected within its stated time (DETECT_WITHIN_S, else SAFE_WITHIN_S), the
safe state comes within SAFE_WITHIN_S, and nothing unsafe happens before it (the blade never past
the fixture's depth by more than 50 um, no contact force above the stated bound). The default run
holds five kinds on the straight cut; the long run every kind, there and on the laparoscopic cut
(the remote centre of motion)."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))
import fault_campaign as fc  # a tool, not a package: imported from its folder

FAST = ("sensor_nan", "corrupted_frames", "slave_solver_failure", "slave_joint_limit", "link_loss")


def check(fault: str, seed: int, scene: str = "straight_incision", window_s: float = fc.WINDOW_S,
          safe_within_s: float = fc.SAFE_WITHIN_S) -> dict:
    t = float(np.random.default_rng(seed).uniform(0.6, 0.9))
    row = fc.run_one(scene, fault, t, seed, window_s)
    print(f"\n{fault}: detected as {row['detected_as']} after {row['t_detect_s']} s, safe after {row['t_safe_s']} s, "
          f"blade past depth {row['depth_excess_um']:.2f} um, force {row['force_max_N']:.1f} N")
    assert row["detected"] and row["t_detect_s"] <= fc.DETECT_WITHIN_S.get(fault, fc.SAFE_WITHIN_S)
    assert row["t_safe_s"] is not None and row["t_safe_s"] <= safe_within_s
    assert row["depth_excess_um"] <= 1e6 * fc.DEPTH_TOL_M and row["force_max_N"] <= fc.FORCE_LIMIT_N
    assert not row["unsafe"] and row["status"] != "ok"  # the run's status names the fault
    return row


@pytest.mark.parametrize("fault", FAST)
def test_fault_detected_and_safe(fault):
    # the slave's faults and a link loss leave the run going: watched for 0.1 s here (the long
    # run and the campaign for 0.4 s)
    row = check(fault, 11, window_s=0.1 if fault.startswith("slave_") or fault == "link_loss" else fc.WINDOW_S)
    if fault == "slave_joint_limit":
        assert row["detected_as"] == "slave joint_limit" and row["t_detect_s"] <= 0.0011  # the next tick
    if fault == "link_loss":
        assert row["detected_as"].startswith("heartbeat") and row["status"] == "link_lost"


@pytest.mark.long
@pytest.mark.parametrize("fault", [f for f in fc.FAULTS if f not in FAST or f.startswith("slave_")])
def test_every_other_fault_detected_and_safe(fault):
    check(fault, 12)


@pytest.mark.long
@pytest.mark.parametrize("fault", fc.FAULTS)
def test_every_fault_on_the_laparoscopic_cut(fault):
    """The trocar cut too: detected and safe within SAFE_WITHIN_S (the slave's lag that once
    delayed its hold to 115 ms ended when it followed the admittance model's output)."""
    check(fault, 13, "laparoscopic_incision")


@pytest.mark.long
@pytest.mark.parametrize("seed, ways", [(12, "command"), (13, "feedback")])
def test_a_link_loss_of_one_way_is_detected(seed, ways):
    """The default run cuts both ways (seed 11); a cut of the commands alone is detected by the
    slave (and the master from its replies), of the feedback alone by the master."""
    row = check("link_loss", seed)
    assert row["ways_cut"] == ways


def test_the_campaign_summary_counts_what_it_ran():
    rows = [{"fault": "sensor_nan", "t_detect_s": 0.001, "t_safe_s": 0.004, "unsafe": False, "depth_excess_um": 0.1,
             "force_max_N": 3.0, "detected_as": "device_emergency"},
            {"fault": "sensor_nan", "t_detect_s": None, "t_safe_s": None, "unsafe": True, "depth_excess_um": 80.0,
             "force_max_N": 3.0, "detected_as": ""}]
    (s,) = fc.summarize(rows)
    assert (s["injected"], s["detected"], s["reached_safe"], s["unsafe"]) == (2, 1, 1, 1)
    assert s["detect_ms_max"] == pytest.approx(1.0) and s["depth_excess_um_max"] == 80.0
    assert "| sensor_nan | 2 | 1 | 1 |" in fc.table([s])
