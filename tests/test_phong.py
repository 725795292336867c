"""Arvo's irradiance tensors and the normalised Phong lobe over polygons (lazyvis_addon.core.phong).

Closed forms (solid angle of a rectangle, Lambert's formula, moments of the hemisphere), Monte Carlo for
clipped polygons (fixed seeds; 4 standard errors), and high-order Gauss-Legendre quadrature for the
numerical range of large exponents.
"""

import numpy as np
import pytest

from lazyvis_addon.core import ggx, phong
from lazyvis_addon.core.geometry import projected_solid_angle
from lazyvis_addon.core.sampling import sample_polygon_solid_angle

UP = np.array([0.0, 0.0, 1.0])


def unit(x):
    x = np.asarray(x, float)
    return x / np.linalg.norm(x)


def rectangle(x0, x1, y0, y1, height=1.0):
    return np.array([[x0, y0, height], [x1, y0, height], [x1, y1, height], [x0, y1, height]], float)


def corner_rectangle_solid_angle(a, b, d):
    """Solid angle of an a x b rectangle at distance d with one corner at the foot of the perpendicular."""
    return np.arctan(a * b / (d * np.sqrt(a * a + b * b + d * d)))


def test_tau0_is_the_solid_angle():
    # Closed form: an off-centre rectangle as a signed sum of four corner rectangles.
    x0, x1, y0, y1, d = -0.3, 1.2, 0.4, 0.9, 0.8
    # x spans the foot (left and right parts add), y lies on one side of it (outer minus inner).
    expected = (corner_rectangle_solid_angle(x1, y1, d) - corner_rectangle_solid_angle(x1, y0, d)
                + corner_rectangle_solid_angle(-x0, y1, d) - corner_rectangle_solid_angle(-x0, y0, d))
    got = phong.axial_moment(rectangle(x0, x1, y0, y1, d)[None], unit([0.3, -0.2, 1])[None], 0)[0]
    assert got == pytest.approx(expected, rel=1e-12)


def test_tau1_is_lamberts_formula():
    polygon = np.array([[0.3, -0.2, 1.0], [1.1, 0.4, 1.6], [-0.5, 0.9, 1.2], [-0.4, -0.3, 0.9]])
    normal = unit([0.2, -0.1, 1.0])
    got = phong.axial_moment(polygon[None], normal[None], 1)[0]
    assert got == pytest.approx(projected_solid_angle(polygon[None], normal[None])[0], rel=1e-12)


def test_hemisphere_closed_forms():
    # A square of half side 1e6 at height 1 covers the hemisphere up to ~1e-6 sr at the horizon.
    huge = rectangle(-1e6, 1e6, -1e6, 1e6)[None]
    orders = np.array([[0, 1, 2, 7, 40, 301]])
    # τ^n(N) over the hemisphere = 2π / (n + 1).
    assert np.allclose(phong.axial_moment(huge, UP[None], orders), 2 * np.pi / (orders + 1.0), rtol=1e-5, atol=0)
    # The normalised Phong lobe seen along the normal (r = N) integrates to exactly 1 over the hemisphere,
    # for any exponent, integer or not.
    for exponent in (0.0, 1.0, 2.5, 10.0, 123.4, 300.0):
        assert phong.phong_polygon_integral(huge, UP[None], UP[None], exponent)[0] == pytest.approx(1.0, rel=1e-6)


def monte_carlo(polygon, function, rng, count=200_000):
    """∫_P function(u) dω by uniform solid-angle sampling: mean and standard error."""
    directions, pdf, _ = sample_polygon_solid_angle(np.repeat(polygon[None], count, 0),
                                                    np.full(count, len(polygon)), rng.random((count, 2)))
    values = function(directions) / pdf
    return values.mean(), values.std() / np.sqrt(count)


CLIPPED_CASES = {
    # lobe axis w, receiver normal v, polygon: each polygon straddles w·u = 0 or v·u = 0 or both.
    "straddles-lobe-horizon": (unit([0.9, 0.0, 0.45]), UP, rectangle(-1.5, 0.3, -0.5, 0.6, 0.7)),
    "straddles-both": (unit([0.6, 0.3, 0.2]), unit([0.1, 0.0, 1.0]),
                       np.array([[-0.8, -0.6, 0.2], [0.9, -0.5, -0.3], [1.0, 0.7, 0.1], [-0.6, 0.8, 0.6]])),
    "inside": (unit([0.1, 0.2, 1.0]), UP, rectangle(-0.4, 0.5, -0.3, 0.6, 1.0)),
}


@pytest.mark.parametrize("case", list(CLIPPED_CASES))
@pytest.mark.parametrize("exponent", [0, 1, 3, 10, 40, 150])
def test_double_axis_moment_matches_monte_carlo(case, exponent):
    w, v, polygon = CLIPPED_CASES[case]
    clipped, count = phong.clip_to_half_spaces(polygon[None], np.array([len(polygon)]), w[None], v[None])
    got = phong.double_axis_moment(clipped, w[None], v[None], exponent, count=count)[0]
    rng = np.random.default_rng(100 + exponent)
    # The clamped lobe max(0, w·u)^n, continued to n = 0 as the indicator of w·u > 0 (its limit n -> 0+).
    mean, error = monte_carlo(polygon, lambda u: np.where(u @ w > 0, np.abs(u @ w) ** exponent, 0.0)
                              * np.maximum(u @ v, 0), rng)
    assert abs(got - mean) < 4 * error + 1e-12


