"""Render a .blend with Cycles as a direct-light reference for LazyVis, to a float EXR.

Settings follow /work/shared/notes/radiometry.md ("Cycles settings for a direct-light reference"):
max_bounces 0 (direct light only), filter_width 0.01 (a point sample at each pixel centre), no
denoising, no adaptive sampling, light_sampling_threshold 0, no clamping, a fixed (not animated) seed,
CPU. The EXR is 32-bit float RGBA, scene-linear, rows top first.

    .venv/bin/python tools/make_cycles_reference.py scene.blend out.exr --samples 64 --resolution 64 64
    blender -b scene.blend -P tools/make_cycles_reference.py -- - out.exr --samples 64

Keep references small while developing (<= 64 x 64, low samples); high-sample references come later.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("blend", help="the .blend to render ('-' for the file already open in Blender)")
    parser.add_argument("output", help="the EXR to write")
    parser.add_argument("--samples", type=int, default=64, help="Cycles samples per pixel (default 64)")
    parser.add_argument("--seed", type=int, default=0, help="Cycles seed (default 0)")
    parser.add_argument("--resolution", type=int, nargs=2, metavar=("W", "H"),
                        help="override the resolution (percentage is set to 100)")
    parser.add_argument("--scene", help="scene name (default: the file's active scene)")
    parser.add_argument("--frame", type=int, help="frame to render (default: the current frame)")
    parser.add_argument("--threads", type=int, default=0, help="render threads (default 0 = all cores)")
    return parser.parse_args(argv)


def configure_cycles(scene, samples: int, seed: int, threads: int = 0, filter_width: float = 0.01) -> None:
    """Cycles settings of a direct-light reference (radiometry.md; ``lazyvis compare`` uses the same,
    ``lazyvis_addon.compare.configure_direct_cycles``); ``filter_width`` the Blackman-Harris pixel filter's
    radius (0.01, a point sample at the pixel centre, unless a test compares filtered images: Blender's
    default is 1.5)."""
    root = str(Path(__file__).resolve().parents[1])
    if root not in sys.path:  # run inside a Blender install, the add-on's package beside this folder
        sys.path.insert(0, root)
    from lazyvis_addon.compare import configure_direct_cycles

    configure_direct_cycles(scene, samples, seed)
    scene.cycles.pixel_filter_type = "BLACKMAN_HARRIS"
    scene.cycles.filter_width = filter_width
    scene.render.threads_mode = "FIXED" if threads > 0 else "AUTO"
    if threads > 0:
        scene.render.threads = threads


def configure_output(scene, path: str) -> None:
    """A single-layer 32-bit float RGBA EXR, no compositing or sequencer."""
    render = scene.render
    render.use_compositing = False
    render.use_sequencer = False
    settings = render.image_settings
    settings.media_type = "IMAGE"
    settings.file_format = "OPEN_EXR"
    settings.color_mode = "RGBA"
    settings.color_depth = "32"
    settings.exr_codec = "ZIP"
    render.use_file_extension = False
    render.filepath = path


def main(argv: list[str]) -> int:
    args = parse_args(argv)
    import bpy

    if args.blend != "-":
        bpy.ops.wm.open_mainfile(filepath=args.blend)
    scene = bpy.data.scenes[args.scene] if args.scene else bpy.context.scene
    if args.frame is not None:
        scene.frame_set(args.frame)
    if args.resolution:
        scene.render.resolution_x, scene.render.resolution_y = args.resolution
        scene.render.resolution_percentage = 100
    width = scene.render.resolution_x * scene.render.resolution_percentage // 100
    height = scene.render.resolution_y * scene.render.resolution_percentage // 100
    configure_cycles(scene, args.samples, args.seed, args.threads)
    configure_output(scene, args.output)
    started = time.perf_counter()
    bpy.ops.render.render(write_still=True, scene=scene.name)
    print(f"Cycles reference {width} x {height}, {args.samples} samples, seed {args.seed}: {args.output} "
          f"({time.perf_counter() - started:.1f} s)")
    return 0


if __name__ == "__main__":
    argv = sys.argv[1:]
    if "--" in sys.argv:  # run inside Blender: blender -b file.blend -P this.py -- ARGS
        argv = sys.argv[sys.argv.index("--") + 1:]
    sys.exit(main(argv))
