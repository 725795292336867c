"""The Rendered viewport: the view's camera, which updates need the scene exported again, and the session
that keeps a progressive render (``core.progressive``) going behind the view.

Blender calls the engine's ``view_update`` after every change to the scene (the depsgraph's ``updates``
name what changed) and ``view_draw`` whenever the view is drawn (after navigation too). The session
exports the scene when something it is made of changed, takes the view's camera from the region at each
draw, and restarts the progressive render when either changed: a coarse image first, the F12 render of
the view last. Only ``draw_image`` needs a GPU context; the rest runs headless (and is tested so).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..core.progressive import ProgressiveRenderer, ViewportImage
from ..core.scene import Camera
from ..core.settings import Settings

# ID types whose updates change the exported scene: geometry and its transforms, materials and their
# node trees and images, lights, the world (the background), collections (what is visible). Updates of
# other IDs (the screen, brushes, workspaces, text) leave the render as it is; a Scene update can be a
# render setting (read again at each restart) or a change of frame.
EXPORTED_ID_TYPES = frozenset({"OBJECT", "MESH", "CURVE", "CURVES", "SURFACE", "META", "FONT", "POINTCLOUD",
                               "VOLUME", "GREASEPENCIL", "MATERIAL", "NODETREE", "IMAGE", "TEXTURE", "LIGHT",
                               "WORLD", "COLLECTION", "SCENE"})


def needs_export(updates) -> bool:
    """Whether any of the depsgraph's ``updates`` (``DepsgraphUpdate``, whose ``id.id_type`` names the
    kind of data-block) changes what the scene exports to."""
    return any(update.id.id_type in EXPORTED_ID_TYPES for update in updates)


def viewport_camera(view_matrix, window_matrix, width: int, height: int) -> Camera:
    """The core camera of a 3D view of ``width`` x ``height`` pixels: ``view_matrix`` (4, 4) world -> view
    and ``window_matrix`` (4, 4) the OpenGL projection (``RegionView3D``'s, or a camera object's
    ``matrix_world.inverted()`` and ``calc_matrix_camera``).

    Perspective: x_ndc = (P00 x + P02 z) / -z, so the frame on the plane z = -1 spans x = (+-1 + P02) / P00;
    the near and far distances are P23 / (P22 -+ 1). Orthographic: x = (+-1 - P03) / P00, near (1 + P23) /
    P22 and far (P23 - 1) / P22; an orthographic view's near plane can lie behind the view's origin
    (Blender centres its clipping on the view), so the camera moves back to it.
    """
    view = np.asarray(view_matrix, dtype=np.float64).reshape(4, 4)
    p = np.asarray(window_matrix, dtype=np.float64).reshape(4, 4)
    world_from_camera = np.linalg.inv(view)
    # Blender's view matrices carry no scale; a camera object's may: rotation and position only.
    world_from_camera[:3, :3] /= np.linalg.norm(world_from_camera[:3, :3], axis=0)
    if p[3, 3] == 0.0:  # perspective: w = -z
        window = np.array([(-1.0 + p[0, 2]) / p[0, 0], (1.0 + p[0, 2]) / p[0, 0],
                           (-1.0 + p[1, 2]) / p[1, 1], (1.0 + p[1, 2]) / p[1, 1]])
        near, far = p[2, 3] / (p[2, 2] - 1.0), p[2, 3] / (p[2, 2] + 1.0)
        projection = "perspective"
    else:
        window = np.array([(-1.0 - p[0, 3]) / p[0, 0], (1.0 - p[0, 3]) / p[0, 0],
                           (-1.0 - p[1, 3]) / p[1, 1], (1.0 - p[1, 3]) / p[1, 1]])
        near, far = (1.0 + p[2, 3]) / p[2, 2], (p[2, 3] - 1.0) / p[2, 2]
        projection = "orthographic"
        if near < 0.0:  # the camera steps back to the near plane (along its local +Z)
            world_from_camera[:3, 3] += world_from_camera[:3, 2] * -near
            near, far = 0.0, far - near
    near = max(float(near), 0.0)
    far = float(far) if np.isfinite(far) and far > near else np.inf
    return Camera(world_from_camera, max(int(width), 1), max(int(height), 1), projection, window, None, near, far)


def same_camera(a: Camera | None, b: Camera | None) -> bool:
    """Whether two cameras render the same image (the view has not moved)."""
    if a is None or b is None:
        return a is b
    return (a.width, a.height, a.projection, a.window, a.clip_start, a.clip_end) == \
        (b.width, b.height, b.projection, b.window, b.clip_start, b.clip_end) and \
        np.array_equal(a.world_from_camera, b.world_from_camera) and np.array_equal(a.screen_window, b.screen_window)


class ViewportSession:
    """One Rendered viewport's state: the exported scene, the view's camera and settings, and the
    progressive render of their newest combination. ``on_image`` is called on the render's thread after
    each step. The renderer keeps the scene's prepared structures (ray tracer, light frames, edge tree)
    between restarts, and what is equal of them across exports (``core.progressive``); ``stop`` lets go
    of them."""

    def __init__(self, on_image=None) -> None:
        self.renderer = ProgressiveRenderer(on_image)
        self.scene = None
        self.camera: Camera | None = None
        self.settings: Settings | None = None
        self.pixel_size = 1  # Blender's viewport Pixel Size (``viewport_pixel_size``)
        self.export_error: str | None = None
        self.texture = None  # (image key, GPUTexture) last drawn (``draw_image``)

    def exported(self, scene, settings: Settings) -> None:
        """A new export of the scene (and the render settings read with it): render it again."""
        self.scene, self.settings, self.export_error = scene, settings, None
        self._restart()

    def failed(self, message: str) -> None:
        """The export failed: stop, and show ``message`` until the next export."""
        self.renderer.cancel(wait=False)
        self.scene, self.export_error = None, message

    def view(self, camera: Camera, settings: Settings | None = None, pixel_size: int | None = None) -> None:
        """The view at a draw: render again where the camera, the settings or the pixel size changed."""
        changed = not same_camera(camera, self.camera) or (settings is not None and settings != self.settings) or \
            (pixel_size is not None and pixel_size != self.pixel_size)
        self.camera = camera
        if settings is not None:
            self.settings = settings
        if pixel_size is not None:
            self.pixel_size = pixel_size
        if changed:
            self._restart()

    def _restart(self) -> None:
        if self.scene is None or self.camera is None or self.settings is None:
            return
        self.renderer.start(replace(self.scene, camera=self.camera), self.settings, self.pixel_size)

    @property
    def latest(self) -> ViewportImage | None:
        return self.renderer.latest

    @property
    def message(self) -> str | None:
        """What the viewport's header should say instead of an image: an export or render failure."""
        return self.export_error or self.renderer.error

    def stop(self) -> None:
        """The viewport closes: cancel its render and let go of the scene's prepared structures."""
        self.renderer.close(timeout=2.0)


