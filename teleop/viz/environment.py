"""What a side's fixture and environment look like, drawn from their own geometry.

A fixture is drawn from the constraints it is built of (a :class:`teleop.dynamics.fixtures.Fixture`,
as the reference tool and the slave's QP get it), whatever its type or scene file. Each kind of
constraint that has a place in space draws it (m, in the frame the fixture was built in):

==========================  ===================================================================
constraint                  drawn as
==========================  ===================================================================
``PlaneHeight``             the plane the tool rests or rolls on (grey slab)
``PointDepth``              the surface plane (left out where the tissue block's top is that
                            plane) and the depth plane the blade tip is held on (amber)
``SphereContact``           the sphere (translucent, with a wireframe)
``RemoteCenter``            the trocar: a translucent port around the pivot, along the surface's
                            normal, and the pivot point
``SurfaceDepth``            the curved surface (a mesh of its height field, closed down to its
                            base plane) and the surface the blade tip is held on, ``depth`` below it
==========================  ===================================================================

Constraints that rule only the tool's motion or orientation (``KnifeEdge``, ``AxisAlong``,
``AxisInPlane``, ``RollingWithoutSlip``) have nothing to draw. Another kind (a user's) is not
guessed at: :func:`fixture_parts` returns it as undrawn, and the view says so once and draws the
tool's frame triad and path. A fixture type with a ``draw(frame)`` method draws itself instead
(:func:`custom_fixture_parts`).

The environment is the tissue: a translucent block whose top face is its surface, drawn on both
sides (at the master through the registration's map, :func:`mapped_tissue`).
"""

from __future__ import annotations

import logging

import numpy as np
from meshcat import geometry as g

from teleop.dynamics import constraints as C
from teleop.dynamics import fixtures as F
from teleop.dynamics.registry import FrameMap
from teleop.dynamics.surface_fixture import SurfaceDepth
from teleop.util.errors import ConfigError
from teleop.viz.shapes import COLORS, frame_from_normal, material, plane_part, pose_matrix, rotation_between

log = logging.getLogger(__name__)

#: constraints with no place in space to draw: they rule the tool's motion or orientation only
MOTION_ONLY = (C.KnifeEdge, C.AxisAlong, C.AxisInPlane, C.RollingWithoutSlip)
#: the legend's words for what a fixture drew: key -> (text, colour)
LEGEND = {
    "tissue": ("tissue", COLORS["tissue"]),
    "plane": ("fixture plane", COLORS["plane"]),
    "depth": ("blade depth (fixture)", COLORS["depth"]),
    "sphere": ("fixture sphere", COLORS["sphere"]),
    "trocar": ("trocar (fixed pivot)", COLORS["trocar"]),
}
#: samples of a curved surface's mesh along its grid's longer side
SURFACE_SAMPLES = 48


def built_in_fixture(fixture_type: str, params: dict) -> F.Fixture:
    """The built-in fixture of a type and its parameters (a ``VizScene``'s ``fixture_params``:
    FixtureSpec fields, SI; defaults as the scene format's), as the reference tool gets it."""
    o, n = params.get("plane_origin_m", (0.0, 0.0, 0.0)), params.get("plane_normal", (0.0, 0.0, 1.0))
    if fixture_type == "rolling_disk":
        return F.rolling_disk(params.get("radius_m", 0.03), o, n)
    if fixture_type == "sphere":
        return F.sphere(params.get("center_m", (0.0, 0.0, 0.0)), params.get("radius_m", 0.05))
    if fixture_type == "scalpel":
        depth, tip = params.get("depth_m", 0.005), params.get("tip_m", (0.0, 0.0, 0.0))
        if params.get("trocar_m") is not None:
            return F.laparoscopic(o, n, depth, tip, params["trocar_m"])
        return F.scalpel(o, n, depth, tip)
    return F.free()


def tool_shape_for(constraints, has_slave: bool) -> str:
    """The drawn tool (teleop.viz.frames.TOOL_SHAPES) for a fixture's constraints: a disk on a
    plane or a sphere, a scalpel for a blade (held at a depth, on a knife edge or through a
    trocar) or wherever a slave cuts with it, else a box."""
    kinds = tuple(type(c) for c in constraints)
    if any(issubclass(k, (C.RollingWithoutSlip, C.AxisInPlane, C.SphereContact)) for k in kinds):
        return "disk"
    if has_slave or any(issubclass(k, (C.PointDepth, C.KnifeEdge, C.RemoteCenter, SurfaceDepth)) for k in kinds):
        return "scalpel"
    return "box"


#: a drawn scalpel's length (m: blade and handle), unless it must reach through a trocar
TOOL_LENGTH_M = 0.12


