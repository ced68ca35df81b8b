"""The MCAP recorder's parts (teleop.app.record): its ROS 2 bytes against mcap-ros2-support's own
encoder, its quaternions, its JSON, and the writer process fed by hooks on stand-in sides: values
and times back as written, a full ring dropping and counting, a file cut short read to its last
chunk, and a run whose process dies leaving a finished file."""

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("mcap")
pytest.importorskip("mcap_ros2")

from mcap_ros2._dynamic import serialize_dynamic

from teleop.app.record import (
    MasterRecorderMcap,
    RecordWriter,
    SlaveRecorderMcap,
    cdr,
    read_record,
    recover,
    schemas,
)
from teleop.app.record.emit import JsonTemplate
from teleop.app.record.hooks import HAND_S


def _random_rotations(n, rng):
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    R = cdr.rotation(q)
    # the quaternion's four branches: near identity and half turns about each axis
    extra = np.array([np.eye(3), np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0])])
    return np.concatenate((R, extra))


def _encoder(datatype):
    return serialize_dynamic(datatype, schemas.msgdef(datatype))[datatype]


def _header(sec, nsec, frame):
    return {"stamp": {"sec": int(sec), "nanosec": int(nsec)}, "frame_id": frame}


def _vec3(v):
    return {"x": float(v[0]), "y": float(v[1]), "z": float(v[2])}


def _quat(q):
    return {"x": float(q[0]), "y": float(q[1]), "z": float(q[2]), "w": float(q[3])}


def test_cdr_bytes_are_mcap_ros2s():
    """Each fixed layout gives byte for byte what mcap-ros2-support's encoder gives."""
    rng = np.random.default_rng(1)
    n = 4
    t = np.array([0.0, 0.001, 1.5, 123.456789])
    _, sec, nsec = cdr.stamp(t)
    p, v, q = rng.normal(size=(n, 3)), rng.normal(size=(n, 6)), cdr.quat_xyzw(_random_rotations(n, rng)[:n])
    h = {"sec": sec, "nanosec": nsec}
    pose = cdr.pose_stamped("master").encode(n, {**h, "p": p, "q": q})
    twist = cdr.twist_stamped("patient").encode(n, {**h, "v": v[:, :3], "w": v[:, 3:]})
    wrench = cdr.wrench_stamped("blade_tip").encode(n, {**h, "f": v[:, :3], "tau": v[:, 3:]})
    names = ["panda_joint1", "j2", "a_long_joint_name_3"]
    joints = cdr.joint_state(names).encode(n, {**h, "position": v[:, :3], "velocity": v[:, 3:]})
    joints_p = cdr.joint_state(names[:1], velocity=False).encode(n, {**h, "position": v[:, :1]})
    tf = cdr.tf_message([("patient", "slave_tool"), ("master", "ref")]).encode(
        n, {**h, "p0": p, "q0": q, "p1": -p, "q1": q})
    for k in range(n):
        def hd(frame, k=k):
            return _header(sec[k], nsec[k], frame)

        assert pose[k] == _encoder(schemas.POSE)({"header": hd("master"), "pose": {
            "position": _vec3(p[k]), "orientation": _quat(q[k])}})
        assert twist[k] == _encoder(schemas.TWIST)({"header": hd("patient"), "twist": {
            "linear": _vec3(v[k, :3]), "angular": _vec3(v[k, 3:])}})
        assert wrench[k] == _encoder(schemas.WRENCH)({"header": hd("blade_tip"), "wrench": {
            "force": _vec3(v[k, :3]), "torque": _vec3(v[k, 3:])}})
        assert joints[k] == _encoder(schemas.JOINTS)({"header": hd(""), "name": names, "position": list(v[k, :3]),
                                                      "velocity": list(v[k, 3:]), "effort": []})
        assert joints_p[k] == _encoder(schemas.JOINTS)({"header": hd(""), "name": names[:1],
                                                        "position": [float(v[k, 0])], "velocity": [], "effort": []})
        assert tf[k] == _encoder(schemas.TF)({"transforms": [
            {"header": hd("patient"), "child_frame_id": "slave_tool",
             "transform": {"translation": _vec3(p[k]), "rotation": _quat(q[k])}},
            {"header": hd("master"), "child_frame_id": "ref",
             "transform": {"translation": _vec3(-p[k]), "rotation": _quat(q[k])}}]})


