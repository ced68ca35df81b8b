"""Physically impossible scenes are refused before anything runs, in one line naming the file, the
key and the reason (teleop.scenario.tables' ranges, teleop.scenario.plausibility's rules); rules on
two keys name the key a --set override changed."""

import copy
import math
import tomllib

import numpy as np
import pytest
import tomli_w
from hypothesis import assume, event, given, settings
from hypothesis import strategies as st

from teleop.app.cli import main
from teleop.scenario.overrides import set_key
from teleop.scenario.random_scene import random_scene
from teleop.scenario.schema import find_scene, load_scene, parse_scene, scene_schema
from teleop.scenario.tables import INERTIA_KGM2, ToolSpec
from teleop.util.errors import FieldError, SceneError


def _table(name: str) -> dict:
    return tomllib.loads(find_scene(name).read_text())


def _refused(tmp_path, data: dict, key: str, reason: str) -> SceneError:
    """``data`` written as a scene file is refused naming the file, ``key`` and ``reason``."""
    path = tmp_path / "bad.toml"
    path.write_text(tomli_w.dumps(data))
    with pytest.raises(SceneError) as e:
        load_scene(str(path))
    err = e.value
    assert (err.key, str(path)) == (key, err.path), str(err)
    assert reason in err.reason, str(err)
    assert str(err).startswith(f"{path}: {key}: ") and "\n" not in str(err)
    return err


def _with(name: str, **edits) -> dict:
    data = copy.deepcopy(_table(name))
    for key, value in edits.items():
        set_key(data, key.replace("__", "."), value, "<test>")
    return data


