"""Pass 2 by silhouettes (the default visibility): exact against the reference integrator on the geometry
that leaks through the paper's blocker map (sub-pixel leaves, dense smooth meshes, foliage), on broken
meshes, and unchanged by its batching and cells."""


import numpy as np
import pytest

from lazyvis_addon.core import Camera, Materials, Scene, Settings, render
from lazyvis_addon.core import detection, edge_tree, regions, silhouettes
from lazyvis_addon.core.demo_scenes import box_triangles, look_at, plane_under_light, quad_triangles
from lazyvis_addon.core.geometry import light_frames
from lazyvis_addon.core.scene import Lights
from lazyvis_addon.core.edge_tree import MeshEdges

CENTRES = Settings(aa_samples=1)


def uv_sphere(centre, radius, rings=12, segments=16) -> np.ndarray:
    """A closed UV sphere (T, 3, 3), outward winding."""
    theta = np.linspace(0.0, np.pi, rings + 1)
    phi = np.linspace(0.0, 2.0 * np.pi, segments + 1)
    grid = np.stack([np.sin(theta)[:, None] * np.cos(phi)[None], np.sin(theta)[:, None] * np.sin(phi)[None],
                     np.broadcast_to(np.cos(theta)[:, None], (rings + 1, segments + 1))], axis=-1)
    grid = np.asarray(centre) + radius * grid
    a, b = grid[:-1, :-1].reshape(-1, 3), grid[1:, :-1].reshape(-1, 3)
    c, d = grid[1:, 1:].reshape(-1, 3), grid[:-1, 1:].reshape(-1, 3)
    triangles = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    area = np.linalg.norm(np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]), axis=1)
    return triangles[area > 1e-12]  # the poles' collapsed triangles


def leaves(count, seed, centre=(0.0, 0.0, 0.5), spread=0.4, size=0.05) -> np.ndarray:
    """``count`` separate small quads at random orientations (2 triangles each)."""
    rng = np.random.default_rng(seed)
    middle = np.asarray(centre) + rng.uniform(-spread, spread, (count, 3)) * (1.0, 1.0, 0.4)
    axes = rng.normal(size=(count, 2, 3))
    axes /= np.linalg.norm(axes, axis=2, keepdims=True)
    u, v = axes[:, 0] * size / 2, axes[:, 1] * size / 4
    corners = np.stack([middle - u - v, middle + u - v, middle + u + v, middle - u + v], axis=1)
    return np.concatenate([corners[:, [0, 1, 2]], corners[:, [0, 2, 3]]])


def exact(scene, settings=CENTRES):
    """The default render and the reference integrator's, RGB. The reference clips triangle by triangle:
    with merged quads it is 1.3e-4 off at one pixel of the sphere (measured), which the triangles and
    the silhouettes (with and without cells) agree on to every digit."""
    return (render(scene, settings).combined[..., :3],
            render(scene, settings.replace(integrator="reference", merge_quads=False)).combined[..., :3])


def assert_exact(image, reference):
    np.testing.assert_allclose(image, reference, rtol=1e-6, atol=1e-7 * reference.max())


def test_a_leaf_far_smaller_than_a_pixel_shadows_the_floor():
    """A 2 cm leaf over a floor whose pixels are 25 cm wide (a twelfth of the footprint): no shadow ray of
    the blocker map hits it, so the paper's method leaks its light; the silhouettes find it by the edge
    tree, and the image is the reference integrator's."""
    leaf = quad_triangles([(0.05, 0.05, 0.3), (0.07, 0.05, 0.3), (0.07, 0.07, 0.3), (0.05, 0.07, 0.3)])
    scene = plane_under_light(resolution=16, blocker=leaf)
    image, reference = exact(scene)
    open_floor = render(plane_under_light(resolution=16), CENTRES).combined[..., :3]
    assert (reference < open_floor - 1e-6).any(), "the leaf casts no shadow: the test proves nothing"
    assert_exact(image, reference)
    paper = render(scene, CENTRES.replace(visibility="blocker_map")).combined[..., :3]
    assert np.abs(paper - reference).max() > 1e-4  # what the shadow rays missed


