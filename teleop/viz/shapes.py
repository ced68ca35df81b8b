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

#: colours (0xRRGGBB). The three force arrows own their hues (green, magenta, red); every other
#: colour is at least ARROW_CONTRAST (CIEDE2000) from each of them, so nothing drawn reads as a
#: force (tests/unit/test_viz_palette.py checks it; docs/viewer.md lists the palette)
COLORS = {
    "operator": 0x10B010,    # operator force arrow, green
    "constraint": 0xC010C0,  # constraint force arrow, magenta
    "contact": 0xE01010,     # tissue contact force arrow, red
    "tool": 0x1A6BE0,        # the reference tool, solid blue
    "ghost": 0x00C8E0,       # the virtual tool, a translucent cyan halo around where the device holds it
    "marker": 0xFFD400,      # the disk's spoke, so rolling shows
    "handle": 0x404040,
    "device": 0x5E6E9A,      # the cobot master device, translucent slate
    "plane": 0x9A9AA0,       # a plane the tool rolls or rests on, grey
    "depth": 0xE0B030,       # where the blade is held: a depth plane or surface, amber
    "sphere": 0x8A9AB4,      # a sphere the tool is held on, blue-grey
    "trocar": 0x505C6E,      # a trocar (remote centre of motion), dark slate
    "contact_line": 0x202020,  # the rolling disk's contact line
    "arm": 0xFF8000,         # the slave arm, orange
    "blade": 0xC8C8D0,
    "tissue": 0xF0C8B0,      # tissue (block or curved surface), peach
    "cut": 0x402018,         # the cut trace, dark brown
    "label": 0x1B2A4A,       # the "master" / "slave" labels, navy
    "trace": 0x3060B0,       # the generic drawing's trace of the tool
    "axis_x": 0x303030,      # the generic drawing's tool axes: x near-black, y grey, z the tool's blue
    "axis_y": 0x8C8C8C,
    "text": 0x202020,        # legend text
    "panel": 0xF8F6EE,       # the opaque card behind the labels and the legend
    "border": 0x8A8A8A,      # its edge
}
#: the force arrows' colours, which nothing else may resemble
ARROW_KEYS = ("operator", "constraint", "contact")
#: the least CIEDE2000 difference between any other colour of COLORS and an arrow's
ARROW_CONTRAST = 25.0
#: drawn after everything else and over it (no depth test): the labels and the legend
ON_TOP = 1000
#: a scale that hides a part without deleting it (arrows with no force, zero-length links)
TINY = 1e-6


def material(color: int, opacity: float = 1.0, **kw) -> g.MeshLambertMaterial:
    """A Lambert material; translucent when opacity < 1 (then it does not write depth)."""
    if opacity < 1.0:
        kw.setdefault("depthWrite", False)
    return g.MeshLambertMaterial(color=color, opacity=opacity, transparent=opacity < 1.0, **kw)


def _rgba(color: int, alpha: int = 255) -> tuple:
    return ((color >> 16) & 255, (color >> 8) & 255, color & 255, alpha)


