"""Pass 2 by silhouettes: the visible part of each light from the edges that cross it (beyond the paper).

Seen from a receiver x, let D(w) count the triangles that the segment from x towards direction w meets
before the light's plane (the depth complexity). The light is visible exactly where D = 0. D is constant
except across the arcs in which mesh edges project, and it jumps there by the sum of ±1 over the edge's
triangles (each triangle covers the side of the arc its third vertex lies on): 0 for an edge between two
faces seen from the same side, ±2 across a fold (a silhouette), ±1 across an open boundary (a leaf's
rim). So, per (receiver, light) couple:

1. **Detection, complete by construction.** Every edge whose arc may cross the light is found by culling
   an edge tree (``MeshEdges``) against boxes around groups of receivers and the light, and keeping the
   edges that can be silhouettes for some point of the group (a sign test of their faces' planes at the
   group box's corners); no shadow ray has to hit anything first.
2. **Arcs.** Per couple, the edges whose jump is not 0 (``_couple_arcs``), clipped to the part in front of
   the light's plane; their range inside the light's cone is kept.
3. **One reference depth.** D at one interior point R of the light, counted by a ray (``depth_counts``)
   and checked by probe rays; a cell of a heavy couple (``regions``) gets its D carried from R.
4. **The arrangement** (``arrangement``, compiled). The arcs split each other and the light's edges into
   pieces; D on each side of a piece is D(R) plus the jumps of the arcs that the arc from R to the
   piece's midpoint crosses. A piece with D = 0 on exactly one side (or a light edge piece with D = 0
   inside) bounds the visible region.
5. **Signed fans.** The visible region is the signed sum of the triangles (R, piece start, piece end):
   +1 where the visible side faces R, -1 otherwise (a winding-number identity), returned as
   ``VisiblePieces`` with signs, on which Lambert's formula and the analytic glossy lobes, integrals linear
   in the region, are taken unchanged.

The cost of a couple follows the arcs crossing its light (S of them: O(S²) for the arrangement), not the
triangles behind them: a dense smooth mesh shows a few silhouette arcs where the old pass 2 subtracted
hundreds of triangles. Laine et al., *Soft Shadow Volumes for Ray Tracing* (SIGGRAPH 2005), count depth
complexity from silhouette edges per light sample; here the region comes out exactly, in closed form.
Detection and arcs run on array batches (the loops are over tree levels, batches and a handful of light
edges); the arrangement, nested loops over a couple's arcs, is a Numba kernel.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numba import njit

from .arcs import Arcs, _cone_planes, _sort_by_couple
from .blockers import _union_find
from .arrangement import jumps_between, visible_fans
from .detection import HULL_WIDTH, _hull_rows, detect_arcs, hull_table
from .edge_tree import LEAF_EDGES, MeshEdges, _morton
from .geometry import (_REFERENCE_WEIGHTS, LightFrames, ReceiverLight, _reference_points, polygon_bounds,
                       reference_points, trim)
from .regions import couple_regions

# Receivers per detection query (neighbours in a Morton order of their positions), and per sub-group:
# a query's receivers share the walk down the edge tree, each sub-group dropping the nodes and edges that
# are a silhouette nowhere in its box.
GROUP_POINTS = 16
# Sub-groups of 4 once let through edges that one receiver's own hull dropped, and a box inside a torus
# emitter's hole came out 9.42 where the reference gives 0.072 (2026-12-05): not a sub-group test dropping an
# edge, as it seemed then, but couples whose clipped light was a point or a segment (a torus face seen along
# the receiver's horizon), whose cone clips no arc, so that every edge given to the arc test was an arc.
# Those lights are left out now (``geometry.negligible_lights``); with them gone the sub-groups of 4 find
# the arcs each couple alone finds (the same images bit for bit: suzanne_dense3, floating_boxes, chapel at
# 512 px) and are faster (one thread, alternating: suzanne_dense3 21.98 / 23.20 -> 21.06 / 21.20 s,
# floating_boxes 5.61 / 5.72 -> 5.07 / 5.21 s; 8 no faster again).
SUB_POINTS = 4
# Arcs per chunk of couples whose detection, regions, depths, arrangement and integrals are worked out
# together (about 7 MB of arcs).
ARC_CHUNK = 1 << 16
# Hits a reference depth ray may count before it gives up (the scene is then assumed solid there).
DEPTH_ROUNDS = 64


# ------------------------------------------------------------------------------------------------------
# Arcs per couple
# ------------------------------------------------------------------------------------------------------

def bounding_cone(couples: ReceiverLight, frames: LightFrames) -> np.ndarray:
    """Inward normals (Nc, 4, 3) of the cone from each receiver through the (u, v) bounding box of its
    clipped light: a cone holding the light's, for a quick test."""
    out = np.empty((len(couples.count), 4, 3))
    _bounding_cones(np.ascontiguousarray(couples.uv, np.float64), np.ascontiguousarray(couples.count, np.int64),
                    np.ascontiguousarray(couples.light, np.int64), np.ascontiguousarray(couples.local, np.float64),
                    frames.tangent, frames.bitangent, frames.normal, out)
    return out


