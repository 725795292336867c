"""Cycles' Shadow Terminator Geometry Offset: shadow rays of smooth-shaded triangles leave from the smooth
surface their vertex normals describe, not from the flat triangle.

A coarse smooth-shaded mesh shades by its interpolated normals but casts shadows by its flat triangles, so
near the terminator (light grazing the surface) a triangle's neighbours hide the light from points that
the shading normal says are lit: the blocky shadow line of low-poly spheres. Cycles lifts each shadow
ray's origin, by an amount that grows as the ray's direction grazes the surface, onto a parabolic patch
through the triangle's corners (Hanika, *Hacking the Shadow Terminator*, Ray Tracing Gems II, 2021).
Blender gives every object this offset (Object > Shading > Shadow Terminator > Geometry Offset, 0.1
by default), so a user's smooth meshes render with it.

Here the lift of every visible point is worked out once (``terminator_lift``, at pass 1), and pass 2's
couples whose light any of it reaches (``terminator_couples``) are seen from lifted origins: their light
is cut into strips over which the amount changes little, each strip a couple of its own seen from the
origin its mean amount gives. Most such couples need no strips: where no edge's arc crosses the light
from any origin the lift gives its directions (``_arcs_may_cross``, a walk of the edge tree over the
segment of origins), every strip would see the light whole or not at all, alike, and the couple stays
one strip. The rest of pass 2 is unchanged: a strip's arcs, depths and fans are a couple's, integrated
from the receiver itself.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .detection import hull_table, segment_may_cross
from .edge_tree import LEAF_EDGES, MeshEdges
from .geometry import (PLANE_EPS, LightFrames, ReceiverLight, clip_by_lines, negligible_lights, pad_to, receiver_light,
                       trim)


def terminator_lift(corners: np.ndarray, normals: np.ndarray, u: np.ndarray, v: np.ndarray,
                    geometric_normal: np.ndarray) -> np.ndarray:
    """The offset (N, 3) from a point of a flat triangle to the smooth surface its vertex normals describe,
    as Cycles' Shadow Terminator Geometry Offset computes it (Hanika, *Hacking the Shadow Terminator*,
    Ray Tracing Gems II, 2021): a parabolic patch through the corners that meets the vertex normals,
    bounded by the tangent planes at the corners, along the interpolated (not normalised) vertex normal.

    Parameters
    ----------
    corners, normals : (N, 3, 3)     the triangle's vertices and unit vertex normals (world space).
    u, v : (N,)                      barycentrics: the point is (1 - u - v) corner 0 + u corner 1 + v corner 2.
    geometric_normal : (N, 3)        unit, on the side the light is seen from (the lift points there).
    """
    weights = np.stack([1.0 - u - v, u, v], axis=1)                                   # (N, 3)
    point = np.einsum("nc,nck->nk", weights, corners)
    normal = np.einsum("nc,nck->nk", weights, normals)
    w0, w1 = weights[:, 0], weights[:, 1]
    V0, V1, V2 = corners[:, 0], corners[:, 1], corners[:, 2]
    N0, N1, N2 = normals[:, 0], normals[:, 1], normals[:, 2]

    def dot(a, b):
        return np.einsum("nk,nk->n", a, b)

    a, b, c = dot(N2 - N0, V0 - V2), dot(N2 - N1, V1 - V2), dot(N1 - N0, V1 - V0)
    height = a * w0 * (w0 - 1.0) + (a + b + c) * w0 * w1 + b * w1 * (w1 - 1.0)
    front = dot(normal, geometric_normal) > 0
    sign = np.where(front, 1.0, -1.0)  # the tangent planes' envelope on the side the normals point to
    envelope = np.full(len(u), np.inf)
    for k in range(3):  # the three corners
        others = [corners[:, j] for j in range(3) if j != k]
        reach = np.maximum(np.maximum(sign * dot(others[0] - corners[:, k], normals[:, k]),
                                      sign * dot(others[1] - corners[:, k], normals[:, k])), 0.0)
        envelope = np.minimum(envelope, np.maximum(sign * dot(corners[:, k] - point, normals[:, k]) + reach, 0.0))
    height = np.where(front, np.maximum(envelope, 0.5 * height), np.minimum(-envelope, 0.5 * height))
    return normal * height[:, None]


def lift_amount(cutoff: np.ndarray, shading_normal: np.ndarray, geometric_normal: np.ndarray,
                direction: np.ndarray) -> np.ndarray:
    """How much of ``SurfacePoints.lift`` Cycles applies to a shadow ray leaving towards unit ``direction``
    (N, 3), (N,) in 0 .. 1: all of it where the light grazes the surface (geometric and shading normals'
    cosines with the ray summing to less than the cutoff), none where either cosine reaches twice it."""
    shading_cos = np.abs(np.einsum("nk,nk->n", shading_normal, direction))
    geometric_cos = np.einsum("nk,nk->n", geometric_normal, direction)
    with np.errstate(divide="ignore", invalid="ignore"):
        amount = np.where(shading_cos < cutoff, np.clip(2.0 - (geometric_cos + shading_cos) / cutoff, 0.0, 1.0),
                          np.clip(1.0 - geometric_cos / cutoff, 0.0, 1.0))
    return np.where(cutoff > 0, amount, 0.0)


# A moved couple's light is cut into strips across which the offset's amount changes by at most this
# much, each seen from its own origin, at most TERMINATOR_STRIPS of them.
TERMINATOR_STEP = 0.25
TERMINATOR_STRIPS = 4


def terminator_couples(surface, frames: LightFrames, couples: ReceiverLight, couple_pixel: np.ndarray,
                       lights: np.ndarray, edges: MeshEdges | None = None
                       ) -> tuple[ReceiverLight, np.ndarray, np.ndarray | None]:
    """Cycles' Shadow Terminator Geometry Offset: a shadow ray leaving a smooth-shaded triangle towards
    grazing light starts from the smooth surface its vertex normals describe (``surface.SurfacePoints.lift``),
    moved by an amount that grows as its direction grazes (``lift_amount``).

    From a moved origin the light is seen wherever the shading normal sees it (Cycles' rays below the
    triangle's own plane meet the triangle itself, or, lifted, pass it), so a (point, light) couple whose
    light needs any offset is set up again with its light clipped to the shading horizon alone (a light
    wholly below the triangle's plane may come back) and its own triangle joins the occluders
    (``silhouette_pieces``). Its light is cut into strips across the direction in which the amount
    changes (fitted over the light's vertices), by steps of TERMINATOR_STEP, each strip seen from the
    origin its mean amount gives: the pieces of a couple's strips add up to its light's. Where no edge's arc
    crosses the light from any origin of the segment the lift spans (``detection.segment_may_cross`` over the
    scene's ``edges``; None: not tested), every strip would see what one origin sees: the couple stays one
    strip, its whole light seen from the origin of the largest amount its directions take.

    Parameters: the batch's ``couples`` and ``couple_pixel`` (``couples_for``) of the lights ``lights``
    (L,) bool. Returns the couples to work out and integrate (each strip a couple of its own), their
    pixels, and their origins' shifts (Nc', 3) float64, or None where nothing moves.
    """
    # Points whose lift is 0 (flat-shaded, or a triangle's corner) see what they saw.
    points = np.flatnonzero(surface.hit & (surface.lift_cutoff > 0) & (surface.lift != 0).any(axis=1))
    light_ids = np.flatnonzero(lights)
    if len(points) == 0 or len(light_ids) == 0:
        return couples, couple_pixel, None
    grazing = grazing_couples(surface.position[points], surface.geometric_normal[points], surface.lift_cutoff[points],
                              light_ids, frames)
    point_row, light_row = np.nonzero(grazing)
    if len(point_row) == 0:
        return couples, couple_pixel, None
    pixel = points[point_row]
    shading, geometric, cutoff = (surface.shading_normal[pixel], surface.geometric_normal[pixel],
                                  surface.lift_cutoff[pixel])
    wide = receiver_light(surface.position[pixel], shading, shading, light_ids[light_row], frames)
    # The amount before its clamp to 0 .. 1 at the light's vertices: a couple moves where it is positive
    # at some vertex (where the clamped amount is).
    raw = _lift_at(wide, frames, cutoff, shading, geometric, wide.uv, clamped=False)
    real = np.arange(wide.uv.shape[1])[None, :] < wide.count[:, None]
    moving = (wide.count >= 3) & (np.where(real, raw, 0.0).max(axis=1) > 0)
    if not moving.any():
        return couples, couple_pixel, None
    pixel, wide, raw = pixel[moving], wide.take(moving), raw[moving]
    shading, geometric, cutoff = shading[moving], geometric[moving], cutoff[moving]
    normals = (cutoff, shading, geometric)
    # Couples no edge's arc crosses from the origins the lift gives their directions: their light is seen
    # whole or not at all from every such origin, one strip seen from the largest amount's. The others are cut.
    crossed, largest = _arcs_may_cross(surface, frames, edges, pixel, wide) if edges is not None else \
        (np.ones(len(pixel), bool), np.ones(len(pixel)))
    cut = _strips(wide, frames, normals, raw, np.flatnonzero(crossed))
    if not crossed.all():
        rows = np.flatnonzero(~crossed)
        one = (rows, wide.uv[rows], wide.count[rows], largest[rows])  # seen from the largest amount's origin
        width = max(cut[1].shape[1], one[1].shape[1])
        cut = tuple(np.concatenate([pad_to(mine, width), pad_to(theirs, width)]) if mine.ndim == 3 else
                    np.concatenate([mine, theirs]) for mine, theirs in zip(cut[:4], one[:4]))
    owner, strip_uv, strip_count, strip_amount = cut[:4]
    # A strip cut off at a vertex of its light can be a sliver of no area: left out as ``couples_for`` leaves
    # out such lights.
    kept = ~negligible_lights(strip_uv, strip_count, wide.local[owner, 2])
    if not kept.all():
        owner, strip_uv, strip_count, strip_amount = owner[kept], strip_uv[kept], strip_count[kept], strip_amount[kept]
    strip = ReceiverLight(wide.light[owner], strip_uv, strip_count, wide.side[owner], wide.local[owner],
                          wide.receiver_in_light[owner])
    # The couples that stay, then the strips of those that move.
    moved = np.zeros((len(surface), len(frames)), bool)
    moved[pixel, wide.light] = True
    stay = ~moved[couple_pixel, couples.light]
    width = max(couples.uv.shape[1], strip_uv.shape[1])
    merged = ReceiverLight(np.concatenate([couples.light[stay], strip.light]),
                           np.concatenate([pad_to(couples.uv[stay], width), pad_to(strip_uv, width)]),
                           np.concatenate([couples.count[stay], strip_count]),
                           np.concatenate([couples.side[stay], strip.side]),
                           np.concatenate([couples.local[stay], strip.local]),
                           np.concatenate([couples.receiver_in_light[stay], strip.receiver_in_light]))
    merged_pixel = np.concatenate([couple_pixel[stay], pixel[owner]])
    shift = np.zeros((len(merged_pixel), 3))
    shift[int(stay.sum()):] = strip_amount[:, None] * surface.lift[pixel[owner]]
    return merged, merged_pixel, shift


def _arcs_may_cross(surface, frames: LightFrames, edges: MeshEdges, pixel: np.ndarray, wide: ReceiverLight
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Whether an edge's arc may cross the light ``wide`` (N couples, their pixels ``pixel``) from the origins
    the lift gives its directions (``detection.segment_may_cross``), (N,) bool, True also where they are not
    clearly in front of the light's plane or the lift does not leave the triangle's plane; and the largest
    amount of the lift any direction to the light takes, (N,) float64 in 0 .. 1 (1 where untested).

    A direction below the receiver's own (flat) plane takes the whole lift (``lift_amount`` is 1 wherever
    the geometric cosine is not positive), one above it at most the amount its smallest geometric and
    shading cosines over that part give (both cosines are smallest at a vertex: their level sets cut the
    light's plane in convex regions). So the light's part above the plane is tested from the segment
    receiver .. receiver + that amount of the lift, where its own triangle's edges are out of reach
    (segment and light on one side of its plane); the part below from the lift's end alone, every triangle
    counted. Where neither test finds an edge, every direction sees the same depth complexity from the
    origin it takes as from the origin of the largest amount."""
    light = wide.light
    near = surface.position[pixel]
    lift = surface.lift[pixel]
    far = near + lift
    toward = wide.side[:, None] * frames.normal[light]
    offset = np.einsum("nk,nk->n", toward, frames.origin[light])
    height_near = np.einsum("nk,nk->n", toward, near) - offset
    height_far = np.einsum("nk,nk->n", toward, far) - offset
    scale = np.abs(near).max(axis=1) + np.sqrt(frames.area[light])
    # The lift leaves the receiver's plane on the geometric normal's side (``terminator_lift``).
    rise = np.einsum("nk,nk->n", lift, surface.geometric_normal[pixel])
    testable = ((height_near > PLANE_EPS * scale) & (height_far > PLANE_EPS * scale) & (rise > PLANE_EPS * scale))
    may, amount = np.ones(len(pixel), bool), np.ones(len(pixel))
    rows = np.flatnonzero(testable)
    if len(rows) == 0:
        return may, amount
    # Two queries per couple: the light's part above the plane from the segment, its own triangle skipped;
    # the part below from the lift's end.
    width = wide.uv.shape[1] + 1  # a convex polygon cut by a line gains at most one vertex
    n_queries = 2 * len(rows)
    polygon, count = np.empty((n_queries, width, 3)), np.empty(n_queries, np.int64)
    start, end, low, high = (np.empty((n_queries, 3)) for _ in range(4))
    uv_low, uv_high, skipped = np.empty((n_queries, 2)), np.empty((n_queries, 2)), np.empty(n_queries, np.int64)
    largest = np.empty(len(rows))

    def rows_of(array):
        return np.ascontiguousarray(array[rows], np.float64)

    _lift_queries(rows_of(wide.uv), np.ascontiguousarray(wide.count[rows], np.int64),
                  np.ascontiguousarray(light[rows], np.int64), rows_of(near), rows_of(lift),
                  rows_of(surface.geometric_normal[pixel]), rows_of(surface.shading_normal[pixel]),
                  rows_of(surface.lift_cutoff[pixel]),
                  np.ascontiguousarray(surface.index_triangle[pixel[rows]], np.int64), frames.origin, frames.tangent,
                  frames.bitangent, polygon, count, start, end, low, high, uv_low, uv_high, skipped, largest)
    query_light, query_side = np.repeat(light[rows], 2), np.repeat(wide.side[rows], 2)
    height = np.repeat(np.maximum(height_near[rows], height_far[rows]), 2)
    hulls = hull_table(frames, low, high, query_light, query_side, height, uv_low, uv_high)
    # The part below is walked only where the part above found nothing.
    settled_by = np.where(np.arange(n_queries) % 2 == 1, np.arange(n_queries) - 1, -1)
    crossed = segment_may_cross(edges, LEAF_EDGES, hulls, query_light, start, end, polygon, count,
                                frames.excluded[query_light], skipped, settled_by)
    may[rows] = crossed[0::2] | crossed[1::2]
    amount[rows] = largest
    return may, amount


@njit(cache=True, nogil=True)
def _lift_queries(uv, count, light, near, lift, geometric, shading, cutoff, own, origin, tangent, bitangent, polygon,
                  out_count, start, end, low, high, uv_low, uv_high, skipped, largest):
    """``_arcs_may_cross``' two queries per couple n (rows 2n and 2n + 1 of the outputs): its light uv[n]
    (count[n] vertices) cut by the receiver's plane (through near[n], unit normal ``geometric``), the part
    above seen from near .. near + largest[n] lift[n] with its own triangle skipped, the part below from
    near + lift[n] alone. Writes each part's world polygon (2N, W, 3) and vertex count (fewer than 3:
    empty), the segment's start, end and box (low, high), the part's (u, v) bounds and the triangle skipped
    (-1: none); and ``largest`` (N,), the largest amount of the lift over the light (``lift_amount``'s bound
    by the smallest cosines over the part above, 1 if there is a part below)."""
    width = uv.shape[1]
    part = np.empty((width + 1, 2))
    for n in range(len(count)):
        l = light[n]
        g0, g1, g2 = geometric[n, 0], geometric[n, 1], geometric[n, 2]
        a = g0 * tangent[l, 0] + g1 * tangent[l, 1] + g2 * tangent[l, 2]
        b = g0 * bitangent[l, 0] + g1 * bitangent[l, 1] + g2 * bitangent[l, 2]
        c = g0 * (origin[l, 0] - near[n, 0]) + g1 * (origin[l, 1] - near[n, 1]) + g2 * (origin[l, 2] - near[n, 2])
        largest[n] = 1.0
        below = False
        for side in (1, 0):  # the part below first: where there is one, the part above reaches the whole lift
            q = 2 * n + side
            sign = 1.0 if side == 0 else -1.0
            kept = 0
            for k in range(count[n]):  # the polygon's edges: keep sign * (a u + b v + c) >= 0
                j = k + 1 if k + 1 < count[n] else 0
                value_k = sign * (a * uv[n, k, 0] + b * uv[n, k, 1] + c)
                value_j = sign * (a * uv[n, j, 0] + b * uv[n, j, 1] + c)
                if value_k >= 0:
                    part[kept, 0], part[kept, 1] = uv[n, k, 0], uv[n, k, 1]
                    kept += 1
                if (value_k >= 0) != (value_j >= 0) and kept < width + 1:
                    t = value_k / (value_k - value_j)
                    part[kept, 0] = uv[n, k, 0] + t * (uv[n, j, 0] - uv[n, k, 0])
                    part[kept, 1] = uv[n, k, 1] + t * (uv[n, j, 1] - uv[n, k, 1])
                    kept += 1
            out_count[q] = kept
            below |= side == 1 and kept >= 3
            if side == 0 and kept >= 3 and not below:
                # The smallest cosines over the part above, at its vertices.
                least_geometric, least_shading = np.inf, np.inf
                for k in range(kept):
                    d0 = origin[l, 0] + part[k, 0] * tangent[l, 0] + part[k, 1] * bitangent[l, 0] - near[n, 0]
                    d1 = origin[l, 1] + part[k, 0] * tangent[l, 1] + part[k, 1] * bitangent[l, 1] - near[n, 1]
                    d2 = origin[l, 2] + part[k, 0] * tangent[l, 2] + part[k, 1] * bitangent[l, 2] - near[n, 2]
                    length = max(np.sqrt(d0 * d0 + d1 * d1 + d2 * d2), 1e-300)
                    least_geometric = min(least_geometric, (d0 * g0 + d1 * g1 + d2 * g2) / length)
                    least_shading = min(least_shading, abs(d0 * shading[n, 0] + d1 * shading[n, 1]
                                                           + d2 * shading[n, 2]) / length)
                bound = max(1.0 - least_geometric / cutoff[n], 2.0 - (least_geometric + least_shading) / cutoff[n])
                largest[n] = min(max(bound, 0.0), 1.0)
            reach = largest[n] if side == 0 else 1.0
            for d in range(3):
                start[q, d] = near[n, d] + (0.0 if side == 0 else lift[n, d])
                end[q, d] = near[n, d] + reach * lift[n, d]
                low[q, d] = min(start[q, d], end[q, d])
                high[q, d] = max(start[q, d], end[q, d])
            skipped[q] = own[n] if side == 0 else -1
            uv_low[q, 0], uv_low[q, 1], uv_high[q, 0], uv_high[q, 1] = np.inf, np.inf, -np.inf, -np.inf
            for k in range(polygon.shape[1]):
                source = min(k, max(kept - 1, 0))  # padding repeats the last vertex
                u, v = part[source, 0], part[source, 1]
                uv_low[q, 0], uv_low[q, 1] = min(uv_low[q, 0], u), min(uv_low[q, 1], v)
                uv_high[q, 0], uv_high[q, 1] = max(uv_high[q, 0], u), max(uv_high[q, 1], v)
                for d in range(3):
                    polygon[q, k, d] = origin[l, d] + u * tangent[l, d] + v * bitangent[l, d]


def _strips(wide: ReceiverLight, frames: LightFrames, normals: tuple, raw: np.ndarray, rows: np.ndarray) -> tuple:
    """The strips of the moved couples ``rows`` of ``wide`` (their raw amounts ``raw`` (N, K) at its vertices,
    ``normals`` as ``_cut_strips`` takes them): the owner (a row of ``wide``), uv, count and amount of each
    (``_cut_strips``' first four). The raw amount fitted over the light's vertices by a plane in (u, v) grows
    along ``axis`` by ``gradient`` per unit of u . axis. Strips: one where the fit takes no lift, one where it
    takes all of it, and between them strips over which it changes by TERMINATOR_STEP (at most
    TERMINATOR_STRIPS of them); each strip is then seen from the origin its mean amount gives."""
    n_moving = len(rows)
    if n_moving == 0:
        return np.zeros(0, np.int64), np.zeros((0, 3, 2)), np.zeros(0, np.int64), np.zeros(0)
    axis, start, end = np.zeros((len(wide.count), 2)), np.empty(n_moving), np.empty(n_moving)
    low_level, high_level, middle = np.empty(n_moving), np.empty(n_moving), np.empty(n_moving, np.int64)
    plan_axis = np.empty((n_moving, 2))
    _strip_plan(np.ascontiguousarray(wide.uv[rows], np.float64), np.ascontiguousarray(wide.count[rows], np.int64),
                np.ascontiguousarray(raw[rows], np.float64), float(TERMINATOR_STEP), int(TERMINATOR_STRIPS),
                plan_axis, start, end, low_level, high_level, middle)
    axis[rows] = plan_axis
    below = (low_level > start).astype(np.int64)
    above = (high_level < end).astype(np.int64)
    strips = below + middle + above
    owner = np.repeat(np.arange(n_moving), strips)
    index = np.arange(int(strips.sum())) - np.repeat(np.cumsum(strips) - strips, strips)
    k, n = index - below[owner], np.maximum(middle[owner], 1)
    lo, hi = low_level[owner], high_level[owner]
    low = np.where(k < 0, start[owner], np.where(k < middle[owner], lo + (hi - lo) * k / n, hi))
    high = np.where(k < 0, lo, np.where(k < middle[owner], lo + (hi - lo) * (k + 1) / n, end[owner]))
    cut = _cut_strips(wide, frames, normals, axis, rows[owner], low, high, index == 0, index == strips[owner] - 1)
    # Where the fitted plane is far from the amount (a large light close by), a strip spans more: split
    # those once more, evenly, by the spread of the amount between their vertices.
    spread, low, high, first, last = cut[4:-1]
    pieces = np.where(spread > 2.0 * TERMINATOR_STEP, np.minimum(np.ceil(spread / TERMINATOR_STEP),
                                                                 TERMINATOR_STRIPS), 1).astype(np.int64)
    split = np.flatnonzero(pieces > 1)
    if len(split):
        # Only the strips split again are cut again (cutting every strip again, as this did, was a third of
        # the set-up on the Suzannes); the others keep their first cut, in their place.
        parts = pieces[split]
        parent = np.repeat(split, parts)
        index = np.arange(int(parts.sum())) - np.repeat(np.cumsum(parts) - parts, parts)
        lo, span, n = low[parent], high[parent] - low[parent], pieces[parent]
        again = _cut_strips(wide, frames, normals, axis, cut[0][parent], lo + span * index / n,
                            lo + span * (index + 1) / n, first[parent] & (index == 0), last[parent] & (index == n - 1))
        cut = _merged_strips(cut, again, np.flatnonzero(pieces == 1), parent[again[-1]], index[again[-1]])
    return cut[:4]


def _cut_strips(wide: ReceiverLight, frames: LightFrames, normals: tuple, axis: np.ndarray, owner: np.ndarray,
                low: np.ndarray, high: np.ndarray, first: np.ndarray, last: np.ndarray):
    """The strips low <= u . axis <= high (no lower bound where ``first``, no upper where ``last``) of the
    couples ``owner`` (S,) of ``wide``, clipped, empty ones dropped, as a tuple of (S',) arrays but for uv:
    owner, uv (S', W, 2), count, the lift's amount over each strip (its mean over the strip's area, by
    one point per fan triangle), the amount's spread between the strip's vertices, the kept strips'
    low, high, first and last, and their rows of the input (S',) int64. ``normals``: each couple's cutoff
    (N,), shading and geometric normals (N, 3)."""
    sides = np.stack([np.concatenate([axis[owner], -low[:, None]], axis=1),
                      np.concatenate([-axis[owner], high[:, None]], axis=1)], axis=1)
    sides[first, 0] = (0.0, 0.0, 1.0)
    sides[last, 1] = (0.0, 0.0, 1.0)
    uv, count = clip_by_lines(wide.uv[owner], wide.count[owner], sides)
    kept = count >= 3
    owner, uv, count = owner[kept], trim(uv[kept], count[kept]), count[kept]
    cutoff, shading, geometric = (np.ascontiguousarray(array[owner], np.float64) for array in normals)
    amount, spread = np.empty(len(owner)), np.empty(len(owner))
    _strip_amounts(np.ascontiguousarray(uv, np.float64), count, np.ascontiguousarray(wide.light[owner], np.int64),
                   np.ascontiguousarray(wide.local[owner], np.float64), frames.tangent, frames.bitangent,
                   frames.normal, cutoff, shading, geometric, amount, spread)
    return owner, uv, count, amount, spread, low[kept], high[kept], first[kept], last[kept], np.flatnonzero(kept)


def _merged_strips(cut: tuple, again: tuple, stay: np.ndarray, again_parent: np.ndarray, again_index: np.ndarray
                   ) -> tuple:
    """The owner, uv, count and amount (``_cut_strips``' first four) of the strips ``stay`` (rows of ``cut``)
    and of the strips ``again`` (cut anew from rows ``again_parent`` of ``cut``, ``again_index`` the k-th of
    each), each new strip where its parent was, in the order of k: the order cutting every strip again gave."""
    row = np.concatenate([stay, again_parent])
    order = np.lexsort((np.concatenate([np.zeros(len(stay), np.int64), again_index]), row))
    width = max(cut[1].shape[1], again[1].shape[1])
    merged = []
    for mine, theirs in zip(cut[:4], again[:4]):  # owner, uv, count, amount
        if mine.ndim == 3:  # the polygons, padded to one width
            mine, theirs = pad_to(mine, width), pad_to(theirs, width)
        merged.append(np.concatenate([mine[stay], theirs])[order])
    return tuple(merged)


@njit(cache=True, nogil=True)
def _strip_plan(uv, count, raw, step, most, axis, start, end, low_level, high_level, middle):
    """Per couple n (its light uv[n, :count[n]], the raw amount at those vertices ``raw`` (N, K)): the plane
    in (u, v) fitted to the raw amount by least squares about the vertices' centre, the unit ``axis`` (N, 2)
    along which it grows ((1, 0) where it is flat), the light's extent ``start`` .. ``end`` along it, the
    levels where the fit reaches 0 and 1 (clipped to that extent) and the strips between them, steps of
    ``step`` of the fit, at least 1 and at most ``most`` (0 where the levels meet). Compiled: as numpy
    passes over (N, K, 2) arrays this was a third of the strips' set-up on the Suzannes."""
    for n in range(len(count)):
        k_count = count[n]
        c0, c1, mean = 0.0, 0.0, 0.0
        for k in range(k_count):
            c0 += uv[n, k, 0]
            c1 += uv[n, k, 1]
            mean += raw[n, k]
        c0, c1, mean = c0 / k_count, c1 / k_count, mean / k_count
        m00, m01, m11, b0, b1 = 1e-30, 0.0, 1e-30, 0.0, 0.0
        for k in range(k_count):
            o0, o1, r = uv[n, k, 0] - c0, uv[n, k, 1] - c1, raw[n, k] - mean
            m00 += o0 * o0
            m01 += o0 * o1
            m11 += o1 * o1
            b0 += o0 * r
            b1 += o1 * r
        determinant = m00 * m11 - m01 * m01
        s0 = (m11 * b0 - m01 * b1) / determinant if determinant > 0 else 0.0
        s1 = (m00 * b1 - m01 * b0) / determinant if determinant > 0 else 0.0
        gradient = np.sqrt(s0 * s0 + s1 * s1)
        flat = not gradient > 1e-12
        a0, a1 = (1.0, 0.0) if flat else (s0 / gradient, s1 / gradient)
        axis[n, 0], axis[n, 1] = a0, a1
        low, high = np.inf, -np.inf
        for k in range(k_count):
            along = uv[n, k, 0] * a0 + uv[n, k, 1] * a1
            low, high = min(low, along), max(high, along)
        start[n], end[n] = low, high
        if flat:
            low_level[n], high_level[n] = low, high
            middle[n] = 1 if high > low else 0
            continue
        centre_along = c0 * a0 + c1 * a1
        level_low = min(max(centre_along - mean / gradient, low), high)
        level_high = min(max(centre_along + (1.0 - mean) / gradient, low), high)
        low_level[n], high_level[n] = level_low, level_high
        middle[n] = min(max(np.ceil((level_high - level_low) * gradient / step), 1), most) \
            if level_high > level_low else 0


def _lift_at(couples: ReceiverLight, frames: LightFrames, cutoff, shading, geometric, uv, clamped: bool = True
             ) -> np.ndarray:
    """``lift_amount`` (N, K) of the directions from each couple's receiver to points uv (N, K, 2) of its
    light's plane (every column, padding included); with ``clamped`` False before its clamp to 0 .. 1 (a
    continuous function: the two branches meet where the shading cosine equals the cutoff)."""
    out = np.empty(uv.shape[:2])
    _amounts(np.ascontiguousarray(uv, np.float64), np.ascontiguousarray(couples.light, np.int64),
             np.ascontiguousarray(couples.local, np.float64), frames.tangent, frames.bitangent, frames.normal,
             np.ascontiguousarray(cutoff, np.float64), np.ascontiguousarray(shading, np.float64),
             np.ascontiguousarray(geometric, np.float64), clamped, out)
    return out


@njit(cache=True, nogil=True)
def _amounts(uv, light, local, tangent, bitangent, normal, cutoff, shading, geometric, clamped, out):
    """``lift_amount`` (``_raw_amount`` where not ``clamped``) of the direction from receiver n to each
    point uv[n, k] of its light's plane, compiled: the (N, K, 3) directions are never stored."""
    for n in range(uv.shape[0]):
        l = light[n]
        u0, v0, h = local[n, 0], local[n, 1], local[n, 2]
        for k in range(uv.shape[1]):
            raw = _raw_amount(uv[n, k, 0], uv[n, k, 1], l, u0, v0, h, tangent, bitangent, normal, cutoff[n],
                              shading, geometric, n)
            out[n, k] = min(max(raw, 0.0), 1.0) if clamped else raw

@njit(cache=True, nogil=True, inline="always")
def _raw_amount(u, v, l, u0, v0, h, tangent, bitangent, normal, c, shading, geometric, n):
    """``lift_amount`` before its clamp to 0 .. 1 (0 where the cutoff is not positive) of the direction
    from receiver n (at (u0, v0), height h in light l's frame) to the point (u, v) of the light's plane:
    continuous, its two branches meet where the shading cosine equals the cutoff."""
    du, dv = u - u0, v - v0
    d0 = du * tangent[l, 0] + dv * bitangent[l, 0] - h * normal[l, 0]
    d1 = du * tangent[l, 1] + dv * bitangent[l, 1] - h * normal[l, 1]
    d2 = du * tangent[l, 2] + dv * bitangent[l, 2] - h * normal[l, 2]
    length = max(np.sqrt(d0 * d0 + d1 * d1 + d2 * d2), 1e-300)
    shading_cos = abs(d0 * shading[n, 0] + d1 * shading[n, 1] + d2 * shading[n, 2]) / length
    geometric_cos = (d0 * geometric[n, 0] + d1 * geometric[n, 1] + d2 * geometric[n, 2]) / length
    if not c > 0:
        return 0.0
    return 2.0 - (geometric_cos + shading_cos) / c if shading_cos < c else 1.0 - geometric_cos / c


@njit(cache=True, nogil=True, inline="always")
def _amount_at(u, v, l, u0, v0, h, tangent, bitangent, normal, c, shading, geometric, n):
    return min(max(_raw_amount(u, v, l, u0, v0, h, tangent, bitangent, normal, c, shading, geometric, n), 0.0), 1.0)


@njit(cache=True, nogil=True)
def _strip_amounts(uv, count, light, local, tangent, bitangent, normal, cutoff, shading, geometric, amount, spread):
    """Per strip n (a convex polygon uv[n, :count[n]]): the lift's mean amount over its area, one point
    (the centroid) per fan triangle, and the spread of the amount between its vertices. The amount is not
    bounded by its vertices' (a cosine peaks inside a segment), hence the area rule."""
    for n in range(len(count)):
        l = light[n]
        u0, v0, h, c = local[n, 0], local[n, 1], local[n, 2], cutoff[n]
        low, high = np.inf, -np.inf
        for k in range(count[n]):
            a = _amount_at(uv[n, k, 0], uv[n, k, 1], l, u0, v0, h, tangent, bitangent, normal, c, shading,
                           geometric, n)
            low, high = min(low, a), max(high, a)
        total, weighted = 0.0, 0.0
        for k in range(1, count[n] - 1):
            ax, ay = uv[n, k, 0] - uv[n, 0, 0], uv[n, k, 1] - uv[n, 0, 1]
            bx, by = uv[n, k + 1, 0] - uv[n, 0, 0], uv[n, k + 1, 1] - uv[n, 0, 1]
            area = 0.5 * abs(ax * by - ay * bx)
            cu = (uv[n, 0, 0] + uv[n, k, 0] + uv[n, k + 1, 0]) / 3.0
            cv = (uv[n, 0, 1] + uv[n, k, 1] + uv[n, k + 1, 1]) / 3.0
            weighted += area * _amount_at(cu, cv, l, u0, v0, h, tangent, bitangent, normal, c, shading, geometric, n)
            total += area
        amount[n] = weighted / total if total > 0 else 0.5 * (low + high)
        spread[n] = high - low


def grazing_couples(position: np.ndarray, geometric_normal: np.ndarray, cutoff: np.ndarray, light_ids: np.ndarray,
                    frames: LightFrames) -> np.ndarray:
    """(P, L) bool: the points (positions and unit normals (P, 3), cutoffs (P,)) whose direction to some
    point of light ``light_ids[l]`` may take a lift. ``lift_amount`` is 0 wherever the geometric cosine is
    at least twice the cutoff, and those directions form a convex cone: a light polygon none of whose
    vertices leaves that cone takes no lift anywhere. Most couples of a smooth mesh are such (the light
    well above the surface), and skip the strips' set-up."""
    out = np.zeros((len(position), len(light_ids)), np.bool_)
    _grazing(np.ascontiguousarray(position, np.float64), np.ascontiguousarray(geometric_normal, np.float64),
             np.ascontiguousarray(cutoff, np.float64), np.ascontiguousarray(light_ids, np.int64),
             np.ascontiguousarray(frames.vertices, np.float64), np.ascontiguousarray(frames.vertex_count, np.int64),
             out)
    return out


@njit(cache=True, nogil=True)
def _grazing(position, normal, cutoff, light_ids, vertices, vertex_count, out):
    for p in range(len(position)):
        limit = 2.0 * cutoff[p]
        for j in range(len(light_ids)):
            light = light_ids[j]
            for v in range(vertex_count[light]):
                d0 = vertices[light, v, 0] - position[p, 0]
                d1 = vertices[light, v, 1] - position[p, 1]
                d2 = vertices[light, v, 2] - position[p, 2]
                cosine = d0 * normal[p, 0] + d1 * normal[p, 1] + d2 * normal[p, 2]
                if cosine < limit * np.sqrt(d0 * d0 + d1 * d1 + d2 * d2):
                    out[p, j] = True
                    break


def compile_terminator() -> list:
    """Compile (or load from Numba's cache) this module's kernel; returns it."""
    three = np.zeros((1, 3))
    _grazing(three, three, np.zeros(1), np.zeros(1, np.int64), np.zeros((1, 3, 3)), np.zeros(1, np.int64),
             np.zeros((1, 1), np.bool_))
    _amounts(np.zeros((1, 3, 2)), np.zeros(1, np.int64), three, three, three, three, np.zeros(1), three, three,
             True, np.empty((1, 3)))
    _strip_amounts(np.zeros((1, 3, 2)), np.full(1, 3, np.int64), np.zeros(1, np.int64), three, three, three, three,
                   np.zeros(1), three, three, np.empty(1), np.empty(1))
    _strip_plan(np.zeros((1, 3, 2)), np.full(1, 3, np.int64), np.zeros((1, 3)), 0.25, 4, np.empty((1, 2)),
                np.empty(1), np.empty(1), np.empty(1), np.empty(1), np.empty(1, np.int64))
    _lift_queries(np.zeros((1, 3, 2)), np.full(1, 3, np.int64), np.zeros(1, np.int64), three, three, three, three,
                  np.ones(1), np.zeros(1, np.int64), three, three, three, np.empty((2, 4, 3)), np.empty(2, np.int64),
                  np.empty((2, 3)), np.empty((2, 3)), np.empty((2, 3)), np.empty((2, 3)), np.empty((2, 2)),
                  np.empty((2, 2)), np.empty(2, np.int64), np.empty(1))
    return [_grazing, _amounts, _strip_amounts, _strip_plan, _lift_queries]
