"""Master and slave as two processes over Zenoh on loopback: a cut end to end with one summary,
and either side killed mid-cut (the other reaches its safe state within the heartbeat and says
why). Free ports, generous connect timeouts: the machine may be loaded."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("zenoh")

from teleop.app.netrun import free_endpoint
from teleop.app.runtime import run_scene
from teleop.scenario.schema import load_scene

PY = [sys.executable, "-m", "teleop"]
ENV = {**os.environ}


def _wait_line(proc, text, timeout_s=180.0):
    """Read the process's stdout until a line contains ``text``."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        line = proc.stdout.readline()
        if not line:
            if proc.poll() is not None:
                raise AssertionError(f"process ended before {text!r}: rc={proc.returncode}")
            continue
        if text in line:
            return
    raise AssertionError(f"no {text!r} within {timeout_s} s")


@pytest.mark.long
def test_a_stiff_wall_over_zenoh_is_rendered_model_mediated(tmp_path):
    """A 100 kN/m wall pressed through two processes: the plane and the wall's force cross the
    authenticated link (wire v7), the slave presses no harder than the master's wall, and what the
    hand feels is what the slave presses."""
    out = tmp_path / "run.json"
    sets = ["tissue.stiffness=100000.0", "link.heartbeat_ms=2000"]
    subprocess.run([*PY, "run", "stiff_contact", "--link", "zenoh", *[a for x in sets for a in ("--set", x)],
                    "--json", str(out)], env=ENV, timeout=400, capture_output=True, text=True)
    s = json.loads(out.read_text())
    assert s["status"] == "ok", s["status_reason"]
    assert s["pressed_less_ticks"] > 0 and "wall_model" in s
    assert s["metrics"]["contact_force_max_N"] < 2 * 1.63  # the undelayed one-process peak, doubled
    assert s["metrics"]["felt_error_rms_N"] < 0.2


@pytest.mark.long
def test_two_process_cut_over_zenoh_writes_one_summary(tmp_path):
    """A 2 s cut (1.5 s of it in the tissue) over Zenoh: one summary, the guard on (passivity
    "auto" on a network), and the tip tracked within 2x the same cut in one process."""
    out = tmp_path / "run.json"
    sets = ["duration_s=2.0", "link.heartbeat_ms=2000"]
    # a slow shared machine cannot hold 1 kHz in both processes: a wide heartbeat here, the 20 ms
    # one is tested below
    rc = subprocess.run([*PY, "run", "straight_incision", "--link", "zenoh", *[a for x in sets for a in ("--set", x)],
                              "--json", str(out)],
                        env=ENV, timeout=400, capture_output=True, text=True)
    s = json.loads(out.read_text())
    assert set(s["link"]) == {"zenoh_master", "zenoh_slave"} and s["endpoint"].startswith("tcp/127.0.0.1:")
    assert s["steps"] == 2000 and s["followed_last_command"]
    assert s["nan"] is False and s["link"]["zenoh_master"]["bad_frames"] == 0
    assert s["metrics"]["cut_depth_error_max_m"] <= 50e-6
    assert sum(s["reply_lag_ticks"].values()) == 2000  # every tick's reply accounted for
    assert {"dissipated_master_J", "dissipated_slave_J"} <= set(s["passivity"])
    one = run_scene(load_scene("straight_incision", sets=sets)).summary["metrics"]
    assert s["metrics"]["tip_tracking_rms_m"] <= 2.0 * one["tip_tracking_rms_m"], (s["metrics"], one)
    if len(os.sched_getaffinity(0)) >= 2:  # each side on a core of its own
        assert {s["clock"]["master"]["core"], s["clock"]["slave"]["core"]} == set(sorted(os.sched_getaffinity(0))[:2])
    assert s["status"] == "ok", (s["status"], rc.stderr[-2000:])
    assert rc.returncode == 0


def _keys(tmp_path, name="keys", tls=False):
    from teleop.link.keys import make_keys

    make_keys(tmp_path / name, ("127.0.0.1", "localhost"), tls=tls)
    return str(tmp_path / name)


def _pair(tmp_path, seconds, extra=(), ep=None, keys=None):
    ep = ep or free_endpoint()
    keys = keys or _keys(tmp_path)
    js, jm = tmp_path / "slave.json", tmp_path / "master.json"
    sets = ["--set", f"duration_s={seconds}", "--keys", keys, *extra]
    slave = subprocess.Popen([*PY, "slave", "straight_incision", "--listen", ep, "--json", str(js), *sets],
                             env=ENV, stdout=subprocess.PIPE, text=True)
    master = subprocess.Popen([*PY, "master", "straight_incision", "--connect", ep, "--json", str(jm), *sets],
                              env=ENV, stdout=subprocess.PIPE, text=True)
    return slave, master, js, jm


def _finish(*procs):
    for p in procs:
        try:
            p.wait(timeout=120)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


