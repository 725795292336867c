"""Regions of pass 2 by silhouettes: each couple's light, or, where many arcs cross it, the cells of a grid
over it.

The arrangement of a region's arcs costs about the square of their number (``arrangement``), so a couple
crossed by more than CELL_ARCS arcs (a receiver under a tree's crown: hundreds of leaf rims) is cut into a
grid of cells of about CELL_TARGET arcs each: each cell is the light clipped to one square of a grid over
its (u, v) box, with its own reference point, and gets the arcs that cross its cone. The regions of a
chunk of couples come out in couple order (a couple's light, or its non-empty cells one after another),
and their arcs in region order, from one compiled pass over the couples' arcs: a couple's arcs are
copied, or each is tested against the cells its (u, v) extent spans, counted and placed by cell, its jump
turned where the cell's reference point lies on the other side of it than the couple's. The same pass
carries the couple's reference depth D(R) to each cell's reference point across the arcs between (from
cell to neighbouring cell), so a cell costs no depth ray.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numba import njit

from .arcs import Arcs, _cone_range, cone_of_light
from .arrangement import _crossing_jump
from .borrowed import borrowed
from .geometry import LightFrames, ReceiverLight, clip_by_lines, pad_to, reference_points, trim

# A couple crossed by more arcs than this is cut into a grid of cells of about CELL_TARGET arcs each (at
# most MAX_GRID x MAX_GRID). Smaller cells cost fewer pairs of arcs each, but an arc is listed in every cell
# it crosses and each cell's edges are carriers and pieces of their own: with the arrangement compiled and
# vectorized, 96 / 24 beat the earlier 48 / 12 (the tree on one thread at 256 px 19.7-21.2 s -> 16.7-17.4 s,
# at 512 px on two 27.3 -> 23.9 s, pieces 26.6 M -> 23.0 M; 128 / 32 and 200 / 50 within this machine's
# spread of 96 / 24; no cells at all 44-51 s).
CELL_ARCS = 96
CELL_TARGET = 24
MAX_GRID = 24
# Cells clipped per array batch.
CELL_BATCH = 1 << 15


@dataclasses.dataclass(frozen=True)
class RegionPolygons:
    """The (u, v) polygons of a chunk's regions, gathered only for the regions asked for (``take``): a
    couple's light stays in the couples' table and a cell's in the cells' (a table of every region's
    polygon was a copy of each chunk's lights, 34 vertices for a disk light: line_profiler put 0.9 s of
    suzanne_dense3's 25 s at 512 px on one thread there; the polygons are read again only for busy and
    whole regions).

    couple_uv : (Nc, K, 2) float64    every couple's clipped light (``ReceiverLight.uv``).
    region_couple, region_cell : (R,) int64    each region's couple, and its row of ``cell_uv`` (-1: the
                                      region is its couple's light).
    cell_uv : (C, Kc, 2) float64      the cells' polygons (padded).
    """

    couple_uv: np.ndarray
    region_couple: np.ndarray
    region_cell: np.ndarray
    cell_uv: np.ndarray

    def take(self, rows: np.ndarray) -> np.ndarray:
        """(len(rows), W, 2) float64 the polygons of regions ``rows`` (padded to a common width)."""
        cell = self.region_cell[rows]
        in_cell = np.flatnonzero(cell >= 0)
        if len(in_cell) == 0:
            return self.couple_uv[self.region_couple[rows]]
        width = max(self.couple_uv.shape[1], self.cell_uv.shape[1])
        out = np.empty((len(rows), width, 2))
        of_light = np.flatnonzero(cell < 0)
        out[of_light] = pad_to(self.couple_uv[self.region_couple[rows[of_light]]], width)
        out[in_cell] = pad_to(self.cell_uv[cell[in_cell]], width)
        return out


def couple_regions(couples: ReceiverLight, frames: LightFrames, arcs: Arcs, arcs_of: np.ndarray,
                   reference: np.ndarray, reference_uv: np.ndarray, members: np.ndarray):
    """The regions of the couples ``members`` (sorted) and their arcs.

    Parameters
    ----------
    couples : the batch's couples; arcs : ``Arcs`` of the members (and no other couple), sorted by couple;
    arcs_of : (Nc,) int64 arcs per couple; reference, reference_uv : (Nc, 3) and (Nc, 2) each couple's R.

    Returns
    -------
    region_couple (R,) int64, ``RegionPolygons`` (their (u, v) polygons), region_count (R,), the arcs per
    region (``Arcs`` whose ``couple`` is the region, in region order, jumps relative to each region's
    reference point) and the regions' reference points (R, 2) in (u, v), how many of the regions are cells,
    and (R,) int64 D(region's R) - D(couple's R) (0 for a couple's light; see ``_region_arcs``). Regions
    follow the members' order.
    """
    grid = np.where(arcs_of[members] > CELL_ARCS,
                    np.minimum(np.ceil(np.sqrt(arcs_of[members] / CELL_TARGET)), MAX_GRID), 0).astype(np.int64)
    heavy_rows = np.flatnonzero(grid > 0)
    if len(heavy_rows) == 0:  # every region is a couple's light: the arcs stay, renumbered by member
        region_arcs = dataclasses.replace(arcs, couple=np.searchsorted(members, arcs.couple))
        polygons = RegionPolygons(couples.uv, members, np.full(len(members), -1, np.int64), np.zeros((0, 3, 2)))
        return (members, polygons, couples.count[members], region_arcs, reference_uv[members], 0,
                np.zeros(len(members), np.int64))
    heavy = members[heavy_rows]
    g = grid[heavy_rows]
    uv, count = couples.uv[heavy], couples.count[heavy]
    real = np.arange(uv.shape[1])[None, :] < count[:, None]
    low = np.stack([np.where(real, uv[..., axis], np.inf).min(axis=1) for axis in range(2)], axis=1)
    high = np.stack([np.where(real, uv[..., axis], -np.inf).max(axis=1) for axis in range(2)], axis=1)
    step = (high - low) / np.maximum(g, 1)[:, None]
    n_cells = g * g
    cell_first = np.cumsum(n_cells) - n_cells
    owner = np.repeat(np.arange(len(heavy)), n_cells)
    cell = np.arange(int(n_cells.sum())) - cell_first[owner]
    cell_i, cell_j = cell // g[owner], cell % g[owner]
    # Clipped in batches of cells, keeping the non-empty ones: a grid's corner cells often miss the light.
    nonempty = np.zeros(len(owner), bool)
    kept_polygons, kept_counts = [], []
    for lo in range(0, len(owner), CELL_BATCH):  # batches of cells
        rows = slice(lo, lo + CELL_BATCH)
        batch_owner = owner[rows]
        u0 = low[batch_owner, 0] + cell_i[rows] * step[batch_owner, 0]
        v0 = low[batch_owner, 1] + cell_j[rows] * step[batch_owner, 1]
        sides = np.zeros((len(u0), 4, 3))                       # u >= u0, u <= u1, v >= v0, v <= v1
        sides[:, 0, 0], sides[:, 0, 2] = 1.0, -u0
        sides[:, 1, 0], sides[:, 1, 2] = -1.0, u0 + step[batch_owner, 0]
        sides[:, 2, 1], sides[:, 2, 2] = 1.0, -v0
        sides[:, 3, 1], sides[:, 3, 2] = -1.0, v0 + step[batch_owner, 1]
        polygon, polygon_count = clip_by_lines(uv[batch_owner], count[batch_owner], sides)
        keep = polygon_count >= 3
        nonempty[rows] = keep
        kept_polygons.append(trim(polygon[keep], polygon_count[keep]))
        kept_counts.append(polygon_count[keep])
    cell_width = max([p.shape[1] for p in kept_polygons] + [3])
    cell_uv = np.concatenate([pad_to(p, cell_width) for p in kept_polygons]) if kept_polygons else \
        np.zeros((0, cell_width, 2))
    cell_count = np.concatenate(kept_counts) if kept_counts else np.zeros(0, np.int64)
    cell_couple = heavy[owner[nonempty]]

    # Regions in member order: one for a light couple, its non-empty cells for a heavy one.
    regions_of = np.ones(len(members), np.int64)
    regions_of[heavy_rows] = np.bincount(owner[nonempty], minlength=len(heavy))
    region_first = np.cumsum(regions_of) - regions_of
    n_regions = int(regions_of.sum())
    region_couple = np.repeat(members, regions_of)
    light_rows = np.flatnonzero(grid == 0)
    region_cell = np.full(n_regions, -1, np.int64)
    region_count = np.empty(n_regions, np.int64)
    region_ref_uv = np.empty((n_regions, 2))
    light_region = region_first[light_rows]
    region_count[light_region] = couples.count[members[light_rows]]
    region_ref_uv[light_region] = reference_uv[members[light_rows]]
    # A heavy couple's k-th non-empty cell is its region region_first + k.
    kept_owner = owner[nonempty]
    rank = np.arange(len(kept_owner)) - (np.cumsum(regions_of[heavy_rows]) - regions_of[heavy_rows])[kept_owner]
    cell_region = region_first[heavy_rows][kept_owner] + rank
    region_cell[cell_region] = np.arange(len(cell_region))
    region_count[cell_region] = cell_count
    cell_ref_uv = reference_points(cell_uv, cell_count)
    region_ref_uv[cell_region] = cell_ref_uv
    # Per grid slot: the cell's region (-1 where empty), its cone and reference direction.
    slot_region = np.full(len(owner), -1, np.int64)
    slot_region[nonempty] = cell_region
    planes, valid = cone_of_light(couples.directions(frames, cell_uv, cell_couple), cell_count)
    slot_cone = np.full(len(owner), -1, np.int64)
    slot_cone[nonempty] = np.arange(len(cell_region))
    cell_ref = couples.directions(frames, cell_ref_uv[:, None, :], cell_couple)[:, 0] if len(cell_couple) else \
        np.zeros((0, 3))

    n_couples = len(couples.count)
    member_arcs = np.zeros(n_couples, np.int64)  # other couples' arcs (other chunks) are not in ``arcs``
    member_arcs[members] = arcs_of[members]
    first_arc = np.cumsum(member_arcs) - member_arcs
    grid_of = np.zeros(n_couples, np.int64)
    grid_of[heavy] = g
    heavy_index = np.full(n_couples, -1, np.int64)
    heavy_index[heavy] = np.arange(len(heavy))

    def f64(a):
        return np.ascontiguousarray(a, np.float64)

    def i64(a):
        return np.ascontiguousarray(a, np.int64)

    inputs = (i64(members), i64(first_arc), i64(member_arcs), i64(region_first), i64(grid_of), i64(heavy_index),
              f64(low), f64(step), i64(cell_first), i64(slot_region), i64(slot_cone), f64(planes),
              np.ascontiguousarray(valid, np.bool_), f64(cell_ref), f64(reference), i64(couples.light),
              f64(couples.local), f64(couples.side), frames.tangent, frames.bitangent, frames.normal,
              f64(arcs.start), f64(arcs.end), f64(arcs.normal), f64(arcs.enter), f64(arcs.leave), i64(arcs.jump))
    capacity = max(1024, 2 * len(arcs.couple))
    while True:  # the rows outgrow their estimate (an arc in several cells): again with four times the room
        carry = np.zeros(n_regions, np.int64)
        out = _region_arcs(*inputs, carry, capacity)
        if out[-1] >= 0:
            m = out[-1]
            # Copies: slices would keep the larger buffers alive.
            region_arcs = Arcs(*(array[:m].copy() for array in out[:-1]))
            polygons = RegionPolygons(couples.uv, region_couple, region_cell, cell_uv)
            return region_couple, polygons, region_count, region_arcs, region_ref_uv, len(cell_region), carry
        capacity *= 4


@njit(cache=True, nogil=True)
def _region_arcs(members, first_arc, arcs_of, region_first, grid_of, heavy_index, low, step, cell_first,
                 slot_region, slot_cone, planes, valid, cell_ref, reference, light, local, side, tangent, bitangent,
                 normal_l, start, end, normal, enter, leave, jump, carry, capacity):
    """The arcs of each region, in region order (see the module docstring). Returns region, start, end,
    normal, enter, leave, jump (capacity rows) and the number filled, or -1 when they did not fit.

    Also fills ``carry`` (regions,) int64: D(cell's R) - D(couple's R) for each cell (0 for a couple's
    light), counted across the arcs between the two points: from the couple's R to its first cell's over
    all the couple's arcs, then from cell to neighbouring cell (a breadth-first walk over the grid) over
    the arcs of the two cells only, as just written (their jumps relative to each cell's R). Two
    side-by-side cells of a grid over a convex light form a convex region, so the segment between their
    reference points stays inside it and every arc it crosses is listed in one of the two."""
    # Every argument borrowed (``borrowed``): no reference counting in the loops below.
    members, first_arc, arcs_of, region_first = borrowed(members), borrowed(first_arc), borrowed(arcs_of), \
        borrowed(region_first)
    grid_of, heavy_index, low, step = borrowed(grid_of), borrowed(heavy_index), borrowed(low), borrowed(step)
    cell_first, slot_region, slot_cone = borrowed(cell_first), borrowed(slot_region), borrowed(slot_cone)
    planes, valid, cell_ref, reference = borrowed(planes), borrowed(valid), borrowed(cell_ref), borrowed(reference)
    light, local, side, tangent = borrowed(light), borrowed(local), borrowed(side), borrowed(tangent)
    bitangent, normal_l, start, end = borrowed(bitangent), borrowed(normal_l), borrowed(start), borrowed(end)
    normal, enter, leave, jump = borrowed(normal), borrowed(enter), borrowed(leave), borrowed(jump)
    carry = borrowed(carry)
    out_region = np.empty(capacity, np.int64)
    out_start = np.empty((capacity, 3))
    out_end = np.empty((capacity, 3))
    out_normal = np.empty((capacity, 3))
    out_enter = np.empty(capacity)
    out_leave = np.empty(capacity)
    out_jump = np.empty(capacity, np.int64)
    # Read back through borrowed names; the owned arrays (returned) stay alive to the end.
    w_start, w_end, w_normal, w_jump = borrowed(out_start), borrowed(out_end), borrowed(out_normal), \
        borrowed(out_jump)
    most = 1
    for r in range(len(members)):
        if grid_of[members[r]] > 0:
            most = max(most, arcs_of[members[r]] * 4)
    row_slot = np.empty(most, np.int64)
    row_arc = np.empty(most, np.int64)
    row_enter = np.empty(most)
    row_leave = np.empty(most)
    per_slot = np.zeros(MAX_GRID * MAX_GRID + 1, np.int64)
    slot_begin = np.zeros(MAX_GRID * MAX_GRID + 1, np.int64)
    queue = np.empty(MAX_GRID * MAX_GRID, np.int64)
    visited = np.zeros(MAX_GRID * MAX_GRID, np.bool_)
    sorted_arc = np.empty(most, np.int64)
    mark = np.zeros(len(start), np.int64)  # the last carry step that tested each arc (a stamp)
    stamp = 0
    m = 0
    for r in range(len(members)):
        c = members[r]
        a0, n = first_arc[c], arcs_of[c]
        g = grid_of[c]
        if g == 0:  # the couple's light is its one region
            if m + n > capacity:
                return out_region, out_start, out_end, out_normal, out_enter, out_leave, out_jump, -1
            carry[region_first[r]] = 0
            for a in range(a0, a0 + n):
                out_region[m] = region_first[r]
                for k in range(3):
                    out_start[m, k], out_end[m, k], out_normal[m, k] = start[a, k], end[a, k], normal[a, k]
                out_enter[m], out_leave[m], out_jump[m] = enter[a], leave[a], jump[a]
                m += 1
            continue
        h = heavy_index[c]
        l = light[c]
        rows = 0
        toward0, toward1, toward2 = -side[c] * normal_l[l, 0], -side[c] * normal_l[l, 1], -side[c] * normal_l[l, 2]
        for a in range(a0, a0 + n):
            # The (u, v) box of the arc's part inside the couple's cone: the grid cells it may cross.
            i0, i1, j0, j1 = g, -1, g, -1
            for e in range(2):
                t = enter[a] if e == 0 else leave[a]
                d0 = start[a, 0] + t * (end[a, 0] - start[a, 0])
                d1 = start[a, 1] + t * (end[a, 1] - start[a, 1])
                d2 = start[a, 2] + t * (end[a, 2] - start[a, 2])
                d_n = d0 * normal_l[l, 0] + d1 * normal_l[l, 1] + d2 * normal_l[l, 2]
                reach = -local[c, 2] / d_n if d_n != 0.0 else np.inf
                u = local[c, 0] + reach * (d0 * tangent[l, 0] + d1 * tangent[l, 1] + d2 * tangent[l, 2])
                v = local[c, 1] + reach * (d0 * bitangent[l, 0] + d1 * bitangent[l, 1] + d2 * bitangent[l, 2])
                fi = np.floor((u - low[h, 0]) / max(step[h, 0], 1e-300))
                fj = np.floor((v - low[h, 1]) / max(step[h, 1], 1e-300))
                if not (np.isfinite(fi) and np.isfinite(fj)):  # an end at infinity in the plane: every cell
                    i0, i1, j0, j1 = 0, g - 1, 0, g - 1
                    continue
                ci, cj = int(min(max(fi, 0.0), g - 1.0)), int(min(max(fj, 0.0), g - 1.0))
                i0, i1 = min(i0, ci), max(i1, ci)
                j0, j1 = min(j0, cj), max(j1, cj)
            for ci in range(i0, i1 + 1):
                for cj in range(j0, j1 + 1):
                    slot = cell_first[h] + ci * g + cj
                    cone = slot_cone[slot]
                    if cone < 0:
                        continue
                    t0, t1, ok = _cone_range(start[a, 0], start[a, 1], start[a, 2], end[a, 0], end[a, 1], end[a, 2],
                                             normal[a, 0], normal[a, 1], normal[a, 2], planes, valid, cone, toward0,
                                             toward1, toward2)
                    if not ok:
                        continue
                    if rows == len(row_slot):  # more rows than four per arc: grow the scratch
                        grown = len(row_slot) * 2
                        row_slot = _grow_int(row_slot, grown)
                        row_arc = _grow_int(row_arc, grown)
                        row_enter = _grow_float(row_enter, grown)
                        row_leave = _grow_float(row_leave, grown)
                    row_slot[rows], row_arc[rows], row_enter[rows], row_leave[rows] = ci * g + cj, a, t0, t1
                    rows += 1
        if m + rows > capacity:
            return out_region, out_start, out_end, out_normal, out_enter, out_leave, out_jump, -1
        # Counting sort of the rows by cell: the cells' regions are consecutive, in slot order.
        cells = g * g
        for s in range(cells + 1):
            per_slot[s] = 0
        for q in range(rows):
            per_slot[row_slot[q] + 1] += 1
        for s in range(cells):
            per_slot[s + 1] += per_slot[s]
        for s in range(cells + 1):
            slot_begin[s] = per_slot[s]
        if len(sorted_arc) < rows:
            sorted_arc = np.empty(len(row_arc), np.int64)
        for q in range(rows):
            sorted_arc[per_slot[row_slot[q]]] = row_arc[q]
            place = m + per_slot[row_slot[q]]
            per_slot[row_slot[q]] += 1
            a = row_arc[q]
            slot = cell_first[h] + row_slot[q]
            out_region[place] = slot_region[slot]
            cone = slot_cone[slot]
            side_couple = normal[a, 0] * reference[c, 0] + normal[a, 1] * reference[c, 1] + \
                normal[a, 2] * reference[c, 2] >= 0
            side_cell = normal[a, 0] * cell_ref[cone, 0] + normal[a, 1] * cell_ref[cone, 1] + \
                normal[a, 2] * cell_ref[cone, 2] >= 0
            for k in range(3):
                out_start[place, k], out_end[place, k], out_normal[place, k] = start[a, k], end[a, k], normal[a, k]
            out_enter[place], out_leave[place] = row_enter[q], row_leave[q]
            out_jump[place] = jump[a] if side_couple == side_cell else -jump[a]
        base = m
        m += rows
        # The cells' depths relative to the couple's R (see the docstring); per_slot[s] now ends slot s.
        root = -1
        for s in range(cells):
            visited[s] = False
            if root < 0 and slot_cone[cell_first[h] + s] >= 0:
                root = s
        if root < 0:
            continue
        ref = reference[c]
        d = 0
        for a in range(a0, a0 + n):
            d += _crossing_jump(a, ref, cell_ref[slot_cone[cell_first[h] + root]], start, end, normal, jump)
        carry[slot_region[cell_first[h] + root]] = d
        visited[root] = True
        queue[0] = root
        head, tail = 0, 1
        while head < tail:
            s = queue[head]
            head += 1
            here = cell_first[h] + s
            for step_i, step_j in ((-1, 0), (1, 0), (0, -1), (0, 1)):
                ni, nj = s // g + step_i, s % g + step_j
                if ni < 0 or nj < 0 or ni >= g or nj >= g:
                    continue
                t = ni * g + nj
                there = cell_first[h] + t
                if visited[t] or slot_cone[there] < 0:
                    continue
                visited[t] = True
                queue[tail] = t
                tail += 1
                stamp += 1
                total = 0
                for part in range(2):  # the arcs of both cells, each tested once, read where they were written
                    u = s if part == 0 else t
                    # A crossing leaves R of cell s's side of its arc (+ its jump there) and arrives on R of
                    # cell t's (- its jump there).
                    turn = 1 if part == 0 else -1
                    for q in range(slot_begin[u], per_slot[u]):
                        a = sorted_arc[q]
                        if mark[a] == stamp:
                            continue
                        mark[a] = stamp
                        total += turn * _crossing_jump(base + q, cell_ref[slot_cone[here]], cell_ref[slot_cone[there]],
                                                       w_start, w_end, w_normal, w_jump)
                carry[slot_region[there]] = carry[slot_region[here]] + total
    return out_region, out_start, out_end, out_normal, out_enter, out_leave, out_jump, m


@njit(cache=True, nogil=True)
def _grow_int(array, size):
    out = np.empty(size, np.int64)
    out[:len(array)] = array
    return out


@njit(cache=True, nogil=True)
def _grow_float(array, size):
    out = np.empty(size)
    out[:len(array)] = array
    return out


def compile_regions() -> list:
    """Compile ``_region_arcs`` (or load it from Numba's cache) on a one-couple input; returns it."""
    i, f, f2 = np.zeros(1, np.int64), np.zeros((1, 3)), np.zeros((1, 2))
    _region_arcs(i, i, i, i, i, i, f2, f2, i, i, i, np.zeros((1, 3, 3)), np.zeros((1, 3), np.bool_), f, f, i, f,
                 np.ones(1), f, f, f, f, f, f, np.zeros(1), np.zeros(1), i, np.zeros(1, np.int64), 16)
    return [_region_arcs]
