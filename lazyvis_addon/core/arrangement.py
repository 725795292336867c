"""The arrangement of silhouette arcs inside a light: which parts of each couple's light are visible.

Pass 2 by silhouettes (``silhouettes``) gives every (receiver, light) couple, or every cell of a heavy
couple's light, its arcs (the mesh edges whose jump is not 0, projected from the receiver, inside the light's
cone) and the depth D(R) of one reference point R. Here each arc and each light edge is split where the
other arcs cross it, the depth of each piece comes from D(R) plus the jumps of the arcs that the arc from R
to the piece's midpoint crosses, and the pieces with D <= 0 on one side and D > 0 on the other bound the
visible region: signed fan triangles (R, p, q) whose sum is the visible region's (Lambert's formula
integrates them like the light's polygon).

The work of a couple is a few nested loops over its arcs (pairs of arcs for the splits, pieces times arcs
for the depths), so it is compiled with Numba, one couple after another in a kernel that releases the GIL:
the render's thread pool runs batches of couples side by side. In numpy the same stage spent most of its
time on gathers and temporaries of (pair,) arrays (the tree sample at 64 px: 27 s of 42 s in pass 2);
compiled, it is a few percent of pass 2.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .borrowed import borrowed

# Where pieces are split, arcs count as a little longer than they are: an arc that ends on another arc
# or on the light's edge (a silhouette chain running into the receiver's own face, which lies in the
# horizon that clipped the light) must split it there. A split where no arc reaches is harmless: both
# parts are classified by their own depths.
SPLIT_SLACK = 1e-6

# Pieces shorter than this (in their carrier's parameter) are rounding, not pieces.
MIN_PIECE = 1e-14

# An arc is not split this close to its own ends (in its parameter, where they lie inside the light): the
# arcs crossing it there are those that share the end (the next edges of a silhouette chain, a leaf's
# rim), which cross it only by rounding (at 1e-17 .. 1e-13 on 60 of the tree sample's couples at 64 px,
# where the other crossings lay beyond 1e-2). Such a split cut off a sliver whose depth was walked from R afresh and came out negative, and it
# broke the carry of the depth along the arc. A piece missed this way is at most a 1e-9 sliver.
ENDPOINT_SLIVER = 1e-9

# A crossing is clean when it lies this far inside the arc that makes it (relative, about radians) and
# that arc's plane is this far from containing the carrier: then D changes there by the arc's jump, and
# the next piece's depth follows from the last one's. Elsewhere (an arc ending on the carrier, an arc
# along it) the next piece's depth is worked out from R afresh.
CLEAN_MARGIN = 1e-6
CLEAN_ANGLE = 1e-9

# An arc whose ends both lie this far (about radians) on one side of the plane through R and a piece's
# midpoint does not cross the arc between them: far above rounding, so the exact test would agree.
APART_ROUNDING = 1e-12

# An arc entering the light across an edge takes its first piece's depth from the edge (see ``_fans``) when
# the crossing is where its range in the cone starts (as directions within SEED_MATCH) and no other
# crossing lies within SEED_GAP of it along the edge (in the edge's parameter).
SEED_MATCH = 1e-9
SEED_GAP = 1e-6


def visible_fans(arcs, light_dirs: np.ndarray, light_count: np.ndarray, reference: np.ndarray,
                 depth: np.ndarray):
    """The visible region of each couple as signed boundary pieces, seen from its receiver.

    Parameters
    ----------
    arcs : ``silhouettes.Arcs`` sorted by couple (start, end, normal (S, 3) float64 directions from the
        receiver, enter, leave (S,) the range inside the cone, jump (S,) int64).
    light_dirs : (Nc, V, 3) float64   the clipped light's vertices minus the receiver (padded).
    light_count : (Nc,) int64         vertices of each.
    reference : (Nc, 3) float64       direction to R; depth : (Nc,) int64 D(R).

    Returns
    -------
    couple : (M,) int64, start, end : (M, 3) float64 directions of each boundary piece, sign : (M,) float64
        (+1: the fan (R, start, end) adds to the visible region, -1: it subtracts);
    whole : (Nc,) bool  the light polygon itself joins the couple's terms with sign +1 (then the pieces
        are the hidden region's boundary, subtracted: fewer than the visible light edges);
    inconsistent : int  couples where D came out negative somewhere (rounding in nearly parallel arcs, or a
        short reference depth); D <= 0 counts as visible there.

    Which side of an arc's plane a piece lies on is interpolated from its carrier's end values, which also
    decided where the carrier was split, so the two decisions agree; splits take arcs a little longer
    (``SPLIT_SLACK``), so that an arc ending on another splits it.
    """
    n_couples = len(depth)
    arcs_of = np.bincount(arcs.couple, minlength=n_couples).astype(np.int64)
    first_arc = (np.cumsum(arcs_of) - arcs_of).astype(np.int64)
    inputs = (first_arc, arcs_of, *(np.ascontiguousarray(getattr(arcs, name), np.float64)
                                     for name in ("start", "end", "normal", "enter", "leave")),
              np.ascontiguousarray(arcs.jump, np.int64), np.ascontiguousarray(light_dirs, np.float64),
              np.ascontiguousarray(light_count, np.int64), np.ascontiguousarray(reference, np.float64),
              np.ascontiguousarray(depth, np.int64))
    capacity = max(16, 2 * (len(arcs.couple) + int(light_count.sum())))
    while True:  # the output outgrows its estimate rarely: then again with twice the room
        couple, start, end, sign, whole, inconsistent = _fans(*inputs, capacity)
        if inconsistent >= 0:
            # Copies: the slices would keep the whole (larger) buffers alive.
            return couple.copy(), start.copy(), end.copy(), sign.copy(), whole, int(inconsistent)
        capacity *= 2


@njit(cache=True, nogil=True, inline="always")
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True, nogil=True, inline="always")
def _cross_dot(a, b, n):
    """(a x b) . n"""
    return (a[1] * b[2] - a[2] * b[1]) * n[0] + (a[2] * b[0] - a[0] * b[2]) * n[1] + (a[0] * b[1] - a[1] * b[0]) * n[2]


@njit(cache=True, nogil=True, inline="always")
def _norm(a):
    return np.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


@njit(cache=True, nogil=True, inline="always")
def _on_arc(point, start, end, normal, slack):
    """``point`` (on the great circle of the arc start -> end, plane ``normal``) lies on the arc, the arc
    grown at both ends by ``slack`` (radians, about; 0: strictly inside)."""
    if slack == 0.0:
        return _cross_dot(start, point, normal) > 0.0 and _cross_dot(point, end, normal) > 0.0
    size = _norm(point) * _norm(normal)
    return (_cross_dot(start, point, normal) > -slack * size * _norm(start)) and \
        (_cross_dot(point, end, normal) > -slack * size * _norm(end))


# Rows of a couple's arcs in ``columns`` (12, n): the coordinates of start, end and normal, then the lengths of
# the three; one arc per column, so the loops over a couple's arcs read consecutive memory and LLVM
# vectorizes them.
START_X, END_X, NORMAL_X, START_LENGTH, END_LENGTH, NORMAL_LENGTH = 0, 3, 6, 9, 10, 11
COLUMN_ROWS = 12


@njit(cache=True, nogil=True, inline="always")
def _one_side(c0, c1, c2, margin, columns, jj):
    """Both ends of the couple's arc jj (``columns``) lie on one side of the plane of normal (c0, c1, c2),
    farther from it than ``margin`` times their lengths (for a unit direction and margin * |c| that is
    about an angle), as a branch-free bool."""
    at_start = c0 * columns[START_X, jj] + c1 * columns[START_X + 1, jj] + c2 * columns[START_X + 2, jj]
    at_end = c0 * columns[END_X, jj] + c1 * columns[END_X + 1, jj] + c2 * columns[END_X + 2, jj]
    reach_start, reach_end = margin * columns[START_LENGTH, jj], margin * columns[END_LENGTH, jj]
    return ((at_start > reach_start) & (at_end > reach_end)) | ((at_start < -reach_start) & (at_end < -reach_end))


@njit(cache=True, nogil=True, inline="always")
def _plane_value(columns, jj, p0, p1, p2):
    """The plane of the couple's arc jj at the direction (p0, p1, p2)."""
    return columns[NORMAL_X, jj] * p0 + columns[NORMAL_X + 1, jj] * p1 + columns[NORMAL_X + 2, jj] * p2


