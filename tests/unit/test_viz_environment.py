"""Each side's fixture and environment, drawn from their own geometry (teleop.viz.environment):
every constraint with a place in space where it is, a curved surface on its height field, a
trocar at its pivot, the tissue on both sides, for every shipped scene; a fixture the view
cannot draw said once, with the tool's axes drawn instead."""

import logging

import numpy as np
import pytest

from teleop.dynamics import constraints as C
from teleop.dynamics.fixtures import Fixture
from teleop.dynamics.registry import FrameMap
from teleop.scenario.schema import list_scenes, load_scene
from teleop.viz import VizFrame, VizScene
from teleop.viz import environment as E
from teleop.viz import layout as L
from teleop.viz.shapes import COLORS

N = np.array([0.0, 0.0, 1.0])


def _by_name(parts) -> dict:
    return {name: (obj, M) for name, obj, M in parts}


def _top_face(obj, M) -> tuple:
    """(a point of a slab's top face, its normal) from its box and transform."""
    thin = obj.geometry.lengths[2]
    return M[:3, 3] + 0.5 * thin * M[:3, 2], M[:3, 2]



def _unknown_rule(name: str, kind: str):
    """A one-row holonomic constraint ``name`` of a class ``kind`` the viewer does not know (a
    user's own)."""

    class Unknown(C.Constraint):
        rows, holonomic = 1, True

        def residual(self, p, R):
            return np.zeros(1)

        def jacobian(self, p, R):
            return np.zeros((1, 6))

        def bias(self, p, R, v, w):
            return np.zeros(1)

    return type(kind, (Unknown,), {"name": name})()

def test_planes_spheres_and_trocars_are_drawn_where_their_constraints_hold_the_tool():
    o = np.array([0.5, 0.1, 0.2])
    cons = (C.PlaneHeight(o, N, 0.03), C.SphereContact(o, 0.05), C.PointDepth(o, N, 0.005),
            C.RemoteCenter(o + 0.075 * N), C.KnifeEdge(), C.AxisAlong(), C.RollingWithoutSlip())
    parts, legend, undrawn = E.fixture_parts(cons, 0.3, 0.2)
    drawn = _by_name(parts)
    assert not undrawn and legend == ["plane", "sphere", "tissue", "depth", "trocar"]
    p, n = _top_face(*drawn["plane"])
    assert np.allclose(p, o) and np.allclose(n, N)  # the plane the disk rolls on, not its height
    assert drawn["sphere"][0].geometry.radius == pytest.approx(0.05) and np.allclose(drawn["sphere"][1][:3, 3], o)
    assert np.allclose(_top_face(*drawn["tissue_plane"])[0], o)
    assert np.allclose(_top_face(*drawn["depth_plane"])[0], o - 0.005 * N)  # where the blade tip is held
    port = drawn["trocar_port"][1]
    assert np.allclose(port[:3, 3], o + 0.075 * N)
    assert abs(port[:3, 1] @ N) == pytest.approx(1.0)  # the port along the surface's normal
    assert np.allclose(drawn["trocar_pivot"][1][:3, 3], o + 0.075 * N)


def test_the_tissue_block_stands_for_the_surface_plane_and_bounds_the_depth_plane():
    tissue = {"origin_m": (0.5, 0.0, 0.2), "normal": (0.0, 0.0, 1.0), "size_m": (0.12, 0.08), "thickness_m": 0.03}
    parts, legend, _ = E.fixture_parts((C.PointDepth((0.5, 0.0, 0.2), N, 0.005),), 0.3, 0.2, tissue)
    drawn = _by_name(parts)
    assert set(drawn) == {"depth_plane"} and legend == ["depth"]  # the block's top is the surface
    obj, M = drawn["depth_plane"]
    assert obj.geometry.lengths[:2] == pytest.approx([0.98 * 0.12, 0.98 * 0.08])  # inside the block
    assert np.allclose(M[:3, :3], E.tissue_rotation(tissue))


def test_a_constraint_of_another_kind_is_not_guessed_at():
    cyl = _unknown_rule("on_cylinder", "OnCylinder")
    parts, legend, undrawn = E.fixture_parts((cyl, C.PlaneHeight()), 0.3, 0.2)
    assert undrawn == [cyl] and legend == ["plane"] and len(parts) == 1


