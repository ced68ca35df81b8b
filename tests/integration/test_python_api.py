"""The README's Python API block, run as written (a user's own constraint and fixture type in a
teleop run), and a scene that names a user's fixture type: enforced by the reference tool, mapped
to the slave, measured by the fixture's own rows."""

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from teleop.app.runtime import run_scene
from teleop.dynamics.registry import FIXTURE_TYPES, register_fixture
from teleop.scenario.schema import load_scene, parse_scene
from teleop.util.errors import SceneError
from teleop.util.typed import as_table

README = Path(__file__).resolve().parents[2] / "README.md"


def python_api_block() -> str:
    text = README.read_text()
    section = text[text.index("## Python API"):]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_the_readme_block_runs_as_written(tmp_path):
    script = tmp_path / "example.py"
    script.write_text(python_api_block())
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    block = python_api_block()
    assert "class OnCylinder(Constraint)" in block and "Session(" in block and "register_fixture" in block


PLUGIN = """
from dataclasses import dataclass
from teleop.dynamics.constraints import PointDepth
from teleop.dynamics.fixtures import Fixture


@dataclass(frozen=True)
class Groove:
    origin_m: tuple = (0.5, 0.0, 0.2)
    depth_m: float = 0.004
    tip_m: tuple = (0.0, 0.0, 0.0)

    def build(self, frame):
        return Fixture("test_groove", (PointDepth(frame.point(self.origin_m), frame.direction((0, 0, 1)),
                                                  frame.length(self.depth_m), frame.body_point(self.tip_m)),), None)
"""


#: the blade tip at a depth below a plane (the library's PointDepth row); the same source is the
#: installed plug-in below, so the in-process type and the plug-in cannot drift apart
_ns: dict = {}
exec(PLUGIN, _ns)  # a literal of this file, the plug-in's own source
Groove = register_fixture("test_groove")(_ns["Groove"])


def groove_scene(**fixture) -> dict:
    data = load_scene("straight_incision").with_overrides(duration_s=0.5, integrator="rk4")
    table = as_table(data)
    table["fixture"] = {"type": "test_groove", "origin_m": list(data.fixture.plane_origin_m),
                        "depth_m": data.fixture.depth_m, **fixture}
    return table


def test_a_scene_names_a_user_fixture_type_and_both_sides_hold_it():
    scene = parse_scene(groove_scene(), "groove.toml")
    assert scene.fixture.type == "test_groove" and isinstance(scene.fixture.params, Groove)
    r = run_scene(scene)
    s, m = r.summary, r.summary["metrics"]
    assert s["status"] == "ok", s
    assert m["slave_fixture_residual_max"] < 1e-9  # the slave's tool on the groove (m)
    assert m["fixture_residual_max"] < 1e-9        # the master's virtual tool on it (m) ...
    assert m["fixture_holonomic_rate_max"] < 1e-9  # ... and moving along it (m/s)
    assert m["fixture_rate_max"] == 0.0            # a groove has no velocity-level row
    assert r.log["slave_q"].shape[0] == s["steps"]


def test_a_user_fixture_type_round_trips_through_overrides():
    scene = parse_scene(groove_scene(), "groove.toml")
    again = scene.with_overrides(sets=["fixture.depth_m=0.003"])
    assert again.fixture.params == Groove(origin_m=scene.fixture.params.origin_m, depth_m=0.003)


def test_bad_user_fixture_tables_name_file_key_and_reason():
    with pytest.raises(SceneError, match=r"groove.toml: fixture.deph_m: unknown key; did you mean 'depth_m'"):
        parse_scene(groove_scene(deph_m=0.1), "groove.toml")
    bad = groove_scene()
    bad["fixture"]["type"] = "test_grove"
    with pytest.raises(SceneError,
                       match=r"fixture.type: unknown fixture type 'test_grove'; did you mean 'test_groove'"):
        parse_scene(bad, "groove.toml")


