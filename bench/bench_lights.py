"""Issue 14's and 16's costs: mesh emitters as hulls, lights the camera sees, and the corrected glossy default.

    .venv/bin/python bench/bench_lights.py [--repeats 3] [--parts torus seen glossy]

Core renders (no Blender export), default settings unless said, fastest of ``--repeats`` after a warm-up:

- a 576-face emissive torus over a floor at 64 px: as one hull (two lights, the default grouping) and as one
  light per triangle (the path crowded emitters and the other integrators take);
- an area light the camera sees (1.2 x 0.8 m, seen from below over a floor) at 256 and 512 px: the render
  with and without it drawn, and the *Drawing lights* stage;
- ``sample_blends/room.blend`` and ``glossy.blend`` (exported through bpy) at 128 and 256 px with the glossy
  integrator ``ltc_cv`` (the default) and ``ltc``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "bench")]

from lazyvis_addon.core import Camera, Lights, Materials, Scene, SeenLights, Settings, render  # noqa: E402
from lazyvis_addon.core.demo_scenes import look_at, quad_triangles  # noqa: E402
from lazyvis_addon.core.emitters import group_mesh_emitters  # noqa: E402
from lazyvis_addon.core.scene import EmitterHulls  # noqa: E402


def fastest(scene: Scene, settings: Settings, repeats: int):
    """(seconds, output) of the fastest of ``repeats`` renders after one warm-up."""
    render(scene, settings)
    best, output = math.inf, None
    for _ in range(repeats):  # repeats: a handful
        started = time.perf_counter()
        output = render(scene, settings)
        best = min(best, time.perf_counter() - started)
    return best, output


def torus(major=0.5, minor=0.15, around=24, across=12, height=0.6) -> np.ndarray:
    """A torus of 2 * around * across triangles about the z axis at ``height``."""
    a, b = np.meshgrid(2 * np.pi * np.arange(around + 1) / around, 2 * np.pi * np.arange(across + 1) / across,
                       indexing="ij")
    ring = major + minor * np.cos(b)
    grid = np.stack([ring * np.cos(a), ring * np.sin(a), height + minor * np.sin(b)], axis=-1)
    p00, p10, p11, p01 = grid[:-1, :-1], grid[1:, :-1], grid[1:, 1:], grid[:-1, 1:]
    return np.concatenate([np.stack([p00, p10, p11], axis=2).reshape(-1, 3, 3),
                           np.stack([p00, p11, p01], axis=2).reshape(-1, 3, 3)])


def torus_scene(grouped: bool) -> Scene:
    emitter = torus()
    floor = quad_triangles([(-3, -3, 0), (3, -3, 0), (3, 3, 0), (-3, 3, 0)])
    lights = Lights(emitter, np.full(len(emitter), 3), np.full((len(emitter), 3), 4.0), np.ones(len(emitter), bool))
    hulls = EmitterHulls.empty()
    if grouped:
        lights, hulls = group_mesh_emitters(lights, np.zeros(len(emitter), np.int64))[:2]
    material = np.concatenate([np.zeros(len(floor), np.int64), np.ones(len(emitter), np.int64)])
    camera = Camera.perspective(look_at((0.0, -3.0, 2.5), (0.0, 0.0, 0.3)), 64, 64, np.radians(50))
    return Scene(np.concatenate([floor, emitter]), material, Materials.diffuse([(0.5,) * 3, (0.5,) * 3]), lights,
                 camera, hulls=hulls)


def seen_light_scene(resolution: int, drawn: bool) -> Scene:
    floor = quad_triangles([(-5, -5, 0), (5, -5, 0), (5, 5, 0), (-5, 5, 0)])
    polygon = [(-0.6, 0.4, 1.5), (0.6, 0.4, 1.5), (0.6, -0.4, 1.5), (-0.6, -0.4, 1.5)]  # emitting downwards
    lights = Lights.from_polygons([polygon], [(5.0, 5.0, 5.0)])
    seen = SeenLights.area((0, 0, 1.5), (0.6, 0, 0), (0, -0.4, 0), (5.0, 5.0, 5.0)) if drawn else SeenLights.empty()
    camera = Camera.perspective(look_at((0.0, -3.5, 0.3), (0.0, 0.0, 1.0), up=(0, 0, 1)), resolution, resolution,
                                math.radians(60))
    return Scene(floor, np.zeros(2, np.int64), Materials.diffuse([(0.5, 0.5, 0.5)]), lights, camera, seen=seen)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--parts", nargs="+", choices=("torus", "seen", "glossy"), default=("torus", "seen", "glossy"),
                        help="which measurements to run (default: all)")
    args = parser.parse_args()

    if "torus" in args.parts:
        torus(args.repeats)
    if "seen" in args.parts:
        seen(args.repeats)
    if "glossy" in args.parts:
        glossy(args.repeats)
    return 0


def torus(repeats: int) -> None:
    print("576-face emissive torus over a floor, 64 px:")
    for grouped, label in ((True, "one hull (two lights)"), (False, "one light per triangle")):
        seconds, output = fastest(torus_scene(grouped), Settings(), repeats)
        print(f"  {label:24s} {seconds:6.2f} s, {output.stats['peak_memory_mb']:.0f} MB peak")


def seen(repeats: int) -> None:
    print("An area light the camera sees, over a floor:")
    for resolution in (256, 512):
        plain, _ = fastest(seen_light_scene(resolution, False), Settings(), repeats)
        seconds, output = fastest(seen_light_scene(resolution, True), Settings(), repeats)
        print(f"  {resolution} px: {plain:.2f} s without, {seconds:.2f} s drawn "
              f"(Drawing lights {output.stats['stage_seconds'].get('Drawing lights', 0.0):.2f} s)")


def glossy(repeats: int) -> None:
    from bench_geometry import load_blend
    print("Glossy integrals (core render of the exported sample):")
    for blend, resolution in (("room", 128), ("room", 256), ("glossy", 128)):
        scene, settings = load_blend(ROOT / "sample_blends" / f"{blend}.blend", resolution, None)
        times = {name: fastest(scene, replace(settings, glossy_integrator=name), repeats)[0]
                 for name in ("ltc", "ltc_cv")}
        print(f"  {blend}.blend {resolution} px: ltc {times['ltc']:.2f} s, ltc_cv (default) {times['ltc_cv']:.2f} s "
              f"({times['ltc_cv'] / times['ltc']:.1f}x)")


if __name__ == "__main__":
    sys.exit(main())
