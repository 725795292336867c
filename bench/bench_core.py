"""Benchmark of the core on the paper-like scene (issue 2's targets). Not a test: it prints figures.

    .venv/bin/python bench/bench_core.py [--resolution 512] [--strip-every 16] [--quick]

Scene: ~600 triangles of floating boxes over a ground plane, 4 area lights of different sizes and colours.
Prints wall time per stage, rays cast, pairs stored, peak memory, the time Embree alone takes for the same
number of rays (the floor), the error against the reference mode, and equal-time / equal-error comparisons
with the standard Monte Carlo baseline.

The reference (every triangle a candidate blocker) is exact but slow, so errors are measured on horizontal
strips of rows (one row band every ``--strip-every`` rows, each rendered as a pixel window: windows render
exactly the full frame's pixels for the reference and standard MC). Monte Carlo timings on the strips are
scaled to the full frame by pixel count.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lazyvis_addon.core import Camera, Scene, Settings, render  # noqa: E402
from lazyvis_addon.core.demo_scenes import floating_boxes  # noqa: E402
from lazyvis_addon.core.trace import RayTracer  # noqa: E402

TARGET_SECONDS = 10.0
TARGET_MISSED_RMSE = 0.005
TARGET_SPEEDUP = 10.0


def with_window(scene: Scene, window) -> Scene:
    cam = scene.camera
    return Scene(scene.triangles, scene.material_index, scene.materials, scene.lights,
                 Camera(cam.world_from_camera, cam.width, cam.height, cam.projection, cam.screen_window, window),
                 scene.background, scene.shading_normals)


def strips(resolution: int, every: int, height: int = 4):
    return [(0, y, resolution, min(y + height, resolution)) for y in range(every // 2, resolution, every)]


def render_strips(scene: Scene, settings: Settings, windows) -> tuple[np.ndarray, float]:
    """Concatenated RGB of the strip windows (P, 3) and the seconds they took."""
    started = time.perf_counter()
    parts = [render(with_window(scene, w), settings).combined[..., :3].reshape(-1, 3) for w in windows]
    return np.concatenate(parts), time.perf_counter() - started


def crop_strips(image: np.ndarray, windows) -> np.ndarray:
    return np.concatenate([image[y0:y1, x0:x1, :3].reshape(-1, 3) for x0, y0, x1, y1 in windows])


def relative_rmse(image: np.ndarray, reference: np.ndarray) -> float:
    return float(np.sqrt(np.mean((image - reference) ** 2)) / np.sqrt(np.mean(reference ** 2)))


def embree_floor(scene: Scene, n_primary: int, n_shadow: int) -> float:
    """Seconds Embree alone needs for the same numbers of primary and shadow rays (nearest hit)."""
    tracer = RayTracer(scene.triangles)
    rng = np.random.default_rng(0)
    eye = scene.camera.position
    targets = scene.triangles[rng.integers(0, len(scene.triangles), n_primary)].mean(axis=1)
    primary_dir = targets - eye
    starts = targets + 1e-3 * rng.normal(size=targets.shape)
    light_points = scene.lights.vertices[rng.integers(0, len(scene.lights), n_shadow), 0]
    shadow_origin = starts[rng.integers(0, n_primary, n_shadow)]
    started = time.perf_counter()
    tracer.intersect(np.broadcast_to(eye, primary_dir.shape), primary_dir, None)
    tracer.intersect(shadow_origin, light_points - shadow_origin, 1.0)
    return time.perf_counter() - started


def peak_memory_of_render(resolution: int) -> float:
    """Peak resident memory (MB) of a fresh process doing one analytic render."""
    code = ("import resource, sys; sys.path.insert(0, %r)\n"
            "from lazyvis_addon.core import render, Settings\n"
            "from lazyvis_addon.core.demo_scenes import floating_boxes\n"
            "render(floating_boxes(%d), Settings(aa_samples=1))\n"
            "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)\n" % (str(ROOT), resolution))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, default=512)
    parser.add_argument("--strip-every", type=int, default=32, help="one 4-row strip every N rows for errors")
    parser.add_argument("--mc-samples", type=int, nargs="+", default=[4, 16, 64])
    parser.add_argument("--json", help="also write the figures here")
    args = parser.parse_args()

    scene = floating_boxes(args.resolution)
    n_pixels = args.resolution ** 2
    print(f"scene: {len(scene.triangles)} triangles, {len(scene.lights)} lights, "
          f"{args.resolution}x{args.resolution}, {os.cpu_count()} cores")

    # The paper's algorithm and its baselines shade one point per pixel: anti-aliasing off here, measured
    # separately below and in bench_antialias.py.
    centres = Settings(aa_samples=1)
    render(floating_boxes(32), centres)  # warm-up (imports, thread pool)
    started = time.perf_counter()
    analytic = render(scene, centres.replace(integrator="analytic"))
    analytic_seconds = time.perf_counter() - started
    stats = analytic.stats
    print(f"\nanalytic render: {analytic_seconds:.2f} s (target < {TARGET_SECONDS:g} s)")
    for stage, seconds in stats["stage_seconds"].items():
        print(f"  {stage:<20s} {seconds:7.2f} s")
    counters = ("rays_cast", "edge_records", "nodes_visited", "edge_tests", "arcs", "cells", "depth_rays", "inconsistent_couples",
                "shadow_rays", "seeds", "pairs", "pairs_stored", "fill_tests", "pieces")
    print("  " + ", ".join(f"{name} {stats[name]:,}" for name in counters if name in stats))
    # The paper's method (Visibility > Blocker Map) beside it; its shadow rays also size the MC floors below.
    started = time.perf_counter()
    paper = render(scene, centres.replace(visibility="blocker_map"))
    paper_seconds = time.perf_counter() - started
    print(f"the paper's blocker map: {paper_seconds:.2f} s, pairs stored {paper.stats['pairs_stored']:,}")
    floor = embree_floor(scene, n_pixels, paper.stats["shadow_rays"])
    print(f"  Embree alone for the same rays: {floor:.2f} s")
    peak = peak_memory_of_render(args.resolution)
    print(f"  peak memory (fresh process): {peak:.0f} MB")
    started = time.perf_counter()
    default = render(scene, Settings())
    print(f"default settings (adaptive anti-aliasing, {Settings().aa_samples} samples at edges): "
          f"{time.perf_counter() - started:.2f} s, {default.stats.get('aa_pixels', 0):,} pixels refined")

    windows = strips(args.resolution, args.strip_every)
    strip_pixels = sum((w[2] - w[0]) * (w[3] - w[1]) for w in windows)
    scale = n_pixels / strip_pixels
    reference, reference_seconds = render_strips(scene, centres.replace(integrator="reference"), windows)
    lazy = crop_strips(analytic.combined, windows)
    missed_rmse = relative_rmse(lazy, reference)
    paper_rmse = relative_rmse(crop_strips(paper.combined, windows), reference)
    print(f"the paper's blocker map against the reference: relative RMSE {paper_rmse:.4%}")
    differing = float(np.mean(np.abs(lazy - reference).max(axis=1) > 1e-6 * reference.max()))
    print(f"\nerror from missed blockers (on {strip_pixels:,} strip pixels, reference took "
          f"{reference_seconds:.1f} s there): relative RMSE {missed_rmse:.4%} (target < {TARGET_MISSED_RMSE:.1%}), "
          f"{differing:.2%} of pixels differ")

    print("\nstandard Monte Carlo (shadow rays over each light, no blocker map), on the strips:")
    rows = []
    for samples in args.mc_samples:
        image, seconds = render_strips(scene, centres.replace(integrator="standard_mc", mc_samples=samples), windows)
        error = relative_rmse(image, reference)
        rows.append((samples, seconds * scale, error))
        print(f"  {samples:4d} samples/light: {seconds * scale:7.2f} s full-frame equivalent, relative RMSE {error:.3%}")
    reduced, reduced_seconds = render_strips(scene, centres.replace(integrator="reduced_mc", mc_samples=4), windows)
    print(f"  reduced-domain MC, 4 samples/light: relative RMSE {relative_rmse(reduced, reference):.3%}")

    # MC error falls as 1/sqrt(samples) and its time grows linearly: fit both on the measured points.
    samples_arr = np.array([r[0] for r in rows], float)
    seconds_arr = np.array([r[1] for r in rows])
    error_arr = np.array([r[2] for r in rows])
    error_constant = float(np.exp(np.mean(np.log(error_arr) + 0.5 * np.log(samples_arr))))
    time_slope, time_offset = np.polyfit(samples_arr, seconds_arr, 1)
    analytic_error = max(missed_rmse, 1e-6)
    samples_equal_error = (error_constant / analytic_error) ** 2
    seconds_equal_error = time_offset + time_slope * samples_equal_error
    samples_equal_time = max((analytic_seconds - time_offset) / time_slope, 0.0)
    error_equal_time = error_constant / np.sqrt(max(samples_equal_time, 1e-9))
    print(f"\nequal time ({analytic_seconds:.1f} s): standard MC affords ~{samples_equal_time:.1f} samples/light, "
          f"relative RMSE ~{error_equal_time:.2%} vs analytic {missed_rmse:.4%}")
    print(f"equal error ({missed_rmse:.4%}): standard MC needs ~{samples_equal_error:,.0f} samples/light, "
          f"~{seconds_equal_error:,.0f} s: analytic is {seconds_equal_error / analytic_seconds:,.0f}x faster "
          f"(target >= {TARGET_SPEEDUP:g}x)")
    one_percent_samples = (error_constant / 0.01) ** 2
    one_percent_seconds = time_offset + time_slope * one_percent_samples
    print(f"equal error (1%): standard MC needs ~{one_percent_samples:,.0f} samples/light, "
          f"~{one_percent_seconds:,.1f} s: analytic is {one_percent_seconds / analytic_seconds:,.1f}x faster")

    # The MC baseline above is numpy code whose cost is mostly sampling overhead; an ideal MC renderer
    # would pay only Embree's occlusion rays. Bound it from below with the measured ray rate.
    rays_per_second = 2.0 * paper.stats["shadow_rays"] / max(floor, 1e-9)  # floor traced ~2x those rays
    lit_couples = paper.stats["shadow_rays"] / Settings().shadow_rays
    ideal_equal_error = lit_couples * samples_equal_error / rays_per_second
    ideal_one_percent = lit_couples * one_percent_samples / rays_per_second
    print(f"ideal MC (Embree occlusion rays only, {rays_per_second / 1e6:.0f} M rays/s): equal error "
          f"~{ideal_equal_error:,.0f} s ({ideal_equal_error / analytic_seconds:,.0f}x the analytic time), "
          f"1% error ~{ideal_one_percent:.1f} s ({ideal_one_percent / analytic_seconds:.1f}x)")

    if args.json:
        Path(args.json).write_text(json.dumps({
            "resolution": args.resolution, "analytic_seconds": analytic_seconds,
            "stage_seconds": stats["stage_seconds"], "rays_cast": stats["rays_cast"],
            "pairs_stored": stats.get("pairs_stored"), "embree_floor_seconds": floor, "peak_memory_mb": peak,
            "paper_seconds": paper_seconds, "paper_relative_rmse": paper_rmse,
            "missed_relative_rmse": missed_rmse, "mc": rows, "equal_error_speedup": seconds_equal_error / analytic_seconds,
        }, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