@njit(cache=True, nogil=True)
def _bounding_cones(uv, count, light, local, tangent, bitangent, normal, out):
    corners = np.empty((1, 4, 3))
    valid = np.empty((1, 4), np.bool_)
    four = np.full(1, 4, np.int64)
    for n in range(len(count)):
        u0, u1, v0, v1 = np.inf, -np.inf, np.inf, -np.inf
        for k in range(count[n]):
            u0, u1 = min(u0, uv[n, k, 0]), max(u1, uv[n, k, 0])
            v0, v1 = min(v0, uv[n, k, 1]), max(v1, uv[n, k, 1])
        l = light[n]
        for corner, (cu, cv) in enumerate(((u0, v0), (u1, v0), (u1, v1), (u0, v1))):
            du, dv = cu - local[n, 0], cv - local[n, 1]
            for d in range(3):
                corners[0, corner, d] = du * tangent[l, d] + dv * bitangent[l, d] - local[n, 2] * normal[l, d]
        _cone_planes(corners, four, out[n:n + 1], valid)


# ------------------------------------------------------------------------------------------------------
# The reference depth
# ------------------------------------------------------------------------------------------------------

def depth_counts(tracer, origin: np.ndarray, target: np.ndarray, own_triangle: np.ndarray, full: np.ndarray,
                 light: np.ndarray | None = None, edges: "MeshEdges | None" = None) -> np.ndarray:
    """Triangles met by the segments origin -> target (N, 3 each), short of the target's light plane, not
    counting ``own_triangle`` (N,); where ``full`` (N,) bool is False only 0 or 1 (hidden or not) is wanted.

    Hits are taken one layer at a time (Embree reports the nearest): a handful of rounds. A hit on the
    triangle just counted is the same layer met again after the step past it, and does not count. Between
    Embree's calls a compiled loop gathers the rays still going (in float32, as Embree takes them) and
    steps them past their hits, without the GIL: as numpy passes these rounds held it for about half of
    their time (the chairs at 512 px: 2.6 of 4.6 s), which the other render thread waited out.
    """
    n = len(origin)
    direction = np.ascontiguousarray(target - origin, np.float64)
    start = np.array(origin, np.float64, order="C")
    reach = np.full(n, 1.0 - 1e-6)
    last = np.full(n, -1, np.int64)
    count = np.zeros(n, np.int64)
    active = np.arange(n, dtype=np.int64)
    own = np.ascontiguousarray(own_triangle, np.int64)
    full = np.ascontiguousarray(full, np.bool_)
    planes = np.ascontiguousarray(edges.in_light_planes if edges is not None and edges.in_light_planes is not None
                                  else np.zeros(0), np.int64)
    n_triangles = edges.n_triangles if edges is not None else 0
    light = np.ascontiguousarray(light if light is not None and len(planes) else np.zeros(n, np.int64), np.int64)
    ray_origin, ray_direction, ray_reach = np.empty((n, 3), np.float32), np.empty((n, 3), np.float32), \
        np.empty(n, np.float32)
    going = n
    for _ in range(DEPTH_ROUNDS):  # depth layers: a handful
        if going == 0:
            break
        _gather_depth_rays(active, going, start, direction, reach, ray_origin, ray_direction, ray_reach)
        triangle, t = tracer.nearest_float32(ray_origin[:going], ray_direction[:going], ray_reach[:going])
        going = _step_depth_rays(active, going, np.ascontiguousarray(triangle, np.int64),
                                 np.ascontiguousarray(t, np.float64), own, full, light, planes, n_triangles, start,
                                 direction, reach, last, count)
    return count


