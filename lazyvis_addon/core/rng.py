"""Counter-based random numbers: a pure function of (seed, frame, stream, global pixel, index).

Every random number the core draws is a hash of its coordinates rather than the next value of a
sequential generator, so a border or tile renders exactly the pixels of the full frame, batches can be
processed in any order, and the same seed gives the same image.
"""

from __future__ import annotations

import numpy as np

# Streams keep unrelated uses of the same pixel independent.
STREAM_SHADOW_RAYS = 1
STREAM_REDUCED_MC = 2
STREAM_STANDARD_MC = 3
STREAM_VERIFY = 4
STREAM_FILM = 5
STREAM_GLOSSY_MC = 6
STREAM_SEEN_LIGHTS = 7

_MASK64 = np.uint64(0xFFFFFFFFFFFFFFFF)


def _mix64(x: np.ndarray) -> np.ndarray:
    """SplitMix64 / MurmurHash3 finaliser on uint64 arrays (wrapping arithmetic is intended)."""
    x = x ^ (x >> np.uint64(30))
    x = x * np.uint64(0xBF58476D1CE4E5B9)
    x = x ^ (x >> np.uint64(27))
    x = x * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


def uniforms(seed: int, frame: int, stream: int, pixel: np.ndarray, index: np.ndarray, dims: int) -> np.ndarray:
    """Uniform numbers in [0, 1), shape (N, dims) float64.

    Parameters
    ----------
    seed, frame, stream : int
        Global identifiers mixed into every number.
    pixel : (N,) int64
        Global pixel index in the full frame (``y * width + x``), never a window-local index.
    index : (N,) int64
        Which number of this pixel (for instance ``light * samples + sample``).
    dims : int
        Uniforms per entry.
    """
    with np.errstate(over="ignore"):
        base = _mix64(np.uint64(seed & 0xFFFFFFFF) * np.uint64(0x9E3779B97F4A7C15)
                      + np.uint64(((frame & 0xFFFFFF) << 8) | (stream & 0xFF)))
        key = _mix64(np.asarray(pixel, dtype=np.int64).astype(np.uint64) ^ base)
        key = _mix64(key + np.asarray(index, dtype=np.int64).astype(np.uint64) * np.uint64(0xD1B54A32D192ED03))
        lanes = key[:, None] + np.arange(1, dims + 1, dtype=np.uint64)[None, :] * np.uint64(0x9E3779B97F4A7C15)
        bits = _mix64(lanes) >> np.uint64(11)
    return bits.astype(np.float64) * (1.0 / 9007199254740992.0)


def stratified_2d(u: np.ndarray, sample: np.ndarray, count: int) -> np.ndarray:
    """Jitter (N, 2) uniforms into stratum ``sample`` of ``count`` strata over the unit square.

    With a square ``count`` the strata form a sqrt(count) grid; otherwise the first dimension is split
    into ``count`` intervals. The spherical-triangle map is area preserving, so strata of the unit square
    are strata of the light's solid angle.
    """
    sample = np.asarray(sample, dtype=np.int64)
    side = int(round(np.sqrt(count)))
    out = np.empty_like(u)
    if side * side == count:
        out[:, 0] = (sample % side + u[:, 0]) / side
        out[:, 1] = (sample // side + u[:, 1]) / side
    else:
        out[:, 0] = (sample + u[:, 0]) / count
        out[:, 1] = u[:, 1]
    return out


def _reverse_bits32(x: np.ndarray) -> np.ndarray:
    """Bit reversal of uint32 arrays."""
    x = ((x >> np.uint32(1)) & np.uint32(0x55555555)) | ((x & np.uint32(0x55555555)) << np.uint32(1))
    x = ((x >> np.uint32(2)) & np.uint32(0x33333333)) | ((x & np.uint32(0x33333333)) << np.uint32(2))
    x = ((x >> np.uint32(4)) & np.uint32(0x0F0F0F0F)) | ((x & np.uint32(0x0F0F0F0F)) << np.uint32(4))
    x = ((x >> np.uint32(8)) & np.uint32(0x00FF00FF)) | ((x & np.uint32(0x00FF00FF)) << np.uint32(8))
    return (x >> np.uint32(16)) | (x << np.uint32(16))


def _owen_scramble(x: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """Hash-based nested uniform (Owen) scrambling of 32-bit fixed-point values (Burley 2020, after
    Laine and Karras): each bit is flipped by a hash of the bits above it, so strata map to strata."""
    x = _reverse_bits32(x)
    with np.errstate(over="ignore"):
        x = x + seed
        x = x ^ (x * np.uint32(0x6C50B47C))
        x = x ^ (x * np.uint32(0xB82F1E52))
        x = x ^ (x * np.uint32(0xC7AFE638))
        x = x ^ (x * np.uint32(0x8D22F6E6))
    return _reverse_bits32(x)


def sobol_2d(seed: int, frame: int, stream: int, pixel: np.ndarray, index: np.ndarray) -> np.ndarray:
    """Points ``index`` of the first two dimensions of Sobol's (0, 2)-sequence, Owen-scrambled per pixel.

    The first 2^m points of a pixel fall one in each cell of every 2^a x 2^b grid with a + b = m (its
    strata of all shapes, not only squares), any count of points is well spread, and a later batch
    continues the same sequence. Scrambling makes each point uniform on [0, 1)^2 and pixels independent.

    Parameters
    ----------
    pixel : (N,) int64   global pixel index (as for ``uniforms``); index : (N,) int64 point of that pixel.

    Returns
    -------
    (N, 2) float64 in [0, 1).
    """
    index = np.asarray(index, dtype=np.int64)
    if len(index) and (index.min() < 0 or index.max() >= 2 ** 32):
        raise ValueError("Sobol index out of range")
    i = index.astype(np.uint32)
    first = _reverse_bits32(i)  # van der Corput: the generator matrix is the identity
    second = np.zeros_like(i)
    direction = np.uint32(0x80000000)
    for bit in range(int(index.max()).bit_length() if len(index) else 0):  # bits of the index: a handful
        second ^= np.where((i >> np.uint32(bit)) & np.uint32(1), direction, np.uint32(0))
        direction = np.uint32(direction ^ (direction >> np.uint32(1)))  # Pascal's triangle mod 2
    keys = (uniforms(seed, frame, stream, pixel, np.zeros_like(index), 2) * 2.0 ** 32).astype(np.uint32)
    points = np.stack([_owen_scramble(first, keys[:, 0]), _owen_scramble(second, keys[:, 1])], axis=1)
    return points.astype(np.float64) * (1.0 / 2.0 ** 32)
