"""Scene metrics, computed every tick from the *virtual* tool (what the encoders measure; for an
ideal master the reference tool itself), as in the paper's Figures 8 and 10.

Each metric set keeps per-tick series for the figures and reduces them to maxima for the JSON.
"""

from __future__ import annotations

import copy
import math
from abc import ABC, abstractmethod

import numpy as np

from teleop.app.recorders import Columns, MasterRecorder, SlaveRecorder
from teleop.dynamics.rotations import cross
from teleop.dynamics.rows import RowStack
from teleop.scenario.schema import FixtureSpec
from teleop.tick.ports import Hook

#: Rolling-error regulariser of Figure 8 D: 1 mm/s.
ROLLING_EPS_M_S = 1e-3


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


class MetricSet(ABC):
    """Collects named per-tick series; ``result()`` reduces them."""

    names: tuple = ()

    def __init__(self, spec: FixtureSpec, n: int, mass_kg: float):
        self.spec, self.mass = spec, mass_kg
        self.n = 0
        self.series = Columns({k: ((), float) for k in self.names}, n)

    def record(self, **values) -> None:
        i = self.n
        self.series.ensure(i)
        for k, v in values.items():
            self.series[k][i] = v
        self.n += 1

    def trimmed(self) -> dict:
        return {k: v[: self.n] for k, v in self.series.items()}

    @abstractmethod
    def update(self, p, R, v, w, operator_W, constraint_W) -> None:
        """Record one tick from the virtual tool pose (p, R), twist (v, w) and the wrenches (6,)."""

    def result(self) -> dict:
        return {}


class RollingDiskMetrics(MetricSet):
    """Figure 8: height error, upright error, rolling velocity V, rolling error (percent)."""

    names = ("height_error_m", "upright_error_rad", "rolling_velocity_m_s", "rolling_error_pct")

    def __init__(self, spec, n, mass_kg):
        super().__init__(spec, n, mass_kg)
        self.nrm = _unit(spec.plane_normal)
        self.o = np.array(spec.plane_origin_m)

    def update(self, p, R, v, w, operator_W, constraint_W):
        axle = R[:, 2]
        forward = cross(self.nrm, axle)
        nf = np.linalg.norm(forward)
        forward = forward / nf if nf > 1e-12 else forward
        V = float(forward @ v)
        r_omega = -self.spec.radius_m * float(w @ axle)  # the paper's r*omega = -r qdot_5
        self.record(
            height_error_m=float(self.nrm @ (p - self.o)) - self.spec.radius_m,
            upright_error_rad=math.asin(max(-1.0, min(1.0, float(self.nrm @ axle)))),
            rolling_velocity_m_s=V,
            rolling_error_pct=100.0 * abs(V - r_omega) / (abs(V) + ROLLING_EPS_M_S),
        )

    def result(self):
        s = self.trimmed()
        return {
            "height_error_max_m": float(np.abs(s["height_error_m"]).max(initial=0.0)),
            "upright_error_max_rad": float(np.abs(s["upright_error_rad"]).max(initial=0.0)),
            "rolling_error_max_pct": float(s["rolling_error_pct"].max(initial=0.0)),
            "rolling_velocity_max_m_s": float(np.abs(s["rolling_velocity_m_s"]).max(initial=0.0)),
        }


