"""VizFrame / VizScene validation, the null view, make_view, and the pure geometry helpers."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from teleop.util.errors import ConfigError
from teleop.viz import NullView, VizFrame, VizScene, make_view
from teleop.viz import layout as L
from teleop.viz import shapes as S

R0 = np.eye(3)


def test_frame_normalises_and_freezes_arrays():
    f = VizFrame(t=1, reference_pose=([0, 0, 0.1], R0.tolist()), operator_wrench=[1, 2, 3, 0, 0, 0],
                 cut_trace=[[0, 0, 0], [0.01, 0, 0]], master_q=[0.1, 0.2])
    assert f.t == 1.0 and isinstance(f.t, float)
    p, R = f.reference_pose
    assert p.shape == (3,) and R.shape == (3, 3)
    assert f.operator_wrench.shape == (6,) and f.cut_trace.shape == (2, 3)
    with pytest.raises(ValueError):
        p[0] = 5.0  # read-only: a frame is a message


@pytest.mark.parametrize("kw, field", [
    (dict(t=float("nan")), "VizFrame.t"),
    (dict(t="0"), "VizFrame.t"),
    (dict(t=0, reference_pose=([0, 0], R0)), "reference_pose.p"),
    (dict(t=0, virtual_pose=([0, 0, 0], 2 * R0)), "virtual_pose.R"),
    (dict(t=0, slave_tool_pose=([0, 0, 0], np.diag([1, 1, -1.0]))), "slave_tool_pose.R"),
    (dict(t=0, reference_pose=np.zeros(3)), "reference_pose"),
    (dict(t=0, operator_wrench=np.zeros(3)), "operator_wrench"),
    (dict(t=0, contact_wrench=[np.inf, 0, 0, 0, 0, 0]), "contact_wrench"),
    (dict(t=0, slave_q=np.zeros((2, 2))), "slave_q"),
    (dict(t=0, cut_trace=np.zeros((4, 2))), "cut_trace"),
])
def test_frame_rejects_bad_fields_naming_them(kw, field):
    with pytest.raises(ConfigError, match=field):
        VizFrame(**kw)


def test_empty_cut_trace_is_zero_points():
    assert VizFrame(t=0, cut_trace=[]).cut_trace.shape == (0, 3)


@pytest.mark.parametrize("kw, field", [
    (dict(fixture_type="cube"), "fixture_type"),
    (dict(fixture_type="free", tool_shape="spoon"), "tool_shape"),
    (dict(fixture_type="sphere", fixture_params={"radius": 1}), "fixture_params"),
    (dict(fixture_type="sphere", fixture_params={"radius_m": -1}), "radius_m"),
    (dict(fixture_type="scalpel", fixture_params={"plane_normal": (0, 0, 0)}), "plane_normal"),
    (dict(fixture_type="scalpel", fixture_params={"depth_m": -0.1}), "depth_m"),
    (dict(fixture_type="free", tissue={"size_m": (0.1, 0)}), "tissue.size_m"),
    (dict(fixture_type="free", tissue={"colour": 1}), "tissue"),
    (dict(fixture_type="free", slave_offset_m=(1, 2)), "slave_offset_m"),
    (dict(fixture_type="free", slave_robot=object()), "slave_robot"),
    (dict(fixture_type="free", master_model=object()), "master_model"),
    (dict(fixture_type="free", force_scale_m_per_N=0), "force_scale_m_per_N"),
])
def test_scene_rejects_bad_settings(kw, field):
    with pytest.raises(ConfigError, match=field):
        VizScene(**kw)


def test_scene_normalises_the_plane_normal_and_tissue():
    s = VizScene("scalpel", {"plane_normal": (0, 0, 2), "depth_m": 0.01, "trocar_m": None}, "scalpel",
                 tissue={"origin_m": (0.5, 0, 0), "normal": (0, 0, 3), "size_m": (0.1, 0.2), "thickness_m": 0.02})
    assert s.fixture_params["plane_normal"] == (0.0, 0.0, 1.0)
    assert "trocar_m" not in s.fixture_params
    assert s.tissue["normal"] == (0.0, 0.0, 1.0) and s.tissue["size_m"] == (0.1, 0.2)


def test_null_view_does_nothing(tmp_path):
    scene = VizScene("free")
    with make_view("null", scene) as view:
        assert isinstance(view, NullView) and view.url is None
        assert view.publish(VizFrame(t=0.0, reference_pose=(np.zeros(3), R0))) is False
        with pytest.raises(ConfigError, match="VizFrame"):
            view.publish("frame")
        with pytest.raises(ConfigError, match="record=True"):
            view.save_html(tmp_path / "x.html")
    view.close()  # twice is fine
    rec = NullView(scene, record=True)
    assert rec.save_html(tmp_path / "x.html") is None
    assert list(tmp_path.iterdir()) == []


def test_make_view_unknown_kind_lists_the_choices():
    with pytest.raises(ConfigError, match="meshcat"):
        make_view("vtk", VizScene("free"))


def test_rotation_between_is_scipys_smallest_rotation():
    """Against scipy's Rotation.align_vectors (one pair: the smallest rotation, unique unless the
    directions are opposite), including directions a hair from equal."""
    rng = np.random.default_rng(0)
    cases = [(rng.normal(size=3), rng.normal(size=3)) for _ in range(50)]
    cases += [(a, a + 1e-9 * rng.normal(size=3)) for a in rng.normal(size=(10, 3))]
    cases += [(a, -a + 1e-3 * rng.normal(size=3)) for a in rng.normal(size=(10, 3))]
    for a, b in cases:
        R = S.rotation_between(a, b)
        ref, _ = Rotation.align_vectors(b[None, :], a[None, :])
        assert np.allclose(R, ref.as_matrix(), atol=1e-9), (a, b)
        assert np.allclose(R.T @ R, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)


def test_rotation_between_a_hair_from_opposite_is_a_half_turn_that_maps_a_onto_b():
    """A hair from opposite, 1 + a.b cancels in Eigen's FromTwoVectors (an unnormalised result
    had R^T R off by 1e-5): still a rotation, mapping a onto b to ~3e-6 (measured) and turning
    by scipy's angle."""
    rng = np.random.default_rng(1)
    for a, k in zip(rng.normal(size=(40, 3)), np.repeat([1e-5, 1e-6, 1e-7, 1e-9], 10)):
        b = -a + k * rng.normal(size=3)
        R = S.rotation_between(a, b)
        ref, _ = Rotation.align_vectors(b[None, :], a[None, :])
        assert np.allclose(R @ (a / np.linalg.norm(a)), b / np.linalg.norm(b), atol=1e-5)
        assert abs(Rotation.from_matrix(R).magnitude() - ref.magnitude()) < 1e-7
        assert np.allclose(R.T @ R, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)