def gauss_legendre_phong(corners, normal, view, exponent, nodes=1500):
    """The normalised Phong lobe · cos over a parallelogram light by 2-D Gauss-Legendre over its area."""
    origin, edge_u, edge_v = corners[0], corners[1] - corners[0], corners[3] - corners[0]
    x, w = np.polynomial.legendre.leggauss(nodes)
    s, w = 0.5 * (x + 1), 0.5 * w
    points = origin + s[:, None, None] * edge_u + s[None, :, None] * edge_v
    plane = np.cross(edge_u, edge_v)
    area = np.linalg.norm(plane)
    distance2 = np.einsum("ijk,ijk->ij", points, points)
    directions = points / np.sqrt(distance2)[..., None]
    jacobian = np.abs(directions @ (plane / area)) / distance2 * area
    mirror = 2 * (normal @ view) * normal - view
    lobe = (exponent + 2) / (2 * np.pi) * np.maximum(directions @ mirror, 0) ** exponent
    return np.einsum("i,j,ij->", w, w, lobe * np.maximum(directions @ normal, 0) * jacobian)


@pytest.mark.parametrize("exponent", [300, 1000, 2000])
def test_large_exponents_are_stable(exponent):
    # The documented range: absolute error of the normalised integral < 1e-10 up to n = 2000, whether the
    # highlight is inside the polygon, at its edge, or far away (where the true value underflows).
    view = unit([0.3, 0.1, 1.0])
    mirror = 2 * view[2] * UP - view
    centre = mirror / mirror[2]
    cases = [rectangle(centre[0] - 0.2, centre[0] + 0.2, centre[1] - 0.2, centre[1] + 0.2),
             rectangle(centre[0] + 0.01, centre[0] + 0.3, centre[1] - 0.1, centre[1] + 0.1),
             rectangle(centre[0] + 0.5, centre[0] + 0.9, centre[1] - 0.2, centre[1] + 0.2)]
    got = phong.phong_polygon_integral(np.stack(cases), np.tile(UP, (3, 1)), np.tile(view, (3, 1)), exponent)
    expected = np.array([gauss_legendre_phong(c, UP, view, exponent) for c in cases])
    assert np.all(np.abs(got - expected) < 1e-10), got - expected


def test_pieces_add_up_and_winding_and_padding_do_not_matter():
    view, exponent = unit([-0.4, 0.2, 1.0]), 37.25
    whole = rectangle(-0.6, 0.8, -0.5, 0.7)
    left, right = rectangle(-0.6, 0.1, -0.5, 0.7), rectangle(0.1, 0.8, -0.5, 0.7)
    padded_reversed = np.concatenate([right[::-1], right[:1], right[:1]])
    pieces = np.stack([np.concatenate([whole, whole[-1:], whole[-1:]]),
                       np.concatenate([left, left[-1:], left[-1:]]), padded_reversed])
    got = phong.phong_polygon_integral(pieces, np.tile(UP, (3, 1)), np.tile(view, (3, 1)), exponent)
    assert got[0] == pytest.approx(got[1] + got[2], rel=1e-12)
    rotation, _ = np.linalg.qr(np.random.default_rng(8).normal(size=(3, 3)))
    rotated = phong.phong_polygon_integral((pieces @ rotation.T), np.tile(UP @ rotation.T, (3, 1)),
                                           np.tile(view @ rotation.T, (3, 1)), exponent)
    assert np.allclose(rotated, got, rtol=1e-11)


def test_non_integer_exponents_interpolate_between_neighbours():
    polygon = rectangle(-0.2, 0.5, -0.3, 0.4)[None]
    view = unit([0.2, 0.0, 1.0])[None]
    low, high, middle = (phong.phong_polygon_integral(polygon, UP[None], view, n)[0] for n in (20.0, 21.0, 20.25))
    assert middle == pytest.approx(0.75 * low + 0.25 * high, rel=1e-12)


def test_view_below_horizon_and_empty_pieces_give_zero():
    polygon = rectangle(-0.2, 0.5, -0.3, 0.4)[None]
    assert phong.phong_polygon_integral(polygon, UP[None], -UP[None], 10.0)[0] == 0.0
    below = rectangle(-0.2, 0.5, -0.3, 0.4, height=-1.0)[None]
    assert phong.phong_polygon_integral(below, UP[None], UP[None], 10.0)[0] == 0.0


def test_roughness_mapping_matches_the_ggx_peak():
    # At normal incidence GGX·cos peaks at 1/(4π α²) in the mirror direction; the normalised Phong lobe
    # peaks at (n + 2)/(2π): the mapping makes them equal, and saturates to a Lambertian lobe (n = 0).
    for roughness in (0.15, 0.2, 0.3, 0.5):
        n = phong.phong_exponent_from_roughness(roughness)
        ggx_peak = ggx.ggx_brdf(UP[None], UP[None], UP[None], roughness, ggx.GlossyMaterial(multiscatter=False))[0, 0]
        assert (n + 2) / (2 * np.pi) == pytest.approx(ggx_peak, rel=1e-12)
    assert phong.phong_exponent_from_roughness(0.2) == pytest.approx(310.5)
    assert phong.phong_exponent_from_roughness(0.8) == 0.0


def test_vertex_count_from_padding():
    square = rectangle(0, 1, 0, 1)
    padded = np.stack([np.concatenate([square, square[-1:], square[-1:]]),
                       np.concatenate([square[:3], square[2:3], square[2:3], square[2:3]])])
    assert phong.vertex_count_from_padding(padded).tolist() == [4, 3]
