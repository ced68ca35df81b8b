"""Every tick on record: an MCAP file written off the tick, which Foxglove opens and ``mcap`` (with
``mcap-ros2-support``) reads without ROS (issue 24, part 1).

    from teleop.app.record import RecordWriter, MasterRecorderMcap, SlaveRecorderMcap, read_record

    with RecordWriter(out / "record.mcap", metadata={"scene": scene.name}) as writer:
        master.side.add_hooks(MasterRecorderMcap(writer, side=master.side))
        slave.side.add_hooks(SlaveRecorderMcap(writer, side=slave.side))
        ...                                    # run: the hooks copy, the writer's process writes
    rec = read_record(out / "record.mcap")     # per channel arrays; reads a killed run's file too
    rec["/slave/contact"]["force"]             # (n, 3) N
    recover(path)                              # a killed writer's file (or spool), finished

``RecordWriter(path, realtime=True)`` for a run paced to the wall clock (its ticks never wait for
the writer), ``spool=True`` where no core is free for the writer (the two-process run: the MCAP
file is written after the run), ``mode="thread"`` for a writer in the run's own process.

:mod:`~teleop.app.record.writer` (the writer process, the rings, crash safety, timestamps),
:mod:`~teleop.app.record.hooks` (what each side records, the channels), :mod:`~teleop.app.record.serve`
(the writer), :mod:`~teleop.app.record.emit` (rows to messages), :mod:`~teleop.app.record.cdr`
(the ROS 2 messages' bytes), :mod:`~teleop.app.record.schemas`, :mod:`~teleop.app.record.reader`.
The Foxglove layout is ``docs/foxglove/teleop_layout.json``.
"""

from teleop.app.record.hooks import LinkRecorderMcap, LoopRecorderMcap, MasterRecorderMcap, SlaveRecorderMcap
from teleop.app.record.reader import Channel, Record, read_record, recover
from teleop.app.record.writer import RecordError, RecordWriter

__all__ = ["Channel", "LinkRecorderMcap", "LoopRecorderMcap", "MasterRecorderMcap", "Record", "RecordError",
           "RecordWriter", "SlaveRecorderMcap", "read_record", "recover"]
