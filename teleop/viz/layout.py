"""Where everything goes in the one Meshcat page: the two sides laid out side by side, and the
transforms of the moving parts for each frame. Geometry helpers live in :mod:`teleop.viz.shapes`."""

from __future__ import annotations

import numpy as np
from meshcat import geometry as g

from teleop.viz.shapes import (
    VIEW_HEIGHT_M,
    VIEW_WIDTH_M,
    COLORS,
    TINY,
    Y_TO_Z,
    arrow_matrices,
    arrow_parts,
    contact_line_matrix,
    contact_line_part,
    device_joint_part,
    fixture_parts,
    geometry_shape,
    material,
    pose_matrix,
    scalpel_parts,
    segment_matrix,
    tissue_parts,
    tool_parts,
)

PITCH = np.radians(20.0)


class Drawing:
    """The scene's geometry and layout (owns pinocchio Data workspaces for the device and arm).

    Paths are relative to the scene root. The handle H is drawn with the device (at its "handle"
    frame, else its last joint); without a device the virtual tool is where the hand is. The master side sits around the layout origin,
    magnified by ``zoom`` about its fixture's centre; the slave side is translated by
    ``slave_offset_m``. The root turns the layout so +x runs left to right on the default camera,
    scales it to fill the view and centres it (we aim by moving the root: meshcat 0.3.2 has no
    camera-target call).
    """

    def __init__(self, scene):
        import pinocchio as pin

        self.pin, self.scene = pin, scene
        p = scene.fixture_params
        self.radius = p.get("radius_m", 0.03)
        tip = p.get("tip_m", (0.0, 0.0, 0.0))
        ft = scene.fixture_type
        self.size = {"rolling_disk": max(8.0 * self.radius, 0.1), "sphere": 3.0 * self.radius,
                     "scalpel": 0.12}.get(ft, 0.15)
        self.zoom = scene.master_zoom or float(np.clip(0.6 / self.size, 1.0, 10.0))
        centre = np.asarray(p.get("center_m" if ft == "sphere" else "plane_origin_m", (0.0, 0.0, 0.0)))
        self.fixed = {"master": pose_matrix(-self.zoom * centre, None, (self.zoom,) * 3),
                      "slave": pose_matrix(scene.slave_offset_m)}
        parts = [(f"master/fixture/{n}", o, M) for n, o, M in fixture_parts(ft, p, self.size)]
        for name, ghost in (("reference", False), ("virtual", True)):
            parts += [(f"master/{name}/{n}", o, M) for n, o, M in tool_parts(scene.tool_shape, self.radius, tip, ghost)]
        if ft == "rolling_disk":
            parts += [(f"master/contact/{n}", o, M) for n, o, M in contact_line_part(self.radius)]
        r_m = 0.0015
        for name, r, where in (("operator", r_m, "master"), ("constraint", r_m, "master"), ("contact", 0.004, "slave")):
            parts += [(f"{where}/arrows/{name}/{n}", o, M) for n, o, M in arrow_parts(r, COLORS[name])]
        parts += [(f"slave/tool/{n}", o, M) for n, o, M in scalpel_parts((0, 0, 0), 1.0, COLORS["tool"])]
        if scene.tissue is not None:
            parts += [(f"slave/tissue/{n}", o, M) for n, o, M in tissue_parts(scene.tissue)]
        self.master = scene.master_model
        if self.master is not None:
            m = self.master
            self.mdata = m.createData()
            self.handle_fid = m.getFrameId("handle") if m.existFrame("handle") else None
            for j in range(1, m.njoints):
                parts.append((f"master/device/link{j}", g.Mesh(g.Cylinder(1.0, 0.004), material(COLORS["device"])), np.eye(4)))
                o, M = device_joint_part(j, m.joints[j])
                parts.append((f"master/device/joint{j}/marker", o, M))
            parts.append(("master/device/link_handle", g.Mesh(g.Cylinder(1.0, 0.004), material(COLORS["device"])), np.eye(4)))
            knob, grip = g.Sphere(0.006), g.Cylinder(0.05, 0.004)  # the handle H: knob at H, grip along -z
            parts += [("master/handle/knob", g.Mesh(knob, material(COLORS["handle"])), np.eye(4)),
                      ("master/handle/grip", g.Mesh(grip, material(COLORS["handle"])), pose_matrix((0, 0, -0.025), Y_TO_Z))]
        self.arm = scene.slave_robot
        self.arm_parts = []
        if self.arm is not None:
            self.adata = self.arm.model.createData()
            self.gdata = pin.GeometryData(self.arm.visual_model)
            for k, gobj in enumerate(self.arm.visual_model.geometryObjects):
                shape = geometry_shape(gobj, scene.mesh_cell_m, COLORS["arm"])
                if shape is not None:
                    self.arm_parts.append((k, f"slave/arm/{gobj.name}"))
                    parts.append((f"slave/arm/{gobj.name}/shape", *shape))
            self.tool_fid = (self.arm.model.getFrameId(scene.slave_tool_frame)
                             if scene.slave_tool_frame is not None else None)
        self.parts = parts
        self.fixed["root"] = self._root_matrix()
        # nodes that move: hidden until a frame places them
        groups = {p.rsplit("/", 1)[0] for p, _, _ in parts}
        self.moving = sorted(p for p, _, _ in parts if "/arrows/" in p)
        self.moving += sorted(p for p in groups if p.split("/")[1] in ("reference", "virtual", "contact", "handle", "tool")
                              or p.startswith("slave/arm/"))
        self.moving += sorted(p for p, _, _ in parts if p.startswith("master/device/link"))
        self.moving += sorted(p for p in groups if p.startswith("master/device/joint"))

    def _root_matrix(self) -> np.ndarray:
        h = 0.5 * self.zoom * self.size
        xs, zs = [-h, h], [-h, h]
        off = np.asarray(self.scene.slave_offset_m)
        if self.arm is not None:
            xs += [off[0] - 0.3, off[0] + 0.9]
            zs += [off[2], off[2] + 1.0]
        if self.scene.tissue is not None:
            o, half = off + self.scene.tissue["origin_m"], 0.5 * max(self.scene.tissue["size_m"])
            xs += [o[0] - half, o[0] + half]
            zs += [o[2] - half, o[2] + half]
        c = np.array([0.5 * (min(xs) + max(xs)), 0.0, 0.5 * (min(zs) + max(zs))])
        s = min(0.8 * VIEW_WIDTH_M / (max(xs) - min(xs)), 0.75 * VIEW_HEIGHT_M / (max(zs) - min(zs)))
        Rz = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # layout +x -> screen right
        c_, s_ = np.cos(PITCH), np.sin(PITCH)
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
            from teleop.errors import ConfigError
            raise ConfigError(f"VizFrame.master_q: expected {m.nq} (pinocchio) or {m.nv} joint values, got {q.shape[0]}")
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
            from teleop.errors import ConfigError
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
        if self.master is not None and f.master_q is not None:
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
        s, head = self.scene.force_scale_m_per_N, 0.009
        for name, w, at in (("operator", f.operator_wrench, handle), ("constraint", f.constraint_wrench, ref)):
            if at is not None:
                shaft, tip = arrow_matrices(at[0], w[:3] if w is not None else np.zeros(3), s, head, 0.5 * self.size)
                out[f"master/arrows/{name}/shaft"], out[f"master/arrows/{name}/head"] = shaft, tip
        tool = f.slave_tool_pose
        if self.arm is not None and f.slave_q is not None:
            q = self._slave_q(f.slave_q)
            pin.forwardKinematics(self.arm.model, self.adata, q)
            pin.updateGeometryPlacements(self.arm.model, self.adata, self.arm.visual_model, self.gdata)
            for k, path in self.arm_parts:
                X = self.gdata.oMg[k]
                out[path] = pose_matrix(X.translation, X.rotation)
            if tool is None and self.tool_fid is not None:
                X = pin.updateFramePlacement(self.arm.model, self.adata, self.tool_fid)
                tool = (X.translation, X.rotation)
        if tool is not None:
            out["slave/tool"] = pose_matrix(*tool)
            w = f.contact_wrench[:3] if f.contact_wrench is not None else np.zeros(3)
            out["slave/arrows/contact/shaft"], out["slave/arrows/contact/head"] = arrow_matrices(tool[0], w, s, 0.024)
        return out
