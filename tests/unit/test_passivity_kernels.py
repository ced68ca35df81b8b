"""The compiled passivity guard (teleop.control.passivity_kernels) against the numpy code it
replaced, bit for bit: the oracle below is that code as it was (the ports' observers and
controllers, the slave guard's command, reply and observation), driven tick by tick beside the
ports and guards on random inputs with zeros of both signs, tiny and huge numbers, and (at the
ports) NaN and infinities. Equal means the same bits (a NaN equals a NaN). Run it uncompiled
too: ``NUMBA_DISABLE_JIT=1``."""

import numpy as np
import pytest

from teleop.control.mapping import Registration
from teleop.control.passivity import MasterPassivity, SlavePassivity, TdpaParams, compute_port_energy
from teleop.dynamics.kernels.so3 import exp3
from teleop.tick.guard import MasterGuard, SlaveGuard
from teleop.tick.messages import ContactFeedback, ToolCommand

pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")  # the oracle's numpy on NaN and inf


def _bits(x) -> bytes:
    a = np.asarray(x, dtype=float)
    return np.where(np.isnan(a), np.nan, a).tobytes()


def assert_same(got, want, what=""):
    assert np.shape(got) == np.shape(want), what
    assert _bits(got) == _bits(want), f"{what}: {got!r} != {want!r}"


# ---- the oracle: the numpy code the kernels replaced ------------------------------------------------


class RefMaster:
    def __init__(self, p: TdpaParams):
        self.params = p
        self.E_in, self.E_out, self.E_diss, self.E_remote = np.zeros(6), np.zeros(6), np.zeros(6), np.zeros(6)
        self.W, self.action, self.f_channel, self.f_rendered = np.zeros(6), np.zeros(6), np.zeros(6), np.zeros(6)
        self._counted = False

    def _receive(self, E_remote):
        if E_remote is not None:
            self.E_remote = np.maximum(self.E_remote, np.asarray(E_remote, dtype=float))

    def account(self, v_m):
        if self._counted:
            return
        v_m = np.asarray(v_m, dtype=float)
        p_done = self.f_rendered * v_m
        dt = self.params.dt_s
        self.E_out = self.E_out + np.maximum(p_done, 0.0) * dt
        self.E_in = self.E_in + np.minimum(np.maximum(-self.f_channel * v_m, 0.0), np.maximum(-p_done, 0.0)) * dt
        self._counted = True

    def motion_scale(self, v_m):
        if not (self.params.enabled and self.params.slows_motion) or self._counted:
            return 1.0
        dt = self.params.dt_s
        p_done = self.f_rendered * np.asarray(v_m, dtype=float) * dt
        room = self.E_remote - self.E_out
        sigma = 1.0
        for i in range(6):
            if p_done[i] > 0.0 and p_done[i] > room[i]:
                sigma = min(sigma, max(room[i], 0.0) / p_done[i])
        return sigma

    def energy_after(self, v_m):
        self.account(v_m)
        return self.E_in.copy()

    def step(self, f_m, v_m, E_remote=None):
        p, dt = self.params, self.params.dt_s
        f_m, v_m = np.asarray(f_m, dtype=float), np.asarray(v_m, dtype=float)
        self._receive(E_remote)
        self.account(v_m)
        W = self.E_remote - self.E_out
        alpha = np.zeros(6)
        if p.enabled:
            act = (W < 0.0) & (np.abs(v_m) > p.v_floor)
            cap = np.maximum(np.broadcast_to(p.alpha_max, 6)[act], f_m[act] / v_m[act])
            alpha[act] = np.minimum(-W[act] / (dt * v_m[act] ** 2), cap)
        f_out = f_m - alpha * v_m
        self.E_diss, self.action = self.E_diss + alpha * v_m * v_m * dt, alpha
        self.W = W
        self.f_channel, self.f_rendered, self._counted = f_m, f_out, False
        return f_out


class RefSlave:
    def __init__(self, p: TdpaParams):
        self.params = p
        self.E_in, self.E_out, self.E_diss, self.E_remote = np.zeros(6), np.zeros(6), np.zeros(6), np.zeros(6)
        self.W, self.action, self.offset = np.zeros(6), np.zeros(6), np.zeros(6)

    _receive = RefMaster._receive

    def step(self, v_des, f_s, E_remote=None):
        p, dt = self.params, self.params.dt_s
        v_des, f_s = np.asarray(v_des, dtype=float), np.asarray(f_s, dtype=float)
        self._receive(E_remote)
        p_out = -f_s * v_des
        E_out = self.E_out + np.maximum(p_out, 0.0) * dt
        W = self.E_remote - E_out + self.E_diss
        dv = np.zeros(6)
        if p.enabled:
            act = (W < 0.0) & (np.abs(f_s) > p.f_floor)
            dv[act] = np.clip(-W[act] / (dt * f_s[act]), -p.dv_max, p.dv_max)
            diss = f_s * dv * dt
            if p.drift_gain > 0.0:
                W_after = W + diss
                dc = -p.drift_gain * self.offset
                cost = np.maximum(-f_s * dc * dt, 0.0)
                budget = np.maximum(p.drift_share * W_after, 0.0)
                scale = np.where(cost > budget, budget / np.maximum(cost, 1e-300), 1.0)
                dc = np.where(W_after >= 0.0, dc * scale, 0.0)
                dv = dv + dc
                diss = diss + f_s * dc * dt
        else:
            diss = np.zeros(6)
        v = v_des + dv
        self.E_in = self.E_in + np.maximum(f_s * v_des, 0.0) * dt
        self.E_out, self.E_diss, self.action = E_out, self.E_diss + diss, dv
        self.W = W + diss
        self.offset = self.offset + dv * dt
        return v


