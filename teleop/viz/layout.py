"""Where everything goes in the one Meshcat page: the two sides laid out side by side, and the
transforms of the moving parts for each frame. Geometry helpers live in :mod:`teleop.viz.shapes`."""

from __future__ import annotations

import logging

import numpy as np
import pinocchio as pin
from meshcat import geometry as g
from pinocchio.visualize import meshcat_visualizer as pmv

from teleop.dynamics.registry import FrameMap
from teleop.util.errors import ConfigError
from teleop.viz.environment import LEGEND, environment_parts, mapped_tissue, shaft_length, side_constraints
from teleop.viz.shapes import (
    COLORS,
    TINY,
    VIEW_HEIGHT_M,
    VIEW_WIDTH_M,
    Y_TO_Z,
    arrow_matrices,
    arrow_parts,
    contact_line_matrix,
    contact_line_part,
    device_joint_part,
    material,
    pose_matrix,
    scalpel_parts,
    segment_matrix,
    sign_part,
    tool_parts,
    triad_parts,
)

log = logging.getLogger(__name__)

PITCH = np.radians(20.0)
#: meshcat's default camera looks at the origin from (3, 0, 1) m: down by this angle (rad); the
#: side view's camera looks level
CAMERA_ELEVATION = float(np.arctan2(1.0, 3.0))
#: layout metres between the two sides' anchors; each side's content is scaled to about SIDE_M
SIDE_M = 1.0
#: how far each frame moves a side's aim toward its tool (1: locked on the tool, 0: fixed)
FOLLOW = 0.15
#: newtons of the legend's scale arrow
SCALE_N = 5.0
#: the longest arrow drawn (layout m); a longer force is drawn this long (the legend says so)
ARROW_MAX_M = 0.6
#: the height of a row of the legend (layout m)
LEGEND_ROW_M = 0.05 * SIDE_M
#: the cobot's opacity: translucent, so the tool it holds shows through its wrist
DEVICE_OPACITY = 0.45


def _visual_parts(robot, prefix: str, color: int | None = None, opacity: float = 1.0) -> list:
    """(part index, group path, part) of each visual of a RobotWrapper-like ``robot``, each made by
    Pinocchio's own Meshcat loader (``loadPrimitive`` / ``loadMesh``); the group is posed from
    ``GeometryData.oMg`` with the mesh scale applied, as Pinocchio's MeshcatVisualizer does."""
    out = []
    for k, gobj in enumerate(robot.visual_model.geometryObjects):
        kind = type(gobj.geometry).__name__
        if kind in ("Box", "Sphere", "Cylinder", "Capsule", "Cone"):
            obj = pmv.loadPrimitive(gobj)
        elif kind.startswith("BVHModel"):
            obj = pmv.loadMesh(gobj.geometry)
        else:
            obj = None
        if obj is None or not isinstance(obj, g.Geometry):
            continue
        c = gobj.meshColor
        rgb = color if color is not None else (int(c[0] * 255) << 16) | (int(c[1] * 255) << 8) | int(c[2] * 255)
        out.append((k, f"{prefix}/{gobj.name}", g.Mesh(obj, material(rgb, opacity))))
    return out