def test_stamps_split_exactly():
    ns, sec, nsec = cdr.stamp(np.array([0.0, 0.001, 0.999, 2.5, 7.0 - 0.001]))
    assert ns.tolist() == [0, 1_000_000, 999_000_000, 2_500_000_000, 6_999_000_000]
    assert (sec.astype(np.int64) * 1_000_000_000 + nsec == ns).all()


def test_quaternions_round_trip():
    R = _random_rotations(500, np.random.default_rng(2))
    q = cdr.quat_xyzw(R)
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-15)
    assert (q[:, 3] >= 0).all()
    assert np.abs(cdr.rotation(q) - R).max() < 1e-14


def test_json_template_is_json_and_nulls_what_is_not_finite():
    j = JsonTemplate().open().integer("tick", 0).num("t_s", 1).string("status", 2).boolean("lost", 3)
    j.open("guard").vec("W_J", slice(4, 6)).close().null("other").close().compile()
    rows = np.array([[3, 0.003, 0, 1, 0.5, -1e-300], [4, np.nan, 1, 0, np.inf, 2.0]])
    out = [json.loads(b) for b in j.render(rows, {0: "ok", 1: 'said "no"'})]
    assert out[0] == {"tick": 3, "t_s": 0.003, "status": "ok", "lost": True, "guard": {"W_J": [0.5, -1e-300]},
                      "other": None}
    assert out[1] == {"tick": 4, "t_s": None, "status": 'said "no"', "lost": False, "guard": {"W_J": [None, 2.0]},
                      "other": None}


# -- stand-in sides: only what the hooks and the captures read --------------------------------------

def _master_side(i, rng, hooks=None):
    R = cdr.rotation(cdr.quat_xyzw(_random_rotations(1, rng)[:1]))[0]
    pv, Rv, vv, wv = rng.normal(size=3), np.eye(3), rng.normal(size=3), rng.normal(size=3)
    hooks = [] if hooks is None else hooks
    return SimpleNamespace(
        master=SimpleNamespace(joints=lambda: None, virtual_pose=lambda: (pv, Rv), virtual_twist=lambda: (vv, wv)),
        tool=SimpleNamespace(t=i * 0.001, q=rng.normal(size=6), lam=rng.normal(size=2),
                             constraint_wrench_W=rng.normal(size=6)),
        guard=None, feedback=None, dt=0.001, hooks=hooks, add_hooks=hooks.extend,
        state=SimpleNamespace(p=rng.normal(size=3), R=R, V=rng.normal(size=6)),
        hand_W=rng.normal(size=6), felt_W=rng.normal(size=6), feedback_W=rng.normal(size=6),
        gain=1.0 - 0.01 * (i % 7), heart=SimpleNamespace(lost=i % 5 == 0), peer_lost=False, tick_ns=1000 + i,
        command_errors=0, status="ok")


def _slave_side(i, rng, hooks=None):
    R = cdr.rotation(cdr.quat_xyzw(_random_rotations(2, rng)[:2]))
    s = SimpleNamespace(p_t=rng.normal(size=3), R_t=R[0], p=rng.normal(size=3), R=R[1], v=rng.normal(size=3),
                        w=rng.normal(size=3), tip=rng.normal(size=3), contact_P=rng.normal(size=6),
                        status=("ok", "saturated", "link_lost")[i % 3])
    hooks = [] if hooks is None else hooks
    return SimpleNamespace(
        state=s,
        arm=SimpleNamespace(q=rng.normal(size=7), qd=rng.normal(size=7), model=None, dt=0.001),
        guard=None,
        heart=SimpleNamespace(lost=False),
        tick_ns=2000 + i,
        last_seq=i,
        without_command=0,
        skipped=0,
        reg=SimpleNamespace(X_PM_p=np.array([0.5, 0.0, 0.2]), X_PM_R=np.eye(3)),
        hooks=hooks, add_hooks=hooks.extend,
    )


class _Sides:
    """Stand-in sides ticked as MasterSide and SlaveSide tick their hooks (each tick a side of new
    random values, the hooks the same): the master's hooks before its tick, its status set, its
    hooks after; the slave's (status set by its tick) after. The recorder's hooks are made
    without a side, so each gives its side a capture at its first tick."""

    def __init__(self, writer, slave_writer=None, seed=3):
        self.rng = np.random.default_rng(seed)
        self.mh, self.sh = MasterRecorderMcap(writer), SlaveRecorderMcap(slave_writer or writer)
        self.mhooks, self.shooks = [self.mh], [self.sh]

    def master(self, i, status, prepare=None):
        ms = _master_side(i, self.rng, self.mhooks)
        if prepare is not None:
            prepare(ms)
        t = i * 0.001
        for h in ms.hooks:
            h.before_tick(i, t, ms)
        ms.status = status  # the status tick i ends in, set before the hooks after it (MasterSide)
        for h in ms.hooks:
            h.after_tick(i, t, ms)
        return ms

    def slave(self, i, prepare=None):
        ss = _slave_side(i, self.rng, self.shooks)
        if prepare is not None:
            prepare(ss)
        for h in ss.hooks:
            h.after_tick(i, i * 0.001, ss)
        return ss


