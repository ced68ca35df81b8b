"""The README's quick-start tour, run as written (issue 25): the commands of the ```sh block under
"## Quick start", each typed into a shell whose PATH has this environment's ``teleop`` (as
``source .venv/bin/activate`` gives), in a fresh folder, one after the other (``teleop replay
runs/cut`` replays the run the line before wrote). A person's commands are left out: a viewer
(it waits for a browser), the keyboard (it waits for keys), a Zenoh pair (two processes on a
network); a run of a scene's whole duration gets ``--duration`` so that the tour stays quick."""

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[2] / "README.md"
#: flags of commands a test cannot type for a person
INTERACTIVE = ("--viewer", "--operator keyboard", "--link zenoh")
#: simulated seconds given to a run that names no duration of its own
SHORT_S = "0.3"


def tour() -> list[str]:
    """The command lines of the first ```sh block under "## Quick start", comments stripped."""
    text = README.read_text(encoding="utf-8")
    section = text.split("\n## Quick start", 1)[1].split("\n## ", 1)[0]
    block = re.search(r"```sh\n(.*?)```", section, re.S)
    assert block, "README: no ```sh block under ## Quick start"
    lines = [line.split(" #", 1)[0].strip() for line in block.group(1).splitlines()]
    return [line for line in lines if line]


def as_run(line: str) -> str | None:
    """The line as this test types it: None for a person's command; ``--duration`` added to a run
    that has none (and not to one that has)."""
    if any(flag in line for flag in INTERACTIVE):
        return None
    words = shlex.split(line)
    if words[:2] == ["teleop", "run"] and "--duration" not in words:
        return f"{line} --duration {SHORT_S}"
    return line


def test_the_tour_is_the_one_this_test_knows():
    lines = tour()
    assert all(line.startswith("teleop ") for line in lines)
    ran = [as_run(line) for line in lines]
    assert sum(r is not None for r in ran) >= 7, ran  # most of the tour runs here, not a vacuous test
    commands = {shlex.split(line)[1] for line in lines}
    assert {"list", "run", "replay", "plot"} <= commands
    assert "teleop run paper_rolling_disk --duration 5 --json out.json" in ran  # its own duration, as written


def test_the_readme_tour_runs_as_written(tmp_path):
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    done = []
    for line in tour():
        cmd = as_run(line)
        if cmd is None:
            continue
        r = subprocess.run(cmd, shell=True, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, f"{cmd!r} exited {r.returncode}:\n{r.stdout[-2000:]}\n{r.stderr[-2000:]}"
        assert "Traceback" not in r.stderr, f"{cmd!r}:\n{r.stderr[-2000:]}"
        done.append((cmd, r.stdout))
    out = dict(done)
    assert "straight_incision" in out["teleop list"]
    cut = tmp_path / "runs" / "cut"
    assert {"metrics.json", "log.npz", "recording.html"} <= {p.name for p in cut.iterdir()}
    assert (cut / "replay.html").stat().st_size > 100_000  # teleop replay runs/cut
    assert (tmp_path / "out.json").is_file()  # --json out.json
    assert any("status     ok" in text for cmd, text in done if "link.round_trip_ms=200" in cmd)


@pytest.mark.parametrize("line, typed", [
    ("teleop run straight_incision --viewer --realtime", None),
    ("teleop run scalpel_fixture --viewer --operator keyboard", None),
    ("teleop run straight_incision --link zenoh", None),
    ("teleop run", f"teleop run --duration {SHORT_S}"),
    ("teleop run paper_rolling_disk --duration 5 --json out.json",
     "teleop run paper_rolling_disk --duration 5 --json out.json"),
    ("teleop replay runs/cut", "teleop replay runs/cut"),
])
def test_what_the_tour_test_types(line, typed):
    assert as_run(line) == typed
