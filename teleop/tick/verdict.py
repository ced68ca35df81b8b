"""One verdict and one summary shape for every runner: one process or two, simulated or wall
clock, keyboard, benches and campaigns. A run's parts are the sides' own summaries
(:meth:`MasterSide.summary`, :meth:`SlaveSide.summary`) and the scene's metrics; whatever carried
the link, the same parts give the same status.

The status covers both sides (:func:`verdict`): "ok" only when both did what was asked.
"""

from __future__ import annotations

from collections.abc import Iterable

#: slave statuses that keep a run from being "ok", mildest first: the run goes on (the slave holds
#: or degrades safely), but its status names the worst of them ("slave_<status>"). "saturated"
#: (a joint bound active, the target still met) is reported in the counts only; relaxed fixture rows
#: (DEGRADED: "fixtures_relaxed") fail the run only on more than RELAXED_SHARE_MAX of its ticks (the
#: fixture tolerances still hold the result); any other fault fails it on one tick.
SLAVE_FAULTS = ("hold", "link_lost", "tracking_error", "fixtures_relaxed", "joint_limit", "infeasible_fallback",
                "invalid_target", "implausible_command")
DEGRADED = ("fixtures_relaxed",)
#: the share of ticks the slave may spend with its fixtures relaxed (DEGRADED) in an "ok" run
RELAXED_SHARE_MAX = 0.01
#: the slave tool's largest distance from its target in an "ok" run, m
SLAVE_TARGET_MAX_M = 0.005
#: each fixture metric's tolerance in an "ok" run (the master side's virtual tool, as the encoders
#: see it, and the slave's blade): m, rad, m/s. A metric absent from a run is not checked.
FIXTURE_TOLERANCES = {
    "depth_error_max_m": 1e-3, "blade_tilt_max_rad": 0.1, "sideslip_max_m_per_s": 0.01,
    "height_error_max_m": 1e-3, "upright_error_max_rad": 0.1,
    "sphere_deviation_max_m": 1e-3, "normal_angle_error_max_rad": 0.1,
    # a user's type: holonomic rows by residual, the others by rate
    "fixture_residual_max": 1e-3, "fixture_rate_max": 0.01,
}
SLAVE_FIXTURE_TOLERANCES = {"cut_depth_error_max_m": 1e-3, "rcm_error_max_m": 2e-3, "slave_fixture_residual_max": 1e-3}


def verdict(master_status: str, steps: int, slave_counts: dict | None = None, metrics: dict | None = None,
            nan: bool = False, exempt: Iterable[str] = (), master_link_lost: int = 0) -> tuple[str, str]:
    """The run's one-word status and a one-line reason, first match wins: "interrupted" (Ctrl-C),
    the master side's fault (``link_refused`` included), "no_ticks", "nan", "link_lost" (either side
    lost the link and held), "slave_<status>" (the worst slave fault, see SLAVE_FAULTS),
    "fixture_violated" (the master side past FIXTURE_TOLERANCES), "slave_fixture_violated"
    (SLAVE_FIXTURE_TOLERANCES), "slave_off_target" (the slave's tool farther than SLAVE_TARGET_MAX_M
    from its target), else "ok". ``exempt``: metric names the scene's fixture does not hold (a
    trocar's fixture lets the blade tilt). ``master_link_lost``: the ticks the master spent in its
    lost-link safe state (:mod:`teleop.tick.heartbeat`): the run is "link_lost" unless the slave did
    worse than ``link_lost``."""
    counts, metrics = slave_counts or {}, metrics or {}
    if master_status == "interrupted":
        return "interrupted", f"stopped by Ctrl-C or SIGTERM after {steps} ticks: a partial run"
    if master_status not in ("ok", "stopped_by_operator"):  # its reason, even before a first tick
        return master_status, f"the master side stopped the run: {master_status}"
    if steps == 0:
        return "no_ticks", "the run ended before its first tick"
    if nan:
        return "nan", "the tool's state became NaN"
    total = max(1, sum(counts.values()))
    worst = [s for s in SLAVE_FAULTS if counts.get(s, 0) and (
        s not in DEGRADED or counts[s] / total > RELAXED_SHARE_MAX)]
    if master_link_lost and (not worst or SLAVE_FAULTS.index(worst[-1]) <= SLAVE_FAULTS.index("link_lost")):
        return "link_lost", (f"the master lost the link to the slave on {master_link_lost} ticks "
                             "(held in its safe state)")
    if worst and worst[-1] == "link_lost":  # the link's fault, not the slave's: the same word either side
        return "link_lost", f"the slave lost the link to the master on {counts['link_lost']} of {total} ticks (held)"
    if worst:
        s = worst[-1]
        return f"slave_{s}", f"the slave was {s!r} on {counts[s]} of {total} ticks"
    for status, tols in (("fixture_violated", FIXTURE_TOLERANCES),
                         ("slave_fixture_violated", SLAVE_FIXTURE_TOLERANCES)):
        for key, tol in tols.items():
            if key not in exempt and metrics.get(key, 0.0) > tol:
                return status, f"{key} = {metrics[key]:.3g}, past its tolerance {tol:g}"
    far = metrics.get("tip_tracking_max_m", 0.0)
    if far > SLAVE_TARGET_MAX_M:
        return "slave_off_target", f"the slave's tool was {far:.3g} m from its target (bound {SLAVE_TARGET_MAX_M:g} m)"
    return "ok", "both sides did what was asked"