@njit(cache=True, nogil=True, inline="always")
def _at_entry(seg_start, seg_end, t, start, end, enter):
    """The point at ``t`` of the light edge seg_start -> seg_end is, as a direction, the point at ``enter`` of
    the arc start -> end (within SEED_MATCH): the crossing is where the arc enters the light."""
    p0 = seg_start[0] + t * (seg_end[0] - seg_start[0])
    p1 = seg_start[1] + t * (seg_end[1] - seg_start[1])
    p2 = seg_start[2] + t * (seg_end[2] - seg_start[2])
    a0 = start[0] + enter * (end[0] - start[0])
    a1 = start[1] + enter * (end[1] - start[1])
    a2 = start[2] + enter * (end[2] - start[2])
    lp = np.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
    la = np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    if not (lp > 0.0 and la > 0.0):
        return False
    d0, d1, d2 = p0 / lp - a0 / la, p1 / lp - a1 / la, p2 / lp - a2 / la
    return d0 * d0 + d1 * d1 + d2 * d2 < SEED_MATCH * SEED_MATCH


@njit(cache=True, nogil=True, inline="always")
def _straddles(va, vb):
    return (va < 0.0 and vb > 0.0) or (va > 0.0 and vb < 0.0)


@njit(cache=True, nogil=True, inline="always")
def _compact(candidates, n):
    """The indices jj < n where ``candidates[jj]`` (0 or 1) is 1, moved to the front in place; their count."""
    count = 0
    for jj in range(n):
        keep = candidates[jj]
        candidates[count] = jj
        count += keep
    return count


