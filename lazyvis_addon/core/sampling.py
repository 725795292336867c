"""Directions towards triangle and convex polygon lights, sampled uniformly in solid angle.

Every vector here points from the shading point to a light vertex and is expressed in world units
(metres; only ratios matter, so any consistent unit works). Solid angles are in steradians (sr) and
densities are per steradian. Arrays are float64 and every function works on N independent rows at once.

Triangles are sampled with Arvo's area-preserving map ("Stratified sampling of spherical triangles",
SIGGRAPH 1995): the unit square maps onto the spherical triangle with constant Jacobian, so uniform
(or stratified) points of the square become uniform (or stratified) directions. Triangles too small for
that map to be evaluated accurately fall back to uniform sampling of the planar triangle by area, whose
solid-angle density is returned exactly, so estimators ``f(direction) / pdf`` stay unbiased either way.
"""

from __future__ import annotations

import numpy as np

MIN_SPHERICAL_SOLID_ANGLE = 1e-9
"""Solid angle (sr) below which a triangle is sampled by area instead of with Arvo's map.

Why 1e-9 sr: in any spherical triangle each angle exceeds half the solid angle (beta + gamma < pi +
alpha, so Omega = alpha + beta + gamma - pi < 2 alpha). The map's inputs (normalised vertices,
angles from cross products) carry absolute errors of a few float64 epsilons (eps = 1.1e-16), so its
error relative to the triangle grows like eps / Omega.
Measured against an 80-bit long-double evaluation of the same map, the worst error in the sample's
areal coordinates is ~1e-8 just above 1e-9 sr (needle-like slivers with aspect ratio 1e6), ~4e-6 at
1e-12 sr and ~1e-4 at 1e-15 sr; 1e-9 sr keeps every triangle far below Monte Carlo noise. Below it, a
well-shaped triangle is less than ~5e-5 rad across, so the solid-angle density of area sampling is
constant across it to ~1e-4 and the fallback costs no variance; for a sliver it may cost some variance
but never bias, because the fallback returns its exact density.
"""

_ONE_MINUS_EPSILON = np.nextafter(1.0, 0.0)


