"""Blocker polygons: coplanar triangle pairs merged into convex quads, and the image unchanged by it."""

import numpy as np

from lazyvis_addon.core import Settings, render
from lazyvis_addon.core.blockers import BlockerPolygons
from lazyvis_addon.core.demo_scenes import box_triangles, floating_boxes


def polygon_area(vertices, count):
    v = vertices[:count]
    return 0.5 * np.linalg.norm(np.sum(np.cross(v, np.roll(v, -1, axis=0)), axis=0))


def test_a_box_becomes_six_convex_quads_of_the_same_area():
    tris = box_triangles((0.3, -0.2, 1.0), (1.0, 2.0, 0.5), rotation_z=0.4)
    blockers = BlockerPolygons.from_triangles(tris)
    assert len(blockers) == 6 and (blockers.count == 4).all()
    # Every triangle maps to a quad containing it; areas add up.
    for quad in range(6):
        members = np.flatnonzero(blockers.of_triangle == quad)
        assert len(members) == 2
        tri_area = sum(0.5 * np.linalg.norm(np.cross(tris[m, 1] - tris[m, 0], tris[m, 2] - tris[m, 0])) for m in members)
        assert np.isclose(polygon_area(blockers.vertices[quad], 4), tri_area, rtol=1e-12)
    # Orientation kept: the quad's normal points the way its triangles' normals do.
    for quad in range(6):
        v = blockers.vertices[quad]
        quad_normal = np.sum(np.cross(v, np.roll(v, -1, axis=0)), axis=0)
        t = tris[np.flatnonzero(blockers.of_triangle == quad)[0]]
        assert np.dot(quad_normal, np.cross(t[1] - t[0], t[2] - t[0])) > 0


