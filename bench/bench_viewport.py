"""Time to the viewport's images (issue 19): the first coarse image and the full one, per sample .blend.

    .venv/bin/python bench/bench_viewport.py [--size 1280 720] [--blends sample_blends/*.blend] [--repeats 3]
        [--cancel-delays 0.05 0.3 1.0] [--no-sequence]

Per .blend, exported through bpy at the viewport size with the engine's settings (the defaults), the
progressive renderer (``core.progressive``, what the Rendered viewport runs) from a start to each step's
image: the start resolution (1/32 and 1/16 at 1280 x 720, ``progressive.step_divisors``), 1/8, 1/4, 1/2 and
full resolution without anti-aliasing, then the final (the F12 render of the view); the median of ``--repeats`` runs after a small warm-up render (the kernels loaded), each on a new
renderer (a scene it has not prepared: the viewport's first start, or a change of geometry). Then the
first image of a restart on a renderer that has started on the scene before (its first image shown,
then cancelled and stopped), the median of ``--repeats``: after the view turned by a degree ("view"), and
after a new scene of equal triangles and brighter lights ("lights": a new export after a change of
lights). Then, for each of ``--cancel-delays``, a render cancelled that many seconds into it: how long its
thread took to stop (the viewport's "any change cancels the work in progress"), the worst of the delays
printed. ``--no-sequence``: the first images only (the cold start's and the restarts').
Targets (printed): the first coarse image within about 0.2 s of a change, and the issue's 1/8 image too.
"""

from __future__ import annotations

import argparse
import copy
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "bench")]

from bench_geometry import load_blend  # noqa: E402

from lazyvis_addon.core.progressive import ProgressiveRenderer, scaled_camera, step_divisors  # noqa: E402
from lazyvis_addon.core.render import render  # noqa: E402

SAMPLE_BLENDS = sorted((ROOT / "sample_blends").glob("*.blend"))
FIRST_IMAGE_TARGET = 0.2


def step_times(scene, settings) -> list[float]:
    """Seconds from a start to each step's image."""
    times: list[float] = []
    renderer = ProgressiveRenderer(on_image=lambda image: times.append(image.seconds))
    renderer.start(scene, settings)
    renderer.wait()
    renderer.close()
    if renderer.error:
        raise RuntimeError(renderer.error)
    return times


def first_image(renderer: ProgressiveRenderer, images: list, scene, settings) -> float:
    """Start ``renderer`` (whose ``on_image`` appends to ``images``) on ``scene`` and return the seconds to
    its first image; the render is then cancelled and its thread waited for."""
    count = len(images)
    generation = renderer.start(scene, settings)
    while not any(image.generation == generation for image in images[count:]):
        if renderer.error:
            raise RuntimeError(renderer.error)
        time.sleep(0.002)
    renderer.cancel(wait=True)
    return next(image.seconds for image in images[count:] if image.generation == generation)


def turned(scene, degrees: float = 1.0):
    """``scene`` seen through its camera turned ``degrees`` about the camera's up axis (a moved view)."""
    angle = np.radians(degrees)
    rotation = np.eye(4)
    rotation[[0, 0, 2, 2], [0, 2, 0, 2]] = np.cos(angle), np.sin(angle), -np.sin(angle), np.cos(angle)
    camera = replace(scene.camera, world_from_camera=scene.camera.world_from_camera @ rotation)
    return replace(scene, camera=camera)


def relit(scene):
    """A new scene of equal arrays but brighter lights (what a new export after a change of lights gives)."""
    scene = copy.deepcopy(scene)
    lights = replace(scene.lights, radiance=scene.lights.radiance * 1.5)
    facing = replace(scene.facing, intensity=scene.facing.intensity * 1.5)
    return replace(scene, lights=lights, facing=facing)


def cold_seconds(scene, settings) -> float:
    """Seconds to the first image of a new renderer's start on ``scene``."""
    images: list = []
    renderer = ProgressiveRenderer(on_image=images.append)
    try:
        return first_image(renderer, images, scene, settings)
    finally:
        renderer.close()


def restart_seconds(scene, settings, changed) -> float:
    """Seconds to the first image of a start on ``changed`` by a renderer that has started on ``scene``
    (its first image shown, then cancelled and stopped)."""
    images: list = []
    renderer = ProgressiveRenderer(on_image=images.append)
    try:
        first_image(renderer, images, scene, settings)
        return first_image(renderer, images, changed, settings)
    finally:
        renderer.close()


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
    parser.add_argument("--no-sequence", action="store_true", help="the first images only")
    args = parser.parse_args()
    width, height = args.size
    sequence = not args.no_sequence
    divisors = step_divisors(width, height)
    steps = [f"1/{d}" if d > 1 else "full" for d in divisors] + ["final (anti-aliased)"]
    columns = " | ".join(steps) if sequence else f"first (1/{divisors[0]})"
    print(f"| sample | {columns} | first after: view | lights | cancel (worst of {args.cancel_delays} s in) |")
    print("|---|" + "---|" * (columns.count("|") + 4))
    firsts, restarts, eighths = [], [], []
    for blend in args.blends:
        scene, settings = load_blend(blend, width, None, height=height)
        # Warm-up: a small render loads the compiled kernels (a viewport session has them from the start).
        render(replace(scene, camera=scaled_camera(scene.camera, 16)), settings)
        if sequence:
            runs = [step_times(scene, settings) for _ in range(args.repeats)]
        else:
            runs = [[cold_seconds(scene, settings)] for _ in range(args.repeats)]
        medians = [statistics.median(run[k] for run in runs) for k in range(min(map(len, runs)))]
        view = statistics.median(restart_seconds(scene, settings, turned(scene)) for _ in range(args.repeats))
        lights = statistics.median(restart_seconds(scene, settings, relit(scene)) for _ in range(args.repeats))
        cancels = [cancel_seconds(scene, settings, delay) for delay in args.cancel_delays]
        firsts.append(medians[0])
        restarts.append(max(view, lights))
        if sequence:
            eighths.append(medians[divisors.index(8)])
        cells = " | ".join(f"{t:.2f} s" for t in medians)
        print(f"| {blend.stem} | {cells} | {view:.2f} s | {lights:.2f} s | "
              f"{max(cancels) if cancels else float('nan'):.3f} s |", flush=True)
    for what, times in (("a start (a new scene)", firsts), ("a restart (view or lights changed)", restarts)):
        verdict = "PASS" if max(times) <= FIRST_IMAGE_TARGET else "FAIL"
        print(f"first coarse image within {FIRST_IMAGE_TARGET} s of {what} on every sample: {verdict} "
              f"(slowest {max(times):.2f} s)")
    if eighths:
        verdict = "PASS" if max(eighths) <= FIRST_IMAGE_TARGET else "FAIL"
        print(f"the 1/8 image within {FIRST_IMAGE_TARGET} s of a start on every sample: {verdict} "
              f"(slowest {max(eighths):.2f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
