"""Peak resident memory of one core render at production resolutions (issue 15: 1920 x 1080 under 2 GB,
3840 x 2160 under 4 GB, the memory budget the real cap).

    .venv/bin/python bench/bench_memory.py [--size 3840 2160] [--budget 2048] [--blend FILE.blend]

Renders once in this process at default settings (but the budget), after a 16 x 16 px warm-up render
that loads the compiled kernels (``--cold``: without it), and prints, in MB: the process's resident memory
before the render (Python, numpy, Numba and its kernels, Embree, bpy if a .blend is read, the scene), its
peak during the render (``VmHWM``, reset first where the kernel allows), and the difference: what the
render itself took. Without ``--blend``: a plane, a box and a square light (``simple_scene``), the scene
of the memory test; ``--json``: also write the figures.
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "bench")]

from lazyvis_addon.core import Camera, Settings, render  # noqa: E402
from lazyvis_addon.core import demo_scenes  # noqa: E402


def simple_scene(width: int, height: int):
    """A 4 x 4 plane, a 0.6 box standing on it and a square light above, seen in perspective at
    ``width`` x ``height``: a soft shadow and the box's outline to anti-alias."""
    box = demo_scenes.box_triangles((0.3, 0.2, 0.3), 0.6, rotation_z=0.4)
    scene = demo_scenes.plane_under_light(resolution=8, light_size=1.0, height=2.0, blocker=box)
    scene.camera = Camera.perspective(demo_scenes.look_at((3.0, -3.0, 2.5), (0.0, 0.0, 0.2)), width, height,
                                      np.radians(50.0))
    return scene


def resident_mb(field: str) -> float:
    """``VmRSS`` or ``VmHWM`` of this process in MB (Linux)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024.0
    raise RuntimeError(f"{field} not in /proc/self/status")


def reset_peak() -> bool:
    """Reset VmHWM to the current resident size (Linux 4.0+: write 5 to clear_refs); False where refused."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", nargs=2, type=int, default=[3840, 2160], metavar=("WIDTH", "HEIGHT"))
    parser.add_argument("--budget", type=float, default=None, help="memory budget in MB (default: Settings')")
    parser.add_argument("--blend", type=Path, default=None, help="a .blend (read through bpy) instead of the simple scene")
    parser.add_argument("--threads", type=int, default=0)
    parser.add_argument("--cold", action="store_true",
                        help="no warm-up render first: the peak includes loading the compiled kernels")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    width, height = args.size
    if args.blend is not None:
        from bench_geometry import load_blend
        scene, settings = load_blend(args.blend, width, None, height=height)
    else:
        scene, settings = simple_scene(width, height), Settings()
    settings = replace(settings, threads=args.threads)
    if args.budget is not None:
        settings = replace(settings, memory_budget_mb=args.budget)
    if not args.cold:
        # A first render of a few pixels loads what stays loaded (Numba's compiled kernels, about 75 MB):
        # the budget is the render's working memory, not the program's.
        warm = copy.copy(scene)
        warm.camera = replace(scene.camera, window=(0, 0, 16, 16))
        render(warm, settings)
    before = resident_mb("VmRSS")
    reset = reset_peak()
    started = time.perf_counter()
    output = render(scene, settings)
    seconds = time.perf_counter() - started
    peak = resident_mb("VmHWM")
    row = dict(scene=args.blend.stem if args.blend else "simple", width=int(scene.camera.width),
               height=int(scene.camera.height), budget_mb=settings.memory_budget_mb, seconds=seconds,
               before_mb=before, peak_mb=peak, render_mb=peak - before, peak_reset=reset,
               working_budget_mb=round(output.stats["working_budget_mb"], 1), bands=int(output.stats.get("bands", 1)),
               stage_seconds={k: round(v, 3) for k, v in output.stats["stage_seconds"].items()})
    print(json.dumps(row))
    if args.json is not None:
        args.json.write_text(json.dumps(row, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