@njit(cache=True, nogil=True, inline="always")
def _split(seg_start, seg_end, first, n, start, end, normal, columns, skip, splits, split_arc, split_clean, va, vb,
           point, candidates):
    """Parameters (written to ``splits``, returned count) where arcs first .. first + n - 1 (not ``skip``)
    cross the segment seg_start -> seg_end, with SPLIT_SLACK (as ``_on_arc``), the arc of each
    (``split_arc``) and whether the crossing is clean (``split_clean``, see CLEAN_MARGIN). ``columns``
    (COLUMN_ROWS, n): the couple's arcs, one per column. Also leaves each arc's plane's values at the
    segment's ends in ``va``, ``vb`` (n,), for ``_near_depth``; ``point`` (3,) and ``candidates`` (n + 1,)
    int64 are scratch."""
    count = 0
    reach = _norm(seg_start) + _norm(seg_end)
    a0, a1, a2 = seg_start[0], seg_start[1], seg_start[2]
    b0, b1, b2 = seg_end[0], seg_end[1], seg_end[2]
    # The carrier's own plane: an arc whose two ends lie on one side of it, both farther than twice the
    # slack (as angles), meets the carrier's great circle nowhere within the slack of its ends (the
    # plane's value along the arc's circle changes by at most the angle travelled, and the arc is shorter
    # than a half circle), so the exact test below would reject it: dropped before it.
    c0, c1, c2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    margin = 2.0 * SPLIT_SLACK * np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
    # The planes' values at both ends, and the arcs whose plane separates them while the carrier's plane
    # may separate theirs: one pass without a branch (which side is data, so a branch would be mispredicted
    # often) that LLVM vectorizes, then the few candidates gathered.
    for jj in range(n):
        x = _plane_value(columns, jj, a0, a1, a2)
        y = _plane_value(columns, jj, b0, b1, b2)
        va[jj] = x
        vb[jj] = y
        apart = _one_side(c0, c1, c2, margin, columns, jj)
        candidates[jj] = ((x < 0.0) ^ (y < 0.0)) & (x != 0.0) & (y != 0.0) & ~apart
    if skip >= first:
        candidates[skip - first] = 0
    crossing = _compact(candidates, n)
    for c in range(crossing):
        jj = candidates[c]
        j = first + jj
        t = va[jj] / (va[jj] - vb[jj])
        for k in range(3):
            point[k] = seg_start[k] + t * (seg_end[k] - seg_start[k])
        from_start, to_end = _cross_dot(start[j], point, normal[j]), _cross_dot(point, end[j], normal[j])
        size = _norm(point) * columns[NORMAL_LENGTH, jj]
        if from_start > -SPLIT_SLACK * size * columns[START_LENGTH, jj] and \
                to_end > -SPLIT_SLACK * size * columns[END_LENGTH, jj]:
            splits[count] = t
            split_arc[count] = j
            split_clean[count] = from_start > CLEAN_MARGIN * size * columns[START_LENGTH, jj] and \
                to_end > CLEAN_MARGIN * size * columns[END_LENGTH, jj] and \
                abs(va[jj]) + abs(vb[jj]) > CLEAN_ANGLE * columns[NORMAL_LENGTH, jj] * reach
            count += 1
    return count


