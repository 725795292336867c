"""Adaptive anti-aliasing mask (lazyvis_addon.core.adaptive): hand-built images whose marked pixels are
known, and a brute-force reference over random images."""

import numpy as np
import pytest

from lazyvis_addon.core.adaptive import close_holes, refine_mask

UP = np.array([0.0, 0.0, 1.0])
TILTED = np.array([0.0, 0.6, 0.8])


def flat_image(height=6, width=7):
    """One triangle (0), material 0, normal +Z, radiance 1 everywhere."""
    return (np.zeros((height, width), np.int64), np.zeros((height, width), np.int64),
            np.tile(UP, (height, width, 1)), np.ones((height, width, 3)))


def test_uniform_image_needs_nothing():
    assert not refine_mask(*flat_image()).any()


def test_coplanar_triangles_do_not_count():
    tri, mat, normal, radiance = flat_image()
    tri[:, 3:] = 1  # the quad's second triangle: same plane, same material, same light
    assert not refine_mask(tri, mat, normal, radiance).any()


def test_crease_marks_the_two_columns_beside_it():
    tri, mat, normal, radiance = flat_image()
    tri[:, 3:] = 1
    normal[:, 3:] = TILTED
    mask = refine_mask(tri, mat, normal, radiance)
    expected = np.zeros_like(mask)
    expected[:, 2:4] = True
    assert np.array_equal(mask, expected)


def test_diagonal_neighbours_count():
    tri, mat, normal, radiance = flat_image()
    tri[2, 3], normal[2, 3] = 5, TILTED  # a single pixel sees a tilted triangle
    mask = refine_mask(tri, mat, normal, radiance)
    expected = np.zeros_like(mask)
    expected[1:4, 2:5] = True
    assert np.array_equal(mask, expected)
    # Only a corner neighbour differs: pixel (0, 0) against (1, 1).
    tri, mat, normal, radiance = flat_image()
    tri[1, 1], normal[1, 1] = 5, TILTED
    assert refine_mask(tri, mat, normal, radiance)[0, 0]


def test_material_boundary():
    tri, mat, normal, radiance = flat_image()
    mat[3:, :] = 2
    mask = refine_mask(tri, mat, normal, radiance)
    assert mask[2:4].all() and not mask[:2].any() and not mask[4:].any()


def test_nothing_seen_against_a_surface():
    tri, mat, normal, radiance = flat_image()
    tri[:, :2], normal[:, :2], radiance[:, :2] = -1, 0.0, 0.0
    mat[:, :2] = 7  # whatever the exporter leaves there
    mask = refine_mask(tri, mat, normal, radiance)
    assert mask[:, 1:3].all() and not mask[:, 3:].any() and not mask[:, 0].any()


@pytest.mark.parametrize("other, marked", [(1.05, False), (1.2, True), (0.85, True), (0.95, False)])
def test_radiance_threshold_is_relative_to_the_brighter(other, marked):
    tri, mat, normal, radiance = flat_image()
    radiance[:, 4:, 1] = other  # one channel differs: 1 vs other, threshold 0.1 x the brighter
    mask = refine_mask(tri, mat, normal, radiance, relative_threshold=0.1)
    assert mask[:, 3:5].all() == marked and not mask[:, :3].any() and not mask[:, 6:].any()


def test_radiance_floor_ignores_dark_noise():
    tri, mat, normal, radiance = flat_image()
    radiance[:] = 0.001
    radiance[:, 4:] = 0.003
    assert refine_mask(tri, mat, normal, radiance).any()
    assert not refine_mask(tri, mat, normal, radiance, radiance_floor=0.01).any()
    assert not refine_mask(tri, mat, normal, np.zeros((6, 7))).any()  # black, scalar radiance


@pytest.mark.parametrize("shape, marked", [((1, 1), 0), ((1, 5), 2), ((5, 1), 2), ((2, 2), 4)])
def test_tiny_images(shape, marked):
    tri, mat, normal, radiance = flat_image(*shape)
    assert refine_mask(tri, mat, normal, radiance).shape == shape
    tri[-1, -1], normal[-1, -1] = 3, TILTED  # the last pixel sees a tilted triangle
    assert refine_mask(tri, mat, normal, radiance).sum() == marked


def reference_mask(tri, mat, normal, radiance, threshold, angle, floor):
    """Pixel by pixel, straight from the rule."""
    height, width = tri.shape
    mask = np.zeros((height, width), bool)
    for r in range(height):
        for c in range(width):
            for dr in (-1, 0, 1):
                for dc in (-1, 0, 1):
                    rr, cc = r + dr, c + dc
                    if (dr, dc) == (0, 0) or not (0 <= rr < height and 0 <= cc < width):
                        continue
                    p, q = (r, c), (rr, cc)
                    polygon = tri[p] != tri[q] and ((tri[p] < 0) != (tri[q] < 0)
                                                    or normal[p] @ normal[q] < np.cos(angle))
                    material = tri[p] >= 0 and tri[q] >= 0 and mat[p] != mat[q]
                    diff = np.abs(radiance[p] - radiance[q]).max()
                    brighter = max(np.abs(radiance[p]).max(), np.abs(radiance[q]).max())
                    light = diff > threshold * brighter and diff > floor
                    mask[r, c] |= bool(polygon or material or light)
    return mask


def test_matches_brute_force(np_rng):
    for _ in range(20):
        height, width = np_rng.integers(1, 9, 2)
        tri = np_rng.integers(-1, 4, (height, width))
        mat = np_rng.integers(0, 2, (height, width))
        normals = np.array([UP, UP, TILTED, -UP])
        normal = np.where((tri >= 0)[..., None], normals[np.maximum(tri, 0)], 0.0)
        radiance = np_rng.choice([0.0, 1.0, 1.05, 2.0], (height, width, 3))
        args = (tri, mat, normal, radiance)
        assert np.array_equal(refine_mask(*args, 0.1, 1e-3, 0.0), reference_mask(*args, 0.1, 1e-3, 0.0))
        assert np.array_equal(refine_mask(*args, 0.5, 1e-3, 0.5), reference_mask(*args, 0.5, 1e-3, 0.5))


def test_shapes_are_checked():
    tri, mat, normal, radiance = flat_image()
    with pytest.raises(ValueError, match="normal"):
        refine_mask(tri, mat, normal[:, :, :2], radiance)


def test_close_holes_marks_pixels_mostly_surrounded_by_marks():
    mask = np.zeros((5, 6), bool)
    mask[0:3, 0:3] = True
    mask[1, 1] = False                   # a hole: 8 marked neighbours
    mask[3:5, 4] = True                  # a column of two: its neighbours see at most 2 marks
    expected = mask.copy()
    expected[1, 1] = True                # every other unmarked pixel has at most 3 marked neighbours
    np.testing.assert_array_equal(close_holes(mask), expected)
    ring = np.ones((3, 3), bool)
    ring[1, 1] = False
    assert close_holes(ring).all()
    corner = np.zeros((3, 3), bool)
    corner[0, 1] = corner[1, 0] = corner[1, 1] = True  # (0, 0): 3 of its 3 in-image neighbours marked
    assert not close_holes(corner)[0, 0]               # outside counts as unmarked
    assert close_holes(corner, min_marked=3)[0, 0]
