"""From edge records to arcs: the exact per-receiver test of the candidates that detection finds.

Detection's walk (``detection``) meets (couple, edge record) pairs: edges that may be a silhouette
somewhere near a group of receivers and may cross the light. Each is tested here at its own receiver:
the jump (``jump_at``: the sum over the edge's faces of the side each face's third vertex lies on), then,
for the few whose jump is not 0 (``arc_test``), the part in front of the light's plane, a quick rejection
by the light's bounding quad and the exact range inside the light's cone. Those are the arcs.
Heavy couples' arcs are then assigned to the cells of a grid over the light (``regions``).

Millions of pairs of a few dozen flops each: compiled with Numba, called from detection's kernel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from .geometry import PLANE_EPS

# Relative tolerance of the sign tests (a third vertex this close to an arc's plane lies on it).
SIGN_EPS = 1e-12
# A plane of the light's cone this parallel to the arc's plane: the arc runs along the light's edge.
ON_BOUNDARY = 1.0 - 1e-13


# Columns of a couple table (``couple_table``), one row per (receiver, light) couple: the receiver, the
# triangle it lies on, the light's plane (unit normal towards the receiver, its offset: height of y above
# it = n . y - offset), the square root of the light's area (a length scale), the direction from the
# receiver to the reference point R, the inward normals of the cone through the light's bounding quad, and
# the emitter hull whose own faces block nothing of the light (``LightFrames.excluded``, -1 for none).
COUPLE_POSITION, COUPLE_OWN, COUPLE_TOWARD, COUPLE_OFFSET, COUPLE_SIZE, COUPLE_REFERENCE, COUPLE_BOUND = \
    0, 3, 4, 7, 8, 9, 12
COUPLE_EXCLUDED = 24
COUPLE_WIDTH = 25


def couple_table(position: np.ndarray, own_triangle: np.ndarray, light: np.ndarray, side: np.ndarray,
                 frames, reference: np.ndarray, bound: np.ndarray) -> np.ndarray:
    """(Nc, COUPLE_WIDTH) float64 rows of what the arc test reads per couple: position (Nc, 3), own_triangle
    (Nc,) int64, light (Nc,) int64 and side (Nc,) float64 (+1 / -1), ``LightFrames``, reference (Nc, 3),
    bound (Nc, 4, 3)."""
    toward = side[:, None] * frames.normal[light]
    offset = np.einsum("nk,nk->n", toward, frames.origin[light])
    table = np.concatenate([position, own_triangle[:, None].astype(np.float64), toward, offset[:, None],
                            np.sqrt(frames.area[light])[:, None], reference, bound.reshape(-1, 12),
                            frames.excluded[light][:, None].astype(np.float64)], axis=1)
    assert table.shape[1] == COUPLE_WIDTH
    return np.ascontiguousarray(table)


@njit(cache=True, nogil=True, inline="always")
def jump_at(rows, c, r, edge_start, third, triangle, cut_light, face_normal, face_offset, face_size, part_of):
    """The change of depth complexity across edge record ``r``'s arc as the receiver of couple ``c`` (a row
    of the couple table ``rows``) sees it, up to its sign: the sum over the edge's faces (not the receiver's
    own, nor those of the emitter hull the couple's light excludes: ``part_of`` (T,) int64, the hull of each
    triangle) of the side of the plane through the receiver and the edge that the face's third vertex lies
    on, sign(m . (a - x)) with the face's normal m = (b - a) x (c - a). 0 for an edge between two faces seen
    from one side: no arc. Records as ``edge_tree.MeshEdges`` holds them.

    The kernels here and in ``detection`` take whole arrays and row indices, never row views: in Numba a
    view (or an array handed to an inlined function) costs an atomic reference count increment and
    decrement, which took two thirds of detection's time (the tree at 256 px, profiled with perf)."""
    excluded = rows[c, COUPLE_EXCLUDED]
    x0, x1, x2 = rows[c, COUPLE_POSITION], rows[c, COUPLE_POSITION + 1], rows[c, COUPLE_POSITION + 2]
    reach = max(abs(edge_start[r, 0] - x0), abs(edge_start[r, 1] - x1), abs(edge_start[r, 2] - x2))
    total = 0.0
    for f in range(face_normal.shape[1]):
        value = face_offset[r, f] - (face_normal[r, f, 0] * x0 + face_normal[r, f, 1] * x1 + face_normal[r, f, 2] * x2)
        if not abs(value) > SIGN_EPS * face_size[r, f] * reach:
            continue
        if triangle[r, f] == rows[c, COUPLE_OWN]:
            continue
        if excluded >= 0 and triangle[r, f] >= 0 and part_of[triangle[r, f]] == excluded:
            continue
        if cut_light[r] >= 0:  # a cut segment's vertex behind the light (from the receiver's side) counts 0
            away = third[r, f, 0] * rows[c, COUPLE_TOWARD] + third[r, f, 1] * rows[c, COUPLE_TOWARD + 1] + \
                third[r, f, 2] * rows[c, COUPLE_TOWARD + 2] - rows[c, COUPLE_OFFSET]
            if not away > 0:
                continue
        total += 1.0 if value > 0 else -1.0
    return total