@njit(cache=True, nogil=True, inline="always")
def _near_depth(seg_start, seg_end, t_mid, own, first, n, start, end, normal, columns, jump, ref, ref_value, depth,
                va, vb, mid, point, candidates):
    """D on the reference side of a piece: D(R) plus the jumps of the arcs (not ``own``) that the arc from
    R to the piece's midpoint crosses; which side of an arc's plane the midpoint lies on is interpolated
    from the carrier's end values ``va``, ``vb`` (n,) (``_split``'s). ``mid``, ``point`` (3,) and
    ``candidates`` (n + 1,) int64: scratch; ``columns`` as ``_split``'s."""
    for k in range(3):
        mid[k] = seg_start[k] + t_mid * (seg_end[k] - seg_start[k])
    d = depth
    # The plane through R and the midpoint: an arc with both ends on one side of it, beyond rounding, does
    # not meet the arc from R (the exact test below, with no slack, would reject it).
    c0 = ref[1] * mid[2] - ref[2] * mid[1]
    c1 = ref[2] * mid[0] - ref[0] * mid[2]
    c2 = ref[0] * mid[1] - ref[1] * mid[0]
    margin = APART_ROUNDING * np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
    for jj in range(n):  # the planes between R and the midpoint, vectorized as in _split
        origin_value = ref_value[jj]
        value = (1.0 - t_mid) * va[jj] + t_mid * vb[jj]
        apart = _one_side(c0, c1, c2, margin, columns, jj)
        candidates[jj] = ((origin_value < 0.0) ^ (value < 0.0)) & (origin_value != 0.0) & (value != 0.0) & ~apart
    if own >= first:
        candidates[own - first] = 0
    crossing = _compact(candidates, n)
    for c in range(crossing):
        jj = candidates[c]
        j = first + jj
        origin_value = ref_value[jj]
        value = (1.0 - t_mid) * va[jj] + t_mid * vb[jj]
        s = origin_value / (origin_value - value)
        for k in range(3):
            point[k] = ref[k] + s * (mid[k] - ref[k])
        if _on_arc(point, start[j], end[j], normal[j], 0.0):
            d += jump[j]
    return d


