"""Closed forms for the geometry kernel: clipping, cone overlap, Lambert's polygon formula."""

import numpy as np
import pytest

from lazyvis_addon.core.geometry import (NEGLIGIBLE_SOLID_ANGLE, blocker_in_front_of_light, clip_convex, cones_overlap,
                                         negligible_lights, polygon_area_2d, projected_solid_angle, split_convex)

SQUARE = np.array([[0.5, -0.5, 1.0], [0.5, 0.5, 1.0], [-0.5, 0.5, 1.0], [-0.5, -0.5, 1.0]])


def quadrature_projected_solid_angle(corners, receiver, normal, n=600):
    """Integral over a planar quad's area of cos_r cos_l / r^2 by the midpoint rule (independent of Eq. 3)."""
    o, e1, e2 = corners[0], corners[1] - corners[0], corners[3] - corners[0]
    s = (np.arange(n) + 0.5) / n
    uu, vv = np.meshgrid(s, s)
    points = o + uu[..., None] * e1 + vv[..., None] * e2
    light_normal = np.cross(e1, e2)
    area = np.linalg.norm(light_normal)
    light_normal /= area
    d = points - receiver
    r2 = np.einsum("...k,...k", d, d)
    cos_r = np.maximum(np.einsum("...k,k", d, normal), 0) / np.sqrt(r2)
    cos_l = np.abs(np.einsum("...k,k", d, light_normal)) / np.sqrt(r2)
    return float(np.sum(cos_r * cos_l / r2) * area / n ** 2)


@pytest.mark.parametrize("receiver,normal", [
    ((0, 0, 0), (0, 0, 1)),
    ((0.7, -0.3, 0.2), (0, 0, 1)),
    ((0.2, 0.1, 0), (0.6, 0.0, 0.8)),
    ((-1.5, 0.4, 0.5), (1.0, 0.0, 0.2)),
])
def test_lambert_matches_quadrature(receiver, normal):
    receiver = np.asarray(receiver, float)
    normal = np.asarray(normal, float) / np.linalg.norm(normal)
    expected = quadrature_projected_solid_angle(SQUARE, receiver, normal)
    got = projected_solid_angle((SQUARE - receiver)[None], normal[None])[0]
    assert got == pytest.approx(expected, rel=2e-4)


def test_lambert_full_hemisphere_is_pi():
    # A huge square far above covers (nearly) the whole hemisphere: integral of cos = pi.
    big = SQUARE * np.array([1e6, 1e6, 1.0])
    assert projected_solid_angle(big[None], np.array([[0, 0, 1.0]]))[0] == pytest.approx(np.pi, rel=1e-5)


def test_lambert_ignores_winding_and_padding():
    padded = np.concatenate([SQUARE, SQUARE[-1:], SQUARE[-1:]])
    normal = np.array([[0, 0, 1.0]])
    a = projected_solid_angle(SQUARE[None], normal)[0]
    assert projected_solid_angle(SQUARE[::-1][None].copy(), normal)[0] == pytest.approx(a, rel=1e-12)
    assert projected_solid_angle(padded[None], normal)[0] == pytest.approx(a, rel=1e-12)


def test_clip_keeps_the_right_half_and_area():
    square = SQUARE[None, :, :2].copy()
    for offset in (-0.4, 0.0, 0.3):
        clipped, count = clip_convex(square, np.array([4]), square[..., 0] - offset)
        assert count[0] == 4
        assert polygon_area_2d(clipped)[0] == pytest.approx(0.5 - offset, rel=1e-12)
    # A diagonal cut of a corner gives a pentagon; clipping everything away gives nothing.
    clipped, count = clip_convex(square, np.array([4]), square[..., 0] + square[..., 1] - 0.5)
    assert count[0] == 3 and polygon_area_2d(clipped)[0] == pytest.approx(0.125, rel=1e-12)
    clipped, count = clip_convex(square, np.array([4]), 0.75 - square[..., 0] - square[..., 1])
    assert count[0] == 5 and polygon_area_2d(clipped)[0] == pytest.approx(1 - 0.25 ** 2 / 2, rel=1e-12)
    clipped, count = clip_convex(square, np.array([4]), square[..., 0] - 1.0)
    assert count[0] == 0


