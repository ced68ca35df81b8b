"""`teleop replay RUN --check`: a run again from its record, every recorded state compared bit for
bit. Identical runs say so in one line (exit 0); a record with one value changed is named at its
tick and field (exit 1); a folder without a record, a record cut short, one of another record
version or not an MCAP file at all are one line naming the file and the reason (exit 2)."""

import json
import struct

import numpy as np
import pytest

pytest.importorskip("mcap")
pytest.importorskip("mcap_ros2")

from mcap.records import Attachment, Message, Metadata, Schema
from mcap.records import Channel as McapChannel
from mcap.stream_reader import StreamReader
from mcap.writer import Writer

from teleop.app.cli import main
from teleop.app.record import read_record
from teleop.app.replay import check_run


def rewrite(src, dst, message=None, metadata=None):
    """A copy of the MCAP file ``src`` at ``dst``, each message's bytes through ``message(topic,
    seq, data)`` and each metadata record through ``metadata(name, values)``."""
    topics, schema_ids, channel_ids = {}, {}, {}
    with open(src, "rb") as f, open(dst, "wb") as g:
        w = Writer(g)
        w.start(profile="", library="test")
        for rec in StreamReader(f, record_size_limit=None).records:
            if isinstance(rec, Schema):
                schema_ids[rec.id] = w.register_schema(rec.name, rec.encoding, rec.data)
            elif isinstance(rec, McapChannel):
                topics[rec.id] = rec.topic
                channel_ids[rec.id] = w.register_channel(rec.topic, rec.message_encoding,
                                                         schema_ids.get(rec.schema_id, 0), dict(rec.metadata))
            elif isinstance(rec, Message):
                data = rec.data if message is None else message(topics[rec.channel_id], rec.sequence, rec.data)
                w.add_message(channel_ids[rec.channel_id], rec.log_time, data, rec.publish_time, rec.sequence)
            elif isinstance(rec, Metadata):
                w.add_metadata(rec.name, dict(rec.metadata) if metadata is None else metadata(rec.name,
                                                                                             dict(rec.metadata)))
            elif isinstance(rec, Attachment):
                w.add_attachment(rec.create_time, rec.log_time, rec.name, rec.media_type, rec.data)
        w.finish()


@pytest.fixture(scope="module")
def cut(tmp_path_factory):
    run = tmp_path_factory.mktemp("cut") / "run"
    assert main(["run", "straight_incision", "--duration", "0.3", "--seed", "3", "--out", str(run), "-q"]) == 0
    return run