class SphereMetrics(MetricSet):
    """Figure 10: deviation from the sphere, normal angle error, normal force along the normal.

    ``normal_force_N`` is the constraint force along the outward normal (what the master renders);
    ``normal_force_expected_N`` is the operator's push into the sphere minus m v_t^2 / r (the
    centripetal term): the value Newton predicts for that force.
    """

    names = ("sphere_deviation_m", "normal_angle_error_rad", "normal_force_N", "normal_force_expected_N", "push_N")

    def __init__(self, spec, n, mass_kg):
        super().__init__(spec, n, mass_kg)
        self.c = np.array(spec.center_m)

    def update(self, p, R, v, w, operator_W, constraint_W):
        d = p - self.c
        dist = float(np.linalg.norm(d))
        n = d / dist
        b = R[:, 2]
        angle = math.atan2(float(np.linalg.norm(cross(n, b))), float(n @ b))
        vt = v - (v @ n) * n
        push = -float(operator_W[:3] @ n)
        self.record(
            sphere_deviation_m=dist - self.spec.radius_m,
            normal_angle_error_rad=angle,
            normal_force_N=float(constraint_W[:3] @ n),
            normal_force_expected_N=push - self.mass * float(vt @ vt) / self.spec.radius_m,
            push_N=push,
        )

    def result(self):
        s = self.trimmed()
        i = int(np.argmax(s["normal_force_N"])) if self.n else 0
        return {
            "sphere_deviation_max_m": float(np.abs(s["sphere_deviation_m"]).max(initial=0.0)),
            "normal_angle_error_max_rad": float(np.abs(s["normal_angle_error_rad"]).max(initial=0.0)),
            "normal_force_max_N": float(s["normal_force_N"].max(initial=0.0)),
            "normal_force_expected_at_max_N": float(s["normal_force_expected_N"][i]) if self.n else 0.0,
            "push_max_N": float(s["push_N"].max(initial=0.0)),
        }


class ScalpelMetrics(MetricSet):
    """The scalpel fixture: blade-tip depth error, blade tilt from the normal, sideways slip speed."""

    names = ("depth_error_m", "blade_tilt_rad", "sideslip_m_per_s", "cut_speed_m_per_s")

    def __init__(self, spec, n, mass_kg):
        super().__init__(spec, n, mass_kg)
        self.nrm = _unit(spec.plane_normal)
        self.o = np.array(spec.plane_origin_m)
        self.tip = np.array(spec.tip_m)

    def update(self, p, R, v, w, operator_W, constraint_W):
        d = R @ self.tip
        tip = p + d
        v_tip = v + cross(w, d)
        blade = R[:, 2]
        tilt = math.atan2(float(np.linalg.norm(cross(blade, -self.nrm))), float(blade @ -self.nrm))
        self.record(
            depth_error_m=float(self.nrm @ (tip - self.o)) + self.spec.depth_m,
            blade_tilt_rad=tilt,
            sideslip_m_per_s=float(R[:, 1] @ v_tip),
            cut_speed_m_per_s=float(R[:, 0] @ v_tip),
        )

    def result(self):
        s = self.trimmed()
        return {
            "depth_error_max_m": float(np.abs(s["depth_error_m"]).max(initial=0.0)),
            "blade_tilt_max_rad": float(np.abs(s["blade_tilt_rad"]).max(initial=0.0)),
            "sideslip_max_m_per_s": float(np.abs(s["sideslip_m_per_s"]).max(initial=0.0)),
            "cut_speed_max_m_per_s": float(np.abs(s["cut_speed_m_per_s"]).max(initial=0.0)),
        }


class FreeMetrics(MetricSet):
    names = ("speed_m_s",)

    def update(self, p, R, v, w, operator_W, constraint_W):
        self.record(speed_m_s=float(np.linalg.norm(v)))

    def result(self):
        return {"speed_max_m_s": float(self.trimmed()["speed_m_s"].max(initial=0.0))}


class FixtureRowMetrics(MetricSet):
    """Any fixture, a user's own included, by its own rows, each judged at the level where it is a
    constraint (as the built-in scalpel's depth and tilt are positions and its side slip a speed):
    a holonomic row h(q) = 0 by its residual |h| (m or rad), a nonholonomic row G nu = 0 by its rate
    |G nu| (m/s or rad/s). ``fixture_holonomic_rate_max`` (|G nu| of the holonomic rows, the
    residual's derivative) is reported, not judged: on a device it is the encoders' quantisation
    differentiated (0.5 mrad at 1 kHz reads ~0.02 rad/s through the observer on every cobot scene)."""

    names = ("fixture_residual", "fixture_rate", "fixture_holonomic_rate")

    def __init__(self, spec, n, mass_kg, constraints=()):
        super().__init__(spec, n, mass_kg)
        # its own copy: a row may keep a warm start (a curved surface's foot point), and the tool's
        # must not move because the metrics evaluated it
        self.rows = RowStack(tuple(copy.deepcopy(tuple(constraints))))
        self.mask = np.asarray(self.rows.holonomic_mask, dtype=bool)

    def update(self, p, R, v, w, operator_W, constraint_W):
        if self.rows.m == 0:
            self.record(fixture_residual=0.0, fixture_rate=0.0, fixture_holonomic_rate=0.0)
            return
        G, _, h = self.rows.evaluate(np.ascontiguousarray(p, dtype=float), np.ascontiguousarray(R, dtype=float))
        rate = np.abs(G @ np.concatenate([v, w]))
        self.record(fixture_residual=float(np.abs(h[self.mask]).max(initial=0.0)),
                    fixture_rate=float(rate[~self.mask].max(initial=0.0)),
                    fixture_holonomic_rate=float(rate[self.mask].max(initial=0.0)))

    def result(self):
        s = self.trimmed()
        return {"fixture_residual_max": float(s["fixture_residual"].max(initial=0.0)),
                "fixture_rate_max": float(s["fixture_rate"].max(initial=0.0)),
                "fixture_holonomic_rate_max": float(s["fixture_holonomic_rate"].max(initial=0.0))}


