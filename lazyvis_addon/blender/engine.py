"""The render engine: export the depsgraph, render with the core, write the render result.

The ``RenderEngine`` subclass only delegates. Every failure ends as ``report({'ERROR'}, message)`` with
no image written, never as a traceback in the user's face (internal errors also print one to the
console for bug reports).
"""

from __future__ import annotations

import time
import traceback

import bpy
import numpy as np

from ..core.progress import Progress, RenderCancelled
from .export import export_depsgraph
from .properties import settings_from_scene

ENGINE_ID = "LAZYVIS"

# Every pass the engine writes: (name, channels, channel ids, type, enabled for a view layer, data from a
# RenderOutput as (H, W, channels) with row 0 at the top). Used both to register and to fill passes.
PASSES = (
    ("Combined", 4, "RGBA", "COLOR", lambda layer: True, lambda out: out.combined),
    ("Depth", 1, "Z", "VALUE", lambda layer: layer.use_pass_z, lambda out: out.depth[..., None]),
    ("Normal", 3, "XYZ", "VECTOR", lambda layer: layer.use_pass_normal, lambda out: out.normal),
    ("Blocker Count", 1, "X", "VALUE", lambda layer: layer.lazyvis.use_pass_blocker_count,
     lambda out: out.blocker_count[..., None]),
    ("Sample Count", 1, "X", "VALUE", lambda layer: layer.lazyvis.use_pass_sample_count,
     lambda out: out.sample_count[..., None]),
)


def render_passes(view_layer):
    """The passes written for ``view_layer``: (name, channels, chan_id, type, data function)."""
    for name, channels, chan_id, kind, enabled, data in PASSES:
        if enabled(view_layer):
            yield name, channels, chan_id, kind, data


# Listeners of every render's progress besides Blender's own display, such as the command line's terminal
# progress bar (lazyvis_addon/cli.py): core ``Progress`` objects whose ``on_stage``, ``on_advance`` and
# ``on_warning`` are called with the engine's, and whose ``is_cancelled`` can stop the render.
observers: list[Progress] = []


def showing_previews() -> bool:
    """Whether a render's image before anti-aliasing is shown: in Blender's render window, not in a
    background render (``blender -b``, the command line, a farm), where nobody sees it and its copy of the
    frame would only cost memory."""
    return not bpy.app.background


class EngineProgress(Progress):
    """Core progress shown in Blender's render window; Esc cancels through ``test_break``. Once the scene
    is exported (``result_target``), the image before anti-aliasing goes into the render result too, so the
    render window shows the pixel centres while anti-aliasing refines them."""

    def __init__(self, engine: bpy.types.RenderEngine) -> None:
        super().__init__()
        self.engine = engine
        self._shown = 0.0
        self.result_target = None  # (view layer, window): where ``on_preview`` writes

    @property
    def wants_preview(self) -> bool:
        return self.result_target is not None and showing_previews()

    def on_preview(self, output) -> None:
        view_layer, window = self.result_target
        write_result(self.engine, view_layer, window, output)

    def on_stage(self, name: str, total: int) -> None:
        self.engine.update_stats("", f"LazyVis | {name}")
        self.engine.update_progress(0.0)
        for observer in observers:
            observer.on_stage(name, total)

    def on_advance(self, name: str, done: int, total: int) -> None:
        now = time.monotonic()
        if total and (now - self._shown > 0.1 or done >= total):  # throttled: the UI needs no more
            self._shown = now
            self.engine.update_progress(min(done / total, 1.0))
        for observer in observers:
            observer.on_advance(name, done, total)

    def is_cancelled(self) -> bool:
        return bool(self.engine.test_break()) or any(observer.is_cancelled() for observer in observers)

    def on_warning(self, message: str) -> None:
        for observer in observers:  # first, so that a progress bar can make room for Blender's report line
            observer.on_warning(message)
        self.engine.report({'WARNING'}, f"LazyVis: {message}")


class PreviewProgress(EngineProgress):
    """A thumbnail's progress: its warnings are about Blender's preview scene (its world, its floor's
    nodes), not the user's, and a thumbnail renders after every edit: not reported."""

    def on_warning(self, message: str) -> None:
        pass


def core_render(scene, settings, progress):
    """The door into the core, imported on first use so that a broken install is a clear render error."""
    from ..core import render
    return render(scene, settings, progress)


# Material and light thumbnails (``RenderEngine.is_preview``): Blender's preview scene at 128 px (32 px for
# icons), redrawn after every edit of the material, in a job off the UI thread. Anti-aliasing draws fewer
# samples there: the preview sphere at 128 px took 3.1 s with the default 16 (2.1 s of it anti-aliasing).
PREVIEW_AA_SAMPLES = 4