@njit(cache=True, nogil=True, inline="always")
def arc_test(rows, c, cones, cone_valid, cone_row, r, total, cut, edge_start, edge_end, out_start, out_end,
             out_normal, out_enter, out_leave, out_jump, m):
    """Whether edge record ``r`` (start, end (E, 3)), whose ``jump_at`` is ``total`` (not 0), is an arc
    crossing the light of couple ``c`` (``rows``: the couple table; cones[cone_row] (V, 3) of (N, V, 3) the
    inward unit normals of the planes through the receiver and its clipped light's edges,
    cone_valid[cone_row] (V,)); if so it is written
    to row ``m`` of the outputs. ``cut``: the record is a cut segment of this couple's light, which lies in
    the light's plane by construction (no front part to clip: it bounds the front part of its triangle
    where that triangle pierces the light).
    Outputs: start, end, normal (S, 3) directions from the receiver (normal = start x end), enter, leave
    (S,) the range inside the cone (0 <= enter < leave <= 1), jump (S,) int64 (change of D crossing the arc
    from R's side to the other).
    """
    x0, x1, x2 = rows[c, COUPLE_POSITION], rows[c, COUPLE_POSITION + 1], rows[c, COUPLE_POSITION + 2]
    a0, a1, a2 = edge_start[r, 0] - x0, edge_start[r, 1] - x1, edge_start[r, 2] - x2
    b0, b1, b2 = edge_end[r, 0] - x0, edge_end[r, 1] - x1, edge_end[r, 2] - x2
    n0, n1, n2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    reference_side = n0 * rows[c, COUPLE_REFERENCE] + n1 * rows[c, COUPLE_REFERENCE + 1] + \
        n2 * rows[c, COUPLE_REFERENCE + 2]
    jump = -(1.0 if reference_side >= 0 else -1.0) * total
    # Front part: height above the light's plane (on the receiver's side) > eps.
    height_a = -rows[c, COUPLE_OFFSET]
    height_b = -rows[c, COUPLE_OFFSET]
    for k in range(3):
        height_a += edge_start[r, k] * rows[c, COUPLE_TOWARD + k]
        height_b += edge_end[r, k] * rows[c, COUPLE_TOWARD + k]
    scale = rows[c, COUPLE_SIZE] + max(abs(a0), abs(a1), abs(a2)) + max(abs(b0), abs(b1), abs(b2))
    eps = PLANE_EPS * scale
    front_a, front_b = (True, True) if cut else (height_a > eps, height_b > eps)
    if front_a != front_b:
        t_plane = (height_a - eps) / (height_a - height_b)
        p0, p1, p2 = a0 + t_plane * (b0 - a0), a1 + t_plane * (b1 - a1), a2 + t_plane * (b2 - a2)
        if front_a:
            b0, b1, b2 = p0, p1, p2
        else:
            a0, a1, a2 = p0, p1, p2
    # Quick rejection by the light's bounding quad: both ends beyond one of its cone's planes.
    beyond = False
    for v in range(4):
        plane = COUPLE_BOUND + 3 * v
        va = rows[c, plane] * a0 + rows[c, plane + 1] * a1 + rows[c, plane + 2] * a2
        vb = rows[c, plane] * b0 + rows[c, plane + 1] * b1 + rows[c, plane + 2] * b2
        beyond |= va < 0 and vb < 0
    # One exit: returning early here (with the cone worked out after the quad test) measured no faster on
    # 2026-12-05, unlike ``detection._box_passes``.
    inside = False
    if (front_a or front_b) and not beyond:
        n0, n1, n2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
        enter, leave, inside = _cone_range(a0, a1, a2, b0, b1, b2, n0, n1, n2, cones, cone_valid, cone_row,
                                           -rows[c, COUPLE_TOWARD], -rows[c, COUPLE_TOWARD + 1],
                                           -rows[c, COUPLE_TOWARD + 2])
        if inside:
            out_start[m, 0], out_start[m, 1], out_start[m, 2] = a0, a1, a2
            out_end[m, 0], out_end[m, 1], out_end[m, 2] = b0, b1, b2
            out_normal[m, 0], out_normal[m, 1], out_normal[m, 2] = n0, n1, n2
            out_enter[m], out_leave[m], out_jump[m] = enter, leave, np.int64(jump)
    return inside