def test_dense_sphere_over_a_floor_matches_the_reference():
    """A smooth closed mesh: its silhouette arcs, not its 370 triangles, clip the light, and the floor's
    penumbra and the sphere's own terminator are exact."""
    scene = plane_under_light(resolution=20, light_size=1.2, height=1.4, blocker=uv_sphere((0.2, -0.1, 0.6), 0.35))
    image, reference = exact(scene)
    assert_exact(image, reference)
    out = render(scene, CENTRES)
    # Every arc passed an exact test, and the edge tree's culling left few tests: under 5 % of every
    # (edge record, pixel) pair (0.7 % measured; with sub-groups of receivers off each couple's own hull
    # culls, so nearly every test found an arc: 1,461 of 1,551).
    assert 0 < out.stats["arcs"] <= out.stats["edge_tests"] < 0.05 * out.stats["edge_records"] * out.stats["pixels"]
    assert 0 < out.stats["max_blockers_per_couple"] < 40     # arcs per couple, of 370 triangles
    assert (out.blocker_count > 0).any()


@pytest.mark.parametrize("defect", ["non_manifold", "duplicate_faces", "flipped_normals", "zero_area",
                                    "coplanar_overlap"])
def test_broken_meshes_render_exactly(defect):
    """Edges shared by three faces, faces repeated, faces wound against their neighbours, faces of no
    area: the depth jumps add up per face whatever the mesh's topology, so every case is exact. Two
    distinct coplanar plates overlapping: a ray through the overlap counts one layer, but the probe rays
    outside it outvote it (a plate overlap covering most of a light would not be outvoted)."""
    blocker = box_triangles((0.1, 0.0, 0.5), (0.5, 0.4, 0.2))
    if defect == "non_manifold":  # a fin on one of the bottom face's edges, slanting out of the box
        fin = np.array([[blocker[0, 0], blocker[0, 1], blocker[0, 0] + (-0.3, 0.0, 0.4)]])
        blocker = np.concatenate([blocker, fin])
    elif defect == "duplicate_faces":
        blocker = np.concatenate([blocker, blocker[:4]])
    elif defect == "flipped_normals":
        blocker = blocker.copy()
        blocker[::3] = blocker[::3, ::-1]
    elif defect == "coplanar_overlap":
        blocker = np.concatenate([
            quad_triangles([(-0.3, -0.3, 0.5), (0.2, -0.3, 0.5), (0.2, 0.2, 0.5), (-0.3, 0.2, 0.5)]),
            quad_triangles([(-0.1, -0.1, 0.5), (0.4, -0.1, 0.5), (0.4, 0.4, 0.5), (-0.1, 0.4, 0.5)])])
    elif defect == "zero_area":
        line = np.array([[(0.0, 0.0, 0.4), (0.3, 0.0, 0.4), (0.6, 0.0, 0.4)],
                         [(0.2, 0.2, 0.45), (0.2, 0.2, 0.45), (0.4, 0.1, 0.45)]])
        blocker = np.concatenate([blocker, line])
    scene = plane_under_light(resolution=16, blocker=blocker)
    image, reference = exact(scene)
    assert_exact(image, reference)


def test_stacked_plates_and_a_pole_through_the_lights_plane():
    """Depth 2 under two overlapping plates (a region bounded only where both end), and a pole that
    crosses the light's plane beside the light (its faces are clipped where they cross: cut segments)."""
    plates = np.concatenate([quad_triangles([(-0.4, -0.4, 0.4), (0.1, -0.4, 0.4), (0.1, 0.1, 0.4), (-0.4, 0.1, 0.4)]),
                             quad_triangles([(-0.2, -0.2, 0.6), (0.3, -0.2, 0.6), (0.3, 0.3, 0.6), (-0.2, 0.3, 0.6)])])
    pole = box_triangles((0.62, 0.1, 1.0), (0.1, 0.1, 1.6))
    scene = plane_under_light(resolution=18, blocker=np.concatenate([plates, pole]))
    image, reference = exact(scene)
    assert_exact(image, reference)
    edges = MeshEdges.from_triangles(scene.triangles, light_frames(scene.validated().lights))
    assert (edges.light >= 0).sum() == 8  # the pole's 8 side triangles cross the light's plane


def test_probe_rays_outvote_a_miscounted_reference_ray_in_two_rounds(monkeypatch):
    """Leaves over a floor, one crossed region in five with R's own ray a layer off: R's count and two
    probes decide where they agree, the other two probes are cast only where they differ, and the mode of
    all five restores every region's depth: the image is the one without the miscount."""
    scene = plane_under_light(resolution=12, blocker=leaves(150, seed=5))
    clean = render(scene, CENTRES)
    counts = silhouettes.depth_counts
    miscounted = []

    def miscounting(tracer, origin, target, own_triangle, full, *args):
        count = counts(tracer, origin, target, own_triangle, full, *args)
        if not full.all():  # the reference rays (probe rays count every region fully)
            wrong = full & (np.arange(len(count)) % 5 == 0)
            count[wrong] += 1
            miscounted.append(int(wrong.sum()))
        return count

    monkeypatch.setattr(silhouettes, "depth_counts", miscounting)
    out = render(scene, CENTRES)
    assert sum(miscounted) > 20
    np.testing.assert_array_equal(out.combined, clean.combined)
    # The second round's two probes only where R was off (and where the clean render needed them too).
    assert clean.stats["depth_rays"] < out.stats["depth_rays"] <= clean.stats["depth_rays"] + 2 * sum(miscounted)


