"""The master side's per-tick log (teleop.app.recorders.MasterRecorder): its ``nan`` flag, read
from the log at the end, says whether any logged tick had a non-finite reference tool or virtual
position."""

import numpy as np
import pytest

from teleop.app.assembly import build_master
from teleop.scenario.schema import load_scene


@pytest.mark.parametrize(("field", "nan_at"), [(None, None), ("q_r", 3), ("q_v_p", 0)])
def test_nan_is_read_from_the_ticks_logged(field, nan_at):
    sc = load_scene("straight_incision", sets=["duration_s=0.01"])
    mb = build_master(sc, 10, np.random.default_rng(0))
    rec = mb.recorder
    rec.n = 5  # five ticks logged, all finite (zeros)
    assert rec.nan is False
    if field is not None:
        rec.log[field][nan_at, 0] = np.nan
        assert rec.nan is True
        rec.log[field][nan_at, 0] = 0.0
    rec.log["q_r"][7, 0] = np.inf  # past the ticks logged: not read
    assert rec.nan is False
