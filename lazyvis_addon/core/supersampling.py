"""Anti-aliasing, run: which edge pixels get samples, how many, shaded in bands on the threads, and pooled.

The estimators themselves (allocation, coverage, the balance-heuristic pool, settling) are in
``antialias``; this module drives them over a ``frame.ShadedFrame``: ``antialias_frame`` marks the edge pixels
(``_marked_pixels``), sets the frame's scale (``_frame_scale``: the same for a window as for the whole
frame), splits the work into bands of rows, and per band shades a pilot of samples, the rest where the
pilot has not settled (``_shade_until_settled``; each sample's pass 2 through ``shading``), and pools them
with the coverage rays (``_pool_with_coverage``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from .antialias import (PILOT_SAMPLES, Coverage, FrameScale, SurfaceStrata, centre_suffices, coverage_rays,
                        covers_one_surface, cull_to_samples, foreign_samples, inherit_blockers, landing_pixels,
                        lattice_pixels, neyman_share, patch_scale, pixel_coverage, pool_samples, probe_centres,
                        probe_pixels, refine_pixels, rgba_of, sample_rgba, samples_for, settled_pixels, stratum_of,
                        subpixel_samples, surface_spread, surface_strata)
from .blocker_map import reference_blocker_map
from .camera import pixel_coordinates
from .edge_tree import MeshEdges
from .frame import (AA_SAMPLES_PER_MB, MARK_RING, CentreGrid, ShadedFrame, global_pixels, silhouette_frame,
                    surface_points)
from .parallel import map_batches, thread_count
from .progress import Progress
from .scene import Scene
from .settings import Settings
from .shading import illuminate, shade_verified
from .kernels import compile_kernels, groups_for
from .surface import SurfacePoints, albedo_scaled_materials, has_albedo_scaled


def antialias_frame(scene: Scene, tracer, extent: float, frames, settings: Settings, progress: Progress, stats: dict,
               pixel_global: np.ndarray, frame: ShadedFrame, wanted_window=None):
    """Supersample the edge pixels of ``frame``: (pixels (P,) int64, filtered RGBA (P, 4), samples (P,)), or
    None where no pixel needs it.

    Which pixels and how many samples each is decided over the whole window (from the centres' radiance).
    The samples are then shaded and pooled in bands of rows, side by side on the threads, each band with
    the pixels within a ring of rows above and below it, whose samples its own pixels' filters reach
    (theirs are shaded again with the next band: a pixel's samples are the same whichever band draws
    them)."""
    camera = scene.camera
    height, width = camera.window_shape
    progress.begin_stage("Anti-aliasing")
    # The frame's scale (radiance floor, samples per unit contrast) where pass 2 shades each centre alone
    # (by silhouettes, or the reference's every-triangle lists): then a window allocates as the whole frame
    # does, and the reference's window as the default's. The paper's blocker map keeps the window's own.
    scale = _frame_scale(scene, tracer, extent, frames, settings, progress, stats, frame) \
        if frame.edges is not None or settings.integrator == "reference" else None
    pixels, contrast = _marked_pixels(scene, tracer, settings, frame, None if scale is None else scale.radiance_floor)
    if wanted_window is not None and wanted_window != camera.window:
        # Only pixels whose samples reach the wanted window's filters: the rest of the margin was rendered
        # for their marks and contrasts.
        reach = int(np.ceil(2.0 * settings.filter_reach))
        xs, ys = pixel_coordinates(camera, pixels)
        x0, y0, x1, y1 = wanted_window
        near = (xs >= x0 - reach) & (xs < x1 + reach) & (ys >= y0 - reach) & (ys < y1 + reach)
        pixels, contrast = pixels[near], contrast[near]
    # Samples are allocated over every marked pixel (a pixel's share does not depend on which others
    # need none). Under a filter far narrower than a pixel, an edge between centres rarely passes
    # under it: camera rays tell which pixels see one triangle there, and those keep their centre.
    share = neyman_share(contrast, settings.aa_samples) if scale is None else scale.share
    counts = samples_for(contrast, share, settings.aa_samples)
    alone = centre_suffices(scene, tracer, pixels, frame.grid.index_triangle[pixels], settings, pixel_global)
    pixels, contrast, counts = pixels[~alone], contrast[~alone], counts[~alone]
    stats["aa_centre_pixels"] = int(alone.sum())
    stats["aa_pixels"] = len(pixels)
    if len(pixels) == 0:
        progress.end_stage()
        return None
    covered = settings.aa_coverage_rays > 0
    # With coverage the pixel's centre, shaded already, is one of its samples.
    wanted = counts - 1 if covered else counts
    strata = surface_strata(scene)  # the surfaces coverage tells apart: once per render
    ring = int(np.ceil(2.0 * settings.filter_reach)) + 1
    row = pixels // width
    # Bands of rows shaded side by side on the threads (the numpy between pass 2's kernels, camera and
    # coverage rays runs on one core otherwise): at least two per thread, each with its thread's share
    # of the budget's samples.
    threads = thread_count(settings.threads)
    most_rows = _side_by_side_rows(frame.band_rows, height, threads, int(wanted.sum()), AA_MIN_BAND_SAMPLES)
    bands = _sample_bands(row, wanted, height, most_rows, settings.memory_budget_mb * AA_SAMPLES_PER_MB / threads)
    counters = ("aa_settled_pixels", "aa_coverage_rays", "aa_verified_samples", "verify_rays")
    nested = progress.nested()  # made here: it forwards cancel checks from this thread only
    grid = frame.grid

    def centre_rgba(lattice: np.ndarray) -> np.ndarray:
        return rgba_of(frame.radiance[lattice], grid.index_triangle[lattice] >= 0,
                       None if grid.emission is None else grid.emission[lattice], scene, settings)

    # Once the pilot's coverage tells the surfaces under a pixel apart, its samples are allocated again by
    # the variation within them (``surface_spread``) at the same samples per unit.
    spread = _SpreadAllocation((height, width), centre_rgba, lambda lattice: stratum_of(grid.index_triangle[lattice],
                                                                                       strata),
                               lambda spread: samples_for(spread, share, settings.aa_samples) - (1 if covered else 0),
                               lambda lattice: _texture_part(scene, frame.centres(lattice), frame.radiance[lattice]))
    # Each band's pass 2 and camera rays run on the pool too: the bands in flight share the budget.
    band_settings = settings.replace(memory_budget_mb=settings.memory_budget_mb / threads)

    def shade_band(rows: tuple[int, int]):
        """The band's own pixels (K,) (rows into ``pixels``), their filtered RGBA (K, 4), samples drawn (K,)
        and the band's counters."""
        first_row, last_row = rows
        chosen = np.flatnonzero((row >= first_row - ring) & (row < last_row + ring))
        own = (row[chosen] >= first_row) & (row[chosen] < last_row)
        counted = dict.fromkeys(counters, 0)  # the band's own: bands run on several threads
        if not own.any():
            return chosen[own], np.zeros((0, 4)), np.zeros(0, np.int64), counted
        # The samples' pass 2 runs as part of this stage: its time stays anti-aliasing's.
        shading = (scene, tracer, extent, band_settings, pixel_global, frames, frame.polygons, nested, counted,
                   frame.lazy_state, frame.verify, frame.edges)
        band = pixels[chosen]
        drawn, rgba, position, triangle, texture, pilot_coverage = _shade_until_settled(
            band, wanted[chosen], contrast[chosen], frame.centres(band), frame.radiance[band], strata, shading, own,
            spread)
        if covered:
            values = _pool_with_coverage(scene, tracer, frame.centres, frame.radiance, band, drawn, rgba, position,
                                         triangle, strata, settings, pixel_global, counted, pilot_coverage, texture)
        else:
            owner = np.repeat(np.arange(len(band)), drawn)
            values = pool_samples(rgba, position, owner, band, drawn, camera.window, settings)
        return chosen[own], values[own], drawn[own], counted

    progress.begin_stage("Anti-aliasing", len(bands), 0)
    pooled = np.zeros((len(pixels), 4))
    final = np.zeros(len(pixels), np.int64)
    stats["aa_samples_shaded"] = stats["aa_settled_pixels"] = stats["aa_coverage_rays"] = 0
    for own, values, drawn, counted in map_batches(shade_band, bands, threads, progress):
        pooled[own] = values
        final[own] = drawn
        stats["aa_samples_shaded"] += int(drawn.sum())
        for name, value in counted.items():
            if value or name in stats:
                stats[name] = stats.get(name, 0) + value
    progress.end_stage()
    return pixels, pooled, final + 1 if covered else final


# Anti-aliasing's work is split into bands side by side on the threads only where each band gets at least
# this much (a band's pass 2, rays and ring of re-shaded rows cost a fixed part: textured.blend at 256 px,
# 52 k samples in four bands, was 8 % slower than in one), and a band at least AA_MIN_BAND_ROWS rows.
AA_MIN_BAND_SAMPLES = 1 << 17


AA_MIN_BAND_PIXELS = 1 << 17


AA_MIN_BAND_ROWS = 32


def _side_by_side_rows(band_rows: int, height: int, threads: int, work: int, least: int) -> int:
    """Rows per band of anti-aliasing's ``work`` (samples or pixels) on the threads: two bands per thread
    where each gets ``least`` of it and AA_MIN_BAND_ROWS rows, fewer otherwise, one where the work is
    small; never more rows than a band of the frame (the budget's)."""
    bands = min(2 * threads, work // max(least, 1))
    if bands <= 1:
        return band_rows
    return min(band_rows, max(AA_MIN_BAND_ROWS, -(-height // bands)))


def _marked_pixels(scene: Scene, tracer, settings: Settings, frame: ShadedFrame, floor: float | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """``antialias.refine_pixels`` over the window in bands of rows on the threads (each with MARK_RING rows
    of its neighbours, and one radiance floor: ``floor``, by default 1e-4 of the window's brightest centre):
    the marked pixels (P,) int64, ascending, and their contrast (P,), the same as the whole window's at once."""
    height, width = scene.camera.window_shape
    x0, y0, x1, _ = scene.camera.window
    grid, radiance = frame.grid, frame.radiance
    if floor is None:
        floor = 1e-4 * max(_brightest(frame), 1e-30)
    threads = thread_count(settings.threads)
    rows_per_band = _side_by_side_rows(frame.band_rows, height, threads, height * width, AA_MIN_BAND_PIXELS)

    def mark(first_row: int) -> tuple[np.ndarray, np.ndarray]:
        last_row = min(first_row + rows_per_band, height)
        low, high = max(first_row - MARK_RING, 0), min(last_row + MARK_RING, height)
        rows = slice(low * width, high * width)
        band = CentreGrid(grid.index_triangle[rows], grid.shading_normal[rows],
                          np.zeros((rows.stop - rows.start, 3)) if grid.emission is None else grid.emission[rows])
        marked, step = refine_pixels(scene, band, radiance[rows], (high - low, width), settings, tracer,
                                     (x0, y0 + low, x1, y0 + high), floor)
        inner = (marked // width + low >= first_row) & (marked // width + low < last_row)
        return marked[inner] + low * width, step[inner]
    # Bands of rows side by side on the threads, in order.
    marks = map_batches(mark, range(0, height, rows_per_band), threads)
    return np.concatenate([m[0] for m in marks]), np.concatenate([m[1] for m in marks])


def _brightest(frame: ShadedFrame) -> float:
    """The largest channel of radiance with emission over the frame's centres (a million at a time)."""
    brightest, step = 0.0, 1 << 20
    for first in range(0, len(frame.radiance), step):  # chunks of centres: bounded temporaries
        rows = slice(first, first + step)
        seen = frame.radiance[rows] if frame.grid.emission is None else frame.radiance[rows] + frame.grid.emission[rows]
        brightest = max(brightest, float(seen.max(initial=0.0)))
    return brightest


def _frame_scale(scene: Scene, tracer, extent: float, frames, settings: Settings, progress: Progress, stats: dict,
                 frame: ShadedFrame) -> FrameScale:
    """``antialias.FrameScale`` of the whole frame, the same whichever window ``frame`` covers: from every
    centre of a small frame, from ``probe_centres``' patches of a larger one. Centres the window has are
    read from ``frame``; the others are shaded here by silhouettes (each on its own, stored as float32 like
    the frame's), so a tile gets the frame's numbers. A frame of the reference integrator (no
    ``frame.edges``) takes those from silhouettes too (exact as well, and the reference's every-triangle
    lists would cost minutes a frame): its window then draws the samples the default's window draws."""
    camera = scene.camera
    full = (0, 0, camera.width, camera.height)
    probe = probe_centres(camera.width, camera.height)
    progress = progress.nested(warnings=False)  # part of anti-aliasing; the window has warned already
    edges = frame.edges

    def silhouette_edges() -> MeshEdges:
        if edges is not None:
            return edges
        compile_kernels(groups_for(scene), progress.check_cancel)
        return MeshEdges.from_triangles(scene.triangles, frames, progress.check_cancel)

    if probe is None:
        if camera.window == full:
            whole = frame
        else:  # a window of a small frame: the rest of the frame's centres, once
            whole_scene = replace(scene, camera=replace(camera, window=full))
            whole = silhouette_frame(whole_scene, tracer, extent, frames, settings.replace(integrator="analytic"),
                                      progress, {}, global_pixels(whole_scene.camera), edges=silhouette_edges())
            scene = whole_scene
        floor = 1e-4 * max(_brightest(whole), 1e-30)
        pixels, contrast = _marked_pixels(scene, tracer, settings, whole, floor)
        return FrameScale(floor, neyman_share(contrast, settings.aa_samples))
    xs, ys = probe_pixels(*probe)
    x0, y0, x1, y1 = camera.window
    inside = (xs >= x0) & (xs < x1) & (ys >= y0) & (ys < y1)
    local = ((ys - y0) * (x1 - x0) + xs - x0)[inside]
    index_triangle = np.full(len(xs), -1, frame.grid.index_triangle.dtype)
    normal = np.zeros((len(xs), 3), np.float32)
    seen = np.zeros((len(xs), 3), np.float32)
    index_triangle[inside] = frame.grid.index_triangle[local]
    normal[inside] = frame.grid.shading_normal[local]
    seen[inside] = frame.radiance[local] if frame.grid.emission is None else \
        frame.radiance[local] + frame.grid.emission[local]
    outside = np.flatnonzero(~inside)
    if len(outside):
        surface = surface_points(scene, tracer, extent, settings, xs[outside], ys[outside])
        radiance, _, _ = illuminate(surface, frames, None, tracer, None, settings.replace(integrator="analytic"),
                                     ys[outside] * camera.width + xs[outside], progress, scene.materials, False,
                                     silhouette_edges())
        index_triangle[outside] = surface.index_triangle
        normal[outside] = surface.shading_normal
        seen[outside] = radiance.astype(np.float32) + surface.emission.astype(np.float32)
        stats["aa_probe_pixels"] = len(outside)
    return patch_scale(scene, index_triangle, normal, seen, (3 * len(probe[1]), 3 * len(probe[0])), settings)


def _sample_bands(row: np.ndarray, samples: np.ndarray, height: int, most_rows: int, most_samples: float):
    """Bands (first_row, last_row) of the window for anti-aliasing: at most ``most_rows`` rows and, where a
    row allows, about ``most_samples`` samples (``samples`` (P,) of the pixels in rows ``row`` (P,))."""
    per_row = np.bincount(row, weights=samples, minlength=height)
    bands = []
    first = 0
    while first < height:  # bands: a handful
        taken = np.cumsum(per_row[first:first + most_rows])
        rows = max(1, int(np.searchsorted(taken, most_samples, side="right")))
        bands.append((first, min(first + rows, height)))
        first += rows
    return bands


# Anti-aliasing samples traced and shaded together at most: a sample's camera ray, surface point, BSDF
# and pass-2 couples take about 1.5 KB while it is shaded, its RGBA, position and triangle 56 bytes after.
# A band of 300,000 samples shaded at once (chairs.blend at 512 px) took 390 MB of temporaries.
AA_SHADE_BATCH = 1 << 16


def _shade_samples(pixels: np.ndarray, counts, *shading, first=0
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Shade ``counts`` (int or (P,)) anti-aliasing samples of each of ``pixels`` (P,), in runs of pixels
    of about AA_SHADE_BATCH samples (``_shade_sample_batch``; ``shading``: its arguments after the counts).

    ``first`` (int or (P,)) is the index of each pixel's first sample in its sequence (a later batch).
    Returns (N, 4) RGBA, (N, 2) raster positions, (N,) triangles seen (-1: none) and the texture's part
    (``_texture_part``: (N, 6), or (N, 0) in a scene without textures) of the N = counts.sum() samples,
    pixel-major. A sample's value does not depend on the samples shaded with it.
    """
    counts = np.broadcast_to(np.asarray(counts, dtype=np.int64), (len(pixels),))
    first = np.broadcast_to(np.asarray(first, dtype=np.int64), (len(pixels),))
    ends = np.cumsum(counts)
    cuts = np.searchsorted(ends, np.arange(AA_SHADE_BATCH, int(ends[-1]) if len(ends) else 0, AA_SHADE_BATCH),
                           side="right")
    bounds = np.unique(np.concatenate([[0], cuts, [len(pixels)]])) if len(pixels) else np.zeros(2, np.int64)
    parts = [_shade_sample_batch(pixels[lo:hi], counts[lo:hi], *shading, first=first[lo:hi])
             for lo, hi in zip(bounds[:-1], bounds[1:])]  # runs of pixels, AA_SHADE_BATCH samples each
    if len(parts) == 1:
        return parts[0]
    return tuple(np.concatenate([part[k] for part in parts]) for k in range(4))


def _texture_part(scene: Scene, surface: SurfacePoints, radiance: np.ndarray) -> np.ndarray:
    """What ``antialias.pool_samples`` takes from textures: (N, 6) float64, the reflected ``radiance`` (N, 3)
    at the points (what their albedo scales) and their albedo where they see a textured diffuse surface
    (``surface.albedo_scaled_materials``; NaN elsewhere); (N, 0) where the scene has none."""
    if not has_albedo_scaled(scene):
        return np.zeros((len(surface), 0))
    textured = surface.hit & albedo_scaled_materials(scene)[np.maximum(surface.material, 0)]
    return np.concatenate([radiance, np.where(textured[:, None], surface.albedo, np.nan)], axis=1)


def _shade_sample_batch(pixels: np.ndarray, counts: np.ndarray, scene: Scene, tracer, extent: float,
                        settings: Settings, pixel_global: np.ndarray, frames, polygons, progress: Progress,
                        stats: dict, lazy_state, verify: bool, edges: MeshEdges | None = None, first=0
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``_shade_samples`` of one run of pixels, all at once.

    ``lazy_state`` is (outer_map, outer window, outer_surface) of the lazy integrators, None otherwise.
    """
    sub, position, sub_global = subpixel_samples(scene, tracer, extent, pixels, settings, pixel_global, counts,
                                                 first)
    landing = landing_pixels(position)
    if lazy_state is not None:
        outer_map, outer, outer_surface = lazy_state
        sub_map = cull_to_samples(inherit_blockers(outer_map, outer, landing, len(frames)), sub, frames,
                                  polygons, settings, progress)
        # A pixel's list holds for the surface seen at its centre, not on another surface seen
        # between centres (a slat's face: the chapel at filter 1.5 was +8.6% too bright), so those
        # samples are always verified. Elsewhere a sample can still meet a blocker that parallax
        # hides at the centre; with verification asked for, every sample is verified.
        check = sub.hit if verify else foreign_samples(sub, landing, outer_surface, outer)
        stats["aa_verified_samples"] = stats.get("aa_verified_samples", 0) + int(check.sum())
        sub_radiance, rays = shade_verified(sub, frames, polygons, tracer, sub_map, settings, sub_global,
                                             progress, scene.materials, check, counts)
        stats["verify_rays"] += rays
    else:
        sub_map = None if settings.integrator == "standard_mc" or edges is not None else \
            reference_blocker_map(sub, frames, polygons, (len(sub), 1), settings, progress)
        sub_radiance, _, _ = illuminate(sub, frames, polygons, tracer, sub_map, settings, sub_global,
                                         progress, scene.materials, edges=edges)
    return sample_rgba(sub_radiance, sub, scene, settings), position, sub.index_triangle, \
        _texture_part(scene, sub, sub_radiance)


@dataclass(frozen=True)
class _SpreadAllocation:
    """What ``_shade_until_settled`` needs to allocate samples by ``antialias.surface_spread``.

    shape : (H, W) the window; centre_rgba, centre_stratum : window-local pixels (M,) -> their centres'
    RGBA (M, 4) and surfaces (M,); samples : spread (P,) -> samples still to draw (P,) int64 (the contrast
    allocation's rule, the centre not counted where coverage makes it a sample); centre_texture :
    window-local pixels (M,) -> their centres' ``_texture_part`` (M, 6) (or (M, 0)).
    """

    shape: tuple[int, int]
    centre_rgba: Callable[[np.ndarray], np.ndarray]
    centre_stratum: Callable[[np.ndarray], np.ndarray]
    samples: Callable[[np.ndarray], np.ndarray]
    centre_texture: Callable[[np.ndarray], np.ndarray]


def _shade_until_settled(pixels: np.ndarray, drawn: np.ndarray, contrast: np.ndarray, centre: SurfacePoints,
                         centre_radiance: np.ndarray, strata: SurfaceStrata, shading: tuple,
                         counted: np.ndarray | None = None, spread: _SpreadAllocation | None = None
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, tuple | None]:
    """Shade the anti-aliasing samples of ``pixels`` (P,): a pilot of ``PILOT_SAMPLES`` each, then the rest
    of ``drawn`` (P,) only where the pilot has not settled (``antialias.settled_pixels``); with ``spread``
    and coverage rays, at most as many as the variation within the pixel's surfaces asks for
    (``antialias.surface_spread``), while its coverage rays stay as many as ``drawn`` asks for.

    ``contrast`` (P,) is each pixel's radiance step to its neighbours, ``centre`` and ``centre_radiance``
    (P, 3) pass 1's points and radiance at the pixels' centres, ``strata`` (T,) ``surface_strata``,
    ``shading`` the arguments ``_shade_samples`` takes after the counts; ``counted`` (P,) bool the pixels
    whose settling the stats count (default all).
    Returns the samples drawn per pixel (P,) int64 and ``_shade_samples``' RGBA, positions, triangles and
    texture parts of them, pixel-major: each pixel's pilot, then its further samples (the next points of its
    sequence); and
    the pilot's coverage with the pixels (P,) bool that drew only their pilot, whose coverage it is
    (``_pool_with_coverage`` traces theirs again otherwise), or None where none was traced.
    """
    scene, tracer, settings, pixel_global, stats = shading[0], shading[1], shading[3], shading[4], shading[8]
    pilot = np.minimum(drawn, PILOT_SAMPLES) if settings.aa_settle_tolerance > 0 else drawn
    by_contrast = drawn
    rgba, position, triangle, texture = _shade_samples(pixels, pilot, *shading)
    rest = drawn - pilot
    if not rest.any():
        return drawn, rgba, position, triangle, texture, None
    centre_rgba = sample_rgba(centre_radiance, centre, scene, settings)
    centre_stratum = stratum_of(centre.index_triangle, strata)
    pilot_stratum = stratum_of(triangle, strata)
    pilot_coverage = None
    if settings.aa_coverage_rays > 0:
        pilot_coverage = pixel_coverage(scene, tracer, pixels, pilot, pilot_stratum, strata, settings, pixel_global,
                                        sample_albedo=_albedo_of(texture), sample_position=position)
        one_surface = covers_one_surface(pilot_coverage, centre_stratum)
        if spread is not None:
            pilot_offset = position - np.repeat(np.stack(pixel_coordinates(scene.camera, pixels), axis=1) + 0.5,
                                                pilot, axis=0)
            within = surface_spread(pixels, spread.shape, settings.filter_reach, pilot_coverage, rgba, pilot_stratum,
                                    pilot, spread.centre_rgba, spread.centre_stratum, contrast, texture,
                                    spread.centre_texture, pilot_offset)
            drawn = np.maximum(np.minimum(drawn, spread.samples(within)), pilot)
            rest = drawn - pilot
    else:
        owner = np.repeat(np.arange(len(pixels)), pilot)
        one_surface = np.bincount(owner, weights=pilot_stratum != centre_stratum[owner], minlength=len(pixels)) == 0
    scale = np.maximum(np.abs(centre_rgba[:, :3]).max(axis=1), contrast)
    calm = settled_pixels(rgba, pilot, centre_rgba, one_surface, settings.aa_settle_tolerance * scale)
    more = ~calm & (rest > 0)
    settled = ~more if counted is None else ~more & counted
    stats["aa_settled_pixels"] = stats.get("aa_settled_pixels", 0) + int(settled.sum())
    # Coverage rays as the contrast allocated (but where one surface settled): at an outline between two
    # smooth surfaces they carry the jump, however few samples the surfaces need (with as few rays as
    # samples the error there doubled).
    rays = coverage_rays(np.where(calm, pilot, by_contrast), settings)
    known = None if pilot_coverage is None else (pilot_coverage, ~more & (rays == coverage_rays(pilot, settings)),
                                                 rays)
    if not more.any():
        return pilot, rgba, position, triangle, texture, known
    extra = _shade_samples(pixels[more], rest[more], *shading, first=pilot[more])
    final = np.where(more, drawn, pilot)
    start = np.cumsum(final) - final
    added = np.zeros(len(pixels), np.int64)
    added[more] = rest[more]
    pilot_rows = np.repeat(start, pilot) + _ranks(pilot)
    extra_rows = np.repeat(start + pilot, added) + _ranks(added)
    merged = []
    for first_part, second_part in zip((rgba, position, triangle, texture), extra):  # four arrays
        out = np.empty((int(final.sum()),) + first_part.shape[1:], first_part.dtype)
        out[pilot_rows], out[extra_rows] = first_part, second_part
        merged.append(out)
    return (final, *merged, known)


def _albedo_of(texture: np.ndarray | None) -> np.ndarray | None:
    """The albedo columns (N, 3) of samples' ``_texture_part`` (N, 6), or None without textures."""
    return None if texture is None or texture.shape[1] == 0 else texture[:, 3:6]


def _ranks(counts: np.ndarray) -> np.ndarray:
    """(counts.sum(),) int64: 0 .. counts[i] - 1 for each i in turn."""
    counts = np.asarray(counts, dtype=np.int64)
    return np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)


def _pool_with_coverage(scene: Scene, tracer, centres: Callable, radiance: np.ndarray, pixels: np.ndarray,
                        drawn: np.ndarray, rgba: np.ndarray, position: np.ndarray, triangle: np.ndarray,
                        strata: SurfaceStrata, settings: Settings, pixel_global: np.ndarray, stats: dict,
                        known: tuple | None = None, texture: np.ndarray | None = None) -> np.ndarray:
    """Filtered RGBA (P, 4) of the anti-aliased ``pixels`` from their ``drawn`` (P,) shaded samples (RGBA
    (N, 4), raster positions (N, 2), triangles seen (N,)), coverage rays and the centres of the pixels
    under their filters (pass 1's radiance (H * W, 3) over the window; ``centres``: window-local pixels ->
    their SurfacePoints).

    Which surface each sample, coverage ray and centre sees: the jumps between surfaces come from the
    cheap coverage rays, and the shaded points only average within each surface (``pool_samples``).
    ``known``: a coverage traced already (``_shade_until_settled``'s pilot) and the pixels (P,) bool whose
    coverage it is for their ``drawn`` samples; only the others' is traced here. ``texture`` (N, 6) the
    samples' ``_texture_part`` (None or (N, 0): no textures).
    """
    sample_albedo = _albedo_of(texture)
    camera = scene.camera
    sample_stratum = stratum_of(triangle, strata)
    if known is None:
        coverage = pixel_coverage(scene, tracer, pixels, drawn, sample_stratum, strata, settings, pixel_global,
                                  sample_albedo=sample_albedo, sample_position=position)
        stats["aa_coverage_rays"] = stats.get("aa_coverage_rays", 0) + coverage.rays
    else:
        coverage = _with_known_coverage(scene, tracer, pixels, drawn, sample_stratum, strata, settings, pixel_global,
                                        stats, *known, sample_albedo=sample_albedo, sample_position=position)
    lattice = lattice_pixels(pixels, camera.window_shape, settings.filter_reach)
    lattice_points = centres(lattice)
    lattice_position = np.stack(pixel_coordinates(camera, lattice), axis=1) + 0.5
    owner = np.concatenate([np.repeat(np.arange(len(pixels)), drawn), np.full(len(lattice), -1)])
    textures = None
    if sample_albedo is not None:
        both = np.concatenate([texture, _texture_part(scene, lattice_points, radiance[lattice])])
        textures = (both[:, :3], both[:, 3:])
    return pool_samples(np.concatenate([rgba, sample_rgba(radiance[lattice], lattice_points, scene, settings)]),
                        np.concatenate([position, lattice_position]), owner, pixels, drawn, camera.window, settings,
                        np.concatenate([sample_stratum, stratum_of(lattice_points.index_triangle, strata)]),
                        coverage, lattice_density=1.0, texture=textures)


def _with_known_coverage(scene: Scene, tracer, pixels: np.ndarray, drawn: np.ndarray, sample_stratum: np.ndarray,
                         strata: SurfaceStrata, settings: Settings, pixel_global: np.ndarray, stats: dict,
                         known: Coverage, reuse: np.ndarray, rays: np.ndarray,
                         sample_albedo: np.ndarray | None = None, sample_position: np.ndarray | None = None
                         ) -> Coverage:
    """``pixel_coverage`` of ``pixels`` with ``drawn`` samples, where the pixels ``reuse`` (P,) bool have it in
    ``known`` already (the same rays: a pixel's coverage depends only on its samples drawn): the others' is
    traced and the two merged in key order. Counts every ray traced, the known ones included."""
    redo = np.flatnonzero(~reuse)
    none = np.zeros(0, np.int64)
    redone = np.repeat(~reuse, drawn)
    fresh = pixel_coverage(scene, tracer, pixels[redo], drawn[redo], sample_stratum[redone], strata,
                           settings, pixel_global, rays[redo],
                           None if sample_albedo is None else sample_albedo[redone],
                           None if sample_position is None else sample_position[redone]) if len(redo) \
        else Coverage(none, none, np.zeros(0), known.stride, 0, None if known.albedo is None else np.zeros((0, 3)),
                      known.parent, np.zeros((0, 2)))
    stats["aa_coverage_rays"] = stats.get("aa_coverage_rays", 0) + known.rays + fresh.rays
    kept = reuse[known.pixel]
    pixel = np.concatenate([known.pixel[kept], redo[fresh.pixel]])
    stratum = np.concatenate([known.stratum[kept], fresh.stratum])
    fraction = np.concatenate([known.fraction[kept], fresh.fraction])
    order = np.argsort(pixel * known.stride + stratum + 1, kind="stable")
    albedo = None if known.albedo is None else np.concatenate([known.albedo[kept], fresh.albedo])[order]
    centroid = None if known.centroid is None or fresh.centroid is None else \
        np.concatenate([known.centroid[kept], fresh.centroid])[order]
    return Coverage(pixel[order], stratum[order], fraction[order], known.stride, known.rays + fresh.rays, albedo,
                    known.parent, centroid)