def test_cone_overlap_and_surround():
    light = np.repeat(SQUARE[None], 4, axis=0)
    tri = lambda pts: np.concatenate([np.asarray(pts, float), np.asarray(pts, float)[-1:]])[None]
    blockers = np.concatenate([
        tri([(-0.1, -0.1, 0.5), (0.1, -0.1, 0.5), (0.0, 0.1, 0.5)]),      # small, inside: overlaps
        tri([(2.0, 2.0, 0.5), (2.1, 2.0, 0.5), (2.0, 2.1, 0.5)]),         # aside: no overlap
        tri([(-5.0, -5.0, 0.5), (5.0, -5.0, 0.5), (0.0, 5.0, 0.5)]),      # huge: surrounds
        tri([(0.26, -5.0, 0.5), (5.0, -5.0, 0.5), (5.0, 5.0, 0.5)]),      # beyond the light's edge x=0.25 at z=.5
    ])
    overlap, surround = cones_overlap(blockers, np.full(4, 3), light, np.full(4, 4))
    assert overlap.tolist() == [True, False, True, False]
    assert surround.tolist() == [False, False, True, False]


def test_blocker_beyond_light_is_cut_away():
    receiver = np.zeros((2, 3))
    # Light plane z = 1, normal facing down (towards the receiver).
    origin = np.array([[0, 0, 1.0]] * 2)
    normal = np.array([[0, 0, -1.0]] * 2)
    above = np.array([[(0, 0, 2.0), (1, 0, 2.0), (0, 1, 2.0)]])
    straddling = np.array([[(0, 0, 0.5), (1, 0, 0.5), (0, 0, 1.5)]])
    polygon, count = blocker_in_front_of_light(receiver, np.concatenate([above, straddling]), np.array([3, 3]),
                                               origin, normal, np.ones(2))
    assert count[0] == 0
    assert count[1] == 4 and (polygon[1, :4, 2] <= 1.0 + 1e-12).all()


def test_split_survives_vertices_alternating_within_rounding_of_the_line():
    """A square whose bottom edge carries vertices 1e-17 above and below the cutting line y = 0: six
    crossings, which overflowed the output (an IndexError mid-render). It is kept whole, inside."""
    square = np.array([[[0.0, -1e-17], [0.25, 1e-17], [0.5, -1e-17], [0.75, 1e-17], [1.0, -1e-17],
                        [1.0, 1.0], [0.0, 1.0]]])
    count = np.array([7])
    inside, inside_count, outside, outside_count = split_convex(square, count, square[..., 1].copy())
    assert inside_count[0] == 7 and outside_count[0] == 0
    np.testing.assert_array_equal(inside[0, :7], square[0])
    # An ordinary cut still splits.
    inside, inside_count, outside, outside_count = split_convex(square, count, square[..., 1] - 0.5)
    assert inside_count[0] == 4 and outside_count[0] == 7