def run_status(master_status: str, steps: int, slave_counts: dict | None, metrics: dict | None = None,
               nan: bool = False, master_link_lost: int = 0) -> str:
    """The run's one-word verdict (:func:`verdict`)."""
    return verdict(master_status, steps, slave_counts, metrics, nan, master_link_lost=master_link_lost)[0]


def run_summary(master_status: str, steps: int, dt_s: float, master: dict | None, slave: dict | None,
                metrics: dict, nan: bool, exempt: Iterable[str] = (), link: dict | None = None) -> dict:
    """The summary of a run from its parts: ``master`` (:meth:`MasterSide.summary`, None for a
    slave process alone), ``slave`` (:meth:`SlaveSide.summary`, None without a slave or for a
    master process alone, which judges the slave by the statuses its replies carried), the
    scene's ``metrics`` of both sides, ``nan`` (the master's tool went non-finite). Keys:
    ``status``, ``status_reason``, ``master_status``, ``steps``, ``dt_s``, ``duration_s``,
    ``nan``, ``metrics``, and what the parts hold (``slave_statuses``, ``heartbeat``,
    ``passivity``, counters). ``link``: the transports' counters by end (a link that refused
    frames only an attacker sends makes the run ``link_attacked``: refused, but said)."""
    m, s = master or {}, slave or {}
    counts = s.get("slave_statuses") if slave is not None else m.get("slave_statuses_heard")
    lost_m = m.get("heartbeat", {}).get("lost_ticks", 0)
    status, reason = verdict(master_status, steps, counts, metrics, nan, tuple(exempt), lost_m)
    if status == "ok" and slave is not None and s.get("heartbeat", {}).get("lost_ticks", 0):
        status, reason = "link_lost", (f"the slave lost the link on {s['heartbeat']['lost_ticks']} ticks "
                                       "(held its joints)")
    if status == "ok" and m.get("pushes_refused"):
        status, reason = "push_refused", (f"the hand's wrench could not be applied on {m['pushes_refused']} ticks "
                                          "(not 6 finite numbers, or past a hand's strength)")
    attacks = link_attacks(link or {})
    if status == "ok" and attacks:
        status, reason = "link_attacked", ("frames no paired peer sends reached the link and were refused: "
                                           + ", ".join(f"{k} {v}" for k, v in sorted(attacks.items())))
    if status == "ok" and s.get("followed_last_command") is False:  # a slave process that ran out of time
        status, reason = "link_lost", (f"the slave followed the master's commands up to {s['last_command_seq']}: "
                                       "the master's last never reached it")
    out = {"status": status, "status_reason": reason, "master_status": master_status, "steps": steps,
           "dt_s": dt_s, "duration_s": steps * dt_s, "nan": bool(nan)}
    if counts is not None:
        out["slave_statuses"] = dict(counts)
    passivity = {**m.get("passivity_master", {}), **s.get("passivity_slave", {})}
    if passivity:
        out["passivity"] = passivity
    hearts = {k: p["heartbeat"] for k, p in (("master", master), ("slave", slave)) if p is not None}
    out["heartbeat"] = hearts
    for part in (m, s):
        out.update({k: v for k, v in part.items() if k not in ("heartbeat", "slave_statuses", "passivity_master",
                                                                "passivity_slave", "slave_statuses_heard")})
    if master is not None:
        out["slave_statuses_heard"] = m.get("slave_statuses_heard", {})
    out["metrics"] = dict(metrics)
    return out


#: refusal reasons no paired peer's frames ever have (a stale or duplicate frame may be the network's)
ATTACK_REASONS = ("malformed", "bad_mac", "other_session", "second_master", "far_future", "invalid")


def link_attacks(link: dict) -> dict[str, int]:
    """The frames refused for :data:`ATTACK_REASONS`, summed over the link's ends (each end's
    counters ``{"refused": {reason: n}}``)."""
    out: dict[str, int] = {}
    for end in link.values():
        refused = end.get("refused", {}) if isinstance(end, dict) else {}
        for k in ATTACK_REASONS:
            if refused.get(k):
                out[k] = out.get(k, 0) + int(refused[k])
    return out
