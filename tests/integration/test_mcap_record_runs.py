"""The MCAP record of real runs (teleop.app.record): every tick of both sides, equal to the run's
own log (log.npz's columns); a cobot's joints and CAN frames; the passivity guard's energies; and
a run killed with SIGKILL at 3 s whose record still holds at least 2.9 s of ticks."""

import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

pytest.importorskip("mcap")
pytest.importorskip("mcap_ros2")

from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, make_reader
from mcap_ros2.decoder import DecoderFactory

from teleop.app.assembly import build_master, build_slave, make_link
from teleop.app.record import (
    LoopRecorderMcap,
    MasterRecorderMcap,
    RecordWriter,
    SlaveRecorderMcap,
    read_record,
    recover,
)
from teleop.app.runtime import run_scene
from teleop.app.session import Session, tick_count
from teleop.master.cobot.database import FrameDatabase
from teleop.scenario.schema import load_scene
from teleop.tick.loop import BilateralLoop


def _record(tmp_path, scene, **kw):
    path = tmp_path / "record.mcap"
    with RecordWriter(path, metadata={"scene": scene.name, "seed": scene.seed}) as w:
        result = run_scene(scene, hooks=[LoopRecorderMcap(w)], **kw)
    assert w.stats()["ticks_dropped"] == 0
    return result, read_record(path, keep_messages=True), path


def test_straight_cut_record_equals_its_log(tmp_path):
    scene = load_scene("straight_incision", sets=["duration_s=1.0"])
    result, rec, path = _record(tmp_path, scene)
    log, n = result.log, result.summary["steps"]
    assert n == 1000 and rec.complete
    schemas = {k: rec[k].schema for k in rec.topics}
    assert schemas == {
        "/master/tool_pose": "geometry_msgs/msg/PoseStamped", "/master/hand_wrench": "geometry_msgs/msg/WrenchStamped",
        "/master/felt_wrench": "geometry_msgs/msg/WrenchStamped", "/master/tf": "tf2_msgs/msg/TFMessage",
        "/master/state": "teleop.MasterTick", "/slave/tool_pose": "geometry_msgs/msg/PoseStamped",
        "/slave/target_pose": "geometry_msgs/msg/PoseStamped", "/slave/contact": "geometry_msgs/msg/WrenchStamped",
        "/slave/joints": "sensor_msgs/msg/JointState", "/slave/tf": "tf2_msgs/msg/TFMessage",
        "/slave/state": "teleop.SlaveTick", "/tf_static": "tf2_msgs/msg/TFMessage"}
    for topic, ch in rec.channels.items():
        if topic != "/tf_static":
            assert len(ch) == n, topic
            assert ch.seq.tolist() == list(range(n))
            assert np.array_equal(ch.t_ns, np.arange(n) * 1_000_000)  # the run's time: tick i at i * dt
    assert np.array_equal(rec["/master/tool_pose"]["p"], log["p_r"])
    assert np.abs(rec["/master/tool_pose"]["R"] - log["R_r"]).max() < 1e-14
    assert np.array_equal(rec["/master/hand_wrench"]["W"], log["operator_W"])
    assert np.array_equal(rec["/master/felt_wrench"]["W"], log["felt_W"])
    assert np.array_equal(rec["/master/state"]["tick_us"], log["master_tick_us"])
    assert np.array_equal(rec["/slave/joints"]["position"], log["slave_q"])
    assert rec["/slave/joints"].names[0].endswith("joint1")
    assert np.array_equal(rec["/slave/tf"].frames["blade_tip"]["p"], log["slave_tip"])
    assert np.array_equal(rec["/slave/state"]["tick_us"], log["slave_tick_us"])
    assert np.allclose(rec["/slave/state"]["tracking_error_m"], log["slave_track_m"], rtol=1e-12, atol=1e-18)
    assert np.allclose(rec["/slave/state"]["contact_force_N"], log["slave_contact_N"], rtol=1e-12, atol=1e-18)
    assert np.abs(np.linalg.norm(rec["/slave/contact"]["force"], axis=1) - log["slave_contact_N"]).max() < 1e-12
    assert rec["/slave/contact"]["force"][-1, 2] != 0.0  # in the tissue by then
    assert set(rec["/master/state"]["status"]) == {"ok"} and set(rec["/slave/state"]["status"]) <= {"ok", "saturated"}
    # a standard reader of a finished file: mcap's seeking reader over its summary, mcap-ros2-support decoding
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count == sum(len(c) for c in rec.channels.values())
        joints = [m.position for _, _, _, m in reader.iter_decoded_messages(topics=["/slave/joints"])]
    assert np.array_equal(joints, log["slave_q"])