@njit(cache=True, nogil=True, inline="always")
def _cone_range(a0, a1, a2, b0, b1, b2, x0, x1, x2, planes, valid, row, toward_x, toward_y, toward_z):
    """The parameter range enter .. leave of the segment a -> b inside a cone (unit inward planes
    planes[row] (V, 3) of (N, V, 3), valid[row] (V,)) that opens towards ``toward``, and whether a range of
    positive length remains. (x0, x1, x2) = a x b."""
    length = max(np.sqrt(x0 * x0 + x1 * x1 + x2 * x2), 1e-300)
    enter, leave = 0.0, 1.0
    outside = False
    for v in range(planes.shape[1]):
        p0, p1, p2 = planes[row, v, 0], planes[row, v, 1], planes[row, v, 2]
        va = p0 * a0 + p1 * a1 + p2 * a2
        vb = p0 * b0 + p1 * b1 + p2 * b2
        if valid[row, v]:
            # An arc along the light's edge (an edge of the receiver's own face lies in the horizon that
            # clipped the light) never crosses the inside: its jump happens on the boundary.
            outside |= abs((p0 * x0 + p1 * x1 + p2 * x2) / length) > ON_BOUNDARY or (va <= 0 and vb <= 0)
            if outside:  # no range inside: the rest of the planes cannot change that
                break
            if va < 0 and vb > 0:
                enter = max(enter, va / (va - vb))
            elif va > 0 and vb < 0:
                leave = min(leave, va / (va - vb))
    # The segment must also point towards the light: a direction on the cone's far nappe passes every
    # plane test too.
    middle = 0.5 * (enter + leave)
    toward = (a0 + middle * (b0 - a0)) * toward_x + (a1 + middle * (b1 - a1)) * toward_y + \
        (a2 + middle * (b2 - a2)) * toward_z
    degenerate = not (x0 * x0 + x1 * x1 + x2 * x2
                      > 1e-30 * (a0 * a0 + a1 * a1 + a2 * a2) * (b0 * b0 + b1 * b1 + b2 * b2))
    return enter, leave, not outside and leave > enter + 1e-12 and toward > 0 and not degenerate


@dataclass
class Arcs:
    """The silhouette arcs crossing each couple's light, as segments relative to the receiver.

    Attributes
    ----------
    couple : (S,) int64     couple of each arc (sorted).
    start, end : (S, 3)     the edge's part in front of the light's plane, minus the receiver.
    normal : (S, 3)         start x end: the plane through the receiver and the arc.
    enter, leave : (S,)     the arc's parameter range inside the light's cone, 0 <= enter < leave <= 1.
    jump : (S,) int64       change of D crossing the arc from the reference point's side to the other.
    """

    couple: np.ndarray
    start: np.ndarray
    end: np.ndarray
    normal: np.ndarray
    enter: np.ndarray
    leave: np.ndarray
    jump: np.ndarray

    def take(self, index) -> "Arcs":
        return Arcs(*(getattr(self, name)[index] for name in
                      ("couple", "start", "end", "normal", "enter", "leave", "jump")))

    def by_couple(self, n_couples: int) -> "Arcs":
        """The arcs sorted by couple (0 <= couple < ``n_couples``), in their order within a couple: a
        counting sort in one compiled pass that releases the GIL. (``take(np.argsort(couple, kind="stable"))``
        held it for a radix sort and seven gathers: on the tree at 512 px, 17 M arcs, 3 s of a one-thread
        render, which the other render thread waited out.)"""
        out = Arcs(np.empty_like(self.couple), np.empty_like(self.start), np.empty_like(self.end),
                   np.empty_like(self.normal), np.empty_like(self.enter), np.empty_like(self.leave),
                   np.empty_like(self.jump))
        _sort_by_couple(np.ascontiguousarray(self.couple, np.int64), np.ascontiguousarray(self.start, np.float64),
                        np.ascontiguousarray(self.end, np.float64), np.ascontiguousarray(self.normal, np.float64),
                        np.ascontiguousarray(self.enter, np.float64), np.ascontiguousarray(self.leave, np.float64),
                        np.ascontiguousarray(self.jump, np.int64), n_couples, out.couple, out.start, out.end,
                        out.normal, out.enter, out.leave, out.jump)
        return out

    @classmethod
    def concat(cls, parts: list["Arcs"]) -> "Arcs":
        return cls(*(np.concatenate([getattr(p, name) for p in parts]) for name in
                     ("couple", "start", "end", "normal", "enter", "leave", "jump")))

    @classmethod
    def empty(cls) -> "Arcs":
        return cls(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0),
                   np.zeros(0), np.zeros(0, np.int64))


