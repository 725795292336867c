"""Detection, compiled: the silhouette arcs that cross each couple's light, found by walking the edge tree.

``silhouettes.silhouette_pieces`` sets up one query per (receiver group, light, side): the box around the
group and the light, the light's plane and the receivers' height above it, four side planes of the hull
of the group's box and the light's bounding rectangle (``hull_table``), and sub-groups of a
few receivers with boxes of their own. Each query walks the edge tree (``edge_tree.MeshEdges``: an
implicit binary tree over leaves of records in Morton order) depth first:

- a node outside the hull, or whose faces all face the group's box one way (its cone of normals), is
  dropped;
- at a leaf, a record outside the hull or a silhouette nowhere in the group's box is dropped; then for
  each sub-group where it may be a silhouette, it is tested exactly at each receiver (``arcs.jump_at``,
  ``arcs.arc_test``): the records whose depth jump is not 0 and whose front part crosses the light's
  cone are the arcs.

Every test only rejects what provably cannot cross the light from a receiver of the group, so the arcs
are complete. One pass from the tree to the arcs: the (group, record) candidates and (receiver, record)
rows between them are never stored (Suzanne at subdivision level 3, 128 px: 6.7 million candidates and
31.7 million rows for 0.5 million arcs; as arrays they were pass 2's largest temporaries).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .borrowed import borrowed
from .arcs import COUPLE_WIDTH, SIGN_EPS, arc_test, cone_plane_row, couple_table, jump_at
from .geometry import PLANE_EPS, LightFrames

# Rows of couples' cones detection starts with (``detect_arcs``), doubled as they fill; None: one per couple
# of the batch, which never fills (about half the couples get one: 57 % on suzanne, 55 % on the tree, 52 % on
# the boxes at 512 px; starting from 4,096 rows, the doubling copies were 2 % of suzanne's time).
CONE_ROWS: int | None = None

# Columns of a hull table (``hull_table``), one row per receiver group or sub-group: the
# bounding box of the receivers' box and their light, the light plane's normal towards the receivers and
# its offset, the plane tolerance, the receivers' largest height above the light, four side planes of the
# hull (normals, offsets, validity 1 / 0) and the receivers' own box.
HULL_LOW, HULL_HIGH, HULL_TOWARD, HULL_BASE, HULL_EPS, HULL_HEIGHT = 0, 3, 6, 9, 10, 11
HULL_SIDE_NORMAL, HULL_SIDE_OFFSET, HULL_SIDE_VALID, HULL_BOX_LOW, HULL_BOX_HIGH = 12, 24, 28, 32, 35
HULL_WIDTH = 38


def hull_table(frames: LightFrames, box_low: np.ndarray, box_high: np.ndarray, light: np.ndarray, side: np.ndarray,
               height: np.ndarray, uv_low: np.ndarray | None = None, uv_high: np.ndarray | None = None
               ) -> np.ndarray:
    """The tests of the hull of receiver boxes and their lights, packed in rows for detection
    (``detection.HULL_*`` name the columns), (N, detection.HULL_WIDTH) float64.

    Parameters
    ----------
    box_low, box_high : (N, 3)    boxes around receivers.
    light : (N,) int64            the light they see.
    side : (N,) float64           +1 / -1: the side of the light the receivers are on.
    height : (N,) float64         the receivers' largest height above the light.
    uv_low, uv_high : (N, 2) float64 or None   a (u, v) rectangle holding the receivers' clipped lights
                                  (tighter than the light's own: a sun's, a lamp's plane, a horizon); None:
                                  the light's bounding rectangle.

    An edge that crosses the light from a point of a box lies in the bounding box of the box and the
    light, inside the hull's four side planes, and has a point in front of the light's plane and below
    the receiver: what the tests keep. Each side plane contains one edge of the light's (u, v) bounding
    rectangle and touches the box, with box and light on its negative side (n . y <= offset), so anything
    beyond it meets no segment from the box to the light.
    """
    table = np.empty((len(light), HULL_WIDTH))
    if uv_low is None:
        real = np.arange(frames.uv.shape[1])[None, :] < frames.vertex_count[:, None]
        uv_low = np.stack([np.where(real, frames.uv[..., k], np.inf).min(axis=1) for k in range(2)], axis=1)[light]
        uv_high = np.stack([np.where(real, frames.uv[..., k], -np.inf).max(axis=1) for k in range(2)], axis=1)[light]
    _hull_rows(np.ascontiguousarray(box_low, np.float64), np.ascontiguousarray(box_high, np.float64),
               np.ascontiguousarray(light, np.int64), np.ascontiguousarray(side, np.float64),
               np.ascontiguousarray(height, np.float64), frames.origin, frames.tangent, frames.bitangent, frames.normal,
               np.ascontiguousarray(uv_low, np.float64), np.ascontiguousarray(uv_high, np.float64), table)
    return table


@njit(cache=True, nogil=True)
def _hull_rows(box_low, box_high, light, side, height, origin, tangent, bitangent, normal, uv_low, uv_high, table):
    corners = np.empty((8, 3))
    for n in range(len(light)):
        l = light[n]
        row = table[n]
        u0, u1, v0, v1 = uv_low[n, 0], uv_high[n, 0], uv_low[n, 1], uv_high[n, 1]
        for k in range(3):
            low, high = box_low[n, k], box_high[n, k]
            for corner in range(4):  # the (u, v) rectangle's corners
                u = u1 if corner & 1 else u0
                v = v1 if corner & 2 else v0
                point = origin[l, k] + u * tangent[l, k] + v * bitangent[l, k]
                low, high = min(low, point), max(high, point)
            row[HULL_LOW + k], row[HULL_HIGH + k] = low, high
            row[HULL_TOWARD + k] = side[n] * normal[l, k]
            row[HULL_BOX_LOW + k], row[HULL_BOX_HIGH + k] = box_low[n, k], box_high[n, k]
        row[HULL_BASE] = row[HULL_TOWARD] * origin[l, 0] + row[HULL_TOWARD + 1] * origin[l, 1] + \
            row[HULL_TOWARD + 2] * origin[l, 2]
        largest_high, largest_low = 0.0, 0.0
        for k in range(3):
            largest_high, largest_low = max(largest_high, abs(row[HULL_HIGH + k])), max(largest_low, abs(row[HULL_LOW + k]))
        row[HULL_EPS] = PLANE_EPS * (largest_high + largest_low)
        row[HULL_HEIGHT] = height[n]
        for i in range(8):
            for k in range(3):
                corners[i, k] = box_high[n, k] if (i >> k) & 1 else box_low[n, k]
        for s in range(4):  # the rectangle's edges u = u0, u = u1, v = v0, v = v1: a point and the outward normal
            axis_value = (u0, u1, v0, v1)[s]
            sign = -1.0 if s % 2 == 0 else 1.0
            valid = True
            tilt = np.inf
            for i in range(8):
                alpha, beta = 0.0, 0.0
                for k in range(3):
                    point = origin[l, k] + axis_value * (tangent[l, k] if s < 2 else bitangent[l, k])
                    out = sign * (tangent[l, k] if s < 2 else bitangent[l, k])
                    alpha += (corners[i, k] - point) * out
                    beta += (corners[i, k] - point) * side[n] * normal[l, k]
                if not beta > 0:
                    valid = False
                    break
                tilt = min(tilt, -alpha / beta)
            if not valid:
                tilt = 0.0
            offset = 0.0
            for k in range(3):
                point = origin[l, k] + axis_value * (tangent[l, k] if s < 2 else bitangent[l, k])
                plane = sign * (tangent[l, k] if s < 2 else bitangent[l, k]) + tilt * side[n] * normal[l, k]
                row[HULL_SIDE_NORMAL + 3 * s + k] = plane
                offset += plane * point
            row[HULL_SIDE_OFFSET + s] = offset
            row[HULL_SIDE_VALID + s] = 1.0 if valid else 0.0


def detect_arcs(edges, leaf_size: int, hulls: np.ndarray, query_light: np.ndarray, units: tuple, member: np.ndarray,
                couples, frames, position: np.ndarray, own_triangle: np.ndarray, bound: np.ndarray,
                reference: np.ndarray, chunk_arcs: int):
    """The arcs of every couple of the queries, in chunks of consecutive queries of about ``chunk_arcs``
    arcs (a generator): memory follows the chunk, not the batch (foliage's arcs per couple vary a
    thousandfold: a batch of 14,000 receivers under the tree's crown at 256 px held 3.8 million arcs).

    Parameters (Q queries of U sub-groups of Nc couples)
    ----------
    edges : ``edge_tree.MeshEdges``; leaf_size : records per leaf.
    hulls : (Q, HULL_WIDTH) float64       each query's receiver group and light (``hull_table``).
    query_light : (Q,) int64              the light (cut segments of other lights are skipped).
    units : the sub-groups, a tuple of
        query_unit, query_units : (Q,) int64   each query's sub-groups query_unit .. + query_units - 1;
        unit_hulls : (U, HULL_WIDTH)      each sub-group's receivers and light;
        unit_first, unit_size : (U,) int64    its couples ``member[first : first + size]``.
    couples : ``ReceiverLight``; frames : ``LightFrames``; position, own_triangle, bound, reference: per
        couple, as ``arcs.arc_test`` takes them. A couple's clipped light as directions from its receiver
        and their cone (``arcs.cone_plane_row``) are worked out where an arc of it is first tested: most
        couples have none, and the directions of every couple's light (34 vertices for a disk) took
        0.65 s of suzanne_dense3's 25 s at 512 px on one thread (line_profiler).

    Yields
    ------
    (first, last) : the chunk's queries first .. last - 1;
    arcs : couple (S,) int64, start, end, normal (S, 3) float64, enter, leave (S,) float64, jump (S,) int64
        (see ``silhouettes.Arcs``), in query order;
    tests, visits : the (couple, record) pairs tested exactly and the tree nodes visited.
    """
    def f64(a):
        return np.ascontiguousarray(a, np.float64)

    def i64(a):
        return np.ascontiguousarray(a, np.int64)

    query_unit, query_units, unit_hulls, unit_first, unit_size = units
    arrays = (f64(edges.node_low), f64(edges.node_high), f64(edges.node_axis), f64(edges.node_spread),
              np.ascontiguousarray(edges.node_lights, np.uint64), np.ascontiguousarray(edges.lights_seen, np.uint64),
              f64(edges.low), f64(edges.high), i64(edges.light), f64(edges.start), f64(edges.end), f64(edges.third),
              i64(edges.triangle), f64(edges.face_normal), f64(edges.face_offset), f64(edges.face_size),
              i64(edges.part_of if edges.part_of is not None and len(edges.part_of) else np.full(1, -1)),
              f64(hulls), i64(query_light), i64(query_unit), i64(query_units), f64(unit_hulls), i64(unit_first),
              i64(unit_size), i64(member),
              couple_table(position, own_triangle, couples.light, couples.side, frames, reference, bound),
              f64(couples.uv), i64(couples.light), f64(couples.local), frames.tangent, frames.bitangent, frames.normal,
              i64(couples.count), np.empty((1,) + couples.uv.shape[1:2] + (3,)),
              np.full(len(couples.uv), -1, np.int64))
    # The cones of the couples an arc is tested at, in rows taken in order as they are first needed: the
    # memory touched is the rows used. A table by couple (1.6 KB each for a disk light) was written sparsely,
    # and the kernel zeroed every page touched (5-8 % of a one-thread suzanne at 512 px under perf).
    cone_rows = max(1, len(couples.uv) if CONE_ROWS is None else min(len(couples.uv), CONE_ROWS))
    cones = np.empty((cone_rows,) + couples.uv.shape[1:2] + (3,))
    cone_valid = np.empty((cone_rows,) + couples.uv.shape[1:2], np.bool_)
    rows_used = np.zeros(1, np.int64)
    capacity = max(chunk_arcs, 1)
    done = 0
    while done < len(hulls):  # chunks of queries
        out = _detect(*arrays, cones, cone_valid, rows_used, edges.n_leaves, leaf_size, done, capacity)
        reached, count, cones_full = out[7], out[8], out[11]
        if cones_full:  # then the query where they filled again, with twice the rows
            cones = np.concatenate([cones, np.empty_like(cones)])
            cone_valid = np.concatenate([cone_valid, np.empty_like(cone_valid)])
        elif reached == done:  # not even one query's arcs fitted
            capacity *= 4
        if reached > done:
            yield (done, reached), tuple(array[:count] for array in out[:7]), out[9], out[10]
            done = reached


@njit(cache=True, nogil=True, inline="always")
def _box_passes(hulls, q, box_low, box_high, i):
    """Box i (rows of box_low, box_high (B, 3)) meets the bounding box of hull q (a row of a hull table),
    lies not wholly beyond a side plane, and has a point in front of the light's plane and not above every
    receiver.

    Whole arrays and row indices, no row views (see ``arcs.jump_at``). The cheapest test first, each
    returning at once: with borrowed arrays an early return costs no reference counting, and it beat the
    single exit this had (detection's kernel on suzanne_dense3's chunks at 256 px 0.83 -> 0.77 s, the
    tree's 1.32 -> 1.25 s, alternating runs)."""
    for k in range(3):
        if box_low[i, k] > hulls[q, HULL_HIGH + k] or box_high[i, k] < hulls[q, HULL_LOW + k]:
            return False
    eps = hulls[q, HULL_EPS]
    height_max = -hulls[q, HULL_BASE]
    height_min = -hulls[q, HULL_BASE]
    for k in range(3):
        w = hulls[q, HULL_TOWARD + k]
        height_max += w * (box_high[i, k] if w > 0 else box_low[i, k])
        height_min += w * (box_low[i, k] if w > 0 else box_high[i, k])
    if not (height_max > eps and height_min < hulls[q, HULL_HEIGHT]):
        return False
    for s in range(4):
        if hulls[q, HULL_SIDE_VALID + s] == 0.0:
            continue
        lowest = 0.0
        for k in range(3):
            n = hulls[q, HULL_SIDE_NORMAL + 3 * s + k]
            lowest += n * (box_low[i, k] if n > 0 else box_high[i, k])
        if lowest > hulls[q, HULL_SIDE_OFFSET + s] + eps:
            return False
    return True


@njit(cache=True, nogil=True, inline="always")
def _one_sided(node_axis, node_spread, node_low, node_high, node, hulls, q):
    """Every oriented face normal o within ``spread`` of ``axis`` (of the node) has o . (a - x) of one sign,
    with a margin above the arc test's sign tolerance, for every edge point a in the node's box and x in
    the receiver box of hull q: then every edge under the node has jump 0 there
    (``edge_tree._normal_cones``)."""
    lowest, highest, far = 0.0, 0.0, 0.0
    for k in range(3):
        # a - x over the two boxes
        d_low = node_low[node, k] - hulls[q, HULL_BOX_HIGH + k]
        d_high = node_high[node, k] - hulls[q, HULL_BOX_LOW + k]
        c = node_axis[node, k]
        lowest += c * (d_low if c > 0 else d_high)
        highest += c * (d_high if c > 0 else d_low)
        far += max(d_low * d_low, d_high * d_high)
    margin = (node_spread[node] + 4.0 * SIGN_EPS) * np.sqrt(far)
    return lowest > margin or highest < -margin


@njit(cache=True, nogil=True, inline="always")
def _may_be_silhouette(edge_start, face_normal, face_size, r, cut, hulls, q):
    """False only where edge record r's jump is 0 at every point of hull q's receiver box: each of its
    faces' planes leaves the whole box on one side (the plane's range over the box excludes 0) and those
    sides cancel. Cut segments count only their vertex in front of the light: they are kept (they are
    few). ``face_size`` (E, K): |face_normal|."""
    reach = 0.0
    half_max = 0.0
    c0 = 0.5 * (hulls[q, HULL_BOX_LOW] + hulls[q, HULL_BOX_HIGH])
    c1 = 0.5 * (hulls[q, HULL_BOX_LOW + 1] + hulls[q, HULL_BOX_HIGH + 1])
    c2 = 0.5 * (hulls[q, HULL_BOX_LOW + 2] + hulls[q, HULL_BOX_HIGH + 2])
    h0 = 0.5 * (hulls[q, HULL_BOX_HIGH] - hulls[q, HULL_BOX_LOW])
    h1 = 0.5 * (hulls[q, HULL_BOX_HIGH + 1] - hulls[q, HULL_BOX_LOW + 1])
    h2 = 0.5 * (hulls[q, HULL_BOX_HIGH + 2] - hulls[q, HULL_BOX_LOW + 2])
    d0, d1, d2 = edge_start[r, 0] - c0, edge_start[r, 1] - c1, edge_start[r, 2] - c2
    reach = max(abs(d0), abs(d1), abs(d2))
    half_max = max(h0, h1, h2)
    cuts = cut
    jump = 0.0
    for f in range(face_normal.shape[1]):
        n0, n1, n2 = face_normal[r, f, 0], face_normal[r, f, 1], face_normal[r, f, 2]
        value = n0 * d0 + n1 * d1 + n2 * d2
        spread = abs(n0) * h0 + abs(n1) * h1 + abs(n2) * h2
        tolerance = SIGN_EPS * face_size[r, f] * (reach + half_max)
        # this face's plane may cut the box: the jump may change inside
        cuts |= not abs(value) > spread + tolerance
        jump += 1.0 if value > 0 else -1.0
    return cuts or jump != 0.0


@njit(cache=True, nogil=True, inline="always")
def _node_may_hold(node, bit, node_lights, node_low, node_high, node_axis, node_spread, hulls, q):
    """The walk's test of a tree node for query q (a row of the hull table ``hulls``): some record under it
    may be a silhouette crossing the light from the query's receivers: its records' lights (``bit``, 0 past
    the 64th light), its box against the hull, and not every face under it turned one way to the box."""
    if bit and not node_lights[node] & bit:
        return False
    if not _box_passes(hulls, q, node_low, node_high, node):
        return False
    return not _one_sided(node_axis, node_spread, node_low, node_high, node, hulls, q)


@njit(cache=True, nogil=True, inline="always")
def _record_may_hold(r, q, bit, record_light, query_light, lights_seen, record_low, record_high, edge_start,
                     face_normal, face_size, hulls):
    """The walk's tests of edge record r for query q: not a cut segment of another light, a silhouette from
    some point of the query's light (``lights_seen``), inside the hull, and a silhouette somewhere in the
    receivers' box (``_may_be_silhouette``)."""
    cut = record_light[r] >= 0
    if cut and record_light[r] != query_light[q]:
        return False
    if bit and not lights_seen[r] & bit:
        return False
    if not _box_passes(hulls, q, record_low, record_high, r):
        return False
    return _may_be_silhouette(edge_start, face_normal, face_size, r, cut, hulls, q)


@njit(cache=True, nogil=True)
def _detect(node_low, node_high, node_axis, node_spread, node_lights, lights_seen, record_low, record_high, record_light, edge_start, edge_end,
            third, triangle, face_normal, face_offset, face_size, part_of, hulls, query_light, query_unit, query_units,
            unit_hulls, unit_first, unit_size, member, couple_rows, light_uv, couple_light, couple_local, tangent,
            bitangent, light_normal, light_count, light_dirs, cone_row, cone, cone_valid, rows_used, n_leaves,
            leaf_size, q_start, capacity):
    """One chunk of ``detect_arcs``' queries from ``q_start``. Couple c's cone is row ``cone_row[c]`` (Nc,) int64
    of ``cone`` (K, V, 3) and ``cone_valid`` (K, V), -1 until an arc is first tested there: then the next row
    (``rows_used`` (1,) int64 counts them; kept from chunk to chunk) is filled from the light's vertices
    ``light_uv`` (Nc, V, 2) as directions from the receiver (``geometry._directions``' numbers, in the scratch
    row ``light_dirs`` (1, V, 3)). Returns the arcs' columns, the query reached, the arcs, tests and visits
    counted, and whether the cones' rows ran out (then the query reached was not begun: again, with more)."""
    # Every array borrowed (``borrowed``): no reference counting in the loops below, 4.7x faster.
    node_low, node_high, node_axis = borrowed(node_low), borrowed(node_high), borrowed(node_axis)
    node_spread, node_lights, lights_seen = borrowed(node_spread), borrowed(node_lights), borrowed(lights_seen)
    record_low, record_high, record_light = borrowed(record_low), borrowed(record_high), borrowed(record_light)
    edge_start, edge_end, third, triangle = borrowed(edge_start), borrowed(edge_end), borrowed(third), borrowed(triangle)
    face_normal, face_offset, face_size = borrowed(face_normal), borrowed(face_offset), borrowed(face_size)
    part_of, hulls, query_light = borrowed(part_of), borrowed(hulls), borrowed(query_light)
    query_unit, query_units, unit_hulls = borrowed(query_unit), borrowed(query_units), borrowed(unit_hulls)
    unit_first, unit_size, member = borrowed(unit_first), borrowed(unit_size), borrowed(member)
    couple_rows, cone, cone_valid = borrowed(couple_rows), borrowed(cone), borrowed(cone_valid)
    light_dirs, light_count, cone_row = borrowed(light_dirs), borrowed(light_count), borrowed(cone_row)
    rows_used = borrowed(rows_used)
    light_uv, couple_light, couple_local = borrowed(light_uv), borrowed(couple_light), borrowed(couple_local)
    tangent, bitangent, light_normal = borrowed(tangent), borrowed(bitangent), borrowed(light_normal)
    out_couple = np.empty(capacity, np.int64)
    out_start = np.empty((capacity, 3))
    out_end = np.empty((capacity, 3))
    out_normal = np.empty((capacity, 3))
    out_enter = np.empty(capacity)
    out_leave = np.empty(capacity)
    out_jump = np.empty(capacity, np.int64)
    # Written through borrowed names; the owned arrays (returned) stay alive to the end.
    w_start, w_end, w_normal = borrowed(out_start), borrowed(out_end), borrowed(out_normal)
    w_enter, w_leave, w_jump = borrowed(out_enter), borrowed(out_leave), borrowed(out_jump)
    n_records = len(record_light)
    stack = np.empty(128, np.int64)
    m = 0
    tests = 0
    visits = 0
    for q in range(q_start, len(hulls)):
        m_before, tests_before, visits_before = m, tests, visits
        # The records that may be a silhouette from some point of this light (all, beyond the 64th).
        bit = np.uint64(1) << np.uint64(query_light[q]) if query_light[q] < 64 else np.uint64(0)
        depth = 1
        stack[0] = 0
        while depth > 0:
            depth -= 1
            node = stack[depth]
            visits += 1
            if not _node_may_hold(node, bit, node_lights, node_low, node_high, node_axis, node_spread, hulls, q):
                continue
            if node < n_leaves - 1:  # inner node: the left child is visited first
                stack[depth] = 2 * node + 2
                stack[depth + 1] = 2 * node + 1
                depth += 2
                continue
            leaf_first = (node - (n_leaves - 1)) * leaf_size
            for r in range(leaf_first, min(leaf_first + leaf_size, n_records)):
                if not _record_may_hold(r, q, bit, record_light, query_light, lights_seen, record_low, record_high,
                                        edge_start, face_normal, face_size, hulls):
                    continue
                cut = record_light[r] >= 0
                for u in range(query_unit[q], query_unit[q] + query_units[q]):
                    if not _box_passes(unit_hulls, u, record_low, record_high, r):
                        continue
                    if not _may_be_silhouette(edge_start, face_normal, face_size, r, cut, unit_hulls, u):
                        continue
                    for j in range(unit_first[u], unit_first[u] + unit_size[u]):
                        if m == capacity:  # this query again, with a new buffer
                            return out_couple, out_start, out_end, out_normal, out_enter, out_leave, out_jump, q, \
                                m_before, tests_before, visits_before, False
                        c = member[j]
                        tests += 1
                        total = jump_at(couple_rows, c, r, edge_start, third, triangle, record_light, face_normal,
                                        face_offset, face_size, part_of)
                        if total == 0.0:
                            continue
                        row = cone_row[c]
                        if row < 0:
                            row = rows_used[0]
                            if row == len(cone):  # this query again, with more rows
                                return out_couple, out_start, out_end, out_normal, out_enter, out_leave, out_jump, \
                                    q, m_before, tests_before, visits_before, True
                            l = couple_light[c]
                            u0, v0, h = couple_local[c, 0], couple_local[c, 1], couple_local[c, 2]
                            for k in range(light_uv.shape[1]):
                                du, dv = light_uv[c, k, 0] - u0, light_uv[c, k, 1] - v0
                                for d in range(3):
                                    light_dirs[0, k, d] = du * tangent[l, d] + dv * bitangent[l, d] - \
                                        h * light_normal[l, d]
                            cone_plane_row(light_dirs, 0, light_count[c], cone, cone_valid, row)
                            cone_row[c] = row
                            rows_used[0] = row + 1
                        if arc_test(couple_rows, c, cone, cone_valid, row, r, total, cut, edge_start, edge_end, w_start,
                                    w_end, w_normal, w_enter, w_leave, w_jump, m):
                            out_couple[m] = c
                            m += 1
    return out_couple, out_start, out_end, out_normal, out_enter, out_leave, out_jump, len(hulls), m, tests, visits, \
        False


# Relative slack of the segment test's planes (``_segment_may_cross``): looser than the arc test's own
# tolerances, so that it keeps whatever the arc test could accept.
SEGMENT_SLACK = 1e-9


def segment_may_cross(edges, leaf_size: int, hulls: np.ndarray, query_light: np.ndarray, near: np.ndarray,
                      far: np.ndarray, polygon: np.ndarray, count: np.ndarray, excluded: np.ndarray,
                      skipped: np.ndarray, settled_by: np.ndarray | None = None) -> np.ndarray:
    """Whether any edge may be an arc crossing light polygon q as seen from some point of the segment
    near[q] .. far[q]: (Q,) bool, False only where no point of the segment sees an arc cross the polygon.

    The Shadow Terminator Geometry Offset moves a couple's origin along a segment (``terminator``); where
    no edge's arc crosses the light from any point of it, the depth complexity is the same for every
    origin of the segment and every direction to the light, and the strips the light would be cut into
    all see what one origin sees.

    Parameters (Q segments)
    ----------
    edges : ``edge_tree.MeshEdges``; leaf_size : records per leaf.
    hulls : (Q, HULL_WIDTH) float64   ``hull_table`` of each segment's box and its polygon's (u, v) rectangle.
    query_light : (Q,) int64          the light.
    near, far : (Q, 3) float64        the segment's ends, both strictly in front of the light's plane.
    polygon : (Q, V, 3) float64       the light's convex polygon as seen from there (world points, ``count``
                                      (Q,) int64 real ones, in order; fewer than 3: nothing crosses).
    excluded : (Q,) int64             the emitter hull whose faces block none of the light (-1 for none).
    skipped : (Q,) int64              a triangle whose edges are left out (-1 for none): the receiver's own,
                                      where the segment and the polygon lie on one side of its plane, so that
                                      no segment between them meets its edges. Every other face counts.
    settled_by : (Q,) int64 or None   query q is not walked (its answer stays False) where the earlier query
                                      settled_by[q] found an edge: both answer for one couple (-1: walked).
    """
    def f64(a):
        return np.ascontiguousarray(a, np.float64)

    def i64(a):
        return np.ascontiguousarray(a, np.int64)

    out = np.zeros(len(hulls), np.bool_)
    if len(hulls) == 0:
        return out
    _segment_detect(f64(edges.node_low), f64(edges.node_high), f64(edges.node_axis), f64(edges.node_spread),
                    np.ascontiguousarray(edges.node_lights, np.uint64),
                    np.ascontiguousarray(edges.lights_seen, np.uint64), f64(edges.low), f64(edges.high),
                    i64(edges.light), f64(edges.start), f64(edges.end), i64(edges.triangle), f64(edges.face_normal),
                    f64(edges.face_offset), f64(edges.face_size),
                    i64(edges.part_of if edges.part_of is not None and len(edges.part_of) else np.full(1, -1)),
                    f64(hulls), i64(query_light), f64(near), f64(far), f64(polygon), i64(count), i64(excluded),
                    i64(skipped), i64(np.full(len(hulls), -1) if settled_by is None else settled_by), edges.n_leaves,
                    leaf_size, out)
    return out


@njit(cache=True, nogil=True)
def _segment_detect(node_low, node_high, node_axis, node_spread, node_lights, lights_seen, record_low, record_high,
                    record_light, edge_start, edge_end, triangle, face_normal, face_offset, face_size, part_of, hulls,
                    query_light, near, far, polygon, count, excluded, skipped, settled_by, n_leaves, leaf_size, out):
    """``segment_may_cross``: per segment the walk of ``_detect`` (the segment's box as the receivers' box),
    each record left tested by ``_segment_may_cross`` until one may cross."""
    node_low, node_high, node_axis = borrowed(node_low), borrowed(node_high), borrowed(node_axis)
    node_spread, node_lights, lights_seen = borrowed(node_spread), borrowed(node_lights), borrowed(lights_seen)
    record_low, record_high, record_light = borrowed(record_low), borrowed(record_high), borrowed(record_light)
    edge_start, edge_end, triangle = borrowed(edge_start), borrowed(edge_end), borrowed(triangle)
    face_normal, face_offset, face_size = borrowed(face_normal), borrowed(face_offset), borrowed(face_size)
    part_of, hulls, query_light = borrowed(part_of), borrowed(hulls), borrowed(query_light)
    near, far, polygon, count, excluded = borrowed(near), borrowed(far), borrowed(polygon), borrowed(count), \
        borrowed(excluded)
    skipped, settled_by = borrowed(skipped), borrowed(settled_by)
    n_records = len(record_light)
    stack = np.empty(128, np.int64)
    for q in range(len(hulls)):
        bit = np.uint64(1) << np.uint64(query_light[q]) if query_light[q] < 64 else np.uint64(0)
        settled = settled_by[q] >= 0 and out[settled_by[q]]
        depth = 1 if count[q] >= 3 and not settled else 0  # less than a triangle: nothing to cross
        stack[0] = 0
        while depth > 0 and not out[q]:
            depth -= 1
            node = stack[depth]
            if not _node_may_hold(node, bit, node_lights, node_low, node_high, node_axis, node_spread, hulls, q):
                continue
            if node < n_leaves - 1:
                stack[depth] = 2 * node + 2
                stack[depth + 1] = 2 * node + 1
                depth += 2
                continue
            leaf_first = (node - (n_leaves - 1)) * leaf_size
            for r in range(leaf_first, min(leaf_first + leaf_size, n_records)):
                if not _record_may_hold(r, q, bit, record_light, query_light, lights_seen, record_low, record_high,
                                        edge_start, face_normal, face_size, hulls):
                    continue
                if record_light[r] >= 0 or _segment_may_cross(r, q, edge_start, edge_end, triangle, face_normal,
                                                              face_offset, face_size, part_of, hulls, near, far,
                                                              polygon, count, excluded, skipped):
                    out[q] = True
                    break


@njit(cache=True, nogil=True, inline="always")
def _segment_may_cross(r, q, edge_start, edge_end, triangle, face_normal, face_offset, face_size, part_of, hulls,
                       near, far, polygon, count, excluded, skipped):
    """False only where edge record r is an arc crossing polygon q from no origin x on the segment
    near[q] .. far[q]. Two necessary conditions, each tested over the whole segment:

    - its jump (``arcs.jump_at``) is not 0 somewhere: each face's plane value at x is linear along the
      segment, so a face whose value keeps one sign beyond the sign tolerance at both ends keeps it between
      them; the record is rejected only where every face does and their signs cancel;
    - its part in front of the light's plane meets the hull of the segment and the polygon, the union of
      the light's cones from the segment's points: clipped by the hull's face through each polygon edge
      (the plane through the edge and whichever end leaves the other end inside), it keeps some length.
    An edge of triangle ``skipped[q]`` is rejected outright.
    """
    for f in range(triangle.shape[1]):
        if triangle[r, f] == skipped[q] and skipped[q] >= 0:
            return False
    x0, x1, x2 = near[q, 0], near[q, 1], near[q, 2]
    y0, y1, y2 = far[q, 0], far[q, 1], far[q, 2]
    reach = max(max(abs(edge_start[r, 0] - x0), abs(edge_start[r, 1] - x1), abs(edge_start[r, 2] - x2)),
                max(abs(edge_start[r, 0] - y0), abs(edge_start[r, 1] - y1), abs(edge_start[r, 2] - y2)))
    total = 0.0
    unsure = False
    for f in range(face_normal.shape[1]):
        if excluded[q] >= 0 and triangle[r, f] >= 0 and part_of[triangle[r, f]] == excluded[q]:
            continue
        n0, n1, n2 = face_normal[r, f, 0], face_normal[r, f, 1], face_normal[r, f, 2]
        at_near = face_offset[r, f] - (n0 * x0 + n1 * x1 + n2 * x2)
        at_far = face_offset[r, f] - (n0 * y0 + n1 * y1 + n2 * y2)
        tolerance = SIGN_EPS * face_size[r, f] * reach
        if abs(at_near) > tolerance and abs(at_far) > tolerance and (at_near > 0) == (at_far > 0):
            total += 1.0 if at_near > 0 else -1.0
        else:
            unsure = True
    if not unsure and total == 0.0:
        return False
    # The part in front of the light's plane (the arc test's, with a zero tolerance: a longer part).
    a0, a1, a2 = edge_start[r, 0], edge_start[r, 1], edge_start[r, 2]
    b0, b1, b2 = edge_end[r, 0], edge_end[r, 1], edge_end[r, 2]
    height_a, height_b = -hulls[q, HULL_BASE], -hulls[q, HULL_BASE]
    for k in range(3):
        height_a += edge_start[r, k] * hulls[q, HULL_TOWARD + k]
        height_b += edge_end[r, k] * hulls[q, HULL_TOWARD + k]
    if not (height_a > 0 or height_b > 0):
        return False
    low, high = 0.0, 1.0
    if not height_a > 0:
        low = height_a / (height_a - height_b)
    elif not height_b > 0:
        high = height_a / (height_a - height_b)
    corners = count[q]
    c0, c1, c2 = 0.0, 0.0, 0.0
    for k in range(corners):
        c0 += polygon[q, k, 0]
        c1 += polygon[q, k, 1]
        c2 += polygon[q, k, 2]
    c0, c1, c2 = c0 / corners, c1 / corners, c2 / corners
    for k in range(corners):
        j = k + 1 if k + 1 < corners else 0
        # The plane through the edge and the near end, turned to the polygon's centre; the far end's if the
        # near end's leaves the far end outside.
        for apex in range(2):
            o0, o1, o2 = (x0, x1, x2) if apex == 0 else (y0, y1, y2)
            p0, p1, p2 = polygon[q, k, 0] - o0, polygon[q, k, 1] - o1, polygon[q, k, 2] - o2
            s0, s1, s2 = polygon[q, j, 0] - o0, polygon[q, j, 1] - o1, polygon[q, j, 2] - o2
            m0, m1, m2 = p1 * s2 - p2 * s1, p2 * s0 - p0 * s2, p0 * s1 - p1 * s0
            if m0 * (c0 - o0) + m1 * (c1 - o1) + m2 * (c2 - o2) < 0:
                m0, m1, m2 = -m0, -m1, -m2
            if apex == 1:
                break
            if m0 * (y0 - x0) + m1 * (y1 - x1) + m2 * (y2 - x2) >= 0:
                break
        length = np.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
        if not length > 0:
            continue  # a repeated vertex: its neighbours' planes bound the polygon
        m0, m1, m2 = m0 / length, m1 / length, m2 / length
        d_a = np.sqrt((a0 - o0) ** 2 + (a1 - o1) ** 2 + (a2 - o2) ** 2)
        d_b = np.sqrt((b0 - o0) ** 2 + (b1 - o1) ** 2 + (b2 - o2) ** 2)
        slack = SEGMENT_SLACK * (d_a + d_b)
        value_a = m0 * (a0 - o0) + m1 * (a1 - o1) + m2 * (a2 - o2) + slack
        value_b = m0 * (b0 - o0) + m1 * (b1 - o1) + m2 * (b2 - o2) + slack
        if value_a < 0 and value_b < 0:
            return False
        if value_a < 0:
            low = max(low, value_a / (value_a - value_b))
        elif value_b < 0:
            high = min(high, value_a / (value_a - value_b))
        if low > high:
            return False
    return True


def compile_detection() -> tuple:
    """Compile ``_detect`` and ``_segment_detect`` (or load them from Numba's cache) on one-query inputs;
    returns them."""
    f, i, one = np.zeros((1, 3)), np.zeros(1, np.int64), np.zeros(1)
    faces = np.zeros((1, 2, 3))
    hull = np.zeros((1, HULL_WIDTH))
    bits = np.zeros(1, np.uint64)
    _detect(f, f, f, one, bits, bits, f, f, i, f, f, faces, np.zeros((1, 2), np.int64), faces, np.zeros((1, 2)),
            np.zeros((1, 2)), np.full(1, -1, np.int64), hull, i, i, i, hull, i, i, i,
            np.full((1, COUPLE_WIDTH), -1.0), np.zeros((1, 3, 2)), i, f, f, f, f, i, np.zeros((1, 3, 3)),
            np.full(1, -1, np.int64), np.zeros((1, 3, 3)), np.zeros((1, 3), np.bool_), np.zeros(1, np.int64), 1, 32, 0,
            16)
    _segment_detect(f, f, f, one, bits, bits, f, f, i, f, f, np.zeros((1, 2), np.int64), faces, np.zeros((1, 2)),
                    np.zeros((1, 2)), np.full(1, -1, np.int64), hull, i, f, f, np.zeros((1, 3, 3)),
                    np.full(1, 3, np.int64),
                    np.full(1, -1, np.int64), np.full(1, -1, np.int64), np.full(1, -1, np.int64), 1, 32,
                    np.zeros(1, np.bool_))
    return _detect, _segment_detect