def test_cobot_record_has_its_joints_and_can_frames(tmp_path):
    scene = load_scene("straight_incision", sets=["duration_s=0.3"]).with_overrides(master="cobot")
    result, rec, _ = _record(tmp_path, scene)
    n = result.summary["steps"]
    assert np.array_equal(rec["/master/joints"]["position"], result.log["master_q"])
    assert len(rec["/master/joints"]) == n
    assert rec["/master/tf"].frames.keys() == {"reference_tool", "reference_tool_M", "device"}
    can = rec["/master/can"]
    assert 3 * n <= len(can) <= 8 * n  # SYNC, command, joints, wrench a period, heartbeats
    ids = {m.frame_id for m in FrameDatabase().db.messages}
    assert set(can["id"].astype(int)) <= ids
    # on the run's clock: tick i's frames in (i dt, (i + 1) dt], and the closing period's after the last tick
    assert (can.t_s > 0).all() and (can.t_s <= (n + 1) * scene.dt_s + 1e-9).all()
    assert np.searchsorted(can.t_s, scene.dt_s) >= 3  # the first tick's frames are there
    assert set(can["rx"]) == {True, False}


def test_guarded_record_has_the_guards_energies(tmp_path):
    scene = load_scene("straight_incision", sets=["duration_s=0.5", "link.round_trip_ms=20"])
    result, rec, _ = _record(tmp_path, scene)
    log = result.log
    assert "tdpa_W_master_J" in log
    assert np.array_equal(rec["/master/state"]["guard.W_J"], log["tdpa_W_master_J"])
    assert np.array_equal(rec["/master/state"]["guard.E_diss_J"], log["tdpa_diss_master_J"])
    assert np.array_equal(rec["/master/state"]["guard.alpha"], log["tdpa_alpha"])
    assert np.array_equal(rec["/slave/state"]["guard.W_J"], log["tdpa_W_slave_J"])
    assert np.array_equal(rec["/slave/state"]["guard.drift_M"], log["tdpa_drift_M"])


@pytest.mark.parametrize("mode", ["process", "thread"])
def test_side_hooks_record_what_the_loop_hook_records(tmp_path, mode):
    """The wiring for every runner: a MasterRecorderMcap on the master side and a SlaveRecorderMcap
    on the slave side (as build_master / build_slave would add them) record the same run as the
    in-process loop's hook, value for value (but the wall clock and the CPU times), the writer a
    process of its own or a thread of the run's."""
    scene = load_scene("straight_incision", sets=["duration_s=0.4", "link.round_trip_ms=10"])
    _, by_loop, _ = _record(tmp_path, scene)
    n = tick_count(scene.duration_s, scene.dt_s)
    rng = np.random.default_rng(scene.seed)
    mb, sb = build_master(scene, n, rng), build_slave(scene, n)
    with RecordWriter(tmp_path / "sides.mcap", mode=mode) as w:
        mb.side.add_hooks(MasterRecorderMcap(w, side=mb.side))  # the rings made now, not at the first tick
        sb.side.add_hooks(SlaveRecorderMcap(w, side=sb.side))
        run = Session.of(
            BilateralLoop(mb.side, sb.side, make_link(scene, rng)), scene.duration_s, mb.recorder
        ).run_ticks()
    assert run.steps == n
    by_sides = read_record(tmp_path / "sides.mcap")
    assert by_sides.topics == by_loop.topics
    for topic, ch in by_loop.channels.items():
        other = by_sides[topic]
        assert np.array_equal(ch.t_ns, other.t_ns) and np.array_equal(ch.seq, other.seq), topic
        for k, v in ch.fields.items():
            if k not in ("wall_time_s", "tick_us"):
                assert np.array_equal(v, other.fields[k]) if isinstance(v, np.ndarray) else v == other.fields[k], \
                    (topic, k)
        for f, fr in ch.frames.items():
            assert np.array_equal(fr["p"], other.frames[f]["p"]) and np.array_equal(fr["q"], other.frames[f]["q"])


