"""Issue 25's papercuts, each as a user meets it: the real-time factor without the compile, a
reader that goes away, -vv, --hold alone, a misspelt scene, --dt past the slave's gain, --json's
mode, a --set into a table the scene does not have, the keyboard status line's reasons."""

import json
import logging
import os
import subprocess
import sys
import time
from types import SimpleNamespace as NS

import numpy as np
import pytest

from teleop.app import progress
from teleop.app.cli import EXIT_READER_GONE, _summary_text, main
from teleop.app.statusline import LIMIT_WORDS, reasons
from teleop.scenario.schema import OPTIONAL_TABLES, load_scene
from teleop.util.errors import SceneError


def _one_line_error(capsys, *parts) -> str:
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("teleop: error: "), err
    for part in parts:
        assert part in lines[0], lines[0]
    return lines[0]


# -- the real-time factor leaves the kernels' compile out -------------------------------------------

def test_the_compile_clock_takes_only_the_compile_inside_the_run_out_of_the_real_time_factor():
    clock = progress.CompileClock()
    clock.first_tick = 100.0
    clock.spans = [(90.0, 95.0), (99.0, 104.0), (104.5, 105.0), (200.0, 210.0)]  # before, across, in, after
    s = {"steps": 2000, "dt_s": 0.001, "wall_s": 7.5, "realtime_factor": 2.0 / 7.5}
    clock.discount(s)
    assert s["compile_s"] == pytest.approx(4.5)  # 4 s of the second span and the third, not the others
    assert s["realtime_factor"] == pytest.approx(2.0 / 3.0, rel=1e-3)
    untouched = {"steps": 10, "dt_s": 0.001, "wall_s": 0.01, "realtime_factor": 1.0}
    assert progress.CompileClock().discount(dict(untouched)) == untouched  # no tick seen: nothing to say


def test_a_first_run_that_compiles_reports_the_loop_rate_and_the_compile_apart(tmp_path, monkeypatch, capsys):
    """A compile inside the first tick (numba's own 'numba:compile' event, as a cold cache fires
    it) no longer drags the real-time factor down: it is reported apart."""
    from numba.core import event

    from teleop.app import runtime
    from teleop.tick.ports import Hook

    class CompilesOnce(Hook):
        def before_tick(self, i, t_s, loop):
            if i == 0:
                with event.trigger_event("numba:compile", data={"dispatcher": None, "args": (), "return_type": None}):
                    time.sleep(0.6)

    real = runtime.run_scene
    monkeypatch.setattr(runtime, "run_scene", lambda scene, hooks=(), **kw: real(scene, hooks=[*hooks, CompilesOnce()],
                                                                                **kw))
    out = tmp_path / "s.json"
    assert main(["run", "paper_rolling_disk", "--duration", "0.2", "--json", str(out)]) == 0
    s = json.loads(out.read_text())
    assert s["compile_s"] >= 0.55
    # wall_s and compile_s are written to the millisecond: the loop's own time lies within 1 ms of their difference
    simulated, loop_s = s["steps"] * s["dt_s"], s["wall_s"] - s["compile_s"]
    assert simulated / (loop_s + 0.001) * 0.99 <= s["realtime_factor"] <= simulated / max(loop_s - 0.001, 1e-4) * 1.01
    assert s["realtime_factor"] > 0.2 / s["wall_s"] * 1.5  # well above what the wall clock alone says
    assert "not counting" in capsys.readouterr().out and "compiling the kernels" in _summary_text(s)


def test_the_bar_leaves_the_compile_out_of_its_rate(monkeypatch):
    import io

    class Tty(io.StringIO):
        def isatty(self):
            return True

    monkeypatch.setattr(progress, "BAR_DELAY_S", 0.0)
    clock = progress.CompileClock()
    clock.first_tick = time.perf_counter() - 10.0
    clock.spans = [(clock.first_tick, clock.first_tick + 9.0)]
    out = Tty()
    bar = progress.RunBar(10.0, 1e-3, stream=out, clock=clock)
    bar.bar.start_t -= 10.0  # 10 s of wall time, 9 of them compiling
    bar(5000, 10_000)
    bar.bar.refresh()
    bar.close()
    import re

    rates = [float(x) for x in re.findall(r"([0-9.]+)x real time", out.getvalue())]
    assert rates and 4.5 < rates[-1] < 5.5  # 5 s simulated in the 1 s of the 10 that did not compile


# -- a reader that goes away ---------------------------------------------------------------------------