def _drive(writer, n, seed=3, slave=True):
    """Ticks 0..n-1 of stand-in sides (:class:`_Sides`), the master's status alternating.
    Returns what the sides held."""
    sides, held = _Sides(writer, seed=seed), []
    for i in range(n):
        ms = sides.master(i, ("ok", "tracking_error")[i % 2])
        ss = sides.slave(i) if slave else None
        held.append((ms, ss))
    return held


@pytest.mark.parametrize(("mode", "spool"), [("process", False), ("thread", False), ("process", True),
                                             ("thread", True)])
def test_record_reads_back_what_the_sides_held(tmp_path, mode, spool):
    """What the sides held, read back exactly: the writer a process or a thread, writing the MCAP
    as the run goes or (spool) after it."""
    path = tmp_path / "r.mcap"
    with RecordWriter(path, metadata={"scene": "stand-in"}, mode=mode, spool=spool) as w:
        held = _drive(w, 300)
        w.link_event(0.0125, "master", "lost", seq=12, detail={"why": "test"})
        w.attach("scene.toml", 'name = "stand-in"\n', "application/toml")
    assert w.stats()["messages"] > 0 and w.stats()["ticks_dropped"] == 0
    assert not os.path.exists(str(path) + ".spool")
    rec = read_record(path, keep_messages=True)
    assert rec.complete and rec.error is None
    assert rec.metadata["teleop"]["scene"] == "stand-in"
    assert rec.attachments == {"scene.toml": b'name = "stand-in"\n'}
    expect = {"/master/tool_pose": schemas.POSE, "/master/hand_wrench": schemas.WRENCH,
              "/master/felt_wrench": schemas.WRENCH, "/master/tf": schemas.TF, "/master/state": "teleop.MasterTick",
              "/slave/tool_pose": schemas.POSE, "/slave/target_pose": schemas.POSE, "/slave/contact": schemas.WRENCH,
              "/slave/joints": schemas.JOINTS, "/slave/tf": schemas.TF, "/slave/state": "teleop.SlaveTick",
              "/tf_static": schemas.TF, "/link/events": "teleop.LinkEvent"}
    assert {k: rec[k].schema for k in rec.topics} == expect
    ms = [h[0] for h in held]
    ss = [h[1] for h in held]
    for topic in expect:
        if topic not in ("/tf_static", "/link/events"):
            ch = rec[topic]
            assert len(ch) == 300
            assert ch.seq.tolist() == list(range(300))
            assert ch.t_ns.tolist() == [i * 1_000_000 for i in range(300)]
    assert np.array_equal(rec["/master/tool_pose"]["p"], [m.state.p for m in ms])
    assert np.abs(rec["/master/tool_pose"]["R"] - [m.state.R for m in ms]).max() < 1e-14
    assert np.array_equal(rec["/master/hand_wrench"]["W"], [m.hand_W for m in ms])
    assert np.array_equal(rec["/master/felt_wrench"]["W"], [m.felt_W for m in ms])
    st = rec["/master/state"]
    assert st["status"] == [("ok", "tracking_error")[i % 2] for i in range(300)]  # the status tick i ended in
    assert np.array_equal(st["gain"], [m.gain for m in ms])
    assert np.array_equal(st["heartbeat_lost"], [m.heart.lost for m in ms])
    assert np.array_equal(st["tool_twist"], [m.state.V for m in ms])
    assert np.array_equal(st["feedback_wrench"], [m.feedback_W for m in ms])
    assert np.array_equal(st["tick_us"], [m.tick_ns * 1e-3 for m in ms])
    assert st["guard"] == [None] * 300
    assert np.allclose(st["wall_time_s"], time.time(), atol=120)
    assert np.array_equal(rec["/slave/joints"]["position"], [s.arm.q for s in ss])
    assert np.array_equal(rec["/slave/joints"]["velocity"], [s.arm.qd for s in ss])
    assert rec["/slave/joints"].names == [f"joint{k}" for k in range(7)]
    assert np.array_equal(rec["/slave/contact"]["W"], [s.state.contact_P for s in ss])
    assert np.array_equal(rec["/slave/target_pose"]["p"], [s.state.p_t for s in ss])
    tf = rec["/slave/tf"].frames
    assert {k: f["parent"] for k, f in tf.items()} == {"slave_tool": "patient", "slave_target": "patient",
                                                         "blade_tip": "patient"}
    assert np.array_equal(tf["blade_tip"]["p"], [s.state.tip for s in ss])
    sst = rec["/slave/state"]
    assert sst["status"] == [s.state.status for s in ss]
    assert np.allclose(sst["tracking_error_m"], [np.linalg.norm(s.state.p - s.state.p_t) for s in ss], rtol=1e-14)
    assert np.allclose(sst["contact_force_N"], [np.linalg.norm(s.state.contact_P[:3]) for s in ss], rtol=1e-14)
    assert np.array_equal(sst["last_command_seq"], range(300))
    assert rec["/tf_static"].frames["master"]["parent"] == "patient"
    assert rec["/link/events"].messages == [{"t_s": 0.0125, "wall_time_s": pytest.approx(time.time(), abs=120),
                                            "side": "master", "kind": "lost", "seq": 12, "detail": {"why": "test"}}]