def shaft_length(constraints) -> float:
    """How long to draw a scalpel (m) held by ``constraints``: TOOL_LENGTH_M, or long enough to
    pass through a trocar (``RemoteCenter``) with a third of its length above it, the tip held on
    a depth plane (``PointDepth``: the pivot's height above that plane) or else at the pivot's
    distance from the plane's origin."""
    length = TOOL_LENGTH_M
    planes = [c for c in constraints if isinstance(c, C.PointDepth)]
    for c in constraints:
        if isinstance(c, C.RemoteCenter):
            if planes:
                p = planes[0]
                reach = float(p.normal @ (c.center - p.origin)) + p.depth
            else:
                reach = float(np.linalg.norm(c.center))
            length = max(length, 1.5 * reach)
    return length


def tissue_rotation(tissue: dict, frame: FrameMap | None = None) -> np.ndarray:
    """The tissue block's axes (z its surface's outward normal), carried by ``frame``'s rotation."""
    R = frame_from_normal(tissue["normal"])
    return R if frame is None else frame.R @ R


def mapped_tissue(tissue: dict, frame: FrameMap) -> dict:
    """The tissue block as the master side draws it: where ``frame`` (the registration's map)
    puts the slave's, scaled with it."""
    return {"origin_m": tuple(frame.point(tissue["origin_m"])), "normal": tuple(frame.direction(tissue["normal"])),
            "size_m": tuple(frame.length(x) for x in tissue["size_m"]),
            "thickness_m": frame.length(tissue["thickness_m"])}


def tissue_parts(tissue: dict, R=None) -> list:
    """A tissue block (translucent, so a cut below the surface shows): top face on its surface;
    its axes those of ``R`` (default :func:`tissue_rotation`)."""
    n = np.asarray(tissue["normal"], dtype=float)
    lx, ly = tissue["size_m"]
    t = tissue["thickness_m"]
    M = pose_matrix(np.asarray(tissue["origin_m"], dtype=float) - 0.5 * t * n,
                    tissue_rotation(tissue) if R is None else R)
    return [("block", g.Mesh(g.Box((lx, ly, t)), material(COLORS["tissue"], 0.75)), M)]


def _on_plane(tissue: dict | None, origin, normal) -> bool:
    """True when the tissue block's top face lies in the plane (origin, normal)."""
    if tissue is None:
        return False
    n_t, n = np.asarray(tissue["normal"], dtype=float), np.asarray(normal, dtype=float)
    gap = abs(float(n @ (np.asarray(tissue["origin_m"], dtype=float) - np.asarray(origin, dtype=float))))
    return abs(float(n_t @ n)) > 1.0 - 1e-9 and gap < 1e-6 * max(tissue["size_m"])


def _plane_shape(tissue: dict | None, R_tissue, normal, size_m: float):
    """(size, R) of a plane drawn with normal ``normal``: the tissue block's footprint (a hair
    inside it) and axes when the plane is parallel to its surface, else a ``size_m`` square."""
    if tissue is not None and abs(float(np.dot(tissue["normal"], normal))) > 1.0 - 1e-9:
        R = R_tissue if float(np.dot(tissue["normal"], normal)) > 0 else R_tissue @ np.diag([1.0, -1.0, -1.0])
        return tuple(0.98 * np.asarray(tissue["size_m"])), R
    return size_m, None


def height_field_parts(surface, depth: float, samples: int = SURFACE_SAMPLES) -> list:
    """A curved surface (a :class:`teleop.dynamics.surface.HeightSurface`) as two meshes over its
    grid: the surface itself, closed by walls down to its base plane (the height field's zero, m),
    and the surface ``depth`` m below it along its normal (where a blade tip is held)."""
    x0, x1, y0, y1 = surface.bounds
    nu = max(8, samples if x1 - x0 >= y1 - y0 else round(samples * (x1 - x0) / (y1 - y0)))
    nv = max(8, samples if y1 - y0 >= x1 - x0 else round(samples * (y1 - y0) / (x1 - x0)))
    u, v = np.linspace(x0, x1, nu), np.linspace(y0, y1, nv)
    U, V = np.meshgrid(u, v, indexing="ij")
    f = surface.spline(u, v)
    fu, fv = surface.spline(u, v, dx=1), surface.spline(u, v, dy=1)
    kQ = surface.k * surface.Q

    def world(a, b, c):  # height-field coordinates (nu, nv) each -> world points (nu * nv, 3)
        return surface.o + np.stack([a.ravel(), b.ravel(), c.ravel()], axis=1) @ kQ.T

    top = world(U, V, f)
    Su = np.stack([np.ones_like(fu), np.zeros_like(fu), fu], axis=-1).reshape(-1, 3) @ kQ.T
    Sv = np.stack([np.zeros_like(fv), np.ones_like(fv), fv], axis=-1).reshape(-1, 3) @ kQ.T
    n = np.cross(Su, Sv)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    faces = _grid_faces(nu, nv)
    ring = np.r_[[(i, 0) for i in range(nu)], [(nu - 1, j) for j in range(1, nv)],
                 [(i, nv - 1) for i in range(nu - 2, -1, -1)], [(0, j) for j in range(nv - 2, 0, -1)]]
    rim = top[ring[:, 0] * nv + ring[:, 1]]
    base = world(U.ravel()[ring[:, 0] * nv + ring[:, 1]], V.ravel()[ring[:, 0] * nv + ring[:, 1]],
                 np.zeros(len(ring)))
    m = len(ring)
    k = np.arange(m)
    walls = np.r_[np.c_[k, (k + 1) % m, m + k], np.c_[(k + 1) % m, m + (k + 1) % m, m + k]]
    skin = g.TriangularMeshGeometry(np.r_[top, rim, base], np.r_[faces, walls + len(top)])
    under = g.TriangularMeshGeometry(top - depth * n, faces)
    return [("surface", g.Mesh(skin, material(COLORS["tissue"], 0.75)), np.eye(4)),
            ("depth_surface", g.Mesh(under, material(COLORS["depth"], 0.45)), np.eye(4))]