@njit(cache=True, nogil=True, inline="always")
def _clear_of_planes(vertex, values, columns, n):
    """No arc's plane passes within CLEAN_MARGIN (about radians) of ``vertex``: ``values`` (n,) are the
    planes' values there (``_split``'s ``va``), ``columns`` as ``_split``'s."""
    size = CLEAN_MARGIN * _norm(vertex)
    clear = True
    for jj in range(n):
        clear &= abs(values[jj]) > size * columns[NORMAL_LENGTH, jj]
    return clear


@njit(cache=True, nogil=True, inline="always")
def _breakpoints(seg_start, seg_end, low, high, skip, first, n, start, end, normal, columns, splits, split_arc,
                 split_clean, va, vb, point, candidates):
    """The carrier seg_start -> seg_end's part low .. high cut where the arcs (not ``skip``) cross it: the
    sorted parameters low, the crossings strictly inside, high, written to ``splits`` with their arcs and
    cleanness (``_split``; -1 and False for low and high); returns their count. (A light edge's crossings
    all lie inside its 0 .. 1; an arc's may fall outside its cone range.)"""
    s = _split(seg_start, seg_end, first, n, start, end, normal, columns, skip, splits, split_arc, split_clean, va, vb,
               point, candidates)
    # An arc's own ends: no split within ENDPOINT_SLIVER of them (the light's edges keep every crossing: a
    # depth carried over a light's vertex relies on them).
    above, below = low, high
    if skip >= 0:
        if low == 0.0:
            above = ENDPOINT_SLIVER
        if high == 1.0:
            below = 1.0 - ENDPOINT_SLIVER
    kept = 0
    for q in range(s):
        if splits[q] > above and splits[q] < below:
            splits[kept], split_arc[kept], split_clean[kept] = splits[q], split_arc[q], split_clean[q]
            kept += 1
    splits[kept], split_arc[kept], split_clean[kept] = low, -1, False
    splits[kept + 1], split_arc[kept + 1], split_clean[kept + 1] = high, -1, False
    _sort(splits, split_arc, split_clean, kept + 2)
    return kept + 2


@njit(cache=True, nogil=True, inline="always")
def _sort(values, arc, clean, n):
    """Sort values[:n] in place, and arc[:n], clean[:n] with them (insertion sort: a few dozen splits per
    carrier)."""
    for i in range(1, n):
        v, a, c = values[i], arc[i], clean[i]
        j = i - 1
        while j >= 0 and values[j] > v:
            values[j + 1], arc[j + 1], clean[j + 1] = values[j], arc[j], clean[j]
            j -= 1
        values[j + 1], arc[j + 1], clean[j + 1] = v, a, c


@njit(cache=True, nogil=True, inline="always")
def _step_depth(d, known, q, splits, split_arc, split_clean, first, jump, ref_value, va):
    """D on the reference side of a carrier's piece q from that of piece q - 1 (``d``, valid if ``known``):
    a clean crossing at splits[q] by arc j changes it by jump_j, + when the carrier leaves R's side of
    arc j's plane there (which side it comes from: the sign of j's plane at the carrier's start, ``va``)
    and - when it comes back. Returns (d, known): unknown after a crossing that is not clean."""
    if q == 0 or not known:
        return d, False
    j = split_arc[q]
    if not split_clean[q] or ref_value[j - first] == 0.0:
        return d, False
    from_reference_side = (va[j - first] > 0.0) == (ref_value[j - first] > 0.0)
    return d + jump[j] if from_reference_side else d - jump[j], True