def _dot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Row-wise dot product of (..., 3) arrays, shape (...)."""
    return np.einsum("...i,...i->...", x, y)


def _length(x: np.ndarray) -> np.ndarray:
    """Row-wise Euclidean length of (..., 3) arrays, shape (...)."""
    return np.sqrt(_dot(x, x))


def _normalize_or_zero(x: np.ndarray) -> np.ndarray:
    """Unit vectors along the rows of ``x`` (..., 3); zero rows stay zero instead of becoming NaN."""
    length = _length(x)
    return x / np.where(length > 0.0, length, 1.0)[..., None]


def _tangent_towards(target_offset: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """Unit tangent at the unit vector ``origin`` (N, 3) along the great circle towards ``origin + target_offset``.

    Gram-Schmidt on the offset ``target - origin`` rather than on ``target`` itself: the offset is
    small but exact to relative precision when the two points are close, whereas ``target - (target .
    origin) origin`` would cancel catastrophically. (Removing the component along ``origin`` gives the
    same vector either way, because the two inputs differ by a multiple of ``origin``.)
    """
    return _normalize_or_zero(target_offset - _dot(target_offset, origin)[:, None] * origin)


def _as_rows(name: str, value, width: int) -> np.ndarray:
    array = np.asarray(value, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != width:
        raise ValueError(f"{name} must have shape (N, {width}), got {array.shape}")
    return array


def _triple_product(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """a . (b x c) for (N, 3) rows, evaluated as a . ((b - a) x (c - a)) (the same value, since the
    added terms are multiples of a . (a x .) = 0). The edge vectors stay accurate for small or distant
    triangles, where b x c of two nearly parallel vectors would lose most of its digits."""
    return _dot(a, np.cross(b - a, c - a))


def spherical_triangle_solid_angle(a, b, c) -> np.ndarray:
    """Solid angle subtended by triangles at the origin (the shading point).

    Parameters
    ----------
    a, b, c : (N, 3) float64
        Vectors from the shading point to the three vertices, any length, either winding.

    Returns
    -------
    (N,) float64
        Solid angle in sr, in [0, 2 pi). Exactly 0 for degenerate rows (collinear vertices, a vertex
        at the shading point, or the shading point in the triangle's plane), never NaN for finite input.

    Van Oosterom and Strackee (1983): tan(Omega / 2) = |a . (b x c)| / (|a||b||c| + (a . b)|c|
    + (a . c)|b| + (b . c)|a|); atan2 picks the right branch when the denominator is negative
    (Omega > pi).
    """
    a, b, c = (_as_rows(name, v, 3) for name, v in (("a", a), ("b", b), ("c", c)))
    triple = _triple_product(a, b, c)
    length_a, length_b, length_c = _length(a), _length(b), _length(c)
    denominator = (length_a * length_b * length_c + _dot(a, b) * length_c
                   + _dot(a, c) * length_b + _dot(b, c) * length_a)
    solid_angle = 2.0 * np.arctan2(np.abs(triple), denominator)
    # A zero triple product means the shading point lies in the triangle's plane: the triangle is seen
    # edge-on and covers no solid angle, although atan2(0, negative) would report 2 pi for points
    # inside it.
    return np.where(triple != 0.0, solid_angle, 0.0)


def _arvo_directions(unit_a: np.ndarray, unit_b: np.ndarray, unit_c: np.ndarray,
                     u: np.ndarray, solid_angle: np.ndarray) -> np.ndarray:
    """Arvo's area-preserving map from the unit square to the spherical triangle ABC.

    Parameters
    ----------
    unit_a, unit_b, unit_c : (M, 3) float64
        Unit vertex directions of non-degenerate triangles.
    u : (M, 2) float64
        Points of [0, 1)^2.
    solid_angle : (M,) float64
        The triangles' solid angles (sr), from ``spherical_triangle_solid_angle``.

    Returns
    -------
    (M, 3) float64 unit directions.

    Step 1 chooses the point C' on the arc AC such that the sub-triangle ABC' has area
    A' = u0 * Omega. Arvo solves for cos |AC'| from the spherical laws of cosines; for a small
    triangle both the numerator and the denominator of that quotient are differences of nearly equal
    terms, and 1 - cos |AC'| is tiny besides (measured against long double: errors of ~1e-3 of the
    triangle's size at the 99th percentile for Omega ~ 3e-9 sr). Here the same point comes from the
    excess of a triangle given two sides and their included angle,
    tan(E / 2) = tan(b/2) tan(c/2) sin(alpha) / (1 + tan(b/2) tan(c/2) cos(alpha)); solved for side b:
        tan(|AC'| / 2) = sin(A'/2) cos(|AB|/2) / (sin(|AB|/2) sin(alpha - A'/2)).
    Every factor is a product of well-conditioned terms: sin(alpha - A'/2) > 0 because A' <= Omega <
    2 alpha, and the half-arc sines and cosines are half chords |B -+ A| / 2 of unit vectors.

    Step 2 picks the point on the arc BC' at angle theta from B with cos(theta) = 1 - u1 (1 - B . C'),
    which is what makes the map area preserving. Written with half angles it reads
    sin(theta / 2) = sqrt(u1) sin(|BC'| / 2) = sqrt(u1) |C' - B| / 2, again free of cancellation.
    """
    u0, u1 = u[:, 0], u[:, 1]

    # Spherical angle alpha at A is the angle between the planes OAB and OAC, i.e. between their unit
    # normals A x B and A x C. Cross with the edge offsets (A x B = A x (B - A)) to keep digits for
    # small triangles. Sine and cosine come from the normals directly so no acos is needed.
    normal_ab = _normalize_or_zero(np.cross(unit_a, unit_b - unit_a))
    normal_ac = _normalize_or_zero(np.cross(unit_a, unit_c - unit_a))
    cos_alpha = np.clip(_dot(normal_ab, normal_ac), -1.0, 1.0)
    sin_alpha = np.minimum(_length(np.cross(normal_ab, normal_ac)), 1.0)

    half_sub_area = 0.5 * u0 * solid_angle
    sin_half_sub_area, cos_half_sub_area = np.sin(half_sub_area), np.cos(half_sub_area)
    # sin(alpha - A'/2) by the angle-difference identity, from the exact sine and cosine of alpha.
    sin_alpha_minus_half_sub_area = sin_alpha * cos_half_sub_area - cos_alpha * sin_half_sub_area

    half_chord_ab = 0.5 * _length(unit_b - unit_a)       # sin(|AB| / 2)
    half_cochord_ab = 0.5 * _length(unit_b + unit_a)     # cos(|AB| / 2)
    half_arc_ac_sub = np.arctan2(sin_half_sub_area * half_cochord_ab,
                                 half_chord_ab * sin_alpha_minus_half_sub_area)
    # C' must stay on the arc AC; rounding near u0 = 1 (or a nearly degenerate alpha) may overshoot.
    half_arc_ac = np.arctan2(_length(unit_c - unit_a), _length(unit_c + unit_a))
    arc_ac_sub = 2.0 * np.clip(half_arc_ac_sub, 0.0, half_arc_ac)
    tangent_a_to_c = _tangent_towards(unit_c - unit_a, unit_a)
    unit_c_sub = np.cos(arc_ac_sub)[:, None] * unit_a + np.sin(arc_ac_sub)[:, None] * tangent_a_to_c

    sin_half_theta = np.minimum(np.sqrt(u1) * 0.5 * _length(unit_c_sub - unit_b), 1.0)
    theta = 2.0 * np.arcsin(sin_half_theta)
    tangent_b_to_c_sub = _tangent_towards(unit_c_sub - unit_b, unit_b)
    direction = np.cos(theta)[:, None] * unit_b + np.sin(theta)[:, None] * tangent_b_to_c_sub
    return _normalize_or_zero(direction)


def _planar_directions(a: np.ndarray, b: np.ndarray, c: np.ndarray,
                       u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Directions to points sampled uniformly by area on the planar triangle abc, with their exact
    solid-angle density.

    Parameters
    ----------
    a, b, c : (M, 3) float64
        Vectors from the shading point to the vertices (world units).
    u : (M, 2) float64
        Points of [0, 1)^2.

    Returns
    -------
    directions : (M, 3) float64 unit vectors (+Z where the sampled point is the shading point itself).
    pdf : (M,) float64 per sr; 0 where the triangle has zero area or is seen exactly edge-on.

    The square-root warp (barycentrics 1 - sqrt(u0), sqrt(u0)(1 - u1), sqrt(u0) u1) is uniform by area.
    Converting area density 1/area to solid angle divides by dω/dA = |cos θ_light| / r². For any point
    of the plane, r |cos θ_light| = |n̂ . point| is the plane's distance from the shading point,
    |a . (b x c)| / (2 area), so pdf = r² / (area |cos θ_light|) = 2 r³ / |a . (b x c)|.
    """
    root_u0 = np.sqrt(u[:, 0])
    weight_a = 1.0 - root_u0
    weight_b = root_u0 * (1.0 - u[:, 1])
    weight_c = root_u0 * u[:, 1]
    point = weight_a[:, None] * a + weight_b[:, None] * b + weight_c[:, None] * c
    distance = _length(point)
    directions = _normalize_or_zero(point)
    directions[distance == 0.0] = (0.0, 0.0, 1.0)

    triple = np.abs(_triple_product(a, b, c))
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        pdf = 2.0 * distance ** 3 / triple
    # Zero area or an edge-on view: the light subtends no solid angle and no finite density exists;
    # pdf 0 tells the caller to skip the sample (its contribution is zero anyway).
    pdf = np.where((triple > 0.0) & np.isfinite(pdf), pdf, 0.0)
    return directions, pdf


def _sample_triangles(a: np.ndarray, b: np.ndarray, c: np.ndarray, u: np.ndarray,
                      solid_angle: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample triangles whose solid angles (N,) are already known.

    Returns directions (N, 3), pdf (N,) per sr, and uses_arvo (N,) bool: True where the row was
    sampled uniformly in solid angle (pdf = 1 / solid_angle), False where the area fallback was used.
    """
    uses_arvo = solid_angle >= MIN_SPHERICAL_SOLID_ANGLE
    directions = np.empty_like(a)
    pdf = np.empty(len(a), dtype=np.float64)

    rows = np.flatnonzero(uses_arvo)
    if rows.size:
        unit_a, unit_b, unit_c = (_normalize_or_zero(v[rows]) for v in (a, b, c))
        directions[rows] = _arvo_directions(unit_a, unit_b, unit_c, u[rows], solid_angle[rows])
        pdf[rows] = 1.0 / solid_angle[rows]

    rows = np.flatnonzero(~uses_arvo)
    if rows.size:
        directions[rows], pdf[rows] = _planar_directions(a[rows], b[rows], c[rows], u[rows])
    return directions, pdf, uses_arvo


def sample_spherical_triangle(a, b, c, u) -> tuple[np.ndarray, np.ndarray]:
    """Sample directions uniformly in the solid angle of triangles.

    Parameters
    ----------
    a, b, c : (N, 3) float64
        Vectors from the shading point to the vertices (world units, any length, either winding).
    u : (N, 2) float64
        Canonical uniforms in [0, 1). The map is area preserving and continuous, so stratified ``u``
        gives stratified directions.

    Returns
    -------
    directions : (N, 3) float64
        Unit vectors inside the triangle's cone.
    pdf : (N,) float64
        Density of each returned direction per sr: 1 / Omega where Arvo's map is used; for triangles
        below ``MIN_SPHERICAL_SOLID_ANGLE`` (area sampling) the exact solid-angle density of that
        direction; 0 only when the triangle subtends no solid angle at all (zero area, or seen exactly
        edge-on), in which case the direction is an arbitrary unit vector to be ignored.
    """
    a, b, c = (_as_rows(name, v, 3) for name, v in (("a", a), ("b", b), ("c", c)))
    u = _as_rows("u", u, 2)
    if not len(a) == len(b) == len(c) == len(u):
        raise ValueError(f"a, b, c and u must have the same length, got {len(a)}, {len(b)}, {len(c)}, {len(u)}")
    directions, pdf, _ = _sample_triangles(a, b, c, u, spherical_triangle_solid_angle(a, b, c))
    return directions, pdf


def _fan(vertices, vertex_count) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Validate a padded polygon batch and return its fan triangles (0, k, k + 1), k = 1 .. V - 2.

    Returns apex (N, 3), first (N, V - 2, 3), second (N, V - 2, 3) and fan_solid_angle (N, V - 2) sr,
    which is 0 for the padding triangles k > count - 2.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    if vertices.ndim != 3 or vertices.shape[2] != 3 or vertices.shape[1] < 3:
        raise ValueError(f"vertices must have shape (N, V, 3) with V >= 3, got {vertices.shape}")
    vertex_count = np.asarray(vertex_count, dtype=np.int64)
    if vertex_count.shape != (len(vertices),):
        raise ValueError(f"vertex_count must have shape ({len(vertices)},), got {vertex_count.shape}")
    count, slots = vertices.shape[:2]
    triangle_count = slots - 2
    apex = vertices[:, 0, :]
    first = vertices[:, 1:-1, :]
    second = vertices[:, 2:, :]
    fan_solid_angle = spherical_triangle_solid_angle(
        np.repeat(apex, triangle_count, axis=0), first.reshape(-1, 3), second.reshape(-1, 3),
    ).reshape(count, triangle_count)
    # Padding repeats the last vertex, which already makes those triangles degenerate; masking by the
    # count also covers callers whose padding is not an exact repeat.
    real = np.arange(1, slots - 1)[None, :] <= (vertex_count[:, None] - 2)
    return apex, first, second, np.where(real, fan_solid_angle, 0.0)


def polygon_solid_angle(vertices, vertex_count) -> np.ndarray:
    """Solid angle (N,) float64 in sr subtended at the origin by convex planar polygons.

    Parameters
    ----------
    vertices : (N, V, 3) float64
        Vertices relative to the shading point, in order around the polygon, padded to V by repeating
        the last vertex.
    vertex_count : (N,) int
        Real vertex count of each polygon (rows with fewer than 3 subtend 0).

    The fan triangles of a convex polygon do not overlap in its plane, and central projection from a
    point off the plane is one-to-one, so their solid angles add up to the polygon's.
    """
    return _fan(vertices, vertex_count)[3].sum(axis=1)


def sample_polygon_solid_angle(vertices, vertex_count, u, repeat: int = 1
                               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample directions uniformly in the solid angle of convex polygons.

    Parameters
    ----------
    vertices : (N, V, 3) float64
        Vertices relative to the shading point (world units), in order around the polygon, padded to V
        by repeating the last vertex.
    vertex_count : (N,) int
        Real vertex count of each polygon.
    u : (N * repeat, 2) float64
        Canonical uniforms in [0, 1); rows i * repeat .. (i + 1) * repeat - 1 sample polygon i.
    repeat : int
        Samples per polygon: the fan's solid angles are computed once and shared.

    Returns
    -------
    directions : (N, 3) float64
        Unit vectors inside the polygon's cone.
    pdf : (N,) float64
        Density of each direction per sr: 1 / solid_angle when the chosen fan triangle is sampled
        uniformly; P(triangle) times that triangle's area-sampling density when it is below
        ``MIN_SPHERICAL_SOLID_ANGLE``; 0 when the polygon subtends no solid angle.
    solid_angle : (N,) float64
        Total solid angle of each polygon in sr.

    The fan triangle (0, k, k + 1) is chosen with probability Omega_k / Omega with ``u[:, 0]``, and
    ``u[:, 0]`` is then rescaled within the chosen triangle's interval of the cumulative distribution
    back to [0, 1). The composite map from the square to the polygon therefore stays area preserving
    and continuous inside each triangle, so stratification of ``u`` carries over to the directions.
    """
    u = _as_rows("u", u, 2)
    apex, first, second, fan_solid_angle = _fan(vertices, vertex_count)
    if repeat > 1:
        apex, first, second, fan_solid_angle = (np.repeat(x, repeat, axis=0)
                                                for x in (apex, first, second, fan_solid_angle))
    if len(u) != len(apex):
        raise ValueError(f"u must have one row per polygon ({len(apex)}), got {len(u)}")
    count, triangle_count = fan_solid_angle.shape
    rows = np.arange(count)

    cumulative = np.cumsum(fan_solid_angle, axis=1)
    solid_angle = cumulative[:, -1]
    target = u[:, 0] * solid_angle
    # The first triangle whose cumulative solid angle exceeds the target; it has Omega_k > 0 because
    # the cumulative sum grows there. u0 * total can round up to total, so clamp to the last triangle
    # that subtends anything.
    chosen = np.count_nonzero(cumulative <= target[:, None], axis=1)
    last_nonzero = triangle_count - 1 - np.argmax(fan_solid_angle[:, ::-1] > 0.0, axis=1)
    chosen = np.minimum(chosen, last_nonzero)

    chosen_solid_angle = fan_solid_angle[rows, chosen]
    # Start of the chosen interval taken from the exclusive cumulative sum itself (not recomputed), so
    # consecutive intervals tile [0, total) without gaps.
    below = np.where(chosen > 0, cumulative[rows, np.maximum(chosen - 1, 0)], 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        remapped = (target - below) / chosen_solid_angle
    remapped = np.clip(np.nan_to_num(remapped, nan=0.0), 0.0, _ONE_MINUS_EPSILON)
    triangle_u = np.column_stack([remapped, u[:, 1]])

    directions, triangle_pdf, uses_arvo = _sample_triangles(
        apex, first[rows, chosen], second[rows, chosen], triangle_u, chosen_solid_angle)
    with np.errstate(divide="ignore", invalid="ignore"):
        pdf = np.where(uses_arvo, 1.0 / solid_angle, chosen_solid_angle / solid_angle * triangle_pdf)
    pdf = np.where(solid_angle > 0.0, pdf, 0.0)
    return directions, pdf, solid_angle
