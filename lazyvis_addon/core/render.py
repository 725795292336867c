"""The one door into the core: ``render(scene, settings, progress) -> RenderOutput``.

Stages, in order: validate the scene, build the ray tracer, trace camera rays, pass 1 (the blocker map),
pass 2 (illumination per pixel batch), compose the passes.

What depends on the scene alone, not on the camera (the validated scene, the ray tracer, the light frames,
the edge tree) is ``prepare``'s ``PreparedScene``: ``render`` builds one and lets go of it at its end, or
takes one built before (``prepared=``) where several renders of one scene share it (the Rendered
viewport's steps and restarts, ``progressive``), the images the same bit for bit.
"""

from __future__ import annotations

import resource
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field, fields, is_dataclass, replace
from typing import Callable

import numpy as np

from .antialias import (PILOT_SAMPLES, Coverage, FrameScale, SurfaceStrata, centre_suffices, neyman_share,
                        patch_scale, probe_centres, probe_pixels, samples_for, covers_one_surface, cull_to_samples,
                        foreign_samples, inherit_blockers, landing_pixels, lattice_pixels, pixel_coverage,
                        pool_samples, refine_pixels, rgba_of, sample_rgba, settled_pixels, stratum_of,
                        subpixel_samples, surface_spread, surface_strata, coverage_rays)
from .blockers import BlockerPolygons
from .blocker_map import BlockerMap, build_blocker_map, flood_fill, reference_blocker_map
from .camera import camera_rays, clip_distance, pixel_coordinates, planar_depth, window_pixels
from .emitters import (FACING_HULL, crowded_hulls, hull_faces_in_scene, hull_tables, hulls_as_triangles,
                       near_receivers, nearby_geometry)
from .facing import too_close
from .geometry import light_frames
from .parallel import map_batches, thread_count
from .bsdf import SurfaceBsdf
from .geometry import light_groups
from .illumination import (VisiblePieces, couple_weights, couples_for, reflected_radiance, standard_mc,
                           verify_visible, visible_pieces)
from .edge_tree import MeshEdges
from .silhouettes import compile_kernels, pixel_batch_for, silhouette_pieces
from .terminator import terminator_couples
from .progress import Progress
from .scene import LOBES_ALL, Camera, Scene
from .seen_lights import OUTLINE_SAMPLES, draw_seen_lights
from .settings import Settings
from .surface import (SurfacePoints, albedo_scaled_materials, has_albedo_scaled, scene_centre, scene_extent,
                      shade_hits)
from .trace import RayTracer

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


def render(scene: Scene, settings: Settings | None = None, progress: Progress | None = None,
           prepared: PreparedScene | None = None) -> RenderOutput:
    """Render direct illumination from polygon lights with exact soft shadows.

    ``prepared``: the scene's camera-independent structures (``prepare``), kept from an earlier render of
    the same scene (the viewport's steps and restarts); the image is the same bit for bit as without it.
    Without it they are built here and released at the end.

    Raises
    ------
    ValueError      bad input (the message names what is wrong); ``prepared`` not prepared from ``scene``
                    (``PreparedScene.serves``) or closed.
    MemoryError     the memory budget in ``settings`` is too small for the image.
    RenderCancelled the progress object reported a cancel.
    """
    settings = settings or Settings()
    progress = progress or Progress()
    started = time.perf_counter()
    if prepared is None:
        with prepare(scene, settings, progress) as own:  # its warnings went to ``progress`` as they came
            return _render_prepared(own, scene.camera, settings, progress, started, fresh=True)
    if not prepared.serves(scene, settings):
        raise ValueError("the prepared scene was prepared from another scene or for another integrator; "
                         "prepare this one")
    with prepared.use():
        for message in prepared.warnings:  # the scene's own warnings, as a render without it gives them
            progress.warn(message)
        return _render_prepared(prepared, scene.camera, settings, progress, started, fresh=False)


