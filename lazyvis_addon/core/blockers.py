"""Blocker polygons: the units that occlude lights in both passes.

The paper clips one triangle per blocker. A quad face of a mesh is two triangles sharing a diagonal,
and clipping by both cuts every visible piece along that diagonal only for the second triangle to remove
the fragments again. Coplanar triangle pairs that share their longest edge and form a convex quad are
merged into one quad blocker (a first step towards the paper's future work on silhouette blockers):
fewer blocker–light pairs to flood-fill and store, fewer and larger pieces in pass 2, and a quad can
surround a light where neither of its triangles could (more umbra detected).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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
    """

    vertices: np.ndarray
    count: np.ndarray
    of_triangle: np.ndarray

    def __len__(self) -> int:
        return len(self.count)

    @classmethod
    def from_triangles(cls, triangles: np.ndarray, merge: bool = True) -> "BlockerPolygons":
        """Blockers of a triangle soup (T, 3, 3); ``merge`` pairs coplanar triangles into convex quads."""
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
        return cls(vertices, count, of_triangle)


def _longest_edge(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index (0..2) of each triangle's longest edge (from vertex i to i+1) and of the opposite vertex."""
    lengths = np.linalg.norm(np.roll(triangles, -1, axis=1) - triangles, axis=2)
    edge = np.argmax(lengths, axis=1)
    return edge, (edge + 2) % 3


def _quad_partners(triangles: np.ndarray) -> np.ndarray:
    """For each triangle, the triangle it merges with into a convex planar quad, or -1."""
    n = len(triangles)
    _, vertex_id = np.unique(triangles.reshape(-1, 3), axis=0, return_inverse=True)
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
    rows = np.arange(len(tri_a))
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