class RefSlaveGuard:
    def __init__(self, params, reg, model_offset=True):
        self.port, self.reg, self.model_offset = RefSlave(params), reg, model_offset
        self.f_M, self.speed = np.zeros(6), np.zeros(6)
        self.W_min_J, self.drift_max_m, self.drift_final_m = float("inf"), 0.0, 0.0

    def observe(self):
        self.W_min_J = min(self.W_min_J, float(self.port.W.sum()))
        self.drift_final_m = float(np.linalg.norm(self.port.offset[:3]))
        self.drift_max_m = max(self.drift_max_m, self.drift_final_m)

    def command(self, cmd):
        live = cmd if cmd is not None and cmd.clutch else None
        v_des = np.concatenate((live.v_m_s, live.w_rad_s)) if live is not None else np.zeros(6)
        v = self.port.step(v_des, self.f_M, None if cmd is None else cmd.energy_J)
        p = self.port.params
        self.speed = self.speed + p.dt_s / (p.drift_speed_tau_s + p.dt_s) * (np.abs(v_des) - self.speed)
        if live is None:
            return None
        off = self.port.offset
        return live.p_m + off[:3], exp3(off[3:]) @ live.R, v

    def reply(self, fb, wall_normal_P=None):
        wrench_P = fb.wrench_P
        f_M = self.reg.wrench_to_master(fb.model_offset_P if self.model_offset else wrench_P)
        if wall_normal_P is not None:
            n = self.reg.X_PM_R.T @ wall_normal_P
            f_M = f_M.copy()
            f_M[:3] -= float(n @ f_M[:3]) * n
        self.f_M = f_M
        off = self.port.offset
        if np.any(off):
            p = self.port.params
            pull_M = np.asarray(p.drift_stiffness) * off * np.minimum(self.speed / p.drift_speed, 1.0)
            R, fs, ts = self.reg.X_PM_R, float(self.reg.force_scale), float(self.reg.torque_scale or 1.0)
            wrench_P = wrench_P + np.concatenate((R @ pull_M[:3] / fs, R @ pull_M[3:] / ts))
        plane = fb.plane_P
        if off[:3].any() and plane[7] > 0.0:
            plane = plane.copy()
            plane[3:6] -= self.reg.X_PM_R @ off[:3] / float(self.reg.scale)
        return wrench_P, plane


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


def _params(rng, **kw):
    a = float(rng.choice([0.5, 10.0, 1e6]))
    alpha = a if rng.random() < 0.5 else tuple(a * rng.uniform(0.5, 2.0, 6))
    return TdpaParams(dt_s=float(rng.choice([5e-4, 1e-3])), enabled=bool(rng.random() < 0.8), alpha_max=alpha,
                      v_floor=1e-6, f_floor=1e-6, dv_max=float(rng.choice([0.01, 10.0])),
                      drift_gain=float(rng.choice([0.0, 2.0])), drift_share=float(rng.uniform(0.0, 1.0)),
                      drift_stiffness=tuple(rng.uniform(0.0, 500.0, 6)), slows_motion=bool(rng.random() < 0.5), **kw)


def _energy(rng, E):
    """A cumulative energy message: the last plus a little (sometimes nothing new, sometimes older)."""
    return np.maximum(E + np.abs(rng.standard_normal(6)) * 10.0 ** rng.integers(-7, -2, 6) * (rng.random(6) < 0.7),
                      0.0)


SEEDS = range(12)


# ---- the ports -----------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("special", [False, True])
def test_master_port_is_the_numpy_port(seed, special):
    rng = np.random.default_rng(seed)
    p = _params(rng)
    port, ref = MasterPassivity(p, log_capacity=200), RefMaster(p)
    E = np.zeros(6)
    for k in range(200):
        v = _vec(rng, scale=0.1, special=special)
        if rng.random() < 0.6:  # the tool's step done: the force's work counted before the step
            assert port.motion_scale(v) == ref.motion_scale(v)
            assert_same(port.energy_after(v), ref.energy_after(v), "energy_after")
        E = _energy(rng, E)
        f, v = _vec(rng, scale=10.0, special=special), _vec(rng, scale=0.1, special=special)
        msg = None if rng.random() < 0.3 else E.copy()
        assert_same(port.step(f, v, msg, t_s=k * p.dt_s), ref.step(f, v, msg), f"tick {k}: the force")
        for name in ("E_in", "E_out", "E_diss", "E_remote", "W", "action", "f_channel", "f_rendered"):
            assert_same(getattr(port, name), getattr(ref, name), f"tick {k}: {name}")
        assert_same(port.observer_sum(), ref.W.sum(), "observer_sum")
    assert_same(port.log.arrays()["W_J"][-1], ref.W)


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("special", [False, True])
def test_slave_port_is_the_numpy_port(seed, special):
    rng = np.random.default_rng(100 + seed)
    p = _params(rng)
    port, ref = SlavePassivity(p), RefSlave(p)
    E = np.zeros(6)
    for k in range(200):
        E = _energy(rng, E)
        v, f = _vec(rng, scale=0.1, special=special), _vec(rng, scale=10.0, special=special)
        msg = None if rng.random() < 0.3 else E.copy()
        assert_same(port.step(v, f, msg), ref.step(v, f, msg), f"tick {k}: the velocity")
        for name in ("E_in", "E_out", "E_diss", "E_remote", "W", "action", "offset"):
            assert_same(getattr(port, name), getattr(ref, name), f"tick {k}: {name}")


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


