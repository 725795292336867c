"""The render's thread pool (``parallel.map_batches`` within ``parallel.render_threads``): nested calls share
the render's threads instead of adding their own, results come in order, failures and cancels stop the rest."""

import threading
import time

import pytest

from lazyvis_addon.core.parallel import map_batches, render_threads
from lazyvis_addon.core.progress import Progress, RenderCancelled


class _Busy:
    """Counts the batch functions running at once (the most seen) and the threads that ran inner batches."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.running = 0
        self.most = 0
        self.inner_threads: set[int] = set()

    def run(self, seconds: float, inner: bool = False) -> None:
        with self.lock:
            self.running += 1
            self.most = max(self.most, self.running)
            if inner:
                self.inner_threads.add(threading.get_ident())
        time.sleep(seconds)
        with self.lock:
            self.running -= 1


def _threads_named_lazyvis() -> list[str]:
    return [thread.name for thread in threading.enumerate() if thread.name.startswith("lazyvis")]


def test_nested_calls_share_the_render_threads_and_end_with_it():
    """Two outer batches, one long and one short, each running inner batches (a band and its pass 2): at no
    moment do more than the render's two threads run a batch (a pool per call ran up to three times as
    many), the short band's thread joins the long band's inner batches once it is free, the results are in
    order, and no thread outlives the context."""
    busy = _Busy()

    def band(length: int) -> list[int]:
        def inner(k: int) -> int:
            busy.run(0.02, inner=length > 2)
            return k * k
        return map_batches(inner, list(range(length)), threads=8)  # asks for 8: the render's 2 hold

    with render_threads(2):
        results = map_batches(band, [12, 1], threads=2)
    assert results == [[k * k for k in range(12)], [0]]
    assert busy.most <= 2
    assert len(busy.inner_threads) == 2  # the long band's inner batches ran on both threads
    assert not _threads_named_lazyvis()


def test_a_failing_inner_batch_reaches_the_caller_and_stops_the_rest():
    """A batch that raises: the exception reaches the outermost caller, the batches not yet started never
    start, and the pool's threads end with the context."""
    started = []

    def inner(k: int) -> int:
        started.append(k)
        if k == 3:
            raise ValueError("batch 3 failed")
        time.sleep(0.01)
        return k

    def band(_: int) -> list[int]:
        return map_batches(inner, list(range(40)), threads=2)

    with pytest.raises(ValueError, match="batch 3 failed"):
        with render_threads(2):
            map_batches(band, [0], threads=2)
    assert len(started) < 40
    assert not _threads_named_lazyvis()


class _CancelAfter(Progress):
    def __init__(self, seconds: float) -> None:
        super().__init__()
        self.deadline = time.perf_counter() + seconds

    def is_cancelled(self) -> bool:
        return time.perf_counter() > self.deadline


def test_a_cancel_stops_shared_batches_within_their_next_check():
    """A cancel seen by the caller stops the batches running on the pool at their next ``check_cancel`` (a
    long batch that checks every 10 ms), within a fraction of a second, and the render's threads end."""
    progress = _CancelAfter(0.15)

    def batch(_: int) -> None:
        for _ in range(500):  # 5 s unless stopped
            time.sleep(0.01)
            progress.check_cancel()

    begun = time.perf_counter()
    with pytest.raises(RenderCancelled):
        with render_threads(2):
            map_batches(batch, list(range(6)), threads=2, progress=progress)
    assert time.perf_counter() - begun < 0.6
    assert not _threads_named_lazyvis()


def test_outside_a_render_a_call_makes_and_ends_its_own_pool():
    """Without ``render_threads`` a call runs on a pool of its own, in order, and leaves no thread behind."""
    assert map_batches(lambda k: k + 1, list(range(10)), threads=3) == list(range(1, 11))
    assert not _threads_named_lazyvis()
