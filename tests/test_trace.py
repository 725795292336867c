"""Ray tracers: Embree (RayTracer) against the brute-force numpy oracle (NumpyRayTracer), and both
against scenes with known answers."""

import numpy as np
import pytest

from lazyvis_addon.core.trace import Hits, NumpyRayTracer, RayTracer

TRACERS = [RayTracer, NumpyRayTracer]


def random_soup(rng, count=300):
    """(count, 3, 3) float64 small random triangles scattered in [-1, 1]^3."""
    centres = rng.uniform(-1.0, 1.0, (count, 3))
    return centres[:, None, :] + rng.normal(0.0, 0.2, (count, 3, 3))


def random_rays(rng, count):
    """Origins in [-2, 2]^3 and non-unit directions (lengths roughly 0.3 to 3)."""
    origins = rng.uniform(-2.0, 2.0, (count, 3))
    directions = rng.normal(size=(count, 3))
    directions *= rng.uniform(0.3, 3.0, (count, 1)) / np.linalg.norm(directions, axis=1, keepdims=True)
    return origins, directions


def quad(offset=(0.0, 0.0, 0.0)):
    """Two triangles covering [0, 2]^2 in the plane z = 0, shifted by ``offset``."""
    square = np.array([[[0, 0, 0], [2, 0, 0], [2, 2, 0]],
                       [[0, 0, 0], [2, 2, 0], [0, 2, 0]]], dtype=np.float64)
    return square + np.asarray(offset, dtype=np.float64)


def barycentric_points(triangles, hits):
    """(N, 3) points (1 - u - v) v0 + u v1 + v v2 of the hit triangles (rows of hits only)."""
    tri = triangles[hits.index_triangle[hits.hit]]
    u, v = hits.u[hits.hit, None], hits.v[hits.hit, None]
    return (1.0 - u - v) * tri[:, 0] + u * tri[:, 1] + v * tri[:, 2]


@pytest.fixture(scope="module")
def soup_scene():
    rng = np.random.default_rng(12345)
    triangles = random_soup(rng)
    origins, directions = random_rays(rng, 20000)
    embree, oracle = RayTracer(triangles), NumpyRayTracer(triangles)
    return dict(triangles=triangles, origins=origins, directions=directions,
                embree=embree, oracle=oracle,
                embree_hits=embree.intersect(origins, directions),
                oracle_hits=oracle.intersect(origins, directions))


def test_backends_agree_on_random_soup(soup_scene):
    embree_hits, oracle_hits = soup_scene["embree_hits"], soup_scene["oracle_hits"]
    same = embree_hits.index_triangle == oracle_hits.index_triangle
    assert 0.1 < oracle_hits.hit.mean() < 0.9  # the test sees both hits and misses
    assert same.mean() >= 0.995, f"backends disagree on {np.count_nonzero(~same)} of {len(same)} rays"
    both = same & oracle_hits.hit
    length = np.linalg.norm(soup_scene["directions"][both], axis=1)
    distance_error = np.abs(embree_hits.t[both] - oracle_hits.t[both]) * length
    assert distance_error.max() < 1e-5 * (1.0 + oracle_hits.t[both] * length).max()
    assert np.abs(embree_hits.u[both] - oracle_hits.u[both]).max() < 1e-3
    assert np.abs(embree_hits.v[both] - oracle_hits.v[both]).max() < 1e-3
    # misses look like misses
    for hits in (embree_hits, oracle_hits):
        assert hits.index_triangle.dtype == np.int64 and hits.t.dtype == np.float64
        assert np.all(np.isinf(hits.t[~hits.hit])) and np.all(hits.u[~hits.hit] == 0)


def test_backends_agree_on_occlusion(soup_scene):
    rng = np.random.default_rng(7)
    origins, directions = soup_scene["origins"], soup_scene["directions"]
    tfar = rng.uniform(0.0, 4.0, len(origins))
    embree_occluded = soup_scene["embree"].occluded(origins, directions, tfar)
    oracle_occluded = soup_scene["oracle"].occluded(origins, directions, tfar)
    assert embree_occluded.dtype == bool and 0.05 < oracle_occluded.mean() < 0.95
    assert (embree_occluded == oracle_occluded).mean() >= 0.995
    # occluded is exactly "the nearest hit is within tfar" for the oracle
    oracle_hits = soup_scene["oracle_hits"]
    np.testing.assert_array_equal(oracle_occluded, oracle_hits.t <= tfar)


