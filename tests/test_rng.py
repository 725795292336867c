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


# The numpy formulas the compiled kernels replaced, kept as the definition the kernels must match bit for
# bit (renders and stored references depend on every number).
def _mix64_reference(x: np.ndarray) -> np.ndarray:
    """SplitMix64 / MurmurHash3 finaliser on uint64 arrays (wrapping arithmetic is intended)."""
    x = x ^ (x >> np.uint64(30))
    x = x * np.uint64(0xBF58476D1CE4E5B9)
    x = x ^ (x >> np.uint64(27))
    x = x * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


def uniforms_reference(seed: int, frame: int, stream: int, pixel: np.ndarray, index: np.ndarray, dims: int) -> np.ndarray:
    """``rng.uniforms``, as numpy passes."""
    with np.errstate(over="ignore"):
        base = _mix64_reference(np.uint64(seed & 0xFFFFFFFF) * np.uint64(0x9E3779B97F4A7C15)
                      + np.uint64(((frame & 0xFFFFFF) << 8) | (stream & 0xFF)))
        key = _mix64_reference(np.asarray(pixel, dtype=np.int64).astype(np.uint64) ^ base)
        key = _mix64_reference(key + np.asarray(index, dtype=np.int64).astype(np.uint64) * np.uint64(0xD1B54A32D192ED03))
        lanes = key[:, None] + np.arange(1, dims + 1, dtype=np.uint64)[None, :] * np.uint64(0x9E3779B97F4A7C15)
        bits = _mix64_reference(lanes) >> np.uint64(11)
    return bits.astype(np.float64) * (1.0 / 9007199254740992.0)


def _reverse_bits32_reference(x: np.ndarray) -> np.ndarray:
    """Bit reversal of uint32 arrays."""
    x = ((x >> np.uint32(1)) & np.uint32(0x55555555)) | ((x & np.uint32(0x55555555)) << np.uint32(1))
    x = ((x >> np.uint32(2)) & np.uint32(0x33333333)) | ((x & np.uint32(0x33333333)) << np.uint32(2))
    x = ((x >> np.uint32(4)) & np.uint32(0x0F0F0F0F)) | ((x & np.uint32(0x0F0F0F0F)) << np.uint32(4))
    x = ((x >> np.uint32(8)) & np.uint32(0x00FF00FF)) | ((x & np.uint32(0x00FF00FF)) << np.uint32(8))
    return (x >> np.uint32(16)) | (x << np.uint32(16))


def _owen_scramble_reference(x: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """Hash-based nested uniform (Owen) scrambling of 32-bit fixed-point values (Burley 2020, after
    Laine and Karras): each bit is flipped by a hash of the bits above it, so strata map to strata."""
    x = _reverse_bits32_reference(x)
    with np.errstate(over="ignore"):
        x = x + seed
        x = x ^ (x * np.uint32(0x6C50B47C))
        x = x ^ (x * np.uint32(0xB82F1E52))
        x = x ^ (x * np.uint32(0xC7AFE638))
        x = x ^ (x * np.uint32(0x8D22F6E6))
    return _reverse_bits32_reference(x)


def sobol_2d_reference(seed: int, frame: int, stream: int, pixel: np.ndarray, index: np.ndarray) -> np.ndarray:
    """``rng.sobol_2d``, as numpy passes."""
    index = np.asarray(index, dtype=np.int64)
    if len(index) and (index.min() < 0 or index.max() >= 2 ** 32):
        raise ValueError("Sobol index out of range")
    i = index.astype(np.uint32)
    first = _reverse_bits32_reference(i)  # van der Corput: the generator matrix is the identity
    second = np.zeros_like(i)
    direction = np.uint32(0x80000000)
    for bit in range(int(index.max()).bit_length() if len(index) else 0):  # bits of the index: a handful
        second ^= np.where((i >> np.uint32(bit)) & np.uint32(1), direction, np.uint32(0))
        direction = np.uint32(direction ^ (direction >> np.uint32(1)))  # Pascal's triangle mod 2
    keys = (uniforms_reference(seed, frame, stream, pixel, np.zeros_like(index), 2) * 2.0 ** 32).astype(np.uint32)
    points = np.stack([_owen_scramble_reference(first, keys[:, 0]), _owen_scramble_reference(second, keys[:, 1])], axis=1)
    return points.astype(np.float64) * (1.0 / 2.0 ** 32)


def test_compiled_numbers_equal_the_numpy_definition_bit_for_bit():
    """``rng.uniforms`` and ``rng.sobol_2d`` (compiled) give exactly the numbers of their numpy definition
    above, for seeds, frames and streams beyond their masks, pixels up to 2^40, indices up to 2^32 - 1,
    several widths, and a scalar pixel broadcast against indices."""
    r = np.random.default_rng(3)
    pixels = r.integers(0, 2 ** 40, 20_000)
    indices = r.integers(0, 2 ** 20, 20_000)
    for seed, frame, stream in [(0, 0, rng.STREAM_FILM), (1, 2, 3), (2 ** 33 + 5, 2 ** 25, 300)]:
        for dims in (1, 2, 5):
            np.testing.assert_array_equal(rng.uniforms(seed, frame, stream, pixels, indices, dims),
                                          uniforms_reference(seed, frame, stream, pixels, indices, dims))
        for index in (indices, np.arange(20_000), np.full(20_000, 2 ** 32 - 1)):
            np.testing.assert_array_equal(rng.sobol_2d(seed, frame, stream, pixels, index),
                                          sobol_2d_reference(seed, frame, stream, pixels, index))
    np.testing.assert_array_equal(rng.uniforms(1, 2, 3, np.int64(5), np.arange(10), 2),
                                  uniforms_reference(1, 2, 3, np.int64(5), np.arange(10), 2))
    assert rng.uniforms(0, 0, 0, np.zeros(0, np.int64), np.zeros(0, np.int64), 3).shape == (0, 3)
