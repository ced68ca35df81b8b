"""Every tick on record: an MCAP file written off the tick, which Foxglove opens and ``mcap`` (with
``mcap-ros2-support``) reads without ROS (issue 24, part 1).

    from teleop.app.record import RecordWriter, MasterRecorderMcap, SlaveRecorderMcap, read_record

    with RecordWriter(out / "record.mcap", metadata={"scene": scene.name}) as writer:
        master.side.add_hooks(MasterRecorderMcap(writer))
        slave.side.add_hooks(SlaveRecorderMcap(writer))
        ...                                    # run: the hooks copy, the writer's thread writes
    rec = read_record(out / "record.mcap")     # per channel arrays; reads a killed run's file too
    rec["/slave/contact"]["force"]             # (n, 3) N
    recover(path)                              # a killed writer's file, finished (summary and all)

:mod:`~teleop.app.record.writer` (the thread, the rings, crash safety, timestamps),
:mod:`~teleop.app.record.hooks` (what each side records, the channels), :mod:`~teleop.app.record.cdr`
(the ROS 2 messages' bytes), :mod:`~teleop.app.record.schemas`, :mod:`~teleop.app.record.reader`.
The Foxglove layout is ``docs/foxglove/teleop_layout.json``.
"""

from teleop.app.record.hooks import LoopRecorderMcap, MasterRecorderMcap, SlaveRecorderMcap
from teleop.app.record.reader import Channel, Record, read_record, recover
from teleop.app.record.writer import RecordError, RecordWriter

__all__ = ["Channel", "LoopRecorderMcap", "MasterRecorderMcap", "Record", "RecordError", "RecordWriter",
           "SlaveRecorderMcap", "read_record", "recover"]
