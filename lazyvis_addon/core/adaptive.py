"""Which pixels need more than their centre sample (Hart, Dutré, Greenberg 1999, section 4.4).

The paper anti-aliases adaptively "in adjacent pixels whose visible points show different polygons with
different surface normals or whose illumination computations based on the first point show sufficiently
different spectral radiance values". ``refine_mask`` marks a pixel when any of its 8 neighbours

- sees another triangle whose normal differs (by more than ``normal_angle``; coplanar triangles of one
  polygon do not count, nor, given shading normals, the triangles of a smooth-shaded mesh; a pixel that
  sees nothing differs from one that sees a surface),
- sees another material, or
- has a radiance that differs by more than ``relative_threshold`` of the larger of the two (largest
  channel difference against the largest channel), ignoring differences below ``radiance_floor``.

Both pixels of a differing pair are marked. Small objects that fall between pixel centres are not seen, as
the paper notes.
"""

from __future__ import annotations

import numpy as np

# Neighbour offsets (row, column) that cover each unordered 8-neighbour pair once.
_HALF_NEIGHBOURHOOD = ((0, 1), (1, -1), (1, 0), (1, 1))


def refine_mask(index_triangle: np.ndarray, material_index: np.ndarray, normal: np.ndarray, radiance: np.ndarray,
                relative_threshold: float = 0.1, normal_angle: float = 1e-3, radiance_floor: float = 0.0
                ) -> np.ndarray:
    """Pixels to anti-alias.

    Parameters
    ----------
    index_triangle : (H, W) int       triangle seen at the pixel centre, -1 for none.
    material_index : (H, W) int       its material (any value where nothing is seen).
    normal : (H, W, 3) float64        unit geometric normal at the centre (0 where nothing is seen); use
                                      face normals, so that smooth shading does not mark every triangle edge.
    radiance : (H, W) or (H, W, C)    radiance computed at the centre (W m^-2 sr^-1).
    relative_threshold : float        relative radiance difference that marks a pair.
    normal_angle : float              normals further apart than this (radians) differ.
    radiance_floor : float            radiance differences below this never mark a pair (noise, black).

    Returns
    -------
    (H, W) bool
    """
    index_triangle = np.asarray(index_triangle)
    height, width = index_triangle.shape
    material_index = np.asarray(material_index)
    normal = np.asarray(normal, dtype=np.float64)
    radiance = np.asarray(radiance, dtype=np.float64).reshape(height, width, -1)
    if material_index.shape != (height, width) or normal.shape != (height, width, 3):
        raise ValueError(f"material_index {material_index.shape} and normal {normal.shape} must match "
                         f"index_triangle {index_triangle.shape} (and have 3 normal components)")
    cos_limit = np.cos(normal_angle)
    seen = index_triangle >= 0
    peak = np.abs(radiance).max(axis=2)
    mask = np.zeros((height, width), dtype=bool)
    for dr, dc in _HALF_NEIGHBOURHOOD:  # four shifted views of the whole image, not a loop over pixels
        a, b = _pair_slices(height, width, dr, dc)
        if a is None:
            continue
        other_polygon = (index_triangle[a] != index_triangle[b]) & (
            (seen[a] != seen[b]) | (np.einsum("...k,...k->...", normal[a], normal[b]) < cos_limit))
        other_material = seen[a] & seen[b] & (material_index[a] != material_index[b])
        difference = np.abs(radiance[a] - radiance[b]).max(axis=2)
        brighter = np.maximum(peak[a], peak[b])
        other_radiance = (difference > relative_threshold * brighter) & (difference > radiance_floor)
        differs = other_polygon | other_material | other_radiance
        mask[a] |= differs
        mask[b] |= differs
    return mask


def close_holes(mask: np.ndarray, min_marked: int = 5) -> np.ndarray:
    """``mask`` (H, W) bool plus every pixel with at least ``min_marked`` of its 8 neighbours marked.

    A pixel whose centre agrees with all its neighbours can still hold what falls between the centres: on
    the chapel, a sliver of light between two slat shadows, black at every centre and at 6% in Cycles, left
    a pixel unmarked inside a ring of marked ones. Neighbours outside the image count as unmarked.
    """
    mask = np.asarray(mask, dtype=bool)
    padded = np.pad(mask, 1).astype(np.int8)
    height, width = mask.shape
    marked = sum(padded[1 + dr:1 + dr + height, 1 + dc:1 + dc + width]  # 8 shifted views, not a pixel loop
                 for dr in (-1, 0, 1) for dc in (-1, 0, 1) if dr or dc)
    return mask | (marked >= min_marked)


def _pair_slices(height: int, width: int, dr: int, dc: int):
    """Slices (a, b) such that pixel a[k] and b[k] are neighbours at offset (dr, dc); (None, None) if empty."""
    if dr >= height or abs(dc) >= width:
        return None, None
    rows_a, rows_b = slice(0, height - dr), slice(dr, height)
    if dc >= 0:
        cols_a, cols_b = slice(0, width - dc), slice(dc, width)
    else:
        cols_a, cols_b = slice(-dc, width), slice(0, width + dc)
    return (rows_a, cols_a), (rows_b, cols_b)