@pytest.mark.long
@pytest.mark.parametrize("victim", ["master", "slave"])
def test_killing_one_side_puts_the_other_in_its_safe_state(tmp_path, victim):
    slave, master, js, jm = _pair(tmp_path, 4.0)
    try:
        _wait_line(master, "master: running")
        time.sleep(1.0)
        (master if victim == "master" else slave).send_signal(signal.SIGKILL)
    finally:
        _finish(slave, master)
    survivor = json.loads((js if victim == "master" else jm).read_text())
    hb = survivor["heartbeat"]["slave" if victim == "master" else "master"]
    assert survivor["status"] == "link_lost" and hb["lost_at_end"] and hb["lost_events"] >= 1
    # detected at the first tick past the 20 ms heartbeat: within 21 ms when ticks run on time; a
    # shared machine that runs a tick late delays the detection by that much (recorded), no more
    k = hb["detect_latency_s"].index(hb["detect_latency_max_s"])
    assert hb["detect_latency_max_s"] <= 0.021 + hb["detect_tick_late_s"][k] + 0.002, hb
    assert hb["speed_while_lost_last"] == 0.0  # held still: the master's tool, the slave's joints


@pytest.mark.long
def test_a_paused_slave_is_a_lost_link_and_the_master_resumes_without_a_jump(tmp_path):
    slave, master, _js, jm = _pair(tmp_path, 4.0)
    try:
        _wait_line(master, "master: running")
        time.sleep(1.0)
        slave.send_signal(signal.SIGSTOP)
        time.sleep(0.3)
        slave.send_signal(signal.SIGCONT)
    finally:
        _finish(slave, master)
    m = json.loads(jm.read_text())
    hb = m["heartbeat"]["master"]
    assert hb["lost_events"] >= 1 and hb["resumed"] >= 1 and not hb["lost_at_end"]
    assert hb["lost_ticks"] >= 250  # the pause, seen as a lost link
    assert hb["step_after_resume_max_m"] <= 1e-3  # the hand pulls at 30 mm/s: 30 um a tick; no jump
    assert m["status"] == "link_lost"  # said, not hidden behind "ok"


def _run(args, tmp_path, timeout=400):
    return subprocess.run([*PY, "run", *args], env=ENV, timeout=timeout, capture_output=True, text=True,
                          cwd=tmp_path)


@pytest.mark.long
def test_run_over_zenoh_honours_every_flag_and_writes_the_run_folder_of_one_process(tmp_path):
    """The issue's command, with a wide heartbeat for a loaded machine: the same folder as an
    in-process run, the flags honoured (duration, seed), one summary of the in-process shape."""
    hb = ["--set", "link.heartbeat_ms=2000"]
    rc = _run(["straight_incision", "--link", "zenoh", "--duration", "2", "--seed", "3", "--out", "runs/z",
               "--json", "z.json", *hb], tmp_path)
    s = json.loads((tmp_path / "z.json").read_text())
    assert s["status"] == "ok" and rc.returncode == 0, (s["status_reason"], rc.stderr[-2000:])
    assert s["steps"] == 2000 and s["seed"] == 3 and s["duration_s"] == pytest.approx(2.0)
    one = _run(["straight_incision", "--duration", "0.2", "--out", "runs/one", "--json", "one.json", *hb], tmp_path)
    assert one.returncode == 0
    files = {p.name for p in (tmp_path / "runs/z").iterdir()}
    # the recording is drawn from the log (no view frames); each process keeps its own record
    assert {p.name for p in (tmp_path / "runs/one").iterdir()} - files <= {"view_frames.npz", "record.mcap"}
    assert {"master.mcap", "slave.mcap"} <= files
    shape = set(json.loads((tmp_path / "one.json").read_text()))
    assert shape - set(s) <= {"link", "record"}, shape - set(s)  # the in-process run's keys (records per side here)
    assert "recording.html" in files and "log.npz" in files


@pytest.mark.long
def test_the_cobot_master_runs_over_zenoh(tmp_path):
    rc = _run(["straight_incision", "--link", "zenoh", "--master", "cobot", "--duration", "1", "--json", "c.json",
               "--set", "link.heartbeat_ms=2000"], tmp_path)
    s = json.loads((tmp_path / "c.json").read_text())
    assert s["master"] == "cobot" and s["can_bus_load_pct"] > 0 and s["steps"] == 1000
    assert s["status"] == "ok" and rc.returncode == 0, s["status_reason"]


@pytest.mark.long
def test_a_violated_fixture_is_reported_alike_in_one_process_and_over_zenoh(tmp_path):
    """Encoders of 4 mm cannot hold the cut's 1 mm depth tolerance: fixture_violated, both ways."""
    args = ["straight_incision", "--master", "cobot", "--duration", "1", "--set", "cobot.encoder_m=0.004",
            "--set", "link.heartbeat_ms=2000"]
    one, net = _run([*args, "--json", "one.json"], tmp_path), _run([*args, "--link", "zenoh", "--json", "z.json"],
                                                                   tmp_path)
    s1, sz = (json.loads((tmp_path / f).read_text()) for f in ("one.json", "z.json"))
    assert s1["status"] == sz["status"] == "fixture_violated", (s1["status_reason"], sz["status_reason"])
    assert one.returncode == net.returncode == 1


