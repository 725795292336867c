"""Time to the viewport's images (issue 19): the first coarse image and the full one, per sample .blend.

    .venv/bin/python bench/bench_viewport.py [--size 1280 720] [--blends sample_blends/*.blend] [--repeats 3]
        [--cancel-delays 0.05 0.3 1.0]

Per .blend, exported through bpy at the viewport size with the engine's settings (the defaults), the
progressive renderer (``core.progressive``, what the Rendered viewport runs) from a start to each step's
image: 1/8, 1/4, 1/2 and full resolution without anti-aliasing, then the final (the F12 render of the
view); the median of ``--repeats`` runs after a small warm-up render (the kernels loaded). Then, for each
of ``--cancel-delays``, a render cancelled that many seconds into it: how long its thread took to stop (the
viewport's "any change cancels the work in progress"), the worst of the delays printed.
Targets (printed): the first coarse image within about 0.2 s of a change.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "bench")]

from bench_geometry import load_blend  # noqa: E402

from lazyvis_addon.core.progressive import ProgressiveRenderer, scaled_camera  # noqa: E402
from lazyvis_addon.core.render import render  # noqa: E402

SAMPLE_BLENDS = sorted((ROOT / "sample_blends").glob("*.blend"))
FIRST_IMAGE_TARGET = 0.2


def step_times(scene, settings) -> list[float]:
    """Seconds from a start to each step's image."""
    times: list[float] = []
    renderer = ProgressiveRenderer(on_image=lambda image: times.append(image.seconds))
    renderer.start(scene, settings)
    renderer.wait()
    if renderer.error:
        raise RuntimeError(renderer.error)
    return times


def cancel_seconds(scene, settings, delay: float) -> float:
    """How long the render in progress takes to stop when it is cancelled ``delay`` s into it."""
    renderer = ProgressiveRenderer()
    renderer.start(scene, settings)
    time.sleep(delay)
    asked = time.perf_counter()
    renderer.cancel(wait=True)
    return time.perf_counter() - asked


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", nargs=2, type=int, default=[1280, 720], metavar=("WIDTH", "HEIGHT"))
    parser.add_argument("--blends", type=Path, nargs="+", default=SAMPLE_BLENDS)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--cancel-delays", type=float, nargs="*", default=[0.05, 0.3, 1.0])
    args = parser.parse_args()
    width, height = args.size
    print(f"| sample | 1/8 | 1/4 | 1/2 | full | final (anti-aliased) | cancel (worst of {args.cancel_delays} s in) |")
    print("|---|---|---|---|---|---|---|")
    firsts = []
    for blend in args.blends:
        scene, settings = load_blend(blend, width, None, height=height)
        # Warm-up: a small render loads the compiled kernels (a viewport session has them from the start).
        render(replace(scene, camera=scaled_camera(scene.camera, 16)), settings)
        runs = [step_times(scene, settings) for _ in range(args.repeats)]
        medians = [statistics.median(run[k] for run in runs) for k in range(min(map(len, runs)))]
        cancels = [cancel_seconds(scene, settings, delay) for delay in args.cancel_delays]
        firsts.append(medians[0])
        cells = " | ".join(f"{t:.2f} s" for t in medians)
        print(f"| {blend.stem} | {cells} | {max(cancels):.3f} s |", flush=True)
    verdict = "PASS" if max(firsts) <= FIRST_IMAGE_TARGET else "FAIL"
    print(f"first coarse image within {FIRST_IMAGE_TARGET} s on every sample: {verdict} "
          f"(slowest {max(firsts):.2f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
