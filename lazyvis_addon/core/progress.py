"""Progress, cancel and warnings: the one object the core talks to while it renders.

The core calls ``begin_stage`` / ``advance`` between batches and ``check_cancel`` (through
``advance``) so that a cancel stops a render within one batch. The Blender layer subclasses this to
drive ``RenderEngine.update_stats`` / ``update_progress`` / ``test_break``; the command line prints a bar.

Only the thread that made the progress object asks the front end (Blender wants its own thread); the pool's
threads call ``check_cancel`` too, between chunks of their work, and it raises there once the owner has
seen a cancel (``stop_workers``): so a cancel waits for a chunk, not for a whole batch (a batch of pass 2
under a tree's crown took 2 s).
"""

from __future__ import annotations

import threading
import time


class RenderCancelled(Exception):
    """Raised inside the core when the progress object reports a cancel."""


class Progress:
    """Base progress sink: records stage timings and warnings, never cancels.

    Subclasses override ``on_stage``, ``on_advance``, ``is_cancelled`` and ``on_warning``.
    """

    def __init__(self) -> None:
        self.stage_seconds: dict[str, float] = {}
        self.warnings: list[str] = []
        self._stage: str | None = None
        self._stage_start = 0.0
        self._total = 0
        self._done = 0
        self._owner = threading.get_ident()
        self._stop = threading.Event()

    # -- called by the core ------------------------------------------------------------------------
    def begin_stage(self, name: str, total: int = 0, done: int = 0) -> None:
        """Start a named stage of ``total`` work units (0 when unknown), ``done`` of them already (a stage
        taken up again for the next band of the frame); closes the previous stage. A stage's seconds add up
        over its bands."""
        self.end_stage()
        self._stage, self._stage_start, self._total, self._done = name, time.perf_counter(), int(total), int(done)
        self.on_stage(name, self._total)
        if self._done:  # a stage taken up again: its bar where it stopped
            self.on_advance(name, self._done, self._total)
        self.check_cancel()

    def advance(self, units: int = 1) -> None:
        """Report ``units`` more work done in the current stage, then check for a cancel."""
        self._done += int(units)
        self.on_advance(self._stage or "", self._done, self._total)
        self.check_cancel()

    def end_stage(self) -> None:
        if self._stage is not None:
            elapsed = time.perf_counter() - self._stage_start
            self.stage_seconds[self._stage] = self.stage_seconds.get(self._stage, 0.0) + elapsed
            self._stage = None

    def nested(self, warnings: bool = True) -> "Progress":
        """A progress for work done as part of the current stage (anti-aliasing shading its samples by pass
        2): the stages it begins are not stages of their own (their time stays the current stage's), while
        cancel and warnings (unless ``warnings`` is False: work that repeats what was warned of) still reach
        this one."""
        return _Nested(self, warnings)

    def warn(self, message: str) -> None:
        """A user-facing warning (dropped degenerate geometry, unsupported input)."""
        self.warnings.append(message)
        self.on_warning(message)

    def check_cancel(self) -> None:
        """Raise RenderCancelled if the render is to stop: on the owner's thread when the front end says so
        (or a worker failed), on a pool thread when the owner has called ``stop_workers``."""
        if threading.get_ident() != self._owner:
            if self._stop.is_set():
                raise RenderCancelled("render cancelled")
            return
        if self._stop.is_set() or self.is_cancelled():
            self._stop.set()
            raise RenderCancelled("render cancelled")

    def stop_workers(self) -> None:
        """Make the pool's threads raise RenderCancelled at their next ``check_cancel``."""
        self._stop.set()

    # -- overridden by front ends ------------------------------------------------------------------
    # Whether the render hands ``on_preview`` its image before anti-aliasing (a copy of the frame's passes,
    # so it costs only where a front end shows it).
    wants_preview = False

    def on_preview(self, output) -> None:
        """The image before anti-aliasing, a ``RenderOutput`` of the window asked for: every pixel its centre
        sample, the image a render at ``aa_samples=1`` gives, bit for bit. Called by a render that
        anti-aliases by silhouettes (the default visibility) when ``wants_preview`` is True, on the
        thread that called ``render``."""

    def on_stage(self, name: str, total: int) -> None:
        pass

    def on_advance(self, name: str, done: int, total: int) -> None:
        pass

    def is_cancelled(self) -> bool:
        return False

    def on_warning(self, message: str) -> None:
        pass


class _Nested(Progress):
    """``Progress.nested``: stages and advances are the outer stage's; cancel and warnings go to the outer
    (whose ``check_cancel`` tells its own thread from the pool's)."""

    def __init__(self, outer: Progress, warnings: bool = True) -> None:
        super().__init__()
        self.outer = outer
        self.forward_warnings = warnings

    def begin_stage(self, name: str, total: int = 0, done: int = 0) -> None:
        self.check_cancel()

    def advance(self, units: int = 1) -> None:
        self.check_cancel()

    def end_stage(self) -> None:
        pass

    def warn(self, message: str) -> None:
        if self.forward_warnings:
            self.outer.warn(message)

    def check_cancel(self) -> None:
        self.outer.check_cancel()

    def stop_workers(self) -> None:
        self.outer.stop_workers()

    def nested(self, warnings: bool = True) -> Progress:
        return self if warnings or not self.forward_warnings else _Nested(self.outer, False)