@pytest.mark.parametrize("hits_key", ["embree_hits", "oracle_hits"])
def test_hit_point_from_barycentrics_lies_on_ray_and_triangle(soup_scene, hits_key):
    hits = soup_scene[hits_key]
    on_ray = soup_scene["origins"][hits.hit] + hits.t[hits.hit, None] * soup_scene["directions"][hits.hit]
    from_barycentrics = barycentric_points(soup_scene["triangles"], hits)
    np.testing.assert_allclose(from_barycentrics, on_ray, atol=1e-4)
    u, v = hits.u[hits.hit], hits.v[hits.hit]
    assert u.min() >= -1e-6 and v.min() >= -1e-6 and (u + v).max() <= 1 + 1e-6


@pytest.mark.parametrize("tracer_class", TRACERS)
def test_quad_known_t_u_v(tracer_class):
    offset = np.array([1.0, -1.0, 0.5])
    tracer = tracer_class(quad(offset))
    origins = np.array([[1.5, 0.5, 3.0], [0.5, 1.5, 3.0], [1.5, 0.5, -2.0], [3.0, 3.0, 3.0]]) + offset
    directions = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    hits = tracer.intersect(origins, directions)
    np.testing.assert_array_equal(hits.index_triangle, [0, 1, 0, -1])  # triangles are two-sided
    np.testing.assert_allclose(hits.t[:3], [3.0, 3.0, 2.0], rtol=1e-6)
    # (1.5, 0.5) = 0.5 * v1 + 0.25 * v2 in triangle 0; (0.5, 1.5) = 0.25 * v1 + 0.5 * v2 in triangle 1
    np.testing.assert_allclose(hits.u[:3], [0.5, 0.25, 0.5], atol=1e-6)
    np.testing.assert_allclose(hits.v[:3], [0.25, 0.5, 0.25], atol=1e-6)
    assert hits.t[3] == np.inf


@pytest.mark.parametrize("tracer_class", TRACERS)
def test_tfar_bounds_occlusion_and_hits(tracer_class):
    tracer = tracer_class(quad())
    origins = np.tile([1.0, 1.0, 2.0], (6, 1))
    directions = np.tile([0.0, 0.0, -1.0], (6, 1))
    # the quad is at t = 2
    tfar = np.array([2.0 * (1 + 1e-5), 2.0 * (1 - 1e-5), 2.0 * (1 + 1e-5), np.inf, -1.0, np.nan])
    expected = np.array([True, False, True, True, False, False])
    np.testing.assert_array_equal(tracer.occluded(origins, directions, tfar), expected)
    np.testing.assert_array_equal(tracer.intersect(origins, directions, tfar).hit, expected)
    assert tracer.occluded(origins, directions, 2.0 * (1 - 1e-5)).sum() == 0  # scalar tfar
    assert tracer.occluded(origins, directions).all()  # no tfar: unbounded


@pytest.mark.parametrize("tracer_class", TRACERS)
def test_non_unit_directions_give_parametric_t(tracer_class):
    tracer = tracer_class(quad())
    origin = np.array([[1.0, 1.0, 3.0]])
    for scale in (0.5, 1.0, 2.5):
        direction = np.array([[0.0, 0.0, -scale]])
        hits = tracer.intersect(origin, direction)
        np.testing.assert_allclose(hits.t, 3.0 / scale, rtol=1e-6)  # t in units of |direction|
        np.testing.assert_allclose(origin + hits.t[:, None] * direction, [[1.0, 1.0, 0.0]], atol=1e-6)
        # tfar is in the same units: just short of the hit in t, not in distance
        assert not tracer.occluded(origin, direction, 3.0 / scale * (1 - 1e-5))[0]
        assert tracer.occluded(origin, direction, 3.0 / scale * (1 + 1e-5))[0]
    assert not tracer.intersect(origin, np.zeros((1, 3))).hit[0]  # a zero direction never hits
    assert not tracer.occluded(origin, np.zeros((1, 3)))[0]