def test_foliage_cells_and_buffers_change_nothing(monkeypatch):
    """Many leaves over a floor: couples crossed by many arcs are cut into cells, each with its own
    reference point, whose depth is carried from the couple's across the arcs between (a wrong carry
    fails here); cells, no cells and chunks of a query or two (detection's buffer outgrown again and
    again, each walk going on in a new buffer from the query it was in) give the same image, the
    reference's, and so do the couples' cones in one row at first (outgrown as often)."""
    scene = plane_under_light(resolution=12, blocker=leaves(150, seed=3))
    image, reference = exact(scene)
    assert_exact(image, reference)
    out = render(scene, CENTRES)
    assert out.stats["cells"] > 0
    monkeypatch.setattr(detection, "CONE_ROWS", 1)  # the couples' cones outgrow their rows again and again
    again = render(scene, CENTRES)
    assert again.stats["arcs"] == out.stats["arcs"]
    np.testing.assert_array_equal(again.combined, out.combined)
    monkeypatch.setattr(regions, "CELL_ARCS", 10 ** 9)
    monkeypatch.setattr(silhouettes, "ARC_CHUNK", 1)
    whole = render(scene, CENTRES)
    assert whole.stats["cells"] == 0 and whole.stats["arcs"] == out.stats["arcs"]
    np.testing.assert_allclose(whole.combined, out.combined, rtol=1e-9, atol=1e-12)


def test_two_sided_emitter_and_a_box_on_the_floor():
    """A box standing on the floor (faces seen edge-on from the floor, the receiver's own plane) and a
    two-sided light lighting both sides of a wall."""
    box = box_triangles((0.2, 0.1, 0.25), (0.5, 0.3, 0.5))
    scene = plane_under_light(resolution=16, blocker=box)
    quad = np.array([(-0.6, -0.6, 1.0), (0.6, -0.6, 1.0), (0.6, 0.6, 1.0), (-0.6, 0.6, 1.0)])
    scene.lights = Lights.from_polygons([quad], [(1.0, 1.0, 1.0)], two_sided=[True])
    image, reference = exact(scene)
    assert_exact(image, reference)


def test_mesh_edges_pair_faces_and_keep_boundaries():
    """A closed box: 18 edges with two faces each; an open quad: 4 boundary edges with one face and the
    diagonal with two."""
    box = MeshEdges.from_triangles(box_triangles((0, 0, 0), (1, 1, 1)))
    assert len(box) == 18 and (box.triangle >= 0).all()
    quad = MeshEdges.from_triangles(quad_triangles([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]))
    faces = (quad.triangle >= 0).sum(axis=1)
    assert len(quad) == 5 and sorted(faces.tolist()) == [1, 1, 1, 1, 2]
    # A book of six pages on one spine: the spine's six faces over two records (MAX_INCIDENCE = 4 each);
    # each page's two other edges are boundaries.
    spine = np.array([(0.0, 0.0, 0.0), (0.0, 1.0, 0.0)])
    angles = np.linspace(0.0, np.pi, 6)
    pages = np.array([[spine[0], spine[1], (np.cos(a), 0.5, np.sin(a))] for a in angles])
    book = MeshEdges.from_triangles(pages)
    faces = (book.triangle >= 0).sum(axis=1)
    along_spine = (np.abs(book.start[:, 0]) + np.abs(book.end[:, 0]) + np.abs(book.start[:, 2])
                   + np.abs(book.end[:, 2])) == 0
    assert len(book) == 14 and sorted(faces[along_spine].tolist()) == [2, 4]
    assert sorted(book.triangle[along_spine][book.triangle[along_spine] >= 0].tolist()) == list(range(6))


def fan_area(couple, start, end, sign, reference, n_couples):
    """Signed area per couple of the fans (R, start, end), all directions on the plane z = 1."""
    r = reference[couple]
    cross = (start[:, 0] - r[:, 0]) * (end[:, 1] - r[:, 1]) - (start[:, 1] - r[:, 1]) * (end[:, 0] - r[:, 0])
    return np.bincount(couple, weights=0.5 * sign * cross, minlength=n_couples)


