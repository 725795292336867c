"""Progressive rendering for the Rendered viewport: a coarse image at once, then finer ones, then the final.

Blender's viewport asks for an image after every change (a light moved, the view turned). LazyVis renders
the scene again at a start resolution (``START_RESOLUTION`` pixels along the longer side: 1/32 of a
1280 x 720 view), halving the divisor down to 1/8, then 1/4, 1/2 and full, each without anti-aliasing
(every pixel its centre sample), then the full resolution at the render's own settings: the last image is
the F12 render of the same view. Each step is a plain ``render.render`` of the scene with its camera at
that resolution (``scaled_camera``): a pixel of a coarse image is ``divisor`` x ``divisor`` viewport pixels
and lies where they do, so the viewport draws it scaled up in place. Where the last render anti-aliases by
silhouettes, the full-resolution image without anti-aliasing is its own pixel centres, handed over before
it anti-aliases (``previewed``), not a render of its own.

The steps share the scene's camera-independent structures (``prepared.prepare``: the validated scene, the ray
tracer, the light frames, the edge tree), built once per scene: the renderer keeps them across starts
while the scene is the same (a moved view replaces only the camera), and a new scene of equal triangles
(a new export after a change of lights or materials) keeps the ray tracer, of equal lights too the rest.

The steps run on a worker thread of their own, one after another; ``start`` cancels the work in progress
(the core's ``Progress.check_cancel`` raises at its next chunk) and begins again from the coarsest step.
The front end polls ``latest`` (Blender's ``view_draw``) or is told through ``on_image`` (where it asks for
a redraw). No bpy here: the Blender layer builds the scenes and draws the images.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from .progress import Progress, RenderCancelled
from .prepared import PreparedScene, prepare
from .render import render
from .scene import Camera, Scene
from .settings import Settings

# Divisors of the viewport's resolution, coarsest first; the last full-resolution step adds anti-aliasing.
DIVISORS = (8, 4, 2, 1)

# Before 1/8, coarser steps (each twice the next one's divisor) until the first image is at most this many
# pixels along the view's longer side, as Cycles' viewport started (its former Start Resolution, 64 by
# default): at 1280 x 720 the 1/8 step of the tree sample took 1.25 s, its 40 x 23 pixels at 1/32 0.15 s.
START_RESOLUTION = 64


@dataclass(frozen=True)
class ViewportImage:
    """One finished step of a progressive render.

    image : (H', W', 4) float32   linear RGBA of the step's window, H' = ceil(H / divisor) rows for a
                                  viewport of H rows (the last row and column may reach past the viewport).
    divisor : int                 viewport pixels per image pixel along each axis.
    window : (x0, y0, x1, y1)     the image's pixels in the step's frame (``scaled_camera``'s window: the
                                  whole frame, or the coarse pixels over a border); viewport pixels
                                  ``divisor`` times these.
    final : bool                  the last step: the render at the given settings (anti-aliased), at the
                                  viewport's resolution over its pixel size.
    generation : int              the ``start`` it belongs to (1, 2, ...).
    seconds : float               from that ``start`` to this image.
    """

    image: np.ndarray
    divisor: int
    window: tuple[int, int, int, int]
    final: bool
    generation: int
    seconds: float


def scaled_camera(camera: Camera, divisor: int) -> Camera:
    """The camera rendering ``camera``'s view with pixels ``divisor`` times larger: ceil(W / divisor) x
    ceil(H / divisor) pixels whose pixel (x, y) covers the viewport's pixels divisor * x .. divisor * (x + 1)
    - 1 (and rows alike), so the frame grows past the right and bottom edges where the size does not divide;
    a border window is grown to whole coarse pixels."""
    if divisor == 1:
        return camera
    width, height = -(-camera.width // divisor), -(-camera.height // divisor)
    left, right, bottom, top = camera.screen_window
    # The frame of divisor * width by divisor * height viewport pixels, anchored at the top left.
    right = left + (right - left) * divisor * width / camera.width
    bottom = top - (top - bottom) * divisor * height / camera.height
    x0, y0, x1, y1 = camera.window
    window = (x0 // divisor, y0 // divisor, -(-x1 // divisor), -(-y1 // divisor))
    return replace(camera, width=width, height=height, screen_window=np.array([left, right, bottom, top]),
                   window=window)


def step_divisors(width: int = 0, height: int = 0) -> tuple[int, ...]:
    """The divisors of a ``width`` x ``height`` view's steps, coarsest first: DIVISORS, after coarser ones
    (32, 16 before 8) until the first step has at most START_RESOLUTION pixels along the longer side."""
    longer = max(width, height)
    coarse = []
    divisor = DIVISORS[0]
    while -(-longer // divisor) > START_RESOLUTION:  # a handful: each halves the first image
        divisor *= 2
        coarse.insert(0, divisor)
    return tuple(coarse) + DIVISORS


def refinement_steps(settings: Settings, width: int = 0, height: int = 0, pixel_size: int = 1
                     ) -> list[tuple[int, Settings, bool]]:
    """(divisor, settings, final) of each image of a ``width`` x ``height`` view: ``step_divisors`` without
    anti-aliasing down to ``pixel_size`` (Blender's viewport Pixel Size: the finest step has pixels that
    many viewport pixels wide), then that resolution at ``settings`` (with their anti-aliasing; a render
    without it ends at the plain finest step). Each image is a plain render of its divisor and settings,
    except that the finest plain image comes from the final render itself where it anti-aliases by
    silhouettes (``previewed``)."""
    pixel_size = max(int(pixel_size), 1)
    plain = settings.replace(aa_samples=1)
    divisors = [divisor for divisor in step_divisors(width, height) if divisor > pixel_size] + [pixel_size]
    steps = [(divisor, plain, False) for divisor in divisors]
    if settings.aa_samples > 1:
        steps.append((pixel_size, settings, True))
    else:
        steps[-1] = (pixel_size, settings, True)
    return steps


def previewed(settings: Settings) -> bool:
    """Whether the final render at ``settings`` gives the finest plain image on its way
    (``Progress.on_preview``: its pixel centres before anti-aliasing), so that step is not rendered on its
    own: it shaded every centre again, half the time to the final image on the floating boxes."""
    return settings.aa_samples > 1 and settings.uses_silhouettes


class _Cancellable(Progress):
    """The core's progress object of one progressive render: it cancels when its event is set, and hands a
    render's image before anti-aliasing to ``preview`` where that is set."""

    def __init__(self, stop: threading.Event) -> None:
        super().__init__()
        self.stop = stop
        self.preview: Callable | None = None

    def is_cancelled(self) -> bool:
        return self.stop.is_set()

    @property
    def wants_preview(self) -> bool:
        return self.preview is not None

    def on_preview(self, output) -> None:
        self.preview(output)