@njit(cache=True, nogil=True)
def _gather_depth_rays(active, going, start, direction, reach, ray_origin, ray_direction, ray_reach):
    """Rows 0 .. going - 1 of the float32 rays: the segments ``active[:going]``' current starts, directions
    and reaches (rounded down, as ``trace`` rounds a ``tfar``)."""
    for i in range(going):
        a = active[i]
        for k in range(3):
            ray_origin[i, k] = np.float32(start[a, k])
            ray_direction[i, k] = np.float32(direction[a, k])
        rounded = np.float32(reach[a])
        if rounded > reach[a]:
            rounded = np.nextafter(rounded, np.float32(-np.inf))
        ray_reach[i] = rounded


@njit(cache=True, nogil=True)
def _step_depth_rays(active, going, triangle, t, own, full, light, planes, n_triangles, start, direction, reach, last,
                     count):
    """One round's hits (``triangle`` (going,) int64, -1 on a miss; ``t`` float64) counted and stepped past:
    a hit on the segment's own triangle, on the triangle it counted last, or on a face in the segment's
    light's plane (``planes``: sorted keys light * n_triangles + triangle) does not count. Keeps in
    ``active`` (in order) the segments still going; returns their number."""
    kept = 0
    for i in range(going):
        a = active[i]
        tri = triangle[i]
        hit = tri >= 0
        counted = hit and tri != own[a] and tri != last[a]
        if counted and len(planes):
            key = light[a] * n_triangles + tri
            where = min(np.searchsorted(planes, key), len(planes) - 1)
            counted = planes[where] != key
        if counted:
            count[a] += 1
        step = (t[i] if hit else 0.0) + 1e-5
        for k in range(3):
            start[a, k] += step * direction[a, k]
        reach[a] -= step
        if hit:
            last[a] = tri
        if hit and reach[a] > 0 and (full[a] or count[a] == 0):
            active[kept] = a
            kept += 1
    return kept


# ------------------------------------------------------------------------------------------------------
# The door: visible pieces of a batch of receivers
# ------------------------------------------------------------------------------------------------------

