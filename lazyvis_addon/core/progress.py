"""Progress, cancel and warnings: the one object the core talks to while it renders.

The core calls ``begin_stage`` / ``advance`` between batches and ``check_cancel`` (through
``advance``) so that a cancel stops a render within one batch. The Blender layer subclasses this to
drive ``RenderEngine.update_stats`` / ``update_progress`` / ``test_break``; the command line prints a bar.
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

    def nested(self) -> "Progress":
        """A progress for work done as part of the current stage (anti-aliasing shading its samples by pass
        2): the stages it begins are not stages of their own (their time stays the current stage's), while
        cancel and warnings still reach this one."""
        return _Nested(self)

    def warn(self, message: str) -> None:
        """A user-facing warning (dropped degenerate geometry, unsupported input)."""
        self.warnings.append(message)
        self.on_warning(message)

    def check_cancel(self) -> None:
        if self.is_cancelled():
            raise RenderCancelled("render cancelled")

    # -- overridden by front ends ------------------------------------------------------------------
    def on_stage(self, name: str, total: int) -> None:
        pass

    def on_advance(self, name: str, done: int, total: int) -> None:
        pass

    def is_cancelled(self) -> bool:
        return False

    def on_warning(self, message: str) -> None:
        pass


class _Nested(Progress):
    """``Progress.nested``: stages and advances are the outer stage's; cancel and warnings go to the outer,
    cancel only from the thread that made this one (front ends ask Blender, which wants its own thread;
    work on the pool is cancelled between its batches by the calling thread)."""

    def __init__(self, outer: Progress) -> None:
        super().__init__()
        self.outer = outer
        self._thread = threading.get_ident()

    def begin_stage(self, name: str, total: int = 0, done: int = 0) -> None:
        self.check_cancel()

    def advance(self, units: int = 1) -> None:
        self.check_cancel()

    def end_stage(self) -> None:
        pass

    def warn(self, message: str) -> None:
        self.outer.warn(message)

    def check_cancel(self) -> None:
        if threading.get_ident() == self._thread:
            self.outer.check_cancel()

    def nested(self) -> Progress:
        return self
