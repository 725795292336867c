"""Light sampling (lazyvis_addon.core.sampling): solid angles against closed forms and an independent
Monte Carlo estimate; the samplers against independent uniform reference directions (two-sample
chi-square), their densities, their cones, and how well they keep stratification.

Statistical tests use fixed seeds, so they are deterministic; the significance level ALPHA = 1e-3 says
how unlikely a false failure would be for an arbitrary seed. There are nine chi-square tests of a correct
sampler in this file, so by Bonferroni the chance that any of them fails by bad luck is below 1 %.
"""

import math

import numpy as np
import pytest

from lazyvis_addon.core import sampling
from lazyvis_addon.core.sampling import (
    MIN_SPHERICAL_SOLID_ANGLE,
    polygon_solid_angle,
    sample_polygon_solid_angle,
    sample_spherical_triangle,
    spherical_triangle_solid_angle,
)

ALPHA = 1e-3
AREAL_CELLS_PER_SIDE = 6  # 36 cells per triangle: about a thousand samples per cell below

# Test triangles: vertices relative to the shading point at the origin, as (3, 3) float64.
TRIANGLES = {
    "ordinary": np.array([[0.3, -0.2, 1.0], [1.1, 0.4, 1.6], [-0.5, 0.9, 1.2]]),
    # Short edge b-c of 1e-4 against long edges of ~1: aspect ratio ~1e4, Omega ~ 2e-5 sr.
    "sliver": np.array([[0.0, 0.0, 1.0], [0.8, 0.5, 1.3], [0.8, 0.5001, 1.3]]),
    # A large triangle just above the shading point, Omega ~ 5.4 sr (most of the hemisphere).
    "large": np.array([[0.0, 1.0, 0.09], [-0.95, -0.45, 0.09], [0.9, -0.55, 0.09]]),
    # About 0.02 across at distance ~1.1: Omega ~ 1e-4 sr.
    "small": np.array([[0.45, 0.3, 1.0], [0.466, 0.3, 1.0035], [0.4535, 0.319, 0.9965]]),
}


# -- independent geometry -------------------------------------------------------------------------

def unit(x):
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def uniform_sphere(rng, count):
    """(count, 3) directions uniform on the unit sphere (normalised Gaussians)."""
    return unit(rng.normal(size=(count, 3)))


def ray_hits_triangle(directions, a, b, c):
    """Moller-Trumbore: does the ray from the origin along each of (M, 3) ``directions`` hit the
    triangle with vertices a, b, c (3,)? (M,) bool."""
    edge1, edge2 = b - a, c - a
    p = np.cross(directions, edge2)
    det = p @ edge1
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        s = -a
        bary_u = (p @ s) * inv
        q = np.cross(s, edge1)
        bary_v = (directions @ q) * inv
        t = (q @ edge2) * inv
    return (det != 0) & (bary_u >= 0) & (bary_v >= 0) & (bary_u + bary_v <= 1) & (t > 0)


def edge_plane_normals(a, b, c):
    """Unit normals (..., 3, 3) of the three planes through the origin and an edge of triangle a, b, c
    (..., 3), oriented towards the inside of its cone. Built from unit vertices and edge differences
    (A x B = A x (B - A)) so that they stay accurate for tiny triangles."""
    A, B, C = unit(a), unit(b), unit(c)
    orientation = np.sign(np.einsum("...i,...i->...", A, np.cross(B - A, C - A)))[..., None, None]
    return orientation * np.stack([unit(np.cross(A, B - A)), unit(np.cross(B, C - B)),
                                   unit(np.cross(C, A - C))], axis=-2)


def cone_margins(directions, a, b, c):
    """Signed sines of the angles from each direction (M, 3) to the three edge planes of the cone
    over triangle a, b, c (3,), positive inside: (M, 3)."""
    return directions @ edge_plane_normals(a, b, c).T


def unit_solid_angle(x, y, z):
    """Solid angle of spherical triangles with unit vertices (..., 3), from the unit-vector form
    tan(Omega / 2) = |x . (y x z)| / (1 + x.y + y.z + z.x)."""
    triple = np.abs(np.einsum("...i,...i->...", x, np.cross(y, z)))
    dots = 1.0 + np.einsum("...i,...i->...", x, y) + np.einsum("...i,...i->...", y, z) \
        + np.einsum("...i,...i->...", z, x)
    return 2.0 * np.arctan2(triple, dots)


