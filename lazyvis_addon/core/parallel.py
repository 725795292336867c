"""Batches on a small thread pool: numpy and Embree release the GIL inside their array calls, so two
threads keep both cores of a workstation busy. Progress and cancel stay on the calling thread."""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import Callable, Iterable, Iterator, Sequence

from threadpoolctl import ThreadpoolController

from .progress import Progress

# While it waits for a batch, the calling thread asks for a cancel this often (seconds).
CANCEL_POLL = 0.1


def thread_count(requested: int) -> int:
    """``requested`` threads, or one per core (at most 8) when 0."""
    return requested if requested > 0 else min(os.cpu_count() or 1, 8)


_blas_controller: ThreadpoolController | None = None
_blas_lock = threading.Lock()
_blas_users = 0
_blas_limit = None  # threadpoolctl's limit while any render runs; undone when the last one ends


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """A context in which numpy's BLAS (OpenBLAS, MKL, Accelerate, as threadpoolctl finds it) runs on one
    thread: a render's parallelism is its own thread pool (``map_batches``), and a BLAS call from each of
    its threads (the camera's and the triangle tests' matrix products) started a BLAS team of its own that
    kept spinning on the cores the pool needed. Measured at 512 px on two threads (this machine, two cores,
    interleaved twice): chairs 8.11 / 8.13 -> 7.61 / 7.50 s, suzanne_dense3 12.41 / 11.86 -> 11.89 /
    11.28 s. The limit is the process's: renders that overlap (the viewport's and F12's) share it, and the
    last to end gives back what the process had before the first began."""
    global _blas_controller, _blas_users, _blas_limit
    with _blas_lock:
        if _blas_controller is None:  # finding the loaded libraries once: about 2 ms
            _blas_controller = ThreadpoolController()
        if _blas_users == 0:
            _blas_limit = _blas_controller.limit(limits=1, user_api="blas")
        _blas_users += 1
    try:
        yield
    finally:
        with _blas_lock:
            _blas_users -= 1
            if _blas_users == 0:
                _blas_limit.restore_original_limits()
                _blas_limit = None


def map_batches(function: Callable, batches: Sequence, threads: int, progress: Progress | None = None,
                units: Iterable[int] | None = None) -> list:
    """``[function(b) for b in batches]`` computed on ``threads`` threads, results in order.

    After each result the progress object advances by that batch's units, and while it waits it checks for a
    cancel every CANCEL_POLL seconds; a cancel (RenderCancelled) or a failed batch stops the batches not yet
    started and stops the running ones at their next ``progress.check_cancel()`` (``function`` should call it
    between chunks of its work), then returns when they have.

    Within a render (``render_threads``) every call shares the render's pool, and a call made on one of its
    threads (a band of the frame whose pass 2 runs its own batches, pass 2's rays) shares rather than adds:
    the calling thread runs batches itself and the pool's other threads join in as they come free; the
    render's thread count holds whatever ``threads`` asks. A pool of its own per call had put up to three
    times the render's threads on the cores (the bands', their pass 2's, the ray tracer's): on two threads
    (medians, both in one process) the anti-aliasing of floating_boxes at 512 px took 1.65 s against 1.23 s
    shared, the chairs' render 10.01 s against 8.85 s. Outside a render a call makes a pool of ``threads``
    for itself.
    """
    units = list(units) if units is not None else [1] * len(batches)
    if threads <= 1 or len(batches) <= 1:
        results = []
        for batch, unit in zip(batches, units):
            results.append(function(batch))
            if progress is not None:
                progress.advance(unit)
        return results
    pool = getattr(_local, "pool", None)
    own = None
    if pool is None:
        own = pool = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="lazyvis")
    else:
        threads = _local.threads
    work = _SharedWork(function, batches, pool, threads)
    worker = getattr(_local, "worker", False)
    for _ in range(min(threads - 1 if worker else threads, len(batches))):
        pool.submit(work.run)
    advanced = 0
    try:
        if worker:  # this thread is one of the pool's: it works too (its waiting would idle a core)
            work.run()
        while True:
            with work.changed:
                finished = work.finished()
                if not finished:
                    work.changed.wait(CANCEL_POLL)
                ready = work.ready_from(advanced)
            if work.error is not None:
                raise work.error
            if progress is not None:
                for unit in units[advanced:ready]:
                    progress.advance(unit)
            advanced = ready
            if finished:
                return work.results
            if progress is not None:
                progress.check_cancel()
    except BaseException:
        work.stop()
        if progress is not None:
            progress.stop_workers()
        work.wait_running()
        raise
    finally:
        if own is not None:
            own.shutdown(wait=True, cancel_futures=True)


# Per thread: the pool its ``map_batches`` calls share (``pool``, of ``threads`` threads; None outside a
# render) and whether the thread is one of that pool's (``worker``).
_local = threading.local()


@contextmanager
def render_threads(threads: int) -> Iterator[None]:
    """A context (a render) whose ``map_batches`` calls, on this thread and on the pool's, share one pool of
    ``threads`` threads, made here and ended on leaving: no thread outlives the render. Within another such
    context, that one's pool."""
    if threads <= 1 or getattr(_local, "pool", None) is not None:
        yield
        return
    pool = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="lazyvis")
    _local.pool, _local.threads = pool, threads
    try:
        yield
    finally:
        _local.pool, _local.threads = None, 0
        pool.shutdown(wait=True, cancel_futures=True)  # helpers never started are no-ops: dropped


class _SharedWork:
    """The batches of one ``map_batches`` call, taken one at a time by whichever thread asks (``run``)."""

    def __init__(self, function: Callable, batches: Sequence, pool: ThreadPoolExecutor, threads: int) -> None:
        self.function, self.batches, self.pool, self.threads = function, batches, pool, threads
        self.results: list = [None] * len(batches)
        self.done = [False] * len(batches)
        self.changed = threading.Condition()
        self.next = 0      # the next batch not yet taken
        self.running = 0   # batches taken and not yet ended
        self.stopped = False
        self.error: BaseException | None = None

    def run(self) -> None:
        """Take and compute batches until none is left (or the work stopped). A helper that starts after
        the call has returned finds none and ends at once."""
        outer = (getattr(_local, "pool", None), getattr(_local, "threads", 0), getattr(_local, "worker", False))
        _local.pool, _local.threads, _local.worker = self.pool, self.threads, True
        try:
            while True:
                with self.changed:
                    if self.stopped or self.next >= len(self.batches):
                        return
                    index = self.next
                    self.next += 1
                    self.running += 1
                try:
                    result = self.function(self.batches[index])
                except BaseException as error:  # handed to the caller, which raises it
                    with self.changed:
                        self.error = self.error or error
                        self.stopped = True
                        self.running -= 1
                        self.changed.notify_all()
                    return
                with self.changed:
                    self.results[index], self.done[index] = result, True
                    self.running -= 1
                    self.changed.notify_all()
        finally:
            _local.pool, _local.threads, _local.worker = outer

    def finished(self) -> bool:
        """Every batch computed, or stopped with none running (call holding ``changed``)."""
        return self.running == 0 and (self.stopped or self.next >= len(self.batches))

    def ready_from(self, first: int) -> int:
        """The end of the run of computed batches from ``first`` (call holding ``changed``)."""
        while first < len(self.done) and self.done[first]:
            first += 1
        return first

    def stop(self) -> None:
        with self.changed:
            self.stopped = True

    def wait_running(self) -> None:
        """Until no batch is running (the pool's threads stop at their next cancel check)."""
        with self.changed:
            while self.running:
                self.changed.wait(CANCEL_POLL)