METRICS = {"rolling_disk": RollingDiskMetrics, "sphere": SphereMetrics, "scalpel": ScalpelMetrics, "free": FreeMetrics}


def make_metrics(spec, n: int, mass_kg: float, constraints=()) -> MetricSet:
    """The metric set of a fixture: the paper's figures' quantities for a built-in type, the rows'
    own residual and rate for a user's type (``constraints``: its rows where the tool is)."""
    if isinstance(spec, FixtureSpec):
        return METRICS[spec.type](spec, n, mass_kg)
    return FixtureRowMetrics(spec, n, mass_kg, constraints)


def band_rms(x: np.ndarray, dt: float, lo_hz: float, hi_hz: float) -> float:
    """RMS of the part of the signal(s) x (n,) or (n, k) in [lo_hz, hi_hz], by FFT (same units)."""
    x = np.asarray(x, dtype=float)
    if x.ndim == 1:
        x = x[:, None]
    n = x.shape[0]
    if n < 4:
        return 0.0
    X = np.fft.rfft(x - x.mean(axis=0), axis=0)
    f = np.fft.rfftfreq(n, dt)
    X[(f < lo_hz) | (f > hi_hz)] = 0.0
    y = np.fft.irfft(X, n=n, axis=0)
    return float(np.sqrt((y**2).sum(axis=1).mean()))


class MasterMetrics:
    """The scene's fixture metrics (a :class:`MetricSet`) of the master: fed, tick by tick in
    order, the virtual tool as the tick began, the operator's wrench of the tick and the
    constraint wrench it produced, all read from the master's rows (``capture``, a
    :class:`~teleop.app.recorders.MasterRecorder`) when :meth:`log` or :meth:`result` is asked.
    Nothing of it runs in the tick (it cost 15 µs a tick there, and nothing in the run reads it
    before the end)."""

    def __init__(self, metrics: MetricSet, capture: MasterRecorder):
        self.metrics, self.capture = metrics, capture
        self._fed = 0

    @property
    def n(self) -> int:
        return self.capture.n

    def _feed(self) -> None:
        """The metric set fed the ticks captured since it was last fed."""
        rows, k = self.capture.rows, self._fed
        n = rows.n
        if n <= k:
            return
        p, R, V = rows.column("v_p0"), rows.column("v_R0", shape=(3, 3)), rows.column("v_V0")
        hand, con = rows.column("hand"), rows.column("con")
        for i in range(k, n):
            self.metrics.update(p[i], R[i], V[i, :3], V[i, 3:], hand[i], con[i])
        self._fed = n

    def log(self) -> dict:
        self._feed()
        return {f"m_{k}": v for k, v in self.metrics.trimmed().items()}

    def result(self) -> dict:
        self._feed()
        return self.metrics.result()