def _grid_faces(nu: int, nv: int) -> np.ndarray:
    """Two triangles per cell of an nu x nv vertex grid (row-major, index i * nv + j)."""
    i, j = np.meshgrid(np.arange(nu - 1), np.arange(nv - 1), indexing="ij")
    a = (i * nv + j).ravel()
    return np.r_[np.c_[a, a + nv, a + 1], np.c_[a + 1, a + nv, a + nv + 1]]


def trocar_parts(center, axis, extent_m: float) -> list:
    """A trocar at ``center`` (m): a translucent port (a short tube along ``axis``, the surface's
    normal) the tool's shaft shows through, and the pivot point itself; sized by the side's
    ``extent_m`` (m)."""
    R = rotation_between((0.0, 1.0, 0.0), axis)  # three.js cylinders run along y
    port = g.Cylinder(0.12 * extent_m, 0.08 * extent_m)
    return [("trocar_port", g.Mesh(port, material(COLORS["trocar"], 0.55)), pose_matrix(center, R)),
            ("trocar_pivot", g.Mesh(g.Sphere(0.02 * extent_m), material(COLORS["trocar"])), pose_matrix(center))]


def _surface_normal(constraints, tissue: dict | None) -> np.ndarray:
    """The up direction of a fixture's surface (a plane's normal, a curved surface's frame),
    else the tissue's, else world z: the way a trocar's port points."""
    for c in constraints:
        if isinstance(c, (C.PointDepth, C.PlaneHeight)):
            return np.asarray(c.normal, dtype=float)
        if isinstance(c, SurfaceDepth):
            return np.asarray(c.surface.Q[:, 2], dtype=float)
    return np.asarray(tissue["normal"] if tissue is not None else (0.0, 0.0, 1.0), dtype=float)


def fixture_parts(constraints, plane_m: float, extent_m: float, tissue: dict | None = None,
                  R_tissue=None) -> tuple[list, list, list]:
    """The drawing of a fixture's ``constraints`` (see the module docstring), in their frame (m):
    planes ``plane_m`` m square (or the ``tissue`` block's footprint when parallel to it), the
    trocar sized by ``extent_m``. Returns (parts [(name, meshcat object, 4x4)], legend keys of
    LEGEND in the order drawn, the constraints it cannot draw)."""
    parts: list = []
    legend: list = []
    undrawn: list = []
    R_t = None if tissue is None else (tissue_rotation(tissue) if R_tissue is None else R_tissue)

    def add(*drawn):  # parts named by what they are; a second of a name gets a number
        names = {p[0] for p in parts}
        for name, obj, M in drawn:
            k, unique = 1, name
            while unique in names:
                k, unique = k + 1, f"{name}{k + 1}"
            parts.append((unique, obj, M))
            names.add(unique)

    def plane(name, key, origin, normal, color, opacity):
        size, R = _plane_shape(tissue, R_t, normal, plane_m)
        add(plane_part(name, origin, normal, size, color, opacity, R))
        legend.append(key)

    for c in constraints:
        if isinstance(c, C.PlaneHeight):
            plane("plane", "plane", c.origin, c.normal, COLORS["plane"], 0.6)
        elif isinstance(c, C.PointDepth):
            if not _on_plane(tissue, c.origin, c.normal):
                plane("tissue_plane", "tissue", c.origin, c.normal, COLORS["tissue"], 0.35)
            plane("depth_plane", "depth", c.origin - c.depth * c.normal, c.normal, COLORS["depth"], 0.4)
        elif isinstance(c, C.SphereContact):
            M = pose_matrix(c.center)
            add(("sphere", g.Mesh(g.Sphere(c.radius), material(COLORS["sphere"], 0.3)), M),
                ("wire", g.Mesh(g.Sphere(c.radius), g.MeshBasicMaterial(color=COLORS["sphere"], wireframe=True)), M))
            legend.append("sphere")
        elif isinstance(c, C.RemoteCenter):
            add(*trocar_parts(c.center, _surface_normal(constraints, tissue), extent_m))
            legend.append("trocar")
        elif isinstance(c, SurfaceDepth):
            add(*height_field_parts(c.surface, c.depth))
            legend += ["tissue", "depth"]
        elif not isinstance(c, MOTION_ONLY):
            undrawn.append(c)
    return parts, list(dict.fromkeys(legend)), undrawn


