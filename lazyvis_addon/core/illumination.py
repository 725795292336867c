"""Pass 2: illumination over the visible part of each light (paper sections 3 and 4.2).

For each (pixel, light) couple the light polygon, already clipped to the receiver's horizon, is cut by
the couple's blockers into convex *visible pieces*: blocker k removes its cone from every piece of its
couple by successive half-plane splits (a piece minus a convex blocker is at most one piece per blocker
edge). Round k applies the k-th blocker of every couple at once, so the loop runs over rounds and
blocker edges while the arrays run over pieces. The pieces are then integrated analytically (Lambert's
polygon formula) or by Monte Carlo over their solid angle.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from numba import njit

from . import rng
from .blocker_map import BlockerMap, first_blocker
from .blockers import BlockerPolygons, silhouette_planes
from .bsdf import SurfaceBsdf
from .emitters import FACING_HULL, taken_hull_planes
from .facing import _gauss_triangle, direction_mask, direction_spread, spot_factors, spread_factors, taken_planes
from .geometry import (PLANE_EPS, LightFrames, ReceiverLight, blocker_in_front_of_light, clip_convex, cone_planes,
                       negligible_lights, pad_to, plane_lines, polygon_area_2d, projected_solid_angle,
                       projected_solid_angle_uv, receiver_light, split_convex, trim)
from .ggx import (FRESNEL_BASIS_SIZE, ROUGHNESS_SQ_THRESHOLD, alpha_from_roughness, dielectric_blend, fresnel_basis,
                  ggx_reflection_pdf, sample_ggx_reflection)
from .ltc import lobe_magnitudes, ltc_adjugate, ltc_frame, ltc_inverse_matrix, ltc_shape_integral
from .phong import phong_exponent_from_roughness, phong_polygon_integral
from .sampling import sample_polygon_solid_angle, sample_spherical_triangle, spherical_triangle_solid_angle
from .scene import LOBE_DIFFUSE, LOBE_GLOSSY, LOBES_ALL
from .settings import Settings
from .surface import SurfacePoints, shadow_rays

# Signed terms (inclusion-exclusion) for couples with at most this many cones, disjoint pieces beyond.
SIGNED_MAX_CONES = 3
# Pieces smaller than this fraction of their light's area are dropped: slivers from shared blocker edges.
SLIVER_FRACTION = 1e-10
PHONG_MAX_EXPONENT = 2000.0


@dataclass
class VisiblePieces:
    """Convex pieces of lights visible from receivers.

    Attributes
    ----------
    couples : ReceiverLight      the (pixel, light) couples of the batch (Nc of them).
    couple_pixel : (Nc,) int64   batch-local pixel of each couple.
    uv : (M, K, 2) float64       pieces in their light's (u, v) coordinates, padded.
    count : (M,) int64
    couple : (M,) int64          couple of each piece.
    max_rounds : int             most blockers any couple had.
    sign : (M,) float64 or None  None: the pieces are disjoint. Otherwise they are signed terms whose
                                 weighted sum is the visible region (``visible_pieces(signed=True)``):
                                 only integrals linear in the region may be taken over them.
    rows : (M,) int64 or None    None: piece i is uv[i]. Otherwise piece i is uv[rows[i]]: ``uv`` is a table
                                 the pieces are read from in place (the couples' whole clipped lights), not
                                 gathered for them (``gathered`` does that where an integrator needs it).
    """

    couples: ReceiverLight
    couple_pixel: np.ndarray
    uv: np.ndarray
    count: np.ndarray
    couple: np.ndarray
    max_rounds: int = 0
    sign: np.ndarray | None = None
    rows: np.ndarray | None = None

    def gathered(self) -> "VisiblePieces":
        """The same pieces with their own polygons (``rows`` None)."""
        return self if self.rows is None else dataclasses.replace(self, uv=self.uv[self.rows], rows=None)


def couples_for(surface: SurfacePoints, frames: LightFrames, exclude: np.ndarray | None = None
                ) -> tuple[ReceiverLight, np.ndarray]:
    """All lit (pixel, light) couples of a batch, ordered by (pixel, light): those whose clipped light is a
    polygon subtending more than ``geometry.NEGLIGIBLE_SOLID_ANGLE``.

    exclude : (N, L) bool or None   couples to leave out (umbra).
    """
    mask = np.broadcast_to(surface.hit[:, None], (len(surface), len(frames))).copy()
    if exclude is not None:
        mask &= ~exclude
    if frames.hulls is not None:  # a hull's receiver takes one of its six planes, decided once per receiver
        rows = np.flatnonzero(frames.kind == FACING_HULL)
        hit = np.flatnonzero(surface.hit)
        taken = np.zeros((len(surface), len(rows)), bool)
        taken[hit] = taken_hull_planes(frames, surface.position[hit])
        mask[:, rows] &= taken
    pixel, light = np.nonzero(mask)
    if frames.any_facing:  # a lamp's receiver takes one of its three planes
        keep = taken_planes(frames, light, surface.position[pixel])
        pixel, light = pixel[keep], light[keep]
    setup = receiver_light(surface.position[pixel], surface.geometric_normal[pixel], surface.shading_normal[pixel],
                           light, frames)
    lit = (setup.count >= 3) & ~negligible_lights(setup.uv, setup.count, setup.local[:, 2])
    keep = np.flatnonzero(lit)
    setup = ReceiverLight(setup.light[keep], trim(setup.uv[keep], setup.count[keep]), setup.count[keep],
                          setup.side[keep], setup.local[keep], setup.receiver_in_light[keep])
    return setup, pixel[keep]


def visible_pieces(surface: SurfacePoints, frames: LightFrames, polygons: BlockerPolygons, blockers: BlockerMap,
                   lights: np.ndarray | None = None, signed: bool = False) -> VisiblePieces:
    """Cut every lit couple's light by its blockers.

    Parameters
    ----------
    surface : the batch's SurfacePoints (N of them).
    blockers : BlockerMap whose ``pixel`` is batch-local and whose ``umbra`` is (N, L).
    lights : (L,) bool or None    only couples with these lights (default: all).
    signed : bool                 return signed terms instead of disjoint pieces (see ``_signed_terms``):
                                  cheaper, for integrals linear in the region (Lambert's formula).
    """
    exclude = blockers.umbra
    if lights is not None:
        exclude = exclude | ~np.asarray(lights, bool)[None, :]
    couples, couple_pixel = couples_for(surface, frames, exclude)
    n_lights = len(frames)
    lookup = np.full(len(surface) * n_lights, -1, np.int64)
    lookup[couple_pixel * n_lights + couples.light] = np.arange(len(couple_pixel))
    entry_couple = lookup[blockers.pixel * n_lights + blockers.light]
    keep = entry_couple >= 0
    entry_couple, entry_blocker = entry_couple[keep], blockers.blocker[keep]

    pieces_uv, pieces_count, pieces_couple = couples.uv.copy(), couples.count.copy(), np.arange(len(couple_pixel))
    if len(entry_couple) == 0:
        return VisiblePieces(couples, couple_pixel, pieces_uv, pieces_count, pieces_couple)

    entry_couple, lines, line_valid = _cone_lines(surface, frames, polygons, couples, couple_pixel, entry_couple,
                                                  entry_blocker)
    order = np.argsort(entry_couple, kind="stable")
    entry_couple, lines, line_valid = entry_couple[order], lines[order], line_valid[order]
    first = np.searchsorted(entry_couple, np.arange(len(couple_pixel)))
    rank = np.arange(len(entry_couple)) - first[entry_couple]
    min_area = SLIVER_FRACTION * frames.area[couples.light]

    rounds = int(rank.max()) + 1
    blockers_of_couple = np.bincount(entry_couple, minlength=len(couple_pixel))
    cones = (entry_couple, rank, lines, line_valid, min_area, blockers_of_couple)
    if not signed:
        uv, count, couple = _disjoint_pieces(couples, np.arange(len(couple_pixel)), *cones, rounds)
        return VisiblePieces(couples, couple_pixel, uv, count, couple, rounds)
    # Inclusion-exclusion pays where few cones meet a light (a box beside a post); n cones that all
    # overlap give 2^n terms (the chapel's floor seen through slats: 20 to 30 cones, ten times the
    # disjoint pieces and time). Couples with more cones than SIGNED_MAX_CONES take disjoint pieces.
    few = blockers_of_couple <= SIGNED_MAX_CONES
    parts = []
    if few.any():
        parts.append(_signed_terms(couples, np.flatnonzero(few), *cones, min(rounds, SIGNED_MAX_CONES)))
    if not few.all():
        uv, count, couple = _disjoint_pieces(couples, np.flatnonzero(~few), *cones, rounds)
        parts.append((uv, count, couple, np.ones(len(count))))
    uv, count, couple, sign = _concat_terms(*parts)
    return VisiblePieces(couples, couple_pixel, uv, count, couple, rounds, sign)


def _disjoint_pieces(couples, subset, entry_couple, rank, lines, line_valid, min_area, blockers_of_couple, rounds):
    """The visible pieces of the couples ``subset``: each couple's light (horizon-clipped) with its cones
    subtracted one round at a time. Returns (uv, count, couple) of the pieces."""
    n_couples = len(couples.count)
    pieces_uv, pieces_count, pieces_couple = couples.uv[subset], couples.count[subset], subset
    finished = []
    for k in range(rounds):  # rounds: the k-th blocker of every couple at once
        # Pieces of couples with no k-th blocker are final: set them aside so rounds stop copying them.
        done = blockers_of_couple[pieces_couple] <= k
        if done.any():
            finished.append((pieces_uv[done], pieces_count[done], pieces_couple[done]))
            pieces_uv, pieces_count, pieces_couple = pieces_uv[~done], pieces_count[~done], pieces_couple[~done]
        this = np.flatnonzero(rank == k)
        entry_of_couple = np.full(n_couples, -1, np.int64)
        entry_of_couple[entry_couple[this]] = this
        entry = entry_of_couple[pieces_couple]
        new_uv, new_count, new_couple, drop = _subtract_blocker(pieces_uv, pieces_count, pieces_couple,
                                                               lines[entry], line_valid[entry], min_area)
        pieces_uv, pieces_count, pieces_couple = _concat_pieces(
            (pieces_uv[~drop], pieces_count[~drop], pieces_couple[~drop]), (new_uv, new_count, new_couple))
    return _concat_pieces(*finished, (pieces_uv, pieces_count, pieces_couple))


def _signed_terms(couples, subset, entry_couple, rank, lines, line_valid, min_area, blockers_of_couple, rounds):
    """The visible region by inclusion–exclusion: L minus the union of cones C_1..C_n is the signed sum of
    L ∩ C_S over subsets S, with sign (-1)^|S|. Intersections of convex sets are convex, so each term is
    one clip (inside parts only, no pieces to split off). Round k intersects every term so far with cone k;
    an empty intersection ends that branch, and a term inside cone k cancels with its intersection, so
    both go. Boxes seen side by side, whose cones meet only along edges, cost one clip each.
    Returns (uv, count, couple, sign) of the terms of the couples ``subset``.
    """
    n_couples = len(couples.count)
    uv, count, couple = couples.uv[subset], couples.count[subset], subset
    sign = np.ones(len(subset))
    finished = []
    for k in range(rounds):  # rounds: the k-th cone of every couple at once
        done = blockers_of_couple[couple] <= k
        if done.any():
            finished.append((uv[done], count[done], couple[done], sign[done]))
            uv, count, couple, sign = uv[~done], count[~done], couple[~done], sign[~done]
        this = np.flatnonzero(rank == k)
        entry_of_couple = np.full(n_couples, -1, np.int64)
        entry_of_couple[entry_couple[this]] = this
        entry = entry_of_couple[couple]
        edge_lines, edge_valid = lines[entry], line_valid[entry]
        separated, covered = _classify(uv, count, edge_lines, edge_valid)
        straddle = np.flatnonzero(~separated & ~covered)
        part_uv, part_count = uv[straddle], count[straddle]
        for i in range(edge_lines.shape[1]):  # cone faces: a handful
            side = _side(edge_lines[straddle, i], part_uv)
            real = np.arange(part_uv.shape[1])[None, :] < part_count[:, None]
            cut = np.flatnonzero(edge_valid[straddle, i] & (part_count >= 3)
                                 & np.where(real, side < 0.0, False).any(axis=1))
            if len(cut):
                clipped, part_count[cut] = clip_convex(part_uv[cut], part_count[cut], side[cut])
                part_uv = pad_to(part_uv, clipped.shape[1])
                part_uv[cut] = pad_to(clipped, part_uv.shape[1])
        owner = couple[straddle]
        big = (part_count >= 3) & (np.abs(polygon_area_2d(part_uv)) > min_area[owner])
        uv, count, couple, sign = _concat_terms((uv[~covered], count[~covered], couple[~covered], sign[~covered]),
                                                (part_uv[big], part_count[big], owner[big], -sign[straddle][big]))
    return _concat_terms(*finished, (uv, count, couple, sign))


def _concat_terms(*parts):
    uv, count, couple = _concat_pieces(*[p[:3] for p in parts])
    return uv, count, couple, np.concatenate([p[3] for p in parts])


def _cone_lines(surface, frames, polygons, couples, couple_pixel, entry_couple, entry_blocker):
    """The cones that cut each couple's light, as lines in its plane.

    Blockers of one closed convex part (``polygons.parts``) in a couple's list become one cone through the
    part's silhouette: the part's faces turned towards the receiver tile that cone, and clipping by each
    of them would cut the light along the edges they share. Where the silhouette cannot be used (the part
    holds the receiver, reaches behind the light, or shows too many edges) the faces clip one by one.

    Returns
    -------
    cone_couple : (E',) int64   couple of each cone; lines : (E', S, 3); valid : (E', S) bool.
    """
    parts = polygons.parts
    if parts is None or len(parts) == 0:
        return (entry_couple,) + _blocker_lines(surface, frames, polygons, couples, couple_pixel, entry_couple,
                                                entry_blocker)
    part = parts.of_blocker[entry_blocker]
    pixel = couple_pixel[entry_couple]
    own = parts.of_blocker[polygons.of_triangle[np.maximum(surface.index_triangle[pixel], 0)]]
    grouped = np.flatnonzero((part >= 0) & (part != own))
    key = entry_couple[grouped] * len(parts) + part[grouped]
    group_key, group_of = np.unique(key, return_inverse=True)
    group_couple, group_part = group_key // len(parts), group_key % len(parts)
    receiver = surface.position[couple_pixel[group_couple]]
    planes, valid, usable = silhouette_planes(parts, group_part, receiver)
    # Every vertex of the part strictly in front of the light, as blocker_in_front_of_light asks of a face.
    light = couples.light[group_couple]
    vertices = parts.vertices[group_part]
    height = couples.side[group_couple][:, None] * np.einsum("nvk,nk->nv", vertices - frames.origin[light][:, None],
                                                             frames.normal[light])
    scale = np.abs(vertices - receiver[:, None]).max(axis=(1, 2)) + np.abs(receiver).max(axis=1)
    usable &= (height > PLANE_EPS * scale[:, None]).all(axis=1)
    face_wise = np.ones(len(entry_couple), bool)
    face_wise[grouped[usable[group_of.ravel()]]] = False
    face_couple = entry_couple[face_wise]
    face_lines, face_valid = _blocker_lines(surface, frames, polygons, couples, couple_pixel, face_couple,
                                            entry_blocker[face_wise])
    cone_couple = group_couple[usable]
    cone_lines = plane_lines(planes[usable], couples.receiver_in_light[cone_couple], couples.light[cone_couple],
                             frames)
    width = max(face_lines.shape[1], cone_lines.shape[1])
    return (np.concatenate([face_couple, cone_couple]),
            np.concatenate([_pad_lines(face_lines, width), _pad_lines(cone_lines, width)]),
            np.concatenate([_pad_lines(face_valid, width), _pad_lines(valid[usable], width)]))


def _pad_lines(values: np.ndarray, width: int) -> np.ndarray:
    """Pad (E, S, ...) lines or validity flags to S = width with zeros (False: not a cone face)."""
    if values.shape[1] >= width:
        return values
    pad = np.zeros((values.shape[0], width - values.shape[1]) + values.shape[2:], values.dtype)
    return np.concatenate([values, pad], axis=1)


def _blocker_lines(surface, frames, polygons, couples, couple_pixel, entry_couple, entry_blocker):
    """Each blocker's cone faces as lines in its light's plane: (E, 5, 3) lines and (E, 5) validity."""
    pixel = couple_pixel[entry_couple]
    light = couples.light[entry_couple]
    x = surface.position[pixel]
    polygon, count = blocker_in_front_of_light(x, polygons.vertices[entry_blocker], polygons.count[entry_blocker],
                                               frames.origin[light], frames.normal[light], couples.side[entry_couple])
    planes, valid = cone_planes(polygon, count)
    lines = plane_lines(planes, couples.receiver_in_light[entry_couple], light, frames)
    return lines, valid


def _side(lines: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Line values at polygon vertices: lines (M, 3), uv (M, K, 2) -> (M, K)."""
    return lines[:, 0, None] * uv[..., 0] + lines[:, 1, None] * uv[..., 1] + lines[:, 2, None]


def _classify(uv, count, lines, valid):
    """Where each piece (M, K, 2) lies against its cone's lines (M, E, 3): wholly outside one of them
    (``separated``, (M,) bool) or inside all (``covered``)."""
    real_vertex = (np.arange(uv.shape[1])[None, :] < count[:, None])[:, None, :]
    value = np.stack([_side(lines[:, i], uv) for i in range(lines.shape[1])], axis=1)  # (M, E, K)
    outside_edge = valid & np.where(real_vertex, value <= 0.0, True).all(axis=2)
    inside_edge = ~valid | np.where(real_vertex, value >= 0.0, True).all(axis=2)
    # A blocker without a valid cone face subtends no solid angle (the receiver lies in its plane): it
    # removes nothing, rather than everything.
    separated = outside_edge.any(axis=1) | ~valid.any(axis=1)
    return separated, ~separated & inside_edge.all(axis=1)


def _subtract_blocker(uv, count, couple, lines, valid, min_area):
    """Remove one blocker's cone from each piece.

    Parameters
    ----------
    uv : (M, K, 2), count : (M,), couple : (M,)   the pieces the blocker applies to.
    lines : (M, E, 3), valid : (M, E)             the blocker's cone faces (inside: value > 0).
    min_area : (Nc,)                              sliver threshold per couple.

    Returns
    -------
    new_uv, new_count, new_couple : pieces replacing the ones marked in ``drop``.
    drop : (M,) bool                              pieces that the blocker touched (replaced or removed).
    """
    separated, covered = _classify(uv, count, lines, valid)
    split = np.flatnonzero(~separated & ~covered)
    drop = ~separated

    # Peel off, edge by edge, the part of the piece outside that edge; what survives every edge lies
    # inside the blocker's cone and is dropped. Only pieces straddling an edge are clipped by it.
    remainder, remainder_count, owner = uv[split], count[split], couple[split]
    edge_valid, edge_lines = valid[split], lines[split]
    last_edge = int(np.flatnonzero(edge_valid.any(axis=0)).max()) if len(split) else -1
    out_uv, out_count, out_couple = [], [], []
    for i in range(last_edge + 1):  # blocker edges: 3, or 4 for a blocker cut by the light's plane
        side = _side(edge_lines[:, i], remainder)
        real = np.arange(remainder.shape[1])[None, :] < remainder_count[:, None]
        any_out = (np.where(real, side, np.inf) < 0).any(axis=1)
        all_out = (np.where(real, side, -np.inf) <= 0).all(axis=1)
        live = edge_valid[:, i] & (remainder_count >= 3)
        whole = np.flatnonzero(live & all_out)            # entirely outside this edge: emit it whole
        cut = np.flatnonzero(live & any_out & ~all_out)    # straddles: emit the outside part, keep the inside
        if len(whole):
            out_uv.append(remainder[whole])
            out_count.append(remainder_count[whole])
            out_couple.append(owner[whole])
        if len(cut):
            inside, inside_count, outside, outside_count = split_convex(remainder[cut], remainder_count[cut],
                                                                        side[cut], want_outside=True)
            big = (outside_count >= 3) & (np.abs(polygon_area_2d(outside)) > min_area[owner[cut]])
            out_uv.append(outside[big])
            out_count.append(outside_count[big])
            out_couple.append(owner[cut][big])
        if i == last_edge:
            break
        remainder_count = remainder_count.copy()
        remainder_count[whole] = 0
        if len(cut):
            remainder = pad_to(remainder, inside.shape[1])
            remainder[cut] = inside
            remainder_count[cut] = inside_count
    if not out_uv:
        return np.zeros((0, 3, 2)), np.zeros(0, np.int64), np.zeros(0, np.int64), drop
    width = max(p.shape[1] for p in out_uv)
    new_uv = np.concatenate([pad_to(p, width) for p in out_uv])
    new_count = np.concatenate(out_count)
    return trim(new_uv, new_count), new_count, np.concatenate(out_couple), drop


def _concat_pieces(*parts):
    width = max(max(p[0].shape[1] for p in parts), 3)
    uv = np.concatenate([pad_to(p[0], width) for p in parts])
    count = np.concatenate([p[1] for p in parts])
    couple = np.concatenate([p[2] for p in parts])
    return trim(uv, count), count, couple


# ------------------------------------------------------------------------------------------------------
# Integrators. Each returns the projected solid angle F (N_couples,) of the visible light per couple,
# so that outgoing radiance = albedo / pi * sum over lights of radiance * F.
# ------------------------------------------------------------------------------------------------------

def analytic(pieces: VisiblePieces, surface: SurfacePoints, frames: LightFrames, clamp: bool = True) -> np.ndarray:
    """Lambert's polygon formula over every visible piece (exact when no blocker was missed).

    Evaluated in each light's own frame, where a piece vertex seen from the receiver is simply
    (u - u_x, v - v_x, -height): no per-vertex change of basis.
    """
    couples = pieces.couples
    if len(pieces.count) == 0:
        return np.zeros(len(pieces.couple_pixel))
    light = couples.light
    normal = surface.shading_normal[pieces.couple_pixel]
    normal_local = np.stack([np.einsum("nk,nk->n", normal, frames.tangent[light]),
                             np.einsum("nk,nk->n", normal, frames.bitangent[light]),
                             np.einsum("nk,nk->n", normal, frames.normal[light])], axis=1)
    per_piece = projected_solid_angle_uv(pieces.uv, pieces.count, couples.local[pieces.couple],
                                         normal_local[pieces.couple], pieces.rows)
    if pieces.sign is None:
        return np.bincount(pieces.couple, weights=per_piece, minlength=len(pieces.couple_pixel))
    # Signed terms: rounding can leave a fully hidden light a hair below zero (``clamp`` False: a part of
    # the terms, summed with others before clamping).
    total = np.bincount(pieces.couple, weights=per_piece * pieces.sign, minlength=len(pieces.couple_pixel))
    return np.maximum(total, 0.0) if clamp else total


def sample_visible(pieces: VisiblePieces, frames: LightFrames, samples: int, couples_wanted: np.ndarray,
                   settings: Settings, pixel_global: np.ndarray, stream: int
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Directions uniform in the solid angle of each couple's visible pieces.

    Parameters
    ----------
    samples : int                     directions per couple (stratified).
    couples_wanted : (Nc,) bool       couples to sample.
    pixel_global : (N,) int64         full-frame pixel index of the batch's pixels (random numbers).
    stream : int                      random-number stream.

    Returns
    -------
    couple : (S,) int64, direction : (S, 3) unit world vectors, pdf : (S,) per sr, total : (Nc,) sr.
    """
    couples = pieces.couples
    n_couples = len(pieces.couple_pixel)
    empty = (np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0), np.zeros(n_couples))
    if len(pieces.count) == 0:
        return empty
    # Fan triangles of every piece; padded fans have zero solid angle and are never chosen.
    directions = couples.directions(frames, pieces.uv, pieces.couple)
    fans = directions.shape[1] - 2
    a = np.repeat(directions[:, 0], fans, axis=0)
    b = directions[:, 1:-1].reshape(-1, 3)
    c = directions[:, 2:].reshape(-1, 3)
    tri_couple = np.repeat(pieces.couple, fans)
    omega = spherical_triangle_solid_angle(a, b, c)
    order = np.argsort(tri_couple, kind="stable")
    a, b, c, tri_couple, omega = a[order], b[order], c[order], tri_couple[order], omega[order]
    cumulative = np.cumsum(omega)
    first = np.searchsorted(tri_couple, np.arange(n_couples))
    last = np.searchsorted(tri_couple, np.arange(n_couples), side="right") - 1
    before = np.where(first > 0, cumulative[np.maximum(first - 1, 0)], 0.0)
    total = np.bincount(tri_couple, weights=omega, minlength=n_couples)
    has = (total > 0) & (last >= first) & couples_wanted
    if not has.any():
        return empty[:3] + (total,)

    couple = np.repeat(np.flatnonzero(has), samples)
    sample = np.tile(np.arange(samples), int(has.sum()))
    pixel = pieces.couple_pixel[couple]
    light = couples.light[couple]
    u = rng.uniforms(settings.seed, settings.frame, stream, pixel_global[pixel], light * samples + sample, 2)
    u = rng.stratified_2d(u, sample, samples)
    target = before[couple] + u[:, 0] * total[couple]
    index = np.clip(np.searchsorted(cumulative, target, side="right"), first[couple], last[couple])
    below = np.where(index > 0, cumulative[np.maximum(index - 1, 0)], 0.0)
    below = np.where(index == first[couple], before[couple], below)
    remapped = np.clip((target - below) / np.maximum(omega[index], 1e-300), 0.0, 1.0 - 1e-12)
    direction, pdf = sample_spherical_triangle(a[index], b[index], c[index], np.stack([remapped, u[:, 1]], axis=1))
    return couple, direction, pdf * omega[index] / total[couple], total


def reduced_domain_mc(pieces: VisiblePieces, surface: SurfacePoints, frames: LightFrames, bsdf: SurfaceBsdf,
                      settings: Settings, pixel_global: np.ndarray, glossy_only: bool = False) -> np.ndarray:
    """Monte Carlo over the visible pieces (paper 3.3): ∫ f cos θ_i dω_i per couple, (Nc, 3).

    f is the whole BSDF, or only its GGX lobes with ``glossy_only`` (then only couples of glossy points are
    sampled). ``settings.mc_samples`` directions per couple: uniform in the solid angle of the visible
    pieces (stratified) for diffuse points; at glossy points half of them uniform and half drawn from the
    GGX lobe (visible normals), combined by the balance heuristic (Veach 1995) so that a narrow lobe under
    a wide light and a wide lobe under a small light are both sampled well. Unbiased for any BSDF.
    """
    n_couples = len(pieces.couple_pixel)
    samples = settings.mc_samples
    glossy_couple = bsdf.glossy[pieces.couple_pixel]
    stream = rng.STREAM_GLOSSY_MC if glossy_only else rng.STREAM_REDUCED_MC
    lobe_samples = samples // 2 if samples > 1 else 0
    uniform_samples = samples - lobe_samples
    weights = np.zeros((n_couples, 3))

    def evaluate(couple, direction):
        pixel = pieces.couple_pixel[couple]
        cosine = np.maximum(np.einsum("nk,nk->n", direction, surface.shading_normal[pixel]), 0.0)
        f = bsdf.glossy_value(pixel, direction) if glossy_only else bsdf.value(pixel, direction)
        return f * cosine[:, None]

    def accumulate(couple, value):
        for channel in range(3):  # colour channels
            weights[:, channel] += np.bincount(couple, weights=value[:, channel], minlength=n_couples)

    if not glossy_only:  # diffuse-only couples: every sample uniform over the visible pieces
        couple, direction, pdf, _ = sample_visible(pieces, frames, samples, ~glossy_couple, settings, pixel_global,
                                                   stream)
        if len(couple):
            accumulate(couple, evaluate(couple, direction) / (samples * np.maximum(pdf, 1e-300))[:, None]
                       * (pdf > 0)[:, None])
    if not glossy_couple.any():
        return weights
    # Glossy couples: uniform samples, weighted against the lobe's density at them ...
    couple, direction, pdf, total = sample_visible(pieces, frames, uniform_samples, glossy_couple, settings,
                                                   pixel_global, stream)
    if len(couple):
        pixel = pieces.couple_pixel[couple]
        lobe_pdf = ggx_reflection_pdf(direction, bsdf.view[pixel], bsdf.normal[pixel], bsdf.roughness[pixel])
        mixed = uniform_samples * pdf + lobe_samples * lobe_pdf
        accumulate(couple, evaluate(couple, direction) * np.where(pdf > 0, 1.0 / np.maximum(mixed, 1e-300), 0.0
                                                                  )[:, None])
    if lobe_samples == 0:
        return weights
    # ... and lobe samples, which count only where they land in the couple's visible pieces.
    couple = np.repeat(np.flatnonzero(glossy_couple & (total > 0)), lobe_samples)
    sample = np.tile(np.arange(lobe_samples), len(couple) // max(lobe_samples, 1))
    pixel = pieces.couple_pixel[couple]
    light = pieces.couples.light[couple]
    u = rng.uniforms(settings.seed, settings.frame, stream, pixel_global[pixel],
                     (len(frames) + light) * samples + sample, 2)
    u = rng.stratified_2d(u, sample, lobe_samples)
    direction, lobe_pdf = sample_ggx_reflection(bsdf.view[pixel], bsdf.normal[pixel], bsdf.roughness[pixel], u)
    inside = (lobe_pdf > 0) & _lands_in_pieces(pieces, frames, couple, direction)
    couple, direction, lobe_pdf = couple[inside], direction[inside], lobe_pdf[inside]
    if len(couple):
        mixed = uniform_samples / total[couple] + lobe_samples * lobe_pdf
        accumulate(couple, evaluate(couple, direction) / mixed[:, None])
    return weights


def _lands_in_pieces(pieces: VisiblePieces, frames: LightFrames, couple: np.ndarray, direction: np.ndarray
                     ) -> np.ndarray:
    """(S,) bool: the ray from couple's receiver along ``direction`` (S, 3) meets one of its visible pieces."""
    couples = pieces.couples
    light = couples.light[couple]
    local = couples.local[couple]
    along = np.stack([np.einsum("nk,nk->n", direction, frames.tangent[light]),
                      np.einsum("nk,nk->n", direction, frames.bitangent[light]),
                      np.einsum("nk,nk->n", direction, frames.normal[light])], axis=1)
    # The receiver is at height local[2] above the light's plane (negative on a two-sided light's back).
    with np.errstate(divide="ignore", invalid="ignore"):
        distance = -local[:, 2] / along[:, 2]
    reaches = np.isfinite(distance) & (distance > 0)
    point = local[:, :2] + np.where(reaches, distance, 0.0)[:, None] * along[:, :2]
    # Candidate pieces: every piece of the sample's couple (pieces sorted by couple, then expanded).
    order = np.argsort(pieces.couple, kind="stable")
    first = np.searchsorted(pieces.couple[order], np.arange(len(pieces.couple_pixel)))
    per_couple = np.bincount(pieces.couple, minlength=len(pieces.couple_pixel))
    candidates = per_couple[couple]
    sample_of = np.repeat(np.arange(len(couple)), candidates)
    offset = np.arange(len(sample_of)) - np.repeat(np.cumsum(candidates) - candidates, candidates)
    piece = order[first[couple][sample_of] + offset]
    uv, count = pieces.uv[piece], pieces.count[piece]
    edge = np.roll(uv, -1, axis=1) - uv
    edge[np.arange(len(piece)), count - 1] = uv[:, 0] - uv[np.arange(len(piece)), count - 1]
    to_point = point[sample_of][:, None, :] - uv
    cross = edge[..., 0] * to_point[..., 1] - edge[..., 1] * to_point[..., 0]
    real = np.arange(uv.shape[1])[None, :] < count[:, None]
    # Convex pieces of either winding: the point is inside when no real edge has it on the wrong side.
    inside = (np.where(real, cross, 0.0) >= 0).all(axis=1) | (np.where(real, cross, 0.0) <= 0).all(axis=1)
    if pieces.sign is not None:
        # Signed terms: the point is in the region where the signs of the terms holding it sum to 1.
        held = np.bincount(sample_of[inside], weights=pieces.sign[piece[inside]], minlength=len(couple))
        return (held > 0.5) & reaches
    landed = np.zeros(len(couple), bool)
    landed[sample_of[inside]] = True
    return landed & reaches


# A light whose angular radius is below this fraction of the GGX lobe's width (alpha) is integrated by the
# lobe's value at its direction (``glossy_analytic``): the lobe's relative change over it is ~1e-3.
SMALL_LIGHT = 0.05


def _light_radius(couples: ReceiverLight, rows: np.ndarray) -> np.ndarray:
    """A bound on the angular radius (R,) radians of couples ``rows``' clipped lights: the (u, v) polygon's
    radius about its vertices' mean, over the distance from the receiver to that mean less the radius."""
    uv, count = couples.uv[rows], couples.count[rows]
    real = np.arange(uv.shape[1])[None, :] < count[:, None]
    centre = (uv * real[..., None]).sum(axis=1) / np.maximum(count, 1)[:, None]
    radius = np.where(real, np.linalg.norm(uv - centre[:, None], axis=2), 0.0).max(axis=1)
    local = couples.local[rows]
    distance = np.sqrt(((centre - local[:, :2]) ** 2).sum(axis=1) + local[:, 2] ** 2)
    return np.where(distance > radius, np.arctan2(radius, np.maximum(distance - radius, 1e-300)), np.pi)


def glossy_analytic(pieces: VisiblePieces, frames: LightFrames, bsdf: SurfaceBsdf, method: str,
                    clamp: bool = True) -> np.ndarray:
    """∫ f_glossy cos θ_i over each couple's visible pieces by an analytic lobe, (Nc, 3).

    ``method`` "ltc": per piece, the share of the GGX lobe it holds by linearly transformed cosines (Heitz et
    al. 2016), times the lobe's albedo with every closure's Fresnel evaluated at the piece's lobe-weighted
    mean direction (``SurfaceBsdf.glossy_magnitude``). "phong": the share of the paper's normalised Phong
    lobe about the mirror direction, exponent peak-matched to the roughness
    (``phong.phong_exponent_from_roughness``), times the lobe's albedo with its mean Fresnel
    (``SurfaceBsdf.glossy_scale``). Only pieces of glossy, not mirror-smooth points are integrated.
    """
    n_couples = len(pieces.couple_pixel)
    weights = np.zeros((n_couples, 3))
    piece_pixel = pieces.couple_pixel[pieces.couple]
    rough = alpha_from_roughness(bsdf.roughness[piece_pixel]) ** 2 > ROUGHNESS_SQ_THRESHOLD  # mirrors: elsewhere
    lobed = np.flatnonzero(bsdf.glossy[piece_pixel] & rough)
    if len(lobed) == 0:
        return weights
    couple = pieces.couple[lobed]
    pixel = piece_pixel[lobed]
    directions = pieces.couples.directions(frames, pieces.uv[lobed], couple)
    normal, view, roughness = bsdf.normal[pixel], bsdf.view[pixel], bsdf.roughness[pixel]
    if method in ("ltc", "ltc_cv"):
        share, centroid = ltc_shape_integral(directions, normal, view, roughness, pieces.count[lobed], centroid=True)
        magnitude = bsdf.glossy_magnitude(pixel, centroid)
        per_piece = share[:, None] * magnitude
        # Lights far narrower than the lobe (a hard point light, a distant small lamp): the true lobe at the
        # piece's direction times its projected solid angle. LTC fits the lobe's integral, not its value at
        # a point: under a hard light on roughness 0.25 it was 17 % below Cycles.
        lobed_couples, inverse = np.unique(couple, return_inverse=True)
        small = _light_radius(pieces.couples, lobed_couples)[inverse] < SMALL_LIGHT * alpha_from_roughness(roughness)
        if method == "ltc_cv":  # LTC as a control variate: its shape error integrated by a Gauss rule
            wide = np.flatnonzero((roughness >= CV_MIN_ROUGHNESS) & ~small)  # small lights: replaced below
            per_piece[wide] += ltc_residual(directions[wide], pieces.count[lobed][wide], pixel[wide], centroid[wide],
                                            bsdf)
        if small.any():
            rows = np.flatnonzero(small)
            real = np.arange(directions.shape[1])[None, :] < pieces.count[lobed][rows, None]
            mean = (directions[rows] / np.linalg.norm(directions[rows], axis=2, keepdims=True)
                    * real[..., None]).sum(axis=1)
            mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-300)
            projected = projected_solid_angle(directions[rows], normal[rows])
            per_piece[rows] = bsdf.glossy_value(pixel[rows], mean) * projected[:, None]
    elif method == "phong":
        # The moments' recurrence costs one step per exponent unit: narrower lobes than n = 2000 (roughness
        # below 0.126) are integrated at n = 2000.
        exponent = np.minimum(phong_exponent_from_roughness(roughness), PHONG_MAX_EXPONENT)
        share = phong_polygon_integral(directions, normal, view, exponent, pieces.count[lobed])
        per_piece = share[:, None] * bsdf.glossy_scale[pixel]
    else:
        raise ValueError(f"unknown glossy integral {method!r}")
    if pieces.sign is not None:  # signed terms (silhouette fans): both integrals are linear in the region
        per_piece = per_piece * pieces.sign[lobed][:, None]
    for channel in range(3):  # colour channels
        weights[:, channel] = np.bincount(couple, weights=per_piece[:, channel], minlength=n_couples)
    return weights if pieces.sign is None or not clamp else np.maximum(weights, 0.0)


def couple_weights(pieces: VisiblePieces, surface: SurfacePoints, frames: LightFrames, bsdf: SurfaceBsdf,
                   settings: Settings, pixel_global: np.ndarray, more: tuple[VisiblePieces, ...] = (),
                   clamp: bool = True) -> np.ndarray:
    """∫ f cos θ_i dω_i over each couple's visible pieces, (Nc, 3): what multiplies the light's radiance.

    ``settings.integrator`` "reduced_mc" samples the whole BSDF; otherwise the diffuse lobe is exact
    (Lambert's formula) and the GGX lobes follow ``settings.glossy_integrator``. ``more``: further sets of
    signed terms of the same couples (pieces of another width, as the silhouettes' whole lights and cells
    beside their fan triangles): the integrals add, and the mirror test sees all sets at once. Spot lights'
    cones scale each couple's integrals (``facing.spot_factors``).
    """
    weights = _couple_weights(pieces, surface, frames, bsdf, settings, pixel_global, more, clamp)
    light = pieces.couples.light
    coned, spread = (frames.spot_cos_half[light] >= -1.0).any(), (frames.spread[light] < np.pi).any()
    if not (coned or spread):
        return weights
    sets = [(part.uv, part.count, part.couple, part.sign)
            for part in (pieces.gathered(), *(m.gathered() for m in more))]
    if coned:
        weights = weights * spot_factors(frames, pieces.couples, pieces.couple_pixel, surface.shading_normal,
                                         sets)[:, None]
    if spread:
        weights = weights * spread_factors(frames, pieces.couples, pieces.couple_pixel, surface.shading_normal,
                                           sets)[:, None]
    return weights


def lobe_masks(frames: LightFrames, light: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Per couple of lights ``light`` (Nc,) int64, 1.0 where its light reaches the diffuse lobe, and where
    it reaches the glossy lobes ((Nc, 1) float64 each, Blender's Ray Visibility of the light's object);
    None when every light reaches both."""
    lobes = frames.lobes[light]
    if (lobes == LOBES_ALL).all():
        return None
    return (((lobes & LOBE_DIFFUSE) != 0).astype(np.float64)[:, None],
            ((lobes & LOBE_GLOSSY) != 0).astype(np.float64)[:, None])


# The control variate's Gauss rule: CV_RULE^2 points per fan triangle of a piece, in LTC's cosine domain
# (``ltc_residual``). Measured on the glossy floor against Cycles at roughness 0.1 / 0.3 / 0.5 / 0.8: 0.31 /
# 0.041 / 0.015 / 0.012 % RMSE, each within Cycles' noise, where plain LTC is 1.0 / 6.0 / 5.7 / 5.3 % (the
# same rule in the light's plane, Fresnel at the centroid: 1.9 / 0.097 / 0.11 / 0.095 %, too coarse for the
# peak below roughness 0.2, where it was left off).
CV_RULE = 4
CV_POINTS, CV_WEIGHTS = _gauss_triangle(CV_RULE)
# Below this roughness plain LTC: the transform stretches a light-sized piece over the whole cosine domain
# and the peak's small patch there falls between the rule's points (per lobe against importance-sampled
# Monte Carlo: at 0.01 a small light at normal view came out 35 % dark where LTC is exact; with the
# adaptive splits below a large one was still 9-30 % off, 8 % with two levels more).
CV_MIN_ROUGHNESS = 0.05
# Fan triangles wider than this angle (radians) are split, at most CV_LEVELS times (4^CV_LEVELS triangles).
# Per lobe against Monte Carlo at views to 85 degrees, three levels left 1.1-1.5 % at roughness 0.1-0.3 on
# lights of a few radians, four 0.25-0.42 %; the room's pieces never need the fourth (1.72 M triangles
# either way at 128 px).
CV_ANGLE = 0.3
CV_LEVELS = 4
# Below this roughness the rule also splits adaptively (``_adaptive_sums``) until a triangle's four halves
# agree with it to CV_TOLERANCE of the whole lobe's integral. Per lobe against Monte Carlo (4 million
# samples), roughness 0.05-0.09 at views 0-85 degrees: the uniform splits alone left 1.6 % (0.05, 70 degrees,
# a light ahead), 2.4 % and 3.8 % (0.05, 80 and 85, a large light at the mirror direction), 1.9 % (0.07, 85);
# with these splits every case is within 0.4 %. Their cost: on a floor 1 m under a 1 m square light at 128
# px, 1.2 -> 3.9 s at roughness 0.05 (0.1 and up unchanged).
CV_FINE_ROUGHNESS = 0.1
CV_TOLERANCE = 2e-4


def ltc_residual(directions: np.ndarray, count: np.ndarray, pixel: np.ndarray, centroid: np.ndarray,
                 bsdf: SurfaceBsdf) -> np.ndarray:
    """∫_P f_glossy cos θ_i dω - (LTC's share of P) · ``glossy_magnitude`` at ``centroid`` over each piece P,
    (P, 3): what plain LTC leaves out, both of the lobe's shape and of the Fresnel's change across the piece
    (LTC's share takes every Fresnel at the piece's lobe-weighted direction: on a dielectric at roughness 0.5
    seen at 60 degrees, 12 % low under a large overhead light). By CV_RULE^2 Gauss points on each fan
    triangle of the piece in LTC's cosine domain, per Fresnel basis function (``ggx.fresnel_basis``):
    Σ_k coefficient_k · norm · ∫ (basis_k(ω_o·h) f_white cos θ_i / norm - basis_k(centroid) D_ltc) dω, f_white
    Cycles' Fresnel-free single-scattering GGX and norm its hemispherical albedo.

    The rule runs where LTC's lobe is a clamped cosine: each fan triangle's corners are mapped by the LTC
    transform M⁻¹ F (a linear map: the light's plane goes to a plane, so the triangle stays one), and with
    ω_o = M⁻¹ F ω / |M⁻¹ F ω| the integral is ∫ (f_white cos θ_i / albedo · dω/dω_o - D_o) dω_o, D_o =
    max(ω_o.z, 0) / π and dω/dω_o = |M⁻¹ F ω|³ / |det M⁻¹|. There the lobe is as wide as a cosine whatever
    the roughness, so the points follow it: in the light's plane a 16-point rule could not resolve the peak
    of a lobe below roughness 0.2, and at views of 85° a light ahead came out 6 % too bright at 0.2.

    directions : (P, K, 3) piece vertices relative to the receiver (in the light's plane), count (P,);
    pixel : (P,) rows of ``bsdf``; centroid : (P, 3) unit, the direction LTC's share took its Fresnel at."""
    out = np.zeros((len(count), 3))
    # The fitted lobe's transform and Jacobian taken once per piece (``ltc.ltc_density``'s formula, tested
    # there): ``ltc_density`` per point would look the tables up at every point.
    normal, view, roughness = bsdf.normal[pixel], bsdf.view[pixel], bsdf.roughness[pixel]
    inverse = ltc_inverse_matrix(roughness, np.einsum("pk,pk->p", normal, view))
    frame = ltc_frame(normal, view)
    transform = np.einsum("pij,pjk->pik", inverse, frame)  # M⁻¹ F
    adjugate = ltc_adjugate(inverse)
    untransform = np.einsum("pji,pjk->pik", frame, adjugate / adjugate[:, 1:2, 1:2])  # Fᵀ M, M = adj / det M⁻¹
    determinant = np.abs(adjugate[:, 1, 1])  # |det M⁻¹|
    norm = np.maximum(lobe_magnitudes(roughness, np.einsum("pk,pk->p", normal, view))[0], 1e-300)
    terms, eta = bsdf.fresnel_terms(pixel)
    half = centroid + view
    half /= np.maximum(np.linalg.norm(half, axis=1, keepdims=True), 1e-300)
    centroid_basis = fresnel_basis(np.einsum("pk,pk->p", half, view), eta)
    fans = np.concatenate([np.flatnonzero(count > i + 1) for i in range(1, directions.shape[1] - 1)]) \
        if directions.shape[1] > 2 else np.zeros(0, np.int64)
    corner = np.concatenate([np.full(int((count > i + 1).sum()), i) for i in range(1, directions.shape[1] - 1)]) \
        if directions.shape[1] > 2 else np.zeros(0, np.int64)
    triangles = np.stack([directions[fans, 0], directions[fans, corner], directions[fans, corner + 1]], axis=1)
    # Into LTC's cosine domain, by components: a batched matmul calls OpenBLAS, whose own threads fought the
    # render's pool (room.blend at 128 px: 2.9 -> 4.1 s).
    per_fan = transform[fans]
    triangles = (per_fan[:, None, :, 0] * triangles[:, :, 0, None] + per_fan[:, None, :, 1] * triangles[:, :, 1, None]
                 + per_fan[:, None, :, 2] * triangles[:, :, 2, None])
    # A fan triangle wider than CV_ANGLE (its corners' largest angle) is split at its edges' midpoints, up to
    # CV_LEVELS times: the rule's points then stay closer than the cosine's width (a light spanning most of
    # the hemisphere at a grazing view was 20 % off with one triangle, 0.3 % with 64).
    unit = triangles / np.linalg.norm(triangles, axis=2, keepdims=True)
    cosine = np.minimum.reduce([np.einsum("fk,fk->f", unit[:, a], unit[:, b]) for a, b in ((0, 1), (1, 2), (2, 0))])
    angle = np.arccos(np.clip(cosine, -1.0, 1.0))
    level = np.clip(np.ceil(np.log2(np.maximum(angle, 1e-300) / CV_ANGLE)), 0, CV_LEVELS).astype(np.int64)
    split_triangles, split_piece = [triangles[level == 0]], [fans[level == 0]]
    for depth in range(1, CV_LEVELS + 1):  # subdivision levels: a handful
        part, owner = triangles[level == depth], fans[level == depth]
        for _ in range(depth):
            a, b, c = part[:, 0], part[:, 1], part[:, 2]
            ab, bc, ca = 0.5 * (a + b), 0.5 * (b + c), 0.5 * (c + a)
            part = np.concatenate([np.stack(t, axis=1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
            owner = np.tile(owner, 4)
        split_triangles.append(part)
        split_piece.append(owner)
    triangles, fans = np.concatenate(split_triangles), np.concatenate(split_piece)
    alpha = alpha_from_roughness(roughness)
    tolerance = np.where(roughness < CV_FINE_ROUGHNESS, CV_TOLERANCE, 0.0)
    per_triangle = np.empty((len(fans), FRESNEL_BASIS_SIZE))
    _residual_triangles(np.ascontiguousarray(triangles, np.float64), np.ascontiguousarray(fans, np.int64),
                        np.ascontiguousarray(normal, np.float64), np.ascontiguousarray(view, np.float64),
                        np.ascontiguousarray(alpha, np.float64), np.ascontiguousarray(untransform, np.float64),
                        np.ascontiguousarray(determinant, np.float64), np.ascontiguousarray(norm, np.float64),
                        np.ascontiguousarray(eta, np.float64), np.ascontiguousarray(centroid_basis, np.float64),
                        tolerance, CV_POINTS, CV_WEIGHTS, per_triangle)
    contribution = norm[fans, None] * np.einsum("fk,fkc->fc", per_triangle, terms[fans])
    for channel in range(3):  # colour channels
        out[:, channel] += np.bincount(fans, weights=contribution[:, channel], minlength=len(count))
    return out


@njit(cache=True, nogil=True)
def _rule_sums(v0, v1, v2, normal, view, a2, untransform, determinant, eta, points, weights, sums):
    """The Gauss rule ``points``, ``weights`` on one triangle v0 v1 v2 (3,) in LTC's cosine domain, into
    ``sums`` (5,): ∫ D_o dω_o and ∫ b_k(ω_o·h) f_white cos θ_i dω/dω_o dω_o for the four Fresnel basis
    functions b_k (``ggx.fresnel_basis``). normal, view (3,) unit; a2 = α²; untransform (M⁻¹ F)⁻¹ (3, 3);
    determinant |det M⁻¹|; eta the dielectric blend's η. f_white is ``ggx.ggx_single_scatter`` (the same
    formulas: D with sin² = 1 - cos², Smith's Λ, height-correlated G2)."""
    e1_0, e1_1, e1_2 = v1[0] - v0[0], v1[1] - v0[1], v1[2] - v0[2]
    e2_0, e2_1, e2_2 = v2[0] - v0[0], v2[1] - v0[1], v2[2] - v0[2]
    c0, c1, c2 = e1_1 * e2_2 - e1_2 * e2_1, e1_2 * e2_0 - e1_0 * e2_2, e1_0 * e2_1 - e1_1 * e2_0
    n0, n1, n2 = normal[0], normal[1], normal[2]
    o0, o1, o2 = view[0], view[1], view[2]
    cos_o = n0 * o0 + n1 * o1 + n2 * o2
    for k in range(5):
        sums[k] = 0.0
    for g in range(len(weights)):
        s, r = points[g, 0], points[g, 1]
        p0, p1, p2 = v0[0] + s * e1_0 + r * e2_0, v0[1] + s * e1_1 + r * e2_1, v0[2] + s * e1_2 + r * e2_2
        distance = np.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
        d_omega = abs(p0 * c0 + p1 * c1 + p2 * c2) / distance ** 3 * weights[g]
        # The fitted lobe in its own domain: the clamped cosine.
        sums[0] += max(p2 / distance, 0.0) / np.pi * d_omega
        # Back to the light's side: ω = (M⁻¹ F)⁻¹ ω_o / |...|, and dω/dω_o = |M⁻¹ F ω|³ / |det M⁻¹|.
        l0 = untransform[0, 0] * p0 + untransform[0, 1] * p1 + untransform[0, 2] * p2
        l1 = untransform[1, 0] * p0 + untransform[1, 1] * p1 + untransform[1, 2] * p2
        l2 = untransform[2, 0] * p0 + untransform[2, 1] * p1 + untransform[2, 2] * p2
        length = max(np.sqrt(l0 * l0 + l1 * l1 + l2 * l2), 1e-300)
        w0, w1, w2 = l0 / length, l1 / length, l2 / length
        jacobian = (distance / length) ** 3 / determinant
        cos_i = w0 * n0 + w1 * n1 + w2 * n2
        # The white single-scattering GGX lobe D G2 / (4 cos_i cos_o), times cos_i.
        h0, h1, h2 = w0 + o0, w1 + o1, w2 + o2
        half_length = np.sqrt(h0 * h0 + h1 * h1 + h2 * h2)
        if not (cos_i > 0.0 and cos_o > 0.0 and half_length > 0.0 and a2 > ROUGHNESS_SQ_THRESHOLD):
            continue
        cos_nh = (n0 * h0 + n1 * h1 + n2 * h2) / half_length
        cos2 = min(cos_nh * cos_nh, 1.0)
        d = a2 / (np.pi * ((1.0 - cos2) + a2 * cos2) ** 2)
        lambda_i = 0.5 * (np.sqrt(1.0 + a2 * max(1.0 / (cos_i * cos_i) - 1.0, 0.0)) - 1.0)
        lambda_o = 0.5 * (np.sqrt(1.0 + a2 * max(1.0 / (cos_o * cos_o) - 1.0, 0.0)) - 1.0)
        value = d * (1.0 / (1.0 + lambda_i + lambda_o)) / (4.0 * cos_o) * jacobian * d_omega
        cos_hv = min(max((h0 * o0 + h1 * o1 + h2 * o2) / half_length, 0.0), 1.0)
        grazing = 1.0 - cos_hv
        grazing5 = grazing ** 5
        sums[1] += value
        sums[2] += value * dielectric_blend(cos_hv, eta)
        sums[3] += value * grazing5
        sums[4] += value * cos_hv * grazing5 * grazing


@njit(cache=True, nogil=True)
def _residual_triangles(triangles, piece, normal, view, alpha, untransform, determinant, norm, eta, centroid_basis,
                        tolerance, points, weights, out):
    """``ltc_residual``'s Gauss rule on each (sub-)triangle ``triangles`` (F, 3, 3) of piece ``piece`` (F,),
    in LTC's cosine domain: per Fresnel basis function b_k (``ggx.fresnel_basis``), ∫ (b_k(ω_o·h) f_white
    cos θ_i / norm · dω/dω_o - b_k(centroid) D_o) dω_o into ``out`` (F, 4). Per piece (rows of the other
    arrays): the shading normal and view (unit), GGX α, (M⁻¹ F)⁻¹ (3, 3), |det M⁻¹|, the white lobe's
    albedo, the dielectric blend's η, the basis at the piece's centroid (4,) and ``tolerance``: where it is
    positive the triangle is split adaptively (``_adaptive_sums``), else the rule runs once. Compiled: as
    numpy passes over (F, G, 3) chunks it was 60 % of the glossy sample's pass 2."""
    sums = np.empty(5)
    for f in range(len(piece)):
        q = piece[f]
        a2 = alpha[q] * alpha[q]
        if tolerance[q] > 0.0:
            _adaptive_sums(triangles[f], normal[q], view[q], a2, untransform[q], determinant[q], eta[q],
                           tolerance[q], norm[q], points, weights, sums)
        else:
            _rule_sums(triangles[f, 0], triangles[f, 1], triangles[f, 2], normal[q], view[q], a2, untransform[q],
                       determinant[q], eta[q], points, weights, sums)
        for k in range(4):
            out[f, k] = sums[k + 1] / norm[q] - centroid_basis[q, k] * sums[0]


# Adaptive splitting below CV_FINE_ROUGHNESS: at most CV_ADAPTIVE_LEVELS halvings of a triangle's edges.
CV_ADAPTIVE_LEVELS = 6


@njit(cache=True, nogil=True)
def _adaptive_sums(triangle, normal, view, a2, untransform, determinant, eta, tolerance, norm, points, weights,
                   sums):
    """``_rule_sums`` over ``triangle`` (3, 3), split into four at its edges' midpoints wherever the four
    halves' sums differ from the whole's by more than ``tolerance`` of a whole lobe (in the fitted lobe's
    integral, or the white lobe's over its albedo ``norm``), down to CV_ADAPTIVE_LEVELS levels: the splits
    follow the sharp part of the lobe, where a uniform split fine enough for it would cost 4^6 triangles a
    piece. (An embedded coarser rule as the error estimate cost 40 % as much and missed 1.3-1.8 % at
    roughness 0.07-0.09, 85 degrees.) Depth first, on a stack of 3 * levels + 1 triangles."""
    size = 3 * CV_ADAPTIVE_LEVELS + 1
    stack = np.empty((size, 3, 3))
    stack_sums = np.empty((size, 5))
    depth = np.empty(size, np.int64)
    children = np.empty((4, 3, 3))
    child_sums = np.empty((4, 5))
    whole = np.empty(5)
    for k in range(5):
        sums[k] = 0.0
    stack[0] = triangle
    _rule_sums(triangle[0], triangle[1], triangle[2], normal, view, a2, untransform, determinant, eta, points,
               weights, whole)
    stack_sums[0] = whole
    depth[0] = 0
    top = 1
    while top > 0:
        top -= 1
        a, b, c = stack[top, 0].copy(), stack[top, 1].copy(), stack[top, 2].copy()
        level = depth[top]
        for k in range(5):
            whole[k] = stack_sums[top, k]
        if level >= CV_ADAPTIVE_LEVELS:
            for k in range(5):
                sums[k] += whole[k]
            continue
        ab, bc, ca = 0.5 * (a + b), 0.5 * (b + c), 0.5 * (c + a)
        children[0, 0], children[0, 1], children[0, 2] = a, ab, ca
        children[1, 0], children[1, 1], children[1, 2] = ab, b, bc
        children[2, 0], children[2, 1], children[2, 2] = ca, bc, c
        children[3, 0], children[3, 1], children[3, 2] = ab, bc, ca
        for i in range(4):
            _rule_sums(children[i, 0], children[i, 1], children[i, 2], normal, view, a2, untransform, determinant,
                       eta, points, weights, child_sums[i])
        # The fitted lobe and the white lobe, each over its whole integral (the Fresnel terms follow the white).
        change = abs(child_sums[0, 0] + child_sums[1, 0] + child_sums[2, 0] + child_sums[3, 0] - whole[0])
        change = max(change, abs(child_sums[0, 1] + child_sums[1, 1] + child_sums[2, 1] + child_sums[3, 1]
                                 - whole[1]) / norm)
        if change <= tolerance:
            for i in range(4):
                for k in range(5):
                    sums[k] += child_sums[i, k]
            continue
        for i in range(4):
            stack[top] = children[i]
            stack_sums[top] = child_sums[i]
            depth[top] = level + 1
            top += 1


def compile_illumination() -> tuple:
    """Compile the kernels here (or load them from Numba's cache); returns them."""
    one, three = np.ones(1), np.ones((1, 3))
    for tolerance in (np.zeros(1), np.ones(1)):  # the plain rule and the adaptive one
        _residual_triangles(np.ones((1, 3, 3)), np.zeros(1, np.int64), three, three, one, np.ones((1, 3, 3)), one,
                            one, one, np.ones((1, 4)), tolerance, CV_POINTS, CV_WEIGHTS, np.empty((1, 4)))
    return (_residual_triangles,)


def _couple_weights(pieces: VisiblePieces, surface: SurfacePoints, frames: LightFrames, bsdf: SurfaceBsdf,
                    settings: Settings, pixel_global: np.ndarray, more: tuple[VisiblePieces, ...] = (),
                    clamp: bool = True) -> np.ndarray:
    masks = lobe_masks(frames, pieces.couples.light)
    if more:
        rough = _without_mirrors(bsdf)
        total = _summed_weights(pieces, surface, frames, rough, settings, pixel_global)
        for part in more:  # a set or two
            total = total + _summed_weights(part, surface, frames, rough, settings, pixel_global)
        total = np.maximum(total, 0.0)
        if bsdf.glossy.any():
            parts = [part.gathered() for part in (pieces, *more)]
            uv, count, couple = _concat_pieces(*[(part.uv, part.count, part.couple) for part in parts])
            every = VisiblePieces(pieces.couples, pieces.couple_pixel, uv, count, couple, pieces.max_rounds,
                                  np.concatenate([part.sign for part in parts]))
            mirror = mirror_weights(every, frames, bsdf)
            total = total + (mirror if masks is None else mirror * masks[1])
        return total
    if pieces.rows is not None and (bsdf.glossy.any() or settings.integrator == "reduced_mc"):
        pieces = pieces.gathered()  # only Lambert's formula reads a table in place
    mirror = mirror_weights(pieces, frames, bsdf) if bsdf.glossy.any() else 0.0
    if settings.integrator == "reduced_mc":  # the whole BSDF sampled at once: Ray Visibility is warned about
        return reduced_domain_mc(pieces, surface, frames, bsdf, settings, pixel_global) + mirror
    projected = analytic(pieces, surface, frames, clamp)
    diffuse = projected[:, None] * bsdf.diffuse[pieces.couple_pixel] / np.pi
    glossy = mirror
    if bsdf.glossy.any():
        if settings.glossy_integrator == "mc":
            glossy = glossy + reduced_domain_mc(pieces, surface, frames, bsdf, settings, pixel_global, glossy_only=True)
        else:
            glossy = glossy + glossy_analytic(pieces, frames, bsdf, settings.glossy_integrator, clamp)
    if masks is None:
        return diffuse + glossy
    return diffuse * masks[0] + glossy * masks[1]


# Signed terms integrated per array pass: the integrals' temporaries (a few hundred bytes per term and
# vertex) of a batch of foliage's 1.6 million fans at once were 2.8 GB (the tree at 256 px).
TERM_CHUNK = 1 << 17


def _summed_weights(pieces: VisiblePieces, surface: SurfacePoints, frames: LightFrames, bsdf: SurfaceBsdf,
                    settings: Settings, pixel_global: np.ndarray) -> np.ndarray:
    """``couple_weights`` of signed terms without the clamp, (Nc, 3), summed over chunks of TERM_CHUNK terms
    (the unclamped integrals are linear in the terms)."""
    if len(pieces.couple) <= TERM_CHUNK:
        return _couple_weights(pieces, surface, frames, bsdf, settings, pixel_global, clamp=False)
    total = 0.0
    for lo in range(0, len(pieces.couple), TERM_CHUNK):  # chunks of terms
        rows = slice(lo, lo + TERM_CHUNK)
        in_place = pieces.rows is not None
        chunk = dataclasses.replace(pieces, uv=pieces.uv if in_place else pieces.uv[rows], count=pieces.count[rows],
                                    couple=pieces.couple[rows], sign=None if pieces.sign is None else pieces.sign[rows],
                                    rows=pieces.rows[rows] if in_place else None)
        total = total + _couple_weights(chunk, surface, frames, bsdf, settings, pixel_global, clamp=False)
    return total


def _without_mirrors(bsdf: SurfaceBsdf) -> SurfaceBsdf:
    """The BSDF with its mirror-smooth lobes set aside (``mirror_weights`` takes them)."""
    smooth = bsdf.glossy & (alpha_from_roughness(bsdf.roughness) ** 2 <= ROUGHNESS_SQ_THRESHOLD)
    if not smooth.any():
        return bsdf
    return dataclasses.replace(bsdf, glossy=bsdf.glossy & ~smooth)


def mirror_weights(pieces: VisiblePieces, frames: LightFrames, bsdf: SurfaceBsdf) -> np.ndarray:
    """The GGX lobes of mirror-smooth points (α² at or below Cycles' threshold, roughness < 0.004), (Nc, 3).

    Cycles treats such a lobe as a perfect mirror: the light is seen in the mirror direction, with the
    lobe's Fresnel-weighted albedo, when that direction meets the couple's visible pieces. The other glossy
    integrators give 0 for them (a delta cannot be integrated or sampled over an area).
    """
    weights = np.zeros((len(pieces.couple_pixel), 3))
    pixel = pieces.couple_pixel
    smooth = bsdf.glossy[pixel] & (alpha_from_roughness(bsdf.roughness[pixel]) ** 2 <= ROUGHNESS_SQ_THRESHOLD)
    couple = np.flatnonzero(smooth)
    if len(couple):
        view, normal = bsdf.view[pixel[couple]], bsdf.normal[pixel[couple]]
        mirrored = 2.0 * np.einsum("nk,nk->n", view, normal)[:, None] * normal - view
        seen = _lands_in_pieces(pieces, frames, couple, mirrored)
        weights[couple[seen]] = bsdf.glossy_scale[pixel[couple[seen]]]
    return weights


def verify_visible(pieces: VisiblePieces, surface: SurfacePoints, frames: LightFrames, polygons: BlockerPolygons,
                   tracer, couples_wanted: np.ndarray, settings: Settings, pixel_global: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Shadow rays into what the blocker map claims is visible: any hit is a blocker the map missed.

    Parameters
    ----------
    couples_wanted : (Nc,) bool  couples to verify.

    Returns
    -------
    pixel, blocker, light : (H,) int64   missed pairs found (batch-local pixel), unique.
    rays : int
    """
    couple, direction, pdf, _ = sample_visible(pieces, frames, settings.verify_rays, couples_wanted, settings,
                                               pixel_global, rng.STREAM_VERIFY)
    empty = np.zeros(0, np.int64)
    if len(couple) == 0:
        return empty, empty, empty, 0
    couples = pieces.couples
    pixel = pieces.couple_pixel[couple]
    light = couples.light[couple]
    origin, tfar, good = shadow_rays(surface, pixel, direction, pdf, frames.origin[light], frames.normal[light],
                                     couples.side[couple])
    found = first_blocker(tracer, polygons, surface, pixel[good], origin[good], direction[good], tfar[good])
    blocked = found >= 0
    pixel, blocker, light = pixel[good][blocked], found[blocked], light[good][blocked]
    n_blockers = max(len(polygons), 1)
    key = np.unique((pixel * len(frames) + light) * n_blockers + blocker)
    return key // n_blockers // len(frames), key % n_blockers, key // n_blockers % len(frames), int(good.sum())


# Shadow rays of standard Monte Carlo per array pass (each carries its padded polygon, up to a few hundred
# bytes): at 512 samples a point-lit 96 px frame's 14 million rays at once were 11 GB.
STANDARD_MC_RAYS = 1 << 18


def standard_mc(surface: SurfacePoints, frames: LightFrames, tracer, bsdf: SurfaceBsdf, settings: Settings,
                pixel_global: np.ndarray, lights: np.ndarray | None = None
                ) -> tuple[np.ndarray, ReceiverLight, np.ndarray, int]:
    """The paper's baseline: shadow rays over the whole light, no blocker map.

    Returns
    -------
    weights : (Nc, 3) estimates of ∫ f cos θ_i dω_i, couples, couple_pixel, rays cast.
    """
    couples, couple_pixel = couples_for(surface, frames, None if lights is None else
                                        np.broadcast_to(~np.asarray(lights, bool)[None, :],
                                                        (len(surface), len(frames))))
    samples = settings.mc_samples
    n_couples = len(couple_pixel)
    if n_couples == 0:
        return np.zeros((0, 3)), couples, couple_pixel, 0
    weights = np.zeros((n_couples, 3))
    cast = 0
    # Chunks of couples, so that the shadow rays' temporaries (a padded polygon per ray) follow the chunk.
    per_chunk = max(1, STANDARD_MC_RAYS // samples)
    for lo in range(0, n_couples, per_chunk):  # chunks of couples
        chunk = np.arange(lo, min(lo + per_chunk, n_couples))
        rows = np.repeat(chunk, samples)
        sample = np.tile(np.arange(samples), len(chunk))
        pixel, light = couple_pixel[rows], couples.light[rows]
        u = rng.uniforms(settings.seed, settings.frame, rng.STREAM_STANDARD_MC, pixel_global[pixel],
                         light * samples + sample, 2)
        u = rng.stratified_2d(u, sample, samples)
        polygons = couples.directions(frames, couples.uv[rows], rows)
        direction, pdf, _ = sample_polygon_solid_angle(polygons, couples.count[rows], u)
        origin, tfar, good = shadow_rays(surface, pixel, direction, pdf, frames.origin[light], frames.normal[light],
                                         couples.side[rows])
        occluded = np.ones(len(rows), bool)
        occluded[good] = tracer.occluded(origin[good], direction[good], tfar[good])
        cosine = np.maximum(np.einsum("nk,nk->n", direction, surface.shading_normal[pixel]), 0.0)
        visible = ~occluded & (pdf > 0)
        estimate = np.zeros((len(rows), 3))
        shown = np.flatnonzero(visible)
        estimate[shown] = bsdf.value(pixel[shown], direction[shown]) * (cosine[shown] / pdf[shown])[:, None]
        if frames.any_facing:  # a spot's cone, on each shadow ray's direction as Cycles evaluates it
            estimate[shown] *= direction_mask(frames, light[shown], direction[shown])[:, None]
        if (frames.spread < np.pi).any():  # an area light's Spread, likewise
            estimate[shown] *= direction_spread(frames, light[shown], direction[shown],
                                                couples.side[rows[shown]])[:, None]
        for c in range(3):  # colour channels
            weights[:, c] += np.bincount(rows, weights=estimate[:, c], minlength=n_couples)
        cast += int(good.sum())
    return weights / samples, couples, couple_pixel, cast


def outgoing_radiance(surface: SurfacePoints, frames: LightFrames, couples: ReceiverLight, couple_pixel: np.ndarray,
                      projected: np.ndarray) -> np.ndarray:
    """Diffuse outgoing radiance (N, 3): albedo / pi * sum over couples of light radiance * F."""
    return reflected_radiance(len(surface), frames, couples, couple_pixel,
                              projected[:, None] * surface.albedo[couple_pixel] / np.pi)


def reflected_radiance(n_points: int, frames: LightFrames, couples: ReceiverLight, couple_pixel: np.ndarray,
                       weights: np.ndarray) -> np.ndarray:
    """Outgoing radiance (N, 3): sum over each point's couples of light radiance * weights (Nc, 3)."""
    radiance = np.zeros((n_points, 3))
    if len(couple_pixel):
        contribution = frames.radiance[couples.light] * weights
        for channel in range(3):  # colour channels
            radiance[:, channel] = np.bincount(couple_pixel, weights=contribution[:, channel], minlength=n_points)
    return radiance
