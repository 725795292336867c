"""Mesh emitters as few lights: planar convex emitters merged into one polygon, closed convex ones as hulls.

Blender meshes that emit (an Emission shader on a subdivided sphere, a neon tube, a panel) reach the core
as emitting triangles, each a two-sided polygon light. Every light costs pass 2 a couple per receiver, so a
sphere of 1,900 faces cost 1,900 lights. Two groupings keep the radiometry and cost one light each:

- a **planar** emitter whose triangles tile a convex polygon (a quad, a subdivided panel, a disk) is that
  polygon, two-sided, of the same radiance;
- a **closed convex** emitter (a UV or ico sphere, a cube, a capped cylinder) is, from any point outside it,
  seen as its silhouette, every direction inside carrying its radiance. Its light is the polygon where the
  cone through the silhouette meets a plane, built per receiver as point lamps' polygons are (``facing``).

The planes of a hull (``hull_frames``): pass 2 clips a light in its own fixed plane, so each hull gets six
virtual lights, the planes tangent to it (supporting planes) with normals +-LAMP_AXES (a generic rotation,
so that no face a user models lies in one). A receiver takes the plane it stands highest above, where the
silhouette's projection (the 2-D convex hull of the projected rim: the vertices of the edges between a
face turned towards it and one turned away) lies within
HOLDER_REACH radii of the hull's centre; each frame's own polygon (``LightFrames.vertices``), the square of
that reach, holds every receiver's. The whole emitter lies behind a supporting plane, so none of its own
faces blocks its light.

A closed emitter counts as convex within NEAR_CONVEX of its radius: a subdivided sphere's non-planar quads
fold by a fraction of a percent, and its outline is then its vertices' hull's (measured on a public scene's
1,920-face sphere: 1.7e-4 of the light of one light per triangle at most).

A **non-convex** emitter E (a torus, a lamp shade, open or closed; two-sided, of one radiance L) is seen
from x in the directions whose first surface is E. Those directions lie in the cone from x through the
convex hull of E's vertices, which two parallel supporting planes bound: the near one, between x and E (the
plane x takes, as for a convex emitter), and the far one beyond E. The cone's section on each is the 2-D
hull of all E's vertices projected there. Two lights integrate over it: the near one of radiance L (its
rays end before E: the directions no other geometry blocks) and the far one of radiance -L (its rays pass
E: the directions that meet nothing at all, through the hole of a torus). Their sum is L over the
directions that meet E and nothing before it: exact when no other geometry lies between the planes inside
the cone (``crowded_hulls`` keeps emitters with other geometry inside their hull one light per triangle;
beside it, ``nearby_geometry`` warns), at the cost of two lights.

A receiver **inside the box** the six supporting planes bound (a floor under an emitter resting on it, near
the contact) stands above no supporting plane, and the cone through the emitter may span nearly a
hemisphere, which no one plane holds. It takes the hull's six **inner lights** instead: the faces of that
box (moved out by INNER_MARGIN radii), facing in, whose rays run from the receiver through the emitter to
the face, the emitter's own faces blocking nothing (``LightFrames.excluded``: detection's jumps and the
depth rays skip them). Every direction from inside the box leaves it through one face, so each face's light
is the face's rectangle cut by the planes of the cone through the emitter (``_inner_section``) and the six
add up to the cone. A non-convex emitter takes six more of radiance -L that its faces block, as above; a
receiver inside its hull (the floor in a torus' hole) takes whole faces (all directions: the -L lights take
out those that miss it).

Limits, stated where they apply: geometry between a hull and the plane (or the box's face) a receiver
takes blocks the light it should not, or none (``nearby_geometry`` warns when geometry comes within 4
radii); where it pierces a near plane inside the light, pass 2's silhouettes may shade it wrong; a
receiver on or inside a convex emitter gets none of its light (as it should); a non-convex emitter's own
surface takes the inner lights (the whole faces: it lies inside its hull), so its other faces light it,
wrongly where other geometry lies behind it in the box (a floor under a torus).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
from numba import njit

from .facing import LAMP_AXES
from .scene import LOBES_ALL, EmitterHulls, Lights

# Kind of a hull's virtual lights in ``LightFrames.kind`` (after the facing kinds 0..2).
FACING_HULL = 3
# A receiver's polygon must lie within this many bounding radii of the hull's centre's foot on the plane:
# the frame's own square of that half-width holds every receiver's (the conservative tests read it).
HOLDER_REACH = 3.0
# The box of a hull's supporting planes, moved out by this fraction of its radius, holds its inner lights
# (the emitter strictly inside it).
INNER_MARGIN = 1e-3
# The same for a non-convex emitter's far plane, whose sections are larger (receivers nearer than about a
# radius to the near plane take another plane, or none).
FAR_HOLDER_REACH = 3.0 * HOLDER_REACH
# Relative tolerance of the planar test (times the emitter's size).
CONVEX_EPS = 1e-7
# A closed emitter is grouped as convex when no vertex lies further in front of a face than this fraction of
# its radius: exactly convex meshes (float32 coordinates aside), and subdivided ones whose non-planar quads
# fold by a fraction of a percent (the outline then is the vertices' hull's, within that fraction).
NEAR_CONVEX = 1e-2
# Far views sampled for a hull's widest silhouette (its polygons' vertex budget, ``hull_tables``).
WIDTH_VIEWS = 96
# A non-convex emitter of at least this many faces becomes one hull (two lights); fewer stay one light per
# triangle.
NONCONVEX_MIN_FACES = 8
# Other geometry closer to a non-convex emitter than this (relative to its radius, and not separated from it by
# a plane) crowds it (``crowded_hulls``); a floor it rests on touches it without crowding it.
CROWDED_MARGIN = 1e-4


# ------------------------------------------------------------------------------------------------------
# Grouping an exporter's emitting triangles
# ------------------------------------------------------------------------------------------------------

def group_mesh_emitters(lights: Lights, part: np.ndarray) -> tuple[Lights, EmitterHulls, np.ndarray, np.ndarray]:
    """Merge each emitter's triangles into one light where that keeps the radiometry.

    Parameters
    ----------
    lights : Lights       polygon lights, mesh emitters' triangles among them (vertex_count 3).
    part : (L,) int64     for each light, the emitter it is a triangle of (one object instance and material:
                          one radiance), -1 for lights that are not to be grouped.

    Returns
    -------
    lights : Lights              the lights not grouped, then one polygon per planar convex emitter.
    hulls : EmitterHulls         one row per closed convex emitter (its faces wound outward), then one per
                                 other emitter of NONCONVEX_MIN_FACES faces or more (``convex`` False).
    light_source, hull_source    (L',), (H,) int64: the input light each output light or hull stands for
                                 (its first triangle; for names).
    """
    part = np.asarray(part, np.int64).reshape(-1)
    if len(part) != len(lights):
        raise ValueError(f"part has {len(part)} entries for {len(lights)} lights")
    grouped = (part >= 0) & (np.asarray(lights.vertex_count) == 3)
    keep_rows = [np.flatnonzero(~grouped)]
    polygons, polygon_rows, hull_faces, hull_rows, other_faces, other_rows = [], [], [], [], [], []
    order = np.flatnonzero(grouped)
    order = order[np.argsort(part[order], kind="stable")]
    bounds = np.flatnonzero(np.diff(part[order])) + 1
    for rows in np.split(order, bounds) if len(order) else []:  # emitters: one per emitting object and material
        triangles = lights.vertices[rows, :3]
        if len(rows) >= 2:
            polygon = planar_convex_union(triangles)
            if polygon is not None:
                polygons.append(polygon)
                polygon_rows.append(rows[0])
                continue
        if len(rows) >= 4:
            outward = closed_convex_faces(triangles)
            if outward is not None:
                hull_faces.append(outward)
                hull_rows.append(rows[0])
                continue
        if len(rows) >= NONCONVEX_MIN_FACES:
            other_faces.append(triangles)
            other_rows.append(rows[0])
            continue
        keep_rows.append(rows)
    kept = np.sort(np.concatenate(keep_rows))
    base = lights.subset(kept)
    if polygons:
        merged = Lights.from_polygons(polygons, lights.radiance[polygon_rows], np.ones(len(polygons), bool))
        merged.cast_shadow = np.asarray(lights.cast_shadow, bool)[polygon_rows]
        merged.lobes = np.asarray(lights.lobes, np.int64)[polygon_rows]
        base = Lights.concat([base, merged])
    hull_faces, hull_rows = hull_faces + other_faces, hull_rows + other_rows
    hulls = EmitterHulls(np.concatenate(hull_faces) if hull_faces else np.zeros((0, 3, 3)),
                         np.repeat(np.arange(len(hull_faces)), [len(f) for f in hull_faces]),
                         lights.radiance[hull_rows] if hull_rows else np.zeros((0, 3)),
                         np.asarray(lights.lobes, np.int64)[hull_rows] if hull_rows else None,
                         np.arange(len(hull_faces)) < len(hull_faces) - len(other_faces))
    return base, hulls, np.concatenate([kept, np.array(polygon_rows, np.int64)]), np.array(hull_rows, np.int64)


def planar_convex_union(triangles: np.ndarray) -> np.ndarray | None:
    """The convex polygon (V, 3) that triangles (K, 3, 3) tile, or None: they lie in one plane and their
    areas sum to that of their vertices' convex hull (they cover it; a mesh's faces do not overlap).
    Collinear hull vertices are dropped; the winding is that of the first triangle."""
    normal = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    doubled = np.linalg.norm(normal, axis=1)
    if not (doubled > 0).all():
        return None
    unit = normal[0] / doubled[0]
    points = triangles.reshape(-1, 3)
    size = float(np.ptp(points, axis=0).max())
    if (np.abs((points - points[0]) @ unit) > CONVEX_EPS * size).any():
        return None
    helper = np.eye(3)[np.argmin(np.abs(unit))]
    tangent = np.cross(unit, helper)
    tangent /= np.linalg.norm(tangent)
    bitangent = np.cross(unit, tangent)
    uv = np.stack([(points - points[0]) @ tangent, (points - points[0]) @ bitangent], axis=1)
    chain = np.empty(2 * len(uv), np.int64)
    hull = chain[:_convex_hull_indices(uv, len(uv), chain, CONVEX_EPS * size * size)]
    if len(hull) < 3:
        return None
    ring = uv[hull]
    hull_area = 0.5 * abs(np.sum(ring[:, 0] * np.roll(ring[:, 1], -1) - np.roll(ring[:, 0], -1) * ring[:, 1]))
    if abs(0.5 * doubled.sum() - hull_area) > 1e-6 * hull_area:
        return None
    return points[hull]  # counter-clockwise about ``unit``: the first triangle's winding


def closed_convex_faces(triangles: np.ndarray, tolerance: float = None) -> np.ndarray | None:
    """Triangles (K, 3, 3) wound outward when they bound a convex solid, else None.

    Closed: every edge is shared by exactly two faces, in opposite directions (vertices matched exactly:
    a mesh's corners come from one vertex array). Convex: no vertex lies further in front of a face's plane
    than ``tolerance`` (default NEAR_CONVEX) times the largest distance of a vertex from their mean: the
    folds of a subdivided surface's non-planar quads pass (their outline is the vertices' hull's to that
    fraction). Faces all wound inward are turned round.
    """
    tolerance = NEAR_CONVEX if tolerance is None else tolerance
    points = triangles.reshape(-1, 3)
    unique_points, vertex = np.unique(points, axis=0, return_inverse=True)
    vertex = vertex.reshape(-1, 3)
    directed = np.stack([vertex, np.roll(vertex, -1, axis=1)], axis=-1).reshape(-1, 2)
    n_vertices = len(unique_points)
    key = directed[:, 0] * n_vertices + directed[:, 1]
    reverse = directed[:, 1] * n_vertices + directed[:, 0]
    if len(np.unique(key)) != len(key):
        return None  # an edge used twice in one direction: not one consistently wound surface
    if not np.isin(reverse, key).all():
        return None  # an open edge (or a face wound against its neighbours)
    normal = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    length = np.linalg.norm(normal, axis=1)
    if not (length > 0).all():
        return None
    normal /= length[:, None]
    offset = np.einsum("kj,kj->k", normal, triangles[:, 0])
    radius = float(np.linalg.norm(unique_points - unique_points.mean(axis=0), axis=1).max())
    # Faces wound outward keep every vertex behind them: the volume they bound is positive.
    volume = np.einsum("kj,kj->k", triangles[:, 0], np.cross(triangles[:, 1], triangles[:, 2])).sum() / 6.0
    if not abs(volume) > 0:
        return None
    sign = 1.0 if volume > 0 else -1.0
    worst = 0.0
    for start in range(0, len(normal), 512):  # chunks of faces, bounding the (512, V) temporary
        height = sign * (normal[start:start + 512] @ unique_points.T - offset[start:start + 512, None])
        worst = max(worst, float(height.max()))
    if worst > tolerance * radius:
        return None
    return triangles if sign > 0 else triangles[:, ::-1].copy()


# ------------------------------------------------------------------------------------------------------
# Hull tables and frames
# ------------------------------------------------------------------------------------------------------

@dataclass
class HullTables:
    """What the per-receiver polygons need of the hulls, packed (H hulls, six planes each).

    vertex (Hv, 3), vertex_start (H + 1,)       unique vertices, m.
    face_normal (Hf, 3), face_offset (Hf,), face_start (H + 1,)   outward unit normals, n . x = offset.
    edge_vertex, edge_face (He, 2) int64, edge_start (H + 1,)     each edge's vertices and its two faces
                                                                  (global rows).
    centre (H, 3), radius (H,)                  the vertices' mean and the largest distance from it, m.
    plane_origin, plane_normal, plane_tangent, plane_bitangent (H, 6, 3)
                                                the supporting planes: normal +-LAMP_AXES[j // 2], origin
                                                the foot of the centre on the plane.
    plane_support (H, 6)                        the plane's distance from the centre, m.
    width (H,) int64                            vertices budgeted per receiver polygon.
    convex (H,) bool                            ``EmitterHulls.convex``: False, the polygon is the outline of
                                                all the vertices (no edges are listed).
    face_vertices (Hf, 3, 3)                    the faces (to find them among the scene's triangles).
    """

    vertex: np.ndarray
    vertex_start: np.ndarray
    face_normal: np.ndarray
    face_offset: np.ndarray
    face_start: np.ndarray
    edge_vertex: np.ndarray
    edge_face: np.ndarray
    edge_start: np.ndarray
    centre: np.ndarray
    radius: np.ndarray
    plane_origin: np.ndarray
    plane_normal: np.ndarray
    plane_tangent: np.ndarray
    plane_bitangent: np.ndarray
    plane_support: np.ndarray
    width: np.ndarray
    convex: np.ndarray
    face_vertices: np.ndarray

    def __len__(self) -> int:
        return len(self.radius)


def plane_axes() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The six supporting planes' normals, tangents and bitangents (6, 3) each: +-LAMP_AXES."""
    axis = np.arange(6) // 2
    sign = np.where(np.arange(6) % 2 == 0, 1.0, -1.0)
    normal = sign[:, None] * LAMP_AXES[axis]
    tangent = LAMP_AXES[(axis + 1) % 3]
    return normal, tangent, np.cross(normal, tangent)


def hull_tables(hulls: EmitterHulls) -> HullTables:
    """Tables of validated hulls; a ValueError when one is not closed and convex."""
    normals, tangents, bitangents = plane_axes()
    parts = {name: [] for name in ("vertex", "face_normal", "face_offset", "edge_vertex", "edge_face")}
    starts = {"vertex": [0], "face": [0], "edge": [0]}
    centre, radius, support, width = [], [], [], []
    for row in range(len(hulls)):  # emitters: a handful
        faces = hulls.faces_of(row)
        convex = bool(hulls.convex[row])
        if convex and closed_convex_faces(faces) is None:
            raise ValueError(f"emitter hull {row} is not a closed convex mesh")
        points, vertex = np.unique(faces.reshape(-1, 3), axis=0, return_inverse=True)
        vertex = vertex.reshape(-1, 3)
        normal = np.cross(faces[:, 1] - faces[:, 0], faces[:, 2] - faces[:, 0])
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
        if convex:
            directed = np.stack([vertex, np.roll(vertex, -1, axis=1)], axis=-1).reshape(-1, 2)
            face_of = np.repeat(np.arange(len(faces)), 3)
            n = len(points)
            key = directed[:, 0] * n + directed[:, 1]
            order = np.argsort(key)
            forward = directed[:, 0] < directed[:, 1]
            # Each undirected edge once: its forward half, and the face of the reverse half.
            twin = order[np.searchsorted(key[order], directed[:, 1] * n + directed[:, 0])]
            edge_vertex = directed[forward]
            edge_face = np.stack([face_of[forward], face_of[twin[forward]]], axis=1)
        else:  # the outline of all the vertices: no rim to find
            edge_vertex = np.zeros((0, 2), np.int64)
            edge_face = np.zeros((0, 2), np.int64)
        mean = points.mean(axis=0)
        reach = float(np.linalg.norm(points - mean, axis=1).max())
        centre.append(mean)
        radius.append(reach)
        support.append(((points - mean) @ normals.T).max(axis=0))
        width.append(_silhouette_budget(normal, edge_face) if convex else _outline_budget(points))
        parts["vertex"].append(points)
        parts["face_normal"].append(normal)
        parts["face_offset"].append(np.einsum("kj,kj->k", normal, faces[:, 0]))
        parts["edge_vertex"].append(edge_vertex + starts["vertex"][-1])
        parts["edge_face"].append(edge_face + starts["face"][-1])
        starts["vertex"].append(starts["vertex"][-1] + len(points))
        starts["face"].append(starts["face"][-1] + len(faces))
        starts["edge"].append(starts["edge"][-1] + len(edge_vertex))
    count = len(hulls)
    centre = np.array(centre).reshape(count, 3)
    support = np.array(support).reshape(count, 6)
    joined = {name: np.concatenate(values) if values else np.zeros((0,) + shape)
              for (name, values), shape in zip(parts.items(), ((3,), (3,), (), (2,), (2,)))}
    return HullTables(joined["vertex"], np.array(starts["vertex"], np.int64), joined["face_normal"],
                      joined["face_offset"], np.array(starts["face"], np.int64),
                      joined["edge_vertex"].astype(np.int64), joined["edge_face"].astype(np.int64),
                      np.array(starts["edge"], np.int64), centre, np.array(radius).reshape(count),
                      centre[:, None] + support[..., None] * normals[None], np.broadcast_to(normals, (count, 6, 3)).copy(),
                      np.broadcast_to(tangents, (count, 6, 3)).copy(), np.broadcast_to(bitangents, (count, 6, 3)).copy(),
                      support, np.array(width, np.int64).reshape(count), np.asarray(hulls.convex, bool).copy(),
                      np.asarray(hulls.triangles, np.float64))


def _fibonacci_views(count: int) -> np.ndarray:
    """``count`` unit directions (count, 3) spread evenly over the sphere."""
    k = np.arange(count) + 0.5
    z = 1.0 - 2.0 * k / count
    phi = math.pi * (3.0 - math.sqrt(5.0)) * k
    return np.stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z], axis=1)


