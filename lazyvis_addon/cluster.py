"""Rendering on a Dask cluster (``distributed``): a frame's tiles, and whole frames, on the workers.

The client exports the scene (Blender's export, as for a local render) and sends it to the workers once;
each worker renders windows of the frame with the Blender-free core (``core.render``: numpy, embreex and
numba, no bpy) and returns their passes; the client stitches them (``merge_outputs``). A window is pixel
for pixel the full frame's (the core renders the margin its anti-aliasing reads), so the stitched frame is
the one a local render gives, bit for bit.

Tasks are retried on a worker's loss (Dask reschedules what a lost worker held; an exception is retried
``RETRIES`` times), a cancel cancels the frame's tasks, and progress counts the tiles as they finish.

``distributed`` is an optional dependency (``pip install 'lazyvis[cluster]'``); the Blender engine never
imports this module.
"""

from __future__ import annotations

import logging
import time
import uuid
from dataclasses import dataclass, replace

import numpy as np

from .core.progress import Progress, RenderCancelled
from .core.render import RenderOutput, render
from .core.scene import Scene
from .core.settings import Settings

# A tile task is tried again this often after an exception (a worker lost is rescheduled by Dask itself).
RETRIES = 2
# How often (seconds) the client looks for finished tiles and for a cancel.
POLL_SECONDS = 0.1
# Stats that describe the scene or the render's set-up, not work done: every tile's are the frame's.
SCENE_STATS = ("triangles", "lights", "working_budget_mb", "edge_records", "kernels_compiled", "bands")


def connect(address: str, workers: int = 2):
    """A ``distributed.Client`` for ``address`` (``tcp://HOST:PORT``), or for a new ``LocalCluster`` of
    ``workers`` single-threaded worker processes on 127.0.0.1 when ``address`` is ``"local"`` (close the
    client to stop it). Start a local cluster before importing bpy: its workers are spawned processes that
    inherit ``sys.path``, where bpy puts its own modules."""
    try:
        from distributed import Client, LocalCluster
    except ImportError as error:
        raise RuntimeError("rendering on a cluster needs Dask's distributed (pip install 'lazyvis[cluster]'): "
                           f"{error}") from None
    if address == "local":
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address=None, silence_logs=logging.WARNING)
        client = Client(cluster)
        client.owned_cluster = cluster  # closed with the client (``close``)
        return client
    return Client(address, timeout="20s")


def close(client) -> None:
    """Close ``client`` and the local cluster it started, if any."""
    cluster = getattr(client, "owned_cluster", None)
    client.close()
    if cluster is not None:
        cluster.close()


def tile_windows(window: tuple[int, int, int, int], columns: int, rows: int) -> list[tuple[int, int, int, int]]:
    """``columns`` x ``rows`` windows (x0, y0, x1, y1) that tile ``window``, row by row from the top left (at
    most as many as it has pixels each way)."""
    x0, y0, x1, y1 = window
    xs = np.unique(np.linspace(x0, x1, min(columns, x1 - x0) + 1).round().astype(int))
    ys = np.unique(np.linspace(y0, y1, min(rows, y1 - y0) + 1).round().astype(int))
    return [(int(xs[i]), int(ys[j]), int(xs[i + 1]), int(ys[j + 1]))
            for j in range(len(ys) - 1) for i in range(len(xs) - 1)]


def _scene(scene: Scene) -> Scene:
    """On a worker: the frame's scene, a task result its tiles share (see ``submit``)."""
    return scene


# glibc's mallopt parameters (malloc.h) and the thresholds a worker renders with (bytes).
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
WORKER_MMAP_THRESHOLD = 32 << 20
WORKER_TRIM_THRESHOLD = 128 << 20


