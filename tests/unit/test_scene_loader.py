"""Scene files: every shipped scene loads; malformed ones fail naming file, key and reason."""

import pytest

from teleop.scenario.schema import list_scenes, load_scene
from teleop.util.errors import SceneError

BASE = """
name = "x"
duration_s = 1.0
effects = ["damping"]
[tool]
mass_kg = 0.25
inertia_kgm2 = [0.0025, 0.0025, 0.0025]
[fixture]
type = "sphere"
radius_m = 0.05
[damping]
linear_Ns_per_m = 1.0
"""


def test_every_shipped_scene_loads():
    names = list_scenes()
    assert {"paper_rolling_disk", "paper_disk_on_sphere", "scalpel_fixture"} <= set(names)
    for n in names:
        assert load_scene(n).name == n


@pytest.mark.parametrize(
    "edit, key, reason",
    [
        (lambda s: s.replace("duration_s = 1.0", "duration_s = -1.0"), "duration_s", "positive"),
        (lambda s: s.replace("duration_s = 1.0", 'duration_s = "long"'), "duration_s", "finite number"),
        (lambda s: s.replace("mass_kg = 0.25", "mass_kg = 0.0"), "tool.mass_kg", "positive"),
        (lambda s: s.replace("mass_kg = 0.25", "mas_kg = 0.25"), "tool.mas_kg", "unknown key"),
        (lambda s: s.replace('type = "sphere"', 'type = "cube"'), "fixture.type",
         "unknown fixture type 'cube'; known types: free, rolling_disk, sphere, scalpel"),
        (lambda s: s.replace("radius_m = 0.05", "radius_m = 0.0"), "fixture.radius_m", "positive"),
        (lambda s: s.replace('["damping"]', '["dampning"]'), "effects", "unknown effect"),
        (lambda s: s.replace('["damping"]', "[]"), "damping", "effect 'damping' is not on"),
        (lambda s: 'integrator = "leapfrog"\n' + s, "integrator", "unknown integrator"),
        (lambda s: s.replace("[0.0025, 0.0025, 0.0025]", "[0.0025, 0.0025]"), "tool.inertia_kgm2", "3 positive"),
        (lambda s: s + "\n[operator]\nphases = [{ start_s = 2.0, end_s = 1.0 }]\n", "operator.phases[0].end_s",
         "after start_s"),
        (lambda s: s.replace("[fixture]", "[fixture\n"), "<syntax>", "not valid TOML"),
    ],
)
def test_malformed_scene_names_file_key_and_reason(tmp_path, edit, key, reason):
    path = tmp_path / "bad.toml"
    path.write_text(edit(BASE))
    with pytest.raises(SceneError) as e:
        load_scene(str(path))
    assert str(path) in str(e.value)
    assert e.value.key == key
    assert reason in str(e.value)


def test_valid_base_scene_loads(tmp_path):
    path = tmp_path / "ok.toml"
    path.write_text(BASE)
    scene = load_scene(str(path))
    assert scene.fixture.type == "sphere" and scene.damping_linear_Ns_per_m == 1.0
