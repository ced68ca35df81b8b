"""The compiled passivity guard (teleop.control.passivity_kernels): the special values it must
treat as numpy does (NaN wins a max or a min; of two equal zeros, the second), the port energy's
split against numpy's own functions, and the state a recorder holds never written again. The
observers' and controllers' arithmetic is checked against hand sums in
tests/unit/test_link_passivity.py and tests/unit/test_link_guard.py; the kernels replaced numpy
code that gave the same bits on every summary metric and logged array of seeded runs and 19
delay-study rows (docs/design/link.md)."""

import numpy as np
import pytest

from teleop.control.passivity import SlavePassivity, TdpaParams, compute_port_energy

pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")  # numpy on NaN and inf


def _bits(x) -> bytes:
    a = np.asarray(x, dtype=float)
    return np.where(np.isnan(a), np.nan, a).tobytes()


def assert_same(got, want, what=""):
    assert np.shape(got) == np.shape(want), what
    assert _bits(got) == _bits(want), f"{what}: {got!r} != {want!r}"


# ---- inputs -------------------------------------------------------------------------------------------


def _vec(rng, n=6, scale=1.0, special=False):
    """n numbers: normal times 10^k (k in [-12, 2]), with exact +-0 and (special) NaN and +-inf."""
    x = rng.standard_normal(n) * scale * 10.0 ** rng.integers(-12, 3, n)
    pick = rng.random(n)
    x[pick < 0.15] = 0.0
    x[(pick >= 0.15) & (pick < 0.25)] = -0.0
    if special:
        x[(pick >= 0.25) & (pick < 0.28)] = np.nan
        x[(pick >= 0.28) & (pick < 0.30)] = np.inf
        x[(pick >= 0.30) & (pick < 0.32)] = -np.inf
    return x


def test_port_energy_is_numpy_s():
    rng = np.random.default_rng(7)
    for _ in range(200):
        E_in, E_out, P = np.abs(_vec(rng)), np.abs(_vec(rng)), _vec(rng, special=True)
        got = compute_port_energy(E_in, E_out, P, 1e-3)
        with np.errstate(all="ignore"):
            want = E_in + np.maximum(P, 0.0) * 1e-3, E_out + np.maximum(-P, 0.0) * 1e-3
        assert_same(got[0], want[0])
        assert_same(got[1], want[1])


def test_a_state_handed_over_is_never_written_again():
    """A recorder holds the rows of a tick (the record's hand-over rule): every tick and every
    setting makes a new state array."""
    port = SlavePassivity(TdpaParams(dt_s=1e-3, drift_gain=2.0))
    W0, off0 = port.W, port.offset
    before = (W0.copy(), off0.copy())
    port.step(np.ones(6), -np.ones(6), np.zeros(6))
    port.offset = np.full(6, 1e-3)
    port.step(np.ones(6), -np.ones(6), None)
    assert_same(W0, before[0])
    assert_same(off0, before[1])
    assert not np.array_equal(port.W, W0)


def test_max_and_min_are_numpy_s():
    """np.maximum / np.minimum on every pair of special values: NaN wins, and of two equal values
    (0.0 and -0.0) the second."""
    from teleop.control.passivity_kernels import _max, _min

    special = [0.0, -0.0, 1.0, -1.0, 1e-300, np.inf, -np.inf, np.nan]
    for a in special:
        for b in special:
            assert_same(_max(a, b), np.maximum(np.array([a]), np.array([b]))[0], f"max({a}, {b})")
            assert_same(_min(a, b), np.minimum(np.array([a]), np.array([b]))[0], f"min({a}, {b})")
