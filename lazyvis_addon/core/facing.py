"""Point, spot and sun lights: lights that face the shading point, as polygons built per receiver.

Cycles 5.0.1 (measured; the README's light table): a point lamp of radius r with Soft Falloff on (Blender's
default) is a disk of radius r always facing the shaded point; with it off, a sphere of radius r; a spot is
that lamp times a cone mask; a sun is a disc of directions of angular diameter Angle. Seen from a receiver x, each is
a cap of directions of uniform radiance:
- a lamp: about c - x (c its centre, d = |c - x|), half-angle atan(r / d) (disk) or asin(r / d) (sphere),
  radiance I / (pi r^2), I its intensity; under a disk at normal incidence that is I / (d^2 + r^2);
- a sun: about its direction, half-angle Angle / 2, radiance E / (pi sin^2(Angle / 2)), E its irradiance.

Pass 2 clips a light in its plane, in a frame fixed per light. So each facing light gets fixed planes, rows
of ``LightFrames`` after the polygon lights (virtual lights), and every receiver a polygon in one of them:
- a lamp three planes through its centre, normals the rows of a fixed generic rotation (so that no
  axis-aligned face a user models lies in one); each receiver takes the plane it sees most face-on
  (|cos| >= 1/sqrt(3)), where its polygon is where the cap's FACING_VERTICES boundary directions meet it;
- a sun one plane facing it beyond the scene, where a receiver's polygon is a regular polygon about the
  point straight towards the sun.
A polygon's directions are the cap's widened so that its area matches the cap's, as a disk light's polygon
is. Each frame's own polygon (``LightFrames.vertices``) holds every receiver's: the conservative tests
(culling, which edges may be silhouettes, grazing) read it.

Limits, stated where they apply: a receiver closer to a lamp than MAX_HALF_ANGLE allows (1.7 radii from a
disk's centre) sees a cap of that half-angle, less light than Cycles (``clamped_receivers`` counts them for a
warning); geometry within about a radius of a lamp's centre is clipped at the lamp's plane, not at the disk
or sphere; radius 0 (angle 0) is a cap of HARD_ANGLE: a shadow edge far below a pixel's width.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .scene import FACING_DISK, FACING_SPHERE, FACING_SUN, FacingLights

# Vertices of each receiver's polygon of a facing light (as many as Blender disk lights get).
FACING_VERTICES = 32
# The polygon's vertex directions lie this much further out (in tan of the half-angle) than the cap's edge:
# a regular polygon inscribed in a circle of this radius has the circle's area.
AREA_SCALE = math.sqrt(2.0 * math.pi / (FACING_VERTICES * math.sin(2.0 * math.pi / FACING_VERTICES)))
# The widest cap a lamp's plane holds: a receiver sees its plane at up to acos(1/sqrt(3)) = 54.7 degrees
# from the normal, and the cap's far edge must still meet the plane, well short of 90 degrees.
MAX_HALF_ANGLE = math.radians(30.0)
MAX_TILT = math.acos(1.0 / math.sqrt(3.0))
# A sun's plane faces it: its cap may be wider (Blender allows Angle up to 180 degrees).
MAX_SUN_HALF_ANGLE = math.radians(60.0)
# Radius 0 and Angle 0: a cap of this half-angle (radians) seen from the scene's extent (hard shadows).
HARD_ANGLE = 1e-4
# A sun's plane lies this many scene extents beyond the scene's centre.
SUN_DISTANCE = 4.0

# Three orthonormal generic directions (rows; right-handed): a rotation by an irrational quaternion.
_q = np.array([0.8186, 0.3403, 0.2744, 0.3674])
_q /= np.linalg.norm(_q)
_w, _x, _y, _z = _q
LAMP_AXES = np.array([[1 - 2 * (_y * _y + _z * _z), 2 * (_x * _y - _w * _z), 2 * (_x * _z + _w * _y)],
                      [2 * (_x * _y + _w * _z), 1 - 2 * (_x * _x + _z * _z), 2 * (_y * _z - _w * _x)],
                      [2 * (_x * _z - _w * _y), 2 * (_y * _z + _w * _x), 1 - 2 * (_x * _x + _y * _y)]])
del _q, _w, _x, _y, _z


def effective_radius(facing: FacingLights, extent: float) -> np.ndarray:
    """Each light's radius (m; half-angle in radians for suns), (F,) float64, radius 0 replaced by a hard
    light's (HARD_ANGLE, times ``extent`` for lamps)."""
    hard = np.where(facing.kind == FACING_SUN, HARD_ANGLE, HARD_ANGLE * extent)
    return np.where(facing.radius > 0, facing.radius, hard)


