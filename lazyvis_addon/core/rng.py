"""Counter-based random numbers: a pure function of (seed, frame, stream, global pixel, index).

Every random number the core draws is a hash of its coordinates rather than the next value of a
sequential generator, so a border or tile renders exactly the pixels of the full frame, batches can be
processed in any order, and the same seed gives the same image.
"""

from __future__ import annotations

import numpy as np
from numba import njit

# Streams keep unrelated uses of the same pixel independent.
STREAM_SHADOW_RAYS = 1
STREAM_REDUCED_MC = 2
STREAM_STANDARD_MC = 3
STREAM_VERIFY = 4
STREAM_FILM = 5
STREAM_GLOSSY_MC = 6
STREAM_SEEN_LIGHTS = 7

_MASK32 = 0xFFFFFFFF


def _base_key(seed: int, frame: int, stream: int) -> np.uint64:
    """The part of every key that (seed, frame, stream) give."""
    # (a compiled function returns a uint64 as a Python int: typed again, the kernels take it as uint64)
    return np.uint64(_base(np.uint64(seed & 0xFFFFFFFF), np.uint64(((frame & 0xFFFFFF) << 8) | (stream & 0xFF))))


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

    Compiled: as numpy passes (four hashes of (N, dims) uint64 temporaries) the anti-aliasing samples' and
    coverage rays' numbers were a tenth of anti-aliasing's time on a textured frame.
    """
    pixel, index = np.broadcast_arrays(np.asarray(pixel, dtype=np.int64), np.asarray(index, dtype=np.int64))
    out = np.empty((pixel.size, dims))
    _uniforms(_base_key(seed, frame, stream), np.ascontiguousarray(pixel.ravel()), np.ascontiguousarray(index.ravel()),
              out)
    return out


@njit(cache=True, nogil=True, inline="always")
def _mix(x):
    """SplitMix64 / MurmurHash3 finaliser of one uint64 (wrapping arithmetic is intended)."""
    x = x ^ (x >> np.uint64(30))
    x = x * np.uint64(0xBF58476D1CE4E5B9)
    x = x ^ (x >> np.uint64(27))
    x = x * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


@njit(cache=True, nogil=True)
def _base(seed, tag):
    return _mix(seed * np.uint64(0x9E3779B97F4A7C15) + tag)


@njit(cache=True, nogil=True, inline="always")
def _key(base, pixel, index):
    key = _mix(np.uint64(pixel) ^ base)
    return _mix(key + np.uint64(index) * np.uint64(0xD1B54A32D192ED03))


@njit(cache=True, nogil=True, inline="always")
def _lane(key, d):
    """Uniform d of a key: 53 bits of its hash, in [0, 1)."""
    bits = _mix(key + np.uint64(d + 1) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(11)
    return np.float64(bits) * (1.0 / 9007199254740992.0)


@njit(cache=True, nogil=True)
def _uniforms(base, pixel, index, out):
    for i in range(out.shape[0]):
        key = _key(base, pixel[i], index[i])
        for d in range(out.shape[1]):
            out[i, d] = _lane(key, d)


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


@njit(cache=True, nogil=True, inline="always")
def _reverse_bits32(x):
    """Bit reversal of 32-bit values held in uint64."""
    x = ((x >> 1) & 0x55555555) | ((x & 0x55555555) << 1)
    x = ((x >> 2) & 0x33333333) | ((x & 0x33333333) << 2)
    x = ((x >> 4) & 0x0F0F0F0F) | ((x & 0x0F0F0F0F) << 4)
    x = ((x >> 8) & 0x00FF00FF) | ((x & 0x00FF00FF) << 8)
    return ((x >> 16) | (x << 16)) & _MASK32


@njit(cache=True, nogil=True, inline="always")
def _owen_scramble(x, seed):
    """Hash-based nested uniform (Owen) scrambling of a 32-bit fixed-point value (Burley 2020, after
    Laine and Karras): each bit is flipped by a hash of the bits above it, so strata map to strata.
    Arithmetic modulo 2^32 in uint64."""
    x = _reverse_bits32(x)
    x = (x + seed) & _MASK32
    x = x ^ ((x * 0x6C50B47C) & _MASK32)
    x = x ^ ((x * 0xB82F1E52) & _MASK32)
    x = x ^ ((x * 0xC7AFE638) & _MASK32)
    x = x ^ ((x * 0x8D22F6E6) & _MASK32)
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
    pixel, index = np.broadcast_arrays(np.asarray(pixel, dtype=np.int64), np.asarray(index, dtype=np.int64))
    if index.size and (index.min() < 0 or index.max() >= 2 ** 32):
        raise ValueError("Sobol index out of range")
    out = np.empty((index.size, 2))
    _sobol_2d(_base_key(seed, frame, stream), np.ascontiguousarray(pixel.ravel()), np.ascontiguousarray(index.ravel()),
              out)
    return out


@njit(cache=True, nogil=True)
def _sobol_2d(base, pixel, index, out):
    for n in range(len(index)):
        i = np.uint64(index[n])
        first = _reverse_bits32(i)  # van der Corput: the generator matrix is the identity
        second = np.uint64(0)
        direction = np.uint64(0x80000000)
        rest = i
        while rest:  # bits of the index: a handful
            if rest & np.uint64(1):
                second ^= direction
            direction = direction ^ (direction >> np.uint64(1))  # Pascal's triangle mod 2
            rest >>= np.uint64(1)
        # The scrambling seeds: the pixel's uniforms of index 0, as 32-bit fixed point.
        key = _key(base, pixel[n], 0)
        seed_first = np.uint64(_lane(key, 0) * 4294967296.0)
        seed_second = np.uint64(_lane(key, 1) * 4294967296.0)
        out[n, 0] = np.float64(_owen_scramble(first, seed_first)) * (1.0 / 4294967296.0)
        out[n, 1] = np.float64(_owen_scramble(second, seed_second)) * (1.0 / 4294967296.0)


def compile_rng() -> tuple:
    """Compile the kernels (or load them from Numba's cache); returns them."""
    uniforms(0, 0, 0, np.zeros(1, np.int64), np.zeros(1, np.int64), 2)
    sobol_2d(0, 0, 0, np.zeros(1, np.int64), np.zeros(1, np.int64))
    return _base, _uniforms, _sobol_2d
