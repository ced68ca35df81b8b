"""The shared unknown-key check of config tables: it names the table, the key and a close match."""

import pytest

from teleop.can.faults import Faults
from teleop.slave import SlaveConfig
from teleop.util.errors import ConfigError, check_table


def test_a_typo_names_the_table_the_key_and_the_closest_known_key():
    with pytest.raises(ConfigError, match=r"^slave\.solvr: unknown key; did you mean 'solver'\?"):
        SlaveConfig.from_dict({"solvr": "osqp"}, "slave")
    with pytest.raises(ConfigError, match=r"^cobot\.faults\.loss_pc: unknown fault; did you mean 'loss_pct'\?"):
        Faults.from_dict({"loss_pc": 1.0}, "cobot.faults")


def test_a_key_far_from_every_known_one_lists_them_all_and_a_non_table_is_refused():
    with pytest.raises(ConfigError, match=r"^t\.zzz: unknown key; known: \['a', 'b'\]$"):
        check_table({"a": 1, "zzz": 2}, "t", ("b", "a"))
    with pytest.raises(ConfigError, match=r"^t: expected a table, got list$"):
        check_table([1], "t", ("a",))
    check_table({"a": 1}, "t", ("a",))  # a valid table passes
