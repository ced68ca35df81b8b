"""tools/delay_study.py --reuse: a study split over processes merges by one last call that runs
nothing; the rows it reads are the rows the parts wrote, in the points' order. A delay.csv of an
older study (without the wall and burst columns) is refused in one line, not misread."""

import csv
import importlib.util
from pathlib import Path

import pytest

TOOLS = Path(__file__).resolve().parents[2] / "tools"


def _study():
    spec = importlib.util.spec_from_file_location("teleop_tools_delay_study", TOOLS / "delay_study.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _rows(path):
    return list(csv.DictReader(open(path)))


def test_reused_rows_are_not_run_and_merge_into_one_table(tmp_path, monkeypatch):
    study = _study()
    args = ["--scenes", "stiff_contact", "--walls", "1e4", "--delays", "0", "--losses", "0", "--seconds", "0.2",
            "--workers", "1"]
    assert study.main([*args, "--out", str(tmp_path / "off"), "--guards", "off"]) == 0
    assert study.main([*args, "--out", str(tmp_path / "tdpa"), "--guards", "tdpa"]) == 0
    ran = []

    def no_runs(fn, points, *a, **k):
        ran.extend(points)
        return []

    monkeypatch.setattr(study, "run_sweep", no_runs)
    assert study.main([*args, "--out", str(tmp_path / "all"), "--guards", "off", "tdpa", "--reuse",
                       str(tmp_path / "off" / "delay.csv"), str(tmp_path / "tdpa" / "delay.csv")]) == 0
    assert ran == []  # every point was read, none run
    merged = _rows(tmp_path / "all" / "delay.csv")
    parts = _rows(tmp_path / "off" / "delay.csv") + _rows(tmp_path / "tdpa" / "delay.csv")
    assert [r["guard"] for r in merged] == ["off", "tdpa"]
    for m, p in zip(merged, parts):
        assert {k: v for k, v in m.items() if k != "stable"} == {k: v for k, v in p.items() if k != "stable"}
    assert (tmp_path / "all" / "delay.md").read_text().count("stiff_contact") == 2


def test_a_table_without_the_new_axes_is_refused(tmp_path, capsys):
    study = _study()
    old = tmp_path / "old.csv"
    old.write_text("scene,delay_ms,loss,guard,status,nan,osc_mm\nstiff_contact,0,0,off,ok,False,0.1\n")
    with pytest.raises(SystemExit) as e:
        study.main(["--scenes", "stiff_contact", "--reuse", str(old), "--out", str(tmp_path / "x")])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "--reuse" in err and "burst_enter" in err and "wall_N_m" in err and "older study" in err
    assert not (tmp_path / "x").exists()  # refused before anything is written
