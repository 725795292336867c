"""From edge records to arcs: the exact per-receiver test of the candidates that detection found.

Detection (``silhouettes.candidate_edges``) gives (couple, edge record) rows: edges that may be a
silhouette somewhere near a group of receivers and may cross the light. Each row is tested here at its
own receiver: the jump (the sum over the edge's faces of the side each face's third vertex lies on), the
part in front of the light's plane, a quick rejection by the light's bounding quad and the exact range
inside the light's cone. Rows that pass become arcs.

Millions of rows of a hundred flops each: compiled with Numba, one row after another, the GIL released
(the render's thread pool runs batches side by side). As numpy array passes the same test spent most of
its time on (row, face) temporaries (the tree sample at 64 px: 7 s of 14 s in pass 2).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .geometry import PLANE_EPS

# Relative tolerance of the sign tests (a third vertex this close to an arc's plane lies on it).
SIGN_EPS = 1e-12
# A plane of the light's cone this parallel to the arc's plane: the arc runs along the light's edge.
ON_BOUNDARY = 1.0 - 1e-13


def test_rows(edges, frames, couples, position: np.ndarray, own_triangle: np.ndarray, cone: np.ndarray,
              cone_valid: np.ndarray, bound: np.ndarray, reference: np.ndarray, couple: np.ndarray,
              record: np.ndarray):
    """Test (couple, edge record) rows: the edges whose jump is not 0 and whose front part crosses the cone.

    Parameters
    ----------
    edges : ``silhouettes.MeshEdges``; frames : ``LightFrames``; couples : ``ReceiverLight`` (Nc couples).
    position : (Nc, 3) float64   each couple's receiver; own_triangle : (Nc,) int64 the triangle it lies on.
    cone : (Nc, V, 3) float64    inward unit normals of the planes through the receiver and the light's edges.
    cone_valid : (Nc, V) bool
    bound : (Nc, 4, 3) float64   inward normals of the cone through the light's bounding quad (quick test).
    reference : (Nc, 3) float64  direction from the receiver to the reference point R.
    couple, record : (N,) int64  the rows.

    Returns
    -------
    couple (S,) int64, start, end, normal (S, 3) float64 (directions from the receiver; normal = start x
    end), enter, leave (S,) float64 (the range inside the cone, 0 <= enter < leave <= 1), jump (S,) int64
    (change of D crossing the arc from R's side to the other), for the rows that are arcs, in row order.
    """
    def f64(a):
        return np.ascontiguousarray(a, np.float64)

    def i64(a):
        return np.ascontiguousarray(a, np.int64)

    keep, start, end, normal, enter, leave, jump = _rows(
        i64(couple), i64(record), f64(position), i64(own_triangle), f64(edges.start), f64(edges.end),
        f64(edges.third), i64(edges.triangle), i64(edges.light), f64(edges.face_normal), f64(edges.face_offset),
        f64(edges.face_size), i64(couples.light), f64(couples.side), f64(frames.origin), f64(frames.normal),
        f64(frames.area), f64(cone), np.ascontiguousarray(cone_valid, np.bool_), f64(bound), f64(reference))
    # Copies: the kernel's outputs are slices of buffers sized for every row, which a batch's list of arcs
    # would keep alive (the tree at 256 px: 1 GB of them per batch).
    return couple[keep], start.copy(), end.copy(), normal.copy(), enter.copy(), leave.copy(), jump.copy()


@njit(cache=True, nogil=True)
def _rows(couple, record, position, own_triangle, edge_start, edge_end, third, triangle, cut_light, face_normal,
          face_offset, face_size, couple_light, couple_side, light_origin, light_normal, light_area, cone,
          cone_valid, bound, reference):
    n = len(couple)
    keep = np.empty(n, np.int64)
    out_start = np.empty((n, 3))
    out_end = np.empty((n, 3))
    out_normal = np.empty((n, 3))
    out_enter = np.empty(n)
    out_leave = np.empty(n)
    out_jump = np.empty(n, np.int64)
    a = np.empty(3)
    b = np.empty(3)
    x = np.empty(3)
    cross = np.empty(3)
    m = 0
    n_faces = face_normal.shape[1]
    for row in range(n):
        c, r = couple[row], record[row]
        for k in range(3):
            x[k] = position[c, k]
        light = couple_light[c]
        side = couple_side[c]
        # Which side of the plane through x and the edge each face's third vertex lies on: the sign of
        # det(a - x, b - x, c - x) = m . (a - x), with the face's normal m = (b - a) x (c - a) per record.
        reach = max(abs(edge_start[r, 0] - x[0]), abs(edge_start[r, 1] - x[1]), abs(edge_start[r, 2] - x[2]))
        total = 0.0
        for f in range(n_faces):
            value = face_offset[r, f] - (face_normal[r, f, 0] * x[0] + face_normal[r, f, 1] * x[1]
                                         + face_normal[r, f, 2] * x[2])
            if not abs(value) > SIGN_EPS * face_size[r, f] * reach:
                continue
            if triangle[r, f] == own_triangle[c]:
                continue
            if cut_light[r] >= 0:  # a cut segment's vertex behind the light (from the receiver's side) counts 0
                away = side * ((third[r, f, 0] - light_origin[light, 0]) * light_normal[light, 0]
                               + (third[r, f, 1] - light_origin[light, 1]) * light_normal[light, 1]
                               + (third[r, f, 2] - light_origin[light, 2]) * light_normal[light, 2])
                if not away > 0:
                    continue
            total += 1.0 if value > 0 else -1.0
        if total == 0.0:
            continue
        for k in range(3):
            a[k] = edge_start[r, k] - x[k]
            b[k] = edge_end[r, k] - x[k]
        _cross(a, b, cross)
        reference_side = cross[0] * reference[c, 0] + cross[1] * reference[c, 1] + cross[2] * reference[c, 2]
        jump = -(1.0 if reference_side >= 0 else -1.0) * total
        # Front part: height above the light's plane (on the receiver's side) > eps.
        height_a = 0.0
        height_b = 0.0
        for k in range(3):
            height_a += (a[k] + x[k] - light_origin[light, k]) * light_normal[light, k]
            height_b += (b[k] + x[k] - light_origin[light, k]) * light_normal[light, k]
        height_a *= side
        height_b *= side
        scale = np.sqrt(light_area[light]) + max(abs(a[0]), abs(a[1]), abs(a[2])) + \
            max(abs(b[0]), abs(b[1]), abs(b[2]))
        eps = PLANE_EPS * scale
        front_a, front_b = height_a > eps, height_b > eps
        if not (front_a or front_b):
            continue
        if front_a != front_b:
            t_plane = (height_a - eps) / (height_a - height_b)
            for k in range(3):
                cut = a[k] + t_plane * (b[k] - a[k])
                if front_a:
                    b[k] = cut
                else:
                    a[k] = cut
        # Quick rejection by the light's bounding quad: both ends beyond one of its cone's planes.
        beyond = False
        for v in range(4):
            va = bound[c, v, 0] * a[0] + bound[c, v, 1] * a[1] + bound[c, v, 2] * a[2]
            vb = bound[c, v, 0] * b[0] + bound[c, v, 1] * b[1] + bound[c, v, 2] * b[2]
            if va < 0 and vb < 0:
                beyond = True
                break
        if beyond:
            continue
        _cross(a, b, cross)
        enter, leave, inside = _cone_range(a, b, cross, cone[c], cone_valid[c], -side * light_normal[light, 0],
                                           -side * light_normal[light, 1], -side * light_normal[light, 2])
        if not inside:
            continue
        keep[m] = row
        for k in range(3):
            out_start[m, k] = a[k]
            out_end[m, k] = b[k]
            out_normal[m, k] = cross[k]
        out_enter[m], out_leave[m], out_jump[m] = enter, leave, np.int64(jump)
        m += 1
    return keep[:m], out_start[:m], out_end[:m], out_normal[:m], out_enter[:m], out_leave[:m], out_jump[:m]


@njit(cache=True, nogil=True)
def _cone_range(a, b, cross, planes, valid, toward_x, toward_y, toward_z):
    """The parameter range enter .. leave of the segment a -> b (3,) inside a cone (unit inward planes
    (V, 3), ``valid`` (V,)) that opens towards ``toward``, and whether a range of positive length remains.
    ``cross`` = a x b."""
    length = max(np.sqrt(cross[0] * cross[0] + cross[1] * cross[1] + cross[2] * cross[2]), 1e-300)
    enter, leave = 0.0, 1.0
    for v in range(planes.shape[0]):
        if not valid[v]:
            continue
        p0, p1, p2 = planes[v, 0], planes[v, 1], planes[v, 2]
        # An arc along the light's edge (an edge of the receiver's own face lies in the horizon that
        # clipped the light) never crosses the inside: its jump happens on the boundary.
        if abs((p0 * cross[0] + p1 * cross[1] + p2 * cross[2]) / length) > ON_BOUNDARY:
            return enter, leave, False
        va = p0 * a[0] + p1 * a[1] + p2 * a[2]
        vb = p0 * b[0] + p1 * b[1] + p2 * b[2]
        if va <= 0 and vb <= 0:
            return enter, leave, False
        if va < 0 and vb > 0:
            enter = max(enter, va / (va - vb))
        elif va > 0 and vb < 0:
            leave = min(leave, va / (va - vb))
    if not leave > enter + 1e-12:
        return enter, leave, False
    # The segment must also point towards the light: a direction on the cone's far nappe passes every
    # plane test too.
    middle = 0.5 * (enter + leave)
    toward = (a[0] + middle * (b[0] - a[0])) * toward_x + (a[1] + middle * (b[1] - a[1])) * toward_y + \
        (a[2] + middle * (b[2] - a[2])) * toward_z
    if not toward > 0:
        return enter, leave, False
    degenerate = not (cross[0] * cross[0] + cross[1] * cross[1] + cross[2] * cross[2]
                      > 1e-30 * (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]) * (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]))
    return enter, leave, not degenerate


def arcs_in_cells(start: np.ndarray, end: np.ndarray, normal: np.ndarray, toward: np.ndarray, box: np.ndarray,
                  grid: np.ndarray, cell_slot: np.ndarray, cell_cone: np.ndarray, planes: np.ndarray,
                  valid: np.ndarray):
    """The (arc, cell) rows of heavy couples' arcs: each arc against the cells of the part of its couple's
    grid that its (u, v) extent spans, kept where it crosses the cell's cone.

    Parameters
    ----------
    start, end, normal : (S, 3) float64   the arcs (segments from the receiver; normal = start x end).
    toward : (S, 3) float64    the direction each arc's cone opens towards (away from the receiver's side).
    box : (S, 4) int64         i0, i1, j0, j1: the grid cells spanned (inclusive).
    grid : (S,) int64          the grid's size g of the arc's couple; cell_slot : (S,) the index of the
                               couple's cell (0, 0) in ``cell_cone`` (cell (i, j) is slot + i g + j).
    cell_cone : (M,) int64     the cone (row of planes / valid) of each grid cell, -1 for an empty cell.

    Returns arc (N,) int64, cone (N,) int64, enter, leave (N,) float64. Only kept rows are stored: a long
    diagonal arc spans g x g cells of its box but crosses about 2 g of them.
    """
    def f64(a):
        return np.ascontiguousarray(a, np.float64)

    def i64(a):
        return np.ascontiguousarray(a, np.int64)

    arrays = (f64(start), f64(end), f64(normal), f64(toward), i64(box), i64(grid), i64(cell_slot), i64(cell_cone),
              f64(planes), np.ascontiguousarray(valid, np.bool_))
    capacity = max(1024, 4 * len(start))
    while True:  # the rows outgrow their estimate: again with four times the room
        arc, cone, enter, leave, complete = _arcs_in_cells(*arrays, capacity)
        if complete:
            return arc.copy(), cone.copy(), enter.copy(), leave.copy()  # not views of the larger buffers
        capacity *= 4


@njit(cache=True, nogil=True)
def _arcs_in_cells(start, end, normal, toward, box, grid, cell_slot, cell_cone, planes, valid, capacity):
    out_arc = np.empty(capacity, np.int64)
    out_cone = np.empty(capacity, np.int64)
    out_enter = np.empty(capacity)
    out_leave = np.empty(capacity)
    m = 0
    for i in range(len(start)):
        for ci in range(box[i, 0], box[i, 1] + 1):
            for cj in range(box[i, 2], box[i, 3] + 1):
                c = cell_cone[cell_slot[i] + ci * grid[i] + cj]
                if c < 0:
                    continue
                enter, leave, ok = _cone_range(start[i], end[i], normal[i], planes[c], valid[c], toward[i, 0],
                                               toward[i, 1], toward[i, 2])
                if not ok:
                    continue
                if m == capacity:
                    return out_arc, out_cone, out_enter, out_leave, False
                out_arc[m], out_cone[m], out_enter[m], out_leave[m] = i, c, enter, leave
                m += 1
    return out_arc[:m], out_cone[:m], out_enter[:m], out_leave[:m], True


@njit(cache=True, nogil=True)
def _cross(a, b, out):
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


def compile_rows() -> None:
    """Compile ``_rows`` and ``_arcs_in_cells`` (or load them from Numba's cache) on one-row inputs."""
    f, i, one = np.zeros((1, 3)), np.zeros(1, np.int64), np.zeros(1)
    _rows(i, i, f, i, f, f, np.zeros((1, 2, 3)), np.zeros((1, 2), np.int64), i, np.zeros((1, 2, 3)),
          np.zeros((1, 2)), np.zeros((1, 2)), i, one, f, f, one, np.zeros((1, 3, 3)), np.zeros((1, 3), np.bool_),
          np.zeros((1, 4, 3)), f)
    _arcs_in_cells(f, f, f, f, np.zeros((1, 4), np.int64), i, i, i, np.zeros((1, 3, 3)), np.zeros((1, 3), np.bool_), 16)
