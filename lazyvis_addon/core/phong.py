"""Phong lobes over polygons with Arvo's irradiance tensors (Arvo, SIGGRAPH 95).

For a convex spherical polygon P (the directions through a planar polygon seen from the receiver) and
unit axes w, v:

- the axial moment τ^n(w) = ∫_P (w·u)^n dω, and
- the double-axis moment ∫_P (w·u)^n (v·u) dω,

both follow from Stokes' theorem on the sphere. With x = w·u, Δ_S x^n = n(n-1) x^(n-2) - n(n+1) x^n and the
outward conormal of edge i being -m_i (m_i = unit normal of the edge's great circle, u_i × u_(i+1)
normalised, for a polygon counter-clockwise about the direction towards it):

    τ^n = [ (n - 1) τ^(n-2) + Σ_i (w·m_i) E_i^(n-1) ] / (n + 1),     τ^0 = Ω (solid angle),
    ∫ x^n (v·u) = [ n (w·v) τ^(n-1) + Σ_i (v·m_i) E_i^n ] / (n + 2)   (divergence of x^n ∇_S (v·u)),

where E_i^k = ∫_0^Θ_i (a cos t + b sin t)^k dt is the edge integral along the arc u(t) = u_i cos t + t_i sin t
(a = w·u_i, b = w·t_i, t_i the unit tangent towards u_(i+1), Θ_i the arc length). With g = a cos t + b sin t,
d/dt (g^(k-1) g') = (k-1) g^(k-2) (a² + b²) - k g^k gives the two-step recurrence

    E^k = [ (k - 1)(a² + b²) E^(k-2) + a^(k-1) b - g(Θ)^(k-1) g'(Θ) ] / k,
    E^0 = Θ,  E^1 = a sin Θ + b (1 - cos Θ).

Numerical range. Both recurrences run forward with contraction factors (k-1)/k (a² + b²) <= 1 and
(n-1)/(n+1) < 1, so rounding errors never grow: the *absolute* error of τ^n and of the double-axis moment
stays near (edges · n_max · 1e-16) sr. Relative accuracy is therefore only lost where the moment itself is
tiny (a lobe far from the polygon, where (w·u)^n underflows towards 0), which is harmless for shading.
Measured against 2-D Gauss–Legendre quadrature (tests/test_phong.py) the normalised Phong integral is
accurate to < 1e-10 absolute for exponents up to 2000; the cost is O(n_max) vectorised steps, so exponents
beyond a few thousand (roughness < ~0.1) are better served by the LTC GGX path (``ltc.py``).
Non-integer exponents are handled by linear interpolation between the two neighbouring integers.
"""

from __future__ import annotations

import numpy as np

from .geometry import clip_convex, cross3
from .sampling import polygon_solid_angle


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...k,...k->...", a, b)


def _normalize_or_zero(x: np.ndarray) -> np.ndarray:
    length = np.sqrt(_dot(x, x))
    return x / np.where(length > 0.0, length, 1.0)[..., None]


def vertex_count_from_padding(points: np.ndarray) -> np.ndarray:
    """Vertex counts (M,) int64 of polygons (M, K, D) padded by repeating their last vertex.

    The count is 1 + the index of the last vertex that differs from its predecessor (at least 1).
    """
    differs = np.any(points[:, 1:] != points[:, :-1], axis=2)
    last = np.where(differs.any(axis=1), points.shape[1] - 1 - np.argmax(differs[:, ::-1], axis=1), 0)
    return (last + 1).astype(np.int64)