class EnergyDrift(Hook):
    """``energy_drift_rel_max``: the largest relative change of the reference tool's energy
    (kinetic plus potential, J) over the stretches of ticks where no external work is done on it:
    the step applied no wrench (no operator force, no contact feedback: all exactly zero), and the
    tool has no damper or other non-conservative effect. The change is measured from the energy
    at the stretch's start, relative to its magnitude (floor ``E_FLOOR_J``). None (JSON null)
    when the run has no such stretch; a damped tool never has one."""

    #: the smallest energy a relative change is taken of (J)
    E_FLOOR_J = 1e-9

    def __init__(self, tool):
        self.active = not tool.model.dissipative
        self.worst: float | None = None
        self._start = self._prev = None

    def before_tick(self, i, t_s, side) -> None:
        if self.active and self._prev is None:
            self._prev = side.tool.energy()

    def after_tick(self, i, t_s, side) -> None:
        if not self.active:
            return
        tool = side.tool
        W = tool.applied_W
        E = tool.energy()
        if tool.status == "ok" and (W is None or not np.any(W)):
            if self._start is None:
                self._start = self._prev
            rel = abs(E - self._start) / max(abs(self._start), self.E_FLOOR_J)
            self.worst = rel if self.worst is None else max(self.worst, rel)
        else:
            self._start = None
        self._prev = E

    def result(self) -> dict:
        return {"energy_drift_rel_max": self.worst}


def tissue_surface(spec):
    """The curved tissue surface of a fixture type that has one (patient frame: a
    :class:`teleop.dynamics.surface.HeightSurface`), or None: a type opts in with a
    ``tissue_surface()`` method and a ``depth_m`` field (the cutting depth below it, m)."""
    params = getattr(spec, "params", None)
    hook = getattr(params, "tissue_surface", None)
    return hook() if callable(hook) and hasattr(params, "depth_m") else None


