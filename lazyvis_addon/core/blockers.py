"""Blocker polygons: the units that occlude lights in both passes.

The paper clips one triangle per blocker. A quad face of a mesh is two triangles sharing a diagonal,
and clipping by both cuts every visible piece along that diagonal only for the second triangle to remove
the fragments again. Coplanar triangle pairs that share their longest edge and form a convex quad are
merged into one quad blocker (a first step towards the paper's future work on silhouette blockers):
fewer blocker–light pairs to flood-fill and store, fewer and larger pieces in pass 2, and a quad can
surround a light where neither of its triangles could (more umbra detected).

Going further towards silhouettes: a closed convex part of the scene (a box, a post, a low-poly cylinder)
occludes, seen from a point outside it, exactly the cone through its silhouette edges, the edges between
a face turned towards the point and one turned away. Pass 2 clips a light once by that cone instead of
once by each of the part's faces in a pixel's list, which cut the light along the edges they share
(``ConvexParts``; ``silhouette_planes``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from .edge_tree import _first_equal_rows
from .geometry import cross3, newell_normal

# Two triangles are coplanar when their unit normals agree to this and the far vertex lies on the plane
# within this fraction of the quad's size.
COPLANAR_EPS = 1e-9


@dataclass
class BlockerPolygons:
    """Convex blocker polygons built from the scene's triangles.

    Attributes
    ----------
    vertices : (B, 4, 3) float64   world-space vertices, triangles padded by repeating their last vertex,
                                   in a consistent cyclic order (convex).
    count : (B,) int64             3 or 4.
    of_triangle : (T,) int64       the blocker each triangle belongs to.
    parts : ConvexParts or None    the closed convex parts the blockers form (None: not looked for).
    """

    vertices: np.ndarray
    count: np.ndarray
    of_triangle: np.ndarray
    parts: "ConvexParts | None" = None

    def __len__(self) -> int:
        return len(self.count)

    @classmethod
    def from_triangles(cls, triangles: np.ndarray, merge: bool = True) -> "BlockerPolygons":
        """Blockers of a triangle soup (T, 3, 3); ``merge`` pairs coplanar triangles into convex quads and
        finds the closed convex parts."""
        n = len(triangles)
        if n == 0:
            return cls(np.zeros((0, 4, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64))
        partner = _quad_partners(triangles) if merge else np.full(n, -1)
        first = np.flatnonzero((partner < 0) | (np.arange(n) < partner))
        vertices = np.concatenate([triangles[first], triangles[first, 2:3]], axis=1)
        count = np.full(len(first), 3, np.int64)
        merged = partner[first] >= 0
        if merged.any():
            a = first[merged]
            b = partner[a]
            vertices[merged] = _quad_vertices(triangles[a], triangles[b])
            count[merged] = 4
        of_triangle = np.empty(n, np.int64)
        of_triangle[first] = np.arange(len(first))
        paired = partner >= 0
        of_triangle[paired & (np.arange(n) > partner)] = of_triangle[partner[paired & (np.arange(n) > partner)]]
        parts = ConvexParts.of_polygons(vertices, count) if merge else None
        return cls(vertices, count, of_triangle, parts)


def _unique_points(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distinct points (U, 3) of ``points`` (N, 3) and the index (N,) int64 of each among them.

    A lexicographic sort of the three columns: several times faster than ``np.unique(axis=0)``, which
    sorts rows as opaque records (8 s for a million-triangle mesh).
    """
    if len(points) == 0:
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    order = np.lexsort((points[:, 2], points[:, 1], points[:, 0]))
    ordered = points[order]
    new = np.concatenate([[True], (ordered[1:] != ordered[:-1]).any(axis=1)])
    inverse = np.empty(len(points), np.int64)
    inverse[order] = np.cumsum(new) - 1
    return ordered[new], inverse


