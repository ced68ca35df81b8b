"""Geometry helpers for the Meshcat view: transforms, tools, fixtures, force arrows, meshes.

Pure functions. Parts are returned as ``(subpath, meshcat object, fixed 4x4 transform)``: the
object is set once under a moving parent node, with the fixed transform on its own node, so a
frame only moves parents. Three.js cylinders have their axis along y; a unit cylinder (height 1 m)
scaled along y draws a segment or an arrow shaft. Lengths in m, colours 0xRRGGBB.
"""

from __future__ import annotations

import io

import numpy as np
import pinocchio as pin
from matplotlib import font_manager
from meshcat import geometry as g
from PIL import Image, ImageDraw, ImageFont

from teleop.dynamics.registry import FrameMap
from teleop.util.errors import ConfigError

#: colours, chosen to be told apart in a screenshot (see tests/integration/test_browser_render.py)
COLORS = {
    "tool": 0x1F4FFF,        # the reference tool, solid blue
    "ghost": 0x33CCFF,       # the virtual tool, translucent cyan
    "marker": 0xFFD400,      # the disk's spoke, so rolling shows
    "handle": 0x404040,
    "device": 0x6A4FC8,      # the cobot master device, violet
    "plane": 0x9A9AA0,
    "depth": 0xE0B030,
    "sphere": 0x50B070,
    "contact_line": 0xD02020,
    "operator": 0x10B010,    # operator force arrow, green
    "constraint": 0xC010C0,  # constraint force arrow, magenta
    "contact": 0xE01010,     # tissue contact force arrow, red
    "arm": 0xFF8000,         # the slave arm, orange
    "blade": 0xC8C8D0,
    "tissue": 0xF04890,      # the tissue block, pink
    "cut": 0x600000,
    "label": 0x00A070,       # the "master" / "slave" labels, sea green
    "trace": 0x3050A0,       # the generic drawing's trace of the tool
    "text": 0x202020,        # legend text
}
#: a scale that hides a part without deleting it (arrows with no force, zero-length links)
TINY = 1e-6


def material(color: int, opacity: float = 1.0, **kw) -> g.MeshLambertMaterial:
    """A Lambert material; translucent when opacity < 1 (then it does not write depth)."""
    if opacity < 1.0:
        kw.setdefault("depthWrite", False)
    return g.MeshLambertMaterial(color=color, opacity=opacity, transparent=opacity < 1.0, **kw)


