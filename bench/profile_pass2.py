"""Where a render's time goes, by compiled kernel and numpy call: one render of a sample .blend on one
thread under cProfile (issue 13's and issue 15's speed work start here).

    .venv/bin/python bench/profile_pass2.py [--width 512] [--top 20] [--blends sample_blends/tree.blend ...]

Per .blend, exported at ``--width`` pixels with the settings the engine would use, a warm-up render and then
one profiled render with ``threads=1``: on the thread pool the profiler sees only the main thread waiting on
its workers. The compiled kernels release the GIL and run side by side on the pool, the numpy calls between
them mostly do not: a render whose time is in the kernels gains from more cores, one whose time is in numpy
barely does (at 512 px on 2 cores: the tree 42.5 s on one thread, 23-25 s on two; the boxes 4.5 s, 4.3 s).
Prints each render's stage seconds, then the ``--top`` functions by time spent in them (self time).
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "bench")]

from bench_geometry import load_blend  # noqa: E402

from lazyvis_addon.core.render import render  # noqa: E402

DEFAULT_BLENDS = [ROOT / "sample_blends" / "tree.blend"]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--blends", nargs="+", type=Path, default=DEFAULT_BLENDS)
    parser.add_argument("--width", type=int, default=512)
    parser.add_argument("--top", type=int, default=20, help="functions listed, by self time")
    args = parser.parse_args()
    for path in args.blends:
        scene, settings = load_blend(path, args.width, None)
        settings = replace(settings, threads=1)
        render(scene, settings)  # warm: Numba's cache loaded, pages touched
        profiler = cProfile.Profile()
        started = time.perf_counter()
        profiler.enable()
        output = render(scene, settings)
        profiler.disable()
        wall = time.perf_counter() - started
        stages = ", ".join(f"{name} {seconds:.2f}" for name, seconds in output.stats["stage_seconds"].items())
        print(f"\n{path.stem} at {args.width} px, one thread: {wall:.2f} s under the profiler\n  stages: {stages}")
        text = io.StringIO()
        pstats.Stats(profiler, stream=text).sort_stats("tottime").print_stats(args.top)
        listing = text.getvalue()
        print(listing[listing.find("   ncalls"):].rstrip())
    return 0


if __name__ == "__main__":
    sys.exit(main())