@njit(cache=True, nogil=True)
def _fans(first_arc, arcs_of, start, end, normal, enter, leave, jump, light_dirs, light_count, reference, depth,
          capacity):
    n_couples = len(depth)
    width = light_dirs.shape[1]
    out_couple = np.empty(capacity, np.int64)
    out_start = np.empty((capacity, 3))
    out_end = np.empty((capacity, 3))
    out_sign = np.empty(capacity)
    whole = np.zeros(n_couples, np.bool_)
    # Scratch for the couple with the most arcs, shared by all (allocations per couple cost as much as
    # the work of a couple with a few arcs).
    most = max(arcs_of.max(), 1) if n_couples else 1
    m, inconsistent = _arrange(
        first_arc, arcs_of, start, end, normal, enter, leave, jump, light_dirs, light_count, reference, depth,
        out_couple, out_start, out_end, out_sign, whole, np.empty(3), np.empty(3), np.empty(most),
        np.empty((COLUMN_ROWS, most)), np.empty(most + 2), np.empty(most + 2, np.int64), np.empty(most + 2, np.bool_),
        np.empty(most), np.empty(most), np.empty(most + 1, np.int64), np.empty((width * (most + 1), 2, 3)),
        np.empty(width * (most + 1), np.bool_), np.empty(most, np.int64), np.empty(most, np.bool_))
    if inconsistent < 0:
        return out_couple, out_start, out_end, out_sign, whole, -1
    return out_couple[:m], out_start[:m], out_end[:m], out_sign[:m], whole, inconsistent


