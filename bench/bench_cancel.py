"""How fast Esc stops a render, stage by stage (issue 17: within a second at every stage).

    .venv/bin/python bench/bench_cancel.py [--width 512] [--delay 0.3] [--blends sample_blends/tree.blend ...]

Per .blend, exported at ``--width`` pixels with the engine's settings (the defaults), a warm-up render, then
one render per stage with a progress object that asks for a cancel ``--delay`` seconds after the stage
begins (a stage over by then has the cancel seen in a later one, which is printed): the time from that request to the render's return
(RenderCancelled), and whether any of the render's threads outlived it. Also the longest stretch between
two cancel checks over a whole render, per stage (what a request at the worst moment waits, on the
calling thread; the pool's threads stop at their next chunk).
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "bench")]

from bench_geometry import load_blend  # noqa: E402

from lazyvis_addon.core.progress import Progress, RenderCancelled  # noqa: E402
from lazyvis_addon.core.render import render  # noqa: E402

STAGES = ("Validating scene", "Building BVH", "Building edge tree", "Camera rays", "Illumination",
          "Composing passes", "Anti-aliasing")


class CancelIn(Progress):
    """Asks for a cancel ``delay`` seconds after ``stage`` begins."""

    def __init__(self, stage: str, delay: float) -> None:
        super().__init__()
        self.stage, self.delay, self.asked, self.current, self.seen_in = stage, delay, None, None, None

    def on_stage(self, name: str, total: int) -> None:
        self.current = name
        if name == self.stage and self.asked is None:
            self.asked = time.perf_counter() + self.delay

    def is_cancelled(self) -> bool:
        cancelled = self.asked is not None and time.perf_counter() > self.asked
        if cancelled and self.seen_in is None:
            self.seen_in = self.current  # the stage under way when the cancel was seen
        return cancelled


class Stretches(Progress):
    """The longest time between two cancel checks, by the stage the stretch ended in."""

    def __init__(self) -> None:
        super().__init__()
        self.last, self.longest, self.current = time.perf_counter(), {}, "start"

    def on_stage(self, name: str, total: int) -> None:
        self.current = name

    def is_cancelled(self) -> bool:
        now = time.perf_counter()
        self.longest[self.current] = max(self.longest.get(self.current, 0.0), now - self.last)
        self.last = now
        return False


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--blends", nargs="+", type=Path, default=[ROOT / "sample_blends" / "tree.blend"])
    parser.add_argument("--width", type=int, default=512)
    parser.add_argument("--delay", type=float, default=0.3, help="seconds into the stage the cancel is asked")
    args = parser.parse_args()
    worst = 0.0
    for path in args.blends:
        scene, settings = load_blend(path, args.width, None)
        render(scene, settings)  # warm: Numba's cache loaded
        stretches = Stretches()
        started = time.perf_counter()
        render(scene, settings, stretches)
        print(f"\n{path.stem} at {args.width} px: {time.perf_counter() - started:.2f} s; longest stretch "
              "without a cancel check, by the stage it ended in: "
              + ", ".join(f"{name} {seconds:.2f} s" for name, seconds in stretches.longest.items()))
        for stage in STAGES:
            progress = CancelIn(stage, args.delay)
            try:
                render(scene, settings, progress)
                print(f"  {stage:20s} over within {args.delay} s: not cancelled")
                continue
            except RenderCancelled:
                latency = time.perf_counter() - progress.asked
            alive = [t.name for t in threading.enumerate() if t.name.startswith("lazyvis")]
            worst = max(worst, latency)
            print(f"  {stage:20s} returned {latency:.3f} s after the request (seen in {progress.seen_in})"
                  + (f"; threads left: {alive}" if alive else ""))
    print(f"\nworst: {worst:.3f} s (target: under 1 s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