def test_arrangement_kernel_on_hand_made_arcs():
    """The compiled arrangement (``arrangement.visible_fans``) on directions in the plane z = 1: a square
    light [-1, 1]^2 with R at (0.3, 0.4). Couple 0: one arc along y = 0 hides the half below it (jump +1
    away from R): visible area 2 of 4. Couple 1: the same arc and a second along x = 0.5 hiding x > 0.5
    (another +1): visible [-1, 0.5] x [0, 1], area 1.5, and where both hide D = 2. Couple 2: no arc
    reaches it and D(R) = 1: nothing visible. (A jump's sign is the change of D crossing its arc away from
    R's side.)"""
    from lazyvis_addon.core.arrangement import visible_fans
    square = np.array([[-1.0, -1.0, 1.0], [1.0, -1.0, 1.0], [1.0, 1.0, 1.0], [-1.0, 1.0, 1.0]])
    light_dirs = np.repeat(square[None], 3, axis=0)
    reference = np.repeat([[0.3, 0.4, 1.0]], 3, axis=0)

    def arc(couple, a, b, jump):
        a, b = np.asarray(a, float), np.asarray(b, float)
        normal = np.cross(a, b)
        return couple, a, b, normal, jump

    rows = [arc(0, (-2, 0, 1), (2, 0, 1), 1), arc(1, (-2, 0, 1), (2, 0, 1), 1), arc(1, (0.5, -2, 1), (0.5, 2, 1), 1)]
    arcs = silhouettes.Arcs(np.array([r[0] for r in rows]), np.array([r[1] for r in rows]),
                            np.array([r[2] for r in rows]), np.array([r[3] for r in rows]),
                            np.full(3, 0.25), np.full(3, 0.75), np.array([r[4] for r in rows]))
    couple, start, end, sign, whole, inconsistent = visible_fans(arcs, light_dirs, np.full(3, 4), reference,
                                                                 np.array([0, 0, 1]))
    area = fan_area(couple, start, end, sign, reference, 3) + 4.0 * whole
    np.testing.assert_allclose(area, [2.0, 1.5, 0.0], atol=1e-12)
    assert inconsistent == 0 and not whole[2]


def test_arcs_entering_across_a_light_edge_take_the_depth_beside_them():
    """An arc entering the light across an edge takes its first piece's depth from the edge piece on R's
    side of it (not a walk from R): square light [-1, 1]^2 on z = 1, R at (0.3, 0.4) inside one layer
    (D(R) = 1). Couple 0: an arc along y = 0 leaving that layer (jump -1 away from R): the lower half is
    visible, area 2. Couple 1: also an arc along x = 0.5 adding a layer beyond it (+1): only x < 0.5, y < 0
    is visible, area 1.5. Taking the edge piece on the wrong side of an arc would flip which half is seen."""
    from lazyvis_addon.core.arrangement import visible_fans
    square = np.array([[-1.0, -1.0, 1.0], [1.0, -1.0, 1.0], [1.0, 1.0, 1.0], [-1.0, 1.0, 1.0]])
    light_dirs = np.repeat(square[None], 2, axis=0)
    reference = np.repeat([[0.3, 0.4, 1.0]], 2, axis=0)
    rows = [(0, (-2.0, 0.0, 1.0), (2.0, 0.0, 1.0), -1), (1, (-2.0, 0.0, 1.0), (2.0, 0.0, 1.0), -1),
            (1, (0.5, -2.0, 1.0), (0.5, 2.0, 1.0), 1)]
    a = np.array([r[1] for r in rows])
    b = np.array([r[2] for r in rows])
    arcs = silhouettes.Arcs(np.array([r[0] for r in rows]), a, b, np.cross(a, b), np.full(3, 0.25),
                            np.full(3, 0.75), np.array([r[3] for r in rows]))
    couple, start, end, sign, whole, inconsistent = visible_fans(arcs, light_dirs, np.full(2, 4), reference,
                                                                 np.ones(2, np.int64))
    area = fan_area(couple, start, end, sign, reference, 2) + 4.0 * whole
    np.testing.assert_allclose(area, [2.0, 1.5], atol=1e-12)
    assert inconsistent == 0


