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