def _frame_camera(camera: Camera, settings: Settings) -> tuple[Camera, tuple[int, int, int, int]]:
    """The camera a render traces (``camera`` checked again; a window grown by ``aa_margin``) and the window
    it returns (x0, y0, x1, y1). A window (a border render, a farm's tile) is rendered with a margin that
    anti-aliasing's decisions for its pixels read, then cropped: its pixels are the full frame's."""
    camera = replace(camera)  # __post_init__ checks it again, as ``Scene.validated`` does
    wanted_window = camera.window
    margin = aa_margin(settings)
    if margin and wanted_window != (0, 0, camera.width, camera.height):
        camera = replace(camera, window=_grown_window(camera, margin))
    return camera, wanted_window


def _render_prepared(prepared: PreparedScene, camera: Camera, settings: Settings, progress: Progress,
                     started: float, fresh: bool) -> RenderOutput:
    """``render`` of ``prepared``'s scene through ``camera``: everything that depends on the camera (the
    window and its margin, the memory budget of the frame, camera rays, pass 2, anti-aliasing, the lights
    the camera sees). ``fresh``: ``prepared`` was built by this render (its stats count the kernels)."""
    camera, wanted_window = _frame_camera(camera, settings)
    scene = replace(prepared.scene, camera=camera)
    height, width = camera.window_shape
    n_pixels = height * width
    stats: dict = {"triangles": len(scene.triangles), "lights": scene.light_count, "pixels": n_pixels}
    # The frame's own arrays and the geometry's structures are paid from the budget first (``prepare``
    # checked it before building them, for the camera it was given); the batches and bands work within
    # the rest.
    working_mb = working_budget_mb(settings.memory_budget_mb, height, width, len(scene.triangles))
    stats["working_budget_mb"] = working_mb
    settings = settings.replace(memory_budget_mb=working_mb)
    tracer, extent, frames, edges = prepared.tracer, prepared.extent, prepared.frames, prepared.edges
    if edges is not None:
        stats["edge_records"] = len(edges)
        stats["kernels_compiled"] = prepared.kernels_compiled and fresh
    # The tracer may have served earlier renders (and serve another render at the same time: a cancelled
    # viewport step still stopping); its counter is the whole tracer's.
    rays_before = tracer.n_rays_cast
    pixel_global = _global_pixels(camera)
    if settings.uses_silhouettes:
        frame = _silhouette_frame(scene, tracer, extent, frames, settings, progress, stats, pixel_global, edges)
    else:
        frame = _blocker_map_frame(scene, tracer, extent, frames, settings, progress, stats, pixel_global)

    resolved = None
    if settings.aa_samples > 1 and (frame.grid.index_triangle >= 0).any():
        resolved = _antialias(scene, tracer, extent, frames, settings, progress, stats, pixel_global, frame,
                              wanted_window)
    output = frame.output
    if resolved is not None:
        pixels, pooled, counts = resolved
        output.combined.reshape(-1, 4)[pixels] = pooled
        output.sample_count.reshape(-1)[pixels] = counts
    if camera.window != wanted_window:
        output = _cropped(output, camera.window, wanted_window)
        scene = replace(scene, camera=replace(camera, window=wanted_window))
        camera, pixel_global = scene.camera, _global_pixels(scene.camera)
        stats["pixels"] = len(pixel_global)
    if len(scene.seen):
        # Lights the camera sees add their radiance over whatever lies behind them (Cycles: a light is no
        # occluder for camera rays and adds no alpha).
        reached, drawn, outlined = draw_seen_lights(scene.seen, camera, tracer, settings, pixel_global, progress)
        output.combined.reshape(-1, 4)[reached, :3] += drawn.astype(np.float32)
        counts = output.sample_count.reshape(-1)
        counts[outlined] = np.maximum(counts[outlined], OUTLINE_SAMPLES)
    stats["rays_cast"] = tracer.n_rays_cast - rays_before
    stats["seconds"] = time.perf_counter() - started
    stats["stage_seconds"] = dict(progress.stage_seconds)
    stats["peak_memory_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    output.stats = stats
    output.warnings = list(progress.warnings)
    return output


class _SharedTracer:
    """A ray tracer held by one or more prepared scenes (a change of lights or materials keeps the BVH):
    its threads stop when the last of them lets go."""

    def __init__(self, tracer: RayTracer) -> None:
        self.tracer = tracer
        self._holders = 1
        self._lock = threading.Lock()

    def share(self) -> "_SharedTracer | None":
        """One more holder; None once the tracer is closed (then build another)."""
        with self._lock:
            if self._holders == 0:
                return None
            self._holders += 1
            return self

    def release(self) -> None:
        with self._lock:
            self._holders -= 1
            last = self._holders == 0
        if last:
            self.tracer.close()


class PreparedScene:
    """What a render builds from the scene alone, whatever the camera, kept for further renders of it.

    ``prepare`` builds it; ``render(scene, settings, progress, prepared=...)`` renders the scene through any
    camera with it (the Rendered viewport's steps at their resolutions, and its restarts while the view
    moves), bit for bit the image of a render without it. Read-only once built, so renders on several
    threads may share it; ``close`` (or a ``with`` block) lets go of it, and its ray tracer's threads stop
    once the last render using it (``use``) has ended.

    Attributes
    ----------
    source : Scene               the scene it was prepared from, its arrays by reference: a scene is not
                                 changed in place once prepared (a change is a new Scene, as the exporter
                                 makes; ``serves`` compares by reference, ``prepare(reuse=)`` by value).
    scene : Scene                ``source`` validated, non-convex mesh emitters as triangles where the
                                 integrator needs them; its camera is the source's (each render sets its own).
    silhouettes : bool           prepared for pass 2 by silhouettes (``Settings.uses_silhouettes``): mesh
                                 emitters and the edge tree depend on it.
    tracer : RayTracer           Embree's BVH over ``scene.triangles``.
    extent : float               the scene's bounding-box diagonal (world units, ``surface.scene_extent``).
    frames : LightFrames         the light frames, ``part_of`` set.
    edges : MeshEdges or None    the edge tree (silhouettes only).
    kernels_compiled : bool      pass 2's kernels were compiled (not loaded from Numba's cache) here.
    warnings : list[str]         the warnings preparing gave (a render given it repeats them).
    reused : tuple[str, ...]     what ``prepare`` took from the scene it was given to reuse: "tracer" (the
                                 same triangles), "lights" (and the same lights: frames and edge tree too).
    """

    def __init__(self, source: Scene, scene: Scene, silhouettes: bool, shared: _SharedTracer, extent: float,
                 frames, edges: MeshEdges | None, kernels_compiled: bool, warnings: list[str],
                 frame_warnings: list[str], reused: tuple[str, ...]) -> None:
        self.source, self.scene, self.silhouettes = source, scene, silhouettes
        self._shared = shared
        self.extent, self.frames, self.edges = extent, frames, edges
        self.kernels_compiled = kernels_compiled
        self.warnings, self._frame_warnings = warnings, frame_warnings
        self.reused = reused
        self._lock = threading.Lock()
        self._users = 0
        self._closing = False
        self._released = False

    @property
    def tracer(self) -> RayTracer:
        return self._shared.tracer

    def serves(self, scene: Scene, settings: Settings) -> bool:
        """Whether ``scene`` is the prepared scene but for its camera (the same arrays by reference: the
        viewport's steps and restarts replace the camera only) and ``settings`` pass 2 the same way."""
        return settings.uses_silhouettes == self.silhouettes and all(
            _same_data(getattr(scene, f.name), getattr(self.source, f.name))
            for f in fields(Scene) if f.name != "camera")

    def acquire(self) -> None:
        """A render (or a run of them) begins to use it: it stays whole until the matching ``release``, even
        if closed meanwhile. Raises ValueError once closed with no render using it (its tracer let go)."""
        with self._lock:
            if self._closing and self._users == 0:
                raise ValueError("the prepared scene is closed")
            self._users += 1

    def release(self) -> None:
        with self._lock:
            self._users -= 1
            free = self._closing and self._users == 0
        if free:
            self._free()

    @contextmanager
    def use(self):
        """``acquire`` ... ``release`` around a block."""
        self.acquire()
        try:
            yield self
        finally:
            self.release()

    def close(self) -> None:
        """Let go of it: its tracer now, or when the last render using it ends (until then those holding it
        may still render with it; afterwards none). Idempotent."""
        with self._lock:
            self._closing = True
            free = self._users == 0
        if free:
            self._free()

    @property
    def closed(self) -> bool:
        """``close`` was called (renders holding it may still be using it)."""
        with self._lock:
            return self._closing

    def _free(self) -> None:
        with self._lock:
            if self._released:
                return
            self._released = True
        self._shared.release()

    def __enter__(self) -> "PreparedScene":
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()


def prepare(scene: Scene, settings: Settings | None = None, progress: Progress | None = None,
            reuse: PreparedScene | None = None) -> PreparedScene:
    """Validate ``scene`` and build what its renders share whatever the camera (``PreparedScene``): the ray
    tracer, the light frames and, for pass 2 by silhouettes, the edge tree. Warnings go to ``progress``
    (and into the result, which repeats them to each render given it).

    ``reuse``: a scene prepared before (not closed; the caller still closes it), whose ray tracer is kept
    where the validated triangles are equal by value, and its light frames and edge tree too where the
    lights are as well (a new export after a change of materials or lights only). The memory budget is
    checked first, for ``scene.camera`` at ``settings``: a scene too large for it fails before anything is
    built.

    Raises ValueError (bad input), MemoryError (budget), RenderCancelled, as ``render``.
    """
    settings = settings or Settings()
    progress = progress or Progress()
    progress.begin_stage("Validating scene")
    warned = len(progress.warnings)
    validated = scene.validated(progress)
    camera, _ = _frame_camera(validated.camera, settings)
    height, width = camera.window_shape
    working_budget_mb(settings.memory_budget_mb, height, width, len(validated.triangles))
    if validated.light_count == 0:
        progress.warn("the scene has no lights: surfaces render black")
    validated = _emitters_as_triangles_where_needed(validated, settings, progress)
    silhouettes = settings.uses_silhouettes
    progress.begin_stage("Building BVH")
    shared, reused = None, ()
    same_triangles = reuse is not None and np.array_equal(reuse.scene.triangles, validated.triangles)
    if same_triangles:
        shared = reuse._shared.share()
        reused = ("tracer",) if shared is not None else ()
    if shared is None:
        shared = _SharedTracer(RayTracer(validated.triangles))
    # Let go of the tracer however preparing ends (a cancel included): its threads would otherwise live
    # until the exception's frames are collected.
    try:
        if same_triangles and reuse.silhouettes == silhouettes and _equal_data(
                (validated.lights, validated.facing, validated.hulls), (reuse.scene.lights, reuse.scene.facing,
                                                                         reuse.scene.hulls)):
            # The frames, the extent and the edge tree depend on the triangles and the lights only.
            extent, frames, edges = reuse.extent, reuse.frames, reuse.edges
            kernels_compiled, frame_warnings = False, list(reuse._frame_warnings)
            for message in frame_warnings:
                progress.warn(message)
            reused += ("lights",)
        else:
            extent = scene_extent(validated)
            frames = light_frames(validated.lights, validated.facing, scene_centre(validated), extent, validated.hulls)
            frames.part_of = hull_faces_in_scene(frames.hulls, validated.triangles)
            before = len(progress.warnings)
            if frames.hulls is not None:
                _warn_nearby_geometry(validated, frames, progress)
            frame_warnings = progress.warnings[before:]
            edges, kernels_compiled = None, False
            if silhouettes:
                progress.begin_stage("Building edge tree")
                edges = MeshEdges.from_triangles(validated.triangles, frames, progress.check_cancel)
                # Numba compiles pass 2's kernels on a machine's first render (about 10 s), then its cache
                # serves them in milliseconds: a stage of its own, so the wait is named and timed.
                progress.begin_stage("Compiling kernels")
                kernels_compiled = compile_kernels()
        progress.end_stage()
    except BaseException:
        shared.release()
        raise
    return PreparedScene(scene, validated, silhouettes, shared, extent, frames, edges, kernels_compiled,
                         progress.warnings[warned:], frame_warnings, reused)


def _same_data(a, b) -> bool:
    """Whether ``a`` and ``b`` hold the same data by reference: arrays over the same memory with the same
    shape, strides and dtype (a view ``Scene.__post_init__`` makes again counts), other values equal;
    field by field of dataclasses, item by item of lists and tuples."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        if not (isinstance(a, np.ndarray) and isinstance(b, np.ndarray)) or a.shape != b.shape or a.dtype != b.dtype:
            return False
        return a.size == 0 or (a.strides == b.strides and
                               a.__array_interface__["data"][0] == b.__array_interface__["data"][0])
    return _walk(a, b, _same_data)


def _equal_data(a, b) -> bool:
    """Whether ``a`` and ``b`` hold equal data by value (arrays: shape, dtype and values), as ``_same_data``
    walks them."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.dtype == b.dtype and \
            np.array_equal(a, b)
    return _walk(a, b, _equal_data)


def _walk(a, b, same: Callable) -> bool:
    """``same`` over the fields of dataclasses and the items of lists and tuples; other values by ==."""
    if is_dataclass(a) and not isinstance(a, type):
        return type(a) is type(b) and all(same(getattr(a, f.name), getattr(b, f.name)) for f in fields(a))
    if isinstance(a, (list, tuple)):
        return type(a) is type(b) and len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    return a is b or (type(a) is type(b) and bool(a == b))


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


def _silhouette_frame(scene: Scene, tracer, extent: float, frames, settings: Settings, progress: Progress,
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
        progress.begin_stage("Building edge tree")
        edges = MeshEdges.from_triangles(scene.triangles, frames, progress.check_cancel)
        progress.end_stage()
        stats["edge_records"] = len(edges)
        # Numba compiles pass 2's kernels on a machine's first render (about 10 s), then its cache serves
        # them in milliseconds: a stage of its own, so the wait is named and timed.
        progress.begin_stage("Compiling kernels")
        stats["kernels_compiled"] = compile_kernels()
        progress.end_stage()

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
            clamped |= _clamped_caps(surface, frames)
        if frames.hulls is not None:
            for hull, count in _near_hull_misses(surface, frames).items():
                near_hulls[hull] = near_hulls.get(hull, 0) + count
        band, band_stats, _ = _illuminate(surface, frames, None, tracer, None, settings, pixel_global[rows], progress,
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
    _warn_clamped_caps(clamped, progress)
    _warn_near_hulls(near_hulls, progress)
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
        return _surface_points(scene, tracer, extent, settings, *pixel_coordinates(camera, pixels))
    return ShadedFrame(output, radiance, grid, centres, rows_per_band, edges=edges)


def _blocker_map_frame(scene: Scene, tracer, extent: float, frames, settings: Settings, progress: Progress,
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
        outer_global = _global_pixels(camera, outer)
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
        _warn_clamped_caps(_clamped_caps(surface, frames), progress)
    if frames.hulls is not None:
        _warn_near_hulls(_near_hull_misses(surface, frames), progress)
    if not frames.cast_shadow.all():
        progress.warn("lights with Cast Shadow off cast shadows with the paper's blocker maps and the Monte Carlo "
                      "integrators; the default silhouettes honour it")
    if (frames.lobes != LOBES_ALL).any() and settings.integrator in ("reduced_mc", "standard_mc"):
        progress.warn("lights' Ray Visibility (Diffuse, Glossy) is honoured by the Analytic and Reference "
                      "integrators; the Monte Carlo integrators light every lobe")
    verify = lazy and settings.verify_rays > 0 and len(frames) > 0
    radiance, pass2_stats, missed = _illuminate(surface, frames, polygons, tracer, blockers, settings, pixel_global,
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
        part, part_stats, missed = _illuminate(surface.take(changed), frames, polygons, tracer,
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
    return ShadedFrame(output, radiance, grid, surface.take, height, (outer_map, outer, outer_surface) if lazy else None,
                       polygons, verify)


def _antialias(scene: Scene, tracer, extent: float, frames, settings: Settings, progress: Progress, stats: dict,
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


# Rows around a band that its inner rows' marks depend on: a pair of neighbours marks both, and a pixel
# with 5 of its 8 neighbours marked is marked too (``adaptive.close_holes``).
MARK_RING = 2


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
        built = MeshEdges.from_triangles(scene.triangles, frames, progress.check_cancel)
        compile_kernels()
        return built

    if probe is None:
        if camera.window == full:
            whole = frame
        else:  # a window of a small frame: the rest of the frame's centres, once
            whole_scene = replace(scene, camera=replace(camera, window=full))
            whole = _silhouette_frame(whole_scene, tracer, extent, frames, settings.replace(integrator="analytic"),
                                      progress, {}, _global_pixels(whole_scene.camera), edges=silhouette_edges())
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
        surface = _surface_points(scene, tracer, extent, settings, xs[outside], ys[outside])
        radiance, _, _ = _illuminate(surface, frames, None, tracer, None, settings.replace(integrator="analytic"),
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


def _global_pixels(camera, window=None) -> np.ndarray:
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


def _cropped(output: RenderOutput, grown, window) -> RenderOutput:
    """``output`` of the window ``grown`` cut to ``window``'s pixels (both full-frame x0, y0, x1, y1)."""
    x0, y0, x1, y1 = window
    rows, columns = slice(y0 - grown[1], y1 - grown[1]), slice(x0 - grown[0], x1 - grown[0])

    def cut(array: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(array[rows, columns])
    return RenderOutput(cut(output.combined), cut(output.blocker_count), cut(output.umbra), cut(output.depth),
                        cut(output.normal), cut(output.sample_count), output.warnings, output.stats)


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
    surface = _surface_points(scene, tracer, extent, settings, xs, ys, progress)
    progress.end_stage()
    return surface


def _surface_points(scene: Scene, tracer, extent: float, settings: Settings, xs: np.ndarray, ys: np.ndarray,
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


# Counters the silhouette pass adds to the render's stats.
SILHOUETTE_COUNTERS = ("nodes_visited", "edge_tests", "arcs", "depth_rays", "inconsistent_couples", "cells")

# Smallest batch split further for threads: per-batch numpy overheads stay well under the work.
MIN_SHARED_BATCH = 1024
# Batches per thread at least (above MIN_SHARED_BATCH pixels each): shadows gather work in a few rows of
# the image, so more, smaller batches even out the threads' loads.
BATCHES_PER_THREAD = 8


def _illuminate(surface: SurfacePoints, frames, polygons, tracer, blockers: BlockerMap | None, settings: Settings,
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
        couples, couple_pixel, origin_shift = terminator_couples(part, frames, couples, couple_pixel, lights)
        found = dict.fromkeys(SILHOUETTE_COUNTERS + ("max_arcs_per_couple",), 0)
        visible = np.zeros(len(couple_pixel), bool)
        weights = np.zeros((len(couple_pixel), 3))
        # Chunks of couples: each couple's terms lie in one chunk, so their clamped sums add.
        for uv, couple, sign, (whole, whole_uv, whole_count) in silhouette_pieces(
                part, frames, edges, tracer, couples, couple_pixel, found, origin_shift):
            fans = VisiblePieces(couples, couple_pixel, uv, np.full(len(couple), 3, np.int64), couple,
                                 found["max_arcs_per_couple"], sign)
            lights_whole = VisiblePieces(couples, couple_pixel, whole_uv, whole_count, whole,
                                         found["max_arcs_per_couple"], np.ones(len(whole)))
            weights += couple_weights(fans, part, frames, bsdf, settings, pixel_global, more=lights_whole)
            visible[couple] = True
            visible[whole] = True
            n_terms += len(couple) + len(whole)
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


def _shade_verified(surface: SurfacePoints, frames, polygons, tracer, blockers: BlockerMap, settings: Settings,
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
        radiance[plain] = _illuminate(surface.take(plain), frames, polygons, tracer, blockers.crop(plain, n_points),
                                      settings, pixel_global[plain], progress, materials)[0]
    chosen = np.flatnonzero(check)
    if len(chosen) == 0 or len(frames) == 0:
        return radiance, 0
    sample_settings = settings.replace(verify_rays=SAMPLE_VERIFY_RAYS)
    radiance[chosen], stats, missed = _illuminate(surface.take(chosen), frames, polygons, tracer,
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
        part, stats, missed = _illuminate(surface.take(changed), frames, polygons, tracer,
                                          blockers.crop(changed, n_points), sample_settings,
                                          pixel_global[changed], progress, materials, True)
        radiance[changed] = part
        rays += stats["verify_rays"]
        missed = (changed[missed[0]], missed[1], missed[2])
    return radiance, rays


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
        sub_radiance, rays = _shade_verified(sub, frames, polygons, tracer, sub_map, settings, sub_global,
                                             progress, scene.materials, check, counts)
        stats["verify_rays"] += rays
    else:
        sub_map = None if settings.integrator == "standard_mc" or edges is not None else \
            reference_blocker_map(sub, frames, polygons, (len(sub), 1), settings, progress)
        sub_radiance, _, _ = _illuminate(sub, frames, polygons, tracer, sub_map, settings, sub_global,
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
    texture parts of them, pixel-major: each pixel's pilot, then its further samples (the next points of its sequence); and
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
                                        sample_albedo=_albedo_of(texture))
        one_surface = covers_one_surface(pilot_coverage, centre_stratum)
        if spread is not None:
            within = surface_spread(pixels, spread.shape, settings.filter_reach, pilot_coverage, rgba, pilot_stratum,
                                    pilot, spread.centre_rgba, spread.centre_stratum, contrast, texture,
                                    spread.centre_texture)
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
                                  sample_albedo=sample_albedo)
        stats["aa_coverage_rays"] = stats.get("aa_coverage_rays", 0) + coverage.rays
    else:
        coverage = _with_known_coverage(scene, tracer, pixels, drawn, sample_stratum, strata, settings, pixel_global,
                                        stats, *known, sample_albedo=sample_albedo)
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
                         sample_albedo: np.ndarray | None = None) -> Coverage:
    """``pixel_coverage`` of ``pixels`` with ``drawn`` samples, where the pixels ``reuse`` (P,) bool have it in
    ``known`` already (the same rays: a pixel's coverage depends only on its samples drawn): the others' is
    traced and the two merged in key order. Counts every ray traced, the known ones included."""
    redo = np.flatnonzero(~reuse)
    none = np.zeros(0, np.int64)
    fresh = pixel_coverage(scene, tracer, pixels[redo], drawn[redo], sample_stratum[np.repeat(~reuse, drawn)], strata,
                           settings, pixel_global, rays[redo],
                           None if sample_albedo is None else sample_albedo[np.repeat(~reuse, drawn)]) if len(redo) \
        else Coverage(none, none, np.zeros(0), known.stride, 0, None if known.albedo is None else np.zeros((0, 3)),
                      known.parent)
    stats["aa_coverage_rays"] = stats.get("aa_coverage_rays", 0) + known.rays + fresh.rays
    kept = reuse[known.pixel]
    pixel = np.concatenate([known.pixel[kept], redo[fresh.pixel]])
    stratum = np.concatenate([known.stratum[kept], fresh.stratum])
    fraction = np.concatenate([known.fraction[kept], fresh.fraction])
    order = np.argsort(pixel * known.stride + stratum + 1, kind="stable")
    albedo = None if known.albedo is None else np.concatenate([known.albedo[kept], fresh.albedo])[order]
    return Coverage(pixel[order], stratum[order], fraction[order], known.stride, known.rays + fresh.rays, albedo,
                    known.parent)


def _clamped_caps(surface: SurfacePoints, frames) -> set[int]:
    """The point and spot lights (scene indices) that some visible point lies too close to (``facing``'s
    MAX_HALF_ANGLE: it sees less of the lamp than Cycles there)."""
    points = surface.position[surface.hit]
    lamps = np.flatnonzero((frames.kind >= 0) & (frames.kind != FACING_HULL))
    return {int(frames.source[light]) for light in lamps if too_close(frames, light, points).any()}  # a handful


def _warn_clamped_caps(close: set[int], progress: Progress) -> None:
    """One warning naming the lamps of ``_clamped_caps``."""
    if close:
        progress.warn("surfaces closer to a point or spot light than 1.7 times its radius get less of its light "
                      f"than in Cycles (point/spot/sun light {', '.join(str(i) for i in sorted(close))})")


def _emitters_as_triangles_where_needed(scene: Scene, settings: Settings, progress: Progress) -> Scene:
    """Non-convex mesh emitters are two lights each for the silhouettes (``emitters``), exact while no other
    geometry lies inside their hull; crowded ones, and all of them under the other integrators, go back to
    one light per face (slower, exact), with one warning for the crowded."""
    other = np.flatnonzero(~scene.hulls.convex)
    if len(other) == 0:
        return scene
    if not settings.uses_silhouettes:
        return hulls_as_triangles(scene, other)
    tables = hull_tables(scene.hulls)
    crowded = np.flatnonzero(crowded_hulls(tables, scene.triangles, hull_faces_in_scene(tables, scene.triangles)))
    if len(crowded):
        progress.warn("mesh emitters with other geometry inside their convex hull are rendered one light per face "
                      f"(slower; emitter {', '.join(map(str, crowded))})")
    return hulls_as_triangles(scene, crowded)


def _near_hull_misses(surface: SurfacePoints, frames) -> dict[int, int]:
    """Mesh emitter (hull) -> visible points that get none of its light (``emitters.near_receivers``: an
    outline with more vertices than budgeted, or a point inside the box of a hull's planes whose inner
    lights fail)."""
    hit = surface.hit
    return near_receivers(frames, surface.position[hit], surface.index_triangle[hit], frames.part_of)


def _warn_near_hulls(missed: dict[int, int], progress: Progress) -> None:
    """One warning naming the emitters of ``_near_hull_misses`` and their pixels."""
    if missed:
        progress.warn("surfaces next to a mesh emitter (seeing more of its outline than budgeted) get none of its "
                      "light "
                      f"({', '.join(f'emitter {h}: {n} pixel(s)' for h, n in sorted(missed.items()))})")


def _warn_nearby_geometry(scene: Scene, frames, progress: Progress) -> None:
    """One warning naming the mesh emitters (hulls) that other geometry comes close to: it may stand between
    the emitter and the plane (or box face) its light is cut in, where it shadows wrongly
    (``emitters.nearby_geometry``)."""
    close = np.flatnonzero(nearby_geometry(frames.hulls, scene.triangles, frames.part_of))
    if len(close):
        progress.warn("geometry within about 4 radii of a mesh emitter may not shadow the emitter's light "
                      "exactly where it is closer to the emitter than its tangent planes "
                      f"(emitter {', '.join(map(str, close))})")