def test_arcs_through_the_lights_corners():
    """The depth inside the light carries from one light edge to the next over their shared vertex, except
    where an arc passes through that vertex: square light [-1, 1]^2 on z = 1, R at (-0.3, 0.4). Couple 0:
    an arc along the diagonal y = x, through two corners, hides the half below it (area 2 visible).
    Couple 1: an arc from the corner (1, -1) to (0, 1) hides the triangle right of it (area 3 visible).
    Couple 2: both: the triangle's part above the diagonal, (1, 1), (0, 1), (1/3, 1/3), of area 1/3, hides
    more (area 5/3 visible)."""
    from lazyvis_addon.core.arrangement import visible_fans
    square = np.array([[-1.0, -1.0, 1.0], [1.0, -1.0, 1.0], [1.0, 1.0, 1.0], [-1.0, 1.0, 1.0]])
    light_dirs = np.repeat(square[None], 3, axis=0)
    reference = np.repeat([[-0.3, 0.4, 1.0]], 3, axis=0)
    diagonal = ((-2.0, -2.0, 1.0), (2.0, 2.0, 1.0))
    through_corner = ((1.5, -2.0, 1.0), (-0.5, 2.0, 1.0))
    rows = [(0, *diagonal), (1, *through_corner), (2, *diagonal), (2, *through_corner)]
    a = np.array([r[1] for r in rows])
    b = np.array([r[2] for r in rows])
    arcs = silhouettes.Arcs(np.array([r[0] for r in rows]), a, b, np.cross(a, b), np.full(4, 0.25),
                            np.full(4, 0.75), np.ones(4, np.int64))  # both arcs are inside for t in 0.25 .. 0.75
    couple, start, end, sign, whole, inconsistent = visible_fans(arcs, light_dirs, np.full(3, 4), reference,
                                                                 np.zeros(3, np.int64))
    area = fan_area(couple, start, end, sign, reference, 3) + 4.0 * whole
    np.testing.assert_allclose(area, [2.0, 3.0, 5.0 / 3.0], atol=1e-12)
    assert inconsistent == 0


def test_a_leafs_rim_is_not_split_where_its_arcs_meet():
    """Leaves' rims: the arcs of a chain share their ends, where rounding alone makes them cross; such a
    split cut a sliver off the arc whose depth, walked from R afresh, came out negative (the tree sample:
    on nine couples in ten; harmless to the image, a wasted walk). Forty small random convex quads (leaves
    far above a receiver) around R = (0.3, 0.4) inside the square light [-1, 1]^2 on z = 1, one per
    couple, R inside some of them, all turned as a receiver sees them: the visible area is the light's
    minus the quad's, no depth comes out negative, and each rim arc is one piece."""
    from lazyvis_addon.core.arrangement import visible_fans
    rng = np.random.default_rng(7)
    square = np.array([[-1.0, -1.0, 1.0], [1.0, -1.0, 1.0], [1.0, 1.0, 1.0], [-1.0, 1.0, 1.0]])
    n = 40
    reference = np.repeat([[0.3, 0.4, 1.0]], n, axis=0)
    rows, depth, hidden = [], np.zeros(n, np.int64), np.zeros(n)
    for c in range(n):
        centre = np.array([0.3, 0.4]) + rng.uniform(-0.02, 0.02, 2)
        angles = np.sort(rng.uniform(0.0, 2.0 * np.pi, 4))
        radii = rng.uniform(0.005, 0.02, 4)  # small, as leaves far above a receiver
        quad = np.column_stack([centre[0] + radii * np.cos(angles), centre[1] + radii * np.sin(angles), np.ones(4)])
        turns = [np.cross(quad[(k + 1) % 4] - quad[k], quad[(k + 2) % 4] - quad[(k + 1) % 4])[2] for k in range(4)]
        if min(turns) < 0:
            quad[:, :2] = centre + 0.01 * np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]])  # not convex: a square
        inside = [np.cross(quad[(k + 1) % 4] - quad[k], reference[c] - quad[k])[2] > 0 for k in range(4)]
        depth[c] = all(inside)
        hidden[c] = 0.5 * abs(sum(np.cross(quad[k], quad[(k + 1) % 4])[2] for k in range(4)))
        for k in range(4):  # a jump is the change of D crossing the arc away from R's side
            rows.append((c, quad[k], quad[(k + 1) % 4], -1 if inside[k] else 1))
    # Turned as a receiver would see them (on z = 1 the rounding is too kind to show the slivers).
    turn, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    a = np.array([r[1] for r in rows]) @ turn.T
    b = np.array([r[2] for r in rows]) @ turn.T
    arcs = silhouettes.Arcs(np.array([r[0] for r in rows]), a, b, np.cross(a, b), np.zeros(len(rows)),
                            np.ones(len(rows)), np.array([r[3] for r in rows]))
    couple, start, end, sign, whole, inconsistent = visible_fans(
        arcs, np.repeat((square @ turn.T)[None], n, axis=0), np.full(n, 4), reference @ turn.T, depth)
    start, end = start @ turn, end @ turn
    r = reference[couple]  # each fan (R, start, end) counts its area with its sign, whichever its winding
    cross = (start[:, 0] - r[:, 0]) * (end[:, 1] - r[:, 1]) - (start[:, 1] - r[:, 1]) * (end[:, 0] - r[:, 0])
    area = np.bincount(couple, weights=0.5 * sign * np.abs(cross), minlength=n) + 4.0 * whole
    np.testing.assert_allclose(area, 4.0 - hidden, atol=1e-12)
    assert inconsistent == 0
    assert np.bincount(couple, minlength=n).tolist() == [4] * n  # the rim's four arcs, whole, no slivers


