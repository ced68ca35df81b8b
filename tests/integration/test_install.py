"""A built wheel, installed non-editable, lists and runs the shipped scenes from outside the repository.

The wheel is built from a copy of the working tree (so no stale ``build/`` leaks in), installed with
``pip install --no-deps --target`` into a temporary folder, and run with only that folder on
``PYTHONPATH`` and the working directory outside the repository: the interpreter imports the
installed copy, whose scenes and robots must come from the wheel's own package data.
"""

import json
import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from teleop.util import resources

ROOT = Path(__file__).resolve().parents[2]  # the repository under test, not teleop's data
SKIP = shutil.ignore_patterns(".git", ".venv", "build", "*.egg-info", "__pycache__", ".hypothesis",
                              ".pytest_cache", "runs", "out", "docs")


def test_resources_find_the_shipped_data():
    assert [p.name for p in resources.scenario_files()] == sorted(p.name for p in (ROOT / "scenarios").glob("*.toml"))
    assert resources.robot_file("cobot/cobot.urdf").read_bytes() == (ROOT / "robots/cobot/cobot.urdf").read_bytes()
    assert resources.robot_file("scalpel/scalpel.urdf").is_file()
    with pytest.raises(FileNotFoundError, match="no_such_robot"):
        resources.robot_file("no_such_robot/x.urdf")


def test_python_dash_m_teleop_and_version():
    r = subprocess.run([sys.executable, "-m", "teleop", "--version"], cwd=ROOT, capture_output=True, text=True,
                       check=True)
    assert r.stdout.startswith("teleop ")
    r = subprocess.run([sys.executable, "-m", "teleop", "list"], cwd=ROOT, capture_output=True, text=True, check=True)
    assert "straight_incision" in r.stdout


def _pip(*args, cwd):
    r = subprocess.run([sys.executable, "-m", "pip", *args], cwd=cwd, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]


@pytest.mark.long
def test_wheel_lists_and_runs_every_shipped_scene(tmp_path):
    src, wheels, target, work = (tmp_path / d for d in ("src", "wheels", "site", "work"))
    shutil.copytree(ROOT, src, symlinks=True, ignore=SKIP)
    work.mkdir()
    _pip("wheel", "--no-deps", "-q", "-w", str(wheels), str(src), cwd=work)
    (whl,) = wheels.glob("*.whl")
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert whl.name.startswith(project["name"].replace("-", "_") + "-")
    _pip("install", "--no-deps", "-q", "--target", str(target), str(whl), cwd=work)

    env = {**os.environ, "PYTHONPATH": str(target)}

    def teleop(*args):
        r = subprocess.run([sys.executable, "-m", "teleop", *args], cwd=work, env=env,
                           capture_output=True, text=True)
        assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
        return r.stdout

    where = subprocess.run(
        [sys.executable, "-c", "import teleop, teleop.util.resources as r; print(teleop.__file__); "
         "print(r.scenario_dir()); print(r.robot_file('cobot/cobot.urdf'))"],
        cwd=work, env=env, capture_output=True, text=True, check=True).stdout.split()
    assert all(Path(p).is_relative_to(target) for p in where), where

    assert teleop("--version").strip() == f"teleop {project['version']}"
    shipped = sorted(p.stem for p in (ROOT / "scenarios").glob("*.toml"))
    assert len(shipped) >= 8
    assert [line.split()[0] for line in teleop("list").splitlines() if line.strip()] == shipped

    teleop("run", "straight_incision", "--headless", "--duration", "0.2", "--json", "out.json")
    s = json.loads((work / "out.json").read_text())
    assert s["scenario"] == "straight_incision" and s["status"] == "ok" and s["nan"] is False
