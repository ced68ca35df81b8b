"""The Meshcat drawing's pieces checked against what they draw from: the cobot's visuals posed
by Pinocchio's own kinematics, the tool's radius, each side following its tool, equal newtons per
metre on both sides, the text signs, and a user's fixture drawn by its own method or generically."""

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
import pytest
from PIL import Image

from teleop.dynamics.registry import FrameMap
from teleop.master.cobot.model import DEFAULT_URDF
from teleop.util.errors import ConfigError
from teleop.viz import VizFrame, VizScene
from teleop.viz import layout as L
from teleop.viz import shapes as S

R0 = np.eye(3)


class Device:
    def __init__(self):
        self.model, _, self.visual_model = pin.buildModelsFromUrdf(str(DEFAULT_URDF))


def test_cobot_visuals_are_posed_where_pinocchio_puts_them():
    dev = Device()
    assert len(dev.visual_model.geometryObjects) >= 5  # the URDF's visuals: ram, wrist, cell, grip
    d = L.Drawing(VizScene("scalpel", {}, "scalpel", master_robot=dev))
    joints = np.array([0.02, -0.01, 0.03, 0.4, 1.2, -0.3])
    states = d.states(VizFrame(t=0, master_q=joints))
    data, gdata = dev.model.createData(), pin.GeometryData(dev.visual_model)
    q = []  # continuous joints are (cos, sin) in pinocchio's q
    for j, x in zip(dev.model.joints[1:], joints):
        q += [np.cos(x), np.sin(x)] if j.nq == 2 else [x]
    q = np.array(q)
    pin.forwardKinematics(dev.model, data, q)
    pin.updateGeometryPlacements(dev.model, data, dev.visual_model, gdata)
    for k, g in enumerate(dev.visual_model.geometryObjects):
        assert np.allclose(states[f"master/device/visuals/{g.name}"], gdata.oMg[k].homogeneous)
    pin.framesForwardKinematics(dev.model, data, q)
    assert np.allclose(states["master/handle"][:3, 3], data.oMf[dev.model.getFrameId("handle")].translation)


def test_the_disk_is_drawn_with_the_tools_radius_not_the_spheres():
    d = L.Drawing(VizScene("sphere", {"radius_m": 0.05}, "disk", tool_radius_m=0.01))
    disk = next(o for p, o, _ in d.parts if p == "master/reference/disk")
    assert disk.geometry.radiusTop == pytest.approx(0.01)
    sphere = next(o for p, o, _ in d.parts if p == "master/fixture/sphere")
    assert sphere.geometry.radius == pytest.approx(0.05)


def test_each_side_follows_its_tool_and_arrows_have_one_scale():
    scene = VizScene("scalpel", {}, "scalpel", tissue={"size_m": (0.1, 0.1)})
    d = L.Drawing(scene)
    p_m, p_s = np.array([0.05, 0.0, 0.0]), np.array([0.3, 0.1, 0.0])
    for _ in range(200):
        states = d.states(VizFrame(t=0, reference_pose=(p_m, R0), slave_tool_pose=(p_s, np.diag([1, -1, -1.0])),
                                   constraint_wrench=[0, 0, 2.0, 0, 0, 0], contact_wrench=[0, 0, 2.0, 0, 0, 0]))
    for side, p in (("master", p_m), ("slave", p_s)):  # the tool lands on its side's anchor
        x = states[side] @ np.r_[p, 1.0]
        assert np.allclose(x[:3], d.anchor[side], atol=1e-9), side
    # a 2 N arrow is as long on screen (layout m) on both sides: length x side zoom
    lm = np.linalg.norm(states["master/arrows/constraint/shaft"][:3, 1]) * d.zoom
    ls = np.linalg.norm(states["slave/arrows/contact/shaft"][:3, 1]) * d.slave_zoom
    assert lm == pytest.approx(ls) == pytest.approx(2.0 * scene.force_scale_m_per_N)


def test_text_png_draws_the_colour_it_is_given():
    import io

    png, aspect = S.text_png([("master", 0x00A070)])
    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGBA"))
    assert aspect > 2.0  # a word is wider than tall
    ink = img[img[..., 3] == 255][:, :3]
    assert len(ink) > 100 and np.all(ink == [0x00, 0xA0, 0x70])


@dataclass(frozen=True)
class Bowl:
    """A user's fixture type with its own drawing."""

    radius_m: float = 0.04

    def build(self, frame):
        raise NotImplementedError  # the view never builds it

    def draw(self, frame):
        from meshcat import geometry as g

        M = np.eye(4)
        M[:3, 3] = frame.point((0.0, 0.0, 0.0))
        return [("bowl", g.Mesh(g.Sphere(frame.length(self.radius_m))), M)]