# one bad value each: (shipped scene to start from, {dotted key: value}, key named, reason fragment)
CASES = [
    ("tremor_incision", {"tool.mass_kg": 1e300}, "tool.mass_kg", "in [0.001, 10] kg"),
    ("tremor_incision", {"tool.mass_kg": 1e-4}, "tool.mass_kg", "in [0.001, 10] kg"),
    ("tremor_incision", {"tool.inertia_kgm2": [1e-300] * 3}, "tool.inertia_kgm2", "outside [1e-09, 1] kg*m^2"),
    ("tremor_incision", {"tool.inertia_kgm2": [1e300] * 3}, "tool.inertia_kgm2", "at most 1 kg*m^2"),
    ("tremor_incision", {"tool.inertia_kgm2": [1e-4, 1e-4, 3e-4]}, "tool.inertia_kgm2", "triangle inequality"),
    ("tremor_incision", {"tool.inertia_kgm2": [3e-4, 0, 0, 0, 1e-4, 0, 0, 0, 1e-4]}, "tool.inertia_kgm2",
     "triangle inequality"),
    ("tremor_incision", {"tool.inertia_kgm2": [1e-4, 1e-5, 0, 0, 1e-4, 0, 0, 0, 1e-4]}, "tool.inertia_kgm2",
     "must be symmetric"),
    ("tremor_incision", {"tool.inertia_kgm2": [1e-4, 0, 0, 0, -1e-4, 0, 0, 0, 1e-4]}, "tool.inertia_kgm2",
     "positive definite"),
    ("paper_rolling_disk", {"tool.mass_kg": 0.001}, "tool.inertia_kgm2", "radius of gyration"),
    ("tremor_incision", {"tool.q0": [1e300, 0, 0, 0, 0, 0]}, "tool.q0", "within +-10"),
    ("tremor_incision", {"tool.qd0": [0, 0, 0, 0, 0, 50.0]}, "tool.qd0", "within +-10"),
    ("tremor_incision", {"dt_s": 1e-7}, "dt_s", "at least 1e-05 s"),
    ("tremor_incision", {"fixture.depth_m": 0.05}, "fixture.depth_m", "does not fit in 30 mm of tissue"),
    ("tremor_incision", {"tissue.thickness_m": 0.004}, "fixture.depth_m", "5 mm deep does not fit in 4 mm"),
    ("curved_incision", {"fixture.depth_m": 0.04}, "fixture.depth_m", "40 mm deep does not fit in 30 mm"),
    ("tremor_incision", {"fixture.depth_m": 0.5}, "fixture.depth_m", "at most 0.1 m"),
    ("curved_surface_incision", {"fixture.depth_m": 0.03}, "fixture.depth_m", "does not fit"),
    ("tremor_incision", {"fixture.plane_origin_m": [0.5, 0.0, 1e300]}, "fixture.plane_origin_m", "within +-10 m"),
    ("tremor_incision", {"fixture.plane_normal": [0.0, 0.0, 1e-300]}, "fixture.plane_normal", "non-zero"),
    ("tremor_incision", {"fixture.tip_m": [0.0, 0.0, 5.0]}, "fixture.tip_m", "within +-1 m"),
    ("laparoscopic_incision", {"fixture.trocar_m": [0.5, 0.0, 0.1]}, "fixture.trocar_m", "inside the tissue"),
    ("laparoscopic_incision", {"fixture.trocar_m": [0.5, 0.0, 1e300]}, "fixture.trocar_m", "within +-10 m"),
    ("paper_disk_on_sphere", {"fixture.radius_m": 5.0}, "fixture.radius_m", "in [0.0001, 1] m"),
    ("paper_disk_on_sphere", {"fixture.center_m": [0.0, 0.0, -1e300]}, "fixture.center_m", "within +-10 m"),
    ("tremor_incision", {"operator.hand.tremor_band_hz": [8.0, 1e9]}, "operator.hand.tremor_band_hz", "below 100 Hz"),
    ("tremor_incision", {"dt_s": 0.01, "operator.hand.tremor_band_hz": [8.0, 60.0]}, "operator.hand.tremor_band_hz",
     "Nyquist rate 50 Hz"),
    ("tremor_incision", {"operator.hand.stiffness_N_per_m": 1e9}, "operator.hand.stiffness_N_per_m", "a hand's grip"),
    ("tremor_incision", {"operator.hand.damping_Ns_per_m": 1e9}, "operator.hand.damping_Ns_per_m", "at most 10000"),
    ("tremor_incision", {"operator.hand.waypoints[2]": [5.5, 1e3, -0.06, -0.015]}, "operator.hand.waypoints[2]",
     "within +-10 m"),
    ("tremor_incision", {"operator.hand.waypoints[2]": [0.51, 0.075, -0.06, -0.015]}, "operator.hand.waypoints[2]",
     "m/s from waypoint 1"),
    ("tremor_incision", {"operator.hand.waypoints[0]": [-1.0, -0.075, -0.06, -0.015]}, "operator.hand.waypoints[0]",
     "in [0, 1e+06] s"),
    ("paper_disk_on_sphere", {"operator.phases[2].force_N": [4.0, 0.0, -1e300]}, "operator.phases[2].force_N",
     "a hand pushes at most 1000 N"),
    ("paper_disk_on_sphere", {"operator.phases[0].torque_Nm": [0.0, 0.0, 1e4]}, "operator.phases[0].torque_Nm",
     "at most 100 N*m"),
    ("paper_disk_on_sphere", {"damping.linear_Ns_per_m": 1e9}, "damping.linear_Ns_per_m", "at most 10000 N*s/m"),
    ("paper_disk_on_sphere", {"damping.angular_Nms_per_rad": 1e9}, "damping.angular_Nms_per_rad", "at most 1000"),
    ("paper_disk_on_sphere", {"effects": ["damping", "gravity"], "gravity.g_m_s2": [0.0, 0.0, -1e4]},
     "gravity.g_m_s2", "+-100 m/s^2"),
    ("paper_disk_on_sphere",
     {"effects": ["damping", "springs"], "springs": [{"anchor_m": [0, 0, 0], "k_N_per_m": 1e12}]},
     "springs[0].k_N_per_m", "[0, 1e+07] N/m"),
    ("paper_disk_on_sphere",
     {"effects": ["damping", "springs"], "springs": [{"anchor_m": [0, 0, 1e3], "k_N_per_m": 1.0}]},
     "springs[0].anchor_m", "within +-10 m"),
    ("tremor_incision", {"mapping.feedback_cutoff_hz": 600.0}, "mapping.feedback_cutoff_hz", "Nyquist rate 500 Hz"),
    ("tremor_incision", {"mapping.feedback_cutoff_hz": 1e9}, "mapping.feedback_cutoff_hz", "in [0, 50000]"),
    ("tremor_incision", {"mapping.scale": 1e6}, "mapping.scale", "a motion scale in [0.01, 100]"),
    ("tremor_incision", {"mapping.position_m": [1e300, 0.0, 0.0]}, "mapping.position_m", "within +-10 m"),
    ("tremor_incision", {"mapping.rpy_rad": [0.0, 0.0, 100.0]}, "mapping.rpy_rad", "within one turn"),
    ("tremor_incision", {"master": "cobot", "dt_s": 0.01, "cobot.observer_bandwidth_hz": 60.0},
     "cobot.observer_bandwidth_hz", "Nyquist rate 50 Hz"),
    ("tremor_incision", {"cobot.offset_m": [0.0, 1e300, 0.0]}, "cobot.offset_m",
     "each coordinate must be in [-10, 10] m"),
    ("tremor_incision", {"cobot.max_velocity": 1e300}, "cobot.max_velocity", "velocity limit must be in (0, 100]"),
    ("tremor_incision", {"tissue.stiffness": 1e12}, "tissue.stiffness", "must be in (0, 1e+07]"),
    ("tremor_incision", {"tissue.origin_m": [0.5, 0.0, 1e300]}, "tissue.origin_m", "[-10, 10] m"),
    ("tremor_incision", {"tissue.thickness_m": 5.0}, "tissue.thickness_m", "(0, 1] m"),
    ("tremor_incision", {"tissue.damping_Ns_per_m": 1e9}, "tissue.damping_Ns_per_m", "[0, 10000] N*s/m"),
    ("tremor_incision", {"tissue.exponent": 50.0}, "tissue.exponent", "[1, 3]"),
    ("tremor_incision", {"tissue.cutting": {"v_smooth_mps": 10.0}}, "tissue.cutting.v_smooth_mps", "(0, 1] m/s"),
    ("tremor_incision", {"slave.base_xyz_m": [100.0, 0.0, 0.0]}, "slave.base_xyz_m", "[-10, 10] m"),
    ("tremor_incision", {"slave.servo_lag_s": 10.0}, "slave.servo_lag_s", "[0, 1] s"),
    ("tremor_incision", {"viewer.tissue_size_m": [100.0, 0.08]}, "viewer.tissue_size_m", "(0, 10]"),
    ("tremor_incision", {"link.loss": 1.5}, "link.loss", "[0, 1)"),
    ("tremor_incision", {"link.dv_max_m_s": 1e6}, "link.dv_max_m_s", "(0, 10]"),
]