@njit(cache=True, nogil=True)
def _arrange(first_arc, arcs_of, start, end, normal, enter, leave, jump, light_dirs, light_count, reference, depth,
             out_couple, out_start, out_end, out_sign, whole, mid, point, ref_value, columns, splits, split_arc,
             split_clean, va, vb, candidates, edge_pieces, edge_seen, seed, seeded):
    """``_fans``' work: fills its outputs (out_couple, out_start, out_end, out_sign, whole) and returns (the
    pieces written, the inconsistent couples), or (m, -1) when the outputs are full. The rest are scratch.
    Every argument is borrowed (``borrowed``: no reference counting in the loops; the caller owns them)."""
    first_arc, arcs_of, start, end = borrowed(first_arc), borrowed(arcs_of), borrowed(start), borrowed(end)
    normal, enter, leave, jump = borrowed(normal), borrowed(enter), borrowed(leave), borrowed(jump)
    light_dirs, light_count, reference = borrowed(light_dirs), borrowed(light_count), borrowed(reference)
    depth, out_couple, out_start, out_end = borrowed(depth), borrowed(out_couple), borrowed(out_start), borrowed(out_end)
    out_sign, whole, mid, point = borrowed(out_sign), borrowed(whole), borrowed(mid), borrowed(point)
    ref_value, columns, splits = borrowed(ref_value), borrowed(columns), borrowed(splits)
    split_arc, split_clean, va, vb = borrowed(split_arc), borrowed(split_clean), borrowed(va), borrowed(vb)
    candidates, edge_pieces, edge_seen = borrowed(candidates), borrowed(edge_pieces), borrowed(edge_seen)
    seed, seeded = borrowed(seed), borrowed(seeded)
    n_couples = len(depth)
    capacity = len(out_couple)
    inconsistent = 0
    m = 0
    for c in range(n_couples):
        n, first = arcs_of[c], first_arc[c]
        ref = reference[c]
        for j in range(n):
            seeded[j] = False
            ref_value[j] = _dot(normal[first + j], ref)
            for axis in range(3):
                columns[START_X + axis, j] = start[first + j, axis]
                columns[END_X + axis, j] = end[first + j, axis]
                columns[NORMAL_X + axis, j] = normal[first + j, axis]
            columns[START_LENGTH, j], columns[END_LENGTH, j] = _norm(start[first + j]), _norm(end[first + j])
            columns[NORMAL_LENGTH, j] = _norm(normal[first + j])
        low = 0
        # Light edge pieces first: their depths decide whether the light is whole (see below).
        count = light_count[c]
        n_edge_pieces = 0
        visible_edges = 0
        carried, carried_known = 0, False
        for k in range(count):
            seg_start = light_dirs[c, k]
            seg_end = light_dirs[c, k + 1 if k + 1 < count else 0]
            cuts = _breakpoints(seg_start, seg_end, 0.0, 1.0, -1, first, n, start, end, normal, columns, splits,
                                split_arc, split_clean, va, vb, point, candidates)
            # D on the inside carries over the vertex from the last edge's last piece, unless an arc's plane
            # passes near the vertex (then an arc may cross there, unseen by either edge's splits).
            d_near, known = carried, carried_known and _clear_of_planes(seg_start, va, columns, n)
            for q in range(cuts - 1):
                t0, t1 = splits[q], splits[q + 1]
                if q > 0:
                    d_before, known_before = d_near, known
                    d_near, known = _step_depth(d_near, known, q, splits, split_arc, split_clean, first, jump,
                                                ref_value, va)
                    j = split_arc[q]
                    # Where an arc enters the light across this edge, alone (no other crossing within
                    # SEED_GAP), the edge piece on R's side of it gives the depth of the arc's first piece
                    # on R's side: the arc's own walk from R (_near_depth) is not needed.
                    if known_before and known and j >= 0 and enter[j] > 0.0 and t0 - splits[q - 1] > SEED_GAP and \
                            t1 - t0 > SEED_GAP and _at_entry(seg_start, seg_end, t0, start[j], end[j], enter[j]):
                        on_reference_side = (va[j - first] > 0.0) == (ref_value[j - first] > 0.0)
                        seed[j - first] = d_before if on_reference_side else d_near
                        seeded[j - first] = True
                if not t1 > t0 + MIN_PIECE:
                    continue
                if not known:
                    d_near = _near_depth(seg_start, seg_end, 0.5 * (t0 + t1), -1, first, n, start, end, normal,
                                         columns, jump, ref, ref_value, depth[c], va, vb, mid, point, candidates)
                    known = True
                low = min(low, d_near)
                for axis in range(3):
                    seg = seg_end[axis] - seg_start[axis]
                    edge_pieces[n_edge_pieces, 0, axis] = seg_start[axis] + t0 * seg
                    edge_pieces[n_edge_pieces, 1, axis] = seg_start[axis] + t1 * seg
                edge_seen[n_edge_pieces] = d_near <= 0
                visible_edges += d_near <= 0
                n_edge_pieces += 1
            carried, carried_known = d_near, known
        hidden_edges = n_edge_pieces - visible_edges
        is_whole = (hidden_edges + 1 < visible_edges) and n > 0
        whole[c] = is_whole
        # Arc pieces: a boundary where D <= 0 on one side only.
        for i in range(first, first + n):
            cuts = _breakpoints(start[i], end[i], enter[i], leave[i], i, first, n, start, end, normal, columns,
                                splits, split_arc, split_clean, va, vb, point, candidates)
            d_near, known = 0, False
            for q in range(cuts - 1):
                t0, t1 = splits[q], splits[q + 1]
                if q == 0 and seeded[i - first]:  # the first piece, from where the arc enters the light
                    d_near, known = seed[i - first], True
                else:
                    d_near, known = _step_depth(d_near, known, q, splits, split_arc, split_clean, first, jump,
                                                ref_value, va)
                if not t1 > t0 + MIN_PIECE:
                    continue
                if not known:
                    d_near = _near_depth(start[i], end[i], 0.5 * (t0 + t1), i, first, n, start, end, normal, columns,
                                         jump, ref, ref_value, depth[c], va, vb, mid, point, candidates)
                    known = True
                d_far = d_near + jump[i]
                low = min(low, min(d_near, d_far))
                seen_near = d_near <= 0
                if seen_near == (d_far <= 0):
                    continue
                if m == capacity:
                    return m, -1
                for axis in range(3):
                    seg = end[i, axis] - start[i, axis]
                    out_start[m, axis] = start[i, axis] + t0 * seg
                    out_end[m, axis] = start[i, axis] + t1 * seg
                out_couple[m] = c
                out_sign[m] = 1.0 if seen_near else -1.0
                m += 1
        for q in range(n_edge_pieces):
            if edge_seen[q] == is_whole:
                continue
            if m == capacity:
                return m, -1
            for axis in range(3):
                out_start[m, axis] = edge_pieces[q, 0, axis]
                out_end[m, axis] = edge_pieces[q, 1, axis]
            out_couple[m] = c
            out_sign[m] = -1.0 if is_whole else 1.0
            m += 1
        if low < 0:
            inconsistent += 1
    return m, inconsistent