def test_lambert_from_light_coordinates_equals_the_direction_form():
    """``projected_solid_angle_uv`` (a polygon in its light's (u, v) plane seen from a receiver given in the
    light's frame) is ``projected_solid_angle`` of the same polygon's directions, padding included."""
    from lazyvis_addon.core.geometry import projected_solid_angle_uv
    rng = np.random.default_rng(7)
    uv = rng.uniform(-1.0, 1.0, (50, 6, 2))
    uv[:, 4:] = uv[:, 3:4]  # padded quads, any winding
    local = np.concatenate([rng.uniform(-1.0, 1.0, (50, 2)), rng.uniform(0.2, 2.0, (50, 1))], axis=1)
    normal = rng.normal(size=(50, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    directions = np.concatenate([uv - local[:, None, :2], np.broadcast_to(-local[:, None, 2:], (50, 6, 1))], axis=2)
    np.testing.assert_allclose(projected_solid_angle_uv(uv, np.full(50, 4), local, normal),
                               projected_solid_angle(directions, normal), rtol=1e-12, atol=1e-15)
    assert (projected_solid_angle_uv(uv, np.full(50, 2), local, normal) == 0).all()  # no polygon


def test_lambert_reads_a_table_in_place_by_rows_and_through_strided_views():
    """Polygons read in place from a table by ``rows`` (the silhouettes' whole lights, read from the couples'
    table) or through a trimmed, strided view of it give exactly what the same polygons gathered and
    contiguous give."""
    from lazyvis_addon.core.geometry import projected_solid_angle_uv
    rng = np.random.default_rng(11)
    count = rng.integers(3, 7, 30)
    angle = np.sort(rng.uniform(0.0, 2.0 * np.pi, (30, 8)), axis=1)
    table = np.stack([np.cos(angle), np.sin(angle)], axis=2) * rng.uniform(0.3, 1.0, (30, 1, 1))
    table[np.arange(8)[None, :] >= count[:, None]] = np.nan  # beyond a polygon's count: never read
    rows = rng.integers(0, 30, 50)  # with repeats, out of order
    local = np.concatenate([rng.uniform(-1.0, 1.0, (50, 2)), rng.uniform(0.2, 2.0, (50, 1))], axis=1)
    normal = rng.normal(size=(50, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    gathered = np.ascontiguousarray(table[rows][:, :6])
    expected = projected_solid_angle_uv(gathered, count[rows], local, normal)
    assert np.isfinite(expected).all() and (expected > 0).all()
    trimmed = table[:, :6]
    assert not trimmed.flags.c_contiguous
    for uv, by_rows in ((table, rows), (trimmed, rows), (table[rows][:, :6], None)):
        np.testing.assert_array_equal(projected_solid_angle_uv(uv, count[rows], local, normal, by_rows), expected)


def test_horizon_clipping_equals_clipping_by_each_line():
    """``receiver_light`` clips every couple's light to its geometric and shading horizons in one compiled
    pass: the same region (area, and every vertex on the lines or inside both) as ``clip_convex`` by one
    line, then the other; receivers behind the light get nothing; a polygon whose vertices straddle a
    line only within rounding (more than two crossings) is kept whole on the side it leans to."""
    from lazyvis_addon.core.geometry import light_frames, plane_lines, receiver_light
    from lazyvis_addon.core.scene import Lights
    hexagon = np.array([[np.cos(a), np.sin(a), 2.0] for a in np.linspace(0, 2 * np.pi, 7)[:-1]])
    facing_down = [SQUARE[::-1] + (0, 0, 1.0), hexagon[::-1]]
    frames = light_frames(Lights.from_polygons(facing_down, [(1.0, 1.0, 1.0)] * 2))
    rng = np.random.default_rng(3)
    n = 400
    position = np.concatenate([rng.uniform(-2, 2, (n, 2)), rng.uniform(-0.5, 1.8, (n, 1))], axis=1)
    geometric = rng.normal(size=(n, 3))
    geometric /= np.linalg.norm(geometric, axis=1, keepdims=True)
    shading = geometric + 0.4 * rng.normal(size=(n, 3))
    shading /= np.linalg.norm(shading, axis=1, keepdims=True)
    light = rng.integers(0, 2, n)
    setup = receiver_light(position, geometric, shading, light, frames)
    # One line, then the other, by the numpy clip.
    width = frames.uv.shape[1]
    uv, count = frames.uv[light].copy(), frames.vertex_count[light].copy()
    above = np.einsum("nk,nk->n", position - frames.origin[light], frames.normal[light]) > 1e-9
    count[~above] = 0
    rel = position - frames.origin[light]
    for normal in (geometric, shading):
        line = plane_lines(normal[:, None], rel, light, frames)[:, 0]
        value = line[:, :1] * uv[..., 0] + line[:, 1:2] * uv[..., 1] + line[:, 2:]
        uv, count = clip_convex(uv, count, value)
    expected = np.where(count >= 3, polygon_area_2d(uv), 0.0)
    got = np.where(setup.count >= 3, polygon_area_2d(setup.uv), 0.0)
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-12)
    assert (setup.count[~above] == 0).all() and (got > 0).sum() > n // 4 and (expected == 0).sum() > n // 10
    assert setup.uv.shape[1] <= width + 2
    # Vertices within rounding of the line, on alternating sides: kept whole on the side they lean to.
    from lazyvis_addon.core.geometry import clip_by_lines
    flat = np.array([[[0.0, 1e-17], [1.0, -1e-17], [2.0, 1e-17], [3.0, -1e-17], [1.5, 2e-17]]])
    for lean, kept in ((0.0, 5), (-10.0, 0)):
        lines = np.array([[[0.0, 1.0, lean * 1e-18], [0.0, 0.0, 1.0]]])  # y >= 0; always true
        assert clip_by_lines(flat, np.array([5]), lines)[1][0] == kept


def test_polygon_bounds_are_the_per_coordinate_min_and_max():
    from lazyvis_addon.core.geometry import polygon_bounds
    uv = np.random.default_rng(3).normal(size=(50, 7, 2))
    low, high = polygon_bounds(uv)
    np.testing.assert_array_equal(low, uv.min(axis=1))
    np.testing.assert_array_equal(high, uv.max(axis=1))


def test_short_edges_take_the_series_and_agree_with_the_arctangent_form():
    """Lambert's formula over a regular 64-gon (its edges under SHORT_EDGE_SINE apart seen from its axis or
    from far, some over it seen from just above it near its rim) against the same sum written with numpy's
    arctan2, to rounding, and against the disk's closed form pi R^2 / (R^2 + h^2) seen from its axis."""
    from lazyvis_addon.core.geometry import SHORT_EDGE_SINE, projected_solid_angle_uv
    angle = np.linspace(0.0, 2.0 * np.pi, 64, endpoint=False)
    branches = []
    for radius, height, offset in ((0.5, 10.0, 0.0), (1.0, 0.05, 0.0), (0.3, 2.0, 6.0), (1.0, 0.01, 0.95),
                                   (2.0, 0.2, 1.9)):
        uv = radius * np.stack([np.cos(angle), np.sin(angle)], axis=1)[None]
        local = np.array([[offset, 0.0, height]])
        got = projected_solid_angle_uv(uv, np.array([64]), local, np.array([[0.0, 0.0, 1.0]]))[0]
        points = np.concatenate([uv[0] - local[0, :2], np.full((64, 1), -height)], axis=1)
        points /= np.linalg.norm(points, axis=1, keepdims=True)
        after = np.roll(points, -1, axis=0)
        cross = np.cross(points, after)
        sine = np.linalg.norm(cross, axis=1)
        angle_between = np.arctan2(sine, (points * after).sum(axis=1))
        expected = abs(0.5 * (cross[:, 2] / sine * angle_between).sum())
        assert got == pytest.approx(expected, rel=1e-13), (radius, height, offset)
        if offset == 0.0:  # the inscribed polygon's closed form: the disk's times its area ratio, nearly
            disk = np.pi * radius ** 2 / (radius ** 2 + height ** 2)
            assert got == pytest.approx(disk, rel=2e-3)
        branches.append((sine < SHORT_EDGE_SINE).all())
    assert branches == [True, True, True, False, False]  # both branches are exercised


def test_negligible_lights_are_those_whose_solid_angle_bound_is_below_the_threshold():
    """A clipped light of area a at distance h subtends at most a / h^2: a polygon whose bound is under
    NEGLIGIBLE_SOLID_ANGLE (a light clipped to a segment or a point) is negligible, one just above it is
    not, at any height and either side of the plane, and the bound is never below the true solid angle."""
    square = SQUARE[:, :2]                                           # area 1
    segment = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [2.0, 0.0]])   # padded, collinear
    point = np.array([[0.3, 0.3], [0.3 + 1e-15, 0.3], [0.3, 0.3 + 1e-15], [0.3, 0.3 + 1e-15]])
    height = np.array([1.0, -1.0, 0.01, 1.0, 1.0])
    polygons = np.stack([square, square, square, segment, point])
    assert negligible_lights(polygons, np.full(5, 4), height).tolist() == [False, False, False, True, True]
    # Only the first ``count`` vertices count: the square's first two are a segment, its first three half of it.
    assert negligible_lights(np.stack([square, square]), np.array([2, 3]), np.array([1.0, 1.0])).tolist() == \
        [True, False]
    for h in (0.01, 1.0, 30.0):
        small = square * np.sqrt(0.5 * NEGLIGIBLE_SOLID_ANGLE) * h   # area half the threshold times h^2
        large = square * np.sqrt(2.0 * NEGLIGIBLE_SOLID_ANGLE) * h
        assert negligible_lights(np.stack([small, large]), np.array([4, 4]), np.array([h, -h])).tolist() == \
            [True, False]
    # The bound holds: the unit square's solid angle seen from above its centre at heights 0.2 .. 5.
    for h in (0.2, 1.0, 5.0):
        corners = np.concatenate([SQUARE[:, :2], np.full((4, 1), h)], axis=1)
        unit = corners / np.linalg.norm(corners, axis=1, keepdims=True)
        # Van Oosterom and Strackee's formula over the fan of two triangles.
        omega = 0.0
        for a, b, c in ((unit[0], unit[1], unit[2]), (unit[0], unit[2], unit[3])):
            omega += 2 * np.arctan2(abs(np.dot(a, np.cross(b, c))), 1 + a @ b + b @ c + c @ a)
        assert omega <= 1.0 / h ** 2
