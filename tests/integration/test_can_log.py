"""`teleop run --can-log PATH`: the capture (candump .log or .asc by suffix), read back by the
cantools CLI with the project's DBC (every frame decodes) and by python-can's readers (transmit and
receive marked from the host's side)."""

import re
import subprocess
import sys

import can

from teleop.app.cli import main
from teleop.master.cobot.database import DEFAULT_DBC, FrameDatabase

HOST_IDS = {m.frame_id for m in FrameDatabase().db.messages if m.senders == ["HOST"]}


def test_can_log_decodes_every_frame_with_the_cantools_cli(tmp_path):
    path = tmp_path / "cap.log"
    assert main(["run", "straight_incision", "--master", "cobot", "--duration", "0.05", "--can-log", str(path)]) == 0
    lines = path.read_text().splitlines()
    assert len(lines) > 150 and all("##" in ln for ln in lines)  # CAN FD frames in candump -L format
    out = subprocess.run([sys.executable, "-m", "cantools", "decode", str(DEFAULT_DBC)], input="\n".join(lines) + "\n",
                         capture_output=True, text=True, timeout=60, check=True).stdout
    decoded = re.findall(r"^\(\S+\) vcan0 (\w+)##\w+ [TR] ::\n(\w+)\(", out, flags=re.M)
    assert len(decoded) == len(lines) and "Unknown" not in out  # every frame, by name
    assert {name for _, name in decoded} >= {"SYNC", "HOST_CMD", "DEV_JOINTS", "DEV_WRENCH", "HOST_HEARTBEAT"}
    for ln in lines:  # candump's direction flag: T for the host's own frames, R for the device's
        fid = int(ln.split()[2].split("#")[0], 16)
        assert ln.endswith(" T" if fid in HOST_IDS else " R"), ln


def test_can_log_asc_marks_tx_and_rx(tmp_path):
    path = tmp_path / "cap.asc"
    assert main(["run", "straight_incision", "--master", "cobot", "--duration", "0.02", "--can-log", str(path)]) == 0
    frames = list(can.ASCReader(str(path)))
    assert len(frames) > 50 and all(f.is_fd for f in frames)
    assert {f.is_rx for f in frames if f.arbitration_id in HOST_IDS} == {False}
    assert {f.is_rx for f in frames if f.arbitration_id not in HOST_IDS} == {True}


def test_can_log_needs_the_cobot(tmp_path, capsys):
    assert main(["run", "straight_incision", "--master", "ideal", "--can-log", str(tmp_path / "x.log")]) == 2
    assert "--can-log" in capsys.readouterr().err
    assert not (tmp_path / "x.log").exists()