@njit(cache=True, nogil=True)
def _sort_by_couple(couple, start, end, normal, enter, leave, jump, n_couples, out_couple, out_start, out_end,
                    out_normal, out_enter, out_leave, out_jump):
    """``Arcs.by_couple``: the arcs (S,) written to the out arrays in couple order, stable."""
    place = np.zeros(n_couples + 1, np.int64)
    for a in range(len(couple)):
        place[couple[a] + 1] += 1
    for c in range(n_couples):
        place[c + 1] += place[c]
    for a in range(len(couple)):
        row = place[couple[a]]
        place[couple[a]] += 1
        out_couple[row] = couple[a]
        for k in range(3):
            out_start[row, k] = start[a, k]
            out_end[row, k] = end[a, k]
            out_normal[row, k] = normal[a, k]
        out_enter[row], out_leave[row], out_jump[row] = enter[a], leave[a], jump[a]


def cone_of_light(directions: np.ndarray, count: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inward unit normals (N, V, 3) of the planes through the origin and each edge of convex polygons given
    by directions (N, V, 3) (padded by repeating the last vertex), and their validity (N, V)."""
    directions = np.ascontiguousarray(directions, np.float64)
    planes = np.empty(directions.shape)
    valid = np.empty(directions.shape[:2], np.bool_)
    _cone_planes(directions, np.ascontiguousarray(count, np.int64), planes, valid)
    return planes, valid


# An edge whose end directions are closer than this (the sine of the angle between them) has no plane.
DEGENERATE_EDGE = 1e-10


@njit(cache=True, nogil=True)
def _cone_planes(directions, count, planes, valid):
    """``cone_plane_row`` for every polygon."""
    for n in range(directions.shape[0]):
        cone_plane_row(directions, n, count[n], planes, valid, n)


@njit(cache=True, nogil=True, inline="always")
def cone_plane_row(directions, d, count, planes, valid, n):
    """The planes of polygon ``directions[d]`` (of ``count`` real vertices), written to planes[n] and
    valid[n]: the plane through vertex k and its successor (the last real vertex closes onto vertex 0),
    turned to face the polygon's centre, normalised; valid where k is a real vertex and the
    plane is not degenerate. Detection works them out for a couple when it first tests an arc there (a row of
    ``detection._detect``'s cones): about half the couples have no candidate edge (at 512 px: 43-48 % on
    suzanne, the tree and the boxes), and a disk light's 64 planes cost more than their tests."""
    width = directions.shape[1]
    last = max(count - 1, 0)
    c0, c1, c2 = 0.0, 0.0, 0.0
    for k in range(width):
        c0 += directions[d, k, 0]
        c1 += directions[d, k, 1]
        c2 += directions[d, k, 2]
    for k in range(width):
        j = 0 if k == last or k + 1 == width else k + 1
        a0, a1, a2 = directions[d, k, 0], directions[d, k, 1], directions[d, k, 2]
        b0, b1, b2 = directions[d, j, 0], directions[d, j, 1], directions[d, j, 2]
        p0, p1, p2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
        if p0 * c0 + p1 * c1 + p2 * c2 < 0:
            p0, p1, p2 = -p0, -p1, -p2
        length = np.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
        # An edge between two vertices one direction apart (a clipped polygon's repeated vertex) has a
        # plane of rounding noise, of any orientation: it bounds nothing, its neighbours do.
        degenerate = not length > DEGENERATE_EDGE * np.sqrt((a0 * a0 + a1 * a1 + a2 * a2) * (b0 * b0 + b1 * b1 + b2 * b2))
        if degenerate:
            planes[n, k, 0], planes[n, k, 1], planes[n, k, 2] = 0.0, 0.0, 0.0
        else:
            planes[n, k, 0], planes[n, k, 1], planes[n, k, 2] = p0 / length, p1 / length, p2 / length
        valid[n, k] = k < count and not degenerate
