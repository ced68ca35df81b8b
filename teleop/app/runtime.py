"""Run a scene in one process: both sides built by :mod:`teleop.app.assembly`, composed by
:class:`~teleop.tick.loop.BilateralLoop` on the scene's link (lockstep, or the simulated channel
of its [link] table) and run by a :class:`~teleop.app.session.Session` on the simulated clock (or
paced to the wall clock), with the scene's metrics as hooks. The tick itself is
:mod:`teleop.tick`.
"""

from __future__ import annotations

import numpy as np

from teleop.app.assembly import (
    build_master,
    build_slave,
    exempt_metrics,
    make_guard,
    make_link,
    make_master,
    make_slave,
)
from teleop.app.metrics import TremorProbe, link_metrics
from teleop.app.session import RunResult, Session, tick_count
from teleop.scenario.schema import FixtureSpec, Scene
from teleop.tick.loop import BilateralLoop
from teleop.tick.ports import Hook

__all__ = ["RunResult", "make_guard", "make_link", "make_master", "make_slave", "run_scene"]


class _ViewHook(Hook):
    """Hands each tick to a view (which throttles itself)."""

    def __init__(self, view):
        self.view = view

    def after_tick(self, i, t_s, loop) -> None:
        self.view.publish_tick(t_s, loop)


def run_scene(scene: Scene, progress=None, realtime: bool = False, operator=None, view=None, hooks=(),
              status_line=None, simulated_link: bool | None = None, record=None) -> RunResult:
    """Run a scene. ``operator`` replaces the scene's (e.g. a keyboard; one with ``stats()`` adds
    them to the summary as "operator"); ``view`` gets every tick and throttles itself;
    ``progress(i, n)`` is called every 1000 ticks; ``hooks`` more loop :class:`~teleop.tick.ports.Hook` s,
    after the scene's own; ``status_line`` a :class:`~teleop.app.statusline.StatusLine` (it watches the
    session); ``simulated_link`` forces the link (:func:`make_link`: True, the simulated channel of
    the scene's [link] table even when it asks for nothing, as the fault campaign's link loss
    needs). The scene's ``heartbeat_ms`` watches a link that can lose messages
    (:mod:`teleop.tick.heartbeat`). ``record``: a :class:`~teleop.app.record.RecordWriter` both
    sides write every tick to (the caller opens and closes it)."""
    n = tick_count(scene.duration_s, scene.dt_s)  # refuses a run past MAX_TICKS before building anything
    rng = np.random.default_rng(scene.seed)
    mb = build_master(scene, n, rng, operator, record=record)
    sb = build_slave(scene, n, record=record)
    link = make_link(scene, rng, simulated_link) if sb is not None else None
    loop_hooks: list[Hook] = []
    tremor = None
    op = mb.side.operator
    if sb is not None and getattr(op, "tremor_on", False) and isinstance(scene.fixture, FixtureSpec):
        reg = mb.registration
        tremor = TremorProbe(op, n, reg.scale, reg.X_PM_R, scene.fixture.plane_normal)
        loop_hooks.append(tremor)
    if view is not None:
        loop_hooks.append(_ViewHook(view))
    loop_hooks += list(hooks) + ([status_line] if status_line is not None else [])
    loop = BilateralLoop(mb.side, sb.side if sb is not None else None, link, loop_hooks)
    session = Session.of(loop, scene.duration_s, mb.recorder, realtime=realtime, progress=progress)
    if status_line is not None:
        status_line.watch(session)
    run = session.run_ticks()
    steps = run.steps
    metrics = mb.result()
    run.log.update(mb.log(steps))
    if sb is not None:
        metrics.update(sb.result())
        run.log.update(sb.log(steps))
    if tremor is not None:
        metrics.update(tremor.result(scene.dt_s))
    if sb is not None:  # the felt force against the true one (and the guard's drift)
        metrics.update(link_metrics(run.master, run.slave, run.log, mb.registration, scene.dt_s,
                                    scene.link.round_trip_ms * 1e-3))
    # Ctrl-C may land between two hooks: every series keeps the ticks all of them recorded
    steps = min([steps] + [len(v) for v in run.log.values()])
    run.steps, run.log = steps, {k: v[:steps] for k, v in run.log.items()}
    result = Session.result(run, metrics, exempt_metrics(scene))
    result.summary = {"scenario": scene.name, **result.summary, "integrator": scene.integrator,
                      "master": scene.master, "seed": scene.seed, "effects": list(scene.effects)}
    if callable(getattr(op, "stats", None)):
        result.summary["operator"] = op.stats()
    return result