@pytest.mark.long
def test_a_slave_killed_mid_run_leaves_the_masters_summary_link_lost_and_exit_1(tmp_path):
    import psutil

    parent = subprocess.Popen([*PY, "run", "straight_incision", "--link", "zenoh", "--duration", "4", "--json",
                                    str(tmp_path / "k.json")], env=ENV, stdout=subprocess.PIPE, text=True)
    try:
        _wait_line(parent, "master: running")
        time.sleep(1.0)
        slaves = [c for c in psutil.Process(parent.pid).children() if "slave" in c.cmdline()]
        assert len(slaves) == 1
        slaves[0].send_signal(signal.SIGKILL)
        parent.stdout.read()
        rc = parent.wait(timeout=200)
    finally:
        _finish(parent)
    s = json.loads((tmp_path / "k.json").read_text())
    assert s["status"] == "link_lost" and rc == 1, s["status_reason"]
    assert s["heartbeat"]["master"]["lost_at_end"] and "slave process exit -9" in s["processes"]


@pytest.mark.long
def test_a_second_master_is_refused_in_one_line_and_the_first_keeps_control(tmp_path):
    ep = free_endpoint()
    # the first pair runs 8 s: the second master's start (interpreter, imports, its warm-up) must
    # fit in it on a loaded machine, or it finds no slave and ends link_lost instead of refused
    slave, master, js, jm = _pair(tmp_path, 8.0, ep=ep, extra=["--set", "link.heartbeat_ms=2000"])
    try:
        _wait_line(master, "master: running")
        second = subprocess.run([*PY, "master", "straight_incision", "--connect", ep, "--keys", str(tmp_path / "keys"),
                                      "--json", str(tmp_path / "second.json"), "--timeout", "20"],
                                env=ENV, capture_output=True, text=True, timeout=200)
    finally:
        _finish(slave, master)
    s2 = json.loads((tmp_path / "second.json").read_text())
    assert second.returncode == 1 and s2["status"] == "link_refused", second.stdout[-2000:]
    refusals = [ln for ln in second.stdout.splitlines() if ln.startswith("master:") and "refused" in ln]
    assert len(refusals) == 1 and "already paired" in refusals[0]
    first, slave_s = json.loads(jm.read_text()), json.loads(js.read_text())
    # the first master kept control to the end; both sides name the attempt, refused and counted
    assert first["steps"] == 8000 and first["heartbeat"]["master"]["lost_ticks"] == 0
    assert slave_s["metrics"]["tip_tracking_max_m"] < 1e-3  # the slave followed it all along
    for s in (first, slave_s):
        assert s["status"] == "link_attacked", s["status_reason"]
    assert "second_master" in slave_s["status_reason"]


@pytest.mark.long
def test_a_tls_pair_runs_the_cut_and_a_certificate_of_another_ca_is_refused(tmp_path):
    """The two-host recipe on loopback: 'teleop keys' certificates, a tls/ endpoint, mutual TLS."""
    keys = _keys(tmp_path, "keys", tls=True)
    ep = free_endpoint().replace("tcp/", "tls/")
    slave, master, js, jm = _pair(tmp_path, 1.0, ep=ep, keys=keys, extra=["--set", "link.heartbeat_ms=2000"])
    _finish(slave, master)
    assert json.loads(jm.read_text())["status"] == "ok" and json.loads(js.read_text())["status"] == "ok"
    other = _keys(tmp_path, "other", tls=True)  # another CA
    ep = free_endpoint().replace("tcp/", "tls/")
    slave = subprocess.Popen([*PY, "slave", "straight_incision", "--listen", ep, "--keys", keys, "--timeout", "30",
                                   "--set", "duration_s=1"], env=ENV, stdout=subprocess.PIPE, text=True)
    try:
        time.sleep(3.0)  # the slave listening
        rc = subprocess.run([*PY, "master", "straight_incision", "--connect", ep, "--keys", other, "--timeout", "15",
                                  "--json", str(tmp_path / "bad.json")], env=ENV, capture_output=True, text=True,
                            timeout=200)
    finally:
        slave.send_signal(signal.SIGINT)
        _finish(slave)
    bad = json.loads((tmp_path / "bad.json").read_text())
    assert rc.returncode == 1 and bad["status"] in ("link_refused", "link_lost") and bad["steps"] == 0
    refusals = [ln for ln in rc.stdout.splitlines() if ln.startswith("master:") and "refused" in ln]
    assert bad["status"] == "link_refused" and len(refusals) == 1, rc.stdout[-1000:]


@pytest.mark.long
def test_the_link_bench_times_zenoh_against_raw_udp_in_one_run():
    """tools/bench.py's link figures (tools/link_bench.py): both transports, two processes, 1 kHz,
    every echoed frame decoded; the figures are times, not bounds (a loaded machine stretches them)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))
    import link_bench

    out = link_bench.measure(400, warmup=100)
    assert set(out) == {"udp", "zenoh"}
    for f in out.values():
        assert f["frames"] == 300 and f["lost"] <= 15  # Zenoh's DROP may shed a frame on a starved core
        assert 0.0 < f["p50_ms"] <= f["p90_ms"] <= f["p99_ms"] <= f["max_ms"]