def custom_fixture_parts(fixture, frame=None) -> list:
    """A user's fixture type's own drawing, the one small protocol the viewer asks of it: a
    method ``draw(frame)`` returning an iterable of ``(name, meshcat object, 4x4 transform)``
    (m, in the frame ``frame`` maps the patient frame into: a
    :class:`teleop.dynamics.registry.FrameMap`, the master workspace for the master side, the
    identity for the slave's), the same map its ``build(frame)`` uses. A fixture without
    ``draw`` gets nothing here: the view then draws it from its constraints
    (:func:`fixture_parts`)."""
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


def side_constraints(scene, side: str) -> tuple[tuple, str | None]:
    """The constraints of a side's fixture (``scene`` a VizScene, ``side`` "master" or "slave"):
    the built fixture the scene gives, else (master) the built-in type's from its parameters or a
    user's fixture built through ``fixture_frame``, else (slave) a user's fixture built in the
    patient frame, else none. Returns (constraints, why a user's fixture could not be built here
    or None)."""
    given = scene.master_fixture if side == "master" else scene.slave_fixture
    if given is not None:
        return tuple(given.constraints), None
    if scene.fixture_object is None:
        if side == "slave":
            return (), None
        return tuple(built_in_fixture(scene.fixture_type, scene.fixture_params).constraints), None
    frame = (scene.fixture_frame if side == "master" else None) or FrameMap.identity()
    try:
        return tuple(scene.fixture_object.build(frame).constraints), None
    except Exception as e:  # a user's type: draw what can be drawn, and say why not
        return (), f"{type(e).__name__}: {e}"


def environment_parts(scene, has_slave: bool, master_tissue: dict | None, extent_m: dict) -> tuple[list, list, bool]:
    """Each side's tissue and fixture (``scene`` a VizScene; the slave side only ``has_slave``):
    the tissue block (the master's ``master_tissue``: the slave's under the map), and the
    fixture, drawn by its type's ``draw(frame)`` if it has one, else from its constraints
    (:func:`fixture_parts`, sized by each side's ``extent_m`` {side: m}). Returns (parts with
    paths under "master/" and "slave/", legend keys of LEGEND, generic): generic is True when a
    fixture has constraints the view cannot draw or could not be built, which is said once, as a
    warning naming them (the view then draws the tool's axes and path)."""
    parts, legend, undrawn, unbuilt = [], [], [], None
    sides = (("master", master_tissue, scene.fixture_frame), ("slave", scene.tissue, None))
    for side, tissue, frame in sides if has_slave else sides[:1]:
        R_t = None if tissue is None else tissue_rotation(scene.tissue, frame)
        if tissue is not None:
            parts += [(f"{side}/tissue/{n}", o, M) for n, o, M in tissue_parts(tissue, R_t)]
            legend.append("tissue")
        if hasattr(scene.fixture_object, "draw"):
            drawn = custom_fixture_parts(scene.fixture_object, frame)
            parts += [(f"{side}/fixture/{n}", o, M) for n, o, M in drawn]
            continue
        cons, why = side_constraints(scene, side)
        unbuilt = unbuilt or why
        drawn, keys, missed = fixture_parts(cons, 1.3 * extent_m[side], extent_m[side], tissue, R_t)
        parts += [(f"{side}/fixture/{n}", o, M) for n, o, M in drawn]
        legend += keys
        undrawn += [c for c in missed if c.name not in {u.name for u in undrawn}]
    if undrawn or unbuilt:
        what = ("its constraint(s) " + ", ".join(f"{c.name} ({type(c).__name__})" for c in undrawn) if undrawn
                else f"it could not be built here ({unbuilt})")
        log.warning("viewer: cannot draw the %r fixture: %s; drawing the tool's axes and its path instead "
                    "(give the fixture type a draw(frame) method)", scene.fixture_type, what)
    return parts, list(dict.fromkeys(legend)), bool(undrawn or unbuilt)