@pytest.mark.parametrize("scene, edits, key, reason", CASES, ids=[f"{c[2]}-{i}" for i, c in enumerate(CASES)])
def test_an_impossible_value_is_refused_naming_file_key_and_reason(tmp_path, scene, edits, key, reason):
    _refused(tmp_path, _with(scene, **edits), key, reason)


def test_each_case_is_refused_only_for_its_edit(tmp_path):
    """The scenes the cases start from load as shipped (so each refusal is the edit's)."""
    for name in {c[0] for c in CASES}:
        load_scene(name)


@pytest.mark.parametrize("sets, key, reason", [
    (["fixture.depth_m=0.04"], "fixture.depth_m", "40 mm deep does not fit in 30 mm"),
    (["tissue.thickness_m=0.004"], "tissue.thickness_m", "5 mm deep does not fit in 4 mm"),
    (["tissue={origin_m=[0.5, 0.0, 0.2], thickness_m=0.002}"], "tissue.thickness_m", "does not fit in 2 mm"),
    (["dt_s=0.05"], "dt_s", "Nyquist rate 10 Hz"),
    (["operator.hand.tremor_band_hz=[8.0, 60.0]", "dt_s=0.01"], "dt_s", "Nyquist rate 50 Hz"),
    (["dt_s=0.01", "operator.hand.tremor_band_hz=[8.0, 60.0]"], "operator.hand.tremor_band_hz", "Nyquist rate 50 Hz"),
    (["operator.hand.tremor_band_hz[1]=60.0", "dt_s=0.01"], "dt_s", "up to 60 Hz"),
    (["dt_s=0.01", "operator.hand.tremor_band_hz[1]=60.0"], "operator.hand.tremor_band_hz[1]", "up to 60 Hz"),
    (["tool.mass_kg=0.0001"], "tool.mass_kg", "in [0.001, 10] kg"),
    (["mapping.feedback_cutoff_hz=0.0", "master=\"cobot\"", "dt_s=0.04"], "dt_s", "20 Hz joint observer"),
    (["mapping.feedback_cutoff_hz=0.0", "dt_s=0.04", "master=\"cobot\""], "master", "20 Hz joint observer"),
    (["mapping.feedback_cutoff_hz=30.0", "dt_s=0.02"], "dt_s", "force feedback low-pass"),
])
def test_a_rule_on_two_keys_names_the_key_an_override_set(sets, key, reason):
    with pytest.raises(SceneError) as e:
        load_scene("tremor_incision", sets=sets)
    assert e.value.key == key, str(e.value)
    assert reason in e.value.reason and "tremor_incision.toml" in e.value.path, str(e.value)