def _schedule(kind, n):
    """The order the two sides tick in: the in-process loop's (each master tick, then the slave's),
    or one side two ticks ahead of the other (as a lockstep replay may run them)."""
    if kind == "loop":
        return [(k, i) for i in range(n) for k in "ms"]
    lead, lag = ("m", "s") if kind == "master_ahead" else ("s", "m")
    out = []
    for i in range(0, n, 2):  # the leader's ticks i and i + 1, then the other side's
        ticks = range(i, min(n, i + 2))
        out += [(lead, j) for j in ticks] + [(lag, j) for j in ticks]
    return out


@pytest.mark.parametrize("kind", ["loop", "master_ahead", "slave_ahead", "two_writers", "master_alone"])
def test_every_tick_is_recorded_whatever_order_the_sides_tick_in(tmp_path, kind):
    """Each side's rows are handed over in batches as its ticks end, and the rest at close:
    every tick's values and status are there, whichever order the sides ticked in (a lockstep
    replay's, each side a writer of its own as two processes have, a master alone)."""
    n = 120
    w = RecordWriter(tmp_path / "r.mcap")
    ws = RecordWriter(tmp_path / "s.mcap") if kind == "two_writers" else w
    sides = _Sides(w, ws, seed=11)
    masters, slaves = [], []
    order = [e for e in _schedule("loop" if kind in ("two_writers", "master_alone") else kind, n)
             if not (kind == "master_alone" and e[0] == "s")]
    for k, i in order:
        if k == "m":
            masters.append(sides.master(i, ("ok", "tracking_error", "ok", "joint_limit")[i % 4]))
        else:
            slaves.append(sides.slave(i))
    w.close()
    ws.close()
    rec = read_record(tmp_path / "r.mcap")
    assert w.stats()["ticks_dropped"] == 0
    st = rec["/master/state"]
    assert st.seq.tolist() == list(range(n))
    assert st["status"] == [m.status for m in masters]
    assert np.array_equal(rec["/master/tool_pose"]["p"], [m.state.p for m in masters])
    assert np.array_equal(rec["/master/hand_wrench"]["W"], [m.hand_W for m in masters])
    assert np.array_equal(st["tick_us"], [m.tick_ns * 1e-3 for m in masters])
    if kind != "master_alone":
        srec = read_record(tmp_path / ("s.mcap" if kind == "two_writers" else "r.mcap"))
        assert srec["/slave/state"].seq.tolist() == list(range(n))
        assert np.array_equal(srec["/slave/joints"]["position"], [s.arm.q for s in slaves])
        assert srec["/slave/state"]["status"] == [s.state.status for s in slaves]