def _heap_for_arrays() -> None:
    """Undo Dask's MALLOC_TRIM_THRESHOLD_=65536 in this worker process (glibc only; elsewhere nothing).

    Dask's nanny starts workers with that variable, and setting it turns off glibc's adaptive mmap
    threshold: every array over 128 kB is then mapped and unmapped afresh, its pages faulted in each time.
    The core's batches of temporaries made a tile 1.8x slower in a worker (6.15 -> 11.1 s for a 480 x 270
    tile of the boxes at 1080p, and the same locally with the variable set). Arrays up to 32 MB come from
    the heap again, and the heap is trimmed past 128 MB."""
    try:
        import ctypes
        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(M_MMAP_THRESHOLD, WORKER_MMAP_THRESHOLD)
        libc.mallopt(M_TRIM_THRESHOLD, WORKER_TRIM_THRESHOLD)
    except (OSError, AttributeError):  # not glibc: its allocator is not tuned by that variable
        pass


def render_window(scene: Scene, settings: Settings, window: tuple[int, int, int, int]) -> RenderOutput:
    """On a worker: the core's render of ``window`` of ``scene``'s frame."""
    _heap_for_arrays()
    return render(replace(scene, camera=replace(scene.camera, window=window)), settings)


@dataclass
class Submitted:
    """A frame's tiles on the cluster: their windows (K,) and futures (K,), and the frame's window."""

    window: tuple[int, int, int, int]
    windows: list
    futures: list


def submit(client, scene: Scene, settings: Settings, columns: int, rows: int) -> Submitted:
    """Send ``scene`` to the cluster once and a task per tile of its camera's window; returns at once."""
    window = scene.camera.window
    windows = tile_windows(window, columns, rows)
    frame = uuid.uuid4().hex[:12]
    # The scene as a task's result, not scattered data: scattered data has no lineage, so a worker lost
    # with the only copy took it away (its tiles were cancelled, "already forgotten"), and a broadcast to
    # every worker stalled on a killed one; a task's result is computed again elsewhere from its spec.
    shared = client.submit(_scene, scene, key=f"lazyvis-scene-{frame}", pure=False)
    futures = [client.submit(render_window, shared, settings, tile, key=f"lazyvis-tile-{frame}-{index}",
                             retries=RETRIES, pure=False)
               for index, tile in enumerate(windows)]
    return Submitted(window, windows, futures)


def gather(client, submitted: Submitted, progress: Progress | None = None) -> RenderOutput:
    """Wait for a frame's tiles (progress: a stage "Cluster tiles", one unit a tile; a cancel cancels the
    tasks and raises RenderCancelled) and stitch them into the frame's window."""
    from distributed import wait

    progress = progress or Progress()
    started = time.perf_counter()
    progress.begin_stage("Cluster tiles", len(submitted.futures))
    waiting = list(submitted.futures)
    try:
        while waiting:  # polls: finished tiles, then a look for a cancel
            try:
                done, not_done = wait(waiting, timeout=POLL_SECONDS, return_when="FIRST_COMPLETED")
            except TimeoutError:  # none finished in this poll
                done, not_done = (), waiting
            for future in done:
                if future.status == "error":
                    future.result()  # raises the worker's exception here, as a local render would
            progress.advance(len(done))
            waiting = list(not_done)
            progress.check_cancel()
    except BaseException:
        client.cancel(submitted.futures)
        raise
    progress.end_stage()
    parts = client.gather(submitted.futures)
    output = merge_outputs(submitted.window, submitted.windows, parts)
    output.stats["seconds"] = time.perf_counter() - started
    output.stats["stage_seconds"]["Cluster tiles"] = output.stats["seconds"]
    return output


def render_on(client, scene: Scene, settings: Settings, columns: int, rows: int,
              progress: Progress | None = None) -> RenderOutput:
    """``core.render`` on the cluster, as ``columns`` x ``rows`` tiles: the same RenderOutput bit for bit."""
    scene = scene.validated(progress or Progress())
    return gather(client, submit(client, scene, settings, columns, rows), progress)


