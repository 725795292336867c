"""Mesh emitters as few lights (``emitters``): grouping, exact silhouettes, renders equal to one light per
triangle, limits and bad input."""

import dataclasses
import importlib

import numpy as np
import pytest

from lazyvis_addon.core import Camera, Lights, Materials, Scene, Settings, render
from lazyvis_addon.core.demo_scenes import box_triangles, icosphere_triangles, look_at, quad_triangles
from lazyvis_addon.core.emitters import (HULL_INNER, HULL_NEAR, HULL_TAKEN, closed_convex_faces, crowded_hulls,
                                         group_mesh_emitters,
                                         hull_faces_in_scene, hull_tables,
                                         hull_polygons, near_receivers, planar_convex_union)
from lazyvis_addon.core.geometry import light_frames
from lazyvis_addon.core.scene import EmitterHulls

CENTRES = Settings(aa_samples=1)
RADIANCE = 4.0


def triangle_solid_angle(apex, triangles):
    """Signed solid angles (K,) of triangles (K, 3, 3) seen from ``apex`` (3,) (Van Oosterom and Strackee)."""
    a, b, c = (triangles[:, i] - apex for i in range(3))
    la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
    numerator = np.einsum("ij,ij->i", a, np.cross(b, c))
    denominator = la * lb * lc + np.einsum("ij,ij->i", a, b) * lc + np.einsum("ij,ij->i", a, c) * lb \
        + np.einsum("ij,ij->i", b, c) * la
    return 2.0 * np.arctan2(numerator, denominator)


def grid_triangles(corner, u, v, n):
    """An n x n grid of quads (2 n^2 triangles) spanning corner + [0, 1] u + [0, 1] v."""
    corner, u, v = (np.asarray(x, np.float64) for x in (corner, u, v))
    out = []
    for i in range(n):  # a test mesh's rows
        for j in range(n):
            p = corner + (i / n) * u + (j / n) * v
            out.append(quad_triangles([p, p + u / n, p + u / n + v / n, p + v / n]))
    return np.concatenate(out)


def emitter_lights(triangles, radiance=RADIANCE):
    return Lights(triangles, np.full(len(triangles), 3), np.full((len(triangles), 3), radiance),
                  np.ones(len(triangles), bool))


# -- grouping ------------------------------------------------------------------------------------------

def test_closed_convex_meshes_are_found_and_wound_outward():
    sphere = icosphere_triangles((0.2, -0.1, 1.0), 0.4, 2)
    assert closed_convex_faces(sphere) is sphere
    inward = sphere[:, ::-1]
    np.testing.assert_array_equal(closed_convex_faces(inward), sphere)
    assert closed_convex_faces(box_triangles((0, 0, 0), 1.0, 0.3)) is not None
    assert closed_convex_faces(sphere[1:]) is None  # open: a face missing
    dented = sphere.copy()
    top = np.argmax(dented.reshape(-1, 3)[:, 2])
    apex = dented.reshape(-1, 3)[top].copy()
    dented[(dented == apex).all(axis=2)] = apex - np.array([0.0, 0.0, 0.2])  # a vertex pushed in: concave
    assert closed_convex_faces(dented) is None


def test_planar_convex_emitters_become_one_polygon_of_the_same_area():
    panel = grid_triangles((0, 0, 2), (1.0, 0.2, 0), (0, 0.5, 0.1), 4)
    polygon = planar_convex_union(panel)
    assert polygon is not None and len(polygon) == 4
    doubled = np.linalg.norm(np.cross(panel[:, 1] - panel[:, 0], panel[:, 2] - panel[:, 0]), axis=1).sum()
    area = 0.5 * np.linalg.norm(sum(np.cross(polygon[k], polygon[(k + 1) % 4]) for k in range(4)))
    assert area == pytest.approx(0.5 * doubled, rel=1e-12)
    # Its winding is the triangles': the same emitting normal.
    normal = np.cross(polygon[1] - polygon[0], polygon[2] - polygon[0])
    assert normal @ np.cross(panel[0, 1] - panel[0, 0], panel[0, 2] - panel[0, 0]) > 0
    l_shape = np.concatenate([grid_triangles((0, 0, 0), (1, 0, 0), (0, 1, 0), 1),
                              grid_triangles((1, 0, 0), (1, 0, 0), (0, 1, 0), 1),
                              grid_triangles((0, 1, 0), (1, 0, 0), (0, 1, 0), 1)])
    assert planar_convex_union(l_shape) is None
    bent = panel.copy()
    bent[0, 0, 2] += 0.1
    assert planar_convex_union(bent) is None