def test_overrides_name_their_key_for_the_mass_and_the_effects():
    with pytest.raises(SceneError) as e:
        load_scene("paper_rolling_disk", sets=["tool.mass_kg=0.001"])  # its 0.0025 kg*m^2: a 1.6 m radius of gyration
    assert e.value.key == "tool.mass_kg" and "radius of gyration" in e.value.reason
    table = _with("tremor_incision", dt_s=0.02, effects=["coriolis", "damping", "tissue", "cutting"])
    set_key(table, "operator.hand.tremor_band_hz", [8.0, 30.0], "<test>")
    scene = parse_scene(table, "t.toml")  # the band is not sampled while the tremor is off
    with pytest.raises(SceneError) as e:
        scene.with_overrides(['effects=["coriolis", "damping", "tissue", "cutting", "tremor"]'])
    assert e.value.key == "effects" and "Nyquist rate 25 Hz" in e.value.reason


def test_the_default_tissue_counts_too(tmp_path):
    """A scene with a slave cutting tissue but no [tissue] table cuts the default block (30 mm)."""
    table = _with("curved_incision", **{"fixture.depth_m": 0.04})
    del table["tissue"]
    _refused(tmp_path, table, "fixture.depth_m", "in 30 mm of tissue (the default tissue's thickness_m)")
    table["effects"].remove("tissue")  # no tissue to cut: no rule
    path = tmp_path / "ok.toml"
    path.write_text(tomli_w.dumps(table))
    assert load_scene(str(path)).fixture.depth_m == 0.04


def test_with_overrides_keywords_name_their_key():
    scene = load_scene("tremor_incision")
    with pytest.raises(SceneError) as e:
        scene.with_overrides(dt_s=0.05)
    assert e.value.key == "dt_s" and "tremor band up to 12 Hz" in e.value.reason
    assert scene.with_overrides(dt_s=0.002).dt_s == 0.002


