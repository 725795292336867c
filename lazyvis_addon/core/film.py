"""The pixel filter, built and sampled the way Cycles does it.

Cycles does not weight samples by the filter: it importance-samples it. Every camera sample of pixel (x, y)
goes through raster position ``(x + T(u0), y + T(u1))``, where ``(u0, u1)`` is the sample's canonical
uniform pair and ``T`` a 1024-entry inverse-CDF table of the 1D filter, read with linear interpolation; the
pixel is the plain average of its samples. The 2D filter is therefore the separable product
``f(dx) f(dy)``, not a radial one.

What Cycles' source says (blender/blender, intern/cycles):

- ``scene/film.cpp`` ``filter_func_blackman_harris(v, width)``: the 4-term Blackman-Harris window
  ``0.35875 - 0.48829 cos(p) + 0.14128 cos(2p) - 0.01168 cos(3p)``, ``p = 2 pi (v / width + 1/2)``;
  ``filter_table()`` calls it with ``width = 2 * filter_width``, so the window spans
  ``[-filter_width, +filter_width]``: **Blender's ``filter_width`` is the radius** (1.5 px by default,
  support 3 px). (Gaussian: ``width *= 3`` and ``exp(-2 (6 v / width)^2)``, i.e. sigma = filter_width / 4,
  truncated at 1.5 filter_width; box: Blender forces filter_width = 1, a uniform offset in the pixel.)
- ``util/math_cdf.h`` / ``math_cdf.cpp``: ``util_cdf_inverted(1024, 0, width / 2, f, make_symmetric=true)``
  tabulates f at 1023 points ``x_i = (width / 2) i / 1022`` (i = 0..1022), accumulates a left Riemann sum
  into a 1024-entry CDF, and inverts it on 512 equally spaced levels ``c_i = i / 511`` with
  ``upper_bound``; entry ``511 +- i`` gets ``0.5 +- x(c_i)``. Entry 1023 is never written and stays 0.
- ``kernel/util/lookup_table.h`` ``lookup_table_read``: ``x = clamp(u, 0, 1) * 1023``, linear
  interpolation between entries ``floor(x)`` and ``floor(x) + 1``; ``kernel/camera/camera.h``
  ``camera_sample``: ``raster = (x + T(u0), y + T(u1))``.

Consequences, both measured on Blender 5.0.1 (tests/test_film.py): offsets are relative to the pixel's
lower-left corner (0.5 is the centre), and the 1/1023 of samples whose ``u`` falls past entry 1022
interpolate towards the stray 0 entry, landing uniformly in ``[0, 0.5 + filter_width]``: a tiny pull
towards the pixel's left and **bottom** edges (Cycles' raster y grows upwards). ``filter_offsets``
reproduces both, converting y to LazyVis' top-down pixel convention.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

# Entries in Cycles' filter table (FILTER_TABLE_SIZE in kernel/types.h).
CYCLES_TABLE_SIZE = 1024

# Blender's ``scene.cycles.pixel_filter_type`` identifiers.
FILTER_TYPES = ("BLACKMAN_HARRIS", "GAUSSIAN", "BOX")

# 4-term Blackman-Harris coefficients, as in Cycles.
_BH = (0.35875, 0.48829, 0.14128, 0.01168)


def blackman_harris(x, width: float) -> np.ndarray:
    """Cycles' Blackman-Harris pixel filter, unnormalised (1 at the pixel centre).

    Parameters
    ----------
    x : (...) float64    offset from the pixel centre along one axis (pixels).
    width : float        Blender's ``filter_width`` (pixels): the filter's radius; support [-width, width].

    Returns
    -------
    (...) float64 weights, 0 outside the support (the window is ~6e-5 at its ends).
    """
    x = np.asarray(x, dtype=np.float64)
    phase = np.pi * x / width + np.pi  # 2 pi (x / (2 width) + 1/2)
    a0, a1, a2, a3 = _BH
    value = a0 - a1 * np.cos(phase) + a2 * np.cos(2.0 * phase) - a3 * np.cos(3.0 * phase)
    return np.where(np.abs(x) <= width, value, 0.0)


def filter_function(x, width: float, filter_type: str = "BLACKMAN_HARRIS") -> np.ndarray:
    """One axis of Cycles' pixel filter of any type, unnormalised (1 at the pixel centre).

    x : (...) float64 offset from the pixel centre (pixels); width : Blender's ``filter_width``.
    Returns (...) float64 weights, 0 outside the support Cycles tabulates: [-w, w] with w = width
    (Blackman-Harris), 1.5 width (Gaussian, sigma = width / 4) or width / 2 (box).
    """
    x = np.asarray(x, dtype=np.float64)
    extent = half_extent(width, filter_type)
    if filter_type == "BLACKMAN_HARRIS":
        return blackman_harris(x, width)
    if filter_type == "GAUSSIAN":
        value = np.exp(-2.0 * (6.0 * x / (3.0 * width)) ** 2)
    else:
        value = np.ones_like(x)
    return np.where(np.abs(x) <= extent, value, 0.0)


def half_extent(width: float, filter_type: str) -> float:
    """Half the support Cycles tabulates for a filter (pixels)."""
    if not width > 0.0:
        raise ValueError(f"filter width must be positive, got {width}")
    if filter_type == "BLACKMAN_HARRIS":
        return width
    if filter_type == "GAUSSIAN":
        return 1.5 * width
    if filter_type == "BOX":
        return 0.5 * width
    raise ValueError(f"unknown filter type {filter_type!r}; expected one of {FILTER_TYPES}")


def filter_table(width: float, filter_type: str = "BLACKMAN_HARRIS", size: int = CYCLES_TABLE_SIZE) -> np.ndarray:
    """Cycles' inverse-CDF table of the 1D pixel filter (re-derived, float64 where Cycles uses float32).

    Parameters
    ----------
    width : float         Blender's ``filter_width`` (pixels).
    filter_type : str     one of FILTER_TYPES (Blender forces width 1 for BOX; pass 1.0 to match).
    size : int            table entries (Cycles: 1024).

    Returns
    -------
    (size,) float64, read-only: sub-pixel positions (pixels, 0.5 = centre) at equally spaced quantiles,
    symmetric about entry (size - 1) // 2; for even ``size`` the last entry is 0, as in Cycles.
    """
    return _table(float(width), filter_type, int(size))


@lru_cache(maxsize=16)
def _table(width: float, filter_type: str, size: int) -> np.ndarray:
    extent = half_extent(width, filter_type)
    # CDF of |f| over [0, extent] from size - 1 samples (left Riemann sum), size entries, normalised.
    samples = extent * np.arange(size - 1) / (size - 2)
    cdf = np.concatenate([[0.0], np.cumsum(np.abs(filter_function(samples, width, filter_type)))])
    cdf /= cdf[-1]
    # Symmetric inversion at levels i / half, i = 0..half, with upper_bound as in util_cdf_invert.
    half = (size - 1) // 2
    levels = np.arange(half + 1) / half
    index = np.searchsorted(cdf, levels, side="right")
    inside = index < size - 1
    safe = np.minimum(index, size - 2)
    t = np.where(inside, (levels - cdf[safe]) / (cdf[safe + 1] - cdf[safe]), 0.0)
    index = np.where(inside, index, size - 1)
    reach = (index + t) / (size - 1) * (2.0 * extent)
    table = np.zeros(size)
    table[half + np.arange(half + 1)] = 0.5 * (1.0 + reach)
    table[half - np.arange(half + 1)] = 0.5 * (1.0 - reach)
    table.setflags(write=False)
    return table


def read_table(table: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Cycles' ``lookup_table_read``: (N,) uniforms in [0, 1] -> (N,) float64 linearly interpolated entries."""
    size = len(table)
    x = np.clip(np.asarray(u, dtype=np.float64), 0.0, 1.0) * (size - 1)
    index = np.minimum(np.floor(x).astype(np.int64), size - 1)
    t = x - index
    following = np.minimum(index + 1, size - 1)
    return (1.0 - t) * table[index] + t * table[following]