def test_grouping_keeps_what_it_cannot_merge_and_names_its_sources():
    sphere = icosphere_triangles((0, 0, 1), 0.3, 1)
    panel = grid_triangles((2, 0, 1), (0.5, 0, 0), (0, 0.5, 0), 3)
    l_shape = np.concatenate([grid_triangles((0, 3, 1), (1, 0, 0), (0, 1, 0), 1),
                              grid_triangles((1, 3, 1), (1, 0, 0), (0, 1, 0), 1),
                              grid_triangles((0, 4, 1), (1, 0, 0), (0, 1, 0), 1)])
    area_light = quad_triangles([(0, 0, 3), (1, 0, 3), (1, 1, 3), (0, 1, 3)])[:1]
    lights = emitter_lights(np.concatenate([area_light, sphere, panel, l_shape]))
    part = np.concatenate([[-1], np.zeros(len(sphere)), np.ones(len(panel)), np.full(len(l_shape), 2)]).astype(int)
    grouped, hulls, light_source, hull_source = group_mesh_emitters(lights, part)
    assert len(hulls) == 1 and len(hulls.triangles) == len(sphere)
    assert len(grouped) == 1 + len(l_shape) + 1  # the ungrouped light, the L's triangles, the panel
    assert list(grouped.vertex_count[-1:]) == [4]
    np.testing.assert_array_equal(hull_source, [1])
    assert light_source[0] == 0 and light_source[-1] == 1 + len(sphere)


# -- each receiver's polygon -----------------------------------------------------------------------------

def hull_scene_frames(triangles):
    hulls = EmitterHulls(triangles, np.zeros(len(triangles), np.int64), [[RADIANCE] * 3])
    return light_frames(Lights.empty(), hulls=hulls)