def compile_arrangement() -> tuple:
    """Compile ``_fans`` and ``_jumps`` (or load them from Numba's cache) on a one-couple input; returns them."""
    f, i, one = np.zeros((1, 3)), np.zeros(1, np.int64), np.zeros(1)
    _fans(i, i, f, f, f, one, one, i, np.zeros((1, 3, 3)), i, f, i, 16)
    _jumps(i, i, f, f, f, i, f, i, f)
    return _fans, _jumps


def jumps_between(arcs, reference: np.ndarray, region: np.ndarray, target: np.ndarray, n_regions: int
                  ) -> np.ndarray:
    """D(target) - D(R) for directions ``target`` (N, 3) float64 in ``region`` (N,) int64: the jumps of the
    region's arcs (``Arcs.couple`` = region, sorted) that the arc from R (``reference`` (n_regions, 3))
    to the target crosses, (N,) int64. This carries probe rays' depths back to R."""
    arcs_of = np.bincount(arcs.couple, minlength=n_regions).astype(np.int64)
    first_arc = (np.cumsum(arcs_of) - arcs_of).astype(np.int64)
    return _jumps(first_arc, arcs_of, np.ascontiguousarray(arcs.start, np.float64),
                  np.ascontiguousarray(arcs.end, np.float64), np.ascontiguousarray(arcs.normal, np.float64),
                  np.ascontiguousarray(arcs.jump, np.int64), np.ascontiguousarray(reference, np.float64),
                  np.ascontiguousarray(region, np.int64), np.ascontiguousarray(target, np.float64))


@njit(cache=True, nogil=True, inline="always")
def _crossing_jump(a, p, q, start, end, normal, jump):
    """The change of D along the segment p -> q (directions) across arc ``a``, whose ``jump`` is taken from
    p's side: the jump where the segment crosses the arc strictly (its plane's values at p and q differ in
    sign and the crossing lies inside the arc, as ``_on_arc`` with no slack), else 0."""
    at_p = _dot(normal[a], p)
    at_q = _dot(normal[a], q)
    if not _straddles(at_p, at_q):
        return 0
    s = at_p / (at_p - at_q)
    x0, x1, x2 = p[0] + s * (q[0] - p[0]), p[1] + s * (q[1] - p[1]), p[2] + s * (q[2] - p[2])
    n0, n1, n2 = normal[a, 0], normal[a, 1], normal[a, 2]
    a0, a1, a2 = start[a, 0], start[a, 1], start[a, 2]
    b0, b1, b2 = end[a, 0], end[a, 1], end[a, 2]
    from_start = (a1 * x2 - a2 * x1) * n0 + (a2 * x0 - a0 * x2) * n1 + (a0 * x1 - a1 * x0) * n2
    to_end = (x1 * b2 - x2 * b1) * n0 + (x2 * b0 - x0 * b2) * n1 + (x0 * b1 - x1 * b0) * n2
    return jump[a] if from_start > 0.0 and to_end > 0.0 else 0


@njit(cache=True, nogil=True)
def _jumps(first_arc, arcs_of, start, end, normal, jump, reference, region, target):
    first_arc, arcs_of, start, end = borrowed(first_arc), borrowed(arcs_of), borrowed(start), borrowed(end)
    normal, jump, reference = borrowed(normal), borrowed(jump), borrowed(reference)
    region, target = borrowed(region), borrowed(target)
    total = np.zeros(len(region), np.int64)
    for p in range(len(region)):
        r = region[p]
        for j in range(first_arc[r], first_arc[r] + arcs_of[r]):
            total[p] += _crossing_jump(j, reference[r], target[p], start, end, normal, jump)
    return total