def filter_offsets(u: np.ndarray, width: float, filter_type: str = "BLACKMAN_HARRIS") -> np.ndarray:
    """Sub-pixel positions of camera samples, distributed like Cycles' pixel filter.

    Parameters
    ----------
    u : (N, 2) float64        canonical uniforms in [0, 1)^2 (one pair per camera sample).
    width : float             Blender's ``filter_width`` (pixels; the filter's radius).
    filter_type : str         one of FILTER_TYPES.

    Returns
    -------
    (N, 2) float64 positions inside the pixel measured from its **top-left** corner (x right, y down), the
    ``offset`` of ``camera.camera_rays``: the centre is (0.5, 0.5); values span [0.5 - w, 0.5 + w] with w
    the filter's half extent, so they leave [0, 1) when w > 0.5 (the ray goes through a neighbour's
    area, as in Cycles). The pixel's value is the plain mean of its samples' radiance.
    """
    u = np.asarray(u, dtype=np.float64)
    table = filter_table(width, filter_type)
    x = read_table(table, u[:, 0])
    y = 1.0 - read_table(table, u[:, 1])  # Cycles' raster y grows upwards; LazyVis' pixel y grows down.
    return np.stack([x, y], axis=1)


def offset_density(t, width: float, filter_type: str = "BLACKMAN_HARRIS") -> np.ndarray:
    """Probability density of one coordinate of ``filter_offsets`` as Cycles' table read produces it.

    Each of the table's first ``size - 2`` intervals holds 1 / (size - 1) of the uniforms and spreads them
    evenly between its two entries; the last one runs from the last real entry down to the stray 0 entry.
    This is the exact density of the x offset; the y offset ``1 - T(u)`` has density ``offset_density(1 - t)``.

    Parameters
    ----------
    t : (...) float64    position inside the pixel measured from its left edge (pixels; 0.5 = centre).
    width, filter_type : as for ``filter_offsets``.

    Returns
    -------
    (...) float64 density per pixel (integrates to 1 over t); 0 outside the filter's support.
    """
    table = filter_table(width, filter_type)
    size = len(table)
    knots = table[:size - 1]
    t = np.asarray(t, dtype=np.float64)
    interval = np.searchsorted(knots, t, side="right") - 1
    regular = (interval >= 0) & (interval < size - 2)
    safe = np.clip(interval, 0, size - 3)
    span = knots[safe + 1] - knots[safe]
    mass = 1.0 / (size - 1)
    density = np.where(regular & (span > 0.0), mass / np.where(span > 0.0, span, 1.0), 0.0)
    stray_end = knots[-1]  # the last interval reads from this entry towards the stray 0
    return density + np.where((t >= 0.0) & (t <= stray_end), mass / stray_end, 0.0)