def _longest_edge(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index (0..2) of each triangle's longest edge (from vertex i to i+1) and of the opposite vertex."""
    lengths = np.linalg.norm(np.roll(triangles, -1, axis=1) - triangles, axis=2)
    edge = np.argmax(lengths, axis=1)
    return edge, (edge + 2) % 3


def _quad_partners(triangles: np.ndarray) -> np.ndarray:
    """For each triangle, the triangle it merges with into a convex planar quad, or -1."""
    n = len(triangles)
    _, vertex_id = _unique_points(triangles.reshape(-1, 3))
    vertex_id = vertex_id.reshape(n, 3)
    edge, _ = _longest_edge(triangles)
    rows = np.arange(n)
    a = vertex_id[rows, edge]
    b = vertex_id[rows, (edge + 1) % 3]
    key = np.minimum(a, b) * (int(vertex_id.max()) + 1) + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    # Exactly two triangles share the key: a run of length 2 in the sorted keys.
    same_next = sorted_key[:-1] == sorted_key[1:]
    run_start = np.concatenate([[True], ~same_next])
    run_id = np.cumsum(run_start) - 1
    run_length = np.bincount(run_id)
    pair_first = np.flatnonzero(same_next & (run_length[run_id[:-1]] == 2))
    t1, t2 = order[pair_first], order[pair_first + 1]
    partner = np.full(n, -1, np.int64)
    ok = _coplanar_convex(triangles[t1], triangles[t2], edge[t1], edge[t2]) & (t1 != t2)
    partner[t1[ok]] = t2[ok]
    partner[t2[ok]] = t1[ok]
    return partner


def _quad_vertices(tri_a: np.ndarray, tri_b: np.ndarray) -> np.ndarray:
    """The quad (N, 4, 3): tri_a's longest edge (p, q) as the diagonal, in tri_a's winding p, opposite_b, q,
    opposite_a... arranged as p -> r_b -> q -> r_a (convex, consistent with tri_a's orientation)."""
    edge, opposite = _longest_edge(tri_a)
    rows = np.arange(len(tri_a))
    p = tri_a[rows, edge]
    q = tri_a[rows, (edge + 1) % 3]
    r_a = tri_a[rows, opposite]
    _, opposite_b = _longest_edge(tri_b)
    r_b = tri_b[rows, opposite_b]
    # tri_a is (p, q, r_a) in its winding; the quad keeps that orientation: p, r_b, q, r_a reversed is
    # q, ... ; walking p -> q -> r_a is tri_a, so the quad goes r_a -> p -> r_b -> q.
    return np.stack([r_a, p, r_b, q], axis=1)


def _coplanar_convex(tri_a, tri_b, edge_a, edge_b) -> np.ndarray:
    normal_a = np.cross(tri_a[:, 1] - tri_a[:, 0], tri_a[:, 2] - tri_a[:, 0])
    normal_b = np.cross(tri_b[:, 1] - tri_b[:, 0], tri_b[:, 2] - tri_b[:, 0])
    na = normal_a / np.linalg.norm(normal_a, axis=1, keepdims=True)
    nb = normal_b / np.linalg.norm(normal_b, axis=1, keepdims=True)
    parallel = np.abs(np.einsum("nk,nk->n", na, nb)) > 1.0 - COPLANAR_EPS
    quad = _quad_vertices(tri_a, tri_b)
    size = np.linalg.norm(quad[:, 2] - quad[:, 0], axis=1) + np.linalg.norm(quad[:, 3] - quad[:, 1], axis=1)
    on_plane = np.abs(np.einsum("nk,nk->n", quad[:, 2] - quad[:, 1], na)) <= COPLANAR_EPS * size
    # Convex (and consistently wound) when every corner turns the same way as tri_a's normal.
    turn = np.einsum("nvk,nk->nv", np.cross(np.roll(quad, -1, axis=1) - quad,
                                            np.roll(quad, -2, axis=1) - np.roll(quad, -1, axis=1)), na)
    convex = (turn > 0).all(axis=1)
    return parallel & on_plane & convex


# Parts with more faces than this are not looked at: the convexity test pads every part to the largest.
PART_MAX_FACES = 32
# Silhouettes with more edges than this are clipped face by face: the cone's planes are padded to the
# widest silhouette of a batch (a box shows 4 or 6 edges).
SILHOUETTE_MAX_EDGES = 8
# A vertex lies behind a face's plane (convexity) within this fraction of the part's size.
CONVEX_EPS = 1e-9
# Face-vertex heights per convexity check batch (8 bytes each).
PART_CHECK_VALUES = 1 << 22


@dataclass
class ConvexParts:
    """Closed convex parts of the scene: connected sets of blocker polygons in which every edge joins
    exactly two faces, in opposite directions, and every vertex lies behind every face's plane.

    Attributes
    ----------
    of_blocker : (B,) int64       the part each blocker polygon belongs to, -1 for none.
    normal : (C, F, 3) float64    outward unit normal of each face (padded with zeros).
    offset : (C, F) float64       normal . p on each face's plane (padded with 1: never faces a point).
    edge_start, edge_end : (C, E, 3) float64   each edge's end points (padded with zeros), valid first.
    edge_faces : (C, E, 2) int64  the two faces (slots in ``normal``) of each edge.
    edge_count : (C,) int64
    vertices : (C, V, 3) float64  the part's vertices (padded by repeating one).
    centroid : (C, 3) float64     mean of the vertices: inside the part.
    size : (C,) float64           largest coordinate extent (metres).
    """

    of_blocker: np.ndarray
    normal: np.ndarray
    offset: np.ndarray
    edge_start: np.ndarray
    edge_end: np.ndarray
    edge_faces: np.ndarray
    edge_count: np.ndarray
    vertices: np.ndarray
    centroid: np.ndarray
    size: np.ndarray

    def __len__(self) -> int:
        return len(self.edge_count)

    @classmethod
    def of_polygons(cls, vertices: np.ndarray, count: np.ndarray, max_faces: int = PART_MAX_FACES
                    ) -> "ConvexParts":
        """Find the closed convex parts among convex polygons (B, K, 3) with ``count`` (B,) vertices."""
        n_blockers, width = count.shape[0], vertices.shape[1]
        empty = cls(np.full(n_blockers, -1, np.int64), np.zeros((0, 1, 3)), np.ones((0, 1)), np.zeros((0, 1, 3)),
                    np.zeros((0, 1, 3)), np.zeros((0, 1, 2), np.int64), np.zeros(0, np.int64), np.zeros((0, 1, 3)),
                    np.zeros((0, 3)), np.zeros(0))
        if n_blockers == 0:
            return empty
        corner = np.arange(width)[None, :]
        real = corner < count[:, None]
        face_of_corner = np.broadcast_to(np.arange(n_blockers)[:, None], real.shape)[real]
        positions, vertex_id = _unique_points(vertices[real])
        ids = np.zeros(real.shape, np.int64)
        ids[real] = vertex_id
        # Directed edges: corner i to the next real corner.
        following = np.where(corner + 1 < count[:, None], corner + 1, 0)
        start = ids[real]
        end = np.take_along_axis(ids, following, axis=1)[real]
        label = _components(start, end, len(positions))
        face_label = label[ids[:, 0]]
        # Closed: each undirected edge is used exactly twice, once in each direction.
        n_ids = len(positions)
        key = np.minimum(start, end) * n_ids + np.maximum(start, end)
        order = np.argsort(key, kind="stable")
        key_sorted = key[order]
        new_run = np.concatenate([[True], key_sorted[1:] != key_sorted[:-1]])
        run = np.cumsum(new_run) - 1
        run_length = np.bincount(run)
        direction = np.where(start < end, 1, -1)[order]
        balanced = np.bincount(run, weights=direction) == 0
        good_run = (run_length == 2) & balanced & (start != end)[order][new_run]
        open_label = np.unique(label[start[order][~good_run[run]]])
        faces_per_label = np.bincount(face_label, minlength=n_ids)
        candidate = (faces_per_label >= 2) & (faces_per_label <= max_faces)
        candidate[open_label] = False
        if not candidate[face_label].any():
            return empty
        # Renumber candidate parts 0 .. C-1 and pad their faces, vertices and edges.
        part_of_label = np.full(n_ids, -1, np.int64)
        part_of_label[np.flatnonzero(candidate)] = np.arange(int(candidate.sum()))
        face_part = part_of_label[face_label]
        n_parts = int(candidate.sum())
        faces = np.flatnonzero(face_part >= 0)
        face_slot = _rank_within(face_part[faces])
        n_faces = int(face_slot.max()) + 1
        first_corner = vertices[faces, 0]
        newell = newell_normal(vertices[faces])
        length = np.linalg.norm(newell, axis=1)
        unit = newell / np.maximum(length, 1e-300)[:, None]
        normal = np.zeros((n_parts, n_faces, 3))
        offset = np.ones((n_parts, n_faces))
        normal[face_part[faces], face_slot] = unit
        offset[face_part[faces], face_slot] = np.einsum("nk,nk->n", unit, first_corner)
        # Vertices of each part.
        vertex_part = np.full(n_ids, -1, np.int64)
        vertex_part[ids[real]] = face_part[face_of_corner]
        part_vertices = np.flatnonzero(vertex_part >= 0)
        vertex_slot = _rank_within(vertex_part[part_vertices])
        n_vertices = int(vertex_slot.max()) + 1
        per_part = np.bincount(vertex_part[part_vertices], minlength=n_parts)
        centroid = np.zeros((n_parts, 3))
        for axis in range(3):  # coordinates
            centroid[:, axis] = np.bincount(vertex_part[part_vertices], weights=positions[part_vertices, axis],
                                            minlength=n_parts) / np.maximum(per_part, 1)
        # Padded with the centroid: inside the part, so it passes every test a real vertex must.
        padded = np.repeat(centroid[:, None], n_vertices, axis=1)
        padded[vertex_part[part_vertices], vertex_slot] = positions[part_vertices]
        size = np.abs(padded - centroid[:, None]).max(axis=(1, 2))
        # Convex: every vertex on or behind every face's plane, and faces of positive area.
        real_face = np.zeros((n_parts, n_faces), bool)
        real_face[face_part[faces], face_slot] = length > 0
        has_face = np.zeros((n_parts, n_faces), bool)
        has_face[face_part[faces], face_slot] = True
        convex = (real_face | ~has_face).all(axis=1)
        chunk = max(1, PART_CHECK_VALUES // (n_faces * n_vertices))  # parts per (C, F, V) array
        for first in range(0, n_parts, chunk):  # chunks of parts: bounded temporaries
            rows = slice(first, first + chunk)
            height = np.einsum("cfk,cvk->cfv", normal[rows], padded[rows]) - offset[rows, :, None]
            tolerance = CONVEX_EPS * np.maximum(size[rows], 1e-300)[:, None, None]
            convex[rows] &= (np.where(has_face[rows, :, None], height, 0.0) <= tolerance).all(axis=(1, 2))
        # Edges: the two directed copies of each undirected edge of a candidate part.
        first_copy = order[new_run & good_run[run]]
        second_copy = order[np.concatenate([new_run[1:], [True]]) & good_run[run]]
        edge_part = face_part[face_of_corner[first_copy]]
        inside = edge_part >= 0
        first_copy, second_copy, edge_part = first_copy[inside], second_copy[inside], edge_part[inside]
        edge_slot = _rank_within(edge_part)
        n_edges = int(edge_slot.max()) + 1 if len(edge_slot) else 1
        edge_start = np.zeros((n_parts, n_edges, 3))
        edge_end = np.zeros((n_parts, n_edges, 3))
        edge_faces = np.zeros((n_parts, n_edges, 2), np.int64)
        edge_start[edge_part, edge_slot] = positions[start[first_copy]]
        edge_end[edge_part, edge_slot] = positions[end[first_copy]]
        slot_of_face = np.full(n_blockers, -1, np.int64)
        slot_of_face[faces] = face_slot
        edge_faces[edge_part, edge_slot, 0] = slot_of_face[face_of_corner[first_copy]]
        edge_faces[edge_part, edge_slot, 1] = slot_of_face[face_of_corner[second_copy]]
        edge_count = np.bincount(edge_part, minlength=n_parts)
        # Keep the convex parts only, renumbered.
        keep = np.flatnonzero(convex)
        renumber = np.full(n_parts, -1, np.int64)
        renumber[keep] = np.arange(len(keep))
        of_blocker = np.full(n_blockers, -1, np.int64)
        of_blocker[faces] = renumber[face_part[faces]]
        return cls(of_blocker, normal[keep], offset[keep], edge_start[keep], edge_end[keep], edge_faces[keep],
                   edge_count[keep], padded[keep], centroid[keep], size[keep])


def _rank_within(group: np.ndarray) -> np.ndarray:
    """Position of each element among the elements of its group (in array order): (N,) int64."""
    order = np.argsort(group, kind="stable")
    sorted_group = group[order]
    first = np.searchsorted(sorted_group, sorted_group, side="left")
    rank = np.empty(len(group), np.int64)
    rank[order] = np.arange(len(group)) - first
    return rank


def _components(start: np.ndarray, end: np.ndarray, n_vertices: int) -> np.ndarray:
    """Connected-component label (smallest vertex id) of each vertex (n_vertices,) int64, joined by edges
    (start, end) (E,) int64: union-find, compiled (label propagation in numpy took a few dozen rounds of
    scattered minima, 0.021 s of anti-aliasing's 0.39 s on suzanne_dense3 at 128 px)."""
    return _union_find(np.ascontiguousarray(start, np.int64), np.ascontiguousarray(end, np.int64), int(n_vertices))


@njit(cache=True, nogil=True)
def _union_find(start, end, n_vertices):
    parent = np.arange(n_vertices)
    for e in range(len(start)):
        a, b = start[e], end[e]
        while parent[a] != a:  # roots, halving the paths on the way
            parent[a] = parent[parent[a]]
            a = parent[a]
        while parent[b] != b:
            parent[b] = parent[parent[b]]
            b = parent[b]
        if a < b:  # the smaller id stays the root: a component's root is its smallest vertex
            parent[b] = a
        elif b < a:
            parent[a] = b
    for v in range(n_vertices):  # parents have smaller ids: each vertex's parent is already final
        parent[v] = parent[parent[v]]
    return parent


def triangle_components(triangles: np.ndarray, corner_normals: np.ndarray | None = None) -> np.ndarray:
    """Connected surfaces of a triangle soup: (T,) int64 label of each triangle (T, 3, 3), equal for
    triangles joined through shared vertex positions.

    ``corner_normals`` (T, 3, 3) float64 normals at the corners (any length): corners then join only where their
    normals agree too (to NORMAL_QUANTUM, rounded), so the labels are the smooth pieces of each surface,
    split at its creases (flat faces at an angle, a smooth mesh's sharp edges)."""
    n = len(triangles)
    if n == 0:
        return np.zeros(0, np.int64)
    # Each corner's id: the first corner at the same position (a hash table over the coordinates' bits, + 0.0
    # making -0.0 equal to 0.0), not a sort: only which corners coincide matters here.
    corners = np.ascontiguousarray(np.asarray(triangles, np.float64).reshape(-1, 3) + 0.0)
    vertex_id = _first_equal_rows(corners.view(np.int64))
    if corner_normals is not None:
        # Then the first corner at the same position with the same rounded normal (21 bits a component:
        # |n / quantum| <= 1000 fits).
        normal = np.asarray(corner_normals, np.float64).reshape(-1, 3)
        # Unit length first (a scene's shading normals are finite, not necessarily unit): a longer one
        # would overflow its 21 bits into the next component's and join normals that differ.
        normal = normal / np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
        code = np.round(normal / NORMAL_QUANTUM).astype(np.int64) + (1 << 20)
        normal_code = (code[:, 0] << 42) | (code[:, 1] << 21) | code[:, 2]
        vertex_id = _first_equal_rows(np.stack([vertex_id, normal_code, np.zeros_like(vertex_id)], axis=1))
    vertex_id = vertex_id.reshape(n, 3)
    label = _components(vertex_id[:, :2].reshape(-1), vertex_id[:, 1:].reshape(-1), 3 * n)
    return label[vertex_id[:, 0]]


# Corner normals (unit vectors) are compared rounded to this: a quad's two triangles, whose normals are
# computed apart, differ in the last bits only. Two normals that straddle a rounding boundary stay apart:
# one surface more for coverage, never a wrong join.
NORMAL_QUANTUM = 1e-3


def silhouette_planes(parts: ConvexParts, part: np.ndarray, receiver: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The cone from each receiver through a convex part, as planes through its silhouette edges.

    Parameters
    ----------
    part : (N,) int64              convex part index.
    receiver : (N, 3) float64      the cone's apex, outside the part.

    Returns
    -------
    planes : (N, S, 3) float64     unit normals through the receiver; a direction w is inside the cone
                                   when planes . w > 0 for every valid plane (S <= SILHOUETTE_MAX_EDGES).
    valid : (N, S) bool
    usable : (N,) bool             False where the receiver is on or inside the part (no face turned
                                   away from it, or none towards it) or the silhouette has more than
                                   SILHOUETTE_MAX_EDGES edges: clip by the faces there.
    """
    n_edges = int(parts.edge_count[part].max()) if len(part) else 1
    normal, offset = parts.normal[part], parts.offset[part]
    tolerance = CONVEX_EPS * (parts.size[part] + np.abs(receiver).max(axis=1))
    facing = np.einsum("nfk,nk->nf", normal, receiver) - offset
    # A face seen edge-on (the receiver in its plane, as on a floor a box stands on) counts as turned
    # away: the silhouette is then the one seen from just behind that plane, and its planes through the
    # receiver bound the same cone (the edge-on face's own plane supports it).
    front = facing > tolerance[:, None]
    has_face = np.abs(normal).sum(axis=2) > 0
    faces = parts.edge_faces[part, :n_edges]
    edge_valid = np.arange(n_edges)[None, :] < parts.edge_count[part][:, None]
    front_a = np.take_along_axis(front, faces[..., 0], axis=1)
    front_b = np.take_along_axis(front, faces[..., 1], axis=1)
    silhouette = (front_a != front_b) & edge_valid
    n_silhouette = silhouette.sum(axis=1)
    usable = front.any(axis=1) & (has_face & ~front).any(axis=1) & (n_silhouette >= 3) \
        & (n_silhouette <= SILHOUETTE_MAX_EDGES)
    width = int(min(max(n_silhouette.max() if len(part) else 3, 3), SILHOUETTE_MAX_EDGES))
    # Compact each row's silhouette edges into its first slots.
    slot = np.cumsum(silhouette, axis=1) - 1
    row, column = np.nonzero(silhouette & (slot < width))
    chosen = np.zeros((len(part), width), np.int64)
    chosen[row, slot[row, column]] = column
    valid = (np.arange(width)[None, :] < n_silhouette[:, None]) & usable[:, None]
    a = parts.edge_start[part[:, None], chosen] - receiver[:, None]
    b = parts.edge_end[part[:, None], chosen] - receiver[:, None]
    planes = cross3(a, b)
    # Inside is towards the part: its centroid lies strictly inside every silhouette plane.
    towards = np.einsum("nsk,nk->ns", planes, parts.centroid[part] - receiver)
    norm = np.sqrt(np.einsum("nsk,nsk->ns", planes, planes))
    planes *= (np.where(towards > 0, 1.0, -1.0) / np.maximum(norm, 1e-300))[:, :, None]
    valid &= norm ** 2 > 1e-28 * np.einsum("nsk,nsk->ns", a, a) * np.einsum("nsk,nsk->ns", b, b)
    return planes, valid, usable