class SlaveMetrics:
    """The slave's accuracy, every tick, in the patient frame (``spec``: the scene's fixture):

    * ``tip_tracking_rms_m``, ``tip_tracking_max_m`` - RMS and largest distance of the slave's tool
      frame from its target;
    * ``cut_depth_error_max_m`` - max |depth of the blade tip - fixture depth| while in tissue;
    * ``cut_direction_error_max_rad`` - max angle between the slave's and the target's cutting axes;
    * ``contact_force_max_N`` - max |tissue force| at the blade tip;
    * ``cut_length_m`` - the tip's path while below the surface;
    * ``rcm_error_max_m`` - max distance of the shaft from the trocar (``rcm``: RemoteCenter rows).

    For a user's fixture type ``slave_fixture_residual_max`` (m or rad) is the largest |h| of its
    holonomic rows at the slave's tool; the depth and cut length stay 0 unless the type has a
    tissue surface (:func:`tissue_surface`: a ``tissue_surface()`` method and a ``depth_m``), against
    which the depth is measured along the normal at the tip's foot.

    Off the tick: the series are derived from the slave's rows (``capture``, a
    :class:`~teleop.app.recorders.SlaveRecorder`: its pose, target, tip, contact force and
    joints), tick by tick in order, when :meth:`log` or :meth:`result` is asked (15 µs a tick in
    the tick: nothing in the run reads them before the end). Its constraint rows are its own
    copies (a warm start of theirs is not the arm's).
    """

    def __init__(self, spec, capture: SlaveRecorder, rcm=(), constraints=()):
        plane = isinstance(spec, FixtureSpec)
        self.surface = tissue_surface(spec)
        self._foot = None
        self.depth = spec.depth_m if plane else (float(spec.params.depth_m) if self.surface is not None else 0.0)
        self.normal = _unit(spec.plane_normal) if plane else None
        self.origin = np.asarray(spec.plane_origin_m if plane else (0.0, 0.0, 0.0), dtype=float)
        self.rows = None if plane else RowStack(tuple(copy.deepcopy(tuple(constraints))))
        self.rcm = tuple(copy.deepcopy(tuple(rcm)))
        series = ("track_m", "depth_err_m", "dir_err_rad", "contact_N") + (("rcm_m",) if self.rcm else ()) \
            + (("fixture_residual",) if self.rows is not None else ())
        self.capture = capture
        self.series = Columns({k: ((), float) for k in series}, capture.rows.capacity)
        self._derived = 0

    @property
    def n(self) -> int:
        return self.capture.n

    def _derive(self) -> None:
        """The series of the ticks captured since they were last derived, in order."""
        log, rows, k = self.series, self.capture.rows, self._derived
        n = rows.n
        if n <= k:
            return
        log.ensure(n - 1)
        P, Rs = rows.column("p"), rows.column("R", shape=(3, 3))
        P_t, R_ts = rows.column("p_t"), rows.column("R_t", shape=(3, 3))
        tips, F = rows.column("tip"), rows.column("contact")
        for i in range(k, n):
            p, R, p_t, R_t, tip = P[i], Rs[i], P_t[i], R_ts[i], tips[i]
            if self.surface is not None:
                sd, _, self._foot = self.surface.signed_distance(tip, self._foot)
                depth = -sd
            else:
                depth = -float(self.normal @ (tip - self.origin)) if self.normal is not None else 0.0
            log["track_m"][i] = float(np.linalg.norm(p - p_t))
            # error while the blade is in the tissue; a tiny floor marks "inside" for the cut length
            log["depth_err_m"][i] = max(abs(depth - self.depth), 1e-15) if depth > 0 else 0.0
            log["dir_err_rad"][i] = math.acos(float(np.clip(R[:, 0] @ R_t[:, 0], -1.0, 1.0)))
            log["contact_N"][i] = float(np.linalg.norm(F[i, :3]))
            if self.rcm:
                log["rcm_m"][i] = max(float(np.linalg.norm(r.residual(p, R))) for r in self.rcm)
            if self.rows is not None and self.rows.m:
                h = self.rows.evaluate(np.ascontiguousarray(p), np.ascontiguousarray(R))[2]
                held = h[np.asarray(self.rows.holonomic_mask, bool)]
                log["fixture_residual"][i] = float(np.abs(held).max(initial=0.0))
        self._derived = n

    def log(self) -> dict:
        self._derive()
        n = self.n
        out = {f"slave_{k}": v[:n] for k, v in self.series.items()}
        return {**out, "slave_q": self.capture.rows.column("q", n), "slave_tip": self.capture.rows.column("tip", n)}

    def result(self) -> dict:
        self._derive()
        k, log = self.n, self.series
        out = {
            "tip_tracking_rms_m": float(np.sqrt(np.mean(log["track_m"][:k] ** 2))) if k else 0.0,
            "tip_tracking_max_m": float(log["track_m"][:k].max(initial=0.0)),
            "cut_depth_error_max_m": float(log["depth_err_m"][:k].max(initial=0.0)),
            "cut_direction_error_max_rad": float(log["dir_err_rad"][:k].max(initial=0.0)),
            "contact_force_max_N": float(log["contact_N"][:k].max(initial=0.0)),
        }
        inside = log["depth_err_m"][:k] > 0  # tip below the surface
        if k > 1:
            steps = np.linalg.norm(np.diff(self.capture.rows.column("tip", k), axis=0), axis=1)
            out["cut_length_m"] = float(steps[inside[1:] & inside[:-1]].sum())
        if self.rcm:
            out["rcm_error_max_m"] = float(log["rcm_m"][:k].max(initial=0.0))
        if self.rows is not None:
            out["slave_fixture_residual_max"] = float(log["fixture_residual"][:k].max(initial=0.0))
        return out