def test_a_file_cut_short_reads_to_its_last_whole_chunk(tmp_path):
    path = tmp_path / "r.mcap"
    with RecordWriter(path, flush_s=0.01) as w:  # 10 ticks a chunk
        _drive(w, 400)
    data = path.read_bytes()
    full = read_record(path)
    counts = []
    for frac in (0.05, 0.3, 0.5, 0.77, 0.95, 0.999):
        cut = tmp_path / f"cut{frac}.mcap"
        cut.write_bytes(data[: int(len(data) * frac)])
        rec = read_record(cut)
        assert not rec.complete and rec.error is not None
        n = len(rec["/master/state"]) if "/master/state" in rec else 0
        counts.append(n)
        for topic, ch in rec.channels.items():  # a prefix of the whole file's messages
            assert ch.seq.tolist() == full[topic].seq.tolist()[: len(ch)]
    assert counts == sorted(counts) and counts[-1] >= 380 and counts[0] < 100
    # mcap's seeking reader reads the footer first: it refuses the cut file, and reads its recovered copy
    from mcap.reader import make_reader

    with open(cut, "rb") as f, pytest.raises(Exception):  # noqa: B017 - whatever the garbage footer gives
        list(make_reader(f).iter_messages())
    fixed, n = recover(cut)
    with open(fixed, "rb") as f:
        msgs = list(make_reader(f).iter_messages(topics=["/master/state"]))
    assert len(msgs) == counts[-1] and n == sum(len(c) for c in rec.channels.values())
    again = read_record(fixed)
    assert again.complete and all(np.array_equal(again[k].seq, rec[k].seq) for k in rec.topics)


@pytest.mark.parametrize("realtime", [False, True])
def test_a_full_ring_drops_ticks_and_counts_them(tmp_path, realtime):
    """A writer that does not keep up: on the simulated clock the hooks wait for it (a while, once
    per stall); paced to the wall clock they never wait. Either way a full ring drops, and counts."""
    path = tmp_path / "r.mcap"
    w = RecordWriter(path, capacity=64, high_water=32, low_water=8, block_s=0.005, realtime=realtime)
    try:
        _drive(w, 5)  # the writer is up and has taken these
        time.sleep(0.5)
        os.kill(w.pid, signal.SIGSTOP)  # a writer that does not keep up
        t0 = time.perf_counter()
        _drive(w, 200, seed=4)
        blocked = time.perf_counter() - t0
    finally:
        os.kill(w.pid, signal.SIGCONT)
        w.close()
    s = w.stats()
    assert s["ticks_dropped"] > 0 and (s["hook_waits"] == 0 if realtime else s["hook_waits"] >= 1)
    if realtime:
        assert s["hook_waited_s"] == 0.0
    else:
        assert blocked < 2.0  # waited once per stall (5 ms), not once per tick
    rec = read_record(path)
    assert len(rec["/master/state"]) + s["ticks_dropped"] // 2 >= 200  # each side drops alike
    assert len(rec["/slave/state"]) < 205


CHILD = textwrap.dedent("""
    import os, sys, signal
    sys.path.insert(0, {tests!r})
    from unit.test_mcap_record import _drive
    from teleop.app.record import RecordWriter
    w = RecordWriter(sys.argv[1])
    _drive(w, 250)
    print(w.pid, flush=True)
    os.kill(os.getpid(), signal.SIGKILL)
""")


def _running(pid):
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split()[2] != "Z"
    except FileNotFoundError:
        return False


def test_the_writer_finishes_the_file_when_the_run_is_killed(tmp_path):
    """SIGKILL on the run's process: the writer takes every row published and finishes the file."""
    path = tmp_path / "r.mcap"
    tests = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    p = subprocess.run([sys.executable, "-c", CHILD.format(tests=tests), str(path)], capture_output=True, text=True,
                       timeout=60, check=False)
    assert p.returncode == -signal.SIGKILL, p.stderr
    pid = int(p.stdout.split()[0])
    end = time.monotonic() + 30
    while time.monotonic() < end and _running(pid):
        time.sleep(0.05)
    rec = read_record(path)
    assert rec.complete, rec.error
    assert rec.metadata["teleop.record"]["closed_by"] == "end of the run's process"
    # every row handed over: all but those of the last batch not yet due (HAND_S: 10 ticks here)
    every = round(HAND_S / 0.001)
    for topic in ("/slave/state", "/master/state"):
        assert rec[topic].seq.tolist() == list(range(len(rec[topic])))
        assert 250 - every < len(rec[topic]) <= 250