CHILD = textwrap.dedent("""
    import sys
    import numpy as np
    from teleop.app.record import LoopRecorderMcap, RecordWriter
    from teleop.app.runtime import run_scene
    from teleop.scenario.schema import load_scene
    from teleop.tick.ports import Hook

    out, progress, spool = sys.argv[1], sys.argv[2], sys.argv[3] == "spool"
    mm = np.memmap(progress, dtype=np.int64, mode="r+", shape=(2,))

    class Progress(Hook):  # the ticks whose rows the recorder has published (every 10 ms of the run)
        def after_tick(self, i, t_s, loop):
            mm[0] = min(rec.master.handover.done, rec.slave.handover.done)

    scene = load_scene("straight_incision", sets=["duration_s=10.0"])
    w = RecordWriter(out, realtime=True, spool=spool)
    mm[1] = w.pid
    rec = LoopRecorderMcap(w)
    run_scene(scene, realtime=True, hooks=[rec, Progress()])
    w.close()
""")


def _gone(pid):
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split()[2] == "Z"
    except FileNotFoundError:
        return True


@pytest.mark.long
@pytest.mark.parametrize(("killed", "spool"), [("run", False), ("run_and_writer", False), ("run", True),
                                               ("run_and_writer", True)])
def test_a_run_killed_at_3_s_keeps_its_ticks(tmp_path, killed, spool):
    """A real-time straight cut SIGKILLed once it has ticked 3 s. The run alone: its writer (in a
    process group of its own) takes every row published and finishes the file. The writer too (the
    worst case): the file, without its summary, still reads to its last chunk, at most 100 ms
    short of what was published, so at least 2.9 s of ticks; a spooling writer's spool becomes
    the file (recover)."""
    path, progress = tmp_path / "record.mcap", tmp_path / "progress"
    progress.write_bytes(bytes(16))
    mm = np.memmap(progress, dtype=np.int64, mode="r", shape=(2,))
    child = subprocess.Popen([sys.executable, "-c", CHILD, str(path), str(progress), "spool" if spool else "-"])
    try:
        end = time.monotonic() + 120
        while mm[0] < 3000 and child.poll() is None and time.monotonic() < end:
            time.sleep(0.002)
        assert mm[0] >= 3000, f"the run did not reach 3 s of ticks (exit {child.poll()})"
        writer = int(mm[1])
        if killed == "run_and_writer":
            os.kill(writer, signal.SIGKILL)
        reached = int(mm[0])
        child.send_signal(signal.SIGKILL)
        child.wait(10)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    end = time.monotonic() + 60
    while not _gone(writer) and time.monotonic() < end:
        time.sleep(0.02)
    if spool and killed == "run_and_writer":
        assert not path.exists()
        recover(path)  # the spool, to the MCAP file
        assert read_record(path).complete
        _check_ticks(read_record(path), reached - 20)  # the spool is written every 10 ms
        return
    rec = read_record(path)
    ticks = {k: len(rec[k]) for k in ("/master/state", "/slave/state", "/slave/joints", "/master/tool_pose")}
    if killed == "run":
        assert rec.complete, rec.error
        assert min(ticks.values()) >= reached, (ticks, reached)
    else:
        assert not rec.complete and rec.error is not None
        assert min(ticks.values()) >= reached - 100, (ticks, reached)
        # mcap's own stream reader reads as much (then stops at the cut); recover() finishes a copy
        n = 0
        with open(path, "rb") as f, pytest.raises(McapError):
            for _, channel, _ in NonSeekingReader(f).iter_messages(log_time_order=False):
                n += channel.topic == "/slave/state"
        assert n == ticks["/slave/state"]
        fixed, _ = recover(path)
        with open(fixed, "rb") as f:
            assert make_reader(f).get_summary().statistics.channel_message_counts  # a summary, as a closed file
    _check_ticks(rec, 0)


def _check_ticks(rec, at_least):
    ticks = {k: len(rec[k]) for k in ("/master/state", "/slave/state", "/slave/joints", "/master/tool_pose")}
    assert min(ticks.values()) >= max(2900, at_least), ticks
    st = rec["/slave/state"]
    assert st.seq.tolist() == list(range(len(st)))  # no gap: every tick up to the last one kept