def cos_weighted_solid_angle(vertices, normal):
    """Closed form of the integral of (normal . w) over the polygon's solid angle (Lambert): half the
    sum over edges of the edge's arc length times normal . (unit normal of the edge's plane).
    vertices (V, 3), normal (3,)."""
    total = 0.0
    for start, end in zip(vertices, np.roll(vertices, -1, axis=0)):
        arc = math.atan2(np.linalg.norm(np.cross(start, end)), start @ end)
        total += 0.5 * arc * (unit(np.cross(start, end)) @ normal)
    return abs(total)


def triangle_planar_samples(rng, a, b, c, count):
    """(count, 3) points uniform by area on the planar triangle a, b, c (sqrt warp)."""
    root = np.sqrt(rng.random(count))[:, None]
    v = rng.random(count)[:, None]
    return (1.0 - root) * a + root * (1.0 - v) * b + root * v * c


# -- reference directions uniform in solid angle --------------------------------------------------

def reference_by_cap(rng, polygon, count):
    """(count, 3) directions uniform inside the convex polygon (V, 3) (a triangle when V = 3): uniform
    directions in a spherical cap around it (cos theta and phi uniform), kept when they hit it."""
    # Axis: the mean vertex direction, or for polygons spread over most of a hemisphere the normal of
    # their plane (towards them), whichever gives the narrower cap.
    normal = unit(np.cross(polygon[1] - polygon[0], polygon[2] - polygon[0]))
    axes = [unit(unit(polygon).sum(axis=0)), normal * np.sign(normal @ polygon[0])]
    axis = max(axes, key=lambda candidate: np.min(unit(polygon) @ candidate))
    cos_max = np.min(unit(polygon) @ axis)
    assert cos_max > 0.0  # a cap narrower than a hemisphere is convex, so it holds the whole polygon
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t1 = unit(np.cross(axis, helper))
    t2 = np.cross(axis, t1)
    kept, total = [], 0
    while total < count:
        cos_t = 1.0 - rng.random(4 * count) * (1.0 - cos_max)
        sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t ** 2))
        phi = 2.0 * np.pi * rng.random(4 * count)
        d = cos_t[:, None] * axis + sin_t[:, None] * (np.cos(phi)[:, None] * t1 + np.sin(phi)[:, None] * t2)
        hits = np.zeros(len(d), bool)
        for k in range(1, len(polygon) - 1):
            hits |= ray_hits_triangle(d, polygon[0], polygon[k], polygon[k + 1])
        kept.append(d[hits])
        total += hits.sum()
    return np.concatenate(kept)[:count]


def reference_by_cap_triangle(rng, a, b, c, count):
    return reference_by_cap(rng, np.stack([a, b, c]), count)


def reference_by_area(rng, a, b, c, count):
    """Directions uniform inside triangle a, b, c: points uniform by area, kept with probability
    (h / r)^3. Since d(omega) = (h / r^3) dA (h the plane's distance), the kept points have constant
    density per steradian; h / r <= 1 makes it a probability. Efficient for slivers, where a cap
    would be mostly empty."""
    normal = unit(np.cross(b - a, c - a))
    plane_distance = abs(normal @ a)
    kept, total = [], 0
    while total < count:
        points = triangle_planar_samples(rng, a, b, c, 4 * count)
        ratio = plane_distance / np.linalg.norm(points, axis=1)
        keep = rng.random(len(points)) < ratio ** 3
        kept.append(unit(points[keep]))
        total += keep.sum()
    return np.concatenate(kept)[:count]


# -- chi-square machinery -------------------------------------------------------------------------

def normal_upper_quantile(alpha):
    """z with P(Z > z) = alpha for a standard normal, by bisection on erfc (no scipy)."""
    low, high = 0.0, 40.0
    for _ in range(200):
        mid = 0.5 * (low + high)
        if 0.5 * math.erfc(mid / math.sqrt(2.0)) > alpha:
            low = mid
        else:
            high = mid
    return 0.5 * (low + high)