class TremorProbe(Hook):
    """A loop hook (it needs both sides in one process): how much physiological tremor the fixtures
    remove: the hand's tremor and the slave tip's motion, both across the cut (the plane normal and
    the blade's side axis, in slave units), in the tremor band. ``tremor_removed_pct`` =
    100 (1 - out / in)."""

    def __init__(self, hand, n: int, scale: float, R_PM: np.ndarray, normal_P):
        self.hand, self.scale, self.R_PM = hand, scale, R_PM
        self.n_P = _unit(normal_P)
        self.across = Columns({"hand": ((2,), float), "tip": ((2,), float)}, n)
        self.k = 0
        self._R_v = None

    def before_tick(self, i, t_s, loop) -> None:
        self._R_v = loop.master.virtual_pose()[1]

    def after_tick(self, i, t_s, loop) -> None:
        self.update(t_s, self._R_v, loop.slave.state.tip)

    def update(self, t: float, R_v: np.ndarray, tip_P: np.ndarray) -> None:
        side_P = self.R_PM @ R_v[:, 1]
        n_M = self.R_PM.T @ self.n_P
        tremor = self.hand.tremor(t)
        self.across.ensure(self.k)
        self.across["hand"][self.k] = (tremor @ n_M / self.scale, tremor @ R_v[:, 1] / self.scale)
        self.across["tip"][self.k] = (tip_P @ self.n_P, tip_P @ side_P)
        self.k += 1

    def result(self, dt: float) -> dict:
        lo, hi = self.hand.spec.tremor_band_hz
        t_in = band_rms(self.across["hand"][: self.k], dt, lo, hi)
        t_out = band_rms(self.across["tip"][: self.k], dt, lo, hi)
        return {
            "tremor_in_rms_m": t_in,
            "tremor_out_rms_m": t_out,
            "tremor_removed_pct": 100.0 * (1.0 - t_out / t_in) if t_in > 0 else 0.0,
        }


def felt_versus_true(felt_N: np.ndarray, true_N: np.ndarray, dt_s: float, max_lag_s: float) -> dict:
    """How the force felt at the master (``felt_N``, (n,) N, the magnitude of what the slave's
    force rendered on the tool) compares with the contact force at the slave (``true_N``, (n,) N,
    already times the feedback gain): the RMS and the peak of their difference, time-aligned at
    the lag in [0, ``max_lag_s``] (the felt force later than the true one by up to the round trip
    and a tick) that makes the RMS least, and that lag (s). Over ticks where either is in contact;
    zeros when neither ever is."""
    n = min(len(felt_N), len(true_N))
    felt, true = np.asarray(felt_N[:n], dtype=float), np.asarray(true_N[:n], dtype=float)
    if n == 0 or not (felt.any() or true.any()):
        return {"felt_error_rms_N": 0.0, "felt_error_peak_N": 0.0, "felt_lag_s": 0.0}
    best = (math.inf, 0.0, 0)
    for lag in range(0, min(n - 1, round(max_lag_s / dt_s)) + 1):  # lags 0 ... max_lag_s, both included
        e = felt[lag:] - true[: n - lag]
        used = (felt[lag:] > 0) | (true[: n - lag] > 0)
        if not used.any():
            continue
        rms = float(np.sqrt(np.mean(e[used] ** 2)))
        if rms < best[0]:
            best = (rms, float(np.abs(e[used]).max()), lag)
    rms, peak, lag = best
    return {"felt_error_rms_N": rms if math.isfinite(rms) else 0.0, "felt_error_peak_N": peak,
            "felt_lag_s": lag * dt_s}


def link_metrics(master: dict | None, slave: dict | None, log: dict, registration, dt_s: float,
                 round_trip_s: float) -> dict:
    """What a run over a guarded or delayed link adds to its metrics, for one process and two
    alike: the guard's drift at the slave's scale (``link_drift_max_m``, ``link_drift_final_m``,
    m), model-mediated the wall's offset from the slave's surface (``link_wall_offset_max_m``,
    ``link_wall_offset_final_m``, m at the slave's scale), and the transparency
    (:func:`felt_versus_true`, when both sides' logs are there)."""
    out: dict = {}
    if master is not None and slave is not None and "passivity_master" in master and "passivity_slave" in slave:
        out["link_drift_max_m"] = slave["passivity_slave"]["drift_max_M_m"] / registration.scale
        out["link_drift_final_m"] = slave["passivity_slave"]["drift_final_M_m"] / registration.scale
    if master is not None and "wall_model" in master:  # model-mediated: the master's surface from the slave's
        out["link_wall_offset_max_m"] = master["wall_model"]["offset_max_M_m"] / registration.scale
        out["link_wall_offset_final_m"] = master["wall_model"]["offset_final_M_m"] / registration.scale
    if "felt_W" in log and "slave_contact_N" in log:
        felt = np.linalg.norm(np.asarray(log["felt_W"])[:, :3], axis=1)
        out.update(felt_versus_true(felt, registration.force_scale * np.asarray(log["slave_contact_N"]), dt_s,
                                    round_trip_s + dt_s))
    return out