@pytest.mark.parametrize("flip", [False, True])
def test_normal_cones_drop_only_edges_the_exact_test_drops(flip, monkeypatch):
    """Detection skips a node whose faces all face a receiver group, or one receiver, one way
    (``_normal_cones``): on a dense sphere over a floor, seen on the floor and on the sphere itself (and
    with every other face's winding flipped, where the cones widen and give up), the render with the
    cones finds exactly the arcs of the render without them, pixel for pixel. On the consistently wound
    sphere the cones are tight enough to spare visits to the tree's nodes, and do."""
    sphere = uv_sphere((0.0, 0.0, 0.5), 0.3, rings=24, segments=32)
    if flip:
        sphere[::2] = sphere[::2, ::-1]
    scene = plane_under_light(resolution=24, blocker=sphere)
    with_cones = render(scene, CENTRES)
    edges = MeshEdges.from_triangles(scene.triangles, light_frames(scene.validated().lights))
    leaves = edges.node_spread[edges.n_leaves - 1:]
    cones = edge_tree._normal_cones
    monkeypatch.setattr(edge_tree, "_normal_cones",
                        lambda *args: (cones(*args)[0], np.full(len(cones(*args)[1]), np.inf)))
    without = render(scene, CENTRES)
    assert with_cones.stats["arcs"] == without.stats["arcs"] > 0
    np.testing.assert_array_equal(with_cones.combined, without.combined)
    np.testing.assert_array_equal(with_cones.blocker_count, without.blocker_count)
    if not flip:
        assert with_cones.stats["nodes_visited"] < without.stats["nodes_visited"]
    else:  # mixed windings: a sphere leaf's normals point both ways, so its cone covers every direction
        assert (leaves[np.isfinite(leaves)] > 1.0).mean() > 0.5


def test_every_normal_under_a_node_lies_within_its_cone():
    """The cones ``detection`` culls by are bounds: each record's two oriented face normals lie within
    its leaf's spread of the leaf's axis, and each node's cone holds its children's (axis distance plus the
    child's spread), on a consistently wound sphere and on one with every other face flipped; a leaf with
    a rim or a cut segment can never be culled (infinite spread)."""
    for flip in (False, True):
        sphere = uv_sphere((0.0, 0.0, 0.5), 0.3, rings=24, segments=32)
        if flip:
            sphere[::2] = sphere[::2, ::-1]
        floor = quad_triangles([(-1.0, -1.0, 0.0), (1.0, -1.0, 0.0), (1.0, 1.0, 0.0), (-1.0, 1.0, 0.0)])  # rims
        triangles = np.concatenate([sphere, floor])
        edges = MeshEdges.from_triangles(triangles)
        winding = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
        leaves, n_records = edges.n_leaves, len(edges)
        two = (edges.triangle[:, 0] >= 0) & (edges.triangle[:, 1] >= 0) & (edges.light < 0)
        if edges.triangle.shape[1] > 2:
            two &= (edges.triangle[:, 2:] < 0).all(axis=1)
        along = np.einsum("ek,ek->e", edges.face_normal[:, 0], winding[np.maximum(edges.triangle[:, 0], 0)])
        flip_sign = np.where(along < 0, -1.0, 1.0)[:, None]
        oriented = np.stack([flip_sign * edges.face_normal[:, 0] / edges.face_size[:, 0, None],
                             -flip_sign * edges.face_normal[:, 1] / np.maximum(edges.face_size[:, 1, None], 1e-300)],
                            axis=1)
        record_leaf = np.arange(n_records) // edge_tree.LEAF_EDGES + leaves - 1
        spread, axis = edges.node_spread, edges.node_axis
        finite = np.isfinite(spread[record_leaf])
        assert finite.any() and (~finite).any()
        assert not np.isfinite(spread[record_leaf[~two]]).any()  # rims and the floor's edges
        distance = np.linalg.norm(oriented[finite] - axis[record_leaf[finite], None], axis=2)
        assert (distance <= spread[record_leaf[finite], None] * (1 + 1e-12) + 1e-12).all()
        inner = np.arange(leaves - 1)
        for child in (2 * inner + 1, 2 * inner + 2):
            has_normals = np.abs(axis[child]).sum(axis=1) > 0
            reach = np.where(has_normals, np.linalg.norm(axis[child] - axis[inner], axis=1), 0.0) + spread[child]
            assert (reach <= spread[inner] * (1 + 1e-12) + 1e-12).all()
        # A consistently wound sphere's leaves are cones narrower than 60 degrees (chord 1), cullable; with
        # mixed windings most cover more than a half space.
        median = np.median(spread[record_leaf[finite]])
        assert median > 1.0 if flip else median < 1.0