def _outline_budget(points: np.ndarray) -> int:
    """Vertices to budget for a non-convex emitter's receiver polygons: the most vertices the outline of its
    points (V, 3) has over WIDTH_VIEWS far views, with the margin of ``_silhouette_budget``."""
    widest = 3
    chain = np.empty(2 * len(points), np.int64)
    for view in _fibonacci_views(WIDTH_VIEWS):  # far views: a hundred
        helper = np.eye(3)[np.argmin(np.abs(view))]
        u = np.cross(view, helper)
        u /= np.linalg.norm(u)
        flat = np.ascontiguousarray(np.stack([points @ u, points @ np.cross(view, u)], axis=1))
        widest = max(widest, _convex_hull_indices(flat, len(flat), chain))
    return int(4 * math.ceil((1.25 * widest + 8) / 4))


def _silhouette_budget(face_normal: np.ndarray, edge_face: np.ndarray) -> int:
    """Vertices to budget for a hull's receiver polygons: its widest silhouette over WIDTH_VIEWS far views
    (Fibonacci directions), with a margin; a multiple of 4 (the holder square's sides)."""
    views = _fibonacci_views(WIDTH_VIEWS)
    front = (face_normal @ views.T) > 0        # (F, D): far views see the faces turned towards them
    edges = (front[edge_face[:, 0]] != front[edge_face[:, 1]]).sum(axis=0)
    return int(4 * math.ceil((1.25 * edges.max() + 8) / 4))


