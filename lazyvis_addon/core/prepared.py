"""What a render needs of a scene that does not depend on the camera: ``prepare`` -> ``PreparedScene``.

The validated scene (emitters that need it turned into triangles, nearby-geometry warnings), the ray
tracer, the light frames and the edge tree. ``render`` builds one and lets go of it at its end; the
Rendered viewport (``progressive``) keeps one across its steps and restarts and shares the tracer
between renders in flight, the images the same bit for bit.
"""

from __future__ import annotations

import threading
from contextlib import contextmanager
from dataclasses import fields, is_dataclass
from typing import Callable

import numpy as np

from .edge_tree import MeshEdges
from .emitters import crowded_hulls, hull_faces_in_scene, hull_tables, hulls_as_triangles, nearby_geometry
from .frame import frame_camera, working_budget_mb
from .geometry import light_frames
from .parallel import thread_count
from .progress import Progress
from .scene import Scene
from .settings import Settings
from .kernels import compile_kernels, groups_for
from .surface import scene_centre, scene_extent
from .trace import RayTracer


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
                                 same triangles), "lights" (and the same lights: frames and edge tree too),
                                 or "edge tree" (lights of the same shapes, another power or colour: the
                                 edge tree and the extent, the frames made again).
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
    camera, _ = frame_camera(validated.camera, settings)
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
        shared = _SharedTracer(RayTracer(validated.triangles, threads=thread_count(settings.threads)))
    # Let go of the tracer however preparing ends (a cancel included): its threads would otherwise live
    # until the exception's frames are collected.
    try:
        if same_triangles and reuse.silhouettes == silhouettes and \
                _equal_data(_light_fields(validated, power=False), _light_fields(reuse.scene, power=False)):
            # The extent and the edge tree depend on the triangles and the lights' shapes only; the frames
            # carry the radiance too: made again where only a light's strength or colour changed (a slider
            # dragged in the viewport; suzanne_dense3 brighter: 0.18 s to prepare with its edge tree built
            # again, 0.025 s keeping it).
            extent, edges = reuse.extent, reuse.edges
            same_power = _equal_data(_light_fields(validated, power=True), _light_fields(reuse.scene, power=True))
            frames = reuse.frames
            if not same_power:
                frames = light_frames(validated.lights, validated.facing, scene_centre(validated), extent,
                                      validated.hulls)
                frames.part_of = reuse.frames.part_of
            kernels_compiled, frame_warnings = False, list(reuse._frame_warnings)
            for message in frame_warnings:
                progress.warn(message)
            reused += ("lights",) if same_power else ("edge tree",)
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
                # Numba compiles pass 2's kernels on a machine's first render (``kernels``), then its cache
                # serves them in milliseconds: a stage of its own, so the wait is named and timed, and
                # first, as the edge tree's build runs some of them.
                progress.begin_stage("Compiling kernels")
                kernels_compiled = compile_kernels(groups_for(validated), progress.check_cancel)
                progress.begin_stage("Building edge tree")
                edges = MeshEdges.from_triangles(validated.triangles, frames, progress.check_cancel)
        progress.end_stage()
    except BaseException:
        shared.release()
        raise
    return PreparedScene(scene, validated, silhouettes, shared, extent, frames, edges, kernels_compiled,
                         progress.warnings[warned:], frame_warnings, reused)


# The fields of a scene's lights that carry their power, not their shape (``_light_fields``).
_POWER_FIELDS = {"radiance", "intensity"}


def _light_fields(scene: Scene, power: bool) -> tuple:
    """The power fields (``_POWER_FIELDS``) of ``scene``'s lights, facing lamps and emitter hulls, or with
    ``power`` False all their other fields: what the extent, the edge tree and the frames' geometry depend
    on."""
    return tuple(tuple(getattr(part, f.name) for f in fields(part) if (f.name in _POWER_FIELDS) == power)
                 for part in (scene.lights, scene.facing, scene.hulls))


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


def _warn_nearby_geometry(scene: Scene, frames, progress: Progress) -> None:
    """One warning naming the mesh emitters (hulls) that other geometry comes close to: it may stand between
    the emitter and the plane (or box face) its light is cut in, where it shadows wrongly
    (``emitters.nearby_geometry``)."""
    close = np.flatnonzero(nearby_geometry(frames.hulls, scene.triangles, frames.part_of))
    if len(close):
        progress.warn("geometry within about 4 radii of a mesh emitter may not shadow the emitter's light "
                      "exactly where it is closer to the emitter than its tangent planes "
                      f"(emitter {', '.join(map(str, close))})")
