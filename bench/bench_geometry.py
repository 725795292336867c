"""Geometry benchmark (issue 13, "exact on real geometry"): LazyVis on the sample .blends, its error
against its own exact reference integrator, and the time Cycles needs for the same error.

    .venv/bin/python bench/bench_geometry.py [--resolutions 128 512] [--json geometry.json]
    .venv/bin/python bench/bench_geometry.py --resolutions 32 --cycles-samples 4 16 \\
        --blends sample_blends/floating_boxes.blend sample_blends/tree.blend
    .venv/bin/python bench/bench_geometry.py --times-only --resolutions 512 --repeats 2   # time targets only

Per .blend and width (the height follows the .blend's aspect), measured:
- LazyVis at the settings a Blender user gets (the engine's ``settings_from_scene``: the .blend's LazyVis
  panel and Cycles' pixel filter; the sample .blends carry 16 anti-aliasing samples and, since
  2026-12-06, Blender's default filter width 1.5 px (0.01 px before: the README's tables), which
  ``--filter-width`` overrides for both renderers): full-frame wall time (fastest of
  ``--repeats``), seconds per stage, the stats counters, the render's own peak memory ("render MB": the
  process's VmHWM, reset before the render, over its resident size then, as bench_memory.py takes it; in
  this process, which has rendered before and whose heap glibc reuses, a lower bound: bench_memory.py
  renders in a fresh one) and the PROCESS peak (ru_maxrss: the largest of this render and all before it).
- error: relative RMSE of RGB (RMSE / RMS of the reference) against ``integrator="reference"`` (every
  triangle a candidate blocker) with the same settings. Above ``--reference-max-pixels`` (default 64) both
  render a window of at most that many pixels instead, centred or moved along the diagonal until it sees
  light (the full-frame time above stays the full frame's).
- Cycles, in this process through bpy, direct light only (tools/make_cycles_reference.py's
  ``configure_cycles``, the .blend's pixel filter), on the same window at each ``--cycles-samples``:
  time and error against the reference image; fits error = c / sqrt(samples) (log space) and
  time = t0 + k samples, and predicts the time to reach max(LazyVis error, 1 %). On a window, the time
  is fitted on whole-frame renders at the lowest and highest sample count instead (a window of 64 pixels
  costs Cycles its scene setup only: its per-sample cost there was noise, once negative).
Targets (PASS/FAIL printed; the exit status is 0 regardless): every sample at 512 px within 2x the
floating boxes' LazyVis time at 512 px, and its render's memory under 1 GB (RENDER_MEMORY_TARGET_MB); suzanne_dense3 within 1.5x the same file with its Subdivision
Surface at level 1 (row "suzanne_dense3@level1": the same three lights and camera; ``suzanne.blend`` is a
level-1 Suzanne under two of them, so it is no measure of what subdivision costs) at each width;
at 128 px LazyVis at least as fast as Cycles to equal error on every sample; LazyVis' error against
the reference under 0.01 % (1e-4) on every sample.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "bench"), str(ROOT / "tools")]

from bench_antialias import blend_scene, relative_rmse, timed  # noqa: E402
from bench_memory import reset_peak, resident_mb  # noqa: E402
from make_cycles_reference import configure_cycles, configure_output  # noqa: E402

from lazyvis_addon.core import Settings, render  # noqa: E402
from lazyvis_addon.core.demo_scenes import fence  # noqa: E402
from lazyvis_addon.core.exr import read_exr  # noqa: E402

SAMPLES = ("floating_boxes", "suzanne", "suzanne_dense", "suzanne_dense3", "tree", "chairs", "chapel")
DEFAULT_BLENDS = [ROOT / "sample_blends" / f"{name}.blend" for name in SAMPLES]
COUNTERS = ("edge_records", "nodes_visited", "edge_tests", "arcs", "pieces", "depth_rays", "inconsistent_couples",
            "pairs_stored", "max_blockers_per_couple", "lights", "pixels", "aa_pixels", "aa_samples_shaded")
CYCLES_ERROR_FLOOR, ERROR_TARGET = 0.01, 1e-4  # Cycles to max(LazyVis error, 1 %); LazyVis vs reference
BOXES_TIME_FACTOR, DENSE3_TIME_FACTOR = 2.0, 1.5
RENDER_MEMORY_TARGET_MB = 1024.0  # a 512 px render's own peak (issue 13)
LEVEL1_ROW = "suzanne_dense3@level1"  # the subdivision target's baseline (LazyVis' time only)


def load_blend(path: Path, width: int, filter_width: float | None, subdivision: int | None = None,
               height: int | None = None):
    """The core scene of a .blend at ``width`` pixels (``height``: default the .blend's aspect) and the
    Settings the render engine would use; ``subdivision``: every Subdivision Surface modifier's viewport
    and render levels set to it first."""
    import bpy
    import lazyvis_addon
    from lazyvis_addon.blender.properties import settings_from_scene

    def subdivided():
        for obj in bpy.data.objects:
            for modifier in getattr(obj, "modifiers", ()):
                if modifier.type == "SUBSURF":
                    modifier.levels = modifier.render_levels = subdivision

    scene = blend_scene(path, width, None if subdivision is None else subdivided, height)
    settings = settings_from_scene(bpy.context.scene)
    lazyvis_addon.unregister()  # blend_scene registers the add-on on every call; the file stays open
    return scene, settings if filter_width is None else replace(settings, filter_width=filter_width)


def centred_border(width: int, height: int, max_pixels: int):
    """Blender border fractions (min_x, max_x, min_y, max_y; y up) of a centred window with the frame's
    aspect and at most ``max_pixels`` pixels, or None when the whole frame is small enough."""
    if width * height <= max_pixels:
        return None
    scale = math.sqrt(max_pixels / (width * height))
    crop_width, crop_height = max(1, int(width * scale)), max(1, int(height * scale))
    left, bottom = (width - crop_width) // 2, (height - crop_height) // 2
    return (left / width, (left + crop_width) / width, bottom / height, (bottom + crop_height) / height)


def lit_border(scene, settings: Settings, width: int, height: int, max_pixels: int):
    """``centred_border``, moved along the frame's diagonal (in steps of the window's size) until the
    window sees some light: a relative error on a black window is 0 / 0 (the chapel's centre at 512 px)."""
    border = centred_border(width, height, max_pixels)
    if border is None:
        return None
    from lazyvis_addon.blender.export import border_window
    size_x, size_y = border[1] - border[0], border[3] - border[2]
    for step in range(0, int(1.0 / max(size_x, size_y)) // 2):  # windows along the diagonal, a few
        for sign in (1, -1):
            shifted = (border[0] + sign * step * size_x, border[1] + sign * step * size_x,
                       border[2] + sign * step * size_y, border[3] + sign * step * size_y)
            if min(shifted) < 0.0 or max(shifted) > 1.0:
                continue
            window = border_window(width, height, shifted)
            probe = render(replace(scene, camera=replace(scene.camera, window=window)),
                           replace(settings, aa_samples=1)).combined[..., :3]
            if probe.max() > 0.0:
                return shifted
    return border


def measure_lazyvis(path: Path, width: int, args, subdivision: int | None = None):
    """Full-frame LazyVis render at default settings: the row of numbers and the RGB image (``subdivision``:
    as ``load_blend``'s; the row is then named ``STEM@levelN``)."""
    scene, settings = load_blend(path, width, args.filter_width, subdivision)
    # The render's own peak: the process's high-water mark reset first (bpy, Numba and earlier rows'
    # references and Cycles renders are resident before), as bench_memory.py measures it.
    peak_reset = reset_peak()
    before = resident_mb("VmRSS")
    out, seconds = timed(scene, settings, args.repeats)
    render_mb = resident_mb("VmHWM") - before
    stats = out.stats
    name = path.stem if subdivision is None else f"{path.stem}@level{subdivision}"
    row = dict(scene=name, width=scene.camera.width, height=scene.camera.height,
               triangles=len(scene.triangles), lazyvis_seconds=seconds,
               stage_seconds={name: float(value) for name, value in stats["stage_seconds"].items()},
               counters={name: int(stats[name]) for name in COUNTERS if name in stats},
               peak_memory_mb=float(stats["peak_memory_mb"]), render_memory_mb=render_mb if peak_reset else None,
               settings=dict(aa_samples=settings.aa_samples, filter_width=settings.filter_width,
                             filter_type=settings.filter_type, visibility=settings.visibility))
    return row, out.combined[..., :3]


def cycles_points(blender_scene, row: dict, border, settings: Settings, sample_counts, reference, scratch: Path):
    """Time and error against ``reference`` of a Cycles render of the window at each sample count
    (``reference`` None: of the whole frame, time only)."""
    import bpy
    output = blender_scene.render
    output.resolution_x, output.resolution_y, output.resolution_percentage = row["width"], row["height"], 100
    output.use_border = border is not None
    if border is not None:
        output.border_min_x, output.border_max_x, output.border_min_y, output.border_max_y = border
        output.use_crop_to_border = True
    exr_path = scratch / "cycles.exr"
    configure_output(blender_scene, str(exr_path))
    points = []
    for samples in [1, *sample_counts]:  # the 1-sample render warms Cycles up and is not counted
        configure_cycles(blender_scene, samples, seed=0, filter_width=settings.filter_width)
        blender_scene.cycles.pixel_filter_type = settings.filter_type
        started = time.perf_counter()
        bpy.ops.render.render(write_still=True, scene=blender_scene.name)
        seconds = time.perf_counter() - started
        if reference is None:
            points.append(dict(samples=samples, seconds=seconds))
            continue
        channels = read_exr(exr_path)
        image = np.stack([channels[name] for name in "RGB"], axis=-1)
        if image.shape != reference.shape:
            raise RuntimeError(f"Cycles rendered {image.shape[:2]}, the reference window is {reference.shape[:2]}")
        points.append(dict(samples=samples, seconds=seconds, error=relative_rmse(image, reference)))
    return points[1:]


def cycles_fit(points, target: float, frame_points) -> dict:
    """error = c / sqrt(samples) from ``points`` (the window's), time = t0 + k samples from
    ``frame_points`` (whole-frame renders), and the predicted whole-frame time to reach ``target``."""
    samples = np.array([p["samples"] for p in points], dtype=float)
    errors = np.array([p["error"] for p in points])
    c = float(np.exp(np.mean(np.log(errors) + 0.5 * np.log(samples))))
    frame_samples = np.array([p["samples"] for p in frame_points], dtype=float)
    seconds = np.array([p["seconds"] for p in frame_points])
    k, t0 = np.polyfit(frame_samples, seconds, 1) if len(frame_points) > 1 else (seconds[0] / frame_samples[0], 0.0)
    k = max(float(k), 0.0)  # the setup alone where more samples cost nothing measurable
    needed = (c / target) ** 2
    return dict(c=c, t0=float(t0), k=k, target=target, samples_needed=needed, seconds=float(t0 + k * needed),
                frame_points=frame_points, extrapolated=bool(errors.min() > target))


def measure_errors(path: Path, row: dict, image, args, scratch: Path) -> None:
    """Adds to ``row`` the error against the reference integrator and the Cycles points and fit.

    The reference integrator does not lift shading points off smooth meshes (Shadow Terminator Geometry
    Offset, ``core/terminator.py``), so where a .blend sets it (Blender's default 0.1 on smooth objects)
    every image compared here, LazyVis', the reference's and Cycles', is rendered with the offset 0: the
    error is the missed blockers' alone. The full-frame time above keeps the .blend's offsets."""
    import bpy
    from lazyvis_addon.blender.export import border_window
    scene, settings = load_blend(path, row["width"], args.filter_width)
    lifted = scene.terminator_offset is not None and bool(np.any(scene.terminator_offset > 0))
    row["terminator_off_for_errors"] = lifted
    if lifted:
        scene = replace(scene, terminator_offset=None)
        for obj in bpy.context.scene.objects:
            if hasattr(obj, "shadow_terminator_geometry_offset"):
                obj.shadow_terminator_geometry_offset = 0.0
    border = lit_border(scene, settings, row["width"], row["height"], args.reference_max_pixels)
    window = border_window(row["width"], row["height"], border)  # Blender's own rounding of the border
    if border is not None:
        scene = replace(scene, camera=replace(scene.camera, window=window))
    if border is not None or lifted:
        image = render(scene, settings).combined[..., :3]
    started = time.perf_counter()
    reference = render(scene, replace(settings, integrator="reference")).combined[..., :3]
    row.update(window=list(window), reference_seconds=time.perf_counter() - started,
               error=relative_rmse(image, reference))
    points = cycles_points(bpy.context.scene, row, border, settings, args.cycles_samples, reference, scratch)
    frame_points = points if border is None else cycles_points(
        bpy.context.scene, row, None, settings, sorted({min(args.cycles_samples), max(args.cycles_samples)}), None,
        scratch)
    target = max(row["error"], CYCLES_ERROR_FLOOR)
    row.update(cycles_points=points, cycles_fit=cycles_fit(points, target, frame_points))


def cost_per_point(row: dict) -> str:
    """Where a row's time goes, per point and light: pass 2 at the pixel centres ("Illumination" over
    pixels x lights) and at the anti-aliasing samples ("Anti-aliasing" over samples x lights; its coverage
    rays and pooling included), and the share of the frame's pixels anti-aliased. A render's time is
    about centres x their cost + samples x theirs, so this tells a scene whose points cost more (more arcs
    per couple) from one with more edge pixels (under a 1.5 px filter every pixel within its reach of an
    outline or a sharp shadow)."""
    counters, stages = row["counters"], row["stage_seconds"]
    lights, pixels = max(counters.get("lights", 0), 1), max(counters.get("pixels", 0), 1)
    samples = counters.get("aa_samples_shaded", 0)
    centre = 1e6 * stages.get("Illumination", 0.0) / (pixels * lights)
    sample = 1e6 * stages.get("Anti-aliasing", 0.0) / (samples * lights) if samples else float("nan")
    return (f"cost: {centre:.1f} us per centre and light, {sample:.1f} us per anti-aliasing sample and light; "
            f"{counters.get('aa_pixels', 0) / pixels:.1%} of the pixels anti-aliased, "
            f"{samples / max(counters.get('aa_pixels', 0), 1):.1f} samples each")


def _megabytes(value) -> str:
    return "n/a" if value is None else f"{value:.0f}"


def print_table(rows, width: int) -> None:
    rows = [row for row in rows if row["width"] == width]
    print(f"\n{width} px wide")
    print(f"{'scene':16s} {'size':>9s} {'triangles':>9s} {'LazyVis s':>9s} {'render MB':>9s} {'peak MB':>8s} {'error':>9s} "
          f"{'ref s':>7s} {'window':>17s} {'Cycles s':>9s} {'Cycles/LV':>9s}")
    for row in rows:
        fit, (x0, y0, x1, y1) = row["cycles_fit"], row["window"]
        cropped = "*" if (x1 - x0, y1 - y0) != (row["width"], row["height"]) else " "
        print(f"{row['scene']:16s} {row['width']:>4d}x{row['height']:<4d} {row['triangles']:9,d} "
              f"{row['lazyvis_seconds']:9.2f} {_megabytes(row.get('render_memory_mb')):>9s} "
              f"{row['peak_memory_mb']:8.0f} {row['error']:9.2e} "
              f"{row['reference_seconds']:7.1f} {f'{x0},{y0}-{x1},{y1}':>17s} {fit['seconds']:8.2f}{cropped} "
              f"{fit['seconds'] / row['lazyvis_seconds']:9.2f}")
    for row in rows:
        fit = row["cycles_fit"]
        print(f"  {row['scene']}: stages " + ", ".join(f"{name} {s:.2f}" for name, s in row["stage_seconds"].items()))
        print("    " + cost_per_point(row))
        print("    counters " + (", ".join(f"{name} {n:,}" for name, n in row["counters"].items()) or "none"))
        print("    Cycles " + ", ".join(f"{p['samples']} spp {p['seconds']:.2f} s {p['error']:.3%}"
                                      for p in row["cycles_points"])
              + "; whole frame " + ", ".join(f"{p['samples']} spp {p['seconds']:.2f} s" for p in fit["frame_points"])
              + f"; fit c {fit['c']:.4f}, t0 {fit['t0']:.2f} s, k {fit['k'] * 1e3:.2f} ms/spp -> "
              f"{fit['samples_needed']:.0f} spp for {fit['target']:.2%} in {fit['seconds']:.2f} s"
              + (" (beyond the measured points)" if fit["extrapolated"] else ""))
    if any(tuple(row["window"]) != (0, 0, row["width"], row["height"]) for row in rows):
        print("  * error on the window; Cycles' time fitted on whole-frame renders")
    lifted = [row["scene"] for row in rows if row.get("terminator_off_for_errors")]
    if lifted:
        print(f"  errors of {', '.join(lifted)} with Shadow Terminator Geometry Offset 0 in every renderer (the "
              "reference integrator has no lift); their times with the .blend's offsets")


def target_checks(rows, widths, baseline=()) -> list[dict]:
    """PASS / FAIL / n/a per target; ``baseline``: rows timed only (``LEVEL1_ROW``)."""
    by_name = {(row["scene"], row["width"]): row for row in [*rows, *baseline]}
    checks = []

    def check(label: str, passed) -> None:
        checks.append(dict(check=label, result="n/a" if passed is None else "PASS" if passed else "FAIL"))

    boxes = by_name.get(("floating_boxes", 512))
    at_512 = [row for row in rows if row["width"] == 512 and row["scene"] != "floating_boxes"]
    for row in at_512:
        limit = BOXES_TIME_FACTOR * boxes["lazyvis_seconds"] if boxes else None
        check(f"512 px {row['scene']} {row['lazyvis_seconds']:.2f} s <= {BOXES_TIME_FACTOR}x floating boxes "
              f"({'n/a' if limit is None else f'{limit:.2f} s'})", limit and row["lazyvis_seconds"] <= limit)
    if not at_512:
        check(f"512 px within {BOXES_TIME_FACTOR}x floating boxes (512 px not measured)", None)
    for row in rows:
        if row["width"] == 512:
            memory = row.get("render_memory_mb")
            check(f"512 px {row['scene']} render memory {_megabytes(memory)} MB < {RENDER_MEMORY_TARGET_MB:.0f} MB",
                  None if memory is None else memory < RENDER_MEMORY_TARGET_MB)
    for width in widths:
        level1, dense3 = by_name.get((LEVEL1_ROW, width)), by_name.get(("suzanne_dense3", width))
        if level1 and dense3:
            check(f"{width} px suzanne_dense3 {dense3['lazyvis_seconds']:.2f} s <= {DENSE3_TIME_FACTOR}x {LEVEL1_ROW} "
                  f"({DENSE3_TIME_FACTOR * level1['lazyvis_seconds']:.2f} s)",
                  dense3["lazyvis_seconds"] <= DENSE3_TIME_FACTOR * level1["lazyvis_seconds"])
        else:
            check(f"{width} px suzanne_dense3 <= {DENSE3_TIME_FACTOR}x {LEVEL1_ROW} (a scene is missing)", None)
    at_128 = [row for row in rows if row["width"] == 128 and "cycles_fit" in row]  # not with --times-only
    for row in at_128:
        check(f"128 px {row['scene']} LazyVis {row['lazyvis_seconds']:.2f} s <= Cycles to "
              f"{row['cycles_fit']['target']:.2%} {row['cycles_fit']['seconds']:.2f} s",
              row["lazyvis_seconds"] <= row["cycles_fit"]["seconds"])
    if not at_128:
        check("128 px LazyVis <= Cycles to equal error (128 px not measured)", None)
    for row in rows:
        if "error" in row:
            check(f"{row['width']} px {row['scene']} error {row['error']:.2e} < {ERROR_TARGET:.0e}",
                  row["error"] < ERROR_TARGET)
    return checks


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolutions", type=int, nargs="+", default=[128, 512], help="widths in pixels")
    parser.add_argument("--blends", type=Path, nargs="+", default=DEFAULT_BLENDS)
    parser.add_argument("--cycles-samples", type=int, nargs="+", default=[16, 64, 256])
    # The reference integrator tests every triangle against every pixel: a 128 x 128 window of the tree at
    # 512 px took 3,030 s (2026-12-03), against 25 s for LazyVis' whole frame. The README's tables use 64.
    parser.add_argument("--reference-max-pixels", type=int, default=64,
                        help="above this, the error is measured on a lit window of this many pixels (default 64; "
                             "the reference integrator's time grows with pixels x triangles)")
    parser.add_argument("--repeats", type=int, default=1, help="timed LazyVis runs; the fastest counts")
    parser.add_argument("--filter-width", type=float, help="pixel filter width for both (default: the .blend's)")
    parser.add_argument("--json", type=Path, help="also write every number to this file")
    parser.add_argument("--times-only", action="store_true",
                        help="LazyVis' times and the time targets only: no reference integrator, no Cycles")
    args = parser.parse_args()
    blends = [path for path in args.blends if path.exists()]
    print("".join(f"skipped (missing): {path}\n" for path in args.blends if not path.exists()), end="")
    render(fence(32), Settings())  # warm-up
    measured, failed, baseline = [], [], []
    for path in blends:  # every full-frame LazyVis render before any reference or Cycles render
        for width in args.resolutions:
            print(f"LazyVis {path.stem} at {width} px ...", flush=True)
            try:
                measured.append((path, *measure_lazyvis(path, width, args)))
            except MemoryError as error:  # a bench reports: note it, go on with the other scenes
                failed.append(dict(scene=path.stem, width=width, failed=f"LazyVis: MemoryError {error}"))
            if path.stem == "suzanne_dense3":  # the subdivision target's baseline: timed, not compared
                print(f"LazyVis {LEVEL1_ROW} at {width} px ...", flush=True)
                baseline.append(measure_lazyvis(path, width, args, subdivision=1)[0])
    with tempfile.TemporaryDirectory() as scratch:
        for path, row, image in [] if args.times_only else measured:
            print(f"reference and Cycles {path.stem} at {row['width']} px ...", flush=True)
            try:
                measure_errors(path, row, image, args, Path(scratch))
            except MemoryError as error:
                row["failed"] = f"reference: MemoryError {error}"
    rows = [row for _, row, _ in measured if "failed" not in row]
    for row in baseline:
        print(f"{row['scene']} at {row['width']} px (LazyVis only): {row['lazyvis_seconds']:.2f} s, "
              f"{row['triangles']} triangles")
    failed += [row for _, row, _ in measured if "failed" in row]
    for row in failed:
        print(f"FAILED {row['scene']} at {row['width']} px: {row['failed']}")
    for width in args.resolutions:
        if args.times_only:
            print(f"\n{width} px wide (LazyVis only)")
            for row in [row for row in [*rows, *baseline] if row["width"] == width]:
                print(f"  {row['scene']}: {row['lazyvis_seconds']:.2f} s; stages "
                      + ", ".join(f"{name} {s:.2f}" for name, s in row["stage_seconds"].items()))
        else:
            print_table(rows, width)
    checks = target_checks(rows, args.resolutions, baseline) + [
        dict(check=f"{row['width']} px {row['scene']} renders", result="FAIL") for row in failed]
    print("\ntargets")
    for item in checks:
        print(f"  {item['result']:4s}  {item['check']}")
    if args.json:
        args.json.write_text(json.dumps(dict(rows=rows, baseline=baseline, failed=failed, checks=checks), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