def chi2_critical(df, alpha=ALPHA):
    """Upper alpha quantile of chi-square with df degrees of freedom (Wilson-Hilferty: (X/df)^(1/3)
    is nearly normal with mean 1 - 2/(9 df) and variance 2/(9 df); accurate to ~1 % for df >= 10)."""
    z = normal_upper_quantile(alpha)
    k = 2.0 / (9.0 * df)
    return df * (1.0 - k + z * math.sqrt(k)) ** 3


def test_chi2_critical_matches_tables():
    # Table values: chi2_{0.999}(30) = 59.703, chi2_{0.999}(100) = 149.449, chi2_{0.95}(50) = 67.505.
    assert chi2_critical(30, 1e-3) == pytest.approx(59.703, rel=0.01)
    assert chi2_critical(100, 1e-3) == pytest.approx(149.449, rel=0.005)
    assert chi2_critical(50, 0.05) == pytest.approx(67.505, rel=0.005)


def two_sample_chi2(counts_1, counts_2):
    """Chi-square statistic and degrees of freedom for 'two binned samples share one distribution'
    (unequal sample sizes; bins empty in both are dropped)."""
    counts_1, counts_2 = np.asarray(counts_1, float), np.asarray(counts_2, float)
    used = (counts_1 + counts_2) > 0
    counts_1, counts_2 = counts_1[used], counts_2[used]
    scale_1 = math.sqrt(counts_2.sum() / counts_1.sum())
    scale_2 = 1.0 / scale_1
    statistic = np.sum((scale_1 * counts_1 - scale_2 * counts_2) ** 2 / (counts_1 + counts_2))
    return statistic, int(used.sum()) - 1


def areal_cells(directions, a, b, c, cells_per_side=AREAL_CELLS_PER_SIDE):
    """Bin index (M,) of each direction on a triangular grid in the spherical triangle's areal
    coordinates (the fractions Omega(d, B, C) / Omega and Omega(A, d, C) / Omega, the spherical
    analogue of barycentrics): cells_per_side^2 cells, indices below 2 * cells_per_side^2."""
    A, B, C = unit(a), unit(b), unit(c)
    total = unit_solid_angle(A, B, C)
    weight_b = unit_solid_angle(A, directions, C) / total
    weight_c = unit_solid_angle(A, B, directions) / total
    scaled_b, scaled_c = cells_per_side * weight_b, cells_per_side * weight_c
    i = np.clip(np.floor(scaled_b), 0, cells_per_side - 1).astype(int)
    j = np.clip(np.floor(scaled_c), 0, cells_per_side - 1).astype(int)
    upper = ((scaled_b - i) + (scaled_c - j) >= 1.0).astype(int)
    return (i * cells_per_side + j) * 2 + upper


def homogeneity_statistic(sampled, reference, a, b, c):
    """(statistic, critical value) of the two-sample chi-square test of sampled vs reference
    directions (M, 3) in triangle a, b, c."""
    bins = 2 * AREAL_CELLS_PER_SIDE ** 2
    statistic, df = two_sample_chi2(np.bincount(areal_cells(sampled, a, b, c), minlength=bins),
                                    np.bincount(areal_cells(reference, a, b, c), minlength=bins))
    return statistic, chi2_critical(df)


def sample_triangle(vertices, u):
    count = len(u)
    a, b, c = (np.broadcast_to(v, (count, 3)) for v in vertices)
    return sample_spherical_triangle(a, b, c, u)


# -- solid angle ----------------------------------------------------------------------------------

def test_solid_angle_of_octant_triangle_is_half_pi():
    a, b, c = np.eye(3)[None, 0], np.eye(3)[None, 1], np.eye(3)[None, 2]
    assert spherical_triangle_solid_angle(a, b, c)[0] == pytest.approx(np.pi / 2, rel=1e-14)
    # Not-unit vertices and the opposite winding give the same.
    assert spherical_triangle_solid_angle(3 * a, c, 0.5 * b)[0] == pytest.approx(np.pi / 2, rel=1e-14)


@pytest.mark.parametrize("width, height, distance", [(2.0, 2.0, 1.0), (0.5, 3.0, 0.7), (1e-3, 2e-3, 5.0),
                                                     (4.0, 4.0, 0.01)])