@pytest.mark.parametrize("tracer_class", TRACERS)
def test_empty_scene_and_no_rays(tracer_class):
    rng = np.random.default_rng(3)
    origins, directions = random_rays(rng, 100)
    tracer = tracer_class(np.zeros((0, 3, 3)))
    hits = tracer.intersect(origins, directions)
    assert isinstance(hits, Hits) and len(hits) == 100
    assert np.all(hits.index_triangle == -1) and np.all(np.isinf(hits.t))
    assert not tracer.occluded(origins, directions, 10.0).any()
    assert tracer.n_rays_cast == 200
    tracer = tracer_class(quad())
    hits = tracer.intersect(np.zeros((0, 3)), np.zeros((0, 3)))
    assert len(hits) == 0 and tracer.occluded(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0,)


def test_threads_batches_and_inactive_rays_match_single_call(soup_scene):
    triangles, origins, directions = soup_scene["triangles"], soup_scene["origins"], soup_scene["directions"]
    reference = soup_scene["embree_hits"]
    with RayTracer(triangles, threads=2, batch_size=1000) as tracer:
        hits = tracer.intersect(origins, directions)
        for name in ("index_triangle", "t", "u", "v"):
            np.testing.assert_array_equal(getattr(hits, name), getattr(reference, name))
        tfar = np.where(np.arange(len(origins)) % 3 == 0, -1.0, np.inf)  # every third ray inactive
        partial = tracer.intersect(origins, directions, tfar)
        active = tfar >= 0
        np.testing.assert_array_equal(partial.index_triangle[active], reference.index_triangle[active])
        assert np.all(partial.index_triangle[~active] == -1)
        occluded = tracer.occluded(origins, directions, tfar)
        np.testing.assert_array_equal(occluded, reference.hit & active)
        assert tracer.n_rays_cast == 3 * len(origins)


@pytest.mark.parametrize("tracer_class", TRACERS)
def test_bad_shapes_raise(tracer_class):
    with pytest.raises(ValueError, match="T x 3 x 3"):
        tracer_class(np.zeros((4, 3)))
    tracer = tracer_class(quad())
    with pytest.raises(ValueError, match="N x 3"):
        tracer.intersect(np.zeros((5, 2)), np.zeros((5, 2)))
    with pytest.raises(ValueError, match="directions"):
        tracer.intersect(np.zeros((5, 3)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match="tfar"):
        tracer.occluded(np.zeros((5, 3)), np.ones((5, 3)), np.ones(4))


@pytest.mark.parametrize("tracer_class", TRACERS)
def test_nearest_float32_is_intersect_of_the_same_float32_rays(tracer_class):
    """The float32 entry the reference depth's compiled rounds use gives ``intersect``'s triangle and t for
    the same rays (bit for bit), across several of Embree's batches and on two threads."""
    rng = np.random.default_rng(7)
    triangles = random_soup(rng, 200)
    origins, directions = random_rays(rng, 9000)
    tfar = rng.uniform(0.0, 4.0, len(origins))
    o32, d32, f32 = origins.astype(np.float32), directions.astype(np.float32), tfar.astype(np.float32)
    tracer = tracer_class(triangles, threads=2, batch_size=4096)
    hits = tracer.intersect(o32.astype(np.float64), d32.astype(np.float64), f32.astype(np.float64))
    triangle, t = tracer.nearest_float32(o32, d32, f32)
    assert 0.1 < hits.hit.mean() < 0.9
    assert triangle.dtype == np.int64 and t.dtype == np.float64
    np.testing.assert_array_equal(triangle, hits.index_triangle)
    np.testing.assert_array_equal(t[hits.hit], hits.t[hits.hit])
    # An empty scene: every ray misses.
    empty_triangle, _ = tracer_class(np.zeros((0, 3, 3))).nearest_float32(o32, d32, f32)
    assert (empty_triangle == -1).all()