def clip_to_half_spaces(points: np.ndarray, count: np.ndarray, *axes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Clip convex polygons to the half-spaces axis · p >= 0 (planes through the receiver).

    points : (M, K, 3) padded vertices relative to the receiver; count : (M,) int64; axes : (M, 3) each.
    Returns (M, K + len(axes), 3) and counts (0 where nothing is left). Only rows that straddle a plane are
    clipped; the others are passed through (padded).
    """
    count = np.asarray(count, dtype=np.int64).copy()
    for axis in axes:  # a handful of planes
        side = _dot(points, axis[:, None, :])
        real = np.arange(points.shape[1])[None, :] < count[:, None]
        out = np.concatenate([points, points[:, -1:]], axis=1)
        count = np.where(np.all(~real | (side < 0.0), axis=1) | (count < 3), 0, count)
        straddle = np.flatnonzero((real & (side < 0.0)).any(axis=1) & (count > 0))
        if len(straddle):
            out[straddle], count[straddle] = clip_convex(points[straddle], count[straddle], side[straddle])
        points = out
    return points, count


class _PolygonEdges:
    """Great-circle edges of convex spherical polygons, oriented counter-clockwise about the polygon.

    Attributes (M polygons, K slots; slot i is the edge from vertex i to the next real vertex)
    ----------
    start, end : (M, K, 3) unit vectors at the two ends.
    tangent : (M, K, 3) unit tangent at ``start`` pointing along the arc (0 for degenerate edges).
    normal : (M, K, 3) m_i, the unit normal of the edge's great circle, pointing into the polygon.
    angle : (M, K) arc length Θ_i in radians (0 for padding and degenerate edges).
    solid_angle : (M,) Ω in sr.
    """

    def __init__(self, points: np.ndarray, count: np.ndarray):
        m, k, _ = points.shape
        slots = np.arange(k)[None, :]
        real = slots < count[:, None]
        # Padding slots point at themselves: zero-length edges that contribute nothing.
        following = np.where(real, np.where(slots + 1 < count[:, None], slots + 1, 0), slots)
        start = _normalize_or_zero(points)
        end = np.take_along_axis(start, following[:, :, None], axis=1)
        offset = end - start
        cross = cross3(start, offset)  # = start × end, accurate for short edges
        sin_angle = np.sqrt(_dot(cross, cross))
        cos_angle = _dot(start, end)
        angle = np.where(real, np.arctan2(sin_angle, cos_angle), 0.0)
        # Orientation from the planar polygon: counter-clockwise about the direction towards it exactly
        # when its Newell normal points away from the receiver.
        planar_next = np.take_along_axis(points, following[:, :, None], axis=1)
        newell = np.where(real[:, :, None], cross3(points, planar_next), 0.0).sum(axis=1)
        centroid = np.where(real[:, :, None], points, 0.0).sum(axis=1)
        orientation = np.sign(_dot(newell, centroid))
        self.start, self.end = start, end
        self.tangent = _normalize_or_zero(offset - _dot(offset, start)[..., None] * start)
        self.normal = _normalize_or_zero(cross) * orientation[:, None, None]
        self.angle = angle
        self.sin_angle = np.where(real, sin_angle, 0.0)
        self.one_minus_cos = np.where(real, 0.5 * _dot(offset, offset), 0.0)  # 1 - cos Θ without cancellation
        self.solid_angle = np.where(orientation != 0.0, polygon_solid_angle(points, count), 0.0)


class _EdgeIntegrals:
    """E_i^k(w) = ∫_0^Θ_i (w · u(t))^k dt for k = 0, 1, 2, ... by the two-step recurrence (see module doc)."""

    def __init__(self, edges: _PolygonEdges, axis: np.ndarray):
        w = axis[:, None, :]
        self.a = _dot(edges.start, w)
        self.b = _dot(edges.tangent, w)
        self.radius2 = self.a ** 2 + self.b ** 2
        self.g_end = _dot(edges.end, w)
        # g'(Θ) = b cos Θ - a sin Θ: the axis against the arc's tangent at its end.
        self.slope_end = self.b * (1.0 - edges.one_minus_cos) - self.a * edges.sin_angle
        self.order = -1
        self.previous = np.zeros_like(self.a)   # E^(k-1)
        self.current = np.zeros_like(self.a)    # E^k
        self.a_power = np.ones_like(self.a)     # a^(k-1) for the next step
        self.g_power = np.ones_like(self.a)
        self.edges = edges

    def step(self) -> np.ndarray:
        """Advance to the next order and return E^k, shape (M, K)."""
        k = self.order + 1
        if k == 0:
            new = self.edges.angle.copy()
        elif k == 1:
            new = self.a * self.edges.sin_angle + self.b * self.edges.one_minus_cos
        else:
            self.a_power = self.a_power * self.a
            self.g_power = self.g_power * self.g_end
            new = ((k - 1) * self.radius2 * self.previous + self.a_power * self.b
                   - self.g_power * self.slope_end) / k
        self.previous, self.current, self.order = self.current, new, k
        return new


def _order_matrix(order, rows: int) -> np.ndarray:
    """Exponents as an (M, J) int64 matrix: a scalar or (M,) becomes one column."""
    orders = np.asarray(order, dtype=np.int64)
    if orders.ndim < 2:
        orders = np.broadcast_to(orders.reshape(-1, 1) if orders.ndim == 1 else orders, (rows, 1))
    if np.any(orders < 0):
        raise ValueError("moment orders must be >= 0")
    return np.array(orders)


def _moments(points: np.ndarray, count: np.ndarray, axis: np.ndarray, second_axis: np.ndarray | None,
             orders: np.ndarray) -> np.ndarray:
    """τ^n(w) (second_axis None) or ∫ (w·u)^n (v·u) dω at the integer orders (M, J) of each polygon."""
    edges = _PolygonEdges(points, count)
    integrals = _EdgeIntegrals(edges, axis)
    w_dot_m = _dot(edges.normal, axis[:, None, :])
    if second_axis is not None:
        v_dot_m = _dot(edges.normal, second_axis[:, None, :])
        w_dot_v = _dot(axis, second_axis)
    result = np.zeros(orders.shape, dtype=np.float64)
    tau_two_below = tau_one_below = np.zeros(len(points))   # τ^(k-2), τ^(k-1)
    for k in range(int(orders.max()) + 1 if orders.size else 0):  # recurrence orders
        edge_one_below = integrals.current                        # E^(k-1)
        edge = integrals.step()                                   # E^k
        if k == 0:
            tau = edges.solid_angle
        elif k == 1:
            tau = 0.5 * np.einsum("mk,mk->m", w_dot_m, edge_one_below)
        else:
            tau = ((k - 1) * tau_two_below + np.einsum("mk,mk->m", w_dot_m, edge_one_below)) / (k + 1)
        if second_axis is None:
            value = tau
        else:
            value = (k * w_dot_v * tau_one_below + np.einsum("mk,mk->m", v_dot_m, edge)) / (k + 2)
        hit = orders == k
        if hit.any():
            result = np.where(hit, value[:, None], result)
        tau_two_below, tau_one_below = tau_one_below, tau
    return result


def _prepare(points, count):
    points = np.asarray(points, dtype=np.float64)
    count = vertex_count_from_padding(points) if count is None else np.asarray(count, dtype=np.int64)
    return points, count


def axial_moment(points: np.ndarray, axis: np.ndarray, order, count: np.ndarray | None = None) -> np.ndarray:
    """τ^n(w) = ∫_P (w·u)^n dω over convex polygons, for integer orders n >= 0.

    Parameters
    ----------
    points : (M, K, 3) float64  polygon vertices relative to the receiver (any length; padded by repeating
                                the last vertex; any winding). The signed integrand is integrated: clip the
                                polygon to w·u >= 0 first if (w·u)^n must be clamped.
    axis : (M, 3) float64       unit w.
    order : int, (M,) or (M, J) int   exponents.
    count : (M,) int64, optional  vertex counts (inferred from the padding when omitted).

    Returns (M,) for a scalar or (M,) order, else (M, J); in sr.
    """
    points, count = _prepare(points, count)
    orders = _order_matrix(order, len(points))
    result = _moments(points, count, np.asarray(axis, dtype=np.float64), None, orders)
    return result[:, 0] if np.ndim(order) < 2 else result


def double_axis_moment(points: np.ndarray, axis: np.ndarray, second_axis: np.ndarray, order,
                       count: np.ndarray | None = None) -> np.ndarray:
    """∫_P (w·u)^n (v·u) dω over convex polygons, for integer orders n >= 0 (Arvo's double-axis moment).

    Parameters as ``axial_moment``; second_axis : (M, 3) unit v (the receiver normal for a BRDF · cos).
    Signed integrand: clip to w·u >= 0 and v·u >= 0 first for the clamped lobe. Returns sr.
    """
    points, count = _prepare(points, count)
    orders = _order_matrix(order, len(points))
    result = _moments(points, count, np.asarray(axis, dtype=np.float64),
                      np.asarray(second_axis, dtype=np.float64), orders)
    return result[:, 0] if np.ndim(order) < 2 else result


def reflect(view: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Mirror direction r = 2 (n·v) n - v, (M, 3)."""
    return 2.0 * _dot(normal, view)[:, None] * normal - view


def phong_exponent_from_roughness(roughness) -> np.ndarray:
    """Phong exponent n whose normalised lobe has the same peak as Cycles' GGX at normal incidence.

    GGX at normal incidence peaks in the mirror direction with f·cos = D(0) G2 / 4 = 1 / (4 π α²) (G2 = 1
    there), and the energy-normalised Phong lobe (n + 2)/(2π) (r·u)^n peaks at (n + 2)/(2π); equal peaks give

        n = 1 / (2 α²) - 2,  α = roughness²,  clamped to >= 0.

    Why not Walter et al.'s n = 2/α² - 2: that matches a *Blinn*-Phong lobe (n·h)^n around the half vector to
    Beckmann. The lobe here is around the mirror direction r, and an angle θ_h from the normal moves the
    reflection by ≈ 2θ_h, so the equivalent mirror-lobe exponent is a quarter of the half-vector one:
    (2/α² - 2)/4 ≈ 1/(2α²), the same as the peak match to first order. Both lobes carry unit energy at normal
    incidence, so matching the peak also matches the width. Roughness 0.2 gives n ≈ 310, 0.3 n ≈ 60,
    roughness >= 0.707 gives n = 0 (1/π over the half-space r·u > 0: Lambertian at normal incidence).
    """
    alpha = np.clip(np.asarray(roughness, dtype=np.float64), 0.0, 1.0) ** 2
    with np.errstate(divide="ignore"):
        return np.maximum(0.5 / alpha ** 2 - 2.0, 0.0)


def phong_polygon_integral(directions: np.ndarray, normal: np.ndarray, view: np.ndarray, exponent,
                           count: np.ndarray | None = None) -> np.ndarray:
    """Integral over each polygon of the normalised Phong BRDF times cos θ_i.

    f(ω_i, ω_o) = (n + 2)/(2π) max(0, r·ω_i)^n with r = 2 (N·ω_o) N - ω_o (modified Phong, energy
    normalised: its albedo is 1 at normal incidence and below 1 elsewhere). At n = 0 the lobe is taken as
    1/π on r·ω_i > 0, the limit n -> 0+.

    Parameters
    ----------
    directions : (M, K, 3) float64  convex polygon vertices relative to the receiver, padded by repeating
                                     the last vertex (any length, any winding).
    normal : (M, 3) float64          unit shading normal N.
    view : (M, 3) float64            unit direction towards the camera ω_o.
    exponent : (M,) or scalar        n >= 0 (non-integer: linear interpolation between floor and ceil).
    count : (M,) int64, optional     vertex counts (inferred from the padding when omitted).

    Returns (M,) float64, dimensionless (1/sr · sr): multiply by the light's radiance (and a colour).
    The polygon is clipped to r·u >= 0 and to N·u >= 0 first; 0 where the view is below the horizon.
    """
    points = np.asarray(directions, dtype=np.float64)
    normal = np.asarray(normal, dtype=np.float64)
    view = np.asarray(view, dtype=np.float64)
    count = vertex_count_from_padding(points) if count is None else np.asarray(count, dtype=np.int64)
    exponent = np.broadcast_to(np.maximum(np.asarray(exponent, dtype=np.float64), 0.0), (len(points),))
    mirror = reflect(view, normal)
    clipped, clipped_count = clip_to_half_spaces(points, count, normal, mirror)
    low = np.floor(exponent)
    orders = np.stack([low, low + 1.0], axis=1).astype(np.int64)
    moments = double_axis_moment(clipped, mirror, normal, orders, count=clipped_count)
    normalised = moments * (orders + 2.0) / (2.0 * np.pi)
    frac = exponent - low
    value = (1.0 - frac) * normalised[:, 0] + frac * normalised[:, 1]
    valid = (clipped_count >= 3) & (_dot(normal, view) > 0.0)
    return np.where(valid, np.maximum(value, 0.0), 0.0)