def test_solid_angle_of_centred_rectangle(width, height, distance):
    """A width x height rectangle centred on the axis at ``distance``:
    Omega = 4 asin(w h / sqrt((w^2 + 4 d^2)(h^2 + 4 d^2))). As polygon and as its two triangles."""
    expected = 4.0 * math.asin(width * height / math.sqrt((width ** 2 + 4 * distance ** 2)
                                                           * (height ** 2 + 4 * distance ** 2)))
    x, y = width / 2, height / 2
    corners = np.array([[-x, -y, distance], [x, -y, distance], [x, y, distance], [-x, y, distance]])
    halves = spherical_triangle_solid_angle(corners[[0, 0]], corners[[1, 2]], corners[[2, 3]])
    assert halves.sum() == pytest.approx(expected, rel=1e-12)
    assert polygon_solid_angle(corners[None], [4])[0] == pytest.approx(expected, rel=1e-12)


def test_solid_angle_matches_monte_carlo():
    rng = np.random.default_rng(11)
    directions = uniform_sphere(rng, 400_000)
    # Random triangles at distances 0.5 to 3, plus the named ones with Omega large enough to count.
    triangles = [rng.normal(size=3) * rng.uniform(0.5, 3.0) + rng.normal(scale=0.6, size=(3, 3))
                 for _ in range(5)] + [TRIANGLES["ordinary"], TRIANGLES["large"]]
    for a, b, c in triangles:
        hit_fraction = ray_hits_triangle(directions, a, b, c).mean()
        estimate = 4 * np.pi * hit_fraction
        standard_error = 4 * np.pi * math.sqrt(hit_fraction * (1 - hit_fraction) / len(directions))
        solid_angle = spherical_triangle_solid_angle(a[None], b[None], c[None])[0]
        assert standard_error > 0
        assert abs(estimate - solid_angle) < 4 * standard_error
        # Winding and vertex order do not matter.
        assert spherical_triangle_solid_angle(c[None], b[None], a[None])[0] == pytest.approx(solid_angle, rel=1e-12)


def test_degenerate_triangles_give_zero_not_nan():
    rng = np.random.default_rng(3)
    u = rng.random((5, 2))
    a = np.array([[1.0, 0, 1], [0, 0, 0], [1, 0, 0], [1, 0, 0], [1, 1, 1]])
    b = np.array([[2.0, 0, 2], [0, 1, 1], [0, 1, 0], [2, 3, 0], [1, 1, 1]])
    c = np.array([[3.0, 0, 3], [1, 0, 1], [-1, -1, 0], [5, -1, 0], [1, 1, 1]])
    # collinear with the shading point; vertex at the shading point; shading point inside the
    # triangle's plane (inside, where the raw formula would say 2 pi; and outside); all vertices equal.
    solid_angle = spherical_triangle_solid_angle(a, b, c)
    np.testing.assert_array_equal(solid_angle, 0.0)
    directions, pdf = sample_spherical_triangle(a, b, c, u)
    np.testing.assert_array_equal(pdf, 0.0)
    assert np.all(np.isfinite(directions))
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0, rtol=1e-12)


# -- triangle sampler: distribution ---------------------------------------------------------------

@pytest.mark.parametrize("name, reference, seed", [("ordinary", reference_by_cap_triangle, 1),
                                                   ("ordinary", reference_by_area, 2),
                                                   ("sliver", reference_by_area, 3),
                                                   ("large", reference_by_cap_triangle, 4),
                                                   ("small", reference_by_cap_triangle, 5)])
def test_triangle_sampler_is_uniform_in_solid_angle(name, reference, seed):
    a, b, c = TRIANGLES[name]
    rng = np.random.default_rng(seed)
    count = 40_000
    directions, pdf = sample_triangle((a, b, c), rng.random((count, 2)))
    statistic, critical = homogeneity_statistic(directions, reference(rng, a, b, c, count), a, b, c)
    assert statistic < critical, f"{name}: chi2 {statistic:.1f} >= {critical:.1f}"
    solid_angle = spherical_triangle_solid_angle(a[None], b[None], c[None])[0]
    np.testing.assert_allclose(pdf, 1.0 / solid_angle, rtol=1e-12)


