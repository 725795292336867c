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
    scene = floating_boxes(resolution=64, n_boxes=9)
    reference = render(scene, Settings(integrator="reference", merge_quads=True)).combined
    reference_split = render(scene, Settings(integrator="reference", merge_quads=False)).combined
    np.testing.assert_allclose(reference, reference_split, atol=1e-6 * reference.max())
    # Detection alone (verification off): a quad is found when either of its triangles is hit.
    merged = render(scene, Settings(merge_quads=True, verify_rays=0))
    split = render(scene, Settings(merge_quads=False, verify_rays=0))
    error = lambda image: np.sqrt(np.mean((image - reference) ** 2))
    assert error(merged.combined) <= error(split.combined)
    assert merged.stats["pairs_stored"] < 0.8 * split.stats["pairs_stored"]
