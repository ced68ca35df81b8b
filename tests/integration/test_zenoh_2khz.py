"""Two processes over Zenoh at 2 kHz: both sides tick at the scene's period (the master's steps are
duration / dt and the slave follows its last command), and two sides given different periods
refuse each other with one line instead of running apart. Not each tick on time: the machine is
shared (a wide heartbeat, as in test_zenoh_pair; the on-time share is measured in the design page)."""

import json
import subprocess
import sys

import pytest

pytest.importorskip("zenoh")

from teleop.app.netrun import free_endpoint
from teleop.link.keys import make_keys

PY = [sys.executable, "-m", "teleop"]


@pytest.mark.long
def test_a_2_khz_cut_over_zenoh_ticks_at_the_scenes_rate(tmp_path):
    out = tmp_path / "run.json"
    sets = ["duration_s=1.0", "link.heartbeat_ms=2000"]
    rc = subprocess.run([*PY, "run", "straight_incision", "--link", "zenoh", "--dt", "0.0005",
                         *[a for x in sets for a in ("--set", x)], "--json", str(out)],
                        timeout=400, capture_output=True, text=True)
    s = json.loads(out.read_text())
    assert s["dt_s"] == 0.0005 and s["steps"] == 2000, (s["steps"], rc.stderr[-2000:])
    assert s["followed_last_command"] and s["last_command_seq"] == 2000
    assert set(s["clock"]) == {"master", "slave"}
    assert s["metrics"]["cut_depth_error_max_m"] <= 50e-6
    assert s["status"] == "ok", (s["status"], s["status_reason"], rc.stderr[-2000:])


@pytest.mark.long
def test_two_sides_at_two_rates_refuse_each_other(tmp_path):
    keys = tmp_path / "keys"
    make_keys(keys, ("127.0.0.1", "localhost"), tls=False)
    ep = free_endpoint()
    common = ["--set", "duration_s=1.0", "--set", "link.heartbeat_ms=2000", "--keys", str(keys), "-q"]
    js, jm = tmp_path / "slave.json", tmp_path / "master.json"
    slave = subprocess.Popen([*PY, "slave", "straight_incision", "--listen", ep, "--json", str(js), *common],
                             stdout=subprocess.DEVNULL)
    master = subprocess.run([*PY, "master", "straight_incision", "--connect", ep, "--dt", "0.0005", "--json",
                             str(jm), *common], timeout=300, capture_output=True, text=True)
    slave.wait(timeout=300)
    m, s = json.loads(jm.read_text()), json.loads(js.read_text())
    assert m["status"] == s["status"] == "link_refused", (m["status_reason"], s["status_reason"])
    assert m["status_reason"].startswith("the slave ticks every 1 ms, this master every 0.5 ms")
    assert s["status_reason"].startswith("the master ticks every 0.5 ms, this slave every 1 ms")
    assert master.returncode == 1 and slave.returncode == 1
    assert m["steps"] < 2000 and s["steps"] <= 3  # refused at once, not run apart