def test_named_triangles_have_the_intended_sizes():
    omega = {name: spherical_triangle_solid_angle(*(v[None] for v in tri))[0] for name, tri in TRIANGLES.items()}
    assert omega["large"] > 5.0
    assert 5e-5 < omega["small"] < 2e-4
    assert 1e-6 < omega["sliver"] < 1e-4
    edges = np.linalg.norm(TRIANGLES["sliver"] - np.roll(TRIANGLES["sliver"], 1, axis=0), axis=1)
    assert edges.min() < 1e-3 * edges.max()


def wrong_sampler_area_uniform(rng, a, b, c, count):
    """Uniform by area on the plane: not uniform in solid angle for a large, close triangle."""
    return unit(triangle_planar_samples(rng, a, b, c, count))


def wrong_sampler_warped_u(rng, a, b, c, count):
    """The real map fed u0^0.8: a density in solid angle that sags along the edge AB (small u0)."""
    u = rng.random((count, 2))
    u[:, 0] **= 0.8
    return sample_triangle((a, b, c), u)[0]


@pytest.mark.parametrize("wrong_sampler", [wrong_sampler_area_uniform, wrong_sampler_warped_u])
def test_chi_square_test_rejects_non_uniform_samplers(wrong_sampler):
    """The homogeneity test above has power: it rejects samplers that are not uniform in solid angle."""
    a, b, c = TRIANGLES["large"]
    rng = np.random.default_rng(99)
    count = 40_000
    statistic, critical = homogeneity_statistic(wrong_sampler(rng, a, b, c, count),
                                                reference_by_cap_triangle(rng, a, b, c, count), a, b, c)
    assert statistic > 3 * critical


def test_sampler_is_arvos_map():
    """The half-angle formulation must be the same map as Arvo's (1995) cosine formulas, written out
    here directly from the paper, on triangles of ordinary size where those are accurate."""
    rng = np.random.default_rng(5)
    count = 20_000
    a, b, c = (rng.normal(size=(count, 3)) for _ in range(3))
    u = rng.random((count, 2))
    solid_angle = spherical_triangle_solid_angle(a, b, c)
    keep = (solid_angle > 1e-2) & (solid_angle < 5.0)
    a, b, c, u, solid_angle = a[keep], b[keep], c[keep], u[keep], solid_angle[keep]
    A, B, C = unit(a), unit(b), unit(c)

    def angle_between(x, y):
        return np.arctan2(np.linalg.norm(np.cross(x, y), axis=1), np.sum(x * y, axis=1))

    alpha = angle_between(np.cross(A, B), np.cross(A, C))
    sub_area = u[:, 0] * solid_angle
    s, t = np.sin(sub_area - alpha), np.cos(sub_area - alpha)
    p = t - np.cos(alpha)
    q = s + np.sin(alpha) * np.sum(A * B, axis=1)
    cos_b_sub = np.clip(((q * t - p * s) * np.cos(alpha) - q) / ((q * s + p * t) * np.sin(alpha)), -1, 1)
    c_sub = cos_b_sub[:, None] * A + np.sqrt(1 - cos_b_sub ** 2)[:, None] * unit(C - np.sum(C * A, axis=1)[:, None] * A)
    z = 1 - u[:, 1] * (1 - np.sum(c_sub * B, axis=1))
    expected = z[:, None] * B + np.sqrt(1 - z ** 2)[:, None] * unit(c_sub - np.sum(c_sub * B, axis=1)[:, None] * B)

    directions, _ = sample_spherical_triangle(a, b, c, u)
    assert len(directions) > count / 4
    np.testing.assert_allclose(directions, expected, atol=1e-8)


# -- triangle sampler: densities and cones --------------------------------------------------------

def half_square_triangle(side, distance):
    """Half of a side x side square centred on the axis at ``distance`` (split along a diagonal through
    the axis, so exactly half the square's solid angle 4 asin(s^2 / (s^2 + 4 d^2)))."""
    h = side / 2
    vertices = np.array([[-h, -h, distance], [h, -h, distance], [h, h, distance]])
    return vertices, 2.0 * math.asin(side ** 2 / (side ** 2 + 4 * distance ** 2))


