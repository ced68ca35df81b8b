"""A real `teleop run --operator keyboard` session in a terminal, typed at through tmux.

Each test starts its own tmux server (a private socket) running the CLI in a pty, waits for the
live status line, types, and reads the screen, the exit code and the JSON summary. The scene is
the scalpel fixture with the device's workspace moved (``cobot.offset_m``) so that its -x face is
30 mm from the tool: a held `s` reaches it in about a second.
"""

import json
import os
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
TMUX = shutil.which("tmux")
pytestmark = pytest.mark.skipif(TMUX is None, reason="tmux is not installed (the CI image has it)")
#: the first tick may compile the kernels on a cold cache (about 30-60 s, more on a loaded machine)
START_TIMEOUT_S = 240.0
SCENE = ["scalpel_fixture", "--set", "cobot.offset_m=[0.55, 0.0, 0.0]"]


class Terminal:
    """A tmux server on its own socket with one 200x50 window running ``command``."""

    def __init__(self, tmp: Path, command: str):
        self.socket = str(tmp / "tmux.sock")
        self.rc_file = tmp / "rc"
        env = {**os.environ, "PYTHONPATH": str(REPO)}
        shell = f"cd {shlex.quote(str(REPO))} && {command}; echo $? > {shlex.quote(str(self.rc_file))}; sleep 600"
        subprocess.run([TMUX, "-S", self.socket, "-f", "/dev/null", "new-session", "-d", "-x", "200", "-y", "50",
                        shell], check=True, env=env)

    def screen(self) -> str:
        out = subprocess.run([TMUX, "-S", self.socket, "capture-pane", "-p", "-J", "-S", "-"], capture_output=True,
                             text=True)
        return out.stdout

    def status(self) -> str:
        """The last status line on the screen ("" before the first)."""
        lines = [ln for ln in self.screen().splitlines() if " | tool " in ln]
        return lines[-1] if lines else ""

    def keys(self, *keys: str) -> None:
        subprocess.run([TMUX, "-S", self.socket, "send-keys", *keys], check=True)

    def wait_for(self, text: str, timeout: float) -> str:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            screen = self.screen()
            if text in screen:
                return screen
            if self.rc_file.exists():
                break
            time.sleep(0.1)
        raise AssertionError(f"{text!r} never showed; the screen:\n{self.screen()}")

    def exit_code(self, timeout: float = 60.0) -> int:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.rc_file.exists() and self.rc_file.read_text().strip():
                return int(self.rc_file.read_text())
            time.sleep(0.1)
        raise AssertionError(f"the session never ended; the screen:\n{self.screen()}")

    def close(self) -> None:
        subprocess.run([TMUX, "-S", self.socket, "kill-server"], capture_output=True)


@pytest.fixture
def terminal(tmp_path):
    made = []

    def start(*args: str) -> Terminal:
        cmd = " ".join(shlex.quote(a) for a in [sys.executable, "-m", "teleop", "run", *SCENE, "--operator",
                                                "keyboard", "--json", str(tmp_path / "summary.json"), *args])
        made.append(Terminal(tmp_path, cmd))
        return made[-1]

    yield start
    for t in made:
        t.close()


def test_held_keys_stay_in_the_workspace_and_x_exits_0(terminal, tmp_path):
    term = terminal()
    term.wait_for(" | tool ", START_TIMEOUT_S)  # the live status line
    end = time.monotonic() + 30.0
    while "| wall" not in term.status():  # until the status line says a wall is braking the tool
        term.keys("s")  # held: the terminal's auto-repeat, as tmux types it
        time.sleep(0.05)
        assert time.monotonic() < end, f"the tool never reached the face; the screen:\n{term.screen()}"
    for _ in range(20):  # held on against the face for a second more
        term.keys("S")
        time.sleep(0.05)
    term.keys("x")
    assert term.exit_code() == 0
    screen = term.screen()
    assert "status     ok" in screen and "Traceback" not in screen
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["status"] == "ok" and s["stopped_by_operator"] is True
    op = s["operator"]
    # pushed into the face, and held there: at it (the status line said "wall") but not through it
    assert -5e-4 < op["workspace_margin_min_m"] < 1e-3 and op["braked_ticks"] > 0
    assert op["speed_max_m_s"] <= op["speed_limit_m_s"] * 1.03
    assert s["steps"] * s["dt_s"] > 1.0  # it ran past a second of typing, not to a scene's duration


def test_ctrl_c_leaves_a_summary_that_says_interrupted(terminal, tmp_path):
    term = terminal()
    term.wait_for(" | tool ", START_TIMEOUT_S)
    for _ in range(10):
        term.keys("w")
        time.sleep(0.05)
    term.keys("C-c")
    assert term.exit_code() == 130
    screen = term.screen()
    assert "status     interrupted" in screen and "Traceback" not in screen
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["status"] == "interrupted" and s["interrupted"] is True and s["steps"] > 0