def test_folded_and_non_convex_pairs_stay_triangles():
    folded = np.array([[(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(1, 0, 0), (0, 1, 0), (1, 1, 0.3)]], float)
    dart = np.array([[(0, 0, 0), (2, 0, 0), (0, 2, 0)], [(2, 0, 0), (0, 2, 0), (0.4, 0.4, 0)]], float)
    for pair in (folded, dart):
        blockers = BlockerPolygons.from_triangles(pair)
        assert len(blockers) == 2 and (blockers.count == 3).all()
    assert len(BlockerPolygons.from_triangles(box_triangles((0, 0, 0), (1, 1, 1)), merge=False)) == 12


def test_merged_quads_change_nothing_exact_and_miss_less():
    """Quads and convex parts' silhouettes (merge_quads) clip exactly like the triangles one by one."""
    scene = floating_boxes(resolution=64, n_boxes=9)
    reference = render(scene, Settings(integrator="reference", merge_quads=True)).combined
    reference_split = render(scene, Settings(integrator="reference", merge_quads=False)).combined
    np.testing.assert_allclose(reference, reference_split, rtol=1e-9, atol=1e-12 * reference.max())
    # Detection alone (the paper's blocker map, verification off): a quad is found when either of its
    # triangles is hit.
    merged = render(scene, Settings(merge_quads=True, verify_rays=0, visibility="blocker_map"))
    split = render(scene, Settings(merge_quads=False, verify_rays=0, visibility="blocker_map"))
    error = lambda image: np.sqrt(np.mean((image - reference) ** 2))
    assert error(merged.combined) <= error(split.combined)
    assert merged.stats["pairs_stored"] < 0.8 * split.stats["pairs_stored"]


# ---------------------------------------------------------------------------------------------------------
# Closed convex parts and their silhouette cones
# ---------------------------------------------------------------------------------------------------------

def ray_hits_box(origin, direction, lower, upper):
    """Slab test: does the ray origin + t direction (t > 0) meet the axis-aligned box? (N,) bool."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lower - origin) / direction
        t2 = (upper - origin) / direction
    near = np.nanmax(np.minimum(t1, t2), axis=1)
    far = np.nanmin(np.maximum(t1, t2), axis=1)
    return (far >= np.maximum(near, 0.0)) & (far > 0)


def test_closed_convex_meshes_are_parts_and_others_are_not():
    box = box_triangles((0, 0, 0.5), (1.0, 2.0, 1.0))
    other_box = box_triangles((5, 0, 0.5), (1.0, 1.0, 1.0), rotation_z=0.3)
    open_box = box_triangles((-5, 0, 0.5), (1.0, 1.0, 1.0))[[0, 1, 2, 3, 4, 6, 7, 8, 9, 10]]  # a quad missing
    inside_out = box_triangles((0, 5, 0.5), (1.0, 1.0, 1.0))[:, ::-1]  # normals inward: not convex outward
    # An L-shaped prism: closed, but not convex.
    l_outline = np.array([(0, 0), (2, 0), (2, 1), (1, 1), (1, 2), (0, 2)], float) + (10, 10)
    floor_tris = [(0, 1, 2), (0, 2, 3), (0, 3, 4), (0, 4, 5)]
    bottom = np.array([[np.append(l_outline[i], 0) for i in t[::-1]] for t in floor_tris])
    top = np.array([[np.append(l_outline[i], 1) for i in t] for t in floor_tris])
    sides = []
    for i in range(6):  # the prism's six side quads
        a, b = l_outline[i], l_outline[(i + 1) % 6]
        sides += [[(*a, 0), (*b, 0), (*b, 1)], [(*a, 0), (*b, 1), (*a, 1)]]
    l_prism = np.concatenate([bottom, top, np.array(sides, float)])
    plane = np.array([[(-9, -9, 0), (9, -9, 0), (9, 9, 0)], [(-9, -9, 0), (9, 9, 0), (-9, 9, 0)]], float)
    pieces = [box, other_box, open_box, inside_out, l_prism, plane]
    triangles = np.concatenate(pieces)
    blockers = BlockerPolygons.from_triangles(triangles)
    part = blockers.parts.of_blocker[blockers.of_triangle]
    bounds = np.cumsum([0] + [len(p) for p in pieces])
    part_of_piece = [np.unique(part[bounds[i]:bounds[i + 1]]) for i in range(len(pieces))]
    assert len(blockers.parts) == 2
    assert len(part_of_piece[0]) == 1 and len(part_of_piece[1]) == 1 and part_of_piece[0] != part_of_piece[1]
    assert part_of_piece[0][0] >= 0 and part_of_piece[1][0] >= 0
    for piece in part_of_piece[2:]:
        assert (piece == -1).all()
    # Without merging nothing is looked for.
    assert BlockerPolygons.from_triangles(triangles, merge=False).parts is None


def test_silhouette_cone_is_the_set_of_directions_that_hit_the_box():
    rng = np.random.default_rng(5)
    centre, size = np.array([0.2, -0.1, 0.6]), np.array([0.4, 1.0, 1.2])
    blockers = BlockerPolygons.from_triangles(box_triangles(centre, size))
    parts = blockers.parts
    lower, upper = centre - size / 2, centre + size / 2
    # Receivers around the box, some on the plane of its bottom face (a box standing on a floor).
    receiver = rng.uniform(-3, 3, (4000, 3))
    receiver[:1000, 2] = lower[2]
    outside = ((receiver < lower - 1e-3) | (receiver > upper + 1e-3)).any(axis=1)
    receiver = receiver[outside]
    from lazyvis_addon.core.blockers import silhouette_planes
    planes, valid, usable = silhouette_planes(parts, np.zeros(len(receiver), np.int64), receiver)
    assert usable.all()
    assert set(np.unique(valid.sum(axis=1))) <= {4, 6}
    # Directions towards the box and at random.
    target = rng.uniform(lower - 0.3 * size, upper + 0.3 * size, (len(receiver), 3))
    for direction in (target - receiver, rng.normal(size=receiver.shape)):
        inside = np.where(valid, np.einsum("nsk,nk->ns", planes, direction) > 0, True).all(axis=1)
        hits = ray_hits_box(receiver, direction, lower, upper)
        assert (inside == hits).mean() > 0.999  # directions grazing an edge may go either way
        assert inside.any() and (~inside).any()



def test_triangle_components_join_triangles_through_shared_vertices():
    """Two boxes apart are two components, a quad's two triangles one; boxes sharing one corner join;
    triangles are joined by vertex positions, not by their order in the soup."""
    from lazyvis_addon.core.blockers import triangle_components
    apart = np.concatenate([box_triangles((0, 0, 0), (1, 1, 1)), box_triangles((5, 0, 0), (1, 1, 1))])
    label = triangle_components(apart)
    assert len(np.unique(label[:12])) == 1 and len(np.unique(label[12:])) == 1 and label[0] != label[12]
    order = np.random.default_rng(0).permutation(len(apart))
    shuffled = triangle_components(apart[order])
    assert len(np.unique(shuffled)) == 2
    np.testing.assert_array_equal(shuffled[:, None] == shuffled[None, :], label[order][:, None] == label[order][None, :])
    touching = np.concatenate([box_triangles((0, 0, 0), (1, 1, 1)), box_triangles((1, 1, 1), (1, 1, 1))])
    assert len(np.unique(triangle_components(touching))) == 1  # the corner (0.5, 0.5, 0.5) is shared
    assert len(triangle_components(np.zeros((0, 3, 3)))) == 0