def test_tiny_triangle_takes_the_area_fallback_with_exact_pdf():
    (a, b, c), solid_angle = half_square_triangle(1e-5, 1.0)
    assert solid_angle < MIN_SPHERICAL_SOLID_ANGLE
    rng = np.random.default_rng(8)
    directions, pdf = sample_triangle((a, b, c), rng.random((20_000, 2)))
    assert np.ptp(pdf) > 0  # the area-sampling density varies: the fallback was taken
    assert np.mean(1.0 / pdf) == pytest.approx(solid_angle, rel=1e-9)
    np.testing.assert_allclose(pdf, 1.0 / solid_angle, rtol=1e-4)
    assert cone_margins(directions, a, b, c).min() > -1e-15


@pytest.mark.parametrize("side, distance", [(2.0, 1.0), (2.0, 0.1)])
def test_area_fallback_pdf_is_the_density_of_its_directions(monkeypatch, side, distance):
    """Forced onto large and close triangles, where area sampling is far from uniform in solid angle,
    the fallback's pdf still integrates correctly: E[1 / pdf] = Omega."""
    monkeypatch.setattr(sampling, "MIN_SPHERICAL_SOLID_ANGLE", np.inf)
    (a, b, c), solid_angle = half_square_triangle(side, distance)
    rng = np.random.default_rng(12)
    _, pdf = sample_triangle((a, b, c), rng.random((100_000, 2)))
    weights = 1.0 / pdf
    assert np.ptp(weights) > 0.1 * solid_angle
    standard_error = weights.std() / math.sqrt(len(weights))
    assert abs(weights.mean() - solid_angle) < 4 * standard_error


def test_arvo_pdf_is_one_over_closed_form_solid_angle():
    (a, b, c), solid_angle = half_square_triangle(2.0, 1.0)
    _, pdf = sample_triangle((a, b, c), np.random.default_rng(2).random((1000, 2)))
    np.testing.assert_allclose(1.0 / pdf, solid_angle, rtol=1e-13)


def test_directions_stay_inside_the_triangle():
    rng = np.random.default_rng(21)
    count = 50_000
    # Random triangles of every size, from ~1e-12 sr to nearly 2 pi, and u including its extremes.
    scale = 10.0 ** rng.uniform(-6, 1, (count, 1))
    centre = unit(rng.normal(size=(count, 3)))
    a, b, c = (centre + scale * rng.normal(size=(count, 3)) for _ in range(3))
    u = rng.random((count, 2))
    u[:200] = np.array([[0.0, 0.0], [0.0, 1 - 2 ** -53], [1 - 2 ** -53, 0.0], [1 - 2 ** -53, 1 - 2 ** -53]])[rng.integers(0, 4, 200)]
    directions, pdf = sample_spherical_triangle(a, b, c, u)
    solid_angle = spherical_triangle_solid_angle(a, b, c)
    assert solid_angle.min() < MIN_SPHERICAL_SOLID_ANGLE < solid_angle.max()
    assert solid_angle.max() > 6.0
    assert np.all(np.isfinite(directions)) and np.all(np.isfinite(pdf)) and np.all(pdf > 0)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0, rtol=1e-14)
    margins = np.einsum("nj,nkj->nk", directions, edge_plane_normals(a, b, c))
    assert margins.min() > -1e-15
    for name, (a, b, c) in TRIANGLES.items():
        directions, _ = sample_triangle((a, b, c), rng.random((10_000, 2)))
        assert cone_margins(directions, a, b, c).min() > -1e-15, name


# -- stratification -------------------------------------------------------------------------------

def jittered_grid(rng, side):
    """(side^2, 2) points, one uniform point in each cell of a side x side grid of the unit square."""
    i, j = np.meshgrid(np.arange(side), np.arange(side), indexing="ij")
    cells = np.stack([i.ravel(), j.ravel()], axis=1)
    return (cells + rng.random(cells.shape)) / side


def stratification_gain(estimate, exact, seeds=8, side=64):
    """RMS error with independent uniforms divided by RMS error with a jittered grid, same count."""
    independent, stratified = [], []
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        independent.append(estimate(rng.random((side * side, 2))) - exact)
        stratified.append(estimate(jittered_grid(rng, side)) - exact)
    return math.sqrt(np.mean(np.square(independent)) / np.mean(np.square(stratified)))