def cap_radiance(facing: FacingLights, radius: np.ndarray) -> np.ndarray:
    """The caps' uniform radiance (F, 3), W m^-2 sr^-1, for radii from ``effective_radius``: I / (pi r^2)
    for lamps, E / (pi sin^2(half-angle)) for suns (their cap at normal incidence gives E)."""
    sun = facing.kind == FACING_SUN
    half = np.minimum(radius, MAX_SUN_HALF_ANGLE)
    area = np.where(sun, np.pi * np.sin(half) ** 2, np.pi * radius ** 2)
    return facing.intensity / area[:, None]


def facing_frames(facing: FacingLights, centre: np.ndarray, extent: float) -> dict:
    """The virtual lights' frames: three per lamp, one per sun, in light order.

    Parameters
    ----------
    facing : validated FacingLights; centre (3,) and extent: the scene's bounding-box centre and diagonal.

    Returns
    -------
    dict of per-frame arrays (K frames): origin, tangent, bitangent, normal (K, 3); uv (K, FACING_VERTICES, 2)
    and vertices (K, FACING_VERTICES, 3) a polygon holding every receiver's; radiance (K, 3); two_sided (K,);
    area (K,) the polygon's; kind, slot, source (K,) int64 (the lamp's plane 0..2, the FacingLights row);
    cap_centre (K, 3), cap_radius (K,); spot_frame (K, 3, 3), spot_cos_half, spot_smooth (K,); cast_shadow, lobes (K,).
    """
    radius = effective_radius(facing, extent)
    radiance = cap_radiance(facing, radius)
    sun = facing.kind == FACING_SUN
    planes = np.where(sun, 1, 3)
    source = np.repeat(np.arange(len(facing)), planes)
    slot = np.arange(len(source)) - np.repeat(np.cumsum(planes) - planes, planes)
    kind = facing.kind[source]
    is_sun = kind == FACING_SUN
    towards = facing.centre / np.maximum(np.linalg.norm(facing.centre, axis=1, keepdims=True), 1e-300)
    # Lamps: the plane through the centre, normal LAMP_AXES[slot], (tangent, bitangent) the next two rows.
    normal = LAMP_AXES[slot % 3].copy()
    tangent = LAMP_AXES[(slot + 1) % 3].copy()
    origin = facing.centre[source].copy()
    # Suns: a plane facing the sun, beyond the scene; its normal points back at the scene.
    reach = 0.5 * extent
    if is_sun.any():
        w = towards[source[is_sun]]
        normal[is_sun] = -w
        helper = np.where(np.abs(w[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
        t = helper - w * np.einsum("nk,nk->n", helper, w)[:, None]
        tangent[is_sun] = t / np.linalg.norm(t, axis=1, keepdims=True)
        origin[is_sun] = centre + SUN_DISTANCE * extent * w
    bitangent = np.cross(normal, tangent)
    # The circle holding every receiver's polygon, about the origin (see ``cap_polygons``): a lamp's far
    # edge lies at d sin(a) / cos(tilt + a) <= AREA_SCALE r / cos(MAX_TILT + MAX_HALF_ANGLE) from its
    # centre (d sin(a) <= AREA_SCALE r for the disk and the sphere, a the widened half-angle); a sun's
    # receivers lie within half the extent of its axis, at most (SUN_DISTANCE + 1/2) extents below.
    lamp_reach = AREA_SCALE * radius[source] / math.cos(MAX_TILT + MAX_HALF_ANGLE)
    sun_tan = np.minimum(AREA_SCALE * np.tan(np.minimum(radius[source], MAX_SUN_HALF_ANGLE)),
                         math.tan(MAX_SUN_HALF_ANGLE))
    sun_reach = reach + (SUN_DISTANCE + 0.5) * extent * sun_tan
    bound = 1.001 * np.where(is_sun, sun_reach, lamp_reach) / math.cos(math.pi / FACING_VERTICES)
    angle = 2.0 * np.pi * np.arange(FACING_VERTICES) / FACING_VERTICES
    uv = bound[:, None, None] * np.stack([np.cos(angle), np.sin(angle)], axis=1)[None]
    vertices = origin[:, None] + uv[..., :1] * tangent[:, None] + uv[..., 1:] * bitangent[:, None]
    polygon_area = 0.5 * FACING_VERTICES * np.sin(2.0 * np.pi / FACING_VERTICES) * bound ** 2
    return dict(origin=origin, tangent=tangent, bitangent=bitangent, normal=normal, uv=uv, vertices=vertices,
                radiance=radiance[source], two_sided=~is_sun, area=polygon_area, kind=kind, slot=slot,
                source=source, cap_centre=np.where(is_sun[:, None], towards[source], facing.centre[source]),
                cap_radius=radius[source], spot_frame=facing.spot_frame[source],
                spot_cos_half=facing.spot_cos_half[source], spot_smooth=facing.spot_smooth[source],
                cast_shadow=facing.cast_shadow[source], spread=np.full(len(source), np.pi),
                lobes=facing.lobes[source])


def cap_polygons(frames, light: np.ndarray, position: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each receiver's polygon of a facing light in that light's plane.

    Parameters
    ----------
    frames : LightFrames; light : (N,) int64 virtual lights (``frames.kind >= 0``); position : (N, 3) receivers.

    Returns
    -------
    uv : (N, FACING_VERTICES, 2) float64   counter-clockwise about the frame's normal;
    count : (N,) int64                     FACING_VERTICES, or 0 where the receiver takes another of the
                                           lamp's planes or lies inside a sphere lamp;
    clamped : (N,) bool                    the cap was wider than the plane holds (see MAX_HALF_ANGLE).

    The cap's boundary directions are a + tan (cos phi e1 + sin phi e2) (a towards the centre or the sun,
    e1, e2 unit and normal to it, tan that of the widened half-angle); each meets the plane where the ray
    from the receiver along it does. Compiled: as numpy passes over (N, K, 3) temporaries it was most of a
    point-lit render's time.
    """
    light = np.ascontiguousarray(light, np.int64)
    uv = np.empty((len(light), FACING_VERTICES, 2))
    count = np.empty(len(light), np.int64)
    clamped = np.empty(len(light), np.bool_)
    _cap_polygons(light, np.ascontiguousarray(position, np.float64), frames.kind, frames.slot, frames.origin,
                  frames.tangent, frames.bitangent, frames.normal, frames.cap_centre, frames.cap_radius, LAMP_AXES,
                  AREA_SCALE, math.tan(MAX_HALF_ANGLE), math.tan(MAX_SUN_HALF_ANGLE), uv, count, clamped)
    return uv, count, clamped


def taken_planes(frames, light: np.ndarray, position: np.ndarray) -> np.ndarray:
    """(N,) bool: the receivers (N, 3) that take virtual light ``light`` (N,) int64: true for polygon lights
    and suns, and for the one plane of a lamp each receiver sees most face-on."""
    kind = frames.kind[light]
    out = np.ones(len(light), bool)
    lamp = np.flatnonzero((kind == FACING_DISK) | (kind == FACING_SPHERE))
    if len(lamp):
        facing_on = np.abs((frames.cap_centre[light[lamp]] - position[lamp]) @ LAMP_AXES.T)
        out[lamp] = np.argmax(facing_on, axis=1) == frames.slot[light[lamp]]
    return out


@njit(cache=True, nogil=True)
def _cap_polygons(light, position, kind, slot, origin, tangent, bitangent, normal, cap_centre, cap_radius, axes,
                  area_scale, widest_lamp, widest_sun, out_uv, out_count, out_clamped):
    k_count = out_uv.shape[1]
    a = np.empty(3)
    e1 = np.empty(3)
    e2 = np.empty(3)
    for n in range(len(light)):
        l = light[n]
        sun = kind[l] == FACING_SUN
        for k in range(3):
            a[k] = cap_centre[l, k] if sun else cap_centre[l, k] - position[n, k]
        distance = np.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
        out_count[n] = 0
        out_clamped[n] = False
        for v in range(k_count):
            out_uv[n, v, 0] = 0.0
            out_uv[n, v, 1] = 0.0
        if not distance > 0:
            continue
        for k in range(3):
            a[k] /= distance
        if not sun:  # the lamp's plane this receiver sees most face-on
            best, best_value = 0, -1.0
            for s in range(3):
                value = abs(a[0] * axes[s, 0] + a[1] * axes[s, 1] + a[2] * axes[s, 2])
                if value > best_value:
                    best, best_value = s, value
            if best != slot[l]:
                continue
        radius = cap_radius[l]
        ratio = radius / distance
        if kind[l] == FACING_DISK:
            tan_half = ratio
        elif kind[l] == FACING_SPHERE:
            if not ratio < 1.0:
                continue  # inside the sphere
            tan_half = ratio / np.sqrt(1.0 - ratio * ratio)
        else:
            tan_half = np.tan(min(radius, 0.5 * np.pi - 1e-6))
        widest = widest_sun if sun else widest_lamp
        tan_widened = area_scale * tan_half
        if tan_widened > widest:
            out_clamped[n] = True
            tan_widened = widest
        along_t = tangent[l, 0] * a[0] + tangent[l, 1] * a[1] + tangent[l, 2] * a[2]
        for k in range(3):
            e1[k] = tangent[l, k] - a[k] * along_t
        length = np.sqrt(e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2])
        for k in range(3):
            e1[k] /= length
        e2[0] = a[1] * e1[2] - a[2] * e1[1]
        e2[1] = a[2] * e1[0] - a[0] * e1[2]
        e2[2] = a[0] * e1[1] - a[1] * e1[0]
        height = 0.0
        rel_t, rel_b = 0.0, 0.0
        for k in range(3):
            rel = position[n, k] - origin[l, k]
            height += rel * normal[l, k]
            rel_t += rel * tangent[l, k]
            rel_b += rel * bitangent[l, k]
        good = True
        for v in range(k_count):
            phi = 2.0 * np.pi * v / k_count
            c, s_ = np.cos(phi) * tan_widened, np.sin(phi) * tan_widened
            w_n, w_t, w_b = 0.0, 0.0, 0.0
            for k in range(3):
                w = a[k] + c * e1[k] + s_ * e2[k]
                w_n += w * normal[l, k]
                w_t += w * tangent[l, k]
                w_b += w * bitangent[l, k]
            if not w_n * height < 0:
                good = False  # this direction never meets the plane
                break
            reach = -height / w_n
            out_uv[n, v, 0] = rel_t + reach * w_t
            out_uv[n, v, 1] = rel_b + reach * w_b
        if not good:
            continue
        doubled = 0.0
        for v in range(k_count):
            j = v + 1 if v + 1 < k_count else 0
            doubled += out_uv[n, v, 0] * out_uv[n, j, 1] - out_uv[n, j, 0] * out_uv[n, v, 1]
        if doubled < 0:  # counter-clockwise about the normal: the spokes turn by the side of the plane
            for v in range(k_count // 2):
                j = k_count - 1 - v
                for k in range(2):
                    out_uv[n, v, k], out_uv[n, j, k] = out_uv[n, j, k], out_uv[n, v, k]
        out_count[n] = k_count


def cone_attenuation(spot_frame: np.ndarray, cos_half: np.ndarray, smooth: np.ndarray,
                     direction: np.ndarray) -> np.ndarray:
    """Cycles' spot cone (N,) float64 on directions (N, 3) from the lamp (any length): smoothstep over
    (cos - cos_half) / smooth, cos the angle between the spot's local -Z and the direction taken into its
    scaled local frame (spot_frame (N, 3, 3)); 1 where cos_half (N,) is below -1 (no cone)."""
    out = np.ones(len(direction))
    coned = np.flatnonzero(cos_half >= -1.0)
    if len(coned) == 0:
        return out
    local = np.einsum("nij,nj->ni", spot_frame[coned], direction[coned])
    cosine = -local[:, 2] / np.maximum(np.linalg.norm(local, axis=1), 1e-300)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.clip((cosine - cos_half[coned]) / smooth[coned], 0.0, 1.0)
    t = np.where(smooth[coned] > 0, t, (cosine > cos_half[coned]).astype(np.float64))
    out[coned] = t * t * (3.0 - 2.0 * t)
    return out


def spread_weight(cosine: np.ndarray, spread: np.ndarray) -> np.ndarray:
    """Cycles' Spread weight (N,) on directions at cos ``cosine`` (N,) from an area light's normal, for Spreads
    ``spread`` (N,) radians: max(tan(s/2) - tan t, 0) normalised by 1 / (tan(s/2) - s/2) (3 / (s/2)^3 below
    s/2 = 0.05); 0 behind the light, 1 for a Spread of pi."""
    half = 0.5 * np.asarray(spread, np.float64)
    norm = spread_normalisation(spread)
    with np.errstate(divide="ignore", invalid="ignore"):
        tangent = np.sqrt(np.maximum(1.0 - cosine ** 2, 0.0)) / np.maximum(cosine, 1e-300)
        weight = np.maximum(np.tan(np.minimum(half, 0.5 * np.pi - 1e-9)) - tangent, 0.0) * norm
    return np.where(half >= 0.5 * np.pi - 1e-12, 1.0, np.where(cosine > 0, weight, 0.0))


def spot_mask(frames, light: np.ndarray, receiver_in_light: np.ndarray) -> np.ndarray:
    """Cycles' spot cone attenuation (N,) float64 for receivers at ``receiver_in_light`` (N, 3) from the
    lamp's centre (``cone_attenuation``); 1 for lights without a cone."""
    return cone_attenuation(frames.spot_frame[light], frames.spot_cos_half[light], frames.spot_smooth[light],
                            receiver_in_light)


def too_close(frames, light: int, points: np.ndarray) -> np.ndarray:
    """(N,) bool: the points (N, 3) whose cap of virtual light ``light`` is clamped (``cap_polygons``'
    ``clamped``): nearer a lamp's centre than MAX_HALF_ANGLE allows, outside a sphere lamp."""
    kind = int(frames.kind[light])
    if kind == FACING_SUN:
        return np.zeros(len(points), bool)
    radius = float(frames.cap_radius[light])
    distance_sq = ((points - frames.cap_centre[light]) ** 2).sum(axis=1)
    limit = AREA_SCALE * radius / math.tan(MAX_HALF_ANGLE)   # d (disk), sqrt(d^2 - r^2) (sphere) below this
    if kind == FACING_SPHERE:
        return (distance_sq > radius ** 2) & (distance_sq - radius ** 2 < limit ** 2)
    return distance_sq < limit ** 2


# ------------------------------------------------------------------------------------------------------
# Spot cones over the cap
# ------------------------------------------------------------------------------------------------------
# Cycles evaluates a spot's cone on each shadow ray's direction (from the sampled point of the lamp to the
# shaded point), so a lamp of radius r blurs the cone's edge by about r / d: over a cap the cone's mask is
# a function of direction. Where it is constant over a couple's light (0 or 1: all but a rim's receivers)
# it multiplies the couple's integrals; elsewhere a fixed Gauss rule (SPOT_RULE points a side, per fan
# triangle of every visible piece, in the light's plane) integrates mask x cosine and the cosine alone, and
# their ratio scales the couple's integrals (exact for the diffuse lobe up to the rule's error; for glossy
# lobes the ratio of the diffuse lobe's is used).
SPOT_RULE = 6


def _gauss_triangle(n: int) -> tuple[np.ndarray, np.ndarray]:
    """A collapsed Gauss-Legendre rule on the unit triangle (0,0), (1,0), (0,1): (n^2, 2) points (s, t)
    and (n^2,) weights summing to 1/2, exact for polynomials of degree 2n - 2."""
    x, w = np.polynomial.legendre.leggauss(n)
    x, w = 0.5 * (x + 1.0), 0.5 * w
    s = np.repeat(x, n)
    t = np.tile(x, n) * (1.0 - s)
    weight = np.repeat(w, n) * np.tile(w, n) * (1.0 - s)
    return np.stack([s, t], axis=1), weight


SPOT_POINTS, SPOT_WEIGHTS = _gauss_triangle(SPOT_RULE)


def direction_mask(frames, light: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """The spot mask (N,) of light ``light`` (N,) int64 along shadow rays leaving receivers in ``direction``
    (N, 3) (towards the lamp, any length): Cycles' smoothstep on the ray's direction in the spot's scaled
    frame; 1 for lights without a cone."""
    return spot_mask(frames, light, -np.asarray(direction, np.float64))


def spot_factors(frames, couples, couple_pixel: np.ndarray, shading_normal: np.ndarray, piece_sets) -> np.ndarray:
    """Per couple (Nc,) float64: what the spot cone leaves of its integrals (1 for other lights).

    Parameters
    ----------
    couples : ReceiverLight; couple_pixel (Nc,); shading_normal (N, 3) unit, per pixel;
    piece_sets : list of (uv (M, K, 2), count (M,), couple (M,), sign (M,) or None): the couple's visible
        region as pieces in the light's plane (signed terms add).
    """
    n_couples = len(couple_pixel)
    factor = np.ones(n_couples)
    coned = np.flatnonzero(frames.spot_cos_half[couples.light] >= -1.0)
    if len(coned) == 0:
        return factor
    light = couples.light[coned]
    # The mask at the light's clipped vertices and at its centre: constant over the (convex) light where
    # all agree on 1 (inside the inner cone, convex), or on 0 with the centre (outside the outer one).
    directions = couples.directions(frames, couples.uv[coned], coned)            # (C, K, 3)
    width = directions.shape[1]
    corner = direction_mask(frames, np.repeat(light, width), directions.reshape(-1, 3)).reshape(-1, width)
    centre = spot_mask(frames, light, couples.receiver_in_light[coned])  # a lamp's frame origin is its centre
    full = (corner == 1.0).all(axis=1)
    dark = (corner == 0.0).all(axis=1) & (centre == 0.0)
    factor[coned[dark]] = 0.0
    rim = coned[~full & ~dark]
    if len(rim) == 0:
        return factor
    is_rim = np.zeros(n_couples, bool)
    is_rim[rim] = True
    masked, plain = _weighted_integrals(_masked_integrals, (frames.spot_frame, frames.spot_cos_half,
                                                            frames.spot_smooth), frames, couples, couple_pixel,
                                        shading_normal, piece_sets, is_rim)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(plain[rim] > 0, masked[rim] / plain[rim], centre[np.searchsorted(coned, rim)])
    factor[rim] = np.clip(ratio, 0.0, 1.0)
    return factor


def _weighted_integrals(kernel, light_arrays: tuple, frames, couples, couple_pixel: np.ndarray,
                        shading_normal: np.ndarray, piece_sets, wanted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per couple (Nc,) twice: ``kernel``'s rule integrals of weight x cosine and of the cosine over the
    pieces of the couples ``wanted`` (Nc,) bool (``_masked_integrals`` or ``_spread_integrals``, their
    per-light arrays ``light_arrays``); the piece sets as ``spot_factors`` takes them."""
    weighted, plain = np.zeros(len(couple_pixel)), np.zeros(len(couple_pixel))
    for uv, count, couple, sign in piece_sets:  # a couple of piece sets
        rows = np.flatnonzero(wanted[couple])
        if len(rows) == 0:
            continue
        c = couple[rows]
        kernel(np.ascontiguousarray(uv[rows], np.float64), np.ascontiguousarray(count[rows], np.int64),
               np.ones(len(rows)) if sign is None else np.ascontiguousarray(sign[rows], np.float64),
               np.ascontiguousarray(c, np.int64), np.ascontiguousarray(couples.local[c], np.float64),
               np.ascontiguousarray(shading_normal[couple_pixel[c]], np.float64),
               np.ascontiguousarray(couples.light[c], np.int64), frames.tangent, frames.bitangent, frames.normal,
               *light_arrays, SPOT_POINTS, SPOT_WEIGHTS, weighted, plain)
    return weighted, plain


@njit(cache=True, nogil=True, inline="always")
def _plane_point_cosine(u, v, h, l, p, tangent, bitangent, light_normal, normal, d):
    """For a point of light l's plane at (u, v) from the receiver's foot (h its height): writes the direction
    d (3,) from the receiver to it and returns |h| / |d|^3 (solid angle per area) times the receiver's cosine
    (0 below its horizon)."""
    for k3 in range(3):
        d[k3] = u * tangent[l, k3] + v * bitangent[l, k3] - h * light_normal[l, k3]
    length = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    cosine = (d[0] * normal[p, 0] + d[1] * normal[p, 1] + d[2] * normal[p, 2]) / length
    return abs(h) / (length * length * length) * cosine if cosine > 0.0 else 0.0


@njit(cache=True, nogil=True)
def _masked_integrals(uv, count, sign, couple, local, normal, light, tangent, bitangent, light_normal, spot_frame,
                      cos_half, smooth, points, weights, masked, plain):
    """Add sign x the rule's integrals of mask x cos and of cos over each piece (fan triangles from vertex
    0) to masked[couple], plain[couple]. A point y = (u, v) of the light's plane seen from the receiver at
    local (u_x, v_x, h): direction d = (u - u_x) t + (v - v_x) b - h n, solid angle |h| / |d|^3 per area."""
    d = np.empty(3)
    for p in range(len(count)):
        l = light[p]
        ux, vx, h = local[p, 0], local[p, 1], local[p, 2]
        total_masked, total_plain = 0.0, 0.0
        for k in range(1, count[p] - 1):
            au, av = uv[p, 0, 0], uv[p, 0, 1]
            bu, bv = uv[p, k, 0] - au, uv[p, k, 1] - av
            cu, cv = uv[p, k + 1, 0] - au, uv[p, k + 1, 1] - av
            area2 = abs(bu * cv - bv * cu)
            for q in range(len(weights)):
                u = au + points[q, 0] * bu + points[q, 1] * cu - ux
                v = av + points[q, 0] * bv + points[q, 1] * cv - vx
                value = weights[q] * area2 * _plane_point_cosine(u, v, h, l, p, tangent, bitangent, light_normal,
                                                                 normal, d)
                if value == 0.0:
                    continue
                # The ray leaves the lamp along -d: its direction in the spot's frame.
                z, size = 0.0, 0.0
                for i in range(3):
                    e = -(spot_frame[l, i, 0] * d[0] + spot_frame[l, i, 1] * d[1] + spot_frame[l, i, 2] * d[2])
                    size += e * e
                    if i == 2:
                        z = e
                cos_angle = -z / np.sqrt(size)
                if smooth[l] > 0.0:
                    t = min(max((cos_angle - cos_half[l]) / smooth[l], 0.0), 1.0)
                else:
                    t = 1.0 if cos_angle > cos_half[l] else 0.0
                total_masked += value * t * t * (3.0 - 2.0 * t)
                total_plain += value
        masked[couple[p]] += sign[p] * total_masked
        plain[couple[p]] += sign[p] * total_plain


# ------------------------------------------------------------------------------------------------------
# Area light Spread
# ------------------------------------------------------------------------------------------------------
# Cycles' Spread (area_light_spread_attenuation, measured against Cycles 5.0.1): emission towards angle t
# from the light's normal is weighted by max(tan a - tan t, 0) N, a = Spread / 2, N = 1 / (tan a - a)
# (3 / a^3 below a = 0.05), which keeps the light's power. Seen from a receiver at height h above the
# light, tan t is the lateral distance r in the light's plane over h: only the disk r < h tan a emits
# towards it, and there the weight falls linearly with r. The light is clipped to the regular polygon of
# SPREAD_SIDES sides inscribed in that disk, so that the weight is smooth over every piece but at the foot
# itself (what the slivers left out carry is ~3 (1 - cos(pi / sides))^2 of the light, 4e-6), and
# integrated over the visible pieces by the spot's Gauss rule.
SPREAD_SIDES = 64


def spread_normalisation(spread: np.ndarray) -> np.ndarray:
    """Cycles' normalize_spread (L,) for Spreads (L,) radians: 1 / (tan a - a), 3 / a^3 below a = 0.05."""
    half = 0.5 * np.asarray(spread, np.float64)
    with np.errstate(divide="ignore"):
        return np.where(half > 0.05, 1.0 / (np.tan(np.minimum(half, 0.5 * np.pi - 1e-9)) - half),
                        3.0 / np.maximum(half, 1e-300) ** 3)


def spread_lines(local: np.ndarray, spread: np.ndarray) -> np.ndarray:
    """Lines (N, SPREAD_SIDES, 3) (a, b, c: keep a u + b v + c >= 0) of the regular polygon inscribed in the
    disk of radius |h| tan(spread / 2) about each receiver's foot (u_x, v_x) in its light's plane (``local``
    (N, 3): u_x, v_x, h)."""
    radius = np.abs(local[:, 2]) * np.tan(np.minimum(0.5 * spread, 0.5 * np.pi - 1e-9))
    angle = 2.0 * np.pi * np.arange(SPREAD_SIDES) / SPREAD_SIDES
    cos, sin = np.cos(angle)[None, :], np.sin(angle)[None, :]
    lines = np.empty((len(local), SPREAD_SIDES, 3))
    lines[..., 0], lines[..., 1] = -cos, -sin
    lines[..., 2] = cos * local[:, :1] + sin * local[:, 1:2] + radius[:, None] * math.cos(math.pi / SPREAD_SIDES)
    return lines


def spread_factors(frames, couples, couple_pixel: np.ndarray, shading_normal: np.ndarray, piece_sets) -> np.ndarray:
    """Per couple (Nc,) float64: the Spread's weight over its visible light, ∫ w cos / ∫ cos (1 for lights
    without a Spread; can exceed 1: the weight keeps the light's power, so it is above 1 towards the normal).
    Arguments as ``spot_factors``."""
    n_couples = len(couple_pixel)
    factor = np.ones(n_couples)
    spread_light = frames.spread[couples.light] < np.pi
    if not spread_light.any():
        return factor
    tan_half = np.tan(np.minimum(0.5 * frames.spread, 0.5 * np.pi - 1e-9))
    weighted, plain = _weighted_integrals(_spread_integrals, (tan_half, spread_normalisation(frames.spread)), frames,
                                          couples, couple_pixel, shading_normal, piece_sets, spread_light)
    rows = np.flatnonzero(spread_light)
    with np.errstate(divide="ignore", invalid="ignore"):
        factor[rows] = np.where(plain[rows] > 0, np.maximum(weighted[rows], 0.0) / plain[rows], 0.0)
    return factor


@njit(cache=True, nogil=True, inline="always")
def _spread_triangle(au, av, bu, bv, cu, cv, ux, vx, h, l, p, normal, tangent, bitangent, light_normal, tan_half,
                     normalisation, points, weights, d):
    """The Gauss rule's (weighted, plain) integrals over the triangle a, b, c of the light's plane; the rule
    collapses onto b (``_gauss_triangle``: x = s, y = t (1 - s)), where the weight's kink is put."""
    eu, ev, fu, fv = bu - au, bv - av, cu - au, cv - av
    area2 = abs(eu * fv - ev * fu)
    total_weighted, total_plain = 0.0, 0.0
    for q in range(len(weights)):
        u = au + points[q, 0] * eu + points[q, 1] * fu - ux
        v = av + points[q, 0] * ev + points[q, 1] * fv - vx
        value = weights[q] * area2 * _plane_point_cosine(u, v, h, l, p, tangent, bitangent, light_normal, normal, d)
        total_weighted += value * max(tan_half[l] - np.sqrt(u * u + v * v) / abs(h), 0.0) * normalisation[l]
        total_plain += value
    return total_weighted, total_plain


@njit(cache=True, nogil=True)
def _spread_integrals(uv, count, sign, couple, local, normal, light, tangent, bitangent, light_normal, tan_half,
                      normalisation, points, weights, weighted, plain):
    """As ``_masked_integrals``, the weight max(tan a - r / |h|, 0) N of the Spread (r the point's distance
    from the receiver's foot F in the light's plane). The weight has a cone's tip at F, so each piece is cut
    into the signed triangles (F, v_k, v_k+1) (their sum is the piece, wherever F lies) and the rule
    collapses onto F, where the weight is smooth in the rule's coordinates (a 20 x 20 m light under a 60
    degree Spread: fanned from a vertex 1e-3 high, from F 2e-6)."""
    d = np.empty(3)
    for p in range(len(count)):
        l = light[p]
        ux, vx, h = local[p, 0], local[p, 1], local[p, 2]
        n = count[p]
        doubled = 0.0
        for k in range(n):
            j = k + 1 if k + 1 < n else 0
            doubled += uv[p, k, 0] * uv[p, j, 1] - uv[p, j, 0] * uv[p, k, 1]
        orient = 1.0 if doubled >= 0 else -1.0
        total_weighted, total_plain = 0.0, 0.0
        for k in range(n):
            j = k + 1 if k + 1 < n else 0
            au, av, cu, cv = uv[p, k, 0], uv[p, k, 1], uv[p, j, 0], uv[p, j, 1]
            turn = (au - ux) * (cv - vx) - (av - vx) * (cu - ux)  # (F, v_k, v_k+1)'s orientation
            if turn == 0.0:
                continue
            w, q = _spread_triangle(au, av, ux, vx, cu, cv, ux, vx, h, l, p, normal, tangent, bitangent,
                                    light_normal, tan_half, normalisation, points, weights, d)
            factor = orient if turn > 0 else -orient
            total_weighted += factor * w
            total_plain += factor * q
        weighted[couple[p]] += sign[p] * total_weighted
        plain[couple[p]] += sign[p] * total_plain


def direction_spread(frames, light: np.ndarray, direction: np.ndarray, side: np.ndarray) -> np.ndarray:
    """The Spread's weight (N,) along shadow rays leaving receivers in ``direction`` (N, 3) towards lights
    ``light`` (N,) seen from ``side`` (N,) (+1 / -1 of a two-sided light); 1 for lights without a Spread."""
    out = np.ones(len(light))
    rows = np.flatnonzero(frames.spread[light] < np.pi)
    if len(rows) == 0:
        return out
    l = light[rows]
    emitted = -direction[rows] / np.maximum(np.linalg.norm(direction[rows], axis=1, keepdims=True), 1e-300)
    cosine = np.einsum("nk,nk->n", emitted, side[rows, None] * frames.normal[l])
    out[rows] = spread_weight(cosine, frames.spread[l])
    return out


def compile_facing():
    """Compile ``_cap_polygons``, ``_masked_integrals`` and ``_spread_integrals`` (or load them from Numba's
    cache) on one-receiver inputs; returns them."""
    one, three, i = np.zeros(1), np.zeros((1, 3)), np.zeros(1, np.int64)
    _cap_polygons(i, three, i, i, three, three, three, three, three, one, LAMP_AXES, 1.0, 1.0, 1.0,
                  np.empty((1, FACING_VERTICES, 2)), np.empty(1, np.int64), np.empty(1, np.bool_))
    _masked_integrals(np.zeros((1, 3, 2)), i, one, i, three, three, i, three, three, three, np.zeros((1, 3, 3)),
                      one, one, SPOT_POINTS, SPOT_WEIGHTS, np.zeros(1), np.zeros(1))
    _spread_integrals(np.zeros((1, 3, 2)), i, one, i, three, three, i, three, three, three, one, one, SPOT_POINTS,
                      SPOT_WEIGHTS, np.zeros(1), np.zeros(1))
    return _cap_polygons, _masked_integrals, _spread_integrals
