"""Hostile input to the `teleop` command (issue 14): every case is one line on stderr naming the
file, key or argument, exit code 2, no traceback, nothing written; outputs whole or not at all."""

import fcntl
import json
import os
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from teleop.app.cli import main
from teleop.util import inputs

SCENES = Path(__file__).parents[2] / "scenarios"


def _scene(tmp_path, name: str, edit) -> str:
    text = (SCENES / f"{name}.toml").read_text()
    p = tmp_path / f"{name}_edited.toml"
    p.write_text(edit(text))
    return str(p)


def _refused(capsys, argv, *words, tmp_path=None):
    """main(argv) exits 2 with one line naming each of ``words``; no --json/--out is written."""
    rc = main(argv)
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    assert "\x1b" not in err
    for w in words:
        assert w in err, err
    if tmp_path is not None:
        assert not (tmp_path / "out.json").exists() and not (tmp_path / "run").exists()
    return err


def _run_args(tmp_path, scene, *more):
    return ["run", scene, "--json", str(tmp_path / "out.json"), "--out", str(tmp_path / "run"), *more]


@pytest.mark.parametrize("args, words", [
    (["--duration", "inf"], ["--duration", "finite"]),
    (["--duration", "nan"], ["--duration", "finite"]),
    (["--seed", "-1"], ["--seed", "non-negative"]),
    (["--dt", "inf"], ["--dt", "finite"]),
    (["--dt", "1e-300"], ["--dt", "at least 1e-05 s"]),
    (["--duration", "1e-300"], ["--duration", "zero ticks"]),
    (["--duration", "1e12"], ["--duration", "at most 2000000 ticks"]),
    (["--duration", "86400"], ["--duration", "at most 2000000 ticks"]),
    (["--set", "cobot.interface=socketcan"], ["cobot.interface", "--allow-hardware"]),
    (["--set", "tissue.origin_m=\"abc\""], ["tissue.origin_m", "expected a list"]),
])
def test_bad_arguments_are_one_line_and_nothing_is_written(tmp_path, capsys, args, words):
    _refused(capsys, _run_args(tmp_path, "straight_incision", *args), *words, tmp_path=tmp_path)


def test_a_sphere_fixture_without_q0_is_a_scene_error_not_a_linalg_traceback(tmp_path, capsys):
    path = _scene(tmp_path, "paper_disk_on_sphere", lambda t: "\n".join(
        ln for ln in t.splitlines() if not ln.startswith("q0")))
    _refused(capsys, _run_args(tmp_path, path), "tool.q0", "singular", tmp_path=tmp_path)


def test_a_urdf_that_is_not_one_is_named(tmp_path, capsys):
    bad = tmp_path / "x.urdf"
    bad.write_text("<robot name='broken'><link")
    _refused(capsys, _run_args(tmp_path, "straight_incision", "--set", f'slave.arm={{urdf="{bad}", flange="x"}}'),
             "slave.arm.urdf", "not a valid URDF", tmp_path=tmp_path)


@pytest.mark.parametrize("kind", ["directory", "dev_zero", "not_utf8", "deep"])
def test_scene_files_that_are_not_scenes(tmp_path, capsys, kind):
    if kind == "directory":
        p = tmp_path / "d.toml"
        p.mkdir()
    elif kind == "dev_zero":
        p = Path("/dev/zero")
    elif kind == "not_utf8":
        p = tmp_path / "x.toml"
        p.write_bytes(b"duration_s = 1.0\nname = \"\xff\"\n")
    else:
        p = tmp_path / "deep.toml"
        p.write_text("x = " + "[" * 100_000 + "]" * 100_000)
    _refused(capsys, _run_args(tmp_path, str(p)), str(p), tmp_path=tmp_path)