def test_a_cut_replays_identical_in_one_line(cut, capsys):
    assert main(["replay", str(cut), "--check"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and "identical: 300 ticks of straight_incision" in out[0] and "bit for bit" in out[0]


def test_one_value_changed_is_named_at_its_tick_and_field(cut, tmp_path, capsys):
    q = read_record(cut / "record.mcap", topics="/slave/joints")["/slave/joints"]["position"]
    before = struct.pack("<d", q[123, 2])
    after = struct.pack("<d", np.nextafter(q[123, 2], 1.0))  # one bit
    tampered = tmp_path / "run"
    tampered.mkdir()
    rewrite(cut / "record.mcap", tampered / "record.mcap",
            message=lambda topic, seq, data: data.replace(before, after, 1) if (topic, seq) == ("/slave/joints", 123)
            else data)
    res = check_run(tampered)
    assert not res.identical
    d = res.difference
    assert (d.tick, d.topic, d.field) == (123, "/slave/joints", "position[2]"), res.line
    assert main(["replay", str(tampered), "--check"]) == 1
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and "differs at tick 123" in out[0] and "/slave/joints position[2]" in out[0]


def test_a_json_state_changed_is_named_too(cut, tmp_path):
    def edit(topic, seq, data):
        if (topic, seq) != ("/master/state", 77):
            return data
        m = json.loads(data)
        m["gain"] = 0.5
        return json.dumps(m).encode()

    tampered = tmp_path / "run"
    tampered.mkdir()
    rewrite(cut / "record.mcap", tampered / "record.mcap", message=edit)
    d = check_run(tampered).difference
    assert (d.tick, d.topic, d.field, d.recorded, d.replayed) == (77, "/master/state", "gain", "0.5", "1.0")


def _bad(args, capsys) -> str:
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("teleop: error: ")
    return err[0]


def test_bad_records_are_one_line_naming_the_file_and_the_reason(cut, tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert "no record to check" in _bad(["replay", str(empty), "--check"], capsys)
    cutoff = tmp_path / "truncated"
    cutoff.mkdir()
    data = (cut / "record.mcap").read_bytes()
    (cutoff / "record.mcap").write_bytes(data[: len(data) // 2])
    line = _bad(["replay", str(cutoff), "--check"], capsys)
    assert "truncated/record.mcap: truncated" in line
    other = tmp_path / "other"
    other.mkdir()
    rewrite(cut / "record.mcap", other / "record.mcap",
            metadata=lambda name, v: {**v, "record_version": "99"} if name == "teleop.replay" else v)
    line = _bad(["replay", str(other), "--check"], capsys)
    assert "other/record.mcap: record version '99'" in line
    garbage = tmp_path / "garbage"
    garbage.mkdir()
    (garbage / "record.mcap").write_bytes(b"not an mcap file at all" * 10)
    assert "garbage/record.mcap: not an MCAP record" in _bad(["replay", str(garbage), "--check"], capsys)
    half = tmp_path / "half"
    half.mkdir()
    (half / "master.mcap").write_bytes(data)
    assert "half/slave.mcap: missing" in _bad(["replay", str(half), "--check"], capsys)
    assert "--check" in _bad(["replay", str(cut), "--check", "--viewer"], capsys)


def _record_run(folder, scene, operator: str = "script", **kw):
    """A run recorded as `teleop run --out` records it (open_run_record, run_scene's side hooks)."""
    from teleop.app.record.runinfo import open_run_record
    from teleop.app.runtime import run_scene

    folder.mkdir(parents=True)
    writer = open_run_record(folder / "record.mcap", scene, runner="one_process", operator=operator,
                             realtime=kw.get("realtime", False))
    try:
        return run_scene(scene, record=writer, **kw)
    finally:
        writer.close()


def _seeded_runs():
    from teleop.scenario.schema import list_scenes

    runs = [(name, 11 + k, ()) for k, name in enumerate(list_scenes())]  # every shipped scene
    runs += [("straight_incision", seed, ()) for seed in (1, 2)]
    runs += [("straight_incision", 5, ("master='cobot'",)),  # the cobot master, its CAN faults on
             ("straight_incision", 6, ("master='cobot'", "effects=['coriolis','damping','tissue','cutting',"
                                                         "'can_faults','sensor_noise','servo_lag']")),
             ("can_faults_incision", 7, ()),
             ("straight_incision", 8, ("link.round_trip_ms=40", "link.jitter_ms=3", "link.loss=0.05")),
             ("straight_incision", 9, ("link.round_trip_ms=12", "link.loss=0.2", "link.burst_enter=0.02")),
             ("stiff_contact", 10, ("link.round_trip_ms=30", "link.loss=0.02")),
             ("tremor_incision", 12, ("link.round_trip_ms=6",)),
             ("paper_rolling_disk", 13, ("integrator='rk4'",))]
    return runs


def test_the_seeded_runs_are_at_least_twenty():
    assert len(_seeded_runs()) >= 20


@pytest.mark.parametrize("name, seed, sets", _seeded_runs(), ids=lambda x: str(x).replace(" ", ""))
def test_every_seeded_run_replays_identical(tmp_path, name, seed, sets):
    """Every shipped scene, the cobot master with CAN faults, delayed and lossy simulated links:
    each recorded and checked bit for bit (0.3 s each; the 20 take some 25 s here, so they are not
    marked long)."""
    from teleop.scenario.schema import load_scene

    scene = load_scene(name, sets=["duration_s=0.3", f"seed={seed}", *sets])
    result = _record_run(tmp_path / "run", scene)
    res = check_run(tmp_path / "run")
    assert res.identical, res.line
    assert res.ticks == result.summary["steps"] > 0


def test_a_scripted_keyboard_session_replays_identical(tmp_path):
    """A person's keys (read from a pipe here, in real time) on record, tick by tick, and the
    session run again from them: identical; without the keys it would not be."""
    import os
    import threading
    import time

    from teleop.app.keyboard import run_at_keyboard
    from teleop.app.record.runinfo import open_run_record
    from teleop.scenario.schema import load_scene

    scene = load_scene("scalpel_fixture", sets=["duration_s=3.0", "seed=4"])
    r, w = os.pipe()

    def type_keys():
        for text, pause in ((b"w", 0.15), (b"ww", 0.2), (b"\x1b[C", 0.2), (b"r", 0.1), (b" ", 0.15), (b" q", 0.2),
                            (b"x", 0.0)):
            os.write(w, text)
            time.sleep(pause)

    folder = tmp_path / "run"
    folder.mkdir()
    writer = open_run_record(folder / "record.mcap", scene, runner="one_process", operator="keyboard", realtime=True)
    typist = threading.Thread(target=type_keys)
    typist.start()
    try:
        result = run_at_keyboard(scene, quiet=True, fd=r, record=writer)
    finally:
        typist.join()
        writer.close()
        os.close(r)
        os.close(w)
    assert result.summary["stopped_by_operator"]
    keys = read_record(folder / "record.mcap", topics="/operator/keys")["/operator/keys"]
    assert "".join(keys["text"]) == "www\x1b[Cr  qx"
    res = check_run(folder)
    assert res.identical, res.line
    assert res.ticks == result.summary["steps"] > 100
