"""CobotConfig: defaults, validation naming the key and the reason."""

import numpy as np
import pytest

from teleop.can.faults import Faults
from teleop.master import CobotConfig, CobotMaster
from teleop.util.errors import ConfigError


def test_defaults():
    cfg = CobotConfig.from_dict({}, "master")
    assert cfg.scale == 1.0 and cfg.capture_path is None and cfg.realtime is False
    assert cfg.kp == (40000.0,) * 6 and isinstance(cfg.faults, Faults) and cfg.fd


def test_vectors_and_faults():
    cfg = CobotConfig.from_dict({"kp": [1e4, 1e4, 1e4, 2e4, 2e4, 2e4], "faults": {"loss_pct": 5}}, "m")
    assert cfg.kp[3] == 2e4 and cfg.faults.loss_pct == 5.0


@pytest.mark.parametrize("d, key, why", [
    ({"scael": 1}, "scael", "unknown"), ({"scale": 0}, "scale", "expected"), ({"kp": [1, 2]}, "kp", "6 finite"),
    ({"stale_cycles": 2.5}, "stale_cycles", "integer"), ({"fd": False}, "fd", "CAN FD"),
    ({"faults": {"loss_pct": -1}}, "faults.loss_pct", "expected"), ({"realtime": "yes"}, "realtime", "true or false"),
    ({"encoder_m": float("nan")}, "encoder_m", "expected"),
])
def test_errors_name_where_and_key(d, key, why):
    with pytest.raises(ConfigError, match=rf"^scene\.cobot\.{key}: .*{why}"):
        CobotConfig.from_dict(d, "scene.cobot")


@pytest.mark.parametrize("key, bad", [("tracking_fault_m", 0.0), ("tracking_fault_rad", -1.0),
                                      ("tracking_fault_m", float("nan"))])
def test_tracking_fault_thresholds_must_be_positive(key, bad):
    with pytest.raises(ConfigError, match=f"cobot.{key}"):
        CobotConfig.from_dict({key: bad}, "cobot")


def test_a_period_shorter_than_the_read_window_is_a_config_error():
    """--dt 1e-4 below cobot.read_window_s (3e-4 s): a clear error naming both, before any bus opens
    (it used to end in startup_timeout)."""
    with pytest.raises(ConfigError, match=r"dt_s.*cobot\.read_window_s"):
        CobotMaster(CobotConfig(), 1e-4, np.random.default_rng(0), np.zeros(3), np.eye(3))