def test_triangle_map_keeps_stratification():
    """Integral of cos(theta) about +Z over the triangle: a jittered 64 x 64 grid of u must beat
    independent uniforms clearly, which needs a continuous, area-preserving map."""
    a, b, c = TRIANGLES["ordinary"]
    normal = np.array([0.0, 0.0, 1.0])
    exact = cos_weighted_solid_angle(np.stack([a, b, c]), normal)

    def estimate(u):
        directions, pdf = sample_triangle((a, b, c), u)
        return np.mean(directions @ normal / pdf)

    assert stratification_gain(estimate, exact) > 3.0


def test_cos_weighted_closed_form_matches_monte_carlo():
    """The closed form the stratification tests rely on, against plain Monte Carlo."""
    a, b, c = TRIANGLES["ordinary"]
    rng = np.random.default_rng(4)
    directions = reference_by_cap_triangle(rng, a, b, c, 100_000)
    solid_angle = spherical_triangle_solid_angle(a[None], b[None], c[None])[0]
    values = solid_angle * directions[:, 2]
    exact = cos_weighted_solid_angle(np.stack([a, b, c]), np.array([0.0, 0.0, 1.0]))
    assert abs(values.mean() - exact) < 4 * values.std() / math.sqrt(len(values))


# -- polygons -------------------------------------------------------------------------------------

def padded(polygons, slots=6):
    """Stack polygons (list of (count_i, 3)) into (N, slots, 3) padded with their last vertex, and counts."""
    vertices = np.stack([np.concatenate([p, np.repeat(p[-1:], slots - len(p), axis=0)]) for p in polygons])
    return vertices, np.array([len(p) for p in polygons])


SQUARE = np.array([[-0.5, -0.5, 1.0], [0.5, -0.5, 1.0], [0.5, 0.5, 1.0], [-0.5, 0.5, 1.0]])
# A convex pentagon in a tilted plane, off the axis.
_PENTAGON_ANGLES = np.radians([10.0, 80.0, 170.0, 230.0, 300.0])
_PENTAGON_RADII = np.array([1.0, 0.8, 1.1, 0.9, 1.0])
PENTAGON = (np.stack([_PENTAGON_RADII * np.cos(_PENTAGON_ANGLES), _PENTAGON_RADII * np.sin(_PENTAGON_ANGLES),
                      np.zeros(5)], axis=1) @ np.array([[1.0, 0, 0.2], [0, 0.9, 0.3], [0, 0, 1]]).T
            + np.array([0.4, -0.2, 1.3]))


def fan_index(directions, polygon):
    """Which fan triangle (0, k, k + 1) of polygon (V, 3) holds each direction (M,): k - 1, or -1."""
    index = np.full(len(directions), -1)
    for k in range(1, len(polygon) - 1):
        inside = cone_margins(directions, polygon[0], polygon[k], polygon[k + 1]).min(axis=1) >= 0
        index[inside & (index < 0)] = k - 1
    return index


def fan_solid_angles(polygon):
    unit_vertices = unit(polygon)
    return np.array([unit_solid_angle(unit_vertices[0], unit_vertices[k], unit_vertices[k + 1])
                     for k in range(1, len(polygon) - 1)])


def test_pentagon_solid_angle_matches_monte_carlo():
    rng = np.random.default_rng(17)
    directions = uniform_sphere(rng, 400_000)
    hits = np.zeros(len(directions), bool)
    for k in range(1, 4):
        hits |= ray_hits_triangle(directions, PENTAGON[0], PENTAGON[k], PENTAGON[k + 1])
    fraction = hits.mean()
    estimate = 4 * np.pi * fraction
    standard_error = 4 * np.pi * math.sqrt(fraction * (1 - fraction) / len(directions))
    vertices, counts = padded([PENTAGON])
    assert abs(polygon_solid_angle(vertices, counts)[0] - estimate) < 4 * standard_error


