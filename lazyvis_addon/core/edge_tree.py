"""The edge tree: a scene's triangle edges as records for silhouette tests, in a tree for culling.

Pass 2 by silhouettes (``silhouettes``) finds, per (receiver, light) couple, the mesh edges whose depth
jump is not 0 and whose arc crosses the light. Here the triangle soup becomes those edge records once per
render: vertices welded, each undirected edge one record with the third vertices of its faces, plus each
light's cut segments (where triangles cross a light's plane); the records in Morton order under an
implicit binary tree whose nodes carry bounding boxes, cones of oriented face normals and the lights
from which something under them may be a silhouette, so that ``detection`` drops whole subtrees.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from numba import njit

from .emitters import hull_faces_in_scene
from .geometry import LightFrames, cross3

# Edge records per leaf of the edge tree.
LEAF_EDGES = 32
# Triangles stored per edge record; an edge shared by more (non-manifold) is split over several records.
MAX_INCIDENCE = 4

# Vertices this close (relative to the scene's coordinates) are welded into one for the edge records.
WELD_EPS = 1e-10
# Cut segments' boxes are grown by this (relative to the scene's coordinates), far above detection's
# tolerance for 'in front of the light's plane' (PLANE_EPS of the coordinates).
CUT_BOX_MARGIN = 1e-6


@dataclass
class MeshEdges:
    """The scene's triangle edges as records for silhouette tests, in a tree for culling.

    Attributes
    ----------
    start, end : (E, 3) float64     end points (world), records in tree order.
    third : (E, K, 3) float64       third vertex of each triangle on the edge (padding repeats ``start``,
                                    which lies on every plane through the edge: it counts 0).
    triangle : (E, K) int64         those triangles (-1 for padding).
    light : (E,) int64              -1 for mesh edges; for a cut segment (where a triangle crosses a
                                    light's plane) the light it belongs to. Cut segments hold one vertex
                                    from each side of the plane; only the one in front of the light counts.
    face_normal : (E, K, 3)         (end - start) x (third - start) of each face (0 for padding).
    face_offset, face_size : (E, K) face_normal . start and |face_normal|.
    low, high : (E, 3) float64      each record's bounding box.
    node_low, node_high : (2P - 1, 3) float64   boxes of an implicit binary tree over P leaves (heap order:
                                    node i has children 2i + 1 and 2i + 2, leaf j is node P - 1 + j).
    """

    start: np.ndarray
    end: np.ndarray
    third: np.ndarray
    triangle: np.ndarray
    light: np.ndarray
    face_normal: np.ndarray
    face_offset: np.ndarray
    face_size: np.ndarray
    low: np.ndarray
    high: np.ndarray
    node_low: np.ndarray
    node_high: np.ndarray
    n_triangles: int = 0
    in_light_planes: np.ndarray | None = None   # sorted light * T + triangle of faces that block nothing of a
                                                 # light (in its plane, or its emitter's own: ``excluded``)
    part_of: np.ndarray | None = None            # (T,) int64: the hull a triangle is a face of, -1
    node_axis: np.ndarray | None = None          # (2P - 1, 3) unit axis of each node's cone of face normals
    node_spread: np.ndarray | None = None        # (2P - 1,) its radius (inf: the node cannot be culled)
    lights_seen: np.ndarray | None = None        # (E,) uint64: bit l set where the record may be a silhouette
                                                 # seen from some point of light l (``_silhouette_lights``)
    node_lights: np.ndarray | None = None        # (2P - 1,) uint64: the bits of the records under each node

    def __len__(self) -> int:
        return len(self.light)

    @property
    def n_leaves(self) -> int:
        return (len(self.node_low) + 1) // 2

    @classmethod
    def from_triangles(cls, triangles: np.ndarray, frames: LightFrames | None = None,
                       check_cancel: Callable[[], None] | None = None) -> "MeshEdges":
        """Edge records of a triangle soup (T, 3, 3): vertices welded by position, each undirected edge one
        record with its triangles' third vertices, plus each light's cut segments. ``check_cancel`` (a
        ``Progress.check_cancel``) is called between the steps: a million triangles take 5 s here, each
        step under half a second."""
        check = check_cancel if check_cancel is not None else (lambda: None)
        triangles = np.asarray(triangles, np.float64)
        n = len(triangles)
        points = triangles.reshape(-1, 3)
        # Vertices within WELD_EPS of the scene's size are one: a seam whose two sides were computed apart
        # (cos 2 pi is not 1) would leave two coincident boundary arcs of opposite jumps, which no sign
        # test tells apart.
        quantum = WELD_EPS * max(float(np.abs(points).max()) if len(points) else 1.0, 1e-300)
        vertex_id = weld(np.round(points / quantum).astype(np.int64))
        positions = np.zeros((int(vertex_id.max()) + 1 if len(vertex_id) else 0, 3))
        positions[vertex_id] = points
        vertex_id = vertex_id.reshape(n, 3)
        check()
        # A face repeated (the same three vertices) blocks as one: the reference depth ray meets the copies
        # at one distance and counts one, so the edges count one too.
        corners = np.sort(vertex_id, axis=1)
        if len(positions) < 1 << 21:  # three ids in one int64 key: a 1-D unique, several times faster
            corners = (corners[:, 0] << 42) | (corners[:, 1] << 21) | corners[:, 2]
        # (``axis=0`` on the one-column keys would sort them as opaque records, several times slower.)
        _, first_copy = np.unique(corners, axis=0 if corners.ndim > 1 else None, return_index=True)
        single = np.zeros(n, bool)
        single[first_copy] = True
        # Half-edge k of a triangle joins corners k and k + 1; its third vertex is corner k + 2.
        first, second = vertex_id, np.roll(vertex_id, -1, axis=1)
        third = np.roll(triangles, -2, axis=1).reshape(-1, 3)
        low_id, high_id = np.minimum(first, second).ravel(), np.maximum(first, second).ravel()
        triangle = np.repeat(np.arange(n), 3)
        keep = (low_id != high_id) & np.repeat(single, 3)  # a collapsed edge has no arc; copies add none
        low_id, high_id, third, triangle = low_id[keep], high_id[keep], third[keep], triangle[keep]
        key = low_id * max(len(positions), 1) + high_id
        check()
        # One stable sort gives both each half-edge's edge (dense ids in key order, as np.unique's
        # inverse) and its rank among the half-edges of that edge in array order.
        order = np.argsort(key, kind="stable")
        sorted_key = key[order]
        new_edge = np.ones(len(key), bool)
        new_edge[1:] = sorted_key[1:] != sorted_key[:-1]
        sorted_edge = np.cumsum(new_edge) - 1
        edge_of = np.empty(len(key), np.int64)
        edge_of[order] = sorted_edge
        rank = np.empty(len(key), np.int64)
        rank[order] = np.arange(len(key)) - np.flatnonzero(new_edge)[sorted_edge]
        if len(rank) and rank.max() >= MAX_INCIDENCE:  # an edge of more faces than a record holds: split
            _, record = np.unique(edge_of * (n + 1) + rank // MAX_INCIDENCE, return_inverse=True)
            record = record.ravel()
        else:  # every edge fits one record (``np.unique``'s inverse is sorted and dense already)
            record = edge_of
        n_records = int(record.max()) + 1 if len(record) else 0
        slot = rank % MAX_INCIDENCE
        # As many slots as the most shared edge needs: 2 for a closed manifold mesh.
        width = max(2, int(slot.max()) + 1 if len(slot) else 2)
        start = np.zeros((n_records, 3))
        end = np.zeros((n_records, 3))
        start[record] = positions[low_id]
        end[record] = positions[high_id]
        thirds = np.repeat(start[:, None], width, axis=1)
        triangles_of = np.full((n_records, width), -1, np.int64)
        thirds[record, slot] = third
        triangles_of[record, slot] = triangle
        lights = np.full(n_records, -1, np.int64)
        parts = [(start, end, thirds, triangles_of, lights)]
        check()
        # Every vertex's height above each light's plane (the cut segments' and the in-plane faces').
        heights = [np.einsum("tvk,k->tv", triangles - frames.origin[light], frames.normal[light])
                   for light in range(len(frames))] if frames is not None else []
        for light, height in enumerate(heights):  # lights: a handful
            parts.append(_cut_segments(triangles, height, frames, light, width, single))
        start, end, thirds, triangles_of, lights = (np.concatenate([p[i] for p in parts]) for i in range(5))
        check()
        winding = cross3(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
        edges = cls._in_tree_order(start, end, thirds, triangles_of, lights, winding, check)
        check()
        edges.n_triangles = n
        edges.part_of = frames.part_of if frames is not None and frames.part_of is not None else \
            hull_faces_in_scene(frames.hulls if frames is not None else None, triangles)
        edges.in_light_planes = _in_light_planes(triangles, heights, frames, edges.part_of) if frames is not None \
            else np.zeros(0, np.int64)
        edges.lights_seen = np.full(len(edges), ALL_LIGHTS, np.uint64)
        check()
        if frames is not None and len(edges):
            _silhouette_lights(edges.start, edges.face_normal, edges.face_offset, edges.face_size, edges.triangle,
                               edges.light, np.ascontiguousarray(frames.vertices, np.float64),
                               np.ascontiguousarray(frames.vertex_count, np.int64), edges.lights_seen)
        padded = np.zeros(edges.n_leaves * LEAF_EDGES, np.uint64)
        padded[:len(edges)] = edges.lights_seen
        level = np.bitwise_or.reduce(padded.reshape(edges.n_leaves, LEAF_EDGES), axis=1)
        levels = [level]
        while len(level) > 1:  # tree levels: log2 of the leaves
            level = level[0::2] | level[1::2]
            levels.append(level)
        edges.node_lights = np.concatenate(levels[::-1])
        return edges

    @classmethod
    def _in_tree_order(cls, start, end, third, triangle, light, winding, check=lambda: None) -> "MeshEdges":
        low, high = np.minimum(start, end), np.maximum(start, end)
        # A cut segment lies in its light's plane, where detection's hull keeps only what has a point in
        # front of the plane (beyond its tolerance): its box is grown off the plane, so the tree and the
        # record test keep it (growing a box only adds candidates).
        cut = light >= 0
        if cut.any():
            margin = CUT_BOX_MARGIN * max(float(np.abs(np.concatenate([low, high])).max()), 1e-300)
            low[cut] -= margin
            high[cut] += margin
        n_leaves = max(1, -(-len(light) // LEAF_EDGES))
        padded_leaves = 1 << int(np.ceil(np.log2(n_leaves)))
        if len(light):
            order = np.argsort(_morton((low + high) * 0.5), kind="stable")
            start, end, third, triangle, light, low, high = (a[order] for a in
                                                             (start, end, third, triangle, light, low, high))
        leaf_low = np.full((padded_leaves * LEAF_EDGES, 3), np.inf)
        leaf_high = np.full((padded_leaves * LEAF_EDGES, 3), -np.inf)
        leaf_low[:len(light)], leaf_high[:len(light)] = low, high
        level_low = leaf_low.reshape(padded_leaves, LEAF_EDGES, 3).min(axis=1)
        level_high = leaf_high.reshape(padded_leaves, LEAF_EDGES, 3).max(axis=1)
        lows, highs = [level_low], [level_high]
        while len(level_low) > 1:  # tree levels: log2 of the leaves
            level_low = np.minimum(level_low[0::2], level_low[1::2])
            level_high = np.maximum(level_high[0::2], level_high[1::2])
            lows.append(level_low)
            highs.append(level_high)
        node_low = np.concatenate(lows[::-1])
        node_high = np.concatenate(highs[::-1])
        check()
        face_normal = cross3((end - start)[:, None], third - start[:, None])
        face_offset = np.einsum("ekd,ed->ek", face_normal, start)
        face_size = np.linalg.norm(face_normal, axis=2)
        check()
        node_axis, node_spread = _normal_cones(face_normal, face_size, triangle, light, winding, padded_leaves)
        return cls(start, end, third, triangle, light, face_normal, face_offset, face_size, low, high, node_low,
                   node_high, node_axis=node_axis, node_spread=node_spread)


def _normal_cones(face_normal: np.ndarray, face_size: np.ndarray, triangle: np.ndarray, light: np.ndarray,
                  winding: np.ndarray, padded_leaves: int) -> tuple[np.ndarray, np.ndarray]:
    """Cones of oriented face normals per node of the edge tree: unit axes (2P - 1, 3) and radii (2P - 1,).

    A record with exactly two faces has the jump sign(m1 . (a - x)) + sign(m2 . (a - x)) (m = its faces'
    ``face_normal``), which is 0 wherever the oriented normals o1 = m1 / |m1| and o2 = -m2 / |m2| see x on
    the same side; both may be negated (the jump only changes sign), and are, so that o1 points along its
    triangle's winding normal (``winding`` (T, 3)): on a consistently wound mesh neighbouring records' o are
    then its normals, whatever direction each record's edge runs. Every o under a node lies within
    ``spread`` (a chord length) of the node's axis, so when
    the axis and the spread say that all of them keep one sign over a receiver box, no edge under the node
    is a silhouette there (``detection``'s walk drops it). Nodes holding a rim, a non-manifold edge, a
    degenerate face or a cut segment get an infinite spread: never dropped this way.
    """
    n_nodes = 2 * padded_leaves - 1
    axis, spread = np.zeros((n_nodes, 3)), np.zeros(n_nodes)
    if len(winding) == 0:
        winding = np.zeros((1, 3))
    _normal_cone_tree(np.ascontiguousarray(face_normal, np.float64), np.ascontiguousarray(face_size, np.float64),
                      np.ascontiguousarray(triangle, np.int64), np.ascontiguousarray(light, np.int64),
                      np.ascontiguousarray(winding, np.float64), padded_leaves, axis, spread)
    return axis, spread


@njit(cache=True, nogil=True)
def _normal_cone_tree(face_normal, face_size, triangle, light, winding, padded_leaves, axis, spread):
    """``_normal_cones`` into ``axis`` (2P - 1, 3) and ``spread`` (2P - 1,), heap order: the leaves from
    their records, then each inner node from its two children, the last first. (As numpy passes over the
    tree's levels it was a fifth of the edge tree's time.)"""
    n_records, width = len(light), triangle.shape[1]
    total = np.zeros((2 * padded_leaves - 1, 3))   # sum of the oriented normals under each node
    oriented = np.empty((2, 3))
    for leaf in range(padded_leaves):
        node = padded_leaves - 1 + leaf
        first, last = leaf * LEAF_EDGES, min((leaf + 1) * LEAF_EDGES, n_records)
        blocked = False
        for r in range(first, last):  # the sum first: the axis is its direction
            if not _two_faces(r, face_normal, face_size, triangle, light, winding, width, oriented):
                blocked = True
                continue
            for k in range(3):
                total[node, k] += oriented[0, k] + oriented[1, k]
        length = max(np.sqrt(total[node, 0] ** 2 + total[node, 1] ** 2 + total[node, 2] ** 2), 1e-300)
        for k in range(3):
            axis[node, k] = total[node, k] / length
        farthest = 0.0
        for r in range(first, last):  # then the farthest normal from it
            if not _two_faces(r, face_normal, face_size, triangle, light, winding, width, oriented):
                continue
            for f in range(2):
                d0, d1, d2 = oriented[f, 0] - axis[node, 0], oriented[f, 1] - axis[node, 1], oriented[f, 2] - axis[node, 2]
                farthest = max(farthest, np.sqrt(d0 * d0 + d1 * d1 + d2 * d2))
        spread[node] = np.inf if blocked else farthest
    for node in range(padded_leaves - 2, -1, -1):  # inner nodes, children first
        for k in range(3):
            total[node, k] = total[2 * node + 1, k] + total[2 * node + 2, k]
        length = max(np.sqrt(total[node, 0] ** 2 + total[node, 1] ** 2 + total[node, 2] ** 2), 1e-300)
        for k in range(3):
            axis[node, k] = total[node, k] / length
        reach = 0.0
        for child in (2 * node + 1, 2 * node + 2):
            # |o - axis| <= |o - child axis| + |child axis - axis|; an empty child (no normals) adds nothing.
            child_reach = spread[child]
            if abs(total[child, 0]) + abs(total[child, 1]) + abs(total[child, 2]) > 0.0:
                d0, d1, d2 = axis[child, 0] - axis[node, 0], axis[child, 1] - axis[node, 1], axis[child, 2] - axis[node, 2]
                child_reach += np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            reach = max(reach, child_reach)
        spread[node] = reach


@njit(cache=True, nogil=True, inline="always")
def _two_faces(r, face_normal, face_size, triangle, light, winding, width, oriented):
    """Record r is a mesh edge of exactly two non-degenerate faces, the first not perpendicular to its
    triangle's winding normal: then its two oriented unit normals are written to ``oriented`` (2, 3)
    (the first along the winding, the second the other face's normal negated likewise)."""
    if light[r] >= 0 or triangle[r, 0] < 0 or triangle[r, 1] < 0:
        return False
    for k in range(2, width):
        if triangle[r, k] >= 0:
            return False
    if not (face_size[r, 0] > 0.0 and face_size[r, 1] > 0.0):
        return False
    w = triangle[r, 0] if triangle[r, 0] < len(winding) else 0
    along = face_normal[r, 0, 0] * winding[w, 0] + face_normal[r, 0, 1] * winding[w, 1] + \
        face_normal[r, 0, 2] * winding[w, 2]
    if along == 0.0:
        return False
    flip = -1.0 if along < 0.0 else 1.0
    for k in range(3):
        oriented[0, k] = flip * face_normal[r, 0, k] / face_size[r, 0]
        oriented[1, k] = -flip * face_normal[r, 1, k] / face_size[r, 1]
    return True


# Every light's bit: a record or node that may be a silhouette from anywhere (lights beyond the 64th are
# never culled this way).
ALL_LIGHTS = np.uint64(0xFFFFFFFFFFFFFFFF)
# Relative margin by which both faces' planes must keep a light's polygon on one side each for the record
# to be no silhouette from any point of it (well above the arc test's SIGN_EPS).
LIGHT_SIDE_EPS = 1e-9


@njit(cache=True, nogil=True)
def _silhouette_lights(start, face_normal, face_offset, face_size, triangle, cut_light, vertices, vertex_count, out):
    """Clear bit l of ``out`` (E,) uint64 for the records that are a silhouette from no point of light l.

    A record's arc, seen from a receiver x, lies in the plane through x and the edge, which meets the
    light at the arc's points p; the signs of the edge's faces at x are those at p (on the far side of the
    edge, both flipped), so an edge whose jump is not 0 at x crossing the light is a silhouette seen from
    a point of the light. An edge between two faces whose planes keep the whole light polygon on opposite
    sides each (m1 . (a - v) and m2 . (a - v) of one sign over its vertices v, with a margin, and the
    signs opposite) is a silhouette from none of its points: it is no arc for any receiver of that light.
    Rims, non-manifold and degenerate records and cut segments keep every bit. On a dense smooth mesh
    under a small light most records go (Suzanne at level 3: 6 to 23 % stay per light).
    """
    n_lights = min(len(vertex_count), 64)
    # Each light's bounding ball (centre, radius): a face plane farther from the centre than the radius
    # and the margin keeps every vertex on one side, without the loop over the polygon's vertices (a
    # disk light has 32). The shortcut decides only what the loop would decide the same way.
    centre = np.zeros((n_lights, 3))
    radius = np.zeros(n_lights)
    for l in range(n_lights):
        for v in range(vertex_count[l]):
            for k in range(3):
                centre[l, k] += vertices[l, v, k] / vertex_count[l]
        for v in range(vertex_count[l]):
            d0, d1, d2 = vertices[l, v, 0] - centre[l, 0], vertices[l, v, 1] - centre[l, 1], \
                vertices[l, v, 2] - centre[l, 2]
            radius[l] = max(radius[l], np.sqrt(d0 * d0 + d1 * d1 + d2 * d2))
    signs = np.zeros(2)
    for r in range(len(start)):
        if cut_light[r] >= 0 or face_normal.shape[1] < 2 or triangle[r, 0] < 0 or triangle[r, 1] < 0:
            continue
        if face_normal.shape[1] > 2 and triangle[r, 2] >= 0:
            continue
        if face_size[r, 0] == 0.0 or face_size[r, 1] == 0.0:
            continue
        for l in range(n_lights):
            # |start - v| (max norm) <= |start - centre| + radius for every vertex v: the loop's margins
            # are at most LIGHT_SIDE_EPS * |m| * that.
            reach_centre = max(abs(start[r, 0] - centre[l, 0]), abs(start[r, 1] - centre[l, 1]),
                               abs(start[r, 2] - centre[l, 2])) + radius[l]
            for f in range(2):
                at_centre = face_offset[r, f] - (face_normal[r, f, 0] * centre[l, 0]
                                                 + face_normal[r, f, 1] * centre[l, 1]
                                                 + face_normal[r, f, 2] * centre[l, 2])
                # 1e-12: rounding of the centre's value, far below the margin.
                clear = face_size[r, f] * (radius[l] * (1.0 + 1e-12) + LIGHT_SIDE_EPS * reach_centre)
                if at_centre > clear:
                    signs[f] = 1.0
                    continue
                if at_centre < -clear:
                    signs[f] = -1.0
                    continue
                above, below = True, True
                for v in range(vertex_count[l]):
                    value = face_offset[r, f] - (face_normal[r, f, 0] * vertices[l, v, 0]
                                                 + face_normal[r, f, 1] * vertices[l, v, 1]
                                                 + face_normal[r, f, 2] * vertices[l, v, 2])
                    reach = max(abs(start[r, 0] - vertices[l, v, 0]), abs(start[r, 1] - vertices[l, v, 1]),
                                abs(start[r, 2] - vertices[l, v, 2]))
                    margin = LIGHT_SIDE_EPS * face_size[r, f] * reach
                    above &= value > margin
                    below &= value < -margin
                signs[f] = 1.0 if above else -1.0 if below else 0.0
            if signs[0] != 0.0 and signs[0] == -signs[1]:
                out[r] &= ~(np.uint64(1) << np.uint64(l))


# Faces within this distance (relative to the scene's coordinates) of a light's plane lie in it: a mesh
# light's own faces, a ceiling a light is set into. They block nothing (the edges' slab leaves them out),
# and a reference depth ray that meets them near its end, by float32 rounding, does not count them.
PLANE_FACE_EPS = 1e-6
# A vertex this close to a light's plane (relative to the scene's coordinates) lies on it for the cut
# segments (the arc test's 'in front' tolerance is PLANE_EPS of the receiver's distances).
CUT_EPS = 1e-9


def _in_light_planes(triangles: np.ndarray, heights: list, frames: LightFrames, part_of: np.ndarray) -> np.ndarray:
    """Sorted keys light * T + triangle (int64) of the faces that block nothing of a light: those lying in
    its plane, and an emitter hull's own faces for the lights that exclude them (``frames.excluded``;
    ``part_of`` (T,) from ``emitters.hull_faces_in_scene``); ``heights``: per light, (T, 3) float64 the
    vertices' heights above its plane."""
    scale = max(float(np.abs(triangles).max()) if len(triangles) else 1.0, 1e-300)
    keys = []
    for light in range(len(frames)):  # lights: a handful
        flat = np.flatnonzero((np.abs(heights[light]) <= PLANE_FACE_EPS * scale).all(axis=1))
        keys.append(light * len(triangles) + flat)
        if frames.excluded[light] >= 0:
            keys.append(light * len(triangles) + np.flatnonzero(part_of == frames.excluded[light]))
    return np.unique(np.concatenate(keys)) if keys else np.zeros(0, np.int64)


def _cut_segments(triangles: np.ndarray, height: np.ndarray, frames: LightFrames, light: int, k: int = 2,
                  single: np.ndarray | None = None):
    """Where triangles cross light ``light``'s plane (``height`` (T, 3) float64: the vertices' heights above
    it): the segment in the plane, as an edge record whose two 'third vertices' are a vertex in front of the
    plane and one behind it. ``single`` (T,) bool: the faces that count (a repeated face's copies cut
    nothing: like its edges, it blocks once; found by fuzzing, where a face and its copy halved a lamp).

    A vertex within CUT_EPS of the scene's size from the plane lies on it (it is an end of the segment), and
    only a triangle with a vertex beyond that on each side crosses: the faces next to a light's own face
    (a mesh emitter's), which touch its plane along an edge, are no crossing by rounding. The point where
    an edge crosses is interpolated from its vertex in front, the same for both triangles on the edge."""
    scale = max(float(np.abs(triangles).max()) if len(triangles) else 1.0, float(np.abs(frames.origin[light]).max()),
                1e-300)
    side = np.where(height > CUT_EPS * scale, 1, np.where(height < -CUT_EPS * scale, -1, 0))
    crosses = (side > 0).any(axis=1) & (side < 0).any(axis=1)
    crossing = np.flatnonzero(crosses if single is None else crosses & single)
    if len(crossing) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, k, 3)), np.zeros((0, k), np.int64), \
            np.zeros(0, np.int64)
    tri, h, side = triangles[crossing], height[crossing], side[crossing]
    following = np.roll(np.arange(3), -1)
    # Candidate ends: the vertices on the plane, then the edges whose ends lie on opposite sides; a
    # crossing triangle has exactly two.
    front_first = (side > 0)[:, :, None]
    near, far = np.where(front_first, tri, tri[:, following]), np.where(front_first, tri[:, following], tri)
    h_near, h_far = np.where(side > 0, h, h[:, following]), np.where(side > 0, h[:, following], h)
    with np.errstate(divide="ignore", invalid="ignore"):
        on_edge = near + (h_near / (h_near - h_far))[:, :, None] * (far - near)
    candidates = np.concatenate([tri, on_edge], axis=1)                                      # (C, 6, 3)
    valid = np.concatenate([side == 0, side * side[:, following] < 0], axis=1)               # (C, 6)
    first_two = np.argsort(~valid, axis=1, kind="stable")[:, :2]
    rows = np.arange(len(crossing))
    start, end = candidates[rows, first_two[:, 0]], candidates[rows, first_two[:, 1]]
    third = np.repeat(start[:, None], k, axis=1)
    third[:, 0] = tri[rows, np.argmax(h, axis=1)]
    third[:, 1] = tri[rows, np.argmin(h, axis=1)]
    triangle = np.full((len(crossing), k), -1, np.int64)
    triangle[:, :2] = crossing[:, None]
    return start, end, third, triangle, np.full(len(crossing), light, np.int64)


def weld(quantized: np.ndarray) -> np.ndarray:
    """The vertex id (N,) int64 of each of ``quantized`` (N, 3) int64 points: equal rows share an id, and
    ids follow the rows' lexicographic order (as a sort of all rows would number them). One pass of a hash
    table over the rows, then a sort of the distinct ones only (a mesh's corners are mostly shared: Suzanne
    at level 3 has 189 k corners and 32 k vertices); the lexicographic sort of every row took a tenth of
    the edge tree's time."""
    if len(quantized) == 0:
        return np.zeros(0, np.int64)
    first = _first_equal_rows(np.ascontiguousarray(quantized, np.int64))
    distinct = np.flatnonzero(first == np.arange(len(first)))
    rows = quantized[distinct]
    rank = np.empty(len(first), np.int64)
    rank[distinct[np.lexsort((rows[:, 2], rows[:, 1], rows[:, 0]))]] = np.arange(len(distinct))
    return rank[first]


@njit(cache=True, nogil=True)
def _first_equal_rows(rows):
    """For each row of ``rows`` (N, 3) int64 the index of the first row equal to it (open addressing, a
    table of at least twice N slots)."""
    size = 1
    while size < 2 * len(rows):
        size <<= 1
    mask = np.uint64(size - 1)
    table = np.full(size, -1, np.int64)
    first = np.empty(len(rows), np.int64)
    for i in range(len(rows)):
        h = (np.uint64(rows[i, 0]) * np.uint64(0x9E3779B97F4A7C15)) ^ \
            (np.uint64(rows[i, 1]) * np.uint64(0xC2B2AE3D27D4EB4F)) ^ \
            (np.uint64(rows[i, 2]) * np.uint64(0x165667B19E3779F9))
        slot = (h ^ (h >> np.uint64(29))) & mask
        while True:  # probes: a few
            j = table[slot]
            if j < 0:
                table[slot] = i
                first[i] = i
                break
            if rows[j, 0] == rows[i, 0] and rows[j, 1] == rows[i, 1] and rows[j, 2] == rows[i, 2]:
                first[i] = j
                break
            slot = (slot + np.uint64(1)) & mask
    return first


def _morton(points: np.ndarray) -> np.ndarray:
    """30-bit Morton codes (N,) int64 of points (N, 3) in their bounding box."""
    if len(points) == 0:
        return np.zeros(0, np.int64)
    low, high = points.min(axis=0), points.max(axis=0)
    cells = ((points - low) / np.maximum(high - low, 1e-300) * 1023).astype(np.int64).clip(0, 1023)
    return _interleave(np.ascontiguousarray(cells))


@njit(cache=True, nogil=True)
def _interleave(cells):
    """Bit b of coordinate a of ``cells`` (N, 3) int64 (0 .. 1023) to bit 3b + a of each code (N,) int64
    (as 30 numpy passes over the points it was most of the Morton order's time)."""
    code = np.zeros(len(cells), np.int64)
    for i in range(len(cells)):
        value = 0
        for bit in range(10):
            for axis in range(3):
                value |= ((cells[i, axis] >> bit) & 1) << (3 * bit + axis)
        code[i] = value
    return code


def compile_edge_tree() -> tuple:
    """Compile the edge tree's kernels (or load them from Numba's cache) on tiny inputs; returns them."""
    three = np.zeros((1, 3))
    _silhouette_lights(three, np.zeros((1, 2, 3)), np.zeros((1, 2)), np.zeros((1, 2)), np.zeros((1, 2), np.int64),
                       np.zeros(1, np.int64), np.zeros((1, 3, 3)), np.zeros(1, np.int64), np.zeros(1, np.uint64))
    _normal_cone_tree(np.zeros((1, 2, 3)), np.zeros((1, 2)), np.zeros((1, 2), np.int64), np.zeros(1, np.int64), three,
                      1, np.zeros((1, 3)), np.zeros(1))
    _first_equal_rows(np.zeros((1, 3), np.int64))
    _interleave(np.zeros((1, 3), np.int64))
    return _silhouette_lights, _normal_cone_tree, _first_equal_rows, _interleave