# ---- the guards ----------------------------------------------------------------------------------------


def _rotation(rng):
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


@pytest.mark.parametrize("seed", SEEDS)
def test_slave_guard_is_the_numpy_guard(seed):
    rng = np.random.default_rng(200 + seed)
    p = _params(rng, drift_speed=0.01)
    reg = Registration(rng.standard_normal(3), _rotation(rng), float(rng.choice([1.0, 3.0])),
                       float(rng.choice([1.0, 0.5])))
    model_offset = bool(rng.random() < 0.5)
    g, ref = SlaveGuard(p, reg, model_offset=model_offset), RefSlaveGuard(p, reg, model_offset)
    E = np.zeros(6)
    for k in range(150):
        E = _energy(rng, E)
        cmd = None
        if rng.random() < 0.9:
            cmd = ToolCommand(k, k * p.dt_s, rng.standard_normal(3) * 0.1, _rotation(rng), _vec(rng, 3, 0.05),
                              _vec(rng, 3, 0.5), bool(rng.random() < 0.85), E.copy())
        out, want = g.command(cmd, k * p.dt_s), ref.command(cmd)
        if want is None:
            assert out is cmd
        else:
            assert out is not None
            assert_same(out.p_m, want[0], "p")
            assert_same(out.R, want[1], "R")
            assert_same(out.v_m_s, want[2][:3], "v")
            assert_same(out.w_rad_s, want[2][3:], "w")
            assert_same(out.energy_J, cmd.energy_J)
            assert out.seq == cmd.seq
        assert_same(g.speed, ref.speed, "speed")
        assert_same(g.drift_M, ref.port.offset, "offset")
        D = rng.standard_normal((6, 6))
        plane = np.zeros(8)
        if rng.random() < 0.7:
            n = rng.standard_normal(3)
            plane = np.concatenate((n / np.linalg.norm(n), rng.standard_normal(3) * 0.1,
                                    [rng.uniform(0, 1e4), float(rng.choice([0.0, 0.5, 1.0]))]))
        fb = ContactFeedback(k, k * p.dt_s, _vec(rng, scale=5.0), "ok", k, np.zeros(6), D + D.T, _vec(rng, scale=0.01),
                             plane)
        normal = None
        if rng.random() < 0.4:
            normal = rng.standard_normal(3)
            normal /= np.linalg.norm(normal)
        got, (wrench, plane_want) = g.reply(fb, normal), ref.reply(fb, normal)
        assert_same(got.wrench_P, wrench, f"tick {k}: the wrench")
        assert_same(got.plane_P, plane_want, f"tick {k}: the plane")
        assert_same(got.energy_J, ref.port.E_in, "energy")
        assert_same(g.f_M, ref.f_M, "f_M")
        g.observe()
        ref.observe()
        assert (g.W_min_J, g.drift_final_m, g.drift_max_m) == (ref.W_min_J, ref.drift_final_m, ref.drift_max_m)


def test_master_guard_observes_the_numpy_sum():
    rng = np.random.default_rng(5)
    p = _params(rng)
    g, ref = MasterGuard(p), RefMaster(p)
    W_min = float("inf")
    for k in range(100):
        f, v = _vec(rng, scale=10.0), _vec(rng, scale=0.1)
        assert_same(g.feedback(f, v, None, k * p.dt_s), ref.step(f, v, None))
        g.observe()
        W_min = min(W_min, float(ref.W.sum()))
        assert g.W_min_J == W_min


def test_max_and_min_are_numpy_s():
    """np.maximum / np.minimum on every pair of special values: NaN wins, and of two equal values
    (0.0 and -0.0) the second."""
    from teleop.control.passivity_kernels import _max, _min

    special = [0.0, -0.0, 1.0, -1.0, 1e-300, np.inf, -np.inf, np.nan]
    for a in special:
        for b in special:
            assert_same(_max(a, b), np.maximum(np.array([a]), np.array([b]))[0], f"max({a}, {b})")
            assert_same(_min(a, b), np.minimum(np.array([a]), np.array([b]))[0], f"min({a}, {b})")