def test_a_fifo_is_refused_without_hanging(tmp_path):
    fifo = tmp_path / "scene.toml"
    os.mkfifo(fifo)
    r = subprocess.run([sys.executable, "-m", "teleop", "run", str(fifo)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "Traceback" not in r.stderr and str(fifo) in r.stderr


def test_read_bytes_refuses_a_fifo_and_a_file_past_its_limit(tmp_path):
    fifo = tmp_path / "f"
    os.mkfifo(fifo)
    with pytest.raises(inputs.ConfigError, match="FIFO"):
        inputs.read_bytes(fifo)
    big = tmp_path / "big"
    big.write_bytes(b"x" * 101)
    with pytest.raises(inputs.ConfigError, match="limit of 100"):
        inputs.read_bytes(big, limit=100)


def test_an_unreadable_file_is_named(tmp_path, monkeypatch):
    p = tmp_path / "s.toml"
    p.write_text("duration_s = 1.0\n")

    def denied(*a, **k):
        raise PermissionError(13, "Permission denied", str(p))

    monkeypatch.setattr(inputs.os, "open", denied)
    with pytest.raises(inputs.ConfigError, match="permission denied"):
        inputs.read_text(p)


def test_a_scene_name_cannot_leave_the_scenarios_folder(capsys):
    _refused(capsys, ["run", "../scenarios/straight_incision"], "scene name")


def test_escapes_in_an_unknown_key_never_reach_the_terminal(tmp_path, capsys):
    p = tmp_path / "k.toml"
    p.write_text((SCENES / "paper_rolling_disk.toml").read_text() + '\n[viewer]\n"a\\u001b[2Jb" = 1\n')
    _refused(capsys, ["run", str(p)], "viewer.a\\x1b[2Jb")


# -------------------------------------------------------------------------------------- outputs

def test_bad_json_and_out_targets_are_found_before_the_run(tmp_path, capsys):
    _refused(capsys, ["run", "paper_rolling_disk", "--json", str(tmp_path)], "--json", "folder")
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep me")
    _refused(capsys, ["run", "paper_rolling_disk", "--out", str(tmp_path / "mine")], "--out", "other files")
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep me"
    _refused(capsys, ["run", "paper_rolling_disk", "--json", "/proc/no/such/x.json"], "--json")


def test_a_second_run_on_one_folder_refuses(tmp_path, capsys):
    out = tmp_path / "run"
    with open(tmp_path / ".run.lock", "a") as lock:  # what a first run holds while it runs
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        _refused(capsys, ["run", "paper_rolling_disk", "--duration", "0.1", "--out", str(out)],
                 "--out", "another run")
    assert not out.exists()


def test_a_run_folder_appears_whole_and_replaces_an_earlier_run(tmp_path, capsys):
    out = tmp_path / "run"
    for _ in range(2):
        assert main(["run", "paper_rolling_disk", "--duration", "0.1", "--out", str(out), "-q"]) == 0
    assert json.loads((out / "metrics.json").read_text())["status"] == "ok"
    assert {"log.npz", "metrics.json"} <= {p.name for p in out.iterdir()}
    assert [p.name for p in tmp_path.iterdir()] == ["run"]  # no lock, no temporary folder left


def test_ctrl_c_leaves_a_summary_marked_interrupted(tmp_path):
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "teleop", "run", "paper_rolling_disk", "--duration", "1000",
                             "--out", str(out), "-v"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    for line in proc.stderr:  # wait for the session's first tick
        if "running" in line:
            break
    time.sleep(1.0)
    proc.send_signal(signal.SIGINT)
    _stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr
    s = json.loads((out / "metrics.json").read_text())
    assert s["status"] == "interrupted" and s["interrupted"] is True and 0 < s["steps"] < 1_000_000
    with np.load(out / "log.npz") as z:
        assert z["t"].shape == (s["steps"],)


# ------------------------------------------------------------------------------------ run logs

def _log(tmp_path, **arrays) -> Path:
    n = 5
    base = {"t": np.arange(1, n + 1) * 1e-3, "p_r": np.zeros((n, 3)), "R_r": np.zeros((n, 3, 3)),
            "q_v_p": np.zeros((n, 3)), "R_v": np.zeros((n, 3, 3)), "operator_W": np.zeros((n, 6)),
            "constraint_W": np.zeros((n, 6)), "tick_us": np.ones(n)}
    base.update(arrays)
    base = {k: v for k, v in base.items() if v is not None}
    p = tmp_path / "log.npz"
    np.savez(p, **base, summary=json.dumps({"scenario": "paper_rolling_disk"}))
    return p


@pytest.mark.parametrize("change, words", [
    ({"t": None}, ["'t' is missing"]),
    ({"p_r": np.zeros((5, 4))}, ["p_r", "shape"]),
    ({"tick_us": np.zeros(4)}, ["tick_us", "shape"]),
    ({"q_r": np.array(["a"] * 5)}, ["q_r", "dtype"]),
    ({"t": np.array([0.0, 1.0, 0.5, 2.0, 3.0])}, ["t:", "increasing"]),
    ({"evil": np.zeros(4)}, ["evil", "shape"]),
])
@pytest.mark.parametrize("command", ["plot", "replay"])
def test_crafted_logs_are_refused(tmp_path, capsys, change, words, command):
    p = _log(tmp_path, **change)
    _refused(capsys, [command, str(p)], str(p), *words)


def test_a_log_with_a_foreign_member_is_refused(tmp_path, capsys):
    p = _log(tmp_path)
    with zipfile.ZipFile(p, "a") as z:
        z.writestr("../evil.pkl", b"x")
    _refused(capsys, ["plot", str(p)], str(p), "unexpected member")


def test_a_log_with_a_pickle_is_refused_without_running_it(tmp_path, capsys):
    p = _log(tmp_path, q_r=np.array([object()] * 5, dtype=object))
    _refused(capsys, ["plot", str(p)], str(p))


@pytest.mark.parametrize("content", [b"not a zip", b"PK\x03\x04garbage"])
def test_a_log_that_is_no_archive_is_refused(tmp_path, capsys, content):
    p = tmp_path / "log.npz"
    p.write_bytes(content)
    _refused(capsys, ["replay", str(p)], str(p), "not")


def test_a_zip_bomb_is_refused_before_it_is_inflated(tmp_path, capsys, monkeypatch):
    p = tmp_path / "log.npz"
    with zipfile.ZipFile(p, "w", compression=zipfile.ZIP_DEFLATED) as z:
        z.writestr("t.npy", b"\0" * 20_000_000)  # 20 MB of zeros, about 20 kB on disk
    assert p.stat().st_size < 100_000
    monkeypatch.setattr(inputs, "MAX_LOG_INFLATED_BYTES", 10_000_000)
    monkeypatch.setattr(np, "load", lambda *a, **k: pytest.fail("np.load reached"))
    _refused(capsys, ["plot", str(p)], str(p), "inflates to 20000000 bytes")


def test_a_log_cannot_point_replay_at_a_file(tmp_path, capsys):
    p = _log(tmp_path)
    with np.load(p) as z:
        arrays = {k: z[k] for k in z.files if k != "summary"}
    np.savez(p, **arrays, summary=json.dumps({"scenario": "/etc/passwd.toml"}))
    _refused(capsys, ["replay", str(p)], "summary.scenario", "not a scene name")
