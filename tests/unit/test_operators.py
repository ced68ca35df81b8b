"""Scripted operators: wrench phases, the virtual hand's path, spring-damper and tremor."""

import numpy as np
import pytest

from teleop.scenario.operators import ScriptedWrench, VirtualHand
from teleop.scenario.schema import FixtureSpec, HandSpec, OperatorSpec, Phase

HAND = HandSpec(((0.0, 0.0, 0.0, 0.1), (2.0, 0.05, 0.0, 0.1)), 300.0, 6.0, 0.0, 0.001, (8.0, 12.0))


def test_hand_follows_the_path_with_a_spring_damper():
    hand = VirtualHand(HAND, None, np.random.default_rng(0), tremor=False)
    np.testing.assert_allclose(hand.path(1.0), [0.025, 0.0, 0.1])
    np.testing.assert_allclose(hand.path_velocity(1.0), [0.025, 0.0, 0.0])
    p = np.array([0.02, 0.001, 0.1])
    v = np.array([0.02, 0.0, 0.0])
    F = hand.wrench(1.0, p, np.eye(3), v, np.zeros(3))
    expected = 300.0 * (np.array([0.025, 0, 0.1]) - p) + 6.0 * (np.array([0.025, 0, 0]) - v)
    np.testing.assert_allclose(F[:3], expected)
    assert np.all(F[3:] == 0)
    np.testing.assert_allclose(hand.path(5.0), [0.05, 0, 0.1])  # holds the last waypoint


def test_tremor_has_the_set_rms_and_lives_in_its_band():
    hand = VirtualHand(HAND, None, np.random.default_rng(3), tremor=True)
    t = np.arange(0, 20.0, 1e-3)
    x = np.array([hand.tremor(ti) for ti in t])
    rms = np.sqrt((x**2).mean(axis=0))
    np.testing.assert_allclose(rms, 0.001, rtol=0.25)
    spec = np.abs(np.fft.rfft(x[:, 0]))
    f = np.fft.rfftfreq(len(t), 1e-3)
    assert 8.0 <= f[np.argmax(spec)] <= 12.0
    in_band = spec[(f >= 7.5) & (f <= 12.5)] ** 2
    assert in_band.sum() / (spec**2).sum() > 0.95


def test_tremor_off_unless_the_effect_is_on_and_seed_determines_it():
    off = VirtualHand(HAND, None, np.random.default_rng(3), tremor=False)
    assert np.all(off.tremor(0.37) == 0)
    a = VirtualHand(HAND, None, np.random.default_rng(3), tremor=True)
    b = VirtualHand(HAND, None, np.random.default_rng(3), tremor=True)
    c = VirtualHand(HAND, None, np.random.default_rng(4), tremor=True)
    assert np.array_equal(a.tremor(0.37), b.tremor(0.37))
    assert not np.array_equal(a.tremor(0.37), c.tremor(0.37))


def test_wrench_phases_ramp_and_repeat():
    spec = OperatorSpec((Phase(0.0, 1.0, (2.0, 0, 0), (0, 0, 0), "world", 0.25),), repeat_s=2.0)
    op = ScriptedWrench(spec, FixtureSpec("free"))
    R = np.eye(3)
    assert op.wrench(0.125, np.zeros(3), R)[0] == pytest.approx(1.0)
    assert op.wrench(0.5, np.zeros(3), R)[0] == pytest.approx(2.0)
    assert op.wrench(1.5, np.zeros(3), R)[0] == 0.0
    assert op.wrench(2.5, np.zeros(3), R)[0] == pytest.approx(2.0)  # repeated
