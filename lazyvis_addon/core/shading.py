"""Pass 2 for a batch of surface points: the light each point reflects, with exact visibility.

``illuminate`` splits the points into batches on the thread pool and, per batch, finds the visible part of
every light: by silhouettes (``_shade_silhouettes``: the edge tree's candidate edges, arcs, regions and the
reference depth, ``silhouettes``) or from a blocker map's lists (``illumination.visible_pieces``), then
integrates the BSDF over those pieces in closed form (``illumination``). ``shade_verified`` re-shades points
whose inherited lists may not hold (anti-aliasing samples that see another surface than their pixel's
centre) after testing them with shadow rays. The warnings about lights too close to their receivers are
gathered here, once per render.
"""

from __future__ import annotations


import numpy as np

from .blocker_map import BlockerMap
from .bsdf import SurfaceBsdf
from .edge_tree import MeshEdges
from .emitters import FACING_HULL, near_receivers
from .facing import too_close
from .geometry import light_groups
from .illumination import (VisiblePieces, couple_weights, couples_for, reflected_radiance, standard_mc, verify_visible,
                           visible_pieces)
from .parallel import map_batches, thread_count
from .progress import Progress
from .settings import Settings
from .silhouettes import pixel_batch_for, silhouette_pieces
from .surface import SurfacePoints
from .terminator import terminator_couples


# Counters the silhouette pass adds to the render's stats.
SILHOUETTE_COUNTERS = ("nodes_visited", "edge_tests", "arcs", "depth_rays", "inconsistent_couples", "cells")


# Smallest batch split further for threads: per-batch numpy overheads stay well under the work.
MIN_SHARED_BATCH = 1024


# Batches per thread at least (above MIN_SHARED_BATCH pixels each): shadows gather work in a few rows of
# the image, so more, smaller batches even out the threads' loads.
BATCHES_PER_THREAD = 8


