"""Batches on a small thread pool: numpy and Embree release the GIL inside their array calls, so two
threads keep both cores of a workstation busy. Progress and cancel stay on the calling thread."""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
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
    cancel every CANCEL_POLL seconds; a cancel (RenderCancelled) or a failed batch cancels the batches not
    yet started and stops the running ones at their next ``progress.check_cancel()`` (``function`` should
    call it between chunks of its work), then returns when they have.
    """
    units = list(units) if units is not None else [1] * len(batches)
    if threads <= 1 or len(batches) <= 1:
        results = []
        for batch, unit in zip(batches, units):
            results.append(function(batch))
            if progress is not None:
                progress.advance(unit)
        return results
    pool = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="lazyvis")
    try:
        # A bounded window of submitted batches keeps memory to a few batches in flight.
        window = 2 * threads
        futures = [pool.submit(function, batch) for batch in batches[:window]]
        results = []
        for index, unit in enumerate(units):
            results.append(_result(futures[index], progress))
            futures[index] = None
            if index + window < len(batches):
                futures.append(pool.submit(function, batches[index + window]))
            if progress is not None:
                progress.advance(unit)
        return results
    except BaseException:
        if progress is not None:
            progress.stop_workers()
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _result(future, progress: Progress | None):
    """The future's result; meanwhile the progress object is asked for a cancel every CANCEL_POLL seconds."""
    if progress is None:
        return future.result()
    while True:
        try:
            return future.result(timeout=CANCEL_POLL)
        except FutureTimeout:
            progress.check_cancel()