def test_welding_numbers_equal_points_in_lexicographic_order():
    """``edge_tree.weld`` gives equal rows one id, different rows different ids, numbered as a sort of the
    distinct rows would (the edge records' order depends on it), on rows with many repeats, negative and
    large coordinates."""
    rng = np.random.default_rng(7)
    distinct = rng.integers(-(1 << 40), 1 << 40, size=(500, 3))
    distinct[::7, 0] = distinct[1::7, 0][: len(distinct[::7])]        # rows sharing a first coordinate
    rows = distinct[rng.integers(0, len(distinct), size=5000)]
    ids = edge_tree.weld(rows)
    _, expected = np.unique(rows, axis=0, return_inverse=True)
    np.testing.assert_array_equal(ids, expected.ravel())
    assert len(edge_tree.weld(np.zeros((0, 3), np.int64))) == 0


def test_batches_and_chunks_follow_the_budget_and_change_nothing(monkeypatch):
    """Pass 2's pixel batches shrink with the memory budget (``pixel_batch_for``: per light and vertex),
    regions are worked out per chunk of couples and the signed terms integrated per chunk of terms: a
    small budget and tiny chunks give the default's image to rounding."""
    from lazyvis_addon.core import illumination
    frames = light_frames(plane_under_light().lights)
    assert silhouettes.pixel_batch_for(64.0, 2, frames) < silhouettes.pixel_batch_for(2048.0, 2, frames)
    with pytest.raises(MemoryError, match="memory budget of 1 MB is too small"):
        silhouettes.pixel_batch_for(1.0, 8, frames)
    scene = plane_under_light(resolution=24, blocker=leaves(60, seed=5))
    default = render(scene, CENTRES)
    monkeypatch.setattr(silhouettes, "ARC_CHUNK", 16)
    monkeypatch.setattr(illumination, "TERM_CHUNK", 7)
    monkeypatch.setattr(silhouettes, "COUPLE_VERTEX_BYTES", 1 << 12)  # batches of a few hundred pixels
    assert silhouettes.pixel_batch_for(64.0, 2, frames) < 24 * 24
    small = render(scene, CENTRES.replace(memory_budget_mb=64.0, threads=2))
    np.testing.assert_allclose(small.combined, default.combined, rtol=1e-9, atol=1e-12)
    assert small.stats["arcs"] == default.stats["arcs"]


def test_a_repeated_vertex_of_a_clipped_polygon_adds_no_plane_to_its_cone():
    """Clipping a light into cells can leave a vertex twice, a rounding apart: the plane through such an
    edge is noise of any orientation and clipped arcs at random (cells of suzanne_dense3 at 128 px were
    up to 6e-4 off the reference integrator). It is dropped: the cone, and the range of an arc inside it,
    are those of the polygon without the repeat."""
    from lazyvis_addon.core.arcs import _cone_range, cone_of_light
    square = np.array([(-0.5, -0.5, 1.0), (0.5, -0.5, 1.0), (0.5, 0.5, 1.0), (-0.5, 0.5, 1.0)])
    repeated = np.insert(square, 2, square[1] + 3e-16, axis=0)                  # vertex 1 twice, a rounding apart
    clean_planes, clean_valid = cone_of_light(square[None], np.array([4]))
    planes, valid = cone_of_light(repeated[None], np.array([5]))
    assert valid.sum() == 4 and not valid[0, 1]
    np.testing.assert_allclose(planes[0][valid[0]], clean_planes[0][clean_valid[0]], atol=1e-12)
    start, end = np.array([-1.0, 0.1, 1.0]), np.array([1.0, 0.2, 1.0])
    cross = np.cross(start, end)
    expected = _cone_range(*start, *end, *cross, clean_planes, clean_valid, 0, 0.0, 0.0, 1.0)
    got = _cone_range(*start, *end, *cross, planes, valid, 0, 0.0, 0.0, 1.0)
    assert got[2] and expected[2]
    np.testing.assert_allclose(got[:2], expected[:2], atol=1e-12)