def test_foxglove_layout_names_what_the_record_holds(tmp_path):
    """Every topic and message path docs/foxglove/teleop_layout.json plots or draws is in a record,
    and so is every frame it shows (but the cobot's ``device``)."""
    layout_path = os.path.join(os.path.dirname(__file__), "..", "..", "docs", "foxglove", "teleop_layout.json")
    with open(layout_path) as f:
        layout = json.load(f)
    path = tmp_path / "r.mcap"
    with RecordWriter(path) as w:
        _drive(w, 20)
    rec = read_record(path, keep_messages=True)
    cfg = layout["configById"]
    paths = [p["value"] for k, c in cfg.items() if k.startswith("Plot!") for p in c["paths"]]
    assert paths
    for p in paths:
        topic, _, field = p.partition(".")
        assert topic in rec, p
        msg = rec[topic].messages[-1]
        for part in field.split("."):
            msg = msg[part] if isinstance(msg, dict) else getattr(msg, part)
        assert isinstance(msg, (int, float)), p
    scene = cfg["3D!teleop"]
    assert all(t in rec for t in scene["topics"])
    frames = {"patient"} | {c for t in ("/master/tf", "/slave/tf", "/tf_static") for c in rec[t].frames}
    assert {k.removeprefix("frame:") for k in scene["transforms"]} - frames == {"device"}
    assert scene["followTf"] in frames
    assert cfg["RawMessages!state"]["topicPath"] in rec


def test_arrays_of_any_layout_are_recorded_alike(tmp_path):
    """A side whose arrays are not C-contiguous float64 (a transposed rotation, float32, a list)
    takes the slow copy (numpy's casting), with the same values."""
    path = tmp_path / "r.mcap"

    def odd_master(ms):
        ms.state.R = np.asfortranarray(ms.state.R)
        ms.hand_W = list(ms.hand_W)
        ms.felt_W = ms.felt_W.astype(np.float32)

    def odd_slave(ss):
        ss.arm.q = list(ss.arm.q)
        ss.state.R = ss.state.R.T.copy().T

    with RecordWriter(path) as w:
        stand, sides = _Sides(w, seed=5), []
        for i in range(30):
            ms = stand.master(i, "ok", odd_master if i % 2 else None)
            ss = stand.slave(i, odd_slave if i % 2 else None)
            sides.append((ms, ss))
    rec = read_record(path)
    assert np.abs(rec["/master/tool_pose"]["R"] - [m.state.R for m, _ in sides]).max() < 1e-14
    assert np.array_equal(rec["/master/hand_wrench"]["W"], [m.hand_W for m, _ in sides])
    assert np.array_equal(rec["/master/felt_wrench"]["W"], [np.asarray(m.felt_W, float) for m, _ in sides])
    assert np.array_equal(rec["/slave/joints"]["position"], [s.arm.q for _, s in sides])
    assert np.abs(rec["/slave/tool_pose"]["R"] - [s.state.R for _, s in sides]).max() < 1e-14


def test_a_killed_spooling_writer_leaves_a_spool_that_recovers(tmp_path):
    """spool=True and the writer killed: the spool it appended to every poll becomes the MCAP file."""
    path = tmp_path / "r.mcap"
    w = RecordWriter(path, spool=True)
    try:
        _drive(w, 300)
        published = [src.ring.w for src in w._sources]  # all but the last batch, not due yet
        time.sleep(0.3)  # a few polls: the rows are in the spool
        os.kill(w.pid, signal.SIGKILL)
    finally:
        with pytest.raises(Exception):  # noqa: B017 - the writer is gone
            w.close()
    assert not path.exists() and os.path.exists(str(path) + ".spool")
    out, n = recover(path)
    assert out == path and n > 0
    rec = read_record(path)
    assert rec.complete
    assert [len(rec["/master/state"]), len(rec["/slave/state"])] == published  # every row published
    assert 300 - round(HAND_S / 0.001) < min(published)
    assert rec.metadata["teleop.record"]["closed_by"] == "recovered from its spool"


def test_rows_over_many_blocks_through_a_wrapping_ring_read_back(tmp_path, monkeypatch):
    """Captured rows in blocks of 7 (a batch spans two), handed through a ring of 64 that wraps
    again and again: every tick back, in order, with its values."""
    from teleop.app import rows as rows_mod

    monkeypatch.setattr(rows_mod, "ROW_CHUNK", 7)
    path = tmp_path / "r.mcap"
    with RecordWriter(path, capacity=64, high_water=32, low_water=8) as w:
        held = _drive(w, 333)
    rec = read_record(path)
    assert w.stats()["ticks_dropped"] == 0
    for topic in ("/master/state", "/slave/state"):
        assert rec[topic].seq.tolist() == list(range(333))
    assert np.array_equal(rec["/master/tool_pose"]["p"], [m.state.p for m, _ in held])
    assert np.array_equal(rec["/slave/joints"]["position"], [s.arm.q for _, s in held])