@pytest.mark.parametrize("a", [[0, 1, 0], [0, 0, 1], [1, 0, 0], [0.3, -0.4, 1.2]])
def test_rotation_between_opposite_directions_is_a_half_turn_about_a_perpendicular(a):
    a = np.asarray(a, dtype=float)
    R = S.rotation_between(a, -a)
    rot = Rotation.from_matrix(R)
    axis = rot.as_rotvec() / rot.magnitude()
    assert np.isclose(rot.magnitude(), np.pi)
    assert abs(axis @ a) < 1e-9 * np.linalg.norm(a)  # any such half turn is a smallest rotation
    assert np.allclose(R @ a, -a) and np.isclose(np.linalg.det(R), 1.0)


def test_segment_matrix_spans_the_two_points():
    a, b = np.array([0.1, 0.2, 0.3]), np.array([0.4, -0.1, 0.7])
    M = S.segment_matrix(a, b)
    ends = M @ np.array([[0, -0.5, 0, 1], [0, 0.5, 0, 1]]).T  # the unit cylinder's end centres
    assert np.allclose(ends[:3, 0], a) and np.allclose(ends[:3, 1], b)
    assert np.allclose(np.linalg.norm(S.segment_matrix(a, a)[:3, :3], axis=0), S.TINY)


def test_arrow_length_is_force_times_scale_and_zero_force_hides_it():
    shaft, head = S.arrow_matrices([0, 0, 0], [0, 3.0, 4.0], 0.01, 0.01)
    assert np.isclose(np.linalg.norm(shaft[:3, 1]), 0.05)  # 5 N * 0.01 m/N along the shaft axis
    assert np.allclose(shaft[:3, 3], 0.025 * np.array([0, 0.6, 0.8]))
    assert np.allclose(head[:3, 3], 0.055 * np.array([0, 0.6, 0.8]))
    capped, _ = S.arrow_matrices([0, 0, 0], [1000.0, 0, 0], 0.01, 0.01, max_m=0.2)
    assert np.isclose(np.linalg.norm(capped[:3, 1]), 0.2)
    for M in S.arrow_matrices([1, 2, 3], np.zeros(3), 0.01, 0.01):
        assert np.linalg.norm(M[:3, :3]) < 1e-5


def test_contact_line_sits_on_the_plane_along_the_rolling_direction():
    R = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # axle (body z) along world y
    M = S.contact_line_matrix(np.array([0.1, 0.2, 0.03]), R, {"plane_normal": (0, 0, 1)})
    assert np.allclose(M[:3, 3], [0.1, 0.2, 0.0])
    assert np.allclose(np.abs(M[:3, 0]), [1, 0, 0]) and np.allclose(M[:3, 2], [0, 0, 1])


def test_drawing_states_cover_every_side():
    from teleop.master.cobot import CobotModel

    scene = VizScene("rolling_disk", {"radius_m": 0.03}, "disk", master_model=CobotModel().model,
                     tissue={"size_m": (0.1, 0.1)})
    d = L.Drawing(scene)
    f = VizFrame(t=0, reference_pose=([0, 0, 0.03], R0), virtual_pose=([0.01, 0, 0.03], R0),
                 operator_wrench=np.r_[1.0, 0, 0, 0, 0, 0], master_q=[0.01, 0.0, 0.03, 0.1, 1.0, 0.2],
                 slave_tool_pose=([0.5, 0, 0], np.diag([1, -1, -1.0])))
    states = d.states(f)
    for path in ("master/reference", "master/virtual", "master/contact", "master/handle", "slave/tool",
                 "master/device/link1", "master/arrows/operator/shaft", "slave/arrows/contact/head"):
        assert path in states, path
    assert np.allclose(states["master/handle"][:3, 3], [0.01, 0.0, 0.03])  # the cobot's handle H
    assert set(states) <= set(d.moving) | set(d.followed)  # the moving parts and the followed sides
    with pytest.raises(ConfigError, match="master_q"):
        d.states(VizFrame(t=0, master_q=[0.0, 1.0]))