def hull_frames(tables: HullTables, radiance: np.ndarray, lobes: np.ndarray | None = None) -> dict:
    """The hulls' virtual lights as ``facing.facing_frames`` gives a lamp's: origin, tangent, bitangent,
    normal (K, 3); uv (K, W, 2) and vertices (K, W, 3) the polygon holding every receiver's (W = the widest
    budget); vertex_count (K,) each row's budget; radiance (K, 3); two_sided (K,) False; area (K,); kind
    FACING_HULL, slot, source the hull (K,) int64; cap_centre (K, 3), cap_radius (K,); spot_frame,
    spot_cos_half, spot_smooth; cast_shadow; spread; lobes (K,) from the hulls' ``lobes`` (H,) (None: all);
    hull_far (K,) bool; excluded (K,) int64.

    In groups of six of one hull: every hull's six outer planes (slots 0..5, the supporting planes: a
    receiver above one takes one), then each non-convex hull's six far planes (slots 0..5, radiance -L),
    then every hull's six inner lights (slots 6..11: the faces of the box of its supporting planes, facing
    inwards, its own faces excluded; a receiver inside the box takes all six), then each non-convex hull's
    six inner lights of radiance -L that its faces block (the module docstring)."""
    count = len(tables)
    hulls, other = np.arange(count), np.flatnonzero(~tables.convex)
    source = np.concatenate([np.repeat(hulls, 6), np.repeat(other, 6), np.repeat(hulls, 6), np.repeat(other, 6)])
    slot = np.concatenate([np.tile(np.arange(6), count + len(other)), np.tile(np.arange(6, 12), count + len(other))])
    part = np.repeat([0, 1, 2, 3], 6 * np.array([count, len(other), count, len(other)]))  # outer, far, inner, -inner
    far = (part == 1) | (part == 3)
    inner = part >= 2
    sign = np.where(far, -1.0, 1.0)
    j = slot % 6
    width = int(tables.width.max()) + 4 if count else 8
    outward = tables.plane_normal[source, j]
    normal = np.where(inner[:, None], -outward, outward)  # facing the receivers
    margin = INNER_MARGIN * tables.radius[source]
    # Outer: the supporting plane. Far: parallel to it through the hull's lowest point along n_j. Inner: the
    # supporting plane moved out by a margin (the emitter strictly inside), facing in.
    origin = np.where(far[:, None] & ~inner[:, None],
                      tables.centre[source] - tables.plane_support[source, j ^ 1][:, None] * outward,
                      tables.plane_origin[source, j] + np.where(inner, margin, 0.0)[:, None] * outward)
    tangent = tables.plane_tangent[source, j]
    bitangent = np.where(inner[:, None], -1.0, 1.0) * tables.plane_bitangent[source, j]  # right-handed
    reach = np.where(far, FAR_HOLDER_REACH, HOLDER_REACH) * tables.radius[source]
    uv = np.zeros((len(source), width, 2))
    vertex_count = np.where(inner, tables.width[source] + 4, tables.width[source])
    # An inner light's polygon: the box's face, a rectangle [low, high] in (tangent, bitangent).
    low, high = _box_face(tables, source, tangent, bitangent, margin)
    centre_uv, half_uv = np.where(inner[:, None], 0.5 * (low + high), 0.0), \
        np.where(inner[:, None], 0.5 * (high - low), reach[:, None])
    for budget in np.unique(vertex_count):  # hull budgets: a handful
        rows = np.flatnonzero(vertex_count == budget)
        square = _square_perimeter(int(4 * (budget // 4)))
        filled = len(square)
        uv[rows, :filled] = centre_uv[rows, None] + half_uv[rows, None] * square[None]
        uv[rows, filled:] = uv[rows, filled - 1:filled]
    vertices = origin[:, None] + uv[..., :1] * tangent[:, None] + uv[..., 1:] * bitangent[:, None]
    area = np.where(inner, np.prod(high - low, axis=1), (2.0 * reach) ** 2)
    return dict(origin=origin, tangent=tangent, bitangent=bitangent, normal=normal, uv=uv, vertices=vertices,
                vertex_count=vertex_count, radiance=sign[:, None] * np.asarray(radiance, np.float64)[source],
                two_sided=np.zeros(len(source), bool), area=area,
                kind=np.full(len(source), FACING_HULL, np.int64), slot=slot, source=source,
                cap_centre=tables.centre[source], cap_radius=tables.radius[source],
                spot_frame=np.broadcast_to(np.eye(3), (len(source), 3, 3)).copy(),
                spot_cos_half=np.full(len(source), -2.0), spot_smooth=np.zeros(len(source)),
                cast_shadow=np.ones(len(source), bool), spread=np.full(len(source), np.pi),
                lobes=np.full(len(source), LOBES_ALL, np.int64) if lobes is None
                else np.asarray(lobes, np.int64)[source], hull_far=far,
                excluded=np.where(inner & ~far, source, -1))


def _box_face(tables: HullTables, source: np.ndarray, tangent: np.ndarray, bitangent: np.ndarray,
              margin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The (tangent, bitangent) ranges (K, 2) low and high, about the face's foot of the centre, of the face of
    each row's box (its hull's supporting planes moved out by ``margin``): tangent and bitangent are +-axes
    of the planes, whose supports give the ranges."""
    def support(direction):  # (K, 3) a +-axis -> the hull's support along it, plus the margin
        j = np.argmax(np.einsum("kjd,kd->kj", tables.plane_normal[source], direction), axis=1)
        return tables.plane_support[source, j] + margin

    low = np.stack([-support(-tangent), -support(-bitangent)], axis=1)
    high = np.stack([support(tangent), support(bitangent)], axis=1)
    return low, high


def _square_perimeter(points: int) -> np.ndarray:
    """``points`` (a multiple of 4) points (points, 2) counter-clockwise along the square [-1, 1]^2."""
    side = points // 4
    t = -1.0 + 2.0 * np.arange(side) / side
    return np.concatenate([np.stack([t, -np.ones(side)], 1), np.stack([np.ones(side), t], 1),
                           np.stack([-t, np.ones(side)], 1), np.stack([-np.ones(side), -t], 1)])


# ------------------------------------------------------------------------------------------------------
# Each receiver's polygon
# ------------------------------------------------------------------------------------------------------

HULL_TAKEN, HULL_NEAR, HULL_OVERFLOW, HULL_INNER = 0, 1, 2, 3


def hull_polygons(frames, light: np.ndarray, position: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each receiver's polygon of a hull's virtual light, in that light's plane.

    Parameters
    ----------
    frames : LightFrames with ``hulls``; light : (N,) int64 hull virtual lights; position : (N, 3) receivers.

    Returns
    -------
    uv : (N, W, 2) float64   counter-clockwise about the plane's normal (padded with its last vertex);
    count : (N,) int64       its vertices, 0 where the receiver takes another of the hull's planes or none;
    status : (N,) int64      HULL_TAKEN (a plane takes the receiver); for a receiver inside the planes' box,
                             HULL_INNER where the row is an inner light (slots 6..11) and the receiver sees
                             the hull within a half-space, else HULL_NEAR; HULL_OVERFLOW (its silhouette has
                             more vertices than budgeted);
    taken : (N,) int64       the plane (slot 0..5) the receiver takes, -1 for none.
    """
    tables = frames.hulls
    light = np.ascontiguousarray(light, np.int64)
    width = int(tables.width.max()) + 4 if len(tables) else 8  # (an inner light's: the outline and a rectangle)
    uv = np.empty((len(light), width, 2))
    count = np.empty(len(light), np.int64)
    status = np.empty(len(light), np.int64)
    taken = np.empty(len(light), np.int64)
    faces = int(np.diff(tables.face_start).max()) if len(tables) else 1
    vertices = int(np.diff(tables.vertex_start).max()) if len(tables) else 1
    front = np.zeros(faces + vertices, np.bool_)  # face flags, then vertex flags (``_silhouette_vertices``)
    rim = np.zeros(vertices, np.int64)
    # The inner lights' rectangles (the other rows' are unused there).
    holder = np.asarray(frames.uv, np.float64)
    box_low, box_high = holder.min(axis=1), holder.max(axis=1)
    _hull_polygons(light, np.ascontiguousarray(position, np.float64), frames.source, frames.slot,
                   np.ascontiguousarray(frames.origin, np.float64), np.ascontiguousarray(frames.tangent, np.float64),
                   np.ascontiguousarray(frames.bitangent, np.float64), box_low, box_high,
                   tables.vertex, tables.vertex_start, tables.face_normal, tables.face_offset, tables.face_start,
                   tables.edge_vertex, tables.edge_face, tables.edge_start, tables.centre, tables.radius,
                   tables.plane_origin, tables.plane_normal, tables.plane_tangent, tables.plane_bitangent,
                   tables.plane_support, tables.width, tables.convex,
                   np.ascontiguousarray(frames.hull_far if getattr(frames, "hull_far", None) is not None
                                        else np.zeros(len(frames.source), bool)),
                   HOLDER_REACH, FAR_HOLDER_REACH, uv, count, status, taken, front, rim)
    return uv, count, status, taken


@njit(cache=True, nogil=True)
def _silhouette_vertices(r, h, vertex_start, face_normal, face_offset, face_start, edge_vertex, edge_face,
                         edge_start, front, out):
    """The vertices (rows of ``vertex``) of hull h's edges between a face turned towards r and one turned
    away, into ``out``; returns their count (0: r sees no face, inside the hull)."""
    f_start = face_start[h]
    any_front = False
    for f in range(f_start, face_start[h + 1]):
        front[f - f_start] = face_normal[f, 0] * r[0] + face_normal[f, 1] * r[1] + face_normal[f, 2] * r[2] \
            > face_offset[f]
        any_front |= front[f - f_start]
    if not any_front:
        return 0
    v0 = vertex_start[h]
    seen = front[face_start[h + 1] - f_start:]  # the scratch's tail: one flag per vertex
    for v in range(vertex_start[h + 1] - v0):
        seen[v] = False
    m = 0
    for e in range(edge_start[h], edge_start[h + 1]):
        if front[edge_face[e, 0] - f_start] != front[edge_face[e, 1] - f_start]:
            for side in range(2):
                v = edge_vertex[e, side]
                if not seen[v - v0]:
                    seen[v - v0] = True
                    out[m] = v
                    m += 1
    return m


@njit(cache=True, nogil=True)
def _project_silhouette(r, h, j, rim, m, vertex, radius, centre, plane_origin, plane_normal, plane_tangent,
                        plane_bitangent, plane_support, reach, far, out):
    """The outline of the rim vertices ``rim[:m]`` seen from r, projected on hull h's plane j (``far``: the
    parallel supporting plane beyond the hull, ``hull_frames``), into ``out`` (budget, 2); returns its vertex
    count, -1 where a point falls outside the holder (``reach`` radii), -2 where the outline has more
    vertices than the budget."""
    origin = np.empty(3)
    for k in range(3):
        origin[k] = centre[h, k] - plane_support[h, j ^ 1] * plane_normal[h, j, k] if far else plane_origin[h, j, k]
    height = 0.0
    ru, rv = 0.0, 0.0
    for k in range(3):
        rel = r[k] - origin[k]
        height += rel * plane_normal[h, j, k]
        ru += rel * plane_tangent[h, j, k]
        rv += rel * plane_bitangent[h, j, k]
    limit = reach * radius[h]
    points = np.empty((m, 2))
    for i in range(m):
        v = rim[i]
        hv, vu, vv = 0.0, 0.0, 0.0
        for k in range(3):
            rel = vertex[v, k] - origin[k]
            hv += rel * plane_normal[h, j, k]
            vu += rel * plane_tangent[h, j, k]
            vv += rel * plane_bitangent[h, j, k]
        # Behind the near supporting plane, in front of the far one (rounding aside).
        hv = max(hv, 0.0) if far else min(hv, 0.0)
        t = height / (height - hv)
        pu, pv = ru + t * (vu - ru), rv + t * (vv - rv)
        if abs(pu) > limit or abs(pv) > limit:
            return -1
        points[i, 0], points[i, 1] = pu, pv
    return _convex_hull(points, m, out)


@njit(cache=True, nogil=True)
def _convex_hull(points, m, out):
    """The convex hull of points[:m] (m, 2), counter-clockwise, into ``out`` (budget, 2); returns its vertex
    count, -2 where it has more than the budget. For a convex emitter every rim point is on it; for a nearly
    convex one (folds of a subdivided surface) it is the outline of the vertices' hull."""
    chain = np.empty(2 * m, np.int64)
    size = _convex_hull_indices(points, m, chain)
    if size > out.shape[0]:
        return -2
    for i in range(size):
        out[i, 0], out[i, 1] = points[chain[i], 0], points[chain[i], 1]
    return size


@njit(cache=True, nogil=True)
def _convex_hull_indices(points, m, chain, tolerance=0.0):
    """Andrew's monotone chain over points[:m] (m, 2): the hull's point indices, counter-clockwise with
    collinear points (a turn of twice the area ``tolerance`` or less) left out, into ``chain`` (2 m,) int64;
    returns their count."""
    order = np.argsort(points[:m, 0])
    for i in range(1, m):  # ties in u ordered by v (rare: an insertion pass)
        k = i
        while k > 0 and points[order[k - 1], 0] == points[order[k], 0] \
                and points[order[k - 1], 1] > points[order[k], 1]:
            order[k - 1], order[k] = order[k], order[k - 1]
            k -= 1
    size = 0
    for sweep in range(2):  # the lower chain left to right, then the upper right to left
        start = size
        for i in range(m):
            p = order[i] if sweep == 0 else order[m - 1 - i]
            while size >= start + 2:
                a, b = chain[size - 2], chain[size - 1]
                turn = (points[b, 0] - points[a, 0]) * (points[p, 1] - points[a, 1]) \
                    - (points[b, 1] - points[a, 1]) * (points[p, 0] - points[a, 0])
                if turn > tolerance:
                    break
                size -= 1
            chain[size] = p
            size += 1
        size -= 1  # each chain's last point starts the other
    return max(size, 0)


@njit(cache=True, nogil=True)
def _inner_section(r, h, l, rim, m, vertex, centre, row_origin, row_tangent, row_bitangent, box_low, box_high, out):
    """The part of inner light l (a face of hull h's box, facing in) through which r, inside the box, sees
    the hull: the face's rectangle (box_low .. box_high in its (tangent, bitangent)) clipped by the planes
    through r and the outline of the rim vertices ``rim[:m]`` (the cone from r through the hull), into
    ``out`` (budget, 2) counter-clockwise; returns its vertex count (0: the cone misses this face), -1 where
    the hull is not within a half-space seen from r (r on or inside it) or the outline overflows."""
    axis = np.empty(3)
    size = 0.0
    for k in range(3):
        axis[k] = centre[h, k] - r[k]
        size += axis[k] * axis[k]
    size = np.sqrt(size)
    if not size > 0:
        return -1
    for k in range(3):
        axis[k] /= size
    helper = np.zeros(3)
    helper[np.argmin(np.abs(axis))] = 1.0
    e1 = np.empty(3)
    e2 = np.empty(3)
    e1[0] = axis[1] * helper[2] - axis[2] * helper[1]
    e1[1] = axis[2] * helper[0] - axis[0] * helper[2]
    e1[2] = axis[0] * helper[1] - axis[1] * helper[0]
    norm = np.sqrt(e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2])
    for k in range(3):
        e1[k] /= norm
    e2[0] = axis[1] * e1[2] - axis[2] * e1[1]  # e1 x e2 = axis
    e2[1] = axis[2] * e1[0] - axis[0] * e1[2]
    e2[2] = axis[0] * e1[1] - axis[1] * e1[0]
    points = np.empty((m, 2))
    for i in range(m):  # gnomonic projection about the axis: the hull must lie in front of r
        v = rim[i]
        along, p1, p2, length = 0.0, 0.0, 0.0, 0.0
        for k in range(3):
            w = vertex[v, k] - r[k]
            along += w * axis[k]
            p1 += w * e1[k]
            p2 += w * e2[k]
            length += w * w
        if not along > 1e-6 * np.sqrt(length):
            return -1
        points[i, 0], points[i, 1] = p1 / along, p2 / along
    chain = np.empty(2 * m, np.int64)
    n_outline = _convex_hull_indices(points, m, chain)
    if n_outline < 3:
        return -1
    # The face rectangle, counter-clockwise in (tangent, bitangent).
    poly = np.empty((out.shape[0] + n_outline + 4, 2))
    other = np.empty((out.shape[0] + n_outline + 4, 2))
    poly[0, 0], poly[0, 1] = box_low[l, 0], box_low[l, 1]
    poly[1, 0], poly[1, 1] = box_high[l, 0], box_low[l, 1]
    poly[2, 0], poly[2, 1] = box_high[l, 0], box_high[l, 1]
    poly[3, 0], poly[3, 1] = box_low[l, 0], box_high[l, 1]
    count = 4
    # q(u, v) = origin + u T + v B; keep (q - r) . N >= 0 for each cone plane N = d_i x d_{i+1}.
    base = np.empty(3)
    for k in range(3):
        base[k] = row_origin[l, k] - r[k]
    d_a = np.empty(3)
    d_b = np.empty(3)
    plane = np.empty(3)
    for i in range(n_outline):
        a, b = chain[i], chain[(i + 1) % n_outline]
        for k in range(3):
            d_a[k] = axis[k] + points[a, 0] * e1[k] + points[a, 1] * e2[k]
            d_b[k] = axis[k] + points[b, 0] * e1[k] + points[b, 1] * e2[k]
        plane[0] = d_a[1] * d_b[2] - d_a[2] * d_b[1]
        plane[1] = d_a[2] * d_b[0] - d_a[0] * d_b[2]
        plane[2] = d_a[0] * d_b[1] - d_a[1] * d_b[0]
        size_a = d_a[0] * d_a[0] + d_a[1] * d_a[1] + d_a[2] * d_a[2]
        size_b = d_b[0] * d_b[0] + d_b[1] * d_b[1] + d_b[2] * d_b[2]
        if not plane[0] * plane[0] + plane[1] * plane[1] + plane[2] * plane[2] > 1e-24 * size_a * size_b:
            continue  # two outline points a rounding apart (a seam's twin vertices): no plane
        alpha, beta, gamma = 0.0, 0.0, 0.0
        for k in range(3):
            alpha += base[k] * plane[k]
            beta += row_tangent[l, k] * plane[k]
            gamma += row_bitangent[l, k] * plane[k]
        kept = 0  # Sutherland-Hodgman against alpha + beta u + gamma v >= 0
        for p in range(count):
            q = (p + 1) % count
            vp = alpha + beta * poly[p, 0] + gamma * poly[p, 1]
            vq = alpha + beta * poly[q, 0] + gamma * poly[q, 1]
            if vp >= 0:
                other[kept, 0], other[kept, 1] = poly[p, 0], poly[p, 1]
                kept += 1
            if (vp >= 0) != (vq >= 0):
                s = vp / (vp - vq)
                other[kept, 0] = poly[p, 0] + s * (poly[q, 0] - poly[p, 0])
                other[kept, 1] = poly[p, 1] + s * (poly[q, 1] - poly[p, 1])
                kept += 1
        count = kept
        for p in range(count):
            poly[p, 0], poly[p, 1] = other[p, 0], other[p, 1]
        if count < 3:
            return 0
    if count > out.shape[0]:
        return -1
    for p in range(count):
        out[p, 0], out[p, 1] = poly[p, 0], poly[p, 1]
    return count


@njit(cache=True, nogil=True)
def _hull_polygons(light, position, source, slot, row_origin, row_tangent, row_bitangent, box_low, box_high,
                   vertex, vertex_start, face_normal, face_offset, face_start,
                   edge_vertex, edge_face, edge_start, centre, radius, plane_origin, plane_normal, plane_tangent,
                   plane_bitangent, plane_support, width, convex, far_row, reach, far_reach, out_uv, out_count,
                   out_status, out_taken, front, rim):
    heights = np.empty(6)
    r = np.empty(3)
    far_uv = np.empty((out_uv.shape[1], 2))
    for n in range(len(light)):
        l = light[n]
        h = source[l]
        for k in range(3):
            r[k] = position[n, k]
        out_count[n] = 0
        out_status[n] = HULL_NEAR
        out_taken[n] = -1
        for j in range(6):
            value = 0.0
            for k in range(3):
                value += (r[k] - plane_origin[h, j, k]) * plane_normal[h, j, k]
            heights[j] = value
        order = np.argsort(-heights)
        inside = not heights[order[0]] > 1e-9 * radius[h]  # inside the planes' box: no plane takes r
        if inside and slot[l] < 6:
            continue
        if convex[h]:
            m = _silhouette_vertices(r, h, vertex_start, face_normal, face_offset, face_start, edge_vertex,
                                     edge_face, edge_start, front, rim)
        else:  # the outline of all the vertices (r lies outside their hull: above a supporting plane)
            m = vertex_start[h + 1] - vertex_start[h]
            for v in range(m):
                rim[v] = vertex_start[h] + v
        if m < 3:
            continue
        taken = -1
        for i in range(6 if not inside else 0):  # the planes r stands above, highest first: the first that fits
            j = order[i]
            if not heights[j] > 1e-9 * radius[h]:
                break
            count = _project_silhouette(r, h, j, rim, m, vertex, radius, centre, plane_origin, plane_normal,
                                        plane_tangent, plane_bitangent, plane_support, reach, False,
                                        out_uv[n, :width[h]])
            if count >= 3 and not convex[h]:  # a non-convex hull's far section must fit too
                far_count = _project_silhouette(r, h, j, rim, m, vertex, radius, centre, plane_origin, plane_normal,
                                                plane_tangent, plane_bitangent, plane_support, far_reach, True,
                                                far_uv[:width[h]])
                if far_count < 3:
                    count = far_count
                elif far_row[l]:
                    count = far_count
                    out_uv[n, :count] = far_uv[:count]
            if count == -2:
                out_status[n] = HULL_OVERFLOW
                break
            if count >= 3:
                taken = j
                break
        if taken < 0:
            if slot[l] >= 6 and out_status[n] == HULL_NEAR:  # inside the box: the inner lights, all six
                count = _inner_section(r, h, l, rim, m, vertex, centre, row_origin, row_tangent, row_bitangent,
                                       box_low, box_high, out_uv[n])
                if count == -1 and not convex[h]:
                    # r inside the hull of a non-convex emitter (the floor in a torus' hole): the whole face,
                    # every direction (the -L lights take out those that meet nothing)
                    out_uv[n, 0, 0], out_uv[n, 0, 1] = box_low[l, 0], box_low[l, 1]
                    out_uv[n, 1, 0], out_uv[n, 1, 1] = box_high[l, 0], box_low[l, 1]
                    out_uv[n, 2, 0], out_uv[n, 2, 1] = box_high[l, 0], box_high[l, 1]
                    out_uv[n, 3, 0], out_uv[n, 3, 1] = box_low[l, 0], box_high[l, 1]
                    count = 4
                if count >= 0:
                    out_status[n] = HULL_INNER
                if count >= 3:
                    out_count[n] = count
                    for v in range(count, out_uv.shape[1]):
                        out_uv[n, v, 0], out_uv[n, v, 1] = out_uv[n, count - 1, 0], out_uv[n, count - 1, 1]
            continue
        if slot[l] >= 6:  # outside the box: no inner light
            out_status[n] = HULL_TAKEN
            out_taken[n] = taken
            continue
        out_status[n] = HULL_TAKEN
        out_taken[n] = taken
        if taken != slot[l]:
            continue
        out_count[n] = count
        for v in range(count, out_uv.shape[1]):
            out_uv[n, v, 0], out_uv[n, v, 1] = out_uv[n, count - 1, 0], out_uv[n, count - 1, 1]


def taken_hull_planes(frames, position: np.ndarray) -> np.ndarray:
    """(N, K) bool over the frames' hull rows (in groups of six, in frame order): the outer plane each
    receiver (N, 3) takes of each hull, or its six inner lights when it lies inside the hull's box
    (``hull_polygons``), computed once per receiver and group."""
    rows = np.flatnonzero(frames.kind == FACING_HULL)
    out = np.zeros((len(position), len(rows)), bool)
    near = {}  # per hull: the receivers no outer plane takes (the only ones an inner light can take)
    for column in range(0, len(rows), 6):  # hulls' groups of six: a handful
        row, source = rows[column], int(frames.source[rows[column]])
        if frames.slot[row] >= 6:  # inner lights: all six, for a receiver inside the box
            inside = near.get(source, np.zeros(0, np.int64))
            status = hull_polygons(frames, np.full(len(inside), row, np.int64), position[inside])[2]
            out[inside[status == HULL_INNER], column:column + 6] = True
        else:
            _, _, status, taken = hull_polygons(frames, np.full(len(position), row, np.int64), position)
            out[:, column:column + 6] = taken[:, None] == frames.slot[rows[column:column + 6]][None]
            near.setdefault(source, np.flatnonzero(status == HULL_NEAR))
    return out


def near_receivers(frames, points: np.ndarray, triangle: np.ndarray | None = None,
                   part_of: np.ndarray | None = None) -> dict[int, int]:
    """For each hull (by row), how many of ``points`` (N, 3) get none of its light (HULL_NEAR or
    HULL_OVERFLOW from every plane), excluding points inside it (or, for a non-convex hull, on its own faces:
    ``triangle`` (N,) the points' triangles, ``part_of`` from ``hull_faces_in_scene``); only hulls with
    some."""
    out = {}
    if frames.hulls is None or len(frames.hulls) == 0 or len(points) == 0:
        return out
    tables = frames.hulls
    first_rows = np.flatnonzero((frames.kind == FACING_HULL) & (frames.slot == 6) & (frames.radiance.max(axis=1) > 0))
    for light in first_rows:  # hulls: a handful
        h = int(frames.source[light])
        faces = slice(tables.face_start[h], tables.face_start[h + 1])
        on_or_inside = np.zeros(len(points), bool)
        if not tables.convex[h]:
            if triangle is not None and part_of is not None:
                on_or_inside = part_of[triangle] == h
            faces = slice(0, 0)
        for start in range(0, len(points), 4096) if faces.stop > faces.start else []:  # batches of points
            height = points[start:start + 4096] @ tables.face_normal[faces].T - tables.face_offset[faces]
            # Float32 positions of the emitter's own surface lie within rounding of its faces.
            tolerance = 1e-5 * (tables.radius[h] + np.abs(tables.centre[h]).max())
            on_or_inside[start:start + 4096] = (height <= tolerance).all(axis=1)
        outside = np.flatnonzero(~on_or_inside)
        status = hull_polygons(frames, np.full(len(outside), light, np.int64), points[outside])[2]
        missed = int(((status != HULL_TAKEN) & (status != HULL_INNER)).sum())
        if missed:
            out[int(frames.source[light])] = missed
    return out


def nearby_geometry(tables: HullTables, triangles: np.ndarray, part_of: np.ndarray | None = None,
                    batch: int = 65536) -> np.ndarray:
    """(H,) bool: hulls with a scene triangle (T, 3, 3) partly within the reach of the region their planes'
    rays cross behind the plane (HOLDER_REACH radii about the centre, a ball of sqrt(2 HOLDER_REACH^2 + 4)
    radii holding it), not inside the hull (not a non-convex hull's own face: ``part_of``, from
    ``hull_faces_in_scene``): geometry there may block some of the light unseen."""
    out = np.zeros(len(tables), bool)
    for h in range(len(tables)):  # hulls: a handful
        ball = math.sqrt(2.0 * HOLDER_REACH ** 2 + 4.0) * tables.radius[h]
        normal = tables.face_normal[tables.face_start[h]:tables.face_start[h + 1]]
        offset = tables.face_offset[tables.face_start[h]:tables.face_start[h + 1]]
        tolerance = NEAR_CONVEX * tables.radius[h]
        for start in range(0, len(triangles), batch):  # batches of triangles
            part = triangles[start:start + batch]
            low, high = part.min(axis=1), part.max(axis=1)
            close = np.flatnonzero((np.maximum(low - tables.centre[h], 0.0) ** 2
                                    + np.maximum(tables.centre[h] - high, 0.0) ** 2).sum(axis=1) < ball ** 2)
            if len(close) == 0:
                continue
            if not tables.convex[h]:
                own = part_of[start:start + batch][close] == h if part_of is not None else np.zeros(len(close), bool)
                if not own.all():
                    out[h] = True
                    break
                continue
            corners = part[close].reshape(-1, 3)
            inside = ((corners @ normal.T - offset) <= tolerance).all(axis=1).reshape(-1, 3).all(axis=1)
            if not inside.all():
                out[h] = True
                break
    return out


def hull_faces_in_scene(tables: HullTables | None, triangles: np.ndarray) -> np.ndarray:
    """(T,) int64: for each scene triangle (T, 3, 3), the hull it is a face of, -1 for none (its inner lights
    exclude them). Matched by their exact coordinates (a hull's faces are copies of the scene's triangles),
    whatever the order of the corners: one sort of every hull face's key and every triangle's together."""
    part_of = np.full(len(triangles), -1, np.int64)
    if tables is None or len(tables) == 0 or len(triangles) == 0:
        return part_of

    def keys(faces):  # one 72-byte key per triangle, its three corners in byte order
        corners = np.ascontiguousarray(faces, np.float64).view(np.dtype((np.void, 24))).reshape(len(faces), 3)
        return np.ascontiguousarray(np.sort(corners, axis=1)).view(np.dtype((np.void, 72))).reshape(-1)

    faces = tables.face_vertices
    face_hull = np.repeat(np.arange(len(tables)), np.diff(tables.face_start))
    _, inverse = np.unique(np.concatenate([keys(faces), keys(triangles)]), return_inverse=True)
    inverse = inverse.reshape(-1)
    hull_of_key = np.full(int(inverse.max()) + 1, -1, np.int64)
    hull_of_key[inverse[:len(faces)]] = face_hull
    part_of[:] = hull_of_key[inverse[len(faces):]]
    return part_of


def crowded_hulls(tables: HullTables | None, triangles: np.ndarray, part_of: np.ndarray,
                  batch: int = 4096) -> np.ndarray:
    """(H,) bool: the non-convex hulls that another scene triangle (T, 3, 3) may enter (not their own faces:
    ``part_of``): along a ray through such a hull the other geometry may lie behind the emitter, which its
    two lights (the module docstring) do not tell from in front, so those emitters stay one light per
    triangle. A triangle is kept out when a plane separates it from the emitter's vertices (touching, within
    CROWDED_MARGIN radii, allowed: a floor the emitter rests on): its own plane, or one normal to one of
    WIDTH_VIEWS directions; otherwise it counts as inside (a conservative test)."""
    out = np.zeros(len(tables) if tables is not None else 0, bool)
    if tables is None:
        return out
    directions = _fibonacci_views(WIDTH_VIEWS)
    for h in np.flatnonzero(~tables.convex):  # non-convex emitters: a handful
        points = tables.vertex[tables.vertex_start[h]:tables.vertex_start[h + 1]]
        eps = CROWDED_MARGIN * tables.radius[h]
        low, high = points.min(axis=0) - eps, points.max(axis=0) + eps
        near = np.flatnonzero((part_of != h) & (triangles.min(axis=1) < high).all(axis=1)
                              & (triangles.max(axis=1) > low).all(axis=1))
        extent_low, extent_high = (points @ directions.T).min(axis=0), (points @ directions.T).max(axis=0)
        for start in range(0, len(near), batch):  # batches of the triangles near the emitter
            part = triangles[near[start:start + batch]]
            normal = np.cross(part[:, 1] - part[:, 0], part[:, 2] - part[:, 0])
            normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
            height = points @ normal.T - np.einsum("bk,bk->b", normal, part[:, 0])     # (V, B)
            apart = (height.min(axis=0) >= -eps) | (height.max(axis=0) <= eps)
            along = np.einsum("bvk,dk->bvd", part, directions)                          # (B, 3, D)
            apart |= ((along.min(axis=1) >= extent_high - eps) | (along.max(axis=1) <= extent_low + eps)).any(axis=1)
            if not apart.all():
                out[h] = True
                break
    return out


def hulls_as_triangles(scene, rows: np.ndarray):
    """``scene`` (a validated ``Scene``) with the emitter hulls ``rows`` (K,) int64 turned back into one
    two-sided light per face (after the polygon lights): the exact path where a hull's two lights are not
    (``crowded_hulls``, or an integrator other than the silhouettes)."""
    hulls = scene.hulls
    rows = np.asarray(rows, np.int64)
    if len(rows) == 0:
        return scene
    faces = [hulls.faces_of(row) for row in rows]  # emitters: a handful
    counts = [len(f) for f in faces]
    triangles = np.concatenate(faces)
    extra = Lights(triangles, np.full(len(triangles), 3, np.int64), np.repeat(hulls.radiance[rows], counts, axis=0),
                   np.ones(len(triangles), bool), lobes=np.repeat(hulls.lobes[rows], counts))
    keep = np.ones(len(hulls), bool)
    keep[rows] = False
    return dataclasses.replace(scene, lights=Lights.concat([scene.lights, extra]), hulls=hulls.subset(keep))


def compile_emitters():
    """Compile ``_hull_polygons`` and its helpers (or load them from Numba's cache) on a one-hull dummy;
    returns them."""
    faces = np.array([[[0, 0, 0], [0, 1, 0], [1, 0, 0]], [[0, 0, 0], [1, 0, 0], [0, 0, 1]],
                      [[0, 0, 0], [0, 0, 1], [0, 1, 0]], [[1, 0, 0], [0, 1, 0], [0, 0, 1]]], np.float64)
    tables = hull_tables(EmitterHulls(faces, np.zeros(4, np.int64), np.ones((1, 3))))

    frames = SimpleNamespace(hulls=tables, **hull_frames(tables, np.ones((1, 3))))
    hull_polygons(frames, np.zeros(1, np.int64), np.array([[2.0, 2.0, 2.0]]))
    hull_polygons(frames, np.full(1, 6, np.int64), np.array([[0.3, 0.3, -0.01]]))  # an inner light
    return _hull_polygons, _silhouette_vertices, _project_silhouette, _convex_hull, _convex_hull_indices, \
        _inner_section