def merge_outputs(window, windows, parts: list[RenderOutput]) -> RenderOutput:
    """The RenderOutput of ``window`` from the outputs ``parts`` of its tiles ``windows``: passes placed,
    warnings once each in order, counters summed (stage seconds summed over the tiles: worker time)."""
    x0, y0, x1, y1 = window
    first = parts[0]

    def frame_of(array: np.ndarray) -> np.ndarray:
        return np.zeros((y1 - y0, x1 - x0) + array.shape[2:], array.dtype)

    names = ("combined", "blocker_count", "umbra", "depth", "normal", "sample_count")
    merged = {name: frame_of(getattr(first, name)) for name in names}
    warnings, stats, stages = [], {}, {}
    for (tx0, ty0, tx1, ty1), part in zip(windows, parts):  # tiles: a handful to a few hundred
        for name in names:
            merged[name][ty0 - y0:ty1 - y0, tx0 - x0:tx1 - x0] = getattr(part, name)
        warnings += [message for message in part.warnings if message not in warnings]
        for key, value in part.stats.items():
            if key == "stage_seconds":
                for stage, seconds in value.items():
                    stages[stage] = stages.get(stage, 0.0) + seconds
            elif key in SCENE_STATS or isinstance(value, bool) or not isinstance(value, (int, float)):
                stats.setdefault(key, value)  # the scene's, the same in every tile
            elif key.startswith("max_") or key == "peak_memory_mb":
                stats[key] = max(stats.get(key, value), value)  # peak memory: of the busiest worker
            else:
                stats[key] = stats.get(key, 0) + value
    stats["pixels"] = (y1 - y0) * (x1 - x0)
    stats["stage_seconds"] = stages
    stats["cluster_tiles"] = len(parts)
    return RenderOutput(**merged, warnings=warnings, stats=stats)


class FrameQueue:
    """Stands in for the Blender engine's core render (``blender.engine.core_render``) while the command line
    renders frames on a cluster, so that Blender still exports the scene and writes the file as for a local
    render. Called while ``submitting``, it sends the exported frame's tiles to the cluster and returns a
    black placeholder at once (that render's result is not saved); called for the frame's real render, it
    waits for them and returns the stitched frame. Submitting frames ahead spreads whole frames over the
    workers. Calls are keyed by (frame, call in the frame): one per view layer."""

    def __init__(self, client, columns: int = 1, rows: int = 1) -> None:
        self.client, self.columns, self.rows = client, columns, rows
        self.pending: dict[tuple[int, int], Submitted] = {}
        self.frame, self.calls, self.submitting = None, 0, False

    def begin(self, frame: int, submitting: bool) -> None:
        """The next engine calls are frame ``frame``'s, to submit (True) or to wait for (False)."""
        self.frame, self.calls, self.submitting = frame, 0, submitting

    def __call__(self, scene: Scene, settings: Settings, progress: Progress) -> RenderOutput:
        key = (self.frame, self.calls)
        self.calls += 1
        if self.submitting:
            scene = scene.validated(Progress())  # its warnings are reported when the frame is rendered
            self.pending[key] = submit(self.client, scene, settings, self.columns, self.rows)
            height, width = scene.camera.window_shape
            return RenderOutput(np.zeros((height, width, 4), np.float32), np.zeros((height, width), np.int32),
                                np.zeros((height, width, scene.light_count), bool),
                                np.zeros((height, width), np.float32), np.zeros((height, width, 3), np.float32),
                                np.ones((height, width), np.int32))
        submitted = self.pending.pop(key, None)
        if submitted is None:  # not sent ahead
            submitted = submit(self.client, scene.validated(progress), settings, self.columns, self.rows)
        output = gather(self.client, submitted, progress)
        for message in output.warnings:
            progress.warn(message)
        return output

    def frames_ahead(self) -> int:
        """Frames to have on the cluster beyond the one being written: enough tiles for every worker."""
        workers = max(len(self.client.scheduler_info().get("workers", {})), 1)
        return max(1, -(-workers // (self.columns * self.rows)))

    def cancel_all(self) -> None:
        """Cancel the tasks of every frame sent ahead (a cancel or an error ends the run)."""
        for submitted in self.pending.values():
            self.client.cancel(submitted.futures)
        self.pending.clear()