def test_the_registry_takes_entry_points_and_names_a_broken_one(monkeypatch):
    from teleop.dynamics import registry

    class EP:
        def __init__(self, name, target):
            self.name, self.value, self._t = name, f"pkg:{name}", target

        def load(self):
            if isinstance(self._t, Exception):
                raise self._t
            return self._t

    reg = registry.FixtureRegistry()
    monkeypatch.setattr(registry, "entry_points", lambda group: [EP("plugin_groove", Groove)])
    assert reg.get("plugin_groove") is Groove and "plugin_groove" in reg.names()
    reg = registry.FixtureRegistry()
    monkeypatch.setattr(registry, "entry_points", lambda group: [EP("broken", ImportError("no module x"))])
    with pytest.raises(Exception, match=r"fixture plug-in 'broken' \(pkg:broken\): ImportError: no module x"):
        reg.names()


def test_the_master_fixture_is_the_patient_fixture_through_the_one_map():
    """A registration with rotation, offset and scale: the master's rows (built through
    Registration.master_frame) vanish exactly where the slave's do, at the mapped pose."""
    from teleop.control.mapping import Registration
    from teleop.dynamics.registry import FrameMap
    from teleop.dynamics.rotations import axis_rotation

    reg = Registration(X_PM_p=np.array([0.4, -0.1, 0.2]), X_PM_R=axis_rotation(2, 0.7) @ axis_rotation(0, 0.3),
                       scale=2.5)
    g = Groove(tip_m=(0.0, 0.0, 0.01))
    slave_row = g.build(FrameMap.identity()).constraints[0]
    master_row = g.build(reg.master_frame()).constraints[0]
    rng = np.random.default_rng(3)
    for _ in range(20):
        p_P, R_P = rng.normal(size=3) * 0.1 + [0.5, 0, 0.2], axis_rotation(1, rng.normal())
        p_M, R_M = reg.pose_to_master(p_P, R_P)
        assert np.allclose(master_row.residual(p_M, R_M), reg.scale * slave_row.residual(p_P, R_P), atol=1e-12)
    assert FIXTURE_TYPES.get("test_groove") is Groove




def _installed_plugin(tmp_path) -> Path:
    """A package that adds the fixture type through the entry-point group teleop.fixtures, as an
    installed distribution would (a dist-info folder on the path)."""
    root = tmp_path / "site"
    (root / "groove_plugin-0.1.dist-info").mkdir(parents=True)
    (root / "groove_plugin.py").write_text(PLUGIN)
    info = root / "groove_plugin-0.1.dist-info"
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: groove-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[teleop.fixtures]\ntest_groove = groove_plugin:Groove\n")
    return root


def test_an_installed_fixture_type_runs_from_the_command_line_and_is_drawn(tmp_path):
    """`teleop run` on a scene naming a fixture type that an installed package adds through the
    entry points: it runs, both sides hold it, and the recording draws it (the generic drawing:
    the tool's frame triad and trace on the master side)."""
    import os

    from teleop.app.view_bridge import viz_scene_for

    scene = parse_scene(groove_scene(), "groove.toml")
    vs = viz_scene_for(scene)
    assert vs.fixture_type == "test_groove" and isinstance(vs.fixture_object, Groove)
    env = dict(os.environ,
               PYTHONPATH=os.pathsep.join([str(_installed_plugin(tmp_path)), os.environ.get("PYTHONPATH", "")]))
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "teleop", "run", str(_write(tmp_path, scene)), "--duration", "0.3",
                        "--out", str(out), "--json", str(tmp_path / "s.json")],
                       capture_output=True, text=True, timeout=600, env=env, cwd=tmp_path)
    assert r.returncode == 0, r.stdout[-1000:] + r.stderr[-2000:]
    import json

    s = json.loads((tmp_path / "s.json").read_text())
    assert s["status"] == "ok" and s["metrics"]["slave_fixture_residual_max"] < 1e-9
    assert (out / "recording.html").stat().st_size > 10_000


def _write(tmp_path, scene) -> Path:
    import tomli_w

    from teleop.app.view_bridge import _plain

    path = tmp_path / "groove.toml"
    path.write_text(tomli_w.dumps(_plain(as_table(scene))))
    return path