def compile_silhouettes() -> tuple:
    """Compile this module's kernels and those it calls from ``arcs`` (or load them from Numba's cache);
    returns them. (``kernels.compile_kernels`` is the door that compiles every group a render needs.)"""
    _cone_planes(np.zeros((1, 3, 3)), np.zeros(1, np.int64), np.empty((1, 3, 3)), np.empty((1, 3), np.bool_))
    Arcs.empty().by_couple(1)
    one_row, no_planes = np.zeros(1, np.int64), np.zeros(0, np.int64)
    _gather_depth_rays(one_row, 1, np.zeros((1, 3)), np.zeros((1, 3)), np.ones(1), np.empty((1, 3), np.float32),
                       np.empty((1, 3), np.float32), np.empty(1, np.float32))
    _step_depth_rays(one_row.copy(), 1, np.full(1, -1, np.int64), np.zeros(1), one_row, np.ones(1, np.bool_),
                     one_row, no_planes, 0, np.zeros((1, 3)), np.zeros((1, 3)), np.ones(1), np.full(1, -1, np.int64),
                     one_row.copy())
    _bounding_cones(np.zeros((1, 3, 2)), np.zeros(1, np.int64), np.zeros(1, np.int64), np.zeros((1, 3)), np.zeros((1, 3)),
                    np.zeros((1, 3)), np.zeros((1, 3)), np.empty((1, 4, 3)))
    _reference_points(np.zeros((1, 3, 2)), np.zeros(1, np.int64), _REFERENCE_WEIGHTS, np.empty((1, 2)))
    one, three = np.zeros(1), np.zeros((1, 3))
    _hull_rows(three, three, np.zeros(1, np.int64), one, one, three, three, three, three, np.zeros((1, 2)),
               np.zeros((1, 2)), np.empty((1, HULL_WIDTH)))
    _fan_triangles_kernel(np.zeros(1, np.int64), np.zeros(1, np.int64), three, three, three, three,
                          np.zeros((1, 2)), three, three, np.empty((1, 3, 2)))
    _union_find(np.zeros(1, np.int64), np.zeros(1, np.int64), 1)  # anti-aliasing's surfaces
    return (_union_find, _cone_planes, _sort_by_couple, _gather_depth_rays, _step_depth_rays, _bounding_cones,
            _reference_points, _hull_rows, _fan_triangles_kernel)


# Bytes of pass 2's per-couple temporaries per vertex of the clipped light (its cone, its directions, the
# analytic integrals over it): about 450 measured on suzanne_dense at 512 px (32-gon disks), rounded up.
COUPLE_VERTEX_BYTES = 512
# Fewer pixels per batch than this and per-batch overheads would make the render far slower than its work:
# the budget is then too small. (A mesh emitter of hundreds of faces, one light per triangle, takes batches
# of about a hundred pixels within the default 2 GB: slow, but it renders.)
MIN_PIXEL_BATCH = 16


def pixel_batch_for(memory_budget_mb: float, threads: int, frames: LightFrames) -> int:
    """Pixels per pass-2 batch: a quarter of the memory budget shared by the threads' batches, each pixel
    costing COUPLE_VERTEX_BYTES per light it takes and vertex of its clipped light (clipping at the horizons
    adds at most a few vertices). suzanne_dense at 512 px with batches of 16384 pixels peaked at 2.7 GB, with
    4096 at 0.95 GB, as fast.

    Raises MemoryError when the budget cannot hold even MIN_PIXEL_BATCH pixels per thread.
    """
    vertices = int(frames.vertex_count.max()) + 4 if len(frames) else 4
    # A receiver takes one plane of each lamp (three) and each convex emitter (six).
    virtual = frames.kind >= 0
    # (A non-convex emitter's receiver takes two: its near and its far light.)
    lights_taken = int((~virtual).sum()) + len(np.unique((frames.kind[virtual] * (len(frames) + 1)
                                                          + frames.source[virtual]) * 2
                                                         + frames.hull_far[virtual]))
    per_pixel = max(lights_taken, 1) * vertices * COUPLE_VERTEX_BYTES
    pixels = int(memory_budget_mb * 2 ** 20 / 4 / max(threads, 1) / per_pixel)
    if pixels < MIN_PIXEL_BATCH:
        needed = MIN_PIXEL_BATCH * per_pixel * max(threads, 1) * 4 / 2 ** 20
        raise MemoryError(f"memory budget of {memory_budget_mb:g} MB is too small for the silhouette batches of "
                          f"{max(threads, 1)} threads (at least {needed:.0f} MB); raise it")
    return pixels


# Vertex weights of the probe points (positive: inside the convex region), far from R's.
_PROBE_WEIGHTS = (0.35, 0.6, 0.85, 0.2)
# Probes cast first; the rest only where these and R's count differ (see _visible_parts).
PROBES_FIRST = 2