class Drawing:
    """The scene's geometry and layout (owns pinocchio Data workspaces for the device and arm).

    Paths are relative to the scene root. The master side is magnified by ``zoom`` and the slave
    side by ``slave_zoom`` so each fills about SIDE_M layout metres; the master side is anchored at
    the layout origin, the slave side at ``slave_offset_m`` (layout m). Each side aims at its tool
    and follows it (``scene.follow``: each frame moves the aim FOLLOW of the way to the tool), so a
    moving tool stays in the middle of its side. Force arrows have the same length per newton on
    both sides (``force_scale_m_per_N`` layout metres, whatever the zooms). The root turns the
    layout so +x runs left to right on the camera (``view="perspective"`` tips it toward the
    camera by PITCH; ``"side"`` looks level, with an orthographic camera set by the view).
    The handle H is drawn with the device (at its "handle" frame, else its last joint); without a
    device the virtual tool is where the hand is.
    """

    def __init__(self, scene):
        self.pin, self.scene = pin, scene
        self._layout()
        self.has_slave = scene.slave_robot is not None or scene.tissue is not None
        self.n_per_m = {"master": self.zoom / scene.force_scale_m_per_N,
                        "slave": self.slave_zoom / scene.force_scale_m_per_N}
        extent = {"master": self.size, "slave": self.slave_size}
        parts, self.legend_keys, self.generic = environment_parts(scene, self.has_slave, self.master_tissue, extent)
        parts += self._tools()
        parts += self._device()
        self.arm = scene.slave_robot
        self.arm_parts = []
        if self.arm is not None:
            self.adata = self.arm.model.createData()
            self.gdata = pin.GeometryData(self.arm.visual_model)
            for k, path, obj in _visual_parts(self.arm, "slave/arm", COLORS["arm"]):
                self.arm_parts.append((k, path))
                parts.append((f"{path}/shape", obj, np.eye(4)))
            self.tool_fid = (self.arm.model.getFrameId(scene.slave_tool_frame)
                             if scene.slave_tool_frame is not None else None)
        parts += self._labels()
        self.parts = parts
        self.fixed["root"] = self._root_matrix()
        # nodes that move: hidden until a frame places them
        groups = {p.rsplit("/", 1)[0] for p, _, _ in parts}
        self.moving = sorted(p for p, _, _ in parts if "/arrows/" in p)
        self.moving += sorted(p for p in groups if (p.count("/") == 1 and p.split("/")[1] in (
            "reference", "virtual", "contact", "handle", "tool"))
            or p.startswith(("slave/arm/", "master/device/visuals/")))
        self.moving += sorted(p for p, _, _ in parts if p.startswith("master/device/link"))
        self.moving += sorted(p for p in groups if p.startswith("master/device/joint"))
        self.followed = ("master", "slave") if scene.follow else ()

    def _layout(self) -> None:
        """Each side's size (m), zoom, aim, anchor and turn. With a map into the master workspace
        (``fixture_frame``) and a tissue, the master side shows the slave's tissue where the map
        puts it; each side is zoomed so its tissue fills it."""
        scene = self.scene
        p, ft, frame, tissue = scene.fixture_params, scene.fixture_type, scene.fixture_frame, scene.tissue
        self.radius = p.get("radius_m", 0.03)
        self.master_tissue = None if tissue is None or frame is None else mapped_tissue(tissue, frame)
        self.size = {"rolling_disk": max(8.0 * self.radius, 0.1),
                     "sphere": min(3.0 * self.radius, 10.0 * (scene.tool_radius_m or self.radius)),
                     "scalpel": 0.2}.get(ft, 0.15)
        self.slave_size = max(tissue["size_m"]) if tissue is not None else 0.6
        self.slave_zoom = float(np.clip(0.6 * SIDE_M / self.slave_size, 0.5, 3.0))
        self.zoom = scene.master_zoom or float(np.clip(0.6 * SIDE_M / self.size, 1.0, 10.0))
        centre = np.asarray(p.get("center_m" if ft == "sphere" else "plane_origin_m", (0.0, 0.0, 0.0)), dtype=float)
        if self.master_tissue is not None:  # zoomed to fill its side, as the slave's tissue fills its own
            self.size = max(self.master_tissue["size_m"])
            self.zoom = scene.master_zoom or float(np.clip(0.6 * SIDE_M / self.size, 0.5, 10.0))
            centre = np.asarray(self.master_tissue["origin_m"], dtype=float)
        self.aim = {"master": centre.copy(),
                    "slave": np.asarray(tissue["origin_m"], dtype=float) if tissue is not None else np.zeros(3)}
        self.anchor = {"master": np.zeros(3), "slave": np.asarray(scene.slave_offset_m, dtype=float)}
        self.turn = {"master": np.eye(3), "slave": self._arm_behind(pin)}
        self.fixed = {side: self._side_matrix(side) for side in ("master", "slave")}

    def _tools(self) -> list:
        """Both tools on the master side (the reference tool and the virtual tool's halo, and the
        tool's axes when the fixture could not be drawn), the slave's tool, the force arrows."""
        scene, p = self.scene, self.scene.fixture_params
        tip = p.get("tip_m", (0.0, 0.0, 0.0))
        if scene.fixture_object is not None and hasattr(scene.fixture_object, "tip_m"):
            tip = (scene.fixture_frame or FrameMap.identity()).body_point(scene.fixture_object.tip_m)
        tool_r = scene.tool_radius_m or self.radius
        length = shaft_length(side_constraints(scene, "master")[0])
        parts = []
        for name, ghost in (("reference", False), ("virtual", True)):
            drawn = tool_parts(scene.tool_shape, tool_r, tip, ghost, length)
            parts += [(f"master/{name}/{n}", o, M) for n, o, M in drawn]
        if self.generic:  # a fixture the view cannot draw: the tool's frame triad (and a trace)
            parts += [(f"master/reference/triad/{n}", o, M) for n, o, M in triad_parts(0.4 * self.size)]
        self.trace_master = [] if self.generic else None
        if scene.fixture_type == "rolling_disk":
            parts += [(f"master/contact/{n}", o, M) for n, o, M in contact_line_part(self.radius)]
        r_m = 0.0015 * 5.0 / self.zoom
        for name, r, where in (("operator", r_m, "master"), ("constraint", r_m, "master"),
                               ("contact", 0.0075 / self.slave_zoom, "slave")):
            parts += [(f"{where}/arrows/{name}/{n}", o, M) for n, o, M in arrow_parts(r, COLORS[name])]
        slave_length = shaft_length(side_constraints(scene, "slave")[0])
        parts += [(f"slave/tool/{n}", o, M)
                  for n, o, M in scalpel_parts((0, 0, 0), 1.0, COLORS["tool"], handle_len=slave_length - 0.03)]
        return parts

    def _device(self) -> list:
        """The master device: the cobot from its URDF's visuals (translucent, so the tool it holds
        shows through), or a stick drawing of a bare model, and its handle."""
        scene, parts = self.scene, []
        self.master = scene.master_model
        self.device_parts = []
        if scene.master_robot is not None:
            self.master = scene.master_robot.model
            self.mdata = self.master.createData()
            self.dgdata = pin.GeometryData(scene.master_robot.visual_model)
            for k, path, obj in _visual_parts(scene.master_robot, "master/device/visuals", COLORS["device"],
                                              DEVICE_OPACITY):
                self.device_parts.append((k, path))
                parts.append((f"{path}/shape", obj, np.eye(4)))
            self.handle_fid = self.master.getFrameId("handle") if self.master.existFrame("handle") else None
        elif self.master is not None:
            m = self.master
            self.mdata = m.createData()
            self.handle_fid = m.getFrameId("handle") if m.existFrame("handle") else None
            for j in range(1, m.njoints):
                parts.append((f"master/device/link{j}", g.Mesh(g.Cylinder(1.0, 0.004), material(COLORS["device"])),
                              np.eye(4)))
                o, M = device_joint_part(j, m.joints[j])
                parts.append((f"master/device/joint{j}/marker", o, M))
            parts.append(("master/device/link_handle", g.Mesh(g.Cylinder(1.0, 0.004), material(COLORS["device"])),
                          np.eye(4)))
        if self.master is not None:
            knob, grip = g.Sphere(0.006), g.Cylinder(0.05, 0.004)  # the handle H: knob at H, grip along -z
            parts += [("master/handle/knob", g.Mesh(knob, material(COLORS["handle"])), np.eye(4)),
                      ("master/handle/grip", g.Mesh(grip, material(COLORS["handle"])),
                       pose_matrix((0, 0, -0.025), Y_TO_Z))]
        return parts

    def _side_matrix(self, side: str) -> np.ndarray:
        """Layout transform of a side: anchor + zoom * (x - aim)."""
        z = self.zoom if side == "master" else self.slave_zoom
        R = self.turn[side]
        return pose_matrix(self.anchor[side] - z * (R @ self.aim[side]), R, (z, z, z))

    def _arm_behind(self, pin) -> np.ndarray:
        """A turn of the slave side about the vertical that puts the arm's base behind its tissue
        and to the right (away from the master side; straight right in the side view), so the
        arm reaches in from the far side instead of across the page."""
        arm = self.scene.slave_robot
        if arm is None or self.scene.tissue is None:
            return np.eye(3)
        d = arm.model.createData()
        pin.forwardKinematics(arm.model, d, pin.neutral(arm.model))
        v = d.oMi[1].translation - np.asarray(self.scene.tissue["origin_m"], dtype=float)
        if np.hypot(v[0], v[1]) < 1e-6:
            return np.eye(3)
        want = 0.0 if self.scene.view == "side" else np.pi / 2  # layout +x, or +y (behind)
        a = want - np.arctan2(v[1], v[0])
        c, s_ = np.cos(a), np.sin(a)
        return np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])

    def _labels(self) -> list:
        """The "master" / "slave" signs above each side and the legend (bottom left, or beside a
        master alone), in layout m (under the root, not the zoomed sides), each on an opaque card
        drawn over everything; the legend's scale arrow is SCALE_N newtons long at the arrows'
        common scale, and it names only what is drawn."""
        h, top = 0.1 * SIDE_M, 0.42 * SIDE_M
        a = self._pitch() + (CAMERA_ELEVATION if self.scene.view == "perspective" else 0.0)
        c_, s_ = np.cos(a), np.sin(a)
        # parallel to the image plane (the camera looks down CAMERA_ELEVATION on the layout tipped
        # by the pitch), so a card is drawn as a rectangle wherever it is on the page
        face = pose_matrix(R=np.array([[1.0, 0.0, 0.0], [0.0, c_, s_], [0.0, -s_, c_]]))
        out = []
        for side in ("master", "slave") if self.has_slave else ("master",):
            name, obj, M = sign_part("sign", [[("text", side, COLORS["label"])]], h)
            M = pose_matrix(self.anchor[side] + [0.08 * SIDE_M, 0.0, top]) @ face @ M
            out.append((f"labels/{side}/{name}", obj, M))
        rows = self.legend_rows()
        row_m = LEGEND_ROW_M
        height = row_m * (len(rows) + 1)  # the card's padding: half a row above and below
        name, obj, M = sign_part("legend", rows, height)
        x, z_top = (-0.55, -0.42) if self.has_slave else (0.62, 0.2)  # bottom left, or beside the master
        self.legend_bottom = z_top * SIDE_M - height
        self.legend_right = x * SIDE_M + 2.0 * M[0, 3]  # the sign spans [0, width] from its anchor
        M = pose_matrix((x * SIDE_M, 0.0, z_top * SIDE_M - 0.5 * height)) @ face @ M
        out.append((f"labels/{name}", obj, M))
        return out

    def legend_rows(self) -> list:
        """The legend's rows (teleop.viz.shapes.sign_png items): the force arrows and their
        scale, the tools, the machines, and what the fixtures and the environment drew."""
        text, m_per_N = COLORS["text"], self.scene.force_scale_m_per_N
        L = SCALE_N * m_per_N / LEGEND_ROW_M * 56 * 1.3  # the scale arrow: SCALE_N newtons, in the sign's pixels
        forces = [("operator's hand force", "operator"), ("fixture (constraint) force", "constraint")]
        if self.has_slave:
            forces.append(("tissue contact force", "contact"))
        rows = [[("arrow", COLORS[key], L), ("text", words, text)] for words, key in forces]
        rows.append([("arrow", text, L), ("text", f"{SCALE_N:g} N (longest drawn: {ARROW_MAX_M / m_per_N:.0f} N)",
                                          text)])
        rows.append([("box", COLORS["tool"]), ("text", "reference tool", text),
                     ("ring", COLORS["ghost"]), ("text", "virtual tool (device)", text)])
        things = [(COLORS["device"], "cobot")] if self.master is not None else []
        if self.scene.slave_robot is not None:
            things.append((COLORS["arm"], "slave arm"))
        things += [LEGEND[k][::-1] for k in self.legend_keys]
        if self.generic:
            things += [(COLORS["axis_x"], "tool x"), (COLORS["axis_y"], "y"), (COLORS["tool"], "z axes")]
        for k in range(0, len(things), 3):
            row: list = []
            for color, words in things[k:k + 3]:
                row += [("box", color), ("text", words, text)]
            rows.append(row)
        return rows

    def _pitch(self) -> float:
        """How far the layout is tipped toward the camera (rad): PITCH, 0 in the side view."""
        return PITCH if self.scene.view == "perspective" else 0.0

    def _root_matrix(self) -> np.ndarray:
        h = 0.5 * SIDE_M
        off = np.asarray(self.scene.slave_offset_m)
        # the slave side, or the legend beside the master
        right = off[0] + h + 0.1 if self.has_slave else self.legend_right + 0.05 * SIDE_M
        bottom = min(-0.75 * SIDE_M, self.legend_bottom - 0.05 * SIDE_M)
        xs, zs = [-h if self.has_slave else -1.6 * h, right], [bottom, 0.6 * SIDE_M]
        c = np.array([0.5 * (min(xs) + max(xs)), 0.0, 0.5 * (min(zs) + max(zs))])
        s = min(0.9 * VIEW_WIDTH_M / (max(xs) - min(xs)), 0.9 * VIEW_HEIGHT_M / (max(zs) - min(zs)))
        Rz = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # layout +x -> screen right
        c_, s_ = np.cos(self._pitch()), np.sin(self._pitch())
        Ry = np.array([[c_, 0.0, s_], [0.0, 1.0, 0.0], [-s_, 0.0, c_]])  # the far side (-x) rises
        return pose_matrix(-s * (Ry @ Rz @ c), Ry @ Rz, (s, s, s))

    def hidden(self) -> dict:
        """{path: transform} that shrinks every moving node away (before the first frame)."""
        return {p: pose_matrix((0.0, 0.0, 0.0), None, (TINY,) * 3) for p in self.moving}

    def _master_q(self, q) -> np.ndarray:
        m = self.master
        if q.shape[0] == m.nq:
            return np.asarray(q, dtype=float)
        if q.shape[0] != m.nv:
            raise ConfigError(f"VizFrame.master_q: expected {m.nq} (pinocchio) or {m.nv} joint values, "
                              f"got {q.shape[0]}")
        out = self.pin.neutral(m)
        for j in range(1, m.njoints):
            jt = m.joints[j]
            x = q[jt.idx_v]
            if jt.nq == 2:
                out[jt.idx_q], out[jt.idx_q + 1] = np.cos(x), np.sin(x)
            else:
                out[jt.idx_q] = x
        return out

    def _slave_q(self, q) -> np.ndarray:
        nq = self.arm.model.nq
        if q.shape[0] > nq:
            raise ConfigError(f"VizFrame.slave_q: the slave model has {nq} joint values, got {q.shape[0]}")
        if q.shape[0] == nq:
            return np.asarray(q, dtype=float)
        out = self.pin.neutral(self.arm.model)  # trailing joints (e.g. locked fingers) stay neutral
        out[: q.shape[0]] = q
        return out

    def states(self, f) -> dict:
        """{path: 4x4 transform} of the moving nodes for frame ``f`` (a VizFrame); nodes whose
        data the frame lacks are left out (they keep their last pose), arrows without a wrench
        are shrunk away."""
        pin, out = self.pin, {}
        ref = f.reference_pose
        if ref is not None:
            out["master/reference"] = pose_matrix(*ref)
            if self.scene.fixture_type == "rolling_disk":
                out["master/contact"] = contact_line_matrix(ref[0], ref[1], self.scene.fixture_params)
        if f.virtual_pose is not None:
            out["master/virtual"] = pose_matrix(*f.virtual_pose)
        handle = f.virtual_pose if f.virtual_pose is not None else ref
        if self.device_parts and f.master_q is not None:
            scaled = pmv.applyScalingOnHomegeneousTransform
            m, d, vm = self.master, self.mdata, self.scene.master_robot.visual_model
            pin.forwardKinematics(m, d, self._master_q(f.master_q))
            pin.updateGeometryPlacements(m, d, vm, self.dgdata)
            for k, path in self.device_parts:
                out[path] = scaled(self.dgdata.oMg[k].homogeneous, vm.geometryObjects[k].meshScale)
            X = pin.updateFramePlacement(m, d, self.handle_fid) if self.handle_fid is not None else d.oMi[m.njoints - 1]
            handle = (X.translation, X.rotation)
            out["master/handle"] = pose_matrix(*handle)
        elif self.master is not None and f.master_q is not None:
            m, d = self.master, self.mdata
            pin.forwardKinematics(m, d, self._master_q(f.master_q))
            for j in range(1, m.njoints):
                a, b = d.oMi[m.parents[j]].translation, d.oMi[j].translation
                out[f"master/device/link{j}"] = segment_matrix(a, b)
                out[f"master/device/joint{j}"] = pose_matrix(b, d.oMi[j].rotation)
            X = d.oMi[m.njoints - 1]
            if self.handle_fid is not None:
                X = pin.updateFramePlacement(m, d, self.handle_fid)
            out["master/device/link_handle"] = segment_matrix(d.oMi[m.njoints - 1].translation, X.translation)
            handle = (X.translation, X.rotation)
            out["master/handle"] = pose_matrix(*handle)
        s = self.scene.force_scale_m_per_N / self.zoom  # m per N on the master side, before the zoom
        head = 0.045 / self.zoom
        for name, w, at in (("operator", f.operator_wrench, handle), ("constraint", f.constraint_wrench, ref)):
            if at is not None:
                shaft, tip = arrow_matrices(at[0], w[:3] if w is not None else np.zeros(3), s, head,
                                            ARROW_MAX_M / self.zoom)
                out[f"master/arrows/{name}/shaft"], out[f"master/arrows/{name}/head"] = shaft, tip
        tool = f.slave_tool_pose
        if self.arm is not None and f.slave_q is not None:
            q = self._slave_q(f.slave_q)
            pin.forwardKinematics(self.arm.model, self.adata, q)
            pin.updateGeometryPlacements(self.arm.model, self.adata, self.arm.visual_model, self.gdata)
            vm = self.arm.visual_model
            for k, path in self.arm_parts:  # as Pinocchio's MeshcatVisualizer poses them
                out[path] = pmv.applyScalingOnHomegeneousTransform(self.gdata.oMg[k].homogeneous,
                                                                   vm.geometryObjects[k].meshScale)
            if tool is None and self.tool_fid is not None:
                X = pin.updateFramePlacement(self.arm.model, self.adata, self.tool_fid)
                tool = (X.translation, X.rotation)
        if tool is not None:
            out["slave/tool"] = pose_matrix(*tool)
            w = f.contact_wrench[:3] if f.contact_wrench is not None else np.zeros(3)
            s_s = self.scene.force_scale_m_per_N / self.slave_zoom
            out["slave/arrows/contact/shaft"], out["slave/arrows/contact/head"] = arrow_matrices(
                tool[0], w, s_s, 0.045 / self.slave_zoom, ARROW_MAX_M / self.slave_zoom)
        self._follow(out, ref, tool)
        if self.trace_master is not None and ref is not None:
            self.trace_master.append(np.asarray(ref[0], dtype=float).copy())
        return out

    def _follow(self, out: dict, ref, tool) -> None:
        """Move each followed side's aim FOLLOW of the way toward its tool; puts the sides'
        transforms in ``out``."""
        for side, at in (("master", ref), ("slave", tool)):
            if side in self.followed and at is not None:
                self.aim[side] = self.aim[side] + FOLLOW * (np.asarray(at[0], dtype=float) - self.aim[side])
                out[side] = self._side_matrix(side)
