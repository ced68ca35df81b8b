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