def test_a_closed_pipe_on_stdout_ends_quietly_with_141():
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    p = subprocess.Popen([sys.executable, "-m", "teleop", "list"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         env=env)
    p.stdout.close()  # the reader is gone before the first line: `teleop list | head -0`
    err = p.stderr.read().decode()
    assert p.wait(timeout=120) == EXIT_READER_GONE == 141
    assert err == ""  # no traceback, no "Exception ignored", no error line


def test_teleop_list_into_head_is_quiet():
    bindir = os.path.dirname(sys.executable)
    r = subprocess.run(["bash", "-c", f'"{bindir}/teleop" list | head -1; echo "rc=${{PIPESTATUS[0]}}"'],
                       capture_output=True, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"}, timeout=120)
    assert r.stderr == ""
    first, rc = r.stdout.splitlines()
    assert first.split()[0] == "can_faults_incision" and rc in ("rc=0", "rc=141")


def test_a_broken_pipe_inside_the_command_is_141_and_says_nothing(monkeypatch, capsys):
    class Gone:
        def write(self, text):
            raise BrokenPipeError(32, "Broken pipe")

        def flush(self):
            pass

        def fileno(self):
            raise ValueError("no descriptor")

    monkeypatch.setattr(sys, "stdout", Gone())
    assert main(["list"]) == 141
    assert capsys.readouterr().err == ""


# -- -vv ------------------------------------------------------------------------------------------------

def test_vv_says_what_the_command_line_resolved_to_and_v_does_not(capsys):
    assert main(["run", "paper_rolling_disk", "--duration", "0.05", "--set", "damping.linear_Ns_per_m=2.0", "-vv"]) == 0
    err = capsys.readouterr().err
    debug = [line for line in err.splitlines() if line.startswith("teleop: debug: ")]
    assert any("scene paper_rolling_disk from " in line and "dt 0.001 s" in line and "50 ticks" in line
               for line in debug)
    assert any("changed on the command line: damping.linear_Ns_per_m" in line for line in debug)
    assert any("numba kernels cached in " in line for line in debug)
    assert "running 50 ticks" in err  # -v's info too
    assert main(["run", "paper_rolling_disk", "--duration", "0.05", "-v"]) == 0
    err = capsys.readouterr().err
    assert "running 50 ticks" in err and "debug:" not in err


# -- --hold alone ---------------------------------------------------------------------------------------

def test_hold_without_the_viewer_is_refused_in_one_line(capsys, tmp_path):
    assert main(["run", "paper_rolling_disk", "--duration", "0.05", "--hold"]) == 2
    _one_line_error(capsys, "--hold", "--viewer")
    assert main(["replay", str(tmp_path), "--hold"]) == 2
    _one_line_error(capsys, "--hold", "--viewer")


# -- a misspelt scene -----------------------------------------------------------------------------------

def test_a_misspelt_scene_gets_did_you_mean_and_no_placeholder(capsys, tmp_path):
    assert main(["run", "straight_incison"]) == 2
    line = _one_line_error(capsys, "straight_incison: no such scene; did you mean 'straight_incision'?")
    assert "<" not in line
    assert main(["run", "qwertyuiop"]) == 2
    _one_line_error(capsys, "qwertyuiop: no such scene; known scenes: ", "paper_rolling_disk")
    assert main(["run", str(tmp_path / "mine.toml")]) == 2
    assert "<" not in _one_line_error(capsys, "mine.toml: no such scene file")


# -- --dt past the slave's gains ------------------------------------------------------------------------

def test_dt_past_the_slaves_gain_names_the_flag_and_why(capsys):
    assert main(["run", "straight_incision", "--dt", "0.01"]) == 2
    _one_line_error(capsys, "teleop: error: --dt 0.01: ", "task gain 300 /s", "slave.k_task_1ps", "dt < 0.00333 s")
    assert main(["run", "straight_incision", "--set", "slave.k_fixture_1ps=2000"]) == 2
    _one_line_error(capsys, "--set slave.k_fixture_1ps: the slave's fixture gain 2000 /s", "dt < 0.0005 s")
    assert main(["run", "straight_incision", "--set", "dt_s=0.005"]) == 2
    _one_line_error(capsys, "--set dt_s: the slave's task gain 300 /s", "(dt is 0.005 s)")
    assert main(["run", "paper_rolling_disk", "--dt", "0.01", "--duration", "0.05", "-q"]) == 0  # no slave: no rule


# -- --json's mode --------------------------------------------------------------------------------------

@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_json_summaries_get_the_mode_a_new_file_gets(tmp_path, umask, mode):
    from teleop.app.outputs import write_json

    old = os.umask(umask)
    try:
        write_json(tmp_path / "s.json", {"a": 1})
    finally:
        os.umask(old)
    assert (tmp_path / "s.json").stat().st_mode & 0o777 == mode


def test_run_json_is_0644_under_the_usual_umask(tmp_path):
    old = os.umask(0o022)
    try:
        assert main(["run", "paper_rolling_disk", "--duration", "0.05", "-q", "--json", str(tmp_path / "s.json")]) == 0
    finally:
        os.umask(old)
    assert (tmp_path / "s.json").stat().st_mode & 0o777 == 0o644


# -- --set into a table the scene does not have ---------------------------------------------------------

def test_a_set_into_a_missing_slave_table_is_refused_not_a_default_panda(capsys):
    assert main(["run", "paper_rolling_disk", "--set", "slave.solver=daqp", "--duration", "0.05"]) == 2
    _one_line_error(capsys, "slave.solver: the scene has no [slave] table", "--set 'slave={}'")
    with pytest.raises(SceneError, match=r"no \[tissue\] table"):
        load_scene("paper_rolling_disk", sets=["tissue.stiffness=1000"])  # was silently accepted, then unused
    with pytest.raises(SceneError, match=r"no \[operator.hand\] table"):
        load_scene("paper_rolling_disk", sets=["operator.hand.stiffness_N_per_m=100"])
    meant = load_scene("paper_rolling_disk", sets=["slave={}", "slave.solver=daqp"])  # said explicitly: a slave
    assert meant.slave is not None and meant.slave.solver == "daqp"
    assert load_scene("straight_incision", sets=["slave.solver=daqp"]).slave.solver == "daqp"  # it has one
    assert load_scene("paper_rolling_disk", sets=["link.round_trip_ms=10"]).link.round_trip_ms == 10  # defaults
    assert {"slave", "tissue", "damping", "gravity", "operator.hand"} <= OPTIONAL_TABLES


# -- the keyboard's status line says why a push does not move the tool ----------------------------------

def _hand(axis: int, sign: float = 1.0, fixture=None):
    target, effort = np.zeros(6), np.zeros(6)
    target[axis], effort[axis] = 0.01 * sign, 9.5 * sign  # a key held; its push grown near the cap
    return NS(target=target, effort=effort, caps=np.full(6, 10.0), fixture=fixture)


def _still_tool(scene):
    from teleop.scenario.build import build_tool

    return build_tool(scene)  # at rest on its fixture


def test_status_line_reasons_each_with_a_stub():
    from teleop.scenario.build import master_fixture_spec

    scene = load_scene("scalpel_fixture")
    tool, spec = _still_tool(scene), master_fixture_spec(scene)
    assert reasons(NS(clutch_engaged=False, active=())) == ["clutch out (space)"]
    assert reasons(NS(clutch_engaged=True, active=("wall",))) == ["wall: braked at the workspace edge"]
    assert reasons(NS(clutch_engaged=True, active=("speed",))) == ["speed: braked at the speed limit"]
    assert reasons(NS(clutch_engaged=True, active=("spin",))) == ["spin: braked at the turn-rate limit"]
    assert set(LIMIT_WORDS) == {"wall", "speed", "spin"}  # every limit teleop.app.limits names
    # r (push down, z): the scalpel's depth row holds the tool; a (sideways, y): the knife edge
    down = NS(clutch_engaged=True, active=(), inner=_hand(2, -1.0, spec))
    assert reasons(down, tool) == ["held by the fixture along z"]
    side = NS(clutch_engaged=True, active=(), inner=_hand(1, 1.0, spec))
    assert reasons(side, tool) == ["held by the fixture along y"]
    # w (forward, x) is free on the fixture: held still, something else resists (tissue, damping)
    ahead = NS(clutch_engaged=True, active=(), inner=_hand(0, 1.0, spec))
    assert reasons(ahead, tool) == ["pushing x without moving (something resists)"]
    # a push that has not grown, or a tool that moves, is no reason to say anything
    idle = _hand(0, 1.0, spec)
    idle.effort[:] = 0.0
    assert reasons(NS(clutch_engaged=True, active=(), inner=idle), tool) == []
    moving = NS(pose=tool.pose, twist=lambda: (np.array([0.01, 0.0, 0.0]), np.zeros(3)), fixture=tool.fixture)
    assert reasons(ahead, moving) == []


def test_the_status_line_shows_the_reason_beside_the_push():
    from teleop.app.statusline import StatusLine
    from teleop.scenario.build import master_fixture_spec

    scene = load_scene("scalpel_fixture")
    tool = _still_tool(scene)
    hand_W = np.array([0.0, 0.0, -10.0, 0.0, 0.0, 0.0])
    loop = NS(slave=None, status="ok", tool=tool, hand_W=hand_W,
              operator=NS(clutch_engaged=True, active=("wall",), inner=_hand(2, -1.0, master_fixture_spec(scene))))
    text = StatusLine(enabled=False).line(1.0, 1.0, loop)
    assert "hand 10.00 N" in text
    assert text.endswith("| slave - | wall: braked at the workspace edge, held by the fixture along z")


def test_the_status_line_reads_a_master_side_alone():
    """A two-process master has no slave beside it: the line shows '-' for it (a master-side hook)."""
    from teleop.app.statusline import StatusLine

    tool = _still_tool(load_scene("scalpel_fixture"))
    side = NS(dt=1e-3, status="ok", tool=tool, hand_W=np.zeros(6), operator=NS(clutch_engaged=True, active=()))
    assert "| slave - |" in StatusLine(enabled=False).line(2.0, 1.0, side) + " |"


def test_logging_is_quiet_about_debug_by_default(capsys):
    from teleop.app.cli import configure_logging

    configure_logging(0, False)
    logging.getLogger("teleop.x").debug("hidden")
    logging.getLogger("teleop.x").warning("shown")
    assert capsys.readouterr().err == "teleop: shown\n"
