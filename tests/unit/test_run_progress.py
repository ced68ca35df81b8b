"""What a run says while it runs (teleop.app.progress): the compile notice, the tqdm bar."""

import io
import logging

from teleop.app import progress
from teleop.app.cli import main


class _Tty(io.StringIO):
    def isatty(self):
        return True


def test_the_bar_shows_eta_and_real_time_factor_on_a_terminal(monkeypatch):
    monkeypatch.setattr(progress, "BAR_DELAY_S", 0.0)
    out = _Tty()
    bar = progress.RunBar(10.0, 1e-3, stream=out)
    for i in range(0, 10_000, 1000):
        bar(i, 10_000)
    bar.bar.refresh()
    text = out.getvalue()
    bar.close()
    assert "s simulated" in text and "x real time" in text and "<" in text  # elapsed<remaining


def test_no_bar_in_a_pipe_or_when_quiet():
    assert progress.RunBar(10.0, 1e-3, stream=io.StringIO()).bar is None
    assert progress.RunBar(10.0, 1e-3, enabled=False, stream=_Tty()).bar is None


def test_a_cold_cache_says_so_once_in_one_line_on_a_terminal_and_not_in_a_pipe(monkeypatch, caplog):
    monkeypatch.setattr(progress, "kernels_cold", lambda: True)
    with caplog.at_level(logging.WARNING, logger="teleop"):
        progress.notice_compile(stream=_Tty())
    assert len([m for m in caplog.messages if "compiling kernels, once" in m]) == 1
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="teleop"):
        progress.notice_compile(stream=io.StringIO())
    assert not caplog.messages  # a pipe: a refused scene stays one line on stderr
    monkeypatch.undo()
    assert progress.kernels_cold() is False  # this session compiled them already: a warm cache


def test_the_summary_says_where_files_went_and_quiet_says_nothing(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", "paper_rolling_disk", "--duration", "0.1", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert f"files      {out}/" in text and "metrics.json" in text
    assert main(["run", "paper_rolling_disk", "--duration", "0.1"]) == 0
    assert "none written" in capsys.readouterr().out
    assert main(["run", "paper_rolling_disk", "--duration", "0.1", "-q", "--json", str(tmp_path / "s.json")]) == 0
    cap = capsys.readouterr()
    assert cap.out == "" and cap.err == ""


def test_json_to_stdout_keeps_stdout_pure_json(capsys):
    import json

    assert main(["run", "paper_rolling_disk", "--duration", "0.1", "--json", "-"]) == 0
    assert json.loads(capsys.readouterr().out)["status"] == "ok"
