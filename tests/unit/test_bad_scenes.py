"""The malformed scene files kept in tests/data/bad_scenes: each names its file, key and reason.

Every file's first line says what it must produce: ``# expect: KEY | REASON FRAGMENT``. Loading
must fail before anything runs (no partial run): ``load_scene`` raises, ``teleop run`` exits 2.
"""

from pathlib import Path

import pytest

from teleop.app.cli import main
from teleop.scenario.schema import load_scene
from teleop.util.errors import SceneError

FILES = sorted((Path(__file__).parents[1] / "data" / "bad_scenes").glob("*.toml"))


def _expect(path: Path):
    head = path.read_bytes().split(b"\n")[0].decode("utf-8")  # a file's later lines may be bad on purpose
    assert head.startswith("# expect: "), f"{path.name} lacks its expectation line"
    key, reason = head[len("# expect: "):].split(" | ")
    return key.strip(), reason.strip()


def test_there_are_at_least_twenty():
    assert len(FILES) >= 20


@pytest.mark.parametrize("path", FILES, ids=[p.stem for p in FILES])
def test_each_bad_scene_gives_its_error(path):
    key, reason = _expect(path)
    with pytest.raises(SceneError) as e:
        load_scene(str(path))
    assert e.value.key == key, str(e.value)
    assert reason in e.value.reason, str(e.value)
    assert str(path) in str(e.value)


@pytest.mark.parametrize("path", FILES[:5], ids=[p.stem for p in FILES[:5]])
def test_cli_refuses_without_running(path, tmp_path, capsys):
    out = tmp_path / "never.json"
    assert main(["run", str(path), "--json", str(out)]) == 2
    assert not out.exists()
    assert _expect(path)[0] in capsys.readouterr().err
