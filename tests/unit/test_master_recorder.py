"""The master side's capture (teleop.app.recorders.MasterRecorder): its ``nan`` flag, read from the
rows at the end, says whether any captured tick had a non-finite reference tool or virtual
position; its log reads the rows back by the ``log.npz`` names."""

import numpy as np
import pytest

from teleop.app.assembly import build_master
from teleop.scenario.schema import load_scene


@pytest.mark.parametrize(("column", "nan_at"), [(None, None), ("q_r", 3), ("v_p0", 0)])
def test_nan_is_read_from_the_ticks_captured(column, nan_at):
    sc = load_scene("straight_incision", sets=["duration_s=0.01"])
    mb = build_master(sc, 10, np.random.default_rng(0))
    rows = mb.recorder.rows
    rows.n = 5  # five ticks captured, all finite (zeros)
    assert mb.recorder.nan is False
    if column is not None:
        rows.at(nan_at)[rows.layout.col(column)] = np.nan
        assert mb.recorder.nan is True
        rows.at(nan_at)[rows.layout.col(column)] = 0.0
    rows.at(7)[rows.layout.col("q_r")] = np.inf  # past the ticks captured: not read
    assert mb.recorder.nan is False


def test_the_log_reads_each_tick_as_the_side_left_it():
    """Ten ticks of the cut: the log's pose and wrenches are the side's, tick by tick (the tick's
    values, copied by a hook of the test's own), and the virtual pose is the one as each began."""
    from teleop.app.assembly import build_slave, make_link
    from teleop.tick.loop import BilateralLoop
    from teleop.tick.ports import Hook

    sc = load_scene("straight_incision", sets=["duration_s=0.01"])
    rng = np.random.default_rng(0)
    mb, sb = build_master(sc, 10, rng), build_slave(sc, 10)

    class Copy(Hook):
        def __init__(self):
            self.seen = []

        def before_tick(self, i, t_s, side):
            self.start = np.array(side.master.virtual_pose()[0])

        def after_tick(self, i, t_s, side):
            self.seen.append((self.start, np.array(side.state.p), np.array(side.state.R),
                              np.array(side.hand_W), np.array(side.felt_W), side.status))

    copy = Copy()
    mb.side.add_hooks(copy)
    loop = BilateralLoop(mb.side, sb.side, make_link(sc, rng))
    for i in range(10):
        loop.tick(i)
    log = mb.log(10)
    for i, (start, p, R, hand, felt, status) in enumerate(copy.seen):
        assert np.array_equal(log["q_v_p"][i], start) and np.array_equal(log["p_r"][i], p)
        assert np.array_equal(log["R_r"][i], R) and np.array_equal(log["operator_W"][i], hand)
        assert np.array_equal(log["felt_W"][i], felt)
        rows = mb.recorder.rows
        assert rows.names[int(rows.at(i)[rows.layout.col("status")])] == status