def sign_png(rows, px: int = 56, panel: bool = True) -> tuple[bytes, float]:
    """A PNG of ``rows`` of items, each row a list of ``("text", text, colour)``, ``("arrow",
    colour, length px)`` (a right-pointing arrow), ``("box", colour)`` (a filled swatch) or
    ``("ring", colour)`` (an outlined swatch), left to right, through Pillow with matplotlib's
    DejaVu Sans (bold, ``px`` tall). ``panel``: on an opaque card (COLORS "panel", edged with
    "border"), else on a transparent ground. Returns (PNG bytes, width / height)."""
    font = ImageFont.truetype(
        font_manager.findfont(font_manager.FontProperties(family="DejaVu Sans", weight="bold")), px)
    row, gap, pad = int(px * 1.3), px // 2, (px // 2 if panel else 12)

    def width(item) -> int:
        kind = item[0]
        if kind == "text":
            return int(font.getbbox(item[1])[2])
        return int(item[2]) if kind == "arrow" else px

    widths = [sum(width(it) for it in items) + gap * max(len(items) - 1, 0) for items in rows]
    img = Image.new("RGBA", (max(widths) + 2 * pad, row * len(rows) + 2 * pad), (255, 255, 255, 0))
    d = ImageDraw.Draw(img)
    if panel:
        edge = max(2, px // 16)
        d.rounded_rectangle([0, 0, img.width - 1, img.height - 1], radius=px // 3, fill=_rgba(COLORS["panel"]),
                            outline=_rgba(COLORS["border"]), width=edge)
    for k, items in enumerate(rows):
        y = pad + k * row
        yc, x = y + row // 2, pad
        for item in items:
            kind, color = item[0], item[-1] if item[0] == "text" else item[1]
            if kind == "text":
                d.text((x, y), item[1], font=font, fill=_rgba(color))
            elif kind == "arrow":
                L = int(item[2])
                d.line([(x, yc), (x + L - px // 3, yc)], fill=_rgba(color), width=max(6, px // 4))
                d.polygon([(x + L, yc), (x + L - px // 3, yc - px // 4), (x + L - px // 3, yc + px // 4)],
                          fill=_rgba(color))
            else:  # a swatch: filled, or outlined (a translucent part)
                s = int(0.7 * px)
                box = [x + (px - s) // 2, yc - s // 2, x + (px + s) // 2, yc + s // 2]
                if kind == "box":
                    d.rectangle(box, fill=_rgba(color))
                else:
                    d.rectangle(box, outline=_rgba(color), width=max(5, px // 8))
            x += width(item) + gap
    buf = io.BytesIO()
    img.save(buf, format="PNG")
    return buf.getvalue(), img.width / img.height


def text_png(lines, px: int = 56, arrows: dict | None = None, panel: bool = False) -> tuple[bytes, float]:
    """A PNG of text ``lines`` [(text, colour)], one per row (:func:`sign_png`); a row whose
    index is in ``arrows`` ({row: (colour, length px)}) starts with an arrow of that colour and
    length. Returns (PNG bytes, width / height)."""
    arrows = arrows or {}
    rows = [([("arrow", *arrows[k])] if k in arrows else []) + [("text", t, c)] for k, (t, c) in enumerate(lines)]
    return sign_png(rows, px, panel)


class OnTop(g.Mesh):
    """A mesh drawn after everything else (three.js ``renderOrder`` ON_TOP): with a material
    that skips the depth test, nothing in the scene covers it, translucent planes included."""

    def lower(self):
        data = super().lower()
        data["object"]["renderOrder"] = ON_TOP
        return data


def sign_part(name: str, rows, height_m: float, panel: bool = True) -> tuple:
    """A flat, camera-facing (layout x right, z up; seen from layout -y) sign of ``rows``
    (:func:`sign_png`) ``height_m`` tall (layout m), drawn on top of everything: (name, meshcat
    object, fixed transform). Anchored at its left edge, vertically centred."""
    png, aspect = sign_png(rows, panel=panel)
    w = height_m * aspect
    tex = g.ImageTexture(g.PngImage(png))
    # front faces only (meshcat's default is both: the mirrored back face would show through);
    # no depth test and drawn last, so the sign stays readable over the arm, the device or a plane
    mat = g.MeshBasicMaterial(map=tex, transparent=True, side=0, depthTest=False, depthWrite=False)
    obj = OnTop(g.Box((w, height_m, 1e-5)), mat)
    # box x, y, z -> layout -x, z, y: the camera (at layout -y) sees the box's -z face, whose
    # texture three.js lays right to left along box x, so the text reads left to right
    R = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    return (name, obj, pose_matrix((0.5 * w, 0.0, 0.0), R))


def text_part(name: str, lines, height_m: float, arrows: dict | None = None, panel: bool = True) -> tuple:
    """:func:`sign_part` of text ``lines`` [(text, colour)] (and ``arrows``, as :func:`text_png`)."""
    rows = [([("arrow", *(arrows or {})[k])] if k in (arrows or {}) else []) + [("text", t, c)]
            for k, (t, c) in enumerate(lines)]
    return sign_part(name, rows, height_m, panel)


def triad_parts(length: float) -> list:
    """A frame triad of ``length`` m (the generic drawing of a tool whose fixture the viewer
    cannot draw): x near-black, y grey, z the tool's blue (no red or green: those are forces)."""
    r = 0.04 * length
    out = []
    for k, (axis, c) in enumerate((((1.0, 0.0, 0.0), COLORS["axis_x"]), ((0.0, 1.0, 0.0), COLORS["axis_y"]),
                                   ((0.0, 0.0, 1.0), COLORS["tool"]))):
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
                  handle_len: float = 0.09, blade_color: int = COLORS["blade"]) -> list:
    """A scalpel whose blade tip is the body point ``tip`` (m): the blade runs back from the tip
    along body -z (body z points into the tissue), wide along x (the cutting direction), thin
    along y; the handle continues it."""
    tip = np.asarray(tip, dtype=float)
    blade = g.Box((0.012, 0.0015, blade_len))
    handle = g.Cylinder(handle_len, 0.005)
    return [
        ("blade", g.Mesh(blade, material(blade_color, opacity)),
         pose_matrix(tip - [0.0, 0.0, 0.5 * blade_len])),
        ("grip", g.Mesh(handle, material(handle_color, opacity)),
         pose_matrix(tip - [0.0, 0.0, blade_len + 0.5 * handle_len], Y_TO_Z)),
    ]


#: the virtual tool's halo: its drawing this much larger than the reference tool's, about its middle
HALO = 1.35


def tool_parts(shape: str, radius: float, tip, ghost: bool, length_m: float = 0.12) -> list:
    """The reference tool (solid blue) or the virtual tool (``ghost``: a translucent cyan halo,
    HALO times the tool's size about its middle, drawn from its back faces, so it shows as a rim
    around the reference tool when the two coincide, and beside it when the device lags) of a
    shape: a disk of ``radius`` (m), a scalpel ``length_m`` long (m, blade and handle) whose blade
    tip is the body point ``tip`` (m), or a box.
    """
    color, opacity = (COLORS["ghost"], 0.4) if ghost else (COLORS["tool"], 1.0)
    if shape == "disk":
        parts = disk_parts(radius, opacity, color)
    elif shape == "scalpel":
        blade = color if ghost else COLORS["blade"]  # the halo all in its one colour
        parts = scalpel_parts(tip, opacity, color, handle_len=length_m - 0.03, blade_color=blade)
    else:
        parts = [("box", g.Mesh(g.Box((0.04, 0.03, 0.02)), material(color, opacity)), np.eye(4))]
    if not ghost:
        return parts
    for _, obj, _ in parts:  # its back faces only: a rim around the tool, which shows unveiled
        obj.material.side = 1
    c = np.mean([M[:3, 3] for _, _, M in parts], axis=0)
    S = pose_matrix(c) @ pose_matrix(scale=(HALO,) * 3) @ pose_matrix(-c)
    return [(n, o, S @ M) for n, o, M in parts]


def plane_part(name: str, origin, normal, size, color: int, opacity: float, R=None) -> tuple:
    """A thin slab whose top face is the plane through ``origin`` with ``normal``: a square of
    ``size`` m, or a ``size`` = (lx, ly) m rectangle; its in-plane axes those of ``R`` (a rotation
    whose z is the normal; default :func:`frame_from_normal`)."""
    n = np.asarray(normal, dtype=float)
    lx, ly = (size, size) if np.isscalar(size) else size
    thin = 0.002 * max(lx, ly)
    M = pose_matrix(np.asarray(origin, dtype=float) - 0.5 * thin * n, frame_from_normal(n) if R is None else R)
    return (name, g.Mesh(g.Box((lx, ly, thin)), material(color, opacity)), M)


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
