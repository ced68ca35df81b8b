"""A run folder keeps the scene it ran, so `teleop replay` draws a run of any scene file (even one
since deleted) with everything the live view drew."""

import numpy as np

from teleop.app.cli import main
from teleop.app.view_bridge import FRAMES_FILE, load_run_scene, save_scene_copy
from teleop.scenario.schema import load_scene
from teleop.util.resources import scenario_dir


def test_the_scene_copy_loads_back_equal(tmp_path):
    scene = load_scene("laparoscopic_incision").with_overrides(["slave.solver='daqp'"], duration_s=0.7, seed=9)
    save_scene_copy(scene, tmp_path)
    back = load_run_scene(tmp_path)
    for key in ("name", "duration_s", "seed", "fixture", "slave", "mapping", "tool", "operator", "effects"):
        assert getattr(back, key) == getattr(scene, key), key


def test_a_run_of_a_scene_file_of_ones_own_replays_with_the_slave_and_device(tmp_path, capsys):
    mine = tmp_path / "my_cut.toml"
    text = (scenario_dir() / "straight_incision.toml").read_text()
    mine.write_text(text.replace('name = "straight_incision"', 'name = "my_cut"'))
    run = tmp_path / "run"
    rc = main(["run", str(mine), "--master", "cobot", "--duration", "0.3", "--out", str(run)])
    assert rc in (0, 1)  # 1: a slave status other than ok (this cut on the cobot falls back on some ticks)
    assert (run / "log.npz").is_file() and (run / "scene.toml").is_file()
    mine.unlink()  # replay finds the scene in the run folder, not by name or path
    frames = np.load(run / FRAMES_FILE)
    for key in ("slave_tool_pose", "contact_wrench", "master_q", "cut_tip", "reference_pose"):
        assert key in frames.files and np.isfinite(frames[key]).all(axis=1).any(), key
    assert np.abs(frames["contact_wrench"][:, :3]).max() > 0.0  # the arrow has something to show
    assert main(["replay", str(run), "--out", str(tmp_path / "again.html")]) == 0
    assert (tmp_path / "again.html").stat().st_size > 100_000
    out = capsys.readouterr().out
    assert "replayed" in out and "of my_cut" in out


def test_hold_keeps_the_page_served_until_ctrl_c():
    import os
    import signal
    import subprocess
    import sys
    import time
    import urllib.request

    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.Popen([sys.executable, "-m", "teleop", "run", "paper_rolling_disk", "--duration", "0.2",
                             "--viewer", "--hold"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    said: list[str] = []  # stderr up to the hold, for the messages below
    try:
        url, deadline = None, time.monotonic() + 120
        while url is None and time.monotonic() < deadline:
            line = proc.stderr.readline()
            said.append(line)
            if "holds the last frame" in line:
                url = line.split()[1]
            assert line or proc.poll() is None, f"teleop ended before holding the page: {''.join(said)[-2000:]}"
        assert url is not None, "".join(said)[-2000:]
        time.sleep(1.0)
        assert proc.poll() is None, "".join(said)[-2000:]  # the run is over, the page is still served
        assert urllib.request.urlopen(url, timeout=10).status == 200
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode in (0, 1) and "Traceback" not in err, (proc.returncode, err[-3000:])
    assert "status" in out, out[-2000:]  # the summary after Ctrl-C
