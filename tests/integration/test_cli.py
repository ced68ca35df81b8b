"""The `teleop` command as a user types it: run, list, errors."""

import json
import subprocess
import sys

import pytest

from teleop.app.cli import main
from teleop.scenario.schema import list_scenes

KEYS = {"scenario", "status", "steps", "dt_s", "duration_s", "nan", "tick_us", "metrics"}


@pytest.mark.parametrize("name", ["paper_rolling_disk", "paper_disk_on_sphere", "scalpel_fixture"])
def test_run_writes_the_json_summary(tmp_path, name):
    out = tmp_path / "out.json"
    rc = main(["run", name, "--master", "ideal", "--headless", "--json", str(out), "--duration", "0.2"])
    assert rc == 0
    s = json.loads(out.read_text())
    assert KEYS <= set(s)
    assert s["scenario"] == name and s["status"] == "ok" and s["nan"] is False
    assert s["steps"] == 200 and s["dt_s"] == 0.001
    assert s["tick_us"]["median"] > 0 and s["tick_us"]["p99"] >= s["tick_us"]["median"]


def test_console_entry_point_and_list():
    r = subprocess.run([sys.executable, "-m", "teleop.app.cli", "list"], capture_output=True, text=True, check=True)
    for name in list_scenes():
        assert name in r.stdout


def test_unknown_scene_is_a_clear_error(capsys):
    assert main(["run", "no_such_scene", "--duration", "0.1"]) == 2
    err = capsys.readouterr().err
    assert "no_such_scene" in err and "known scenes" in err


def test_run_out_dir_writes_log_and_plots(tmp_path):
    rc = main(["run", "paper_disk_on_sphere", "--duration", "0.3", "--out", str(tmp_path)])
    assert rc == 0
    assert (tmp_path / "metrics.json").exists() and (tmp_path / "log.npz").exists()
    html = (tmp_path / "recording.html").read_text()
    assert "meshcat" in html.lower() and len(html) > 100_000  # self-contained: the viewer inlined
    pngs = sorted(p.name for p in tmp_path.glob("*.png"))
    assert pngs and all((tmp_path / p).stat().st_size > 5000 for p in pngs)


def test_plot_command_redraws_a_log(tmp_path):
    assert main(["run", "paper_rolling_disk", "--duration", "0.2", "--out", str(tmp_path / "run")]) == 0
    assert main(["plot", str(tmp_path / "run"), "--out", str(tmp_path / "figs")]) == 0
    assert (tmp_path / "figs" / "figure8.png").stat().st_size > 5000


def test_plot_without_a_log_is_a_clear_error(tmp_path, capsys):
    assert main(["plot", str(tmp_path)]) == 2
    assert "no run log" in capsys.readouterr().err


def test_replay_writes_a_new_recording_and_keeps_the_runs_own(tmp_path, capsys):
    import hashlib

    assert main(["run", "straight_incision", "--duration", "0.3", "--out", str(tmp_path / "run")]) == 0
    own = tmp_path / "run" / "recording.html"
    before = hashlib.sha256(own.read_bytes()).hexdigest()
    assert main(["replay", str(tmp_path / "run")]) == 0
    assert hashlib.sha256(own.read_bytes()).hexdigest() == before  # the run's own file untouched
    assert (tmp_path / "run" / "replay.html").stat().st_size > 100_000
    assert "replayed" in capsys.readouterr().out
    assert main(["replay", str(tmp_path / "run"), "--out", str(own)]) == 2  # not over the run's files
    assert "--force" in capsys.readouterr().err
    log = tmp_path / "run" / "log.npz"
    assert main(["replay", str(tmp_path / "run"), "--out", str(log), "--force"]) == 2  # data: never
    assert log.stat().st_size > 1000
    assert hashlib.sha256(own.read_bytes()).hexdigest() == before


def test_an_incision_run_plots_the_slave_and_its_contact_force(tmp_path):
    """Issue #4: the contact force against time, with the slave's tracking, depth and direction."""
    import numpy as np

    assert main(["run", "straight_incision", "--duration", "1.5", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "incision.png").stat().st_size > 5000
    log = np.load(tmp_path / "log.npz")
    assert log["slave_contact_N"].max() > 0 and len(log["slave_contact_N"]) == 1500