def text_png(lines, px: int = 56, pad: int = 12, arrows: dict | None = None) -> tuple[bytes, float]:
    """A transparent PNG of text ``lines`` [(text, colour)], one per row, through Pillow with
    matplotlib's DejaVu Sans; a row whose key is in ``arrows`` ({row: (colour, length px)}) starts
    with an arrow of that colour and length. Returns (PNG bytes, width / height)."""
    font = ImageFont.truetype(
        font_manager.findfont(font_manager.FontProperties(family="DejaVu Sans", weight="bold")), px)
    arrows = arrows or {}
    lead = {k: int(v[1]) + px // 2 for k, v in arrows.items()}
    widths = [font.getbbox(t)[2] + lead.get(k, 0) for k, (t, _) in enumerate(lines)]
    row = int(px * 1.3)
    img = Image.new("RGBA", (max(widths) + 2 * pad, row * len(lines) + 2 * pad), (255, 255, 255, 0))
    d = ImageDraw.Draw(img)
    for k, (text, color) in enumerate(lines):
        y = pad + k * row
        x = pad
        if k in arrows:
            c, L = arrows[k]
            rgb = ((c >> 16) & 255, (c >> 8) & 255, c & 255, 255)
            yc = y + row // 2
            d.line([(x, yc), (x + L - px // 3, yc)], fill=rgb, width=max(4, px // 4))
            d.polygon([(x + L, yc), (x + L - px // 3, yc - px // 5), (x + L - px // 3, yc + px // 5)], fill=rgb)
            x += lead[k]
        d.text((x, y), text, font=font, fill=((color >> 16) & 255, (color >> 8) & 255, color & 255, 255))
    buf = io.BytesIO()
    img.save(buf, format="PNG")
    return buf.getvalue(), img.width / img.height


def text_part(name: str, lines, height_m: float, arrows: dict | None = None) -> tuple:
    """A flat, camera-facing (layout x right, z up; seen from layout -y) sign of ``lines`` of
    text ``height_m`` tall (layout m): (name, meshcat object, fixed transform). Anchored at its
    left edge, vertically centred."""
    png, aspect = text_png(lines, arrows=arrows)
    w = height_m * aspect
    tex = g.ImageTexture(g.PngImage(png))
    # front faces only (meshcat's default is both: the mirrored back face would show through);
    # no depth test, so the text stays readable in front of the arm or the device
    mat = g.MeshBasicMaterial(map=tex, transparent=True, side=0, depthTest=False)
    obj = g.Mesh(g.Box((w, height_m, 1e-5)), mat)
    # box x, y, z -> layout -x, z, y: the camera (at layout -y) sees the box's -z face, whose
    # texture three.js lays right to left along box x, so the text reads left to right
    R = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    return (name, obj, pose_matrix((0.5 * w, 0.0, 0.0), R))


def triad_parts(length: float) -> list:
    """A frame triad: x red, y green, z blue unit-ish axes of ``length`` m (the generic drawing of
    a tool whose fixture has no drawing of its own)."""
    r = 0.04 * length
    out = []
    for k, (axis, c) in enumerate((((1.0, 0.0, 0.0), 0xE02020), ((0.0, 1.0, 0.0), 0x20A020),
                                   ((0.0, 0.0, 1.0), 0x2040E0))):
        out.append((f"axis{k}", g.Mesh(g.Cylinder(1.0, r), material(c)),
                    segment_matrix((0.0, 0.0, 0.0), np.asarray(axis) * length)))
    return out


def pose_matrix(p=(0.0, 0.0, 0.0), R=None, scale=(1.0, 1.0, 1.0)) -> np.ndarray:
    """4x4 homogeneous transform: translation p (m), rotation R, then per-axis scale."""
    M = np.eye(4)
    if R is not None:
        M[:3, :3] = R
    M[:3, :3] = M[:3, :3] * np.asarray(scale, dtype=float)
    M[:3, 3] = p
    return M


def rotation_between(a, b) -> np.ndarray:
    """The smallest rotation taking direction a onto direction b (Eigen's
    ``Quaternion::FromTwoVectors`` through Pinocchio; a half turn when they are opposite).
    Tested against scipy's ``Rotation.align_vectors``, which is 90x slower here (1.9 ms against
    21 µs a call, measured; called for every arrow of every frame). Near opposite directions
    Eigen's quaternion is not unit (1 + a.b cancels: R^T R off by 1e-5 a hair from opposite), so
    it is normalised; it then maps a onto b to ~3e-6 there, to round-off elsewhere."""
    a = np.asarray(a, dtype=float) / np.linalg.norm(a)
    b = np.asarray(b, dtype=float) / np.linalg.norm(b)
    q = pin.Quaternion.FromTwoVectors(a, b)
    q.normalize()
    return q.matrix()


def frame_from_normal(n) -> np.ndarray:
    """A rotation whose z axis is the unit normal n (its x axis is as close to world x as can be)."""
    return rotation_between((0.0, 0.0, 1.0), n)


Y_TO_Z = rotation_between((0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


def segment_matrix(a, b) -> np.ndarray:
    """Transform of a unit cylinder (1 m along y, centred) drawn from point a to point b (m)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    d = b - a
    L = float(np.linalg.norm(d))
    if L < 1e-6:
        return pose_matrix(a, None, (TINY, TINY, TINY))
    return pose_matrix(0.5 * (a + b), rotation_between((0.0, 1.0, 0.0), d / L), (1.0, L, 1.0))


def arrow_matrices(origin, vector, m_per_unit: float, head_m: float, max_m: float = 0.3):
    """(shaft, head) transforms of an arrow from ``origin`` along ``vector`` (e.g. a force in N),
    ``m_per_unit`` m per unit of the vector, capped at ``max_m``; hidden when the vector is ~0."""
    v = np.asarray(vector, dtype=float)
    n = float(np.linalg.norm(v))
    L = min(n * m_per_unit, max_m)
    if L < 1e-5:
        hidden = pose_matrix(origin, None, (TINY, TINY, TINY))
        return hidden, hidden
    d = v / n
    R = rotation_between((0.0, 1.0, 0.0), d)
    o = np.asarray(origin, dtype=float)
    return (pose_matrix(o + 0.5 * L * d, R, (1.0, L, 1.0)),
            pose_matrix(o + (L + 0.5 * head_m) * d, R))


def arrow_parts(radius: float, color: int) -> list:
    """A unit shaft (radius m) and a cone head (3 radius wide, 6 radius long) along +y."""
    head = g.Cylinder(6.0 * radius, radiusTop=0.0, radiusBottom=2.5 * radius)
    return [("shaft", g.Mesh(g.Cylinder(1.0, radius), material(color)), np.eye(4)),
            ("head", g.Mesh(head, material(color)), np.eye(4))]


def disk_parts(radius: float, opacity: float, color: int) -> list:
    """An upright disk: axle along body z, 0.15 radius thick, with a spoke along body x."""
    rot = pose_matrix(R=Y_TO_Z)
    t = 0.15 * radius
    parts = [("disk", g.Mesh(g.Cylinder(t, radius), material(color, opacity)), rot)]
    if opacity >= 1.0:
        spoke = g.Box((0.9 * radius, 0.12 * radius, 1.2 * t))
        parts.append(("spoke", g.Mesh(spoke, material(COLORS["marker"])), pose_matrix((0.45 * radius, 0.0, 0.0))))
    return parts


def scalpel_parts(tip, opacity: float, handle_color: int, blade_len: float = 0.03,
                  handle_len: float = 0.09) -> list:
    """A scalpel whose blade tip is the body point ``tip`` (m): the blade runs back from the tip
    along body -z (body z points into the tissue), wide along x (the cutting direction), thin
    along y; the handle continues it."""
    tip = np.asarray(tip, dtype=float)
    blade = g.Box((0.012, 0.0015, blade_len))
    handle = g.Cylinder(handle_len, 0.005)
    return [
        ("blade", g.Mesh(blade, material(COLORS["blade"], opacity)),
         pose_matrix(tip - [0.0, 0.0, 0.5 * blade_len])),
        ("grip", g.Mesh(handle, material(handle_color, opacity)),
         pose_matrix(tip - [0.0, 0.0, blade_len + 0.5 * handle_len], Y_TO_Z)),
    ]


def tool_parts(shape: str, radius: float, tip, ghost: bool) -> list:
    """The reference tool (solid) or the virtual tool (``ghost``: translucent) of a shape."""
    color, opacity = (COLORS["ghost"], 0.35) if ghost else (COLORS["tool"], 1.0)
    if shape == "disk":
        return disk_parts(radius, opacity, color)
    if shape == "scalpel":
        return scalpel_parts(tip, opacity, color)
    return [("box", g.Mesh(g.Box((0.04, 0.03, 0.02)), material(color, opacity)), np.eye(4))]


def plane_part(name: str, origin, normal, size: float, color: int, opacity: float) -> tuple:
    """A thin square slab (size m) whose top face is the plane through origin with normal."""
    n = np.asarray(normal, dtype=float)
    thin = 0.002 * size
    M = pose_matrix(np.asarray(origin, dtype=float) - 0.5 * thin * n, frame_from_normal(n))
    return (name, g.Mesh(g.Box((size, size, thin)), material(color, opacity)), M)


def fixture_parts(fixture_type: str, params: dict, size: float) -> list:
    """The static geometry of a fixture on the master side (m): the rolling plane, the sphere
    (translucent with a wireframe), or the tissue plane and the blade's depth plane."""
    if fixture_type == "rolling_disk":
        return [plane_part("plane", params.get("plane_origin_m", (0, 0, 0)),
                           params.get("plane_normal", (0, 0, 1)), size, COLORS["plane"], 0.6)]
    if fixture_type == "sphere":
        c, r = params.get("center_m", (0.0, 0.0, 0.0)), params.get("radius_m", 0.05)
        M = pose_matrix(c)
        return [("sphere", g.Mesh(g.Sphere(r), material(COLORS["sphere"], 0.3)), M),
                ("wire", g.Mesh(g.Sphere(r), g.MeshBasicMaterial(color=COLORS["sphere"], wireframe=True)), M)]
    if fixture_type == "scalpel":
        o = np.asarray(params.get("plane_origin_m", (0.0, 0.0, 0.0)), dtype=float)
        n = np.asarray(params.get("plane_normal", (0.0, 0.0, 1.0)), dtype=float)
        d = params.get("depth_m", 0.005)
        return [plane_part("tissue_plane", o, n, size, COLORS["tissue"], 0.35),
                plane_part("depth_plane", o - d * n, n, size, COLORS["depth"], 0.35)]
    return []


#: fixture types drawn by :func:`fixture_parts`; any other is a user's (see custom_fixture_parts)
FIXTURE_DRAWN = ("free", "rolling_disk", "sphere", "scalpel")


def custom_fixture_parts(fixture, frame=None) -> list:
    """A user's fixture type's own drawing, the one small protocol the viewer asks of it: a
    method ``draw(frame)`` returning an iterable of ``(name, meshcat object, 4x4 transform)``
    (m, in the frame ``frame`` maps the patient frame into: a
    :class:`teleop.dynamics.registry.FrameMap`, the master workspace for the master side), the
    same map its ``build(frame)`` uses. A fixture without ``draw`` gets nothing here: the view
    then draws the tool's frame triad and the trace of its path instead."""
    draw = getattr(fixture, "draw", None)
    if draw is None:
        return []
    if frame is None:
        frame = FrameMap.identity()
    out = []
    for k, item in enumerate(draw(frame)):
        try:
            name, obj, M = item
            M = np.asarray(M, dtype=float).reshape(4, 4)
        except (TypeError, ValueError):
            raise ConfigError(f"{type(fixture).__name__}.draw: item {k} is not "
                              "(name, meshcat object, 4x4 transform)") from None
        out.append((str(name), obj, M))
    return out


def contact_line_part(radius: float) -> tuple:
    """The rolling disk's contact line: a segment along local x through the contact point."""
    pts = np.array([[-1.5 * radius, 0.0, 0.0], [1.5 * radius, 0.0, 0.0]], dtype=np.float32).T
    obj = g.LineSegments(g.PointsGeometry(pts), g.LineBasicMaterial(color=COLORS["contact_line"]))
    dot = g.Mesh(g.Sphere(0.08 * radius), material(COLORS["contact_line"]))
    return [("line", obj, np.eye(4)), ("dot", dot, np.eye(4))]


def contact_line_matrix(p, R, params: dict) -> np.ndarray:
    """Pose of the contact line for a disk at (p, R): at the contact point on the plane, local x
    along the rolling direction (axle x normal), local z along the plane normal."""
    n = np.asarray(params.get("plane_normal", (0.0, 0.0, 1.0)), dtype=float)
    o = np.asarray(params.get("plane_origin_m", (0.0, 0.0, 0.0)), dtype=float)
    c = p - (float((p - o) @ n)) * n
    heading = np.cross(R[:, 2], n)
    if np.linalg.norm(heading) < 1e-9:
        heading = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    x = heading / np.linalg.norm(heading)
    return pose_matrix(c, np.column_stack([x, np.cross(n, x), n]))


def tissue_parts(tissue: dict) -> list:
    """A tissue block (translucent, so a cut below the surface shows): top face on the plane."""
    n = np.asarray(tissue["normal"], dtype=float)
    lx, ly = tissue["size_m"]
    t = tissue["thickness_m"]
    M = pose_matrix(np.asarray(tissue["origin_m"], dtype=float) - 0.5 * t * n, frame_from_normal(n))
    return [("block", g.Mesh(g.Box((lx, ly, t)), material(COLORS["tissue"], 0.75)), M)]


def polyline(points, color: int = COLORS["cut"]) -> g.Line:
    """A line strip through (n, 3) points (m)."""
    pts = np.ascontiguousarray(np.asarray(points, dtype=np.float32).T)
    return g.Line(g.PointsGeometry(pts), g.LineBasicMaterial(color=color))


def joint_axis(joint) -> np.ndarray:
    """The axis (in the joint frame) of a one-axis pinocchio joint, z when not known."""
    name = joint.shortname()
    last = name[-1] if name else "Z"
    return {"X": np.array([1.0, 0.0, 0.0]), "Y": np.array([0.0, 1.0, 0.0])}.get(last, np.array([0.0, 0.0, 1.0]))


def device_joint_part(k: int, joint) -> tuple:
    """A marker for device joint k: a block for a prismatic joint, a ring-like disc (smaller for
    later joints, so a wrist whose axes meet stays readable) along a revolute joint's axis."""
    name = joint.shortname()
    mat = material(COLORS["device"])
    if "JointModelP" in name:
        return g.Mesh(g.Box((0.02, 0.02, 0.02)), mat), np.eye(4)
    r = max(0.006, 0.02 - 0.003 * k)
    return g.Mesh(g.Cylinder(0.004, r), mat), pose_matrix(R=rotation_between((0.0, 1.0, 0.0), joint_axis(joint)))


# --------------------------------------------------------------------------------------------
# The whole scene: its static parts, its layout, and the poses of its moving nodes for a frame.
# --------------------------------------------------------------------------------------------

#: the meshcat default camera sits at (3, 0, 1) m looking at the origin, 75 deg vertical field of
#: view: the visible height at the origin is about 4.85 m, the width about 8.6 m at 16:9
VIEW_HEIGHT_M, VIEW_WIDTH_M = 4.85, 8.6
#: the layout is tipped toward the camera by this much (rad), so planes are seen from above