def test_a_curved_surface_is_drawn_on_its_height_field_and_its_depth_below_it():
    scene = load_scene("curved_surface_incision")
    surface = scene.fixture.params.tissue_surface()
    depth = scene.fixture.params.depth_m
    parts = _by_name(E.height_field_parts(surface, depth, samples=24))
    skin, under = parts["surface"][0].geometry, parts["depth_surface"][0].geometry
    top = skin.vertices[: len(under.vertices)]
    for p in top[:: 37]:  # on the surface: its own foot, at no distance
        s, _, _ = surface.signed_distance(p)
        assert abs(s) < 1e-6
    for p in under.vertices[:: 37]:  # the blade's surface: depth below, along the normal
        s, _, _ = surface.signed_distance(p)
        assert s == pytest.approx(-depth, abs=1e-6)
    base = skin.vertices[len(top):]  # the rim, then the walls' foot on the height field's base plane
    foot = base[len(base) // 2:]
    assert np.allclose((foot - surface.o) @ surface.Q[:, 2], 0.0, atol=1e-6)
    assert skin.faces.max() < len(skin.vertices) and under.faces.max() < len(under.vertices)


def test_the_tool_shape_follows_the_fixture():
    assert E.tool_shape_for((C.RollingWithoutSlip(),), False) == "disk"
    assert E.tool_shape_for((C.SphereContact(),), True) == "disk"
    assert E.tool_shape_for((C.PointDepth(),), False) == "scalpel"
    assert E.tool_shape_for((), True) == "scalpel"  # the slave's tool
    assert E.tool_shape_for((), False) == "box"


@pytest.fixture
def no_meshes(monkeypatch):
    """viz_scene_for without the arm's and the cobot's meshes (what they draw is tested elsewhere)."""
    from teleop.app import view_bridge

    monkeypatch.setattr(view_bridge, "slave_robot_for", lambda scene: None)
    monkeypatch.setattr(view_bridge, "master_robot_for", lambda scene: None)
    return view_bridge.viz_scene_for


@pytest.mark.parametrize("name", list_scenes())
def test_every_shipped_scene_draws_its_fixture_and_environment_on_both_sides(name, no_meshes, caplog):
    scene = load_scene(name)
    with caplog.at_level(logging.WARNING, logger="teleop"):
        d = L.Drawing(no_meshes(scene))
    assert not d.generic and not caplog.records  # every shipped fixture is drawn from its geometry
    paths = {p for p, _, _ in d.parts}
    sides = ("master", "slave") if scene.slave is not None else ("master",)
    for side in sides:
        if scene.fixture.type != "free":
            assert any(p.startswith(f"{side}/fixture/") for p in paths), (side, sorted(paths))
        if scene.slave is not None:
            assert f"{side}/tissue/block" in paths, side
    if scene.fixture.type == "scalpel" and scene.fixture.trocar_m is not None:
        assert {f"{s}/fixture/trocar_port" for s in sides} <= paths
    if scene.fixture.type == "surface_scalpel":
        assert {f"{s}/fixture/surface" for s in sides} <= paths
    words = " ".join(item[1] for row in d.legend_rows() for item in row if item[0] == "text")
    for key in d.legend_keys:
        assert E.LEGEND[key][0] in words


def test_the_master_side_shows_the_slaves_tissue_and_trocar_under_the_map(no_meshes):
    """laparoscopic_incision, 3:1: the master's trocar and tissue where the registration puts
    the slave's, each side's tissue filling its side, each side's tool long enough to pass its
    trocar."""
    from teleop.scenario.build import master_frame

    scene = load_scene("laparoscopic_incision")
    d = L.Drawing(no_meshes(scene))
    frame = master_frame(scene)
    parts = {p: (o, M) for p, o, M in d.parts}
    assert np.allclose(parts["master/fixture/trocar_port"][1][:3, 3], frame.point(scene.fixture.trocar_m))
    assert np.allclose(parts["slave/fixture/trocar_port"][1][:3, 3], scene.fixture.trocar_m)
    assert np.allclose(parts["master/tissue/block"][0].geometry.lengths,
                       frame.length(1.0) * np.array(parts["slave/tissue/block"][0].geometry.lengths))
    assert d.zoom * frame.length(max(d.scene.tissue["size_m"])) == pytest.approx(0.6 * L.SIDE_M)
    pivot = frame.length(scene.fixture.trocar_m[2] - scene.fixture.plane_origin_m[2] + scene.fixture.depth_m)
    grip, M = parts["master/reference/grip"]
    top = -(M[2, 3] - 0.5 * grip.geometry.height)  # the handle's far end along the shaft (body -z)
    assert top > 1.2 * pivot and E.shaft_length(d.scene.master_fixture.constraints) == pytest.approx(1.5 * pivot)
    assert E.shaft_length(d.scene.slave_fixture.constraints) == pytest.approx(E.TOOL_LENGTH_M)  # 75 mm: 0.12 passes


def test_a_fixture_the_view_cannot_draw_is_said_once_and_gets_the_tools_axes(caplog):
    fx = Fixture("odd", (_unknown_rule("odd_rule", "Odd"), C.PlaneHeight()), None)
    tissue = {"origin_m": (0.0, 0.0, 0.0), "size_m": (0.1, 0.1)}
    scene = VizScene("free", {}, "box", tissue=tissue, master_fixture=fx, slave_fixture=fx,
                     fixture_frame=FrameMap.identity())
    with caplog.at_level(logging.WARNING, logger="teleop"):
        d = L.Drawing(scene)
        d.states(VizFrame(t=0.0, reference_pose=(np.zeros(3), np.eye(3))))
    said = [r.getMessage() for r in caplog.records]
    assert len(said) == 1 and "odd_rule (Odd)" in said[0] and "draw(frame)" in said[0]
    assert d.generic and sum(p.startswith("master/reference/triad/") for p, _, _ in d.parts) == 3
    assert {"master/fixture/plane", "slave/fixture/plane"} <= {p for p, _, _ in d.parts}  # the rest is drawn
    colours = {obj.material.color for p, obj, _ in d.parts if "/triad/" in p}
    assert not colours & {COLORS[k] for k in ("operator", "constraint", "contact")}  # no force's colour
    words = [item[1] for row in d.legend_rows() for item in row if item[0] == "text"]
    assert "z axes" in words