def test_each_receiver_takes_one_plane_whose_polygon_subtends_the_emitter_exactly():
    sphere = icosphere_triangles((0.1, 0.2, 0.3), 0.5, 3)
    frames = hull_scene_frames(sphere)
    rng = np.random.default_rng(3)
    direction = rng.normal(size=(400, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    receivers = np.array([0.1, 0.2, 0.3]) + direction * rng.uniform(0.9, 5.0, size=(400, 1))  # 1.8 to 10 radii
    counts, statuses = [], []
    for light in range(len(frames)):  # the hull's six planes
        uv, count, status, _ = hull_polygons(frames, np.full(len(receivers), light), receivers)
        counts.append(count)
        statuses.append(status)
        for n in np.flatnonzero(count > 0)[:40]:
            polygon = frames.origin[light] + uv[n, :count[n], :1] * frames.tangent[light] \
                + uv[n, :count[n], 1:] * frames.bitangent[light]
            fan = np.stack([np.repeat(polygon[:1], count[n] - 2, 0), polygon[1:-1], polygon[2:]], axis=1)
            facing = np.einsum("kj,kj->k", np.cross(sphere[:, 1] - sphere[:, 0], sphere[:, 2] - sphere[:, 0]),
                               receivers[n] - sphere[:, 0]) > 0
            expected = abs(triangle_solid_angle(receivers[n], sphere[facing]).sum())
            assert abs(triangle_solid_angle(receivers[n], fan).sum()) == pytest.approx(expected, rel=1e-12)
    taken = (np.array(counts) > 0).sum(axis=0)
    assert (taken == 1).all()
    assert (np.array(statuses) == HULL_TAKEN).all()


def test_receivers_inside_or_against_the_emitter_take_no_plane():
    sphere = icosphere_triangles((0, 0, 0), 1.0, 2)
    frames = hull_scene_frames(sphere)
    inside = np.array([[0.0, 0.0, 0.0], [0.2, -0.3, 0.1]])
    _, count, status, _ = hull_polygons(frames, np.zeros(2, np.int64), inside)
    assert (count == 0).all() and (status == HULL_NEAR).all()


# -- renders -----------------------------------------------------------------------------------------------

def sphere_over_floor(sphere, hulls: bool, resolution=24, blocker=True):
    floor = quad_triangles([(-3, -3, 0), (3, -3, 0), (3, 3, 0), (-3, 3, 0)])
    slab = quad_triangles([(-0.4, -0.1, 0.15), (0.4, -0.1, 0.15), (0.4, 0.1, 0.15), (-0.4, 0.1, 0.15)])
    geometry = [floor, slab] if blocker else [floor]
    triangles = np.concatenate(geometry + [sphere])
    material = np.concatenate([np.zeros(sum(len(g) for g in geometry), np.int64), np.ones(len(sphere), np.int64)])
    materials = Materials(np.array([[0.8, 0.8, 0.8], [0.0, 0.0, 0.0]]), np.array([[0.0] * 3, [RADIANCE] * 3]))
    lights = emitter_lights(sphere)
    hull_rows = EmitterHulls.empty()
    if hulls:
        lights, hull_rows, _, _ = group_mesh_emitters(lights, np.zeros(len(sphere), np.int64))
    camera = Camera.perspective(look_at((0.0, -3.0, 3.0), (0.0, 0.0, 0.3)), resolution, resolution, np.radians(55))
    return Scene(triangles, material, materials, lights, camera, hulls=hull_rows)


def test_a_sphere_emitter_renders_as_its_triangles_do_but_as_one_light():
    sphere = icosphere_triangles((0.0, 0.0, 1.0), 0.3, 2)  # 320 faces
    grouped = sphere_over_floor(sphere, hulls=True)
    assert len(grouped.lights) == 0 and len(grouped.hulls) == 1 and grouped.light_count == 1
    one_light = render(grouped, CENTRES)
    # One light per triangle: 320 lights take about 1.1 MB per pixel of pass 2's temporaries, so a 1 GB budget
    # on two threads holds batches of about a hundred pixels (it stopped with a MemoryError below 256).
    per_triangle = render(sphere_over_floor(sphere, hulls=False),
                          dataclasses.replace(CENTRES, memory_budget_mb=1024, threads=2))
    lit = per_triangle.combined[..., :3] > 0
    assert lit.mean() > 0.5
    ratio = one_light.combined[..., :3][lit] / per_triangle.combined[..., :3][lit]
    assert np.abs(ratio - 1).max() < 1e-5
    # The slab's shadow is on the floor: the same light, blocked.
    assert per_triangle.combined[..., 0].min() < 0.5 * np.median(per_triangle.combined[..., 0])


def test_npz_round_trip_keeps_the_hulls(tmp_path):
    scene = sphere_over_floor(icosphere_triangles((0.0, 0.0, 1.0), 0.3, 1), hulls=True)
    scene.save_npz(tmp_path / "scene.npz")
    loaded = Scene.load_npz(tmp_path / "scene.npz")
    np.testing.assert_array_equal(loaded.hulls.triangles, scene.hulls.triangles)
    np.testing.assert_array_equal(loaded.hulls.radiance, scene.hulls.radiance)
    np.testing.assert_array_equal(render(loaded, CENTRES).combined, render(scene, CENTRES).combined)


def emitter_resting_on_floor(emitter, grouped: bool, resolution=24):
    """A floor, a box beside and the emitter (black, emitting RADIANCE) resting on the floor, seen close."""
    return emitter_scene(emitter, grouped, [box_triangles((1.1, 0.4, 0.1), 0.2, 0.3)],
                         look_at((0.4, -2.0, 1.6), (0.0, 0.0, 0.1)), resolution)


def emitter_scene(emitter, grouped: bool, geometry: list, camera_matrix, resolution: int) -> Scene:
    """A floor, other ``geometry`` and the emitter (black, emitting RADIANCE; one light per triangle, or
    grouped as ``group_mesh_emitters`` does when ``grouped``) through a 50-degree camera."""
    geometry = [quad_triangles([(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)])] + geometry
    triangles = np.concatenate(geometry + [emitter])
    material = np.concatenate([np.zeros(sum(len(g) for g in geometry), np.int64), np.ones(len(emitter), np.int64)])
    materials = Materials(np.array([[0.8, 0.8, 0.8], [0.0, 0.0, 0.0]]), np.array([[0.0] * 3, [RADIANCE] * 3]))
    lights, hulls = emitter_lights(emitter), EmitterHulls.empty()
    if grouped:
        lights, hulls, _, _ = group_mesh_emitters(lights, np.zeros(len(emitter), np.int64))
    camera = Camera.perspective(camera_matrix, resolution, resolution, np.radians(50))
    return Scene(triangles, material, materials, lights, camera, hulls=hulls)


@pytest.mark.parametrize("shape", ["sphere", "torus", "tilted torus"])
def test_an_emitter_resting_on_the_floor_lights_it_right_up_to_the_contact(shape):
    """Floor points inside the box of the emitter's supporting planes take no plane; they take its six inner
    lights instead (the box's faces, the emitter's own faces blocking nothing; for a non-convex one, six
    more of radiance -L), each cut to the cone through the emitter (the whole face where the receiver lies
    inside a non-convex emitter's hull: the floor in a torus' hole). The floor then equals one light per
    triangle everywhere, the brightest pixels at the contact included (before: dark there, warned)."""
    emitter = {"sphere": lambda: icosphere_triangles((0.0, 0.0, 0.3), 0.3, 2),
               "torus": lambda: torus_triangles(centre=(0.1, 0.0, 0.15), tilt=0.0),
               "tilted torus": lambda: torus_triangles(centre=(0.1, 0.0, 0.35), tilt=0.3)}[shape]()
    scene = emitter_resting_on_floor(emitter, grouped=True)
    frames = light_frames(scene.lights, hulls=scene.hulls)
    near = np.array([[0.0, -0.05, 0.0]])  # under the emitter: inside the box, outside the emitter
    statuses = hull_polygons(frames, np.full(1, np.flatnonzero(frames.slot == 6)[0]), near)[2]
    assert (statuses == HULL_INNER).all() and near_receivers(frames, near) == {}
    out = render(scene, CENTRES)
    assert not any("none of its light" in w for w in out.warnings)
    exact = render(emitter_resting_on_floor(emitter, grouped=False), PER_TRIANGLE)
    lit = exact.combined[..., :3] > 1e-6
    assert lit.mean() > 0.5
    assert np.abs(out.combined[..., :3][lit] / exact.combined[..., :3][lit] - 1).max() < 1e-5


def test_bad_hulls_are_refused_with_a_clear_message():
    sphere = icosphere_triangles((0.0, 0.0, 1.0), 0.3, 1)
    scene = sphere_over_floor(sphere, hulls=True)
    open_mesh = dataclasses.replace(scene, hulls=EmitterHulls(sphere[1:], np.zeros(len(sphere) - 1, np.int64),
                                                               [[RADIANCE] * 3]))
    with pytest.raises(ValueError, match="not a closed convex mesh"):
        render(open_mesh, CENTRES)
    with pytest.raises(ValueError, match="at least 4 faces"):
        render(dataclasses.replace(scene, hulls=EmitterHulls(sphere[:3], np.zeros(3, np.int64), [[1.0] * 3])))
    nan = sphere.copy()
    nan[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="finite"):
        render(dataclasses.replace(scene, hulls=EmitterHulls(nan, np.zeros(len(sphere), np.int64), [[1.0] * 3])))
    with pytest.raises(ValueError, match="must not be negative"):
        render(dataclasses.replace(scene, hulls=EmitterHulls(sphere, np.zeros(len(sphere), np.int64), [[-1.0] * 3])))
    dark = render(dataclasses.replace(scene, hulls=EmitterHulls(sphere, np.zeros(len(sphere), np.int64),
                                                                 [[0.0] * 3])), CENTRES)
    assert any("zero radiance" in w for w in dark.warnings)


# -- non-convex emitters ---------------------------------------------------------------------------------

def torus_triangles(centre=(0.1, 0.0, 1.6), major=0.5, minor=0.15, around=24, across=12, tilt=0.4):
    """A torus (2 * around * across triangles) about the tilted z axis through ``centre``."""
    c, s = np.cos(tilt), np.sin(tilt)
    a, b = np.meshgrid(2 * np.pi * np.arange(around + 1) / around, 2 * np.pi * np.arange(across + 1) / across,
                       indexing="ij")
    x, y, w = (major + minor * np.cos(b)) * np.cos(a), (major + minor * np.cos(b)) * np.sin(a), minor * np.sin(b)
    grid = np.stack([x, c * y - s * w, s * y + c * w], axis=-1) + np.asarray(centre)
    return _quads(grid)


def shade_triangles(centre=(-0.2, 0.1, 1.5), radius=0.35, height=0.4, around=20):
    """A lamp shade: a truncated cone open at both ends (2 * around triangles), wider at the bottom."""
    a = 2 * np.pi * np.arange(around + 1) / around
    ring = lambda r, z: np.stack([r * np.cos(a), r * np.sin(a), np.full_like(a, z)], axis=-1)  # noqa: E731
    grid = np.stack([ring(radius, -height / 2), ring(0.6 * radius, height / 2)], axis=1) + np.asarray(centre)
    return _quads(grid)


def _quads(grid):
    """Two triangles per cell of a (m + 1, n + 1, 3) grid of points."""
    p00, p10, p11, p01 = grid[:-1, :-1], grid[1:, :-1], grid[1:, 1:], grid[:-1, 1:]
    first = np.stack([p00, p10, p11], axis=2).reshape(-1, 3, 3)
    second = np.stack([p00, p11, p01], axis=2).reshape(-1, 3, 3)
    return np.concatenate([first, second])


def emitter_over_floor(emitter, grouped: bool, resolution=28, extra=None):
    """A floor, a slab under the emitter and the emitter (black, emitting RADIANCE) seen from above and aside."""
    slab = quad_triangles([(-0.5, -0.15, 0.3), (0.5, -0.15, 0.3), (0.5, 0.15, 0.3), (-0.5, 0.15, 0.3)])
    return emitter_scene(emitter, grouped, [slab] + ([extra] if extra is not None else []),
                         look_at((0.4, -4.0, 3.2), (0.0, 0.0, 0.6)), resolution)


PER_TRIANGLE = dataclasses.replace(CENTRES, memory_budget_mb=4096)


@pytest.mark.parametrize("shape", ["torus", "shade"])
def test_a_non_convex_emitter_is_two_lights_and_renders_as_its_triangles_do(shape, monkeypatch):
    """A torus (closed, a hole) and a lamp shade (open at both ends) become one hull each: a near light of
    radiance L and a far one of -L, the directions through the emitter's hull less those that meet nothing
    (through the hole, the shade's openings). The image equals one light per triangle, the exact path, to
    rounding; without the far light it would not (the floor under the hole would be too bright)."""
    emitter = torus_triangles() if shape == "torus" else shade_triangles()
    scene = emitter_over_floor(emitter, grouped=True)
    assert len(scene.lights) == 0 and len(scene.hulls) == 1 and not scene.hulls.convex[0]
    frames = light_frames(scene.lights, hulls=scene.hulls)
    # Six outer, six far, six inner and six negative inner lights.
    assert len(frames) == 24 and frames.hull_far.sum() == 12 and (frames.radiance[frames.hull_far] < 0).all()
    two = render(scene, CENTRES)
    exact = render(emitter_over_floor(emitter, grouped=False), PER_TRIANGLE)
    assert not any("none of its light" in w or "one light per face" in w for w in two.warnings)
    lit = exact.combined[..., :3] > 1e-6
    assert lit.mean() > 0.5
    ratio = two.combined[..., :3][lit] / exact.combined[..., :3][lit]
    assert np.abs(ratio - 1).max() < 1e-5
    # The far light takes out what passes through: without it the floor is too bright somewhere.
    prepared_module = importlib.import_module("lazyvis_addon.core.prepared")
    original = prepared_module.light_frames

    def near_only(*args, **kwargs):
        frames = original(*args, **kwargs)
        frames.radiance[frames.hull_far] = 0.0
        return frames

    monkeypatch.setattr(prepared_module, "light_frames", near_only)
    brighter = render(scene, CENTRES).combined[..., :3][lit] / exact.combined[..., :3][lit]
    assert brighter.max() > 1.05


def test_other_geometry_inside_a_non_convex_emitter_keeps_it_one_light_per_face():
    """A box inside the torus' hole may stand behind the emitter along a ray, which the two lights cannot
    tell: the emitter stays one light per triangle, with one warning, and the image is the exact one: the
    reference integrator's, at any batch size (a pixel on the box's top once came out 9.42 instead of 0.072
    with detection's sub-groups of 4 receivers, ``silhouettes.SUB_POINTS``: torus faces clipped to a point or a
    segment by the box top's horizon kept every edge as an arc, ``geometry.negligible_lights``)."""
    emitter = torus_triangles(tilt=0.0)
    plug = box_triangles((0.1, 0.0, 1.6), 0.15, 0.1)
    scene = emitter_over_floor(emitter, grouped=True, extra=plug)
    exact = render(scene, CENTRES.replace(integrator="reference")).combined
    for batch in (16384, 64):
        out = render(scene, CENTRES.replace(pixel_batch=batch))
        assert sum("one light per face" in w for w in out.warnings) == 1
        np.testing.assert_allclose(out.combined, exact, rtol=1e-6, atol=1e-6 * exact.max(), err_msg=str(batch))
    per_triangle = render(emitter_over_floor(emitter, grouped=False, extra=plug), PER_TRIANGLE).combined
    np.testing.assert_allclose(per_triangle, exact, rtol=1e-6, atol=1e-6 * exact.max())
    # A floor the emitter rests on touches it without crowding it.
    resting = torus_triangles(centre=(0.1, 0.0, 0.15), tilt=0.0)
    tables = hull_tables(EmitterHulls(resting, np.zeros(len(resting), np.int64), [[1.0] * 3], convex=[False]))
    floor = quad_triangles([(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)])
    triangles = np.concatenate([floor, resting])
    part_of = hull_faces_in_scene(tables, triangles)
    np.testing.assert_array_equal(part_of, [-1, -1] + [0] * len(resting))
    assert not crowded_hulls(tables, triangles, part_of)[0]
    inner = box_triangles((0.1, 0.0, 0.15), 0.15)  # in its hole
    assert crowded_hulls(tables, np.concatenate([triangles, inner]), np.concatenate([part_of, [-1] * len(inner)]))[0]


def test_the_other_integrators_take_a_non_convex_emitter_face_by_face():
    from lazyvis_addon.core.prepared import _emitters_as_triangles_where_needed
    from lazyvis_addon.core.progress import Progress
    scene = emitter_over_floor(torus_triangles(), grouped=True).validated()
    kept = _emitters_as_triangles_where_needed(scene, CENTRES, Progress())
    assert len(kept.hulls) == 1 and len(kept.lights) == 0
    other = _emitters_as_triangles_where_needed(scene, Settings(integrator="reference"), Progress())
    assert len(other.hulls) == 0 and len(other.lights) == len(scene.hulls.triangles)
    assert other.lights.two_sided.all()