@pytest.mark.parametrize("name, polygon", [("square", SQUARE), ("pentagon", PENTAGON)])
def test_polygon_sampler_is_uniform_and_picks_fans_by_solid_angle(name, polygon):
    rng = np.random.default_rng(31 + len(polygon))
    count = 60_000
    # Square and pentagon share one padded batch, so padding and per-row counts are exercised.
    vertices, counts = padded([SQUARE, PENTAGON] * (count // 2))
    row = 0 if name == "square" else 1
    directions, pdf, solid_angle = sample_polygon_solid_angle(vertices, counts, rng.random((len(vertices), 2)))
    directions, pdf, solid_angle = directions[row::2], pdf[row::2], solid_angle[row::2]

    fans = fan_solid_angles(polygon)
    assert solid_angle[0] == pytest.approx(fans.sum(), rel=1e-12)
    np.testing.assert_allclose(pdf, 1.0 / solid_angle[0], rtol=1e-12)  # E[1 / pdf] = Omega, exactly

    chosen = fan_index(directions, polygon)
    assert np.all(chosen >= 0)  # every direction inside the polygon
    # Fan choice: chi-square goodness of fit of the counts against Omega_k / Omega.
    observed = np.bincount(chosen, minlength=len(fans))
    expected = len(directions) * fans / fans.sum()
    assert np.sum((observed - expected) ** 2 / expected) < chi2_critical(len(fans) - 1)

    # Uniformity: two-sample chi-square on (fan triangle, areal cell) bins against directions
    # uniform in a cap around the polygon, kept when inside it.
    reference = reference_by_cap(rng, polygon, len(directions))
    cells = 2 * AREAL_CELLS_PER_SIDE ** 2

    def binned(d):
        k = fan_index(d, polygon)
        cell = np.zeros(len(d), int)
        for t in range(len(fans)):
            mask = k == t
            cell[mask] = areal_cells(d[mask], polygon[0], polygon[t + 1], polygon[t + 2])
        return np.bincount(k * cells + cell, minlength=len(fans) * cells)

    statistic, df = two_sample_chi2(binned(directions), binned(reference))
    assert statistic < chi2_critical(df), f"{name}: chi2 {statistic:.1f}"


def test_polygon_fallback_pdf_is_the_density_of_its_directions(monkeypatch):
    """With every fan triangle forced onto area sampling, pdf = P(triangle) x area density must still
    satisfy E[1 / pdf] = Omega for a close pentagon (strongly non-uniform area sampling)."""
    monkeypatch.setattr(sampling, "MIN_SPHERICAL_SOLID_ANGLE", np.inf)
    close = PENTAGON - np.array([0.0, 0.0, 1.1])
    count = 100_000
    vertices, counts = padded([close] * count)
    _, pdf, solid_angle = sample_polygon_solid_angle(vertices, counts, np.random.default_rng(6).random((count, 2)))
    weights = 1.0 / pdf
    assert np.ptp(weights) > 0.1 * solid_angle[0]
    assert abs(weights.mean() - solid_angle[0]) < 4 * weights.std() / math.sqrt(count)


def test_polygon_map_keeps_stratification():
    """The u0 remap inside the chosen fan triangle keeps the composite map area preserving."""
    normal = unit(np.array([0.2, -0.1, 1.0]))
    exact = cos_weighted_solid_angle(PENTAGON, normal)
    side = 64
    vertices, counts = padded([PENTAGON] * side * side)

    def estimate(u):
        directions, pdf, _ = sample_polygon_solid_angle(vertices, counts, u)
        return np.mean(directions @ normal / pdf)

    assert stratification_gain(estimate, exact, side=side) > 3.0


def test_degenerate_polygons_give_zero_pdf_not_nan():
    edge_on = SQUARE - np.array([0.0, 0.0, 1.0])          # shading point in the polygon's plane
    collapsed = np.repeat(SQUARE[:1], 4, axis=0)          # all vertices equal
    vertices, counts = padded([edge_on, collapsed, SQUARE])
    counts[2] = 2                                         # fewer than three real vertices
    directions, pdf, solid_angle = sample_polygon_solid_angle(vertices, counts, np.full((3, 2), 0.5))
    np.testing.assert_array_equal(solid_angle, 0.0)
    np.testing.assert_array_equal(pdf, 0.0)
    assert np.all(np.isfinite(directions))
