"""Command line: render a .npz scene to a multi-channel EXR without Blender.

    python -m lazyvis_addon.core scene.npz -o out.exr [--integrator analytic] [--shadow-rays 4] ...
    python -m lazyvis_addon.core --demo floating_boxes -o out.exr     # the built-in sample scene
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

from . import demo_scenes
from .exr import write_exr
from .film import FILTER_TYPES
from .png import linear_to_srgb8, write_png
from .progress import Progress, RenderCancelled
from .render import RenderOutput, render
from .scene import Scene
from .settings import GLOSSY_INTEGRATORS, INTEGRATORS, VISIBILITY_METHODS, Settings


class ConsoleProgress(Progress):
    """A one-line progress bar on stderr."""

    def __init__(self, stream=None) -> None:
        super().__init__()
        # stderr as it is when the bar is made (a default argument would keep the one of the first import)
        self.stream = stream if stream is not None else sys.stderr
        self._last = 0.0

    def on_stage(self, name: str, total: int) -> None:
        self.stream.write(f"\r{name:<22s}" + " " * 40)
        self.stream.flush()

    def on_advance(self, name: str, done: int, total: int) -> None:
        now = time.perf_counter()
        if total and (now - self._last > 0.1 or done >= total):
            self._last = now
            filled = int(30 * done / total)
            self.stream.write(f"\r{name:<22s} [{'#' * filled}{'.' * (30 - filled)}] {100 * done / total:5.1f}%")
            self.stream.flush()

    def on_warning(self, message: str) -> None:
        self.stream.write(f"\nwarning: {message}\n")

    def finish(self) -> None:
        self.stream.write("\r" + " " * 70 + "\r")
        self.stream.flush()


def output_channels(output: RenderOutput) -> dict[str, np.ndarray]:
    """The EXR channels of a render: R, G, B, A, BlockerCount, Depth, Normal.X/Y/Z, Umbra (lights hidden),
    SampleCount (camera samples averaged per pixel)."""
    channels = {name: output.combined[..., index] for index, name in enumerate("RGBA")}
    channels["BlockerCount"] = output.blocker_count.astype(np.float32)
    channels["Depth"] = output.depth
    for index, axis in enumerate("XYZ"):
        channels[f"Normal.{axis}"] = output.normal[..., index]
    channels["Umbra"] = output.umbra.sum(axis=2).astype(np.float32)
    channels["SampleCount"] = output.sample_count.astype(np.float32)
    return channels


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m lazyvis_addon.core", description=__doc__.splitlines()[0])
    parser.add_argument("scene", nargs="?", help="scene .npz written by Scene.save_npz")
    parser.add_argument("--demo", choices=["floating_boxes", "plane"], help="render a built-in scene instead")
    parser.add_argument("-o", "--output", required=True, help="output .exr path")
    parser.add_argument("--png", help="also write an sRGB preview PNG here")
    parser.add_argument("--resolution", type=int, help="override the resolution (square demo scenes only)")
    parser.add_argument("--window", type=int, nargs=4, metavar=("X0", "Y0", "X1", "Y1"),
                        help="render only this pixel window of the frame (y down from the top row)")
    defaults = Settings()
    parser.add_argument("--integrator", choices=INTEGRATORS, default=defaults.integrator)
    parser.add_argument("--glossy-integrator", choices=GLOSSY_INTEGRATORS, default=defaults.glossy_integrator,
                        help="how GGX lobes are integrated over the visible pieces")
    parser.add_argument("--visibility", choices=VISIBILITY_METHODS, default=defaults.visibility,
                        help="silhouettes (complete, exact) or the paper's blocker map")
    parser.add_argument("--shadow-rays", type=int, default=defaults.shadow_rays)
    parser.add_argument("--verify-rays", type=int, default=defaults.verify_rays,
                        help="verification rays per pixel and light (0: off)")
    parser.add_argument("--edge-samples", type=int, default=defaults.aa_samples,
                        help="anti-aliasing samples per edge pixel on average, more at stronger edges "
                             "(1: pixel centres only)")
    parser.add_argument("--coverage-rays", type=int, default=defaults.aa_coverage_rays,
                        help="camera rays per edge pixel that only find the surface they see (0: off)")
    parser.add_argument("--settle-tolerance", type=float, default=defaults.aa_settle_tolerance,
                        help="an edge pixel whose 3 pilot samples agree with its centre within this fraction "
                             "stops there (0: every edge sample)")
    parser.add_argument("--filter-width", type=float, default=defaults.filter_width,
                        help="pixel filter width in pixels, as Cycles' Film > Pixel Filter > Width")
    parser.add_argument("--filter-type", choices=FILTER_TYPES, default=defaults.filter_type)
    parser.add_argument("--samples", type=int, default=defaults.mc_samples, help="Monte Carlo samples per light")
    parser.add_argument("--connectivity", type=int, choices=(4, 8), default=defaults.connectivity)
    parser.add_argument("--no-umbra", action="store_true", help="disable umbra detection")
    parser.add_argument("--seed", type=int, default=defaults.seed)
    parser.add_argument("--memory-mb", type=float, default=defaults.memory_budget_mb)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.demo:
            builder = {"floating_boxes": demo_scenes.floating_boxes, "plane": demo_scenes.plane_under_light}[args.demo]
            scene = builder(args.resolution) if args.resolution else builder()
        elif args.scene:
            scene = Scene.load_npz(args.scene)
        else:
            print("error: give a scene .npz or --demo NAME", file=sys.stderr)
            return 2
        if args.window:  # the camera as it is (its clip distances too), another window
            scene.camera = dataclasses.replace(scene.camera, window=tuple(args.window))
        settings = Settings(integrator=args.integrator, glossy_integrator=args.glossy_integrator,
                            visibility=args.visibility,
                            shadow_rays=args.shadow_rays, verify_rays=args.verify_rays, mc_samples=args.samples,
                            aa_samples=args.edge_samples, aa_coverage_rays=args.coverage_rays,
                            aa_settle_tolerance=args.settle_tolerance,
                            filter_width=args.filter_width,
                            filter_type=args.filter_type,
                            connectivity=args.connectivity, umbra_detection=not args.no_umbra, seed=args.seed,
                            memory_budget_mb=args.memory_mb)
        progress = ConsoleProgress()
        output = render(scene, settings, progress)
        progress.finish()
    except (ValueError, MemoryError, OSError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    except RenderCancelled:
        print("cancelled", file=sys.stderr)
        return 130
    except KeyboardInterrupt:
        print("\ncancelled", file=sys.stderr)
        return 130
    Path(args.output).parent.mkdir(parents=True, exist_ok=True)
    write_exr(args.output, output_channels(output))
    if args.png:
        write_png(args.png, linear_to_srgb8(output.combined[..., :3]))
    stats = output.stats
    print(f"wrote {args.output}: {output.combined.shape[1]} x {output.combined.shape[0]}, "
          f"{stats['seconds']:.2f} s, {stats['rays_cast']} rays, {stats.get('pairs_stored', 0)} blocker pairs")
    return 0


if __name__ == "__main__":
    sys.exit(main())
