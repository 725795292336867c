"""Pass 2's arrangement kernel and whole renders on the sample .blends (issue 13's speed work).

    .venv/bin/python bench/bench_arrangement.py [--width 512] [--repeats 3] [--blends sample_blends/tree.blend ...]
    .venv/bin/python bench/bench_arrangement.py --save-chunks chunks.pkl      # keep the captured chunks
    .venv/bin/python bench/bench_arrangement.py --compare chunks.pkl          # same outputs as a saved run?

Per .blend, exported at ``--width`` pixels through Blender's exporter with the settings the engine would use:
- the whole render's wall time (default settings, warm: one render first, then the median of ``--repeats``);
- the arrangement kernel alone (``arrangement._fans``) on six chunks of couples captured from the middle of
  that render, fastest of ``--repeats``: microseconds per arc of the regions it gets (a cell's arcs count
  once per cell), so a change of the kernel is timed without the rest of pass 2's noise.
``--save-chunks`` writes the chunks and the kernel's outputs; ``--compare`` checks that this code gives the
same outputs, bit for bit, on chunks saved by another version (the kernel's inputs do not depend on it).
"""

from __future__ import annotations

import argparse
import pickle
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "bench"), str(ROOT / "tools")]

from bench_geometry import load_blend  # noqa: E402

from lazyvis_addon.core import arrangement, render  # noqa: E402

DEFAULT_BLENDS = [ROOT / "sample_blends" / f"{name}.blend" for name in ("floating_boxes", "suzanne_dense3", "tree")]
CHUNKS = 6


def captured_chunks(scene, settings) -> list[tuple]:
    """The arrangement kernel's inputs for CHUNKS consecutive chunks from the middle of a render (one
    thread, so the chunks come in order)."""
    kernel = arrangement._fans
    calls = []

    def capture(*inputs):
        calls.append(inputs)
        return kernel(*inputs)

    capture.stats = kernel.stats  # the render asks whether the kernels were compiled
    arrangement._fans = capture
    try:
        render(scene, settings.replace(threads=1, aa_samples=1))
    finally:
        arrangement._fans = kernel
    middle = max(len(calls) // 2 - CHUNKS // 2, 0)
    return calls[middle:middle + CHUNKS]


def kernel_seconds(chunks: list[tuple], repeats: int) -> tuple[float, list]:
    """Fastest wall time of the kernel over all chunks, and its outputs."""
    best, outputs = None, None
    for _ in range(max(repeats, 1)):
        started = time.perf_counter()
        outputs = [arrangement._fans(*inputs) for inputs in chunks]
        seconds = time.perf_counter() - started
        best = seconds if best is None else min(best, seconds)
    return best, outputs


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--blends", type=Path, nargs="+", default=DEFAULT_BLENDS)
    parser.add_argument("--width", type=int, default=512)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--save-chunks", type=Path, help="write the captured chunks and outputs here")
    parser.add_argument("--compare", type=Path, help="check the outputs on chunks saved by --save-chunks")
    args = parser.parse_args()

    if args.compare:
        saved = pickle.loads(args.compare.read_bytes())
        for name, (chunks, expected) in saved.items():
            _, outputs = kernel_seconds(chunks, 1)
            same = all(all(np.array_equal(np.asarray(a), np.asarray(b)) for a, b in zip(ours, theirs))
                       for ours, theirs in zip(outputs, expected))
            print(f"{name}: {'identical' if same else 'DIFFERENT'} outputs on {len(chunks)} chunks")
        return 0

    saved = {}
    print(f"{'scene':<16} {'render s (median)':>18} {'kernel s':>9} {'arcs':>9} {'us/arc':>7}")
    for path in args.blends:
        scene, settings = load_blend(path, args.width, None)
        render(scene, settings)  # warm: kernels loaded, caches filled
        times = []
        for _ in range(max(args.repeats, 1)):
            started = time.perf_counter()
            render(scene, settings)
            times.append(time.perf_counter() - started)
        chunks = captured_chunks(scene, settings)
        seconds, outputs = kernel_seconds(chunks, args.repeats)
        arcs = int(sum(int(inputs[1].sum()) for inputs in chunks))
        print(f"{path.stem:<16} {statistics.median(times):>18.2f} {seconds:>9.3f} {arcs:>9,} "
              f"{1e6 * seconds / max(arcs, 1):>7.3f}", flush=True)
        saved[path.stem] = (chunks, outputs)
    if args.save_chunks:
        args.save_chunks.write_bytes(pickle.dumps(saved))
    return 0


if __name__ == "__main__":
    sys.exit(main())
