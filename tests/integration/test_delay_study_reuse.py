"""tools/delay_study.py --reuse: a study split over processes merges by one last call that runs
nothing; the rows it reads are the rows the parts wrote, in the points' order."""

import csv
import importlib.util
from pathlib import Path

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
    args = ["--scenes", "stiff_contact", "--delays", "0", "--losses", "0", "--seconds", "0.2", "--workers", "1"]
    assert study.main([*args, "--out", str(tmp_path / "off"), "--guards", "off"]) == 0
    assert study.main([*args, "--out", str(tmp_path / "tdpa"), "--guards", "tdpa"]) == 0
    ran = []

    def no_runs(fn, points, *a, **k):
        ran.extend(points)
        return []

    monkeypatch.setattr(study, "run_sweep", no_runs)
    assert study.main([*args, "--out", str(tmp_path / "all"), "--reuse", str(tmp_path / "off" / "delay.csv"),
                       str(tmp_path / "tdpa" / "delay.csv")]) == 0
    assert ran == []  # every point was read, none run
    merged = _rows(tmp_path / "all" / "delay.csv")
    parts = _rows(tmp_path / "off" / "delay.csv") + _rows(tmp_path / "tdpa" / "delay.csv")
    assert [r["guard"] for r in merged] == ["off", "tdpa"]
    for m, p in zip(merged, parts):
        assert {k: v for k, v in m.items() if k != "stable"} == {k: v for k, v in p.items() if k != "stable"}
    assert (tmp_path / "all" / "delay.md").read_text().count("stiff_contact") == 2
