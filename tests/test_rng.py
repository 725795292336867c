"""Counter-based random numbers (lazyvis_addon.core.rng): the Sobol points that place anti-aliasing samples."""

import numpy as np
import pytest

from lazyvis_addon.core import rng
from test_sampling import chi2_critical


def cells(points, a, m):
    """Cell index of each point in the 2^a x 2^(m - a) grid."""
    return (np.floor(points[:, 0] * 2 ** a) * 2 ** (m - a) + np.floor(points[:, 1] * 2 ** (m - a))).astype(int)


@pytest.mark.parametrize("m", [2, 3, 4, 6])
def test_sobol_points_of_a_pixel_are_stratified_in_every_grid_shape(m):
    """The first 2^m points of each pixel put one point in every cell of every 2^a x 2^(m-a) grid (a (0, m,
    2)-net), scrambled or not; a second batch (indices 2^m .. 2^(m+1) - 1) completes a (0, m+1, 2)-net."""
    n = 2 ** m
    pixels = np.array([0, 7, 123456, 2 ** 40])
    for pixel in pixels:
        points = rng.sobol_2d(1, 2, rng.STREAM_FILM, np.full(2 * n, pixel), np.arange(2 * n))
        for a in range(m + 1):
            assert len(set(cells(points[:n], a, m))) == n, (pixel, a)
        for a in range(m + 2):
            assert len(set(cells(points, a, m + 1))) == 2 * n, (pixel, a)
    # Plain jittered strata, for contrast, fail the 1 x 2^m grid with n points in a sqrt(n) grid.
    u = rng.stratified_2d(np.random.default_rng(0).uniform(size=(16, 2)), np.arange(16), 16)
    assert len(set(cells(u, 0, 4))) < 16


def test_sobol_points_are_uniform_and_independent_across_pixels():
    """Scrambling makes any one point uniform over the square (chi-square on a 16 x 16 grid over many
    pixels) and neighbouring pixels' point sets unrelated (correlation of their first points ~ 0)."""
    pixels = np.arange(100_000)
    for index in (0, 5):
        points = rng.sobol_2d(0, 0, rng.STREAM_FILM, pixels, np.full(len(pixels), index))
        counts = np.bincount(cells(points, 4, 8), minlength=256)
        expected = len(pixels) / 256
        assert np.sum((counts - expected) ** 2 / expected) < chi2_critical(255)
    first = rng.sobol_2d(0, 0, rng.STREAM_FILM, pixels, np.zeros(len(pixels), np.int64))
    assert abs(np.corrcoef(first[:-1, 0], first[1:, 0])[0, 1]) < 0.02
    other_seed = rng.sobol_2d(1, 0, rng.STREAM_FILM, pixels, np.zeros(len(pixels), np.int64))
    assert abs(np.corrcoef(first[:, 0], other_seed[:, 0])[0, 1]) < 0.02
    with pytest.raises(ValueError, match="Sobol index"):
        rng.sobol_2d(0, 0, rng.STREAM_FILM, np.zeros(1, np.int64), np.array([-1]))