def _probe_points(uv: np.ndarray, count: np.ndarray, probe: np.ndarray) -> np.ndarray:
    """Probe points (N, 2) inside convex polygons (N, V, 2): probe ``probe`` (N,) int64 (an index into
    _PROBE_WEIGHTS) leans towards vertex probe * count / len(_PROBE_WEIGHTS) of its polygon."""
    rows = np.arange(len(count))
    corner = (probe * count) // len(_PROBE_WEIGHTS)
    weight = np.asarray(_PROBE_WEIGHTS)[probe]
    centre = reference_points(uv, count)
    return (1.0 - weight)[:, None] * centre + weight[:, None] * uv[rows, corner]


def _most_common(values: np.ndarray) -> np.ndarray:
    """Per row of (N, K) int64 values, the one that occurs most often, the largest among the most frequent."""
    counts = (values[:, :, None] == values[:, None, :]).sum(axis=2)             # (N, K) occurrences
    best = counts.max(axis=1, keepdims=True)
    return np.where(counts == best, values, np.iinfo(np.int64).min).max(axis=1)


def _fan_triangles(couples: ReceiverLight, frames: LightFrames, couple: np.ndarray, reference_uv: np.ndarray,
                   start: np.ndarray, end: np.ndarray) -> np.ndarray:
    """Fan triangles (M, 3, 2) float64 in (u, v): each piece's region reference point ``reference_uv``
    (M, 2), then where its directions ``start``, ``end`` (M, 3) from the receiver of ``couple`` (M,) int64
    meet the light's plane (inf or nan for a direction parallel to it, as numpy's division gives)."""
    out = np.empty((len(couple), 3, 2))
    _fan_triangles_kernel(np.ascontiguousarray(couple, np.int64), np.ascontiguousarray(couples.light, np.int64),
                          np.ascontiguousarray(couples.local, np.float64), frames.tangent, frames.bitangent,
                          frames.normal, np.ascontiguousarray(reference_uv, np.float64),
                          np.ascontiguousarray(start, np.float64), np.ascontiguousarray(end, np.float64), out)
    return out


@njit(cache=True, nogil=True, error_model="numpy")  # numpy's division: inf or nan, never an exception
def _fan_triangles_kernel(couple, light, local, tangent, bitangent, normal, reference_uv, start, end, out):
    for m in range(len(couple)):
        c = couple[m]
        l = light[c]
        out[m, 0, 0], out[m, 0, 1] = reference_uv[m, 0], reference_uv[m, 1]
        for corner in range(2):
            d = start[m] if corner == 0 else end[m]
            d_t = d[0] * tangent[l, 0] + d[1] * tangent[l, 1] + d[2] * tangent[l, 2]
            d_b = d[0] * bitangent[l, 0] + d[1] * bitangent[l, 1] + d[2] * bitangent[l, 2]
            d_n = d[0] * normal[l, 0] + d[1] * normal[l, 1] + d[2] * normal[l, 2]
            reach = -local[c, 2] / d_n
            out[m, 1 + corner, 0] = local[c, 0] + reach * d_t
            out[m, 1 + corner, 1] = local[c, 1] + reach * d_b