@dataclass(frozen=True)
class Groove:
    """A user's fixture type without a drawing."""

    depth_m: float = 0.002

    def build(self, frame):
        raise NotImplementedError


def test_a_user_fixture_draws_itself_in_the_master_frame():
    frame = FrameMap(R0, np.array([0.1, 0.0, 0.0]), 0.5)
    d = L.Drawing(VizScene("bowl", {}, "box", fixture_object=Bowl(), fixture_frame=frame))
    _name, obj, M = next(x for x in d.parts if x[0] == "master/fixture/bowl")
    assert obj.geometry.radius == pytest.approx(0.02) and np.allclose(M[:3, 3], [0.05, 0, 0])
    assert d.trace_master is None


def test_a_user_fixture_without_a_drawing_gets_a_triad_and_a_trace():
    d = L.Drawing(VizScene("groove", {}, "box", fixture_object=Groove()))
    assert sum(p.startswith("master/reference/triad/") for p, _, _ in d.parts) == 3
    for k in range(3):
        d.states(VizFrame(t=k, reference_pose=([0.01 * k, 0, 0], R0)))
    assert np.allclose(d.trace_master, [[0, 0, 0], [0.01, 0, 0], [0.02, 0, 0]])


def test_a_bad_user_drawing_is_named():
    class Bad(Groove):
        def draw(self, frame):
            return [("x", None)]

    with pytest.raises(ConfigError, match=r"Bad\.draw: item 0"):
        L.Drawing(VizScene("bad", {}, "box", fixture_object=Bad()))


def test_scene_refuses_an_unknown_type_without_its_object_and_a_bad_view():
    with pytest.raises(ConfigError, match="fixture_object"):
        VizScene("groove", {})
    with pytest.raises(ConfigError, match=r"VizScene\.view"):
        VizScene("free", {}, view="fisheye")


def test_labels_and_legend_are_opaque_cards_drawn_over_everything():
    """Readable over any plane: the signs are drawn last (three.js renderOrder) without a depth
    test, on an opaque card; the translucent fixture planes once covered the legend."""
    import io

    d = L.Drawing(VizScene("scalpel", {}, "scalpel", tissue={"size_m": (0.1, 0.1)}))
    signs = [(p, o) for p, o, _ in d.parts if p.startswith("labels/")]
    assert {p for p, _ in signs} == {"labels/master/sign", "labels/slave/sign", "labels/legend"}
    for _, obj in signs:
        lowered = obj.lower()
        assert lowered["object"]["renderOrder"] == S.ON_TOP
        mat = lowered["materials"][0]
        assert mat["depthTest"] is False and mat["depthWrite"] is False
    others = [o.lower()["object"].get("renderOrder", 0) for p, o, _ in d.parts if not p.startswith("labels/")]
    assert max(others) < S.ON_TOP
    png, _ = S.sign_png([[("text", "master", S.COLORS["label"])]])
    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGBA"))
    h, w = img.shape[:2]
    assert np.all(img[h // 2, 5:15, 3] == 255)  # the card is opaque at its edge
    assert tuple(img[h // 2, w // 2 - 60:w // 2 + 60, :3].reshape(-1, 3).max(axis=0)) <= (0xF8, 0xF6, 0xEE)


def test_the_virtual_tool_is_a_halo_around_the_reference_tool():
    d = L.Drawing(VizScene("scalpel", {}, "scalpel"))
    parts = {p: (o, M) for p, o, M in d.parts}
    for piece in ("blade", "grip"):
        ref, ghost = parts[f"master/reference/{piece}"], parts[f"master/virtual/{piece}"]
        assert np.linalg.norm(ghost[1][:3, 0]) == pytest.approx(S.HALO * np.linalg.norm(ref[1][:3, 0]))
        assert ghost[0].material.color == S.COLORS["ghost"] and ghost[0].material.opacity < 1.0
        assert ghost[0].material.side == 1  # its back faces: a rim, the tool seen unveiled
    words = [item[1] for row in d.legend_rows() for item in row if item[0] == "text"]
    assert "reference tool" in words and "virtual tool (device)" in words


def test_the_cobot_is_translucent_so_the_tool_it_holds_shows():
    d = L.Drawing(VizScene("rolling_disk", {"radius_m": 0.03}, "disk", master_robot=Device()))
    device = [o for p, o, _ in d.parts if p.startswith("master/device/visuals/")]
    assert device and all(o.material.opacity == L.DEVICE_OPACITY < 1.0 for o in device)
    assert all(o.material.color == S.COLORS["device"] for o in device)
