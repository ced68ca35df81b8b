"""THE control period and nothing else: the two sides of the teleoperator and their messages.

:class:`~teleop.tick.master_side.MasterSide` and :class:`~teleop.tick.slave_side.SlaveSide` each
own everything on their end of the link (their half of the tick, guard, heartbeat, safe state);
:mod:`teleop.tick.messages` are the only things that cross; :mod:`teleop.tick.loop` composes the
two in one process; :mod:`teleop.tick.verdict` judges a run. Transports (:mod:`teleop.link`)
carry the messages and sit above this package.
"""
