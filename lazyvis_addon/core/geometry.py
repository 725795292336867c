"""Polygon geometry shared by both passes: light frames, convex clipping, blocker cones, Lambert's formula.

Everything is batched: N independent problems at once, polygons padded to K vertices by repeating their
last vertex (so a zero-length closing edge contributes nothing to edge sums) with an explicit count.

Visibility is reasoned about with *cones from the receiver*: a blocker polygon B occludes the part of a
light seen from x whose directions lie inside the cone from x through B, provided B lies in front of the
light. The cone's faces are planes through x, one per edge of B; a plane through x meets the light's plane
in a line, so clipping a light by a blocker never needs the blocker's projection (which runs off to
infinity as a blocker vertex approaches the plane through x parallel to the light).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from .borrowed import borrowed

from .emitters import FACING_HULL, hull_frames, hull_polygons, hull_tables
from .facing import cap_polygons, facing_frames, spread_lines
from .scene import LOBES_ALL, Lights

# Relative tolerance for "on the plane" decisions (angles in radians, distances over lengths).
PLANE_EPS = 1e-9


@dataclass
class LightFrames:
    """Orthonormal frames of the lights, for 2-D work in each light's plane.

    Attributes
    ----------
    origin : (L, 3) float64      vertex 0 of each light.
    tangent, bitangent : (L, 3)  in-plane axes; (tangent, bitangent, normal) is right-handed.
    normal : (L, 3) float64      unit emitting normal.
    uv : (L, V, 2) float64       vertices in (tangent, bitangent) coordinates, counter-clockwise.
    vertices : (L, V, 3)         world-space vertices (padded).
    vertex_count : (L,) int64
    radiance : (L, 3) float64
    two_sided : (L,) bool
    area : (L,) float64          m^2.

    Point, spot and sun lights (``facing``) follow the polygon lights as virtual lights (three planes per
    lamp, one per sun) whose polygon is built per receiver (``facing.cap_polygons``); for them ``uv`` and
    ``vertices`` hold a polygon containing every receiver's, and
    kind : (L,) int64            -1 for polygon lights, else FACING_DISK / FACING_SPHERE / FACING_SUN.
    slot, source : (L,) int64    the lamp's plane (0..2) and the row of ``Scene.facing`` (-1 for polygons).
    cap_centre, cap_radius       (L, 3), (L,): the lamp's centre and radius (a sun's direction, half-angle).
    spot_frame, spot_cos_half, spot_smooth   (L, 3, 3), (L,), (L,): the spot cone (``facing.spot_mask``).
    scene_light : (L,) int64     the light of passes and statistics (polygon lights, then facing lights).
    cast_shadow : (L,) bool      False: nothing blocks the light (Cast Shadow off).
    spread : (L,) float64        Cycles' area light Spread, radians (pi: Lambertian; ``Lights.spread``).
    lobes : (L,) int64           the BSDF lobes the light reaches (``scene.LOBE_DIFFUSE | LOBE_GLOSSY``).
    hull_far : (L,) bool         a non-convex emitter's far light (``emitters``: radiance -L, in the plane
                                 beyond the emitter parallel to its near light's).
    excluded : (L,) int64        the emitter hull whose own faces block none of the light (a hull's inner
                                 lights, ``emitters``); -1 for none.

    Mesh emitters grouped as hulls (``Scene.hulls``) follow as virtual lights, kind FACING_HULL, in groups of
    six: twelve for a convex emitter (its supporting planes, and the inner faces of their box), twenty-four
    for a non-convex one (also its far planes and the inner faces' -L twins; ``emitters.hull_frames``), whose
    polygon is built per receiver too (``emitters.hull_polygons``; ``hulls`` their tables, source the hull).
    """

    origin: np.ndarray
    tangent: np.ndarray
    bitangent: np.ndarray
    normal: np.ndarray
    uv: np.ndarray
    vertices: np.ndarray
    vertex_count: np.ndarray
    radiance: np.ndarray
    two_sided: np.ndarray
    area: np.ndarray
    kind: np.ndarray | None = None
    slot: np.ndarray | None = None
    source: np.ndarray | None = None
    cap_centre: np.ndarray | None = None
    cap_radius: np.ndarray | None = None
    spot_frame: np.ndarray | None = None
    spot_cos_half: np.ndarray | None = None
    spot_smooth: np.ndarray | None = None
    scene_light: np.ndarray | None = None
    cast_shadow: np.ndarray | None = None
    spread: np.ndarray | None = None
    lobes: np.ndarray | None = None
    hull_far: np.ndarray | None = None
    excluded: np.ndarray | None = None
    hulls: object = None
    part_of: object = None       # (T,) int64 scene triangle -> the hull it is a face of, -1 (render sets it)

    def __post_init__(self) -> None:
        count = len(self.vertex_count)
        defaults = dict(kind=np.full(count, -1, np.int64), slot=np.zeros(count, np.int64),
                        source=np.full(count, -1, np.int64), cap_centre=np.zeros((count, 3)),
                        cap_radius=np.zeros(count), spot_frame=np.broadcast_to(np.eye(3), (count, 3, 3)).copy(),
                        spot_cos_half=np.full(count, -2.0), spot_smooth=np.zeros(count),
                        scene_light=np.arange(count, dtype=np.int64), cast_shadow=np.ones(count, bool),
                        spread=np.full(count, np.pi), lobes=np.full(count, LOBES_ALL, np.int64),
                        hull_far=np.zeros(count, bool), excluded=np.full(count, -1, np.int64))
        for name, value in defaults.items():
            if getattr(self, name) is None:
                setattr(self, name, value)

    def __len__(self) -> int:
        return len(self.vertex_count)

    @property
    def any_facing(self) -> bool:
        return bool((self.kind >= 0).any())


def light_frames(lights: Lights, facing=None, centre: np.ndarray | None = None, extent: float = 1.0,
                 hulls=None) -> LightFrames:
    """Frames of validated lights (see ``Scene.validated``): the polygon lights, then the virtual lights of
    ``facing`` (FacingLights; ``centre`` (3,) and ``extent`` the scene's bounding-box centre and diagonal),
    then those of ``hulls`` (EmitterHulls)."""
    frames = _polygon_frames(lights)
    if facing is not None and len(facing):
        extra = facing_frames(facing, np.zeros(3) if centre is None else np.asarray(centre, np.float64), extent)
        extra["vertex_count"] = np.full(len(extra["kind"]), extra["uv"].shape[1])
        frames = _joined(frames, extra, len(lights))
    if hulls is not None and len(hulls):
        tables = hull_tables(hulls)
        frames = _joined(frames, hull_frames(tables, hulls.radiance, hulls.lobes),
                         len(lights) + (len(facing) if facing else 0))
        frames.hulls = tables
    return frames


def _joined(frames: LightFrames, extra: dict, first_scene_light: int) -> LightFrames:
    """``frames`` followed by virtual lights ``extra`` (``facing_frames``' arrays), whose scene lights are
    ``first_scene_light`` + their source."""
    width = max(frames.uv.shape[1], extra["uv"].shape[1])

    def padded(array, k):
        return np.concatenate([array, np.repeat(array[:, -1:], k - array.shape[1], axis=1)], axis=1) \
            if array.shape[1] < k else array

    joined = {}
    for name in ("origin", "tangent", "bitangent", "normal", "radiance", "two_sided", "area", "kind", "slot",
                 "cap_centre", "cap_radius", "spot_frame", "spot_cos_half", "spot_smooth", "cast_shadow", "spread",
                 "lobes"):
        joined[name] = np.concatenate([getattr(frames, name), extra[name]])
    joined["uv"] = np.concatenate([padded(frames.uv, width), padded(extra["uv"], width)])
    joined["vertices"] = np.concatenate([padded(frames.vertices, width), padded(extra["vertices"], width)])
    joined["vertex_count"] = np.concatenate([frames.vertex_count, extra["vertex_count"]])
    joined["source"] = np.concatenate([frames.source, extra["source"]])
    joined["hull_far"] = np.concatenate([frames.hull_far, extra.get("hull_far", np.zeros(len(extra["source"]), bool))])
    joined["excluded"] = np.concatenate([frames.excluded, extra.get("excluded", np.full(len(extra["source"]), -1,
                                                                                          np.int64))])
    joined["scene_light"] = np.concatenate([frames.scene_light, first_scene_light + extra["source"]])
    return LightFrames(**joined, hulls=frames.hulls)


def _polygon_frames(lights: Lights) -> LightFrames:
    vertices = np.asarray(lights.vertices, dtype=np.float64)
    newell = newell_normal(vertices)
    area = 0.5 * np.linalg.norm(newell, axis=1)
    normal = newell / np.maximum(2.0 * area, 1e-300)[:, None]
    origin = vertices[:, 0]
    tangent = vertices[:, 1] - origin
    tangent -= normal * np.einsum("lk,lk->l", tangent, normal)[:, None]
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-300)
    bitangent = np.cross(normal, tangent)
    rel = vertices - origin[:, None]
    uv = np.stack([np.einsum("lvk,lk->lv", rel, tangent), np.einsum("lvk,lk->lv", rel, bitangent)], axis=-1)
    return LightFrames(origin, tangent, bitangent, normal, uv, vertices, np.asarray(lights.vertex_count),
                       np.asarray(lights.radiance, dtype=np.float64), np.asarray(lights.two_sided, bool), area,
                       cast_shadow=np.asarray(lights.cast_shadow, bool), spread=np.asarray(lights.spread, np.float64),
                       lobes=np.asarray(lights.lobes, np.int64))


def newell_normal(polygons: np.ndarray) -> np.ndarray:
    """Newell's normal of padded polygons (N, K, 3) -> (N, 3): twice the area along the unit normal.
    Padding that repeats the last vertex adds nothing (its edges have zero length)."""
    return cross3(polygons, np.roll(polygons, -1, axis=1)).sum(axis=1)


def light_groups(frames: LightFrames) -> list[np.ndarray]:
    """Lights grouped by polygon size, (L,) bool masks: pieces are padded to the widest polygon of what is
    clipped together, so quads are not cut and integrated at a 32-gon disk's width. A handful of groups
    (vertex counts up to 4, 8, 16, ...)."""
    if len(frames) == 0:
        return []
    size_class = np.ceil(np.log2(np.maximum(frames.vertex_count, 4))).astype(np.int64)
    return [size_class == c for c in np.unique(size_class)]


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product over the last axis (any leading shape); cheaper than np.cross on small trailing axes."""
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx], axis=-1)


# ------------------------------------------------------------------------------------------------------
# Convex clipping
# ------------------------------------------------------------------------------------------------------

def clip_convex(points: np.ndarray, count: np.ndarray, side: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Keep the part of each convex polygon where the affine function ``side`` is >= 0 (see ``split_convex``).

    Parameters
    ----------
    points : (N, K, D) float64
        Padded polygons (D = 2 or 3).
    count : (N,) int64
        Real vertex counts (0 for an empty polygon).
    side : (N, K) float64
        The affine function's value at each vertex (any value at padding).

    Returns
    -------
    clipped : (N, K + 1, D) float64, padded by repeating the last vertex (zeros where nothing remains).
    clipped_count : (N,) int64, 0 where nothing (or less than a triangle) remains.
    """
    return split_convex(points, count, side, want_outside=False)[:2]


def split_convex(points: np.ndarray, count: np.ndarray, side: np.ndarray, want_outside: bool = True):
    """Both parts of each convex polygon cut by the line ``side`` = 0: where side >= 0 and where side < 0.

    Same parameters as ``clip_convex``. A convex polygon's inside vertices form one cyclic run, entered
    and left across one edge each, so each part is a gather: its run of vertices from where it starts,
    then the crossing where it ends and the crossing where it began (the original winding).

    Returns
    -------
    inside, inside_count, outside, outside_count : as ``clip_convex`` returns, for side >= 0 and side < 0
    (``outside`` is None when ``want_outside`` is False). A vertex on the line belongs to the inside run;
    the outside part reaches it through a crossing at the vertex itself.
    """
    n, k, dims = points.shape
    rows = np.arange(n)
    last = np.maximum(count - 1, 0)
    valid = np.arange(k)[None, :] < count[:, None]

    def runs(side):
        inside = side >= 0.0
        # Each vertex's successor: the next slot, except that the last real vertex closes onto vertex 0.
        inside_next = np.roll(inside, -1, axis=1)
        inside_next[rows, last] = inside[:, 0]
        return inside, (inside != inside_next) & valid

    inside, change = runs(side)
    # A convex polygon crosses a line at most twice. Nearly collinear vertices lying within rounding of
    # the line can alternate sides and cross it more often (seen on the chapel's slats at 64 samples per
    # pixel): such a polygon touches the line only within rounding, so it is kept whole on the side where
    # its vertices lean.
    tangled = change.sum(axis=1) > 2
    if tangled.any():
        side = side.copy()
        side[tangled] = np.where(np.where(valid[tangled], side[tangled], 0.0).sum(axis=1) >= 0.0, 1.0, -1.0
                                 )[:, None]
        inside, change = runs(side)
    n_inside = (inside & valid).sum(axis=1)
    # The edge leaving the inside run and the edge entering it (edge i joins vertex i to its successor).
    exit_edge = np.argmax(change & inside, axis=1)
    enter_edge = np.argmax(change & ~inside, axis=1)
    exit_next = np.where(exit_edge == last, 0, exit_edge + 1)
    enter_next = np.where(enter_edge == last, 0, enter_edge + 1)

    def crossing(edge, following):
        a, b = side[rows, edge], side[rows, following]
        with np.errstate(divide="ignore", invalid="ignore"):  # rows without crossings are never gathered
            return points[rows, edge] + (a / (a - b))[:, None] * (points[rows, following] - points[rows, edge])

    # Slots k and k + 1: the exit and entry crossings; slot k + 2: zeros for empty parts.
    extended = np.concatenate([points, crossing(exit_edge, exit_next)[:, None],
                               crossing(enter_edge, enter_next)[:, None], np.zeros((n, 1, dims))], axis=1)
    slot = np.arange(k + 1)[None, :]
    cut = (n_inside > 0) & (n_inside < count)

    def part(run_start, run_length, end_crossing, start_crossing, whole):
        """Gather one part (N, K + 1, D) and its count; ``whole`` rows keep the polygon as it is."""
        index = np.where(slot < run_length[:, None], (run_start[:, None] + slot) % np.maximum(count, 1)[:, None],
                         np.where(slot == run_length[:, None], end_crossing, start_crossing))
        index = np.where(whole[:, None], np.minimum(slot, last[:, None]), index)
        part_count = np.where(cut, run_length + 2, np.where(whole, count, 0))
        index = np.where((part_count < 3)[:, None], k + 2, index)
        return np.take_along_axis(extended, index[:, :, None], axis=1), np.where(part_count >= 3, part_count, 0)

    inside_part, inside_count = part(enter_next, n_inside, k, k + 1, n_inside == count)
    if not want_outside:
        return inside_part, inside_count, None, None
    outside_part, outside_count = part(exit_next, count - n_inside, k + 1, k, (n_inside == 0) & (count > 0))
    return inside_part, inside_count, outside_part, outside_count


def polygon_area_2d(uv: np.ndarray) -> np.ndarray:
    """Signed area of padded 2-D polygons (N, K, 2) -> (N,), positive when counter-clockwise."""
    nxt = np.roll(uv, -1, axis=1)
    return 0.5 * np.sum(uv[..., 0] * nxt[..., 1] - nxt[..., 0] * uv[..., 1], axis=1)


# A clipped light subtending at most this solid angle (steradians) gives less than this share of its radiance,
# far below a pixel's precision. Such a light is a point or a segment up to rounding (a light clipped to the
# receiver's horizon along one of its edges, or to one of its corners), and its cone's planes are not planes
# at all: detection's arc test kept every edge it was given there, whose arcs made up a visible region of
# their own (a box inside a torus emitter's hole, a light per face: 9.42 where the reference gives 0.072).
NEGLIGIBLE_SOLID_ANGLE = 1e-12


def negligible_lights(uv: np.ndarray, count: np.ndarray, height: np.ndarray) -> np.ndarray:
    """Which clipped lights subtend at most NEGLIGIBLE_SOLID_ANGLE from their receivers: (N,) bool.

    uv : (N, K, 2) float64   the lights' (u, v) polygons in their planes (m), ``count`` (N,) int64 vertices each.
    height : (N,) float64    each receiver's distance from its light's plane (m; of either sign).

    A region of area a whose points all lie at distance |height| or more subtends at most a / height^2. The
    areas are compiled (``_polygon_areas``): in numpy over the padded table they took 0.5 us a couple of a
    disk light (34 vertices), a second per frame of suzanne's samples at 512 px."""
    area = np.empty(len(count))
    _polygon_areas(np.ascontiguousarray(uv, np.float64), np.ascontiguousarray(count, np.int64), area)
    return np.abs(area) <= NEGLIGIBLE_SOLID_ANGLE * np.asarray(height) * np.asarray(height)


@njit(cache=True, nogil=True)
def _polygon_areas(uv, count, out):
    """Signed area of each polygon uv[n, :count[n]] (N, K, 2) into ``out`` (N,), its first vertex taken as
    the origin (no cancellation between coordinates far from the light's centre)."""
    for n in range(len(count)):
        twice = 0.0
        u0, v0 = uv[n, 0, 0], uv[n, 0, 1]
        for k in range(1, count[n] - 1):
            twice += (uv[n, k, 0] - u0) * (uv[n, k + 1, 1] - v0) - (uv[n, k + 1, 0] - u0) * (uv[n, k, 1] - v0)
        out[n] = 0.5 * twice


def pad_to(points: np.ndarray, width: int) -> np.ndarray:
    """Pad (M, K, D) polygons to K = width by repeating the last column (already the last vertex)."""
    if points.shape[1] >= width:
        return points
    return np.concatenate([points, np.repeat(points[:, -1:], width - points.shape[1], axis=1)], axis=1)


def trim(points: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Drop trailing padding columns that no polygon uses (keeps at least 3)."""
    width = max(int(count.max()) if len(count) else 3, 3)
    return points[:, :width]


def polygon_bounds(uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per polygon of (N, V, 2) float64 points (padding repeating a real vertex), the low and high corners
    (N, 2) of its bounding rectangle. Reduced per coordinate over a flat row: numpy's min over the middle
    axis of (N, V, 2) runs an inner loop of length 2, nine times as slow on (100000, 36, 2) (a profile of
    Suzanne at 512 px on one thread put 2.0 s in reductions before, 0.4 s after; whole renders did not
    move beyond the machine's noise)."""
    flat = uv.reshape(len(uv), -1)
    low = np.stack([flat[:, 0::2].min(axis=1), flat[:, 1::2].min(axis=1)], axis=1)
    high = np.stack([flat[:, 0::2].max(axis=1), flat[:, 1::2].max(axis=1)], axis=1)
    return low, high


# ------------------------------------------------------------------------------------------------------
# Blocker cones
# ------------------------------------------------------------------------------------------------------

def blocker_in_front_of_light(receiver: np.ndarray, polygon: np.ndarray, count: np.ndarray, light_origin: np.ndarray,
                              light_normal: np.ndarray, light_side: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The part of each blocker polygon strictly in front of its light, relative to the receiver.

    Parameters
    ----------
    receiver : (N, 3) float64        visible points x.
    polygon : (N, K, 3) float64      blocker vertices (world space, padded), count : (N,) int64.
    light_origin, light_normal : (N, 3)
    light_side : (N,) float64        +1 when x is on the light's normal side, -1 on its back (two-sided).

    Returns
    -------
    clipped : (N, K + 1, 3) float64  the blocker clipped to the light's x side, minus x (padded).
    count : (N,) int64               0 when no part of the blocker lies in front of the light.
    """
    height = light_side[:, None] * np.einsum("nvk,nk->nv", polygon - light_origin[:, None], light_normal)
    relative = polygon - receiver[:, None]
    scale = np.abs(relative).max(axis=(1, 2)) + np.abs(receiver).max(axis=1)
    # A vertex on the light's plane (a light set into a ceiling) blocks nothing.
    side = height - PLANE_EPS * scale[:, None]
    clipped = np.concatenate([relative, relative[:, -1:]], axis=1)
    count = np.asarray(count, dtype=np.int64).copy()
    real = np.arange(polygon.shape[1])[None, :] < count[:, None]
    straddle = np.flatnonzero((real & (side < 0)).any(axis=1))
    if len(straddle):
        clipped[straddle], count[straddle] = clip_convex(relative[straddle], count[straddle], side[straddle])
    return clipped, count


def cone_planes(polygon: np.ndarray, count: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inward unit normals of the planes through the origin and each edge of a convex polygon.

    Parameters
    ----------
    polygon : (N, K, 3) float64   polygon vertices relative to the cone's apex (padded).
    count : (N,) int64

    Returns
    -------
    planes : (N, K, 3) float64    unit normals; a direction w is inside the cone when planes . w > 0
                                  for every valid plane.
    valid : (N, K) bool           False for padding, degenerate edges and degenerate cones (apex in the
                                  polygon's plane: no solid angle).
    """
    n, k, _ = polygon.shape
    nxt = np.roll(polygon, -1, axis=1)
    edge_normal = np.cross(polygon, nxt)
    # Orientation: the polygon's (Newell) normal against the apex decides which side is inside.
    newell = edge_normal.sum(axis=1)
    lengths = np.linalg.norm(polygon, axis=2)
    orient = np.einsum("nk,nk->n", newell, polygon[:, 0])
    size = lengths.max(axis=1)
    nondegenerate = np.abs(orient) > 1e-12 * size ** 3
    sign = np.where(orient > 0, 1.0, -1.0)  # counter-clockwise about the apex-to-polygon axis -> inside is +
    norm = np.linalg.norm(edge_normal, axis=2)
    # Padding repeats the last vertex, so the real edges are 0 .. count-2 and the closing edge K-1.
    index = np.arange(k)[None, :]
    real_edge = (index <= count[:, None] - 2) | (index == k - 1)
    valid = real_edge & (norm > 1e-14 * (lengths * np.roll(lengths, -1, axis=1)))
    valid &= nondegenerate[:, None] & (count[:, None] >= 3)
    planes = edge_normal * (sign[:, None] / np.maximum(norm, 1e-300))[:, :, None]
    return planes, valid


def cones_overlap(blocker: np.ndarray, blocker_count: np.ndarray, light: np.ndarray, light_count: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Do the cones from the origin through a blocker and through a light intersect? Does the blocker's
    cone contain the light's?

    Separating-axis test on the sphere: two convex cones with a common apex are disjoint exactly when a
    face plane of one of them has the whole other cone on its outside.

    Parameters
    ----------
    blocker : (N, Kb, 3), blocker_count : (N,)   blocker polygon relative to the apex.
    light : (N, Kl, 3), light_count : (N,)       light polygon relative to the apex.

    Returns
    -------
    overlap : (N,) bool   conservative: touching cones count as overlapping.
    surround : (N,) bool  the light's cone lies strictly inside the blocker's.
    """
    b_planes, b_valid = cone_planes(blocker, blocker_count)
    l_planes, l_valid = cone_planes(light, light_count)
    light_dir = light / np.maximum(np.linalg.norm(light, axis=2, keepdims=True), 1e-300)
    blocker_dir = blocker / np.maximum(np.linalg.norm(blocker, axis=2, keepdims=True), 1e-300)
    # (N, Kb, Kl): blocker plane i against light vertex j (padding repeats real vertices: harmless).
    b_vs_l = np.einsum("nik,njk->nij", b_planes, light_dir)
    l_vs_b = np.einsum("njk,nik->nji", l_planes, blocker_dir)
    tol = 1e-12
    separated = ((b_vs_l.max(axis=2) < -tol) & b_valid).any(axis=1)
    separated |= ((l_vs_b.max(axis=2) < -tol) & l_valid).any(axis=1)
    has_cone = b_valid.any(axis=1) & (blocker_count >= 3)
    overlap = has_cone & ~separated
    inside_all = np.where(b_valid[:, :, None], b_vs_l > 1e-9, True).all(axis=(1, 2))
    surround = overlap & inside_all & (b_valid.sum(axis=1) >= 3)
    return overlap, surround


def plane_lines(planes: np.ndarray, receiver_in_light: np.ndarray, frames_index: np.ndarray,
                frames: LightFrames) -> np.ndarray:
    """Where planes through the receiver cut the light's plane, as lines in the light's (u, v) coordinates.

    Parameters
    ----------
    planes : (N, K, 3) float64       plane normals through the receiver (world space).
    receiver_in_light : (N, 3)       x - light origin, in world space.
    frames_index : (N,) int64        which light.

    Returns
    -------
    lines : (N, K, 3) float64        (a, b, c) with a u + b v + c = planes . (y - x) for y = origin + u t + v b.
    """
    tangent = frames.tangent[frames_index]
    bitangent = frames.bitangent[frames_index]
    a = np.einsum("nik,nk->ni", planes, tangent)
    b = np.einsum("nik,nk->ni", planes, bitangent)
    c = -np.einsum("nik,nk->ni", planes, receiver_in_light)
    return np.stack([a, b, c], axis=-1)


# ------------------------------------------------------------------------------------------------------
# Lambert's polygon formula
# ------------------------------------------------------------------------------------------------------

def projected_solid_angle(directions: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Integral of (normal . w) over the solid angle of each polygon (the paper's Eq. 3 without L / 2).

    Parameters
    ----------
    directions : (N, K, 3) float64   polygon vertices relative to the receiver, padded by repeating the
                                     last vertex, counter-clockwise about the axis from the receiver
                                     towards the polygon (any winding works: the sign is fixed by taking
                                     the polygon's side of ``normal``). Must lie in the upper hemisphere.
    normal : (N, 3) float64          unit receiver normal.

    Returns
    -------
    (N,) float64, steradians, >= 0: irradiance / radiance for a constant-radiance polygon.
    """
    return np.abs(np.einsum("nd,nd->n", irradiance_vector(directions), normal))


def irradiance_vector(directions: np.ndarray) -> np.ndarray:
    """The vector form factor of each polygon (Arvo 1994), (N, 3): its dot product with a unit normal is
    the polygon's projected solid angle about that normal (up to the sign set by the winding), and its
    direction is the cosine-weighted mean direction of the polygon. Arguments as ``projected_solid_angle``."""
    directions = np.ascontiguousarray(directions, np.float64)
    out = np.empty((directions.shape[0], 3))
    _irradiance_vectors(directions, out)
    return out


def projected_solid_angle_uv(uv: np.ndarray, count: np.ndarray, local: np.ndarray, normal_local: np.ndarray,
                             rows: np.ndarray | None = None) -> np.ndarray:
    """``projected_solid_angle`` of polygons in their light's plane, (N,): uv (N, K, 2) padded polygons in the
    light's (u, v) coordinates with ``count`` (N,) vertices, local (N, 3) the receiver in the light's frame
    (u, v, height), normal_local (N, 3) the unit receiver normal in that frame. A vertex seen from the
    receiver is (u - u_x, v - v_x, -height): no per-vertex change of basis, and no (N, K, 3) directions
    stored; only the real vertices are visited (the padding's zero-length edges add nothing). ``rows``
    (N,) int64: polygon n is uv[rows[n]] (a table read in place, ``VisiblePieces.rows``)."""
    out = np.empty(len(count))
    rows = np.arange(len(count)) if rows is None else np.ascontiguousarray(rows, np.int64)
    # Read in place, strided or not: the whole lights' polygons come trimmed (``trim``: a view of a table's
    # first columns), and making them contiguous first copied them, 0.8 s of suzanne's 15 s at 512 px on one
    # thread (the kernel is compiled for both layouts).
    _projected_solid_angles_uv(np.asarray(uv, np.float64), rows, np.ascontiguousarray(count, np.int64),
                               np.ascontiguousarray(local, np.float64), np.ascontiguousarray(normal_local, np.float64),
                               out)
    return out


@njit(cache=True, nogil=True, inline="always")
def _unit(a0, a1, a2):
    """The direction (a0, a1, a2) as a unit vector (scalars; a zero vector stays zero)."""
    length = max(np.sqrt(a0 * a0 + a1 * a1 + a2 * a2), 1e-300)
    return a0 / length, a1 / length, a2 / length


# Below this sine of the angle between an edge's ends, ``_unit_edge_vector`` takes its angle from a series.
SHORT_EDGE_SINE = 0.1


@njit(cache=True, nogil=True, inline="always")
def _unit_edge_vector(a0, a1, a2, b0, b1, b2):
    """One edge's term of the irradiance vector (times 2) between unit directions a and b: the unit vector
    of a x b times the angle between them (scalars: no arrays, so nothing to reference-count when inlined).
    The callers normalise each vertex once for the two edges that share it (as a function of both ends
    the normalising was half of the work, and the same numbers: the kernels' results are unchanged).

    The angle over its sine is arcsin(s) / s for an angle under a right one: where the sine is under
    SHORT_EDGE_SINE (a disk light's 64 edges seen from more than a few radii away) its series to s^12, whose
    next term is below 1.4e-16 there, replaces arctan2 and the division, half of the kernel's time
    (12.8 M edges of random disks: 0.28 -> 0.14 s, largest difference 3e-16 of the largest result)."""
    c0, c1, c2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    sin_sq = c0 * c0 + c1 * c1 + c2 * c2
    cos = a0 * b0 + a1 * b1 + a2 * b2
    if cos > 0.0 and sin_sq < SHORT_EDGE_SINE * SHORT_EDGE_SINE:
        x = sin_sq
        ratio = 1.0 + x * (1.0 / 6.0 + x * (3.0 / 40.0 + x * (5.0 / 112.0 + x * (35.0 / 1152.0 + x * (
            63.0 / 2816.0 + x * (231.0 / 13312.0))))))
    else:
        sin = np.sqrt(sin_sq)
        ratio = np.arctan2(sin, cos) / sin if sin > 1e-15 else 1.0
    return c0 * ratio, c1 * ratio, c2 * ratio


@njit(cache=True, nogil=True)
def _projected_solid_angles_uv(uv, rows, count, local, normal_local, out):
    # Borrowed (``borrowed``): no reference counting per polygon; the vertices are read in place, as the
    # directions (u - u_x, v - v_x, -height) ``_irradiance_vectors`` sums over, in its order of operations.
    uv, rows, count, local, normal_local = borrowed(uv), borrowed(rows), borrowed(count), borrowed(local), \
        borrowed(normal_local)
    out = borrowed(out)
    for n in range(len(count)):
        r = rows[n]
        k_count = min(count[n], uv.shape[1])
        if k_count < 3:
            out[n] = 0.0
            continue
        height = -local[n, 2]
        total0, total1, total2 = 0.0, 0.0, 0.0
        f0, f1, f2 = _unit(uv[r, 0, 0] - local[n, 0], uv[r, 0, 1] - local[n, 1], height)
        a0, a1, a2 = f0, f1, f2
        for k in range(k_count):
            b0, b1, b2 = f0, f1, f2  # the last edge closes onto vertex 0
            if k + 1 < k_count:
                b0, b1, b2 = _unit(uv[r, k + 1, 0] - local[n, 0], uv[r, k + 1, 1] - local[n, 1], height)
            e0, e1, e2 = _unit_edge_vector(a0, a1, a2, b0, b1, b2)
            total0 += e0
            total1 += e1
            total2 += e2
            a0, a1, a2 = b0, b1, b2
        out[n] = abs(0.5 * total0 * normal_local[n, 0] + 0.5 * total1 * normal_local[n, 1]
                     + 0.5 * total2 * normal_local[n, 2])


@njit(cache=True, nogil=True)
def _irradiance_vectors(directions, out):
    """Per polygon: 1/2 sum over its edges (u_k, u_k+1) of the unit vectors of u_k x u_k+1 times the angle
    between them (the padding's repeated vertex adds zero-length edges, which add nothing). Compiled: as
    numpy passes over (N, K, 3) temporaries it was the largest share of pass 2's integrals."""
    n_polygons, width = directions.shape[0], directions.shape[1]
    for n in range(n_polygons):
        total0, total1, total2 = 0.0, 0.0, 0.0
        f0, f1, f2 = _unit(directions[n, 0, 0], directions[n, 0, 1], directions[n, 0, 2])
        a0, a1, a2 = f0, f1, f2
        for k in range(width):
            b0, b1, b2 = f0, f1, f2  # the last edge closes onto vertex 0
            if k + 1 < width:
                b0, b1, b2 = _unit(directions[n, k + 1, 0], directions[n, k + 1, 1], directions[n, k + 1, 2])
            e0, e1, e2 = _unit_edge_vector(a0, a1, a2, b0, b1, b2)
            total0 += e0
            total1 += e1
            total2 += e2
            a0, a1, a2 = b0, b1, b2
        out[n, 0], out[n, 1], out[n, 2] = 0.5 * total0, 0.5 * total1, 0.5 * total2


# ------------------------------------------------------------------------------------------------------
# Receiver-light setup shared by both passes
# ------------------------------------------------------------------------------------------------------

@dataclass
class ReceiverLight:
    """A batch of (receiver, light) couples: the light as the receiver sees it.

    Attributes
    ----------
    light : (N,) int64           light index.
    uv : (N, K, 2) float64       the light clipped to the receiver's geometric and shading horizons, in the
                                 light's (u, v) coordinates (padded).
    count : (N,) int64           its vertex count, 0 when the light contributes nothing (behind the light,
                                 below the horizon).
    side : (N,) float64          +1 when the receiver is on the light's normal side, -1 on the back of a
                                 two-sided light.
    local : (N, 3) float64       the receiver in the light's frame: (u, v, height above the plane).
    receiver_in_light : (N, 3)   receiver minus the light's origin (world axes).
    """

    light: np.ndarray
    uv: np.ndarray
    count: np.ndarray
    side: np.ndarray
    local: np.ndarray
    receiver_in_light: np.ndarray

    def directions(self, frames: LightFrames, uv: np.ndarray | None = None, index: np.ndarray | None = None
                   ) -> np.ndarray:
        """World-space vectors from the receiver to points (N, K, 2) of the light plane -> (N, K, 3)."""
        uv = np.ascontiguousarray(self.uv if uv is None else uv, np.float64)
        rows = np.arange(len(self.light)) if index is None else np.arange(len(self.light))[index]
        out = np.empty(uv.shape[:2] + (3,))
        _directions(uv, rows, np.ascontiguousarray(self.light, np.int64), np.ascontiguousarray(self.local, np.float64),
                    frames.tangent, frames.bitangent, frames.normal, out)
        return out

    def take(self, index) -> "ReceiverLight":
        return ReceiverLight(self.light[index], self.uv[index], self.count[index], self.side[index], self.local[index],
                             self.receiver_in_light[index])

    def moved(self, frames: LightFrames, shift: np.ndarray) -> "ReceiverLight":
        """The couples with their receivers moved by ``shift`` (N, 3) (world units), their lights as they
        were clipped: what shadow rays leaving from a lifted origin see (Cycles' Shadow Terminator Geometry
        Offset)."""
        light = self.light
        local = self.local + np.stack([np.einsum("nk,nk->n", shift, frames.tangent[light]),
                                       np.einsum("nk,nk->n", shift, frames.bitangent[light]),
                                       np.einsum("nk,nk->n", shift, frames.normal[light])], axis=1)
        return ReceiverLight(light, self.uv, self.count, self.side, local, self.receiver_in_light + shift)


@njit(cache=True, nogil=True)
def _directions(uv, rows, light, local, tangent, bitangent, normal, out):
    """out[n, k] = (u - u_x) t + (v - v_x) b - h n for point k of row n (couple rows[n]): ``ReceiverLight.directions``
    without its (N, K, 3) temporaries."""
    for n in range(uv.shape[0]):
        c = rows[n]
        l = light[c]
        u0, v0, h = local[c, 0], local[c, 1], local[c, 2]
        for k in range(uv.shape[1]):
            du, dv = uv[n, k, 0] - u0, uv[n, k, 1] - v0
            for d in range(3):
                out[n, k, d] = du * tangent[l, d] + dv * bitangent[l, d] - h * normal[l, d]


def receiver_light(position: np.ndarray, geometric_normal: np.ndarray, shading_normal: np.ndarray,
                   light: np.ndarray, frames: LightFrames) -> ReceiverLight:
    """Set up (receiver, light) couples; all inputs (N, ...) with ``light`` (N,) int64."""
    rel = position - frames.origin[light]
    height = np.einsum("nk,nk->n", rel, frames.normal[light])
    side = np.where(frames.two_sided[light] & (height < 0), -1.0, 1.0)
    scale = np.abs(position).max(axis=1) + np.sqrt(frames.area[light])
    lit = side * height > PLANE_EPS * scale
    # Only as wide as the widest light involved: frames pad every light to the largest polygon (a disk).
    width = max(int(frames.vertex_count[light].max()), 3) if len(light) else 3
    horizons = plane_lines(np.stack([geometric_normal, shading_normal], axis=1), rel, light, frames)  # (N, 2, 3)
    polygon_uv, polygon_count = frames.uv[light, :width], np.where(lit, frames.vertex_count[light], 0)
    kind = frames.kind[light]
    facing_rows = np.flatnonzero((kind >= 0) & (kind != FACING_HULL))
    hull_rows = np.flatnonzero(kind == FACING_HULL)
    if len(facing_rows) or len(hull_rows):
        polygon_uv = polygon_uv.copy()
        polygon_count = polygon_count.copy()
    if len(facing_rows):  # point, spot and sun lights: each receiver's own polygon (``facing``)
        cap_uv, cap_count, _ = cap_polygons(frames, light[facing_rows], position[facing_rows])
        polygon_uv[facing_rows] = cap_uv[:, :width]
        polygon_count[facing_rows] = np.where(lit[facing_rows], cap_count, 0)
    if len(hull_rows):  # convex mesh emitters: each receiver's silhouette (``emitters``)
        hull_uv, hull_count, _, _ = hull_polygons(frames, light[hull_rows], position[hull_rows])
        polygon_uv[hull_rows] = hull_uv[:, :width]
        polygon_count[hull_rows] = np.where(lit[hull_rows], hull_count, 0)
    uv, count = clip_by_lines(polygon_uv, polygon_count, horizons)
    local = np.stack([np.einsum("nk,nk->n", rel, frames.tangent[light]),
                      np.einsum("nk,nk->n", rel, frames.bitangent[light]), height], axis=1)
    spread_rows = np.flatnonzero(frames.spread[light] < np.pi)
    if len(spread_rows):  # a Spread below 180 degrees: only the disk of the light that emits towards x
        lines = spread_lines(local[spread_rows], frames.spread[light[spread_rows]])
        narrowed, narrowed_count = clip_by_lines(uv[spread_rows], count[spread_rows], lines)
        uv = pad_to(uv, narrowed.shape[1])
        uv[spread_rows] = narrowed
        count = count.copy()
        count[spread_rows] = narrowed_count
    uv = trim(uv, count)
    return ReceiverLight(light, uv, count, side, local, rel)


def clip_by_lines(polygons: np.ndarray, count: np.ndarray, lines: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each convex 2-D polygon clipped to where all its lines hold, in one compiled pass.

    Parameters
    ----------
    polygons : (N, W, 2) float64   counter-clockwise, padded (``count`` (N,) real vertices; 0: empty).
    lines : (N, J, 3) float64      (a, b, c): the part where a u + b v + c >= 0 is kept (a vertex on a line
                                   is inside).

    Returns (N, W + J, 2) polygons padded by repeating the last vertex (zeros where empty) and their counts
    (N,) int64 (0 where less than a triangle is left). A convex polygon crosses a line at most twice; one
    whose vertices lie within rounding of a line and alternate sides (seen on the chapel's slats at 64
    samples per pixel) touches it only within rounding, and is kept whole on the side where it leans.
    """
    out = np.empty((polygons.shape[0], polygons.shape[1] + lines.shape[1], 2))
    out_count = np.empty(polygons.shape[0], np.int64)
    _clip_by_lines(np.ascontiguousarray(polygons, np.float64), np.ascontiguousarray(count, np.int64),
                   np.ascontiguousarray(lines, np.float64), out, out_count)
    return out, out_count


@njit(cache=True, nogil=True)
def _clip_by_lines(polygons, count_in, lines, out_uv, out_count):
    capacity = out_uv.shape[1]
    polygon = np.empty((capacity, 2))
    clipped = np.empty((capacity, 2))
    side = np.empty(capacity)
    for n in range(polygons.shape[0]):
        count = count_in[n]
        for k in range(count):
            polygon[k, 0], polygon[k, 1] = polygons[n, k, 0], polygons[n, k, 1]
        for h in range(lines.shape[1]):
            if count == 0:
                break
            a, b, c = lines[n, h, 0], lines[n, h, 1], lines[n, h, 2]
            below, total, changes = False, 0.0, 0
            for k in range(count):
                side[k] = a * polygon[k, 0] + b * polygon[k, 1] + c
                below |= side[k] < 0.0
                total += side[k]
            if not below:
                continue
            for k in range(count):
                changes += (side[k] >= 0.0) != (side[(k + 1) % count] >= 0.0)
            if changes > 2:  # tangled within rounding: whole on the side it leans to
                if total < 0.0:
                    count = 0
                continue
            kept = 0
            for k in range(count):
                j = (k + 1) % count
                if side[k] >= 0.0:
                    clipped[kept, 0], clipped[kept, 1] = polygon[k, 0], polygon[k, 1]
                    kept += 1
                if (side[k] >= 0.0) != (side[j] >= 0.0):
                    t = side[k] / (side[k] - side[j])
                    clipped[kept, 0] = polygon[k, 0] + t * (polygon[j, 0] - polygon[k, 0])
                    clipped[kept, 1] = polygon[k, 1] + t * (polygon[j, 1] - polygon[k, 1])
                    kept += 1
            count = kept if kept >= 3 else 0
            for k in range(count):
                polygon[k, 0], polygon[k, 1] = clipped[k, 0], clipped[k, 1]
        out_count[n] = count
        for k in range(capacity):
            last = min(k, max(count - 1, 0))
            out_uv[n, k, 0] = polygon[last, 0] if count > 0 else 0.0
            out_uv[n, k, 1] = polygon[last, 1] if count > 0 else 0.0


def compile_geometry() -> tuple:
    """Compile the geometry kernels (or load them from Numba's cache) on one-polygon inputs; returns them."""
    square = np.zeros((1, 4, 3))
    _irradiance_vectors(square, np.empty((1, 3)))
    for uv in (np.zeros((2, 4, 2)), np.zeros((2, 5, 2))[:, :4]):  # contiguous, and trimmed tables' views
        _projected_solid_angles_uv(uv, np.arange(2), np.zeros(2, np.int64), np.zeros((2, 3)), np.zeros((2, 3)),
                                   np.empty(2))
    _directions(np.zeros((1, 4, 2)), np.zeros(1, np.int64), np.zeros(1, np.int64), np.zeros((1, 3)), np.zeros((1, 3)),
                np.zeros((1, 3)), np.zeros((1, 3)), np.empty((1, 4, 3)))
    _clip_by_lines(np.zeros((1, 4, 2)), np.zeros(1, np.int64), np.zeros((1, 2, 3)), np.empty((1, 6, 2)),
                   np.empty(1, np.int64))
    _polygon_areas(np.zeros((1, 4, 2)), np.zeros(1, np.int64), np.empty(1))
    return _irradiance_vectors, _projected_solid_angles_uv, _directions, _clip_by_lines, _polygon_areas


def _first_primes(count: int) -> np.ndarray:
    """The first ``count`` primes, (count,) int64 (a sieve; count is a few hundred)."""
    limit = max(16, int(count * (np.log(count + 2) + np.log(np.log(count + 2)) + 2)))
    sieve = np.ones(limit, bool)
    sieve[:2] = False
    for p in range(2, int(limit ** 0.5) + 1):  # the sieve's primes up to sqrt(limit): a few dozen
        if sieve[p]:
            sieve[p * p::p] = False
    return np.flatnonzero(sieve)[:count].astype(np.int64)


# Weights of the light's vertices in the reference point: positive (R inside the convex light) and
# irregular, so that R lies on no arc's plane in any regular arrangement: 1 + the fractional parts of the
# square roots of the primes, between which no relation with small integer coefficients holds. (A golden-
# ratio sequence has them: its weights k = 1..4 satisfy w1 + w4 = w2 + w3, which put R on the midline of
# every parallelogram light, where a blocker edge centred under a square light lies.)
_REFERENCE_WEIGHTS = 1.0 + np.modf(np.sqrt(_first_primes(256).astype(np.float64)))[0]


def reference_points(uv: np.ndarray, count: np.ndarray) -> np.ndarray:
    """A generic interior point R of each convex polygon (N, V, 2) with ``count`` (N,) vertices, (N, 2): its
    vertices' mean under irregular positive weights (``_REFERENCE_WEIGHTS``)."""
    out = np.empty((len(count), 2))
    _reference_points(np.ascontiguousarray(uv, np.float64), np.ascontiguousarray(count, np.int64),
                      _REFERENCE_WEIGHTS, out)
    return out


@njit(cache=True, nogil=True)
def _reference_points(uv, count, weights, out):
    for n in range(len(count)):
        total, u, v = 0.0, 0.0, 0.0
        for k in range(count[n]):
            total += weights[k]
            u += weights[k] * uv[n, k, 0]
            v += weights[k] * uv[n, k, 1]
        total = max(total, 1e-300)
        out[n, 0], out[n, 1] = u / total, v / total
