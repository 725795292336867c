"""The one door into the core: ``render(scene, settings, progress) -> RenderOutput``.

Stages, in order, and where each lives:

- ``prepared``: validate the scene, build the ray tracer, the light frames and the edge tree (what depends
  on the scene alone, not on the camera: ``prepare`` -> ``PreparedScene``; ``render`` builds one and lets
  go of it at its end, or takes one built before, ``prepared=``, where several renders of one scene share
  it: the Rendered viewport's steps and restarts, ``progressive``, the images the same bit for bit).
- ``frame``: camera rays, then every pixel centre shaded band by band, by silhouettes (the default) or by
  the paper's blocker map (pass 1, ``blocker_map``) and blocker subtraction; composed into the passes.
- ``shading``: pass 2 for a batch of points (the visible part of each light, integrated in closed form),
  which the frame and anti-aliasing both call.
- ``supersampling``: anti-aliasing of the edge pixels (the estimators are ``antialias``').
- here: the seen lights drawn over the image, the window cut out of the frame rendered, the stats.
"""

from __future__ import annotations

import resource
import time
from dataclasses import replace

import numpy as np

from .frame import RenderOutput, blocker_map_frame, frame_camera, global_pixels, silhouette_frame, working_budget_mb
from .heap import retained_heap
from .parallel import one_blas_thread, render_threads, thread_count
from .prepared import PreparedScene, prepare
from .progress import Progress
from .scene import Camera, Scene
from .seen_lights import OUTLINE_SAMPLES, draw_seen_lights
from .settings import Settings
from .supersampling import antialias_frame


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
    # The render's threads are its parallelism, one pool shared by all its batches (``parallel.render_threads``,
    # ``parallel.one_blas_thread``), and its batches reuse the heap's freed memory (``heap.retained_heap``).
    with one_blas_thread(), render_threads(thread_count(settings.threads)), retained_heap(settings.memory_budget_mb):
        return _render(scene, settings, progress, prepared, started)


def _render(scene: Scene, settings: Settings, progress: Progress, prepared: PreparedScene | None,
            started: float) -> RenderOutput:
    """``render``'s work."""
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


def _render_prepared(prepared: PreparedScene, camera: Camera, settings: Settings, progress: Progress,
                     started: float, fresh: bool) -> RenderOutput:
    """``render`` of ``prepared``'s scene through ``camera``: everything that depends on the camera (the
    window and its margin, the memory budget of the frame, camera rays, pass 2, anti-aliasing, the lights
    the camera sees). ``fresh``: ``prepared`` was built by this render (its stats count the kernels)."""
    camera, wanted_window = frame_camera(camera, settings)
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
    pixel_global = global_pixels(camera)
    if settings.uses_silhouettes:
        frame = silhouette_frame(scene, tracer, extent, frames, settings, progress, stats, pixel_global, edges)
    else:
        frame = blocker_map_frame(scene, tracer, extent, frames, settings, progress, stats, pixel_global)

    resolved = None
    if settings.aa_samples > 1 and (frame.grid.index_triangle >= 0).any():
        if progress.wants_preview and settings.uses_silhouettes:
            # The centres before anti-aliasing writes its pixels over them. (The blocker map's centres
            # come from the extended flood fill with anti-aliasing on: not a plain render's.)
            preview = replace(frame.output, combined=frame.output.combined.copy(),
                              sample_count=frame.output.sample_count.copy())
            preview = _delivered(preview, scene, wanted_window, settings.replace(aa_samples=1), tracer, progress)
            progress.on_preview(_with_stats(preview, stats, tracer, rays_before, started, progress))
        resolved = antialias_frame(scene, tracer, extent, frames, settings, progress, stats, pixel_global, frame,
                              wanted_window)
    output = frame.output
    if resolved is not None:
        pixels, pooled, counts = resolved
        output.combined.reshape(-1, 4)[pixels] = pooled
        output.sample_count.reshape(-1)[pixels] = counts
    output = _delivered(output, scene, wanted_window, settings, tracer, progress)
    return _with_stats(output, stats, tracer, rays_before, started, progress)


def _delivered(output: RenderOutput, scene: Scene, wanted_window, settings: Settings, tracer, progress: Progress
               ) -> RenderOutput:
    """``output`` of the window ``scene``'s camera traced, cut to ``wanted_window`` (full-frame x0, y0, x1,
    y1), with the lights the camera sees drawn over it: what the render returns."""
    camera = scene.camera
    if camera.window != wanted_window:
        output = _cropped(output, camera.window, wanted_window)
        camera = replace(camera, window=wanted_window)
    if len(scene.seen):
        # Lights the camera sees add their radiance over whatever lies behind them (Cycles: a light is no
        # occluder for camera rays and adds no alpha).
        reached, drawn, outlined = draw_seen_lights(scene.seen, camera, tracer, settings, global_pixels(camera),
                                                    progress)
        output.combined.reshape(-1, 4)[reached, :3] += drawn.astype(np.float32)
        counts = output.sample_count.reshape(-1)
        counts[outlined] = np.maximum(counts[outlined], OUTLINE_SAMPLES)
    return output


def _with_stats(output: RenderOutput, stats: dict, tracer, rays_before: int, started: float, progress: Progress
                ) -> RenderOutput:
    """``output`` with the render's statistics so far and its warnings."""
    output.stats = dict(stats, pixels=output.combined.shape[0] * output.combined.shape[1],
                        rays_cast=tracer.n_rays_cast - rays_before, seconds=time.perf_counter() - started,
                        stage_seconds=dict(progress.stage_seconds),
                        peak_memory_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0)
    output.warnings = list(progress.warnings)
    return output


def _cropped(output: RenderOutput, grown, window) -> RenderOutput:
    """``output`` of the window ``grown`` cut to ``window``'s pixels (both full-frame x0, y0, x1, y1)."""
    x0, y0, x1, y1 = window
    rows, columns = slice(y0 - grown[1], y1 - grown[1]), slice(x0 - grown[0], x1 - grown[0])

    def cut(array: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(array[rows, columns])
    return RenderOutput(cut(output.combined), cut(output.blocker_count), cut(output.umbra), cut(output.depth),
                        cut(output.normal), cut(output.sample_count), output.warnings, output.stats)