def render_frame(engine: bpy.types.RenderEngine, depsgraph, preview: bool = False) -> None:
    """Render one view layer of one frame into the engine's render result; ``preview``: a material or light
    thumbnail (fewer anti-aliasing samples, the preview scene's warnings not reported)."""
    scene = depsgraph.scene
    view_layer = depsgraph.view_layer
    progress = PreviewProgress(engine) if preview else EngineProgress(engine)
    try:
        progress.begin_stage("Exporting scene")
        settings = settings_from_scene(scene)
        if preview:
            settings = settings.replace(aa_samples=min(settings.aa_samples, PREVIEW_AA_SAMPLES))
        exported = export_depsgraph(depsgraph, progress, camera_object=engine.camera_override or scene.camera,
                                    resolution=(engine.resolution_x, engine.resolution_y),
                                    disk_vertices=scene.lazyvis.disk_vertices)
        progress.end_stage()
        if not preview:
            progress.result_target = (view_layer, exported.scene.camera.window)
        output = core_render(exported.scene, settings, progress)
        write_result(engine, view_layer, exported.scene.camera.window, output)
    except RenderCancelled:
        engine.update_stats("", "LazyVis | Cancelled")
        return
    except ValueError as error:
        engine.report({'ERROR'}, f"LazyVis: {error}")
        return
    except MemoryError as error:
        engine.report({'ERROR'}, f"LazyVis: {str(error) or 'out of memory'} (Performance > Memory Budget)")
        return
    except ImportError as error:
        engine.report({'ERROR'}, f"LazyVis: the renderer could not be loaded ({error}); reinstall the add-on")
        return
    except Exception as error:  # a bug: keep Blender running, leave the details in the console
        traceback.print_exc()
        engine.report({'ERROR'}, f"LazyVis internal error ({type(error).__name__}: {error}); "
                                 "the system console has the details")
        return
    engine.update_stats("", done_message(output.stats))


def done_message(stats: dict) -> str:
    """The status line after a render: total time and the stages that took the most (at most four)."""
    seconds = stats.get("seconds")
    if seconds is None:
        return "LazyVis | Done"
    stages = sorted(stats.get("stage_seconds", {}).items(), key=lambda item: -item[1])[:4]
    detail = ", ".join(f"{name} {value:.2f} s" for name, value in stages if value >= 0.005)
    return f"LazyVis | Done in {seconds:.2f} s" + (f" ({detail})" if detail else "")


def write_result(engine: bpy.types.RenderEngine, view_layer, window, output) -> None:
    """Write the core's passes (rows top-down) into Blender's result (rows bottom-up) for the window."""
    x0, y0, x1, y1 = window
    width, height = x1 - x0, y1 - y0
    # Result coordinates start at the border's corner (measured): the whole result is the window.
    result = engine.begin_result(0, 0, width, height, layer=view_layer.name)
    try:
        if (result.resolution_x, result.resolution_y) != (width, height):
            raise RuntimeError(f"Blender's render result is {result.resolution_x} x {result.resolution_y} "
                               f"pixels but the rendered window is {width} x {height}")
        layer = result.layers[0]
        for name, channels, _chan_id, _kind, data in render_passes(view_layer):
            render_pass = layer.passes.find_by_name(name, "")
            if render_pass is None:
                continue
            pixels = np.asarray(data(output), dtype=np.float32)[::-1]  # Blender's rows start at the bottom
            render_pass.rect.foreach_set(np.ascontiguousarray(pixels).reshape(-1))
    except BaseException:
        engine.end_result(result, cancel=True)
        raise
    engine.end_result(result)


class LazyVisRenderEngine(bpy.types.RenderEngine):
    """Direct illumination with lazy visibility evaluation (Hart, Dutre, Greenberg 1999)."""

    bl_idname = ENGINE_ID
    bl_label = "Lazy Visibility"
    bl_use_preview = True  # material and light thumbnails (``render_frame``'s preview)
    bl_use_shading_nodes_custom = False
    bl_use_eevee_viewport = True  # Material Preview in the viewport uses EEVEE

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)  # Blender makes its engine data there
        self._viewport = None

    def __del__(self):
        try:
            viewport = self._viewport
        except (AttributeError, ReferenceError):  # Blender freed the engine's data first (at exit, Ctrl-C)
            return
        if viewport is not None:  # its render thread stops at the core's next cancel check
            viewport.stop()

    def render(self, depsgraph):
        render_frame(self, depsgraph, preview=self.is_preview)

    def viewport_session(self):
        """This engine's Rendered viewport (``viewport.ViewportSession``), made on first use."""
        if self._viewport is None:
            from .viewport import ViewportSession
            self._viewport = ViewportSession()
        return self._viewport

    def view_update(self, context, depsgraph):
        from .viewport import view_update
        view_update(self, context, depsgraph)

    def view_draw(self, context, depsgraph):
        from .viewport import view_draw
        view_draw(self, context, depsgraph)

    def update_render_passes(self, scene=None, renderlayer=None):
        for name, channels, chan_id, kind, _data in render_passes(renderlayer):
            self.register_pass(scene, renderlayer, name, channels, chan_id, kind)


classes = (LazyVisRenderEngine,)


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister() -> None:
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