def silhouette_pieces(surface, frames: LightFrames, edges: MeshEdges, tracer, couples: ReceiverLight,
                      couple_pixel: np.ndarray, stats: dict, origin_shift: np.ndarray | None = None):
    """The visible region of each couple of a batch as signed triangles in its light's plane, in chunks of
    couples of about ARC_CHUNK arcs (a generator: a chunk's terms are integrated before the next chunk is
    worked out, so memory follows the chunk). Every couple's terms lie in one chunk.

    Parameters
    ----------
    surface : SurfacePoints of the batch; couples, couple_pixel : its lit couples (``couples_for``).
    stats : dict          counters to add to: tree nodes visited, edge candidates tested exactly, arcs,
                          reference depth rays, inconsistent couples, cells, most arcs of a couple; and
                          "arcs_of_couple" (Nc,) int64, filled in.
    origin_shift : (Nc, 3) float64 or None   where the light is seen from, relative to each receiver
                          (``terminator_couples``); the terms are integrated from the receiver.

    Yields
    ------
    uv : (M, 3, 2) float64 triangles (R, p, q), couple : (M,) int64, sign : (M,) float64,
    lights : (W,) int64   the couples whose whole clipped light (``couples.uv``) is a further term of sign
                          +1 (couples wholly visible, or whose hidden part the fans subtract),
    cells : (couple (C,), uv (C, K, 2), count (C,))   further terms of sign +1: the whole cells of heavy
                          couples.
    A couple with no term has no visible part (umbra).
    """
    n_couples = len(couple_pixel)
    stats["arcs_of_couple"] = arcs_of = np.zeros(n_couples, np.int64)
    if n_couples == 0:
        return
    position = surface.position[couple_pixel]
    own = surface.index_triangle[couple_pixel]
    if origin_shift is not None:
        couples = couples.moved(frames, origin_shift)
        position = position + origin_shift
        # From a lifted origin the receiver's own triangle is an occluder like any other: it can only hide
        # the light below its plane, as Cycles' shadow rays meet it there (it skips it above).
        own = np.where((origin_shift != 0).any(axis=1), -1, own)
    bound = bounding_cone(couples, frames)
    reference_uv = reference_points(couples.uv, couples.count)
    reference = couples.directions(frames, reference_uv[:, None, :], np.arange(n_couples))[:, 0]

    # Groups of receivers near each other; one query per (group, light).
    pixels = np.unique(couple_pixel)
    order = pixels[np.argsort(_morton(surface.position[pixels]), kind="stable")]
    group_of_pixel = np.full(len(surface), -1, np.int64)
    group_of_pixel[order] = np.arange(len(order)) // GROUP_POINTS
    n_lights = len(frames)
    group = group_of_pixel[couple_pixel]
    # One query per (group, light, side of the light): a two-sided light lights receivers of a group on
    # both of its sides, whose slabs differ.
    query_key = (group * n_lights + couples.light) * 2 + (couples.side > 0)
    morton_rank = np.empty(len(surface), np.int64)
    morton_rank[order] = np.arange(len(order))
    by_query = np.lexsort((morton_rank[couple_pixel], query_key))
    keys, query_first, query_size = np.unique(query_key[by_query], return_index=True, return_counts=True)
    query_group, query_light = keys // 2 // n_lights, keys // 2 % n_lights
    query_couple = by_query[query_first]
    query_side = couples.side[query_couple]
    height = couples.side * couples.local[:, 2]
    # Sub-groups: SUB_POINTS consecutive couples (Morton order) of a query, each with its own box and hull.
    rank_in_query = np.arange(n_couples) - np.repeat(query_first, query_size)
    query_units = -(-query_size // SUB_POINTS)
    query_unit = np.cumsum(query_units) - query_units
    unit_of = np.repeat(query_unit, query_size) + rank_in_query // SUB_POINTS   # per entry of by_query
    n_units = int(query_units.sum())
    unit_size = np.bincount(unit_of, minlength=n_units)
    unit_first = np.cumsum(unit_size) - unit_size
    unit_query = np.repeat(np.arange(len(keys)), query_units)
    # Boxes, heights and (u, v) rectangles (padding repeats a real vertex) of the sub-groups, then of the
    # queries (runs of sub-groups) and of the groups (runs of queries, the key's high part): reductions over
    # consecutive runs (a scattered ``np.minimum.at`` per couple cost the boxes' 512 px frame 0.44 s).
    uv_low, uv_high = polygon_bounds(couples.uv)                                # (Nc, 2)
    unit_low = np.minimum.reduceat(position[by_query], unit_first, axis=0)
    unit_high = np.maximum.reduceat(position[by_query], unit_first, axis=0)
    unit_height = np.maximum(np.maximum.reduceat(height[by_query], unit_first), 0.0)
    unit_uv_low = np.minimum.reduceat(uv_low[by_query], unit_first, axis=0)
    unit_uv_high = np.maximum.reduceat(uv_high[by_query], unit_first, axis=0)
    query_height = np.maximum.reduceat(unit_height, query_unit)
    query_uv_low = np.minimum.reduceat(unit_uv_low, query_unit, axis=0)
    query_uv_high = np.maximum.reduceat(unit_uv_high, query_unit, axis=0)
    new_group = np.r_[True, query_group[1:] != query_group[:-1]]
    group_first, query_group_run = np.flatnonzero(new_group), np.cumsum(new_group) - 1
    group_low = np.minimum.reduceat(np.minimum.reduceat(unit_low, query_unit, axis=0), group_first, axis=0)
    group_high = np.maximum.reduceat(np.maximum.reduceat(unit_high, query_unit, axis=0), group_first, axis=0)
    hulls = hull_table(frames, group_low[query_group_run], group_high[query_group_run], query_light, query_side,
                       query_height, query_uv_low, query_uv_high)
    unit_hulls = hull_table(frames, unit_low, unit_high, query_light[unit_query], query_side[unit_query], unit_height,
                            unit_uv_low, unit_uv_high)
    chunks = detect_arcs(edges, LEAF_EDGES, hulls, query_light, (query_unit, query_units, unit_hulls, unit_first,
                                                                 unit_size), by_query, couples, frames, position,
                         own, bound, reference, ARC_CHUNK)
    for (first, last), found, tests, visits in chunks:  # chunks of queries, about ARC_CHUNK arcs each
        members = np.sort(by_query[query_first[first]:query_first[last - 1] + query_size[last - 1]])
        arcs = Arcs(*found)  # in query order; gathered by couple where the regions are made
        arcs_of[members] = np.bincount(arcs.couple, minlength=n_couples)[members]
        stats["nodes_visited"] += visits
        stats["edge_tests"] += tests
        stats["arcs"] += len(arcs.couple)
        stats["max_arcs_per_couple"] = max(stats["max_arcs_per_couple"], int(arcs_of[members].max()))
        yield _visible_parts(surface, couple_pixel, couples, frames, edges, tracer, arcs, arcs_of, reference,
                             reference_uv, position, own, members, stats)


def _visible_parts(surface, couple_pixel, couples, frames, edges, tracer, arcs: Arcs, arcs_of: np.ndarray,
                   reference, reference_uv, position, own, members: np.ndarray, stats: dict):
    """Regions, reference depths and the arrangement of the couples ``members`` (sorted, whose arcs
    ``arcs`` are, in query order): signed fan triangles (uv (M, 3, 2), couple (M,), sign (M,)), the couples
    whose whole light is a term (W,) int64, and the cells that are whole terms (couple, uv, count); adds to
    ``stats``."""
    arcs = arcs.by_couple(len(couple_pixel))
    # Regions: a couple's light, or, where many arcs cross it (foliage), the cells of a grid over it, so
    # that the arrangement's cost (pairs of arcs) follows the arcs per cell.
    region_couple, region_polygons, region_count, region_arcs, region_ref_uv, cells, carry = couple_regions(
        couples, frames, arcs, arcs_of, reference, reference_uv, members)
    stats["cells"] += cells
    region_arcs_of = np.bincount(region_arcs.couple, minlength=len(region_couple))

    # The reference depth of each couple: counted fully where arcs cross its light, hidden or not elsewhere.
    # A cell's comes from its couple's, carried across the couple's arcs between the two reference points
    # (both inside the couple's convex light, whose arcs are all known): no ray per cell.
    pixel = couple_pixel[members]
    origin = position[members] + surface.offset[pixel][:, None] * surface.geometric_normal[pixel]
    crossed_members = np.flatnonzero(arcs_of[members] > 0)
    member_depth = depth_counts(tracer, origin, position[members] + reference[members], own[members],
                                arcs_of[members] > 0, couples.light[members], edges)
    stats["depth_rays"] += len(members)
    couple_arcs = dataclasses.replace(arcs, couple=np.searchsorted(members, arcs.couple))  # by member row
    # One ray can count too few layers (faces touching or overlapping where it passes, met at one
    # distance) or too many (through an edge two faces share): probe rays to other points of each
    # crossed light, carried back to R across the arcs between, each estimate D(R) too, and the value
    # most of the estimates give is kept (the larger on a tie).

    def probe_estimates(rows: np.ndarray, probes: list[int]) -> np.ndarray:
        """(len(rows), len(probes)) int64 estimates of D(R) of the couples members[rows]: each probe
        ray's count carried back to R."""
        probe_row = np.repeat(rows, len(probes))
        probe = np.tile(np.asarray(probes, np.int64), len(rows))
        probe_couple = members[probe_row]
        probe_uv = _probe_points(couples.uv[probe_couple], couples.count[probe_couple], probe)
        probe_dir = couples.directions(frames, probe_uv[:, None, :], probe_couple)[:, 0]
        probe_depth = depth_counts(tracer, origin[probe_row], position[probe_couple] + probe_dir,
                                   own[probe_couple], np.ones(len(probe_row), bool), couples.light[probe_couple],
                                   edges)
        between = jumps_between(couple_arcs, reference[members], probe_row, probe_dir, len(members))
        stats["depth_rays"] += len(probe_row)
        return (probe_depth - between).reshape(len(rows), len(probes))

    if len(crossed_members):
        # The mode of R's count and all probes' estimates, in two rounds: where R and the first two probes
        # agree, that value is the mode of all five whatever the other two give (three of five), so their
        # rays are cast only where the first three differ.
        estimates = np.concatenate([member_depth[crossed_members][:, None],
                                    probe_estimates(crossed_members, list(range(PROBES_FIRST)))], axis=1)
        assert 2 * estimates.shape[1] > len(_PROBE_WEIGHTS) + 1  # a unanimous first round is a majority
        split = np.flatnonzero((estimates != estimates[:, :1]).any(axis=1))
        decided = estimates[:, 0].copy()
        if len(split):
            rest = probe_estimates(crossed_members[split], list(range(PROBES_FIRST, len(_PROBE_WEIGHTS))))
            decided[split] = _most_common(np.concatenate([estimates[split], rest], axis=1))
        member_depth[crossed_members] = decided
    depth = member_depth[np.searchsorted(members, region_couple)] + carry

    # Regions crossed by no arc are wholly visible or wholly hidden: their polygon as it is.
    crossed = region_arcs_of > 0
    plain = np.flatnonzero(~crossed & (depth == 0) & (region_count >= 3))
    busy = np.flatnonzero(crossed)
    renumber = np.full(len(region_couple), -1, np.int64)
    renumber[busy] = np.arange(len(busy))
    sub = dataclasses.replace(region_arcs, couple=renumber[region_arcs.couple])
    # Directions only of the regions arcs cross: a disk light is a polygon of 64 vertices, and working
    # them out for every region took suzanne_dense3 at 512 px 2.8 s of 36 on one thread.
    busy_dirs = couples.directions(frames, region_polygons.take(busy), region_couple[busy])
    busy_ref = couples.directions(frames, region_ref_uv[busy][:, None, :], region_couple[busy])[:, 0]
    piece_region, p_start, p_end, sign, whole, inconsistent = visible_fans(
        sub, busy_dirs, region_count[busy], busy_ref, depth[busy])
    stats["inconsistent_couples"] += inconsistent
    piece_region = busy[piece_region]
    piece_couple = region_couple[piece_region]
    whole_regions = np.concatenate([plain, busy[whole]])
    uv = _fan_triangles(couples, frames, piece_couple, region_ref_uv[piece_region], p_start, p_end)
    # Whole regions: a couple's light is read in place from the couples' table by the integrals (gathering
    # them, most of a frame's couples, cost suzanne at 512 px 0.85 s of 13 on one thread); cells come
    # gathered.
    of_cell = region_polygons.region_cell[whole_regions] >= 0
    lights, cells = whole_regions[~of_cell], whole_regions[of_cell]
    polygons = (region_couple[cells], trim(region_polygons.take(cells), region_count[cells]), region_count[cells])
    return uv, piece_couple, sign, region_couple[lights], polygons