def test_the_command_line_names_the_flag_and_runs_nothing(tmp_path, capsys):
    out = tmp_path / "never.json"
    assert main(["run", "tremor_incision", "--dt", "0.05", "--json", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--dt 0.05" in err and "Nyquist" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()
    assert main(["run", "straight_incision", "--set", "fixture.depth_m=0.05", "--json", str(out)]) == 2
    err = capsys.readouterr().err
    assert "straight_incision.toml: fixture.depth_m: a cut 50 mm deep does not fit in 30 mm of tissue" in err
    assert not out.exists()


def test_python_built_tables_check_their_ranges_too():
    with pytest.raises(FieldError) as e:
        ToolSpec(mass_kg=1e300, inertia_kgm2=(1e-3, 1e-3, 1e-3))
    assert e.value.key == "mass_kg"
    with pytest.raises(FieldError) as e:
        ToolSpec(mass_kg=0.1, inertia_kgm2=(1e-4, 1e-4, 3e-4))
    assert e.value.key == "inertia_kgm2" and "triangle" in e.value.reason


def test_every_shipped_scene_is_plausible_on_either_master():
    from teleop.scenario.schema import list_scenes

    for name in list_scenes():
        load_scene(name)
        load_scene(name, sets=['master="cobot"'])


def test_random_scenes_are_plausible():
    """The fuzzer's generator draws real bodies (its scenes load; the inertias meet the triangle inequality)."""
    for seed in range(300):
        scene = parse_scene(random_scene(np.random.default_rng(seed)), f"<fuzz seed {seed}>")
        J = sorted(scene.tool.inertia_kgm2)
        assert J[0] + J[1] >= J[2]


def test_the_schema_shows_the_ranges():
    props = scene_schema()["properties"]
    tool = props["tool"]["properties"]
    assert (tool["mass_kg"]["minimum"], tool["mass_kg"]["maximum"]) == (1e-3, 10.0)
    assert tool["q0"]["items"]["minimum"] == -10.0 and tool["q0"]["items"]["maximum"] == 10.0
    assert (props["dt_s"]["minimum"], props["dt_s"]["maximum"]) == (1e-5, 0.1)
    tissue = props["tissue"]["properties"]
    assert tissue["thickness_m"]["exclusiveMinimum"] == 0.0 and tissue["thickness_m"]["maximum"] == 1.0
    assert tissue["stiffness"]["maximum"] == 1e7
    assert tissue["thickness_m"]["description"].endswith("plausible: (0, 1] m")
    assert tissue["origin_m"]["items"]["minimum"] == -10.0
    assert props["cobot"]["properties"]["offset_m"]["items"]["maximum"] == 10.0
    assert props["slave"]["properties"]["servo_lag_s"]["maximum"] == 1.0
    assert props["operator"]["properties"]["hand"]["properties"]["tremor_band_hz"]["items"]["maximum"] == 100.0
    assert "Nyquist" in props["mapping"]["properties"]["feedback_cutoff_hz"]["description"]


# -- the inertia property ---------------------------------------------------------------------------

LO, HI = INERTIA_KGM2
_moment = st.one_of(st.floats(1e-12, 10.0), st.floats(-1e-3, 1e-3), st.sampled_from([0.0, LO, HI]),
                    st.floats(1e-5, 1e-3))


#: a real body's moments from its mass distribution's second moments S: J_x = S_y + S_z etc.
_body = st.tuples(*[st.floats(1e-10, 0.6)] * 3).map(lambda S: (S[1] + S[2], S[0] + S[2], S[0] + S[1]))


def _physical(J) -> bool:
    """The oracle, written out: every moment positive and in range, and each at most the sum of the
    other two (J1 + J2 >= J3 in every order)."""
    return all(LO <= j <= HI for j in J) and all(J[i] <= J[(i + 1) % 3] + J[(i + 2) % 3] for i in range(3))


def _near_boundary(J) -> bool:
    return any(abs(J[i] - J[(i + 1) % 3] - J[(i + 2) % 3]) <= 1e-6 * max(map(abs, J)) for i in range(3))


def _rotation(a, b, c) -> np.ndarray:
    def rx(t):
        return np.array([[1, 0, 0], [0, math.cos(t), -math.sin(t)], [0, math.sin(t), math.cos(t)]])

    def rz(t):
        return np.array([[math.cos(t), -math.sin(t), 0], [math.sin(t), math.cos(t), 0], [0, 0, 1]])

    return rz(a) @ rx(b) @ rz(c)


@settings(max_examples=300, deadline=None)
@given(J=st.one_of(st.tuples(_moment, _moment, _moment), _body), angles=st.tuples(*[st.floats(-math.pi, math.pi)] * 3))
def test_inertias_are_accepted_iff_a_rigid_body_has_them(J, angles):
    assume(not _near_boundary(J))
    table = _with("paper_disk_on_sphere", **{"tool.mass_kg": 1.0, "tool.inertia_kgm2": list(J)})
    try:
        parse_scene(table, "p.toml")
        accepted = True
    except SceneError as e:
        assert e.key == "tool.inertia_kgm2", str(e)
        accepted = False
    event("accepted" if accepted else "refused")
    assert accepted == _physical(J), (J, accepted)
    # the same body turned, as a 3x3 matrix: the same verdict (away from the range's edges, where
    # the eigenvalues' round-off would decide)
    if all(LO * 1.001 <= j <= HI * 0.999 for j in J):
        R = _rotation(*angles)
        M = R @ np.diag(J) @ R.T
        table["tool"]["inertia_kgm2"] = ((M + M.T) / 2).reshape(-1).tolist()
        try:
            parse_scene(table, "p.toml")
            turned = True
        except SceneError as e:
            assert e.key == "tool.inertia_kgm2" and "triangle" in e.reason, str(e)
            turned = False
        assert turned == accepted, (J, angles)