def image_rectangle(image: ViewportImage, region_height: int) -> tuple[int, int, int, int]:
    """(left, bottom, width, height) in region pixels (Blender's: y up from the bottom) where ``image``
    is drawn: its window's coarse pixels times its divisor, rows counted down from the region's top."""
    x0, y0, x1, y1 = image.window
    d = image.divisor
    return d * x0, region_height - d * y1, d * (x1 - x0), d * (y1 - y0)


def display_rows(image: ViewportImage) -> np.ndarray:
    """(H' * W' * 4,) float32 of the image with its rows bottom-up, as Blender's textures take them."""
    return np.ascontiguousarray(image.image[::-1], dtype=np.float32).reshape(-1)


def draw_image(engine, depsgraph, image: ViewportImage, region_height: int, session: ViewportSession) -> None:
    """Draw ``image`` over the region in the scene's view transform (Blender's display space shader), each
    image pixel over its ``divisor`` x ``divisor`` region pixels, where its window lies (``image_rectangle``).
    The image goes to the GPU once (``session.texture`` keeps it for the redraws that follow). Needs a GPU
    context."""
    import gpu
    from gpu_extras.presets import draw_texture_2d

    height, width = image.image.shape[:2]
    key = (image.generation, image.divisor, image.final)
    if session.texture is None or session.texture[0] != key:
        buffer = gpu.types.Buffer("FLOAT", width * height * 4, display_rows(image))
        session.texture = (key, gpu.types.GPUTexture((width, height), format="RGBA16F", data=buffer))
    texture = session.texture[1]
    gpu.state.blend_set("ALPHA_PREMULT")
    engine.bind_display_space_shader(depsgraph.scene)
    try:
        left, bottom, drawn_width, drawn_height = image_rectangle(image, region_height)
        draw_texture_2d(texture, (left, bottom), drawn_width, drawn_height)
    finally:
        engine.unbind_display_space_shader()
        gpu.state.blend_set("NONE")


