"""The frame of pixel centres: pass 1 and pass 2 at every pixel's centre, band by band, composed into
the image and its passes (``RenderOutput``).

``_primary`` / ``surface_points`` trace the camera rays (what each pixel's centre sees);
``silhouette_frame`` shades the centres by silhouettes (the default: the edge tree finds every edge that
can cross a light, ``silhouettes`` turns them into the visible part of each light) in bands of rows whose
size the memory budget sets (``working_budget_mb``, ``band_rows_for``); ``blocker_map_frame`` is the
paper's route (a blocker map seeded by shadow rays, ``blocker_map``, then blocker subtraction). Both
return a ``ShadedFrame``: the output so far and what anti-aliasing (``supersampling``) needs of it.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Callable

import numpy as np

from .antialias import sample_rgba
from .blocker_map import BlockerMap, build_blocker_map, flood_fill, reference_blocker_map
from .blockers import BlockerPolygons
from .camera import camera_rays, clip_distance, pixel_coordinates, planar_depth, window_pixels
from .edge_tree import MeshEdges
from .parallel import map_batches, thread_count
from .progress import Progress
from .scene import LOBES_ALL, Camera, Scene
from .settings import Settings
from .shading import (MIN_SHARED_BATCH, clamped_caps, illuminate, near_hull_misses, warn_clamped_caps,
                      warn_near_hulls)
from .kernels import compile_kernels, groups_for
from .surface import SurfacePoints, shade_hits


# Depth written where no surface is seen (Blender's convention for an empty Z pass).
BACKGROUND_DEPTH = 1e10


@dataclass
class RenderOutput:
    """The image and its passes, for the rendered window (row 0 = top row).

    Attributes
    ----------
    combined : (H, W, 4) float32     linear RGBA; alpha 1 where a surface is seen.
    blocker_count : (H, W) int32     blocker–light pairs stored per pixel.
    umbra : (H, W, L) bool           the light is hidden at this pixel (umbra detection).
    depth : (H, W) float32           planar camera depth, BACKGROUND_DEPTH where nothing is hit.
    normal : (H, W, 3) float32       world-space shading normal facing the camera (0 on background).
    sample_count : (H, W) int32      camera samples drawn for the pixel where anti-aliased (``aa_samples`` on
                                     average, more at stronger edges), 1 where the centre was shaded alone.
    warnings : list[str]
    stats : dict                     stage seconds, rays, pairs, peak memory.
    """

    combined: np.ndarray
    blocker_count: np.ndarray
    umbra: np.ndarray
    depth: np.ndarray
    normal: np.ndarray
    sample_count: np.ndarray
    warnings: list = field(default_factory=list)
    stats: dict = field(default_factory=dict)


def frame_camera(camera: Camera, settings: Settings) -> tuple[Camera, tuple[int, int, int, int]]:
    """The camera a render traces (``camera`` checked again; a window grown by ``aa_margin``) and the window
    it returns (x0, y0, x1, y1). A window (a border render, a farm's tile) is rendered with a margin that
    anti-aliasing's decisions for its pixels read, then cropped: its pixels are the full frame's."""
    camera = replace(camera)  # __post_init__ checks it again, as ``Scene.validated`` does
    wanted_window = camera.window
    margin = aa_margin(settings)
    if margin and wanted_window != (0, 0, camera.width, camera.height):
        camera = replace(camera, window=_grown_window(camera, margin))
    return camera, wanted_window


@dataclass
class CentreGrid:
    """What anti-aliasing reads of every pixel centre of the window (N = H * W, row-major): the triangle seen
    (N,) int32 or int64 (-1: none), its shading normal (N, 3) and emitted radiance (N, 3) float32 (float64
    in the blocker-map path; emission None: none emits)."""

    index_triangle: np.ndarray
    shading_normal: np.ndarray
    emission: np.ndarray


@dataclass
class ShadedFrame:
    """Pass 2's result over the window, before anti-aliasing.

    Attributes
    ----------
    output : RenderOutput        every pass composed from the pixel centres.
    radiance : (N, 3) float32    reflected radiance at the centres (float64 in the blocker-map path).
    grid : CentreGrid            the centres' triangles, normals and emission.
    centres : callable           window-local pixels (P,) int64 -> their SurfacePoints (the ones pass 2
                                 shaded: kept, or traced again, which gives the same points).
    band_rows : int              rows per band of the frame (the memory budget's).
    lazy_state, polygons, verify, edges: what the anti-aliasing samples are shaded with.
    """

    output: RenderOutput
    radiance: np.ndarray
    grid: CentreGrid
    centres: Callable
    band_rows: int
    lazy_state: tuple | None = None
    polygons: BlockerPolygons | None = None
    verify: bool = False
    edges: MeshEdges | None = None


# Bytes per pixel of the frame's own arrays, which live through the whole render: the centres' radiance,
# triangle and normal that anti-aliasing reads (40), the passes (40 to 50), the pixels' full-frame indices
# (8); with a margin for the passes' final reshapes and a light's umbra flags.
FRAME_PIXEL_BYTES = 112


# The least working memory a render takes besides its frame: a band of a row or two and pass 2's smallest
# batches of a few lights (a scene of many lights may need more; pass 2 then names what it needs).
MIN_WORKING_MB = 8.0


# Bytes per triangle of the ray tracer (Embree's BVH and its float32 copy), the edge tree and their builds'
# temporaries, at their peak: measured 1,640 and 1,600 (0.5 and 1 million triangles, 2026-12-05).
GEOMETRY_TRIANGLE_BYTES = 1700


def geometry_mb(triangles: int) -> float:
    """What the geometry's structures of a scene of ``triangles`` triangles take at their peak, MB."""
    return triangles * GEOMETRY_TRIANGLE_BYTES / 2 ** 20


def working_budget_mb(memory_budget_mb: float, height: int, width: int, triangles: int = 0) -> float:
    """The memory budget (MB) left for bands and batches once a ``width`` x ``height`` frame's own arrays
    (FRAME_PIXEL_BYTES a pixel) and the geometry's structures (``geometry_mb``) are paid. Raises
    MemoryError, naming the least budget that renders, when less than MIN_WORKING_MB would be left (so a
    scene too large for the budget stops with a message, not at the operating system's out-of-memory
    killer)."""
    frame_mb = height * width * FRAME_PIXEL_BYTES / 2 ** 20
    mesh_mb = geometry_mb(triangles)
    working = memory_budget_mb - frame_mb - mesh_mb
    if working < MIN_WORKING_MB:
        least = np.ceil(frame_mb + mesh_mb + MIN_WORKING_MB)
        if mesh_mb > frame_mb:
            raise MemoryError(f"memory budget of {memory_budget_mb:g} MB is too small for {triangles:,} triangles "
                              f"(at least {least:.0f} MB: {mesh_mb:.0f} MB for the ray tracer and the edge tree, "
                              f"{frame_mb:.0f} MB for the {width} x {height} frame's passes, {MIN_WORKING_MB:g} MB "
                              "to work in); raise it or simplify the meshes")
        raise MemoryError(f"memory budget of {memory_budget_mb:g} MB is too small for a {width} x {height} "
                          f"frame (at least {least:.0f} MB: {frame_mb:.0f} MB for "
                          f"its passes, {MIN_WORKING_MB:g} MB to work in); raise it")
    return working


# Bytes per pixel of a band's pixel centres and their shading (``SurfacePoints``, about 230, the band's
# radiance and composed passes), and the share of the memory budget a band may take: pass 2's batches
# and the frame's own arrays (about 130 bytes a pixel) take the rest.
BAND_PIXEL_BYTES = 512


BAND_BUDGET_SHARE = 0.25


# Anti-aliasing samples shaded together at most, per MB of the memory budget (a sample's surface point
# and shading take about as much as a pixel centre's).
AA_SAMPLES_PER_MB = (1 << 20) * BAND_BUDGET_SHARE / BAND_PIXEL_BYTES


def _batch_in_flight(settings: Settings, threads: int) -> int:
    """Pixels per batch of camera rays or composing on the thread pool: four pass-2 batches at most, and
    the batches in flight (two per thread) within a band's share of the budget, as the band itself."""
    most = settings.memory_budget_mb * (1 << 20) * BAND_BUDGET_SHARE // (BAND_PIXEL_BYTES * 2 * threads)
    return max(MIN_SHARED_BATCH, min(settings.pixel_batch * 4, int(most)))


def band_rows_for(memory_budget_mb: float, width: int) -> int:
    """Rows of the window per band: the band's centres within BAND_BUDGET_SHARE of the budget (at least
    one row: a budget that small renders slowly, it does not fail)."""
    return max(1, int(memory_budget_mb * (1 << 20) * BAND_BUDGET_SHARE // (BAND_PIXEL_BYTES * max(width, 1))))


def silhouette_frame(scene: Scene, tracer, extent: float, frames, settings: Settings, progress: Progress,
                      stats: dict, pixel_global: np.ndarray, edges: MeshEdges | None = None) -> ShadedFrame:
    """Camera rays, pass 2 by silhouettes and the composed passes, band after band of rows: a band's
    centres live only while it is shaded, so memory follows the band (``band_rows_for``), not the frame.
    Every pixel's value depends on its own centre alone, so bands do not change the image. ``edges``: the
    edge tree, built here (and the kernels compiled) when None."""
    camera = scene.camera
    height, width = camera.window_shape
    n_pixels = height * width
    x0, y0, x1, _ = camera.window
    if edges is None:
        # Numba compiles pass 2's kernels on a machine's first render (``kernels``), then its cache serves
        # them in milliseconds: a stage of its own, so the wait is named and timed, and first, as the edge
        # tree's build runs some of them.
        progress.begin_stage("Compiling kernels")
        stats["kernels_compiled"] = compile_kernels(groups_for(scene), progress.check_cancel)
        progress.begin_stage("Building edge tree")
        edges = MeshEdges.from_triangles(scene.triangles, frames, progress.check_cancel)
        progress.end_stage()
        stats["edge_records"] = len(edges)

    rows_per_band = band_rows_for(settings.memory_budget_mb, width)
    # The frame's own arrays (FRAME_PIXEL_BYTES): what anti-aliasing reads of the centres (emission only
    # once a band emits: most scenes' surfaces do not), float32 as it only takes contrasts and normal steps
    # from them and pools them into float32 RGBA; and the composed passes.
    radiance = np.zeros((n_pixels, 3), np.float32)
    grid = CentreGrid(np.full(n_pixels, -1, np.int32 if len(scene.triangles) < 2 ** 31 else np.int64),
                      np.zeros((n_pixels, 3), np.float32), None)
    combined = np.zeros((n_pixels, 4), np.float32)
    depth = np.full(n_pixels, BACKGROUND_DEPTH, np.float32)
    normal = np.zeros((n_pixels, 3), np.float32)
    arcs_per_pixel = np.zeros(n_pixels, np.int32)
    umbra = np.zeros((n_pixels, len(frames)), bool)
    clamped, near_hulls = set(), {}
    kept = None  # the one band's centres when the frame is a single band (anti-aliasing reuses them)
    for first_row in range(0, height, rows_per_band):  # bands of rows
        last_row = min(first_row + rows_per_band, height)
        rows = slice(first_row * width, last_row * width)
        window = (x0, y0 + first_row, x1, y0 + last_row)
        surface = _primary(scene, tracer, extent, settings, progress, window, stage=(n_pixels, rows.start))
        if frames.any_facing:
            clamped |= clamped_caps(surface, frames)
        if frames.hulls is not None:
            for hull, count in near_hull_misses(surface, frames).items():
                near_hulls[hull] = near_hulls.get(hull, 0) + count
        band, band_stats, _ = illuminate(surface, frames, None, tracer, None, settings, pixel_global[rows], progress,
                                          scene.materials, False, edges, stage=(n_pixels, rows.start))
        progress.begin_stage("Composing passes", n_pixels, rows.start)
        radiance[rows] = band
        grid.index_triangle[rows] = surface.index_triangle
        grid.shading_normal[rows] = surface.shading_normal
        if grid.emission is None and surface.emission.any():
            grid.emission = np.zeros((n_pixels, 3), np.float32)
        if grid.emission is not None:
            grid.emission[rows] = surface.emission
        _compose_in_batches(scene, surface, band, settings, (combined[rows], depth[rows], normal[rows]), progress)
        arcs_per_pixel[rows] = np.minimum(band_stats.pop("arcs_per_pixel"), np.iinfo(np.int32).max)
        umbra[rows] = band_stats.pop("umbra")
        for name, value in band_stats.items():
            if name == "max_blockers_per_couple":
                stats[name] = max(stats.get(name, 0), value)
            else:
                stats[name] = stats.get(name, 0) + value
        kept = surface if first_row == 0 and last_row == height else None
        del surface, band  # before the next band's are made: one band's centres at a time
    progress.end_stage()
    stats["bands"] = -(-height // rows_per_band)
    warn_clamped_caps(clamped, progress)
    warn_near_hulls(near_hulls, progress)
    # The passes' blocker count becomes the silhouette arcs crossing the pixel's lights.
    stats["missed_pairs_found"] = []
    stats["pairs_stored"] = int(arcs_per_pixel.sum(dtype=np.int64))
    folded = _folded_umbra(frames, umbra, scene.light_count)
    output = RenderOutput(combined.reshape(height, width, 4), arcs_per_pixel.reshape(height, width),
                          folded.reshape(height, width, scene.light_count), depth.reshape(height, width),
                          normal.reshape(height, width, 3), np.ones((height, width), np.int32))

    def centres(pixels: np.ndarray) -> SurfacePoints:
        if kept is not None:
            return kept.take(pixels)
        return surface_points(scene, tracer, extent, settings, *pixel_coordinates(camera, pixels))
    return ShadedFrame(output, radiance, grid, centres, rows_per_band, edges=edges)


def blocker_map_frame(scene: Scene, tracer, extent: float, frames, settings: Settings, progress: Progress,
                       stats: dict, pixel_global: np.ndarray) -> ShadedFrame:
    """Camera rays, pass 1 (the paper's blocker map, or the reference's every-triangle lists), pass 2 and
    the composed passes over the whole window at once (the frame is not split into bands here)."""
    camera = scene.camera
    height, width = camera.window_shape
    n_pixels = height * width
    polygons = BlockerPolygons.from_triangles(scene.triangles, merge=settings.merge_quads)
    stats["blocker_polygons"] = len(polygons)
    lazy = settings.integrator in ("analytic", "reduced_mc")
    blockers = None
    if lazy:
        # Pass 1 runs over the window grown by a margin; pass 2 shades only the window.
        outer = _grown_window(camera, settings.window_margin)
        outer_surface = _primary(scene, tracer, extent, settings, progress, outer)
        outer_shape = (outer[3] - outer[1], outer[2] - outer[0])
        n_outer = outer_shape[0] * outer_shape[1]
        outer_global = global_pixels(camera, outer)
        outer_map = build_blocker_map(outer_surface, frames, polygons, tracer, outer_shape, outer_global,
                                      settings, progress)
        inner = _inner_indices(camera.window, outer)
        surface = outer_surface.take(inner)
        blockers = outer_map.crop(inner, n_outer)
        stats.update(outer_map.stats)
    else:
        surface = _primary(scene, tracer, extent, settings, progress)
        if settings.integrator == "reference":
            blockers = reference_blocker_map(surface, frames, polygons, (height, width), settings, progress)
            stats.update(blockers.stats)

    if frames.any_facing:
        warn_clamped_caps(clamped_caps(surface, frames), progress)
    if frames.hulls is not None:
        warn_near_hulls(near_hull_misses(surface, frames), progress)
    if not frames.cast_shadow.all():
        progress.warn("lights with Cast Shadow off cast shadows with the paper's blocker maps and the Monte Carlo "
                      "integrators; the default silhouettes honour it")
    if (frames.lobes != LOBES_ALL).any() and settings.integrator in ("reduced_mc", "standard_mc"):
        progress.warn("lights' Ray Visibility (Diffuse, Glossy) is honoured by the Analytic and Reference "
                      "integrators; the Monte Carlo integrators light every lobe")
    verify = lazy and settings.verify_rays > 0 and len(frames) > 0
    radiance, pass2_stats, missed = illuminate(surface, frames, polygons, tracer, blockers, settings, pixel_global,
                                                progress, scene.materials, verify)
    stats.update(pass2_stats)
    stats["missed_pairs_found"] = []
    for _ in range(settings.refine_rounds if verify else 0):  # refinement rounds: a few
        stats["missed_pairs_found"].append(len(missed[0]))
        if len(missed[0]) == 0:
            break
        # Missed pairs are new seeds: flood-fill them over the outer grid, merge, re-shade what changed.
        pixel, blocker, light, umbra, fill_stats = flood_fill(outer_surface, frames, polygons, outer_shape,
                                                              inner[missed[0]], missed[1], missed[2], settings,
                                                              progress)
        if not settings.umbra_detection:
            umbra[:] = False
        merged = BlockerMap.from_entries(np.concatenate([outer_map.pixel, pixel]),
                                         np.concatenate([outer_map.light, light]),
                                         np.concatenate([outer_map.blocker, blocker]), outer_map.umbra | umbra)
        window_map = merged.crop(inner, n_outer)
        n_window = len(inner)
        changed = np.flatnonzero((window_map.count_per_pixel(n_window) != blockers.count_per_pixel(n_window))
                                 | (window_map.umbra != blockers.umbra).any(axis=1))
        outer_map, blockers = merged, window_map
        if len(changed) == 0:
            break
        part, part_stats, missed = illuminate(surface.take(changed), frames, polygons, tracer,
                                               window_map.crop(changed, n_window), settings, pixel_global[changed],
                                               progress, scene.materials, verify)
        radiance[changed] = part
        missed = (changed[missed[0]], missed[1], missed[2])
        stats["verify_rays"] += part_stats["verify_rays"]
        stats["reshaded_pixels"] = stats.get("reshaded_pixels", 0) + len(changed)
    if blockers is not None:
        stats["pairs_stored"] = len(blockers.pixel)
    progress.begin_stage("Composing passes")
    combined, depth, normal = _compose_centres(scene, surface, radiance, settings)
    count, umbra = _blocker_passes(frames, blockers, n_pixels, scene.light_count)
    output = RenderOutput(combined.reshape(height, width, 4), count.reshape(height, width),
                          umbra.reshape(height, width, scene.light_count), depth.reshape(height, width),
                          normal.reshape(height, width, 3), np.ones((height, width), np.int32))
    progress.end_stage()
    grid = CentreGrid(surface.index_triangle, surface.shading_normal, surface.emission)
    return ShadedFrame(output, radiance, grid, surface.take, height,
                       (outer_map, outer, outer_surface) if lazy else None, polygons, verify)


# Rows around a band that its inner rows' marks depend on: a pair of neighbours marks both, and a pixel
# with 5 of its 8 neighbours marked is marked too (``adaptive.close_holes``).
MARK_RING = 2


def _compose_in_batches(scene: Scene, surface: SurfacePoints, radiance: np.ndarray, settings: Settings,
                        passes: tuple[np.ndarray, np.ndarray, np.ndarray], progress: Progress) -> None:
    """``_compose_centres`` of a band's points into ``passes`` (views of the frame's RGBA, depth and normal
    rows), in batches on the thread pool (textures are looked up here)."""
    threads = thread_count(settings.threads)
    step = _batch_in_flight(settings, threads)
    starts = list(range(0, len(surface), step))

    def compose(start: int) -> None:
        rows = np.arange(start, min(start + step, len(surface)))
        for target, values in zip(passes, _compose_centres(scene, surface.take(rows), radiance[rows], settings)):
            target[rows] = values
    map_batches(compose, starts, threads, progress,
                [min(start + step, len(surface)) - start for start in starts])


def _compose_centres(scene: Scene, surface: SurfacePoints, radiance: np.ndarray, settings: Settings):
    """The passes the pixel centres give: RGBA (N, 4), planar depth (N,) and shading normal (N, 3), float32."""
    hit = surface.hit
    combined = sample_rgba(radiance, surface, scene, settings).astype(np.float32)
    depth = np.full(len(hit), BACKGROUND_DEPTH, np.float32)
    depth[hit] = planar_depth(scene.camera, surface.position[hit])
    normal = np.zeros((len(hit), 3), np.float32)
    normal[hit] = surface.shading_normal[hit]
    return combined, depth, normal


def _blocker_passes(frames, blockers: BlockerMap | None, n_pixels: int, n_lights: int):
    """Blocker pairs (N,) int32 and umbra (N, lights) bool per pixel of a blocker map (zeros without one)."""
    if blockers is None:
        return np.zeros(n_pixels, np.int32), np.zeros((n_pixels, n_lights), bool)
    return blockers.count_per_pixel(n_pixels), _folded_umbra(frames, blockers.umbra, n_lights)


def _folded_umbra(frames, umbra: np.ndarray, n_lights: int) -> np.ndarray:
    """(N, lights) bool: umbra (N, frames) with a lamp's virtual lights (its three planes) folded into it."""
    if umbra.shape[1] == n_lights:
        return umbra
    folded = np.zeros((len(umbra), n_lights), bool)
    for light, target in enumerate(frames.scene_light):  # frames: a handful
        folded[:, target] |= umbra[:, light]
    return folded


def global_pixels(camera, window=None) -> np.ndarray:
    xs, ys = window_pixels(camera, window)
    return ys * camera.width + xs


def aa_margin(settings: Settings) -> int:
    """Pixels around a window that its anti-aliased pixels depend on (0: none, each pixel is its centre's).

    A pixel's value pools the samples of every anti-aliased pixel whose filter overlaps its own (up to
    twice the filter's reach away); how many samples that one draws depends on its marks and contrast,
    read from the centres MARK_RING pixels around it; and the window's own outermost marks take a guessed
    ring outside it (``refine_pixels``), so they are not the frame's: one pixel more. Pass 2 by
    silhouettes (and the reference integrator) shades each centre on its own, so with this margin a window's
    pixels are the frame's bit for bit; the paper's blocker map floods between pixels, and keeps the wider
    ``window_margin``."""
    if settings.aa_samples <= 1 or not (settings.uses_silhouettes or settings.integrator == "reference"):
        return 0
    return int(np.ceil(2.0 * settings.filter_reach)) + MARK_RING + 1


def _grown_window(camera, margin: int) -> tuple[int, int, int, int]:
    x0, y0, x1, y1 = camera.window
    return (max(0, x0 - margin), max(0, y0 - margin), min(camera.width, x1 + margin), min(camera.height, y1 + margin))


def _inner_indices(window, outer) -> np.ndarray:
    """Row-major indices, in the outer window's grid, of the inner window's pixels (ascending)."""
    x0, y0, x1, y1 = window
    ox0, oy0, ox1, _ = outer
    rows, cols = np.mgrid[y0 - oy0:y1 - oy0, x0 - ox0:x1 - ox0]
    return (rows * (ox1 - ox0) + cols).reshape(-1)


def _primary(scene: Scene, tracer, extent: float, settings: Settings, progress: Progress,
             window=None, stage: tuple[int, int] | None = None) -> SurfacePoints:
    """Camera rays through pixel centres of ``window`` (default: the camera's) and what they see.
    ``stage``: (total, done) of the "Camera rays" stage when the window is a band of a larger frame."""
    xs, ys = window_pixels(scene.camera, window)
    total, done = stage if stage is not None else (len(xs), 0)
    progress.begin_stage("Camera rays", total, done)
    surface = surface_points(scene, tracer, extent, settings, xs, ys, progress)
    progress.end_stage()
    return surface


def surface_points(scene: Scene, tracer, extent: float, settings: Settings, xs: np.ndarray, ys: np.ndarray,
                    progress: Progress | None = None) -> SurfacePoints:
    """What camera rays through the centres of full-frame pixels (xs, ys) (N,) int64 see, in batches (a
    pixel's point does not depend on the batch it is traced in)."""
    camera = scene.camera
    threads = thread_count(settings.threads)
    step = _batch_in_flight(settings, threads)
    starts = list(range(0, max(len(xs), 1), step))

    def trace(start: int) -> SurfacePoints:
        origins, directions = camera_rays(camera, xs[start:start + step], ys[start:start + step])
        hits = tracer.intersect(origins, directions, clip_distance(camera, directions))
        return shade_hits(scene, origins, directions, hits.index_triangle, hits.u, hits.v, extent)

    # The window's arrays, filled batch by batch (a list of parts and their concatenation held the frame
    # twice: at 3840 x 2160 this stage peaked at 3.77 GB, 2.16 GB filled in place); the first batch tells
    # their types, the others are traced and shaded on the thread pool (shading is numpy: textures, normals).
    first = trace(0)
    frame = {f.name: np.empty((len(xs), *getattr(first, f.name).shape[1:]), getattr(first, f.name).dtype)
             for f in fields(SurfacePoints)}

    def fill(start: int, part: SurfacePoints | None = None) -> None:
        part = trace(start) if part is None else part
        for name, array in frame.items():
            array[start:start + step] = getattr(part, name)

    fill(0, first)
    if progress is not None:
        progress.advance(min(step, len(xs)))
    del first
    map_batches(fill, starts[1:], threads, progress,
                [min(start + step, len(xs)) - start for start in starts[1:]])
    return SurfacePoints(**frame)
