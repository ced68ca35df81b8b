"""The fault-injection campaign (tools/fault_campaign.py) on the straight cut, cobot master: each
single fault at a seeded random time is detected, the safe state comes within SAFE_WITHIN_S, and
nothing unsafe happens before it (the blade never past the fixture's depth by more than 50 um, no
contact force above the stated bound)."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))
import fault_campaign as fc  # noqa: E402  (a tool, not a package: imported from its folder)

FAST = ("sensor_nan", "corrupted_frames", "slave_solver_failure")


def check(fault: str, seed: int) -> dict:
    t = float(np.random.default_rng(seed).uniform(0.6, 0.9))
    row = fc.run_one("straight_incision", fault, t, seed)
    print(f"\n{fault}: detected as {row['detected_as']} after {row['t_detect_s']} s, safe after {row['t_safe_s']} s, "
          f"blade past depth {row['depth_excess_um']:.2f} um, force {row['force_max_N']:.1f} N")
    assert row["detected"] and row["t_detect_s"] <= fc.SAFE_WITHIN_S
    assert row["t_safe_s"] is not None and row["t_safe_s"] <= fc.SAFE_WITHIN_S
    assert row["depth_excess_um"] <= 1e6 * fc.DEPTH_TOL_M and row["force_max_N"] <= fc.FORCE_LIMIT_N
    assert not row["unsafe"] and row["status"] != "ok"  # the run's status names the fault
    return row


@pytest.mark.parametrize("fault", FAST)
def test_fault_detected_and_safe(fault):
    check(fault, 11)


@pytest.mark.long
@pytest.mark.parametrize("fault", [f for f in fc.FAULTS if f not in FAST and f != "slave_joint_limit"])
def test_every_other_fault_detected_and_safe(fault):
    check(fault, 12)


@pytest.mark.long
def test_a_slave_joint_limit_stays_safe():
    """A slave joint pinned at its position: the follower holds the fixture with the other joints.
    It is detected only when the follower's status escalates past "saturated" (which fault-free
    cuts report too): in the campaign, 1 run of 12 (an open gap, README). Detected or not, it must
    stay safe: blade within 50 um of the depth, force bounded."""
    t = float(np.random.default_rng(12).uniform(0.6, 0.9))
    row = fc.run_one("straight_incision", "slave_joint_limit", t, 12)
    print(f"\nslave_joint_limit: detected {row['detected']} ({row['detected_as']}), blade past depth "
          f"{row['depth_excess_um']:.2f} um, force {row['force_max_N']:.1f} N")
    assert not row["unsafe"] and row["depth_excess_um"] <= 1e6 * fc.DEPTH_TOL_M
    assert row["force_max_N"] <= fc.FORCE_LIMIT_N


def test_the_campaign_summary_counts_what_it_ran():
    rows = [{"fault": "sensor_nan", "t_detect_s": 0.001, "t_safe_s": 0.004, "unsafe": False, "depth_excess_um": 0.1,
             "force_max_N": 3.0, "detected_as": "device_emergency"},
            {"fault": "sensor_nan", "t_detect_s": None, "t_safe_s": None, "unsafe": True, "depth_excess_um": 80.0,
             "force_max_N": 3.0, "detected_as": ""}]
    (s,) = fc.summarize(rows)
    assert (s["injected"], s["detected"], s["reached_safe"], s["unsafe"]) == (2, 1, 1, 1)
    assert s["detect_ms_max"] == pytest.approx(1.0) and s["depth_excess_um_max"] == 80.0
    assert "| sensor_nan | 2 | 1 | 1 |" in fc.table([s])
