"""Fault settings validation."""

import pytest

from teleop.can.faults import Faults
from teleop.util.errors import ConfigError


def test_defaults_and_from_dict():
    assert not Faults().any
    f = Faults.from_dict({"loss_pct": 5, "latency_ms": 2, "jitter_ms": 1}, "cobot.faults")
    assert f.any and f.loss_pct == 5.0 and f.latency_ms == 2.0


@pytest.mark.parametrize("d, key", [({"loss_pct": 101}, "loss_pct"), ({"jitter_ms": -1}, "jitter_ms"),
                                    ({"latency_ms": "x"}, "latency_ms"), ({"bus_off_at_s": -2}, "bus_off_at_s"),
                                    ({"typo": 1}, "typo")])
def test_bad_values_name_the_key(d, key):
    with pytest.raises(ConfigError, match=rf"cobot\.faults\.{key}"):
        Faults.from_dict(d, "cobot.faults")