def illuminate(surface: SurfacePoints, frames, polygons, tracer, blockers: BlockerMap | None, settings: Settings,
                pixel_global: np.ndarray, progress: Progress, materials, verify: bool = False,
                edges: MeshEdges | None = None, stage: tuple[int, int] | None = None
                ) -> tuple[np.ndarray, dict, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Pass 2 over pixel batches: by the blocker map ``blockers``, or by silhouettes when ``edges`` is given.
    ``stage``: (total, done) of the "Illumination" stage when the points are a band of a larger frame.

    Returns
    -------
    radiance : (N, 3) outgoing radiance; stats : dict (with ``edges``, also "umbra" (N, L) bool and
    "arcs_per_pixel" (N,) int64 arrays);
    missed : (pixel, blocker, light) pairs that verification rays found missing (pixel indexes ``surface``).
    """
    n_pixels = len(surface)
    radiance = np.zeros((n_pixels, 3))
    stats = {"pieces": 0, "max_blockers_per_couple": 0, "verify_rays": 0}
    if edges is not None:
        stats.update(umbra=np.zeros((n_pixels, len(frames)), bool), arcs_per_pixel=np.zeros(n_pixels, np.int64),
                     **dict.fromkeys(SILHOUETTE_COUNTERS, 0))
    empty = np.zeros(0, np.int64)
    if len(frames) == 0:
        return radiance, stats, (empty, empty, empty)
    # Batches of at most pixel_batch, but enough of them to keep every thread busy: anti-aliasing shades
    # sets of a few thousand samples, which one batch would leave to one core.
    threads = thread_count(settings.threads)
    batch = min(settings.pixel_batch, max(MIN_SHARED_BATCH, -(-n_pixels // (BATCHES_PER_THREAD * threads))))
    if edges is not None:  # the silhouettes' temporaries grow with the lights' vertices
        batch = min(batch, pixel_batch_for(settings.memory_budget_mb, threads, frames))
    # Entries are sorted by pixel, so each batch's entries form one contiguous run.
    entry_bounds = None
    if blockers is not None:
        entry_bounds = np.searchsorted(blockers.pixel, np.arange(0, n_pixels + batch, batch))
    starts = list(range(0, n_pixels, batch))
    groups = light_groups(frames)

    def shade(index: int):
        start = starts[index]
        stop = min(start + batch, n_pixels)
        part = surface.take(np.arange(start, stop))
        bsdf = SurfaceBsdf.of(part, materials)
        globals_ = pixel_global[start:stop]
        result = np.zeros((stop - start, 3))
        n_pieces, rounds, verify_rays, found = 0, 0, 0, []
        local = None
        if edges is not None:
            result, n_pieces, rounds, extra = _shade_silhouettes(part, bsdf, globals_, frames, edges, tracer, settings,
                                                                 groups, progress.check_cancel)
            return start, stop, result, n_pieces, rounds, (empty, empty, empty, 0), extra
        if settings.integrator != "standard_mc":
            lo, hi = entry_bounds[index], entry_bounds[index + 1]
            local = BlockerMap(blockers.pixel[lo:hi] - start, blockers.light[lo:hi], blockers.blocker[lo:hi],
                               blockers.umbra[start:stop])
        for lights in groups:  # lights of similar polygon size: a handful of groups
            if settings.integrator == "standard_mc":
                weights, couples, couple_pixel, _ = standard_mc(part, frames, tracer, bsdf, settings, globals_,
                                                                lights)
            else:
                # Lambert's formula alone (no glossy lobe, no sampling, no verification) takes the cheaper
                # signed terms; the reference integrator keeps disjoint pieces as the independent check.
                signed = settings.integrator == "analytic" and not verify and not bsdf.glossy.any()
                pieces = visible_pieces(part, frames, polygons, local, lights, signed)
                couples, couple_pixel = pieces.couples, pieces.couple_pixel
                weights = couple_weights(pieces, part, frames, bsdf, settings, globals_)
                n_pieces += len(pieces.count)
                rounds = max(rounds, pieces.max_rounds)
                if verify:
                    # Every lit couple: a couple with no blocker found may be one whose blockers all escaped
                    # pass 1.
                    pixel, blocker, light, rays = verify_visible(pieces, part, frames, polygons, tracer,
                                                                 np.ones(len(couple_pixel), bool), settings, globals_)
                    found.append((pixel + start, blocker, light))
                    verify_rays += rays
            result += reflected_radiance(stop - start, frames, couples, couple_pixel, weights)
        missed = tuple(np.concatenate([f[i] for f in found]) if found else empty for i in range(3))
        return start, stop, result, n_pieces, rounds, missed + (verify_rays,), None

    progress.begin_stage("Illumination", *(stage if stage is not None else (n_pixels, 0)))
    units = [min(start + batch, n_pixels) - start for start in starts]
    found = []
    for start, stop, result, n_pieces, rounds, missed, extra in map_batches(shade, range(len(starts)), threads,
                                                                            progress, units):
        radiance[start:stop] = result
        if extra is not None:
            stats["umbra"][start:stop] = extra["umbra"]
            stats["arcs_per_pixel"][start:stop] = extra["arcs_per_pixel"]
            for name in SILHOUETTE_COUNTERS:
                stats[name] += extra[name]
        stats["pieces"] += n_pieces
        stats["max_blockers_per_couple"] = max(stats["max_blockers_per_couple"], rounds)
        stats["verify_rays"] += missed[3]
        found.append(missed[:3])
    progress.end_stage()
    missed = tuple(np.concatenate([f[i] for f in found]) if found else empty for i in range(3))
    return radiance, stats, missed


def _shade_silhouettes(part: SurfacePoints, bsdf: SurfaceBsdf, pixel_global: np.ndarray, frames, edges: MeshEdges,
                       tracer, settings: Settings, groups, check_cancel=None) -> tuple[np.ndarray, int, int, dict]:
    """Pass 2 by silhouettes over one batch of N points: radiance (N, 3), terms integrated, most arcs of a
    couple, and the batch's "umbra" (N, L), "arcs_per_pixel" (N,) and SILHOUETTE_COUNTERS. ``check_cancel``
    (a ``Progress.check_cancel``) is called between chunks of couples."""
    n_points = len(part)
    result = np.zeros((n_points, 3))
    extra = {"umbra": np.zeros((n_points, len(frames)), bool), "arcs_per_pixel": np.zeros(n_points, np.int64),
             **dict.fromkeys(SILHOUETTE_COUNTERS, 0)}
    n_terms, rounds = 0, 0
    for lights in groups:  # lights of similar polygon size: a handful of groups
        couples, couple_pixel = couples_for(part, frames, np.broadcast_to(~lights[None, :], (n_points, len(frames))))
        shadowless = ~frames.cast_shadow[couples.light]
        if shadowless.any():  # Cast Shadow off: the whole clipped light, no detection, no lifted origins
            free = np.flatnonzero(shadowless)
            whole = VisiblePieces(couples, couple_pixel, couples.uv[free], couples.count[free], free, 0,
                                  np.ones(len(free)))
            free_weights = couple_weights(whole, part, frames, bsdf, settings, pixel_global)
            result += reflected_radiance(n_points, frames, couples, couple_pixel, free_weights)
            n_terms += len(free)
            kept = np.flatnonzero(~shadowless)
            couples, couple_pixel = couples.take(kept), couple_pixel[kept]
        # Couples seen from lifted origins (Shadow Terminator Geometry Offset) come as strips of their
        # lights, couples of their own: their terms add up per pixel like any lights'.
        couples, couple_pixel, origin_shift = terminator_couples(part, frames, couples, couple_pixel, lights, edges)
        found = dict.fromkeys(SILHOUETTE_COUNTERS + ("max_arcs_per_couple",), 0)
        visible = np.zeros(len(couple_pixel), bool)
        weights = np.zeros((len(couple_pixel), 3))
        # Chunks of couples: each couple's terms lie in one chunk, so their clamped sums add.
        for uv, couple, sign, lights, (cells, cell_uv, cell_count) in silhouette_pieces(
                part, frames, edges, tracer, couples, couple_pixel, found, origin_shift):
            rounds_seen = found["max_arcs_per_couple"]
            fans = VisiblePieces(couples, couple_pixel, uv, np.full(len(couple), 3, np.int64), couple, rounds_seen,
                                 sign)
            # Whole lights read in place from the couples' table (``VisiblePieces.rows``), whole cells gathered.
            whole_lights = VisiblePieces(couples, couple_pixel, couples.uv, couples.count[lights], lights, rounds_seen,
                                         np.ones(len(lights)), rows=lights)
            whole_cells = VisiblePieces(couples, couple_pixel, cell_uv, cell_count, cells, rounds_seen,
                                        np.ones(len(cells)))
            weights += couple_weights(fans, part, frames, bsdf, settings, pixel_global,
                                      more=(whole_lights, whole_cells))
            visible[couple] = True
            visible[lights] = True
            visible[cells] = True
            n_terms += len(couple) + len(lights) + len(cells)
            if check_cancel is not None:
                check_cancel()
        result += reflected_radiance(n_points, frames, couples, couple_pixel, weights)
        rounds = max(rounds, found["max_arcs_per_couple"])
        seen = np.zeros((n_points, len(frames)), bool)
        seen[couple_pixel[visible], couples.light[visible]] = True
        lit = np.zeros((n_points, len(frames)), bool)
        lit[couple_pixel, couples.light] = True
        extra["umbra"] |= lit & ~seen
        extra["arcs_per_pixel"] += np.bincount(couple_pixel, weights=found["arcs_of_couple"],
                                               minlength=n_points).astype(np.int64)
        for name in SILHOUETTE_COUNTERS:
            extra[name] += found[name]
    return result, n_terms, rounds, extra


# Verification at anti-aliasing samples: rays per sample and light (whatever ``verify_rays`` is), and
# rounds of adding what they find. A pair found at one sample joins the lists of all the pixel's samples,
# so 16 samples cast 64 rays per pixel between them.
SAMPLE_VERIFY_RAYS = 4


SAMPLE_VERIFY_ROUNDS = 3


def shade_verified(surface: SurfacePoints, frames, polygons, tracer, blockers: BlockerMap, settings: Settings,
                    pixel_global: np.ndarray, progress: Progress, materials, check: np.ndarray, counts: np.ndarray
                    ) -> tuple[np.ndarray, int]:
    """Pass 2 over anti-aliasing samples, which have no pixel grid to flood-fill over: verification rays
    at the samples in ``check`` (N,) bool; a pair found at a sample is added to the lists of its group
    (the samples of one pixel: ``counts`` (P,) consecutive samples each), which are shaded again, a few
    rounds. A pair added where its blocker does not overlap the light clips nothing, so sharing is safe.

    Returns (N, 3) radiance and the verification rays cast.
    """
    n_points = len(surface)
    radiance = np.zeros((n_points, 3))
    plain = np.flatnonzero(~check)
    if len(plain):
        radiance[plain] = illuminate(surface.take(plain), frames, polygons, tracer, blockers.crop(plain, n_points),
                                      settings, pixel_global[plain], progress, materials)[0]
    chosen = np.flatnonzero(check)
    if len(chosen) == 0 or len(frames) == 0:
        return radiance, 0
    sample_settings = settings.replace(verify_rays=SAMPLE_VERIFY_RAYS)
    radiance[chosen], stats, missed = illuminate(surface.take(chosen), frames, polygons, tracer,
                                                  blockers.crop(chosen, n_points), sample_settings,
                                                  pixel_global[chosen], progress, materials, True)
    missed = (chosen[missed[0]], missed[1], missed[2])
    rays = stats["verify_rays"]
    group_start = np.cumsum(counts) - counts
    group_of = np.repeat(np.arange(len(counts)), counts)
    for _ in range(SAMPLE_VERIFY_ROUNDS):  # rounds: a few
        if len(missed[0]) == 0:
            break
        group = group_of[missed[0]]
        size = counts[group]
        members = np.repeat(group_start[group], size) + np.arange(size.sum()) - np.repeat(np.cumsum(size) - size, size)
        blockers = BlockerMap.from_entries(np.concatenate([blockers.pixel, members]),
                                           np.concatenate([blockers.light, np.repeat(missed[2], size)]),
                                           np.concatenate([blockers.blocker, np.repeat(missed[1], size)]),
                                           blockers.umbra)
        changed = np.unique(members)
        part, stats, missed = illuminate(surface.take(changed), frames, polygons, tracer,
                                          blockers.crop(changed, n_points), sample_settings,
                                          pixel_global[changed], progress, materials, True)
        radiance[changed] = part
        rays += stats["verify_rays"]
        missed = (changed[missed[0]], missed[1], missed[2])
    return radiance, rays


def clamped_caps(surface: SurfacePoints, frames) -> set[int]:
    """The point and spot lights (scene indices) that some visible point lies too close to (``facing``'s
    MAX_HALF_ANGLE: it sees less of the lamp than Cycles there)."""
    points = surface.position[surface.hit]
    lamps = np.flatnonzero((frames.kind >= 0) & (frames.kind != FACING_HULL))
    return {int(frames.source[light]) for light in lamps if too_close(frames, light, points).any()}  # a handful


def warn_clamped_caps(close: set[int], progress: Progress) -> None:
    """One warning naming the lamps of ``clamped_caps``."""
    if close:
        progress.warn("surfaces closer to a point or spot light than 1.7 times its radius get less of its light "
                      f"than in Cycles (point/spot/sun light {', '.join(str(i) for i in sorted(close))})")


def near_hull_misses(surface: SurfacePoints, frames) -> dict[int, int]:
    """Mesh emitter (hull) -> visible points that get none of its light (``emitters.near_receivers``: an
    outline with more vertices than budgeted, or a point inside the box of a hull's planes whose inner
    lights fail)."""
    hit = surface.hit
    return near_receivers(frames, surface.position[hit], surface.index_triangle[hit], frames.part_of)


def warn_near_hulls(missed: dict[int, int], progress: Progress) -> None:
    """One warning naming the emitters of ``near_hull_misses`` and their pixels."""
    if missed:
        progress.warn("surfaces next to a mesh emitter (seeing more of its outline than budgeted) get none of its "
                      "light "
                      f"({', '.join(f'emitter {h}: {n} pixel(s)' for h, n in sorted(missed.items()))})")