def test_a_blocker_piercing_a_light_matches_the_reference_integrator():
    """Found by issue 14's convex emitters (geometry between an emitter and its tangent plane): a slab through
    a tilted square light, both over a floor. The reference integrator clips the slab at the light's plane;
    the silhouettes close the slab's front part by its cut segment, which lies in the light's plane (it was
    dropped as 'not in front', 414 of 576 pixels off), and the cut runs along the light's midline, where
    the old reference weights put R (then the two halves of the cut took opposite jumps)."""
    floor = quad_triangles([(-3, -3, 0), (3, -3, 0), (3, 3, 0), (-3, 3, 0)])
    light = [(-0.5, 0.5, 1.2), (0.5, 0.5, 0.8), (0.5, -0.5, 0.8), (-0.5, -0.5, 1.2)]  # tilted, facing down
    slab = quad_triangles([(-0.8, -0.1, 1.0), (0.8, -0.1, 1.0), (0.8, 0.1, 1.0), (-0.8, 0.1, 1.0)])
    triangles = np.concatenate([floor, slab])
    camera = Camera.perspective(look_at((0.0, -3.0, 3.0), (0.0, 0.0, 0.3)), 24, 24, np.radians(55))
    scene = Scene(triangles, np.zeros(len(triangles), np.int64), Materials.diffuse([(0.8,) * 3]),
                  Lights.from_polygons([light], [[4.0] * 3]), camera)
    ours = render(scene, Settings(aa_samples=1)).combined[..., 0]
    reference = render(scene, Settings(aa_samples=1, integrator="reference")).combined[..., 0]
    np.testing.assert_allclose(ours, reference, rtol=1e-4, atol=1e-7)


def test_the_reference_point_lies_on_no_midline_of_a_parallelogram():
    """R must lie on no arc's plane in a regular arrangement. A blocker edge centred under a square light
    projects onto the light's midlines; R keeps more than 0.5 % of the light's size off them, for squares,
    rectangles and parallelograms (weights with w1 + w4 = w2 + w3 put R on a midline of every one)."""
    from lazyvis_addon.core.geometry import reference_points
    shapes = np.array([[(-1, -1), (1, -1), (1, 1), (-1, 1)], [(0, 0), (3, 0), (3, 1), (0, 1)],
                       [(0, 0), (2, 0), (2.5, 1), (0.5, 1)]], np.float64)
    for shape in shapes:
        for shift in range(4):  # any vertex first
            uv = np.roll(shape, shift, axis=0)
            r = reference_points(uv[None], np.array([4]))[0]
            for a, b in ((0, 1), (1, 2)):  # the midline joining the midpoints of edges (a, b) and (a+2, b+2)
                p, q = (uv[a] + uv[b]) / 2, (uv[(a + 2) % 4] + uv[(b + 2) % 4]) / 2
                line = q - p
                off = abs(line[0] * (r - p)[1] - line[1] * (r - p)[0]) / np.linalg.norm(line)
                size = np.linalg.norm(uv[b] - uv[a])
                assert off > 0.005 * size, (shape, shift, off)


def test_arcs_sorted_by_couple_keep_their_order_within_a_couple():
    """``Arcs.by_couple`` (the compiled counting sort) is the stable sort by couple: every arc's row moves
    with it, arcs of one couple keep their order, couples without arcs are skipped."""
    from lazyvis_addon.core.arcs import Arcs
    rng = np.random.default_rng(5)
    n = 5000
    couple = rng.integers(0, 300, n) * 2  # odd couples have no arcs
    arcs = Arcs(couple, rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), rng.normal(size=(n, 3)),
                rng.uniform(size=n), rng.uniform(size=n), rng.integers(-2, 3, n))
    expected = arcs.take(np.argsort(couple, kind="stable"))
    got = arcs.by_couple(600)
    for name in ("couple", "start", "end", "normal", "enter", "leave", "jump"):
        np.testing.assert_array_equal(getattr(got, name), getattr(expected, name))
    assert len(Arcs.empty().by_couple(3).couple) == 0