class ProgressiveRenderer:
    """Renders the steps of ``refinement_steps`` on a worker thread, the newest ``start`` only.

    ``on_image(ViewportImage)`` is called on the worker thread after each step (keep it short: Blender's
    ``tag_redraw``); ``render_function`` is ``render.render`` (a test may wrap it), called as
    ``render_function(scene, settings, progress, prepared=...)``.

    The prepared scene (``prepared.PreparedScene``) of the newest start that made one is kept for the starts
    that follow (``prepared``) and closed when a newer one replaces it or at ``close``; each worker holds
    the one it renders with (``acquire``), so closing it never pulls the tracer from under a step.
    """

    def __init__(self, on_image: Callable[[ViewportImage], None] | None = None,
                 render_function: Callable = render) -> None:
        self.on_image = on_image
        self.render_function = render_function
        self._lock = threading.Lock()
        self._latest: ViewportImage | None = None
        self._error: str | None = None
        self._generation = 0
        self._worker: threading.Thread | None = None
        self._stop = threading.Event()
        self._prepared: PreparedScene | None = None

    # -- the front end's side ------------------------------------------------------------------------------
    def start(self, scene: Scene, settings: Settings, pixel_size: int = 1) -> int:
        """Cancel the render in progress and begin this one at its coarsest step (down to ``pixel_size``,
        ``refinement_steps``); returns its generation. The previous images stay ``latest`` until the first
        new one replaces them."""
        self.cancel(wait=False)
        with self._lock:
            self._generation += 1
            generation = self._generation
            self._error = None
            self._stop = threading.Event()
            stop = self._stop
            # The kept scene, held for the new worker: to render with where it serves this scene, else to
            # take what is equal from (preparing runs on the worker, not on Blender's thread).
            base = self._prepared
            if base is not None:
                base.acquire()
        worker = threading.Thread(target=self._run, args=(scene, settings, pixel_size, generation, stop, base),
                                  name="lazyvis-viewport", daemon=True)
        self._worker = worker
        worker.start()
        return generation

    def cancel(self, wait: bool = True, timeout: float | None = None) -> bool:
        """Stop the render in progress (it raises at the core's next cancel check). With ``wait``, return
        once its thread has ended (or ``timeout`` seconds have passed): True when no worker is left."""
        self._stop.set()
        worker = self._worker
        if wait and worker is not None:
            worker.join(timeout)
            return not worker.is_alive()
        return worker is None or not worker.is_alive()

    def close(self, timeout: float | None = None) -> bool:
        """Cancel the render in progress (waiting up to ``timeout`` s for it) and close the kept prepared
        scene (its tracer's threads stop once the worker lets go of it). Returns ``cancel``'s answer."""
        stopped = self.cancel(wait=True, timeout=timeout)
        with self._lock:
            prepared, self._prepared = self._prepared, None
        if prepared is not None:
            prepared.close()
        return stopped

    @property
    def prepared(self) -> PreparedScene | None:
        """The prepared scene kept for the next start (None before the first step or after ``close``)."""
        with self._lock:
            return self._prepared

    def wait(self, timeout: float | None = None) -> bool:
        """Wait for the current render's last step; True if it has ended (finished, failed or cancelled)."""
        worker = self._worker
        if worker is not None:
            worker.join(timeout)
            return not worker.is_alive()
        return True

    @property
    def generation(self) -> int:
        """The newest ``start``'s generation (0 before the first)."""
        with self._lock:
            return self._generation

    @property
    def latest(self) -> ViewportImage | None:
        """The newest finished step (of the newest generation that finished one)."""
        with self._lock:
            return self._latest

    @property
    def error(self) -> str | None:
        """What stopped the current render, for the viewport's header (None: nothing)."""
        with self._lock:
            return self._error

    # -- the worker's side ---------------------------------------------------------------------------------
    def _run(self, scene: Scene, settings: Settings, pixel_size: int, generation: int, stop: threading.Event,
             base: PreparedScene | None) -> None:
        started = time.perf_counter()
        progress = _Cancellable(stop)  # made on this thread: the core asks it for cancels here
        prepared = None  # the prepared scene this worker holds (acquired), released at the end
        steps = refinement_steps(settings, scene.camera.width, scene.camera.height, pixel_size)
        try:
            if base is not None and base.serves(scene, settings):
                prepared, base = base, None
            else:
                # Prepared with the first step's camera and settings: its memory budget check is that
                # step's, as the step's own render would make it. Its own progress object: the warnings
                # reach each step's output through ``render``, which repeats them.
                first, first_settings, _ = steps[0]
                prepared = prepare(replace(scene, camera=scaled_camera(scene.camera, first)), first_settings,
                                   _Cancellable(stop), reuse=base)
                prepared.acquire()
                self._keep(prepared, generation, stop)
                if base is not None:
                    base.release()
                    base = None
            if previewed(settings):  # the final render shows the plain step before it
                steps = steps[:-2] + steps[-1:]
            for divisor, step_settings, final in steps:
                step_scene = replace(scene, camera=scaled_camera(scene.camera, divisor))
                window = step_scene.camera.window

                def show(output, final: bool = False, divisor: int = divisor, window: tuple = window) -> None:
                    image = ViewportImage(output.combined, divisor, window, final, generation,
                                          time.perf_counter() - started)
                    with self._lock:
                        if stop.is_set() or generation != self._generation:
                            raise RenderCancelled("a newer start")
                        self._latest = image
                    if self.on_image is not None:
                        self.on_image(image)

                progress.preview = show if final and previewed(settings) else None
                show(self.render_function(step_scene, step_settings, progress, prepared=prepared), final)
        except RenderCancelled:
            return
        except (ValueError, MemoryError) as error:  # bad input and budgets: the core's own messages
            self._fail(generation, str(error))
        except Exception as error:  # noqa: BLE001 - the viewport shows it in its header, never a traceback
            self._fail(generation, f"{type(error).__name__}: {error}")
        finally:
            for held in (base, prepared):
                if held is not None:
                    held.release()

    def _keep(self, prepared: PreparedScene, generation: int, stop: threading.Event) -> None:
        """Keep a newly prepared scene for the starts that follow, closing the one it replaces, if its start
        is still the newest and not cancelled (``close`` may have run); close it otherwise (this worker
        still holds it until it ends)."""
        with self._lock:
            if generation == self._generation and not stop.is_set():
                prepared, self._prepared = self._prepared, prepared
        if prepared is not None:
            prepared.close()

    def _fail(self, generation: int, message: str) -> None:
        with self._lock:
            if generation == self._generation:
                self._error = message