def render_region(context, scene) -> tuple[int, int, int, int] | None:
    """The region's pixels to render (x0, y0, x1, y1), rows from the top, or None for all of it: in the
    camera's view the scene's render border (Output > Render Region) inside the camera's frame as the
    view shows it, elsewhere the view's own Render Region (View > Render Region)."""
    region, view = context.region, context.region_data
    width, height = region.width, region.height
    if getattr(view, "view_perspective", None) == "CAMERA":
        render = scene.render
        if not render.use_border or scene.camera is None:
            return None
        left, right, bottom, top = camera_frame(view, scene, width, height)
        fractions = (render.border_min_x, render.border_max_x, render.border_min_y, render.border_max_y)
    else:
        space = getattr(context, "space_data", None)
        if space is None or not getattr(space, "use_render_border", False):
            return None
        left, right, bottom, top = 0.0, float(width), 0.0, float(height)
        fractions = (space.render_border_min_x, space.render_border_max_x, space.render_border_min_y,
                     space.render_border_max_y)
    min_x, max_x, min_y, max_y = fractions
    x0 = int(np.clip(np.floor(left + min_x * (right - left)), 0, width))
    x1 = int(np.clip(np.ceil(left + max_x * (right - left)), 0, width))
    y_low = int(np.clip(np.floor(bottom + min_y * (top - bottom)), 0, height))
    y_high = int(np.clip(np.ceil(bottom + max_y * (top - bottom)), 0, height))
    if x1 <= x0 or y_high <= y_low:
        raise ValueError("the render region lies outside the view: move it into the view or turn it off")
    return (x0, height - y_high, x1, height - y_low)


def camera_frame(view, scene, width: int, height: int) -> tuple[float, float, float, float]:
    """(left, right, bottom, top) in the pixels (y up) of a ``width`` x ``height`` region of the scene
    camera's frame in a camera view: its ``view_frame`` corners through the view's matrices."""
    camera = scene.camera
    corners = np.array([tuple(camera.matrix_world @ corner) for corner in camera.data.view_frame(scene=scene)])
    clip = np.c_[corners, np.ones(len(corners))] @ (np.array(view.window_matrix) @ np.array(view.view_matrix)).T
    ndc = clip[:, :2] / clip[:, 3:4]
    region = (ndc + 1.0) / 2.0
    xs, ys = region[:, 0] * width, region[:, 1] * height
    return float(xs.min()), float(xs.max()), float(ys.min()), float(ys.max())


def viewport_pixel_size(context, scene) -> int:
    """Blender's Render Properties > Performance > Viewport > Pixel Size (``render.preview_pixel_size``):
    the final viewport image's pixels are that many screen pixels wide; Automatic follows the interface's
    pixel size (2 on a high-DPI display), as Cycles does."""
    chosen = scene.render.preview_pixel_size
    if chosen == 'AUTO':
        return max(1, int(round(context.preferences.system.pixel_size)))
    return max(1, int(chosen))


def _region_camera(context, scene=None) -> Camera:
    region, view = context.region, context.region_data
    camera = viewport_camera(view.view_matrix, view.window_matrix, region.width, region.height)
    if scene is not None:
        window = render_region(context, scene)
        if window is not None:
            camera = replace(camera, window=window)
    return camera


def view_update(engine, context, depsgraph) -> None:
    """``RenderEngine.view_update``: export the scene again where the updates touch it (always the first
    time), then let the session restart its render. Failures become the viewport's message."""
    from .export import export_depsgraph
    from .properties import settings_from_scene

    session = engine.viewport_session()
    if session.scene is not None and not needs_export(depsgraph.updates):
        return
    scene = depsgraph.scene
    try:
        camera = _region_camera(context, scene)
        exported = export_depsgraph(depsgraph, camera=camera, disk_vertices=scene.lazyvis.disk_vertices)
        session.camera = camera
        session.pixel_size = viewport_pixel_size(context, scene)
        session.exported(exported.scene, settings_from_scene(scene))
    except (ValueError, MemoryError) as error:
        session.failed(str(error))
    except Exception as error:  # a bug: the console keeps the details, the viewport a line
        import traceback
        traceback.print_exc()
        session.failed(f"internal error ({type(error).__name__}: {error})")


def view_draw(engine, context, depsgraph) -> None:
    """``RenderEngine.view_draw``: follow the view's camera and the render settings, draw the newest
    image, and keep asking for redraws until the final one has been drawn."""
    from .properties import settings_from_scene

    session = engine.viewport_session()
    try:
        camera = _region_camera(context, depsgraph.scene)
    except ValueError as error:
        engine.update_stats("", f"LazyVis: {error}")
        return
    session.view(camera, settings_from_scene(depsgraph.scene), viewport_pixel_size(context, depsgraph.scene))
    image = session.latest
    if image is not None:
        draw_image(engine, depsgraph, image, context.region.height, session)
    message = session.message
    if message:
        engine.update_stats("", f"LazyVis: {message}")
        return
    if image is None or not image.final or image.generation != session.renderer.generation:
        engine.update_stats("", "LazyVis | Rendering" if image is None else
                            f"LazyVis | 1/{image.divisor} resolution" if not image.final else "LazyVis | Refining")
        engine.tag_redraw()
    else:
        engine.update_stats("", f"LazyVis | Done in {image.seconds:.2f} s")
