"""``lazyvis compare FILE.blend``: LazyVis against Cycles on one frame, as a picture and figures (issue 19's
comparison figure: the paper's Fig. 7 for any scene).

Four renders of the file's scene through Blender, each timed around ``bpy.ops.render.render``:
1. LazyVis at the file's settings (time T, image L);
2. a Cycles reference, direct light only (Cycles' settings as ``tools/make_cycles_reference.py`` gives
   them: no bounces, denoiser, adaptive sampling or clamping; the file's pixel filter): two renders of
   half ``--reference-samples`` with different seeds, averaged (image R; their difference is R's noise);
3. Cycles with its time limit set to T (equal time);
4. Cycles at the samples that reach LazyVis' error or 1 %, whichever is larger (equal error), found from two
   short Cycles renders (16 and 64 samples) by fitting error = c / samples^a, at most a quarter of the
   reference's samples (``capped`` in the figures).
Errors are relative RMSE against R with R's own noise taken out of the square (an error below R's noise
cannot be resolved: give the reference enough samples). The PNG shows
LazyVis, Cycles at equal time and Cycles at equal error over their error maps (|X - R| over R's mean, 0 to
``ERROR_MAP_TOP`` black to white through red and yellow); the figures go to stdout and, with ``--json``,
to a file.
"""

from __future__ import annotations

import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np

# The error maps' white: a pixel off by this share of the reference's mean.
ERROR_MAP_TOP = 0.1
# Cycles samples of the two renders the equal-error fit is made from.
FIT_SAMPLES = (16, 64)


def configure_direct_cycles(scene, samples: int, seed: int) -> None:
    """Cycles as a direct-light reference, the scene's own pixel filter kept (``make_cycles_reference``'s
    settings otherwise)."""
    scene.render.engine = "CYCLES"
    cycles = scene.cycles
    cycles.device = "CPU"
    cycles.samples = samples
    cycles.use_adaptive_sampling = False
    cycles.use_denoising = False
    cycles.max_bounces = 0
    cycles.light_sampling_threshold = 0.0
    cycles.sample_clamp_direct = 0.0
    cycles.sample_clamp_indirect = 0.0
    cycles.seed = seed
    cycles.use_animated_seed = False
    cycles.time_limit = 0.0


def timed_render(scene, folder: Path, name: str) -> tuple[float, np.ndarray]:
    """Render ``scene`` with its engine: (seconds, (H, W, 3) float64 linear RGB)."""
    import bpy

    from .cli import combined_rgb
    from .core.exr import read_exr

    started = time.perf_counter()
    bpy.ops.render.render(scene=scene.name)
    seconds = time.perf_counter() - started
    path = folder / f"{name}.exr"
    bpy.data.images["Render Result"].save_render(filepath=str(path), scene=scene)
    return seconds, combined_rgb(read_exr(path)).astype(np.float64)


def relative_rmse(image: np.ndarray, reference: np.ndarray, reference_noise: float = 0.0) -> float:
    """RMS of image - reference over every RGB value, over the reference's mean, with the reference's own
    noise (RMS, same units) taken out of the square: E[(X - R)^2] = e_X^2 + noise^2 for X independent of R."""
    square = float(np.mean((image - reference) ** 2)) - reference_noise ** 2
    return math.sqrt(max(square, 0.0)) / max(float(reference.mean()), 1e-30)


def samples_for_error(errors: dict[int, float], target: float) -> int:
    """Cycles samples that reach ``target`` relative RMSE, from errors measured at two sample counts
    ({samples: error}), fitted as error = c / samples^a (a kept within 0.3 .. 1.5)."""
    (s1, e1), (s2, e2) = sorted(errors.items())
    slope = math.log(max(e1, 1e-30) / max(e2, 1e-30)) / math.log(s2 / s1)
    slope = min(max(slope, 0.3), 1.5)
    return max(1, int(math.ceil(s2 * (max(e2, 1e-30) / target) ** (1.0 / slope))))


def error_map(image: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 false colour of |image - reference| (largest channel) over the reference's mean:
    black at 0, then red, yellow and white at ERROR_MAP_TOP."""
    value = np.abs(image - reference).max(axis=2) / max(float(reference.mean()), 1e-30) / ERROR_MAP_TOP
    value = np.clip(value, 0.0, 1.0)[..., None]
    colour = np.clip(3.0 * value - np.array([0.0, 1.0, 2.0]), 0.0, 1.0)
    return np.round(255.0 * colour).astype(np.uint8)


def compare_scene(scene, reference_samples: int, folder: Path, log=print) -> tuple[dict, np.ndarray]:
    """The four renders of ``scene`` (a bpy Scene, its engine LazyVis): the figures and the (2H, 3W, 3)
    uint8 picture."""
    from .cli import configure_output
    from .core.png import linear_to_srgb8

    configure_output(scene.render, False)  # the renders are read back as float RGBA EXR
    engine = scene.render.engine
    lazyvis_seconds, lazyvis = timed_render(scene, folder, "lazyvis")
    log(f"LazyVis: {lazyvis_seconds:.2f} s")
    # The reference: two half-sample Cycles renders of different seeds, averaged; their difference measures
    # the average's own noise, RMS(A - B) / 2, which every error below has taken out.
    halves = []
    for seed in (1, 2):
        configure_direct_cycles(scene, reference_samples // 2, seed=seed)
        halves.append(timed_render(scene, folder, f"reference{seed}"))
    reference_seconds = halves[0][0] + halves[1][0]
    reference = 0.5 * (halves[0][1] + halves[1][1])
    noise = 0.5 * math.sqrt(float(np.mean((halves[0][1] - halves[1][1]) ** 2)))
    log(f"Cycles reference: {reference_samples} samples, {reference_seconds:.1f} s, its noise "
        f"{100 * noise / max(float(reference.mean()), 1e-30):.2f} % of the mean")
    lazyvis_error = relative_rmse(lazyvis, reference, noise)
    fit = {}
    for samples in FIT_SAMPLES:
        configure_direct_cycles(scene, samples, seed=3)
        fit[samples] = relative_rmse(timed_render(scene, folder, f"fit{samples}")[1], reference, noise)
    configure_direct_cycles(scene, 1 << 24, seed=4)
    scene.cycles.time_limit = lazyvis_seconds
    equal_time_seconds, equal_time = timed_render(scene, folder, "equal_time")
    target = max(lazyvis_error, 0.01)
    most = max(reference_samples // 4, 1)
    samples = min(samples_for_error(fit, target), most)
    configure_direct_cycles(scene, samples, seed=5)
    equal_error_seconds, equal_error = timed_render(scene, folder, "equal_error")
    scene.render.engine = engine
    figures = dict(
        lazyvis=dict(seconds=round(lazyvis_seconds, 3), error=lazyvis_error),
        reference=dict(samples=reference_samples, seconds=round(reference_seconds, 3),
                       noise=noise / max(float(reference.mean()), 1e-30)),
        cycles_equal_time=dict(seconds=round(equal_time_seconds, 3), error=relative_rmse(equal_time, reference, noise)),
        cycles_equal_error=dict(samples=samples, seconds=round(equal_error_seconds, 3),
                                error=relative_rmse(equal_error, reference, noise), target=target,
                                capped=samples == most),
        cycles_fit={str(s): e for s, e in fit.items()},
        speedup=round(equal_error_seconds / max(lazyvis_seconds, 1e-9), 3))
    top = np.concatenate([linear_to_srgb8(image) for image in (lazyvis, equal_time, equal_error)], axis=1)
    bottom = np.concatenate([error_map(image, reference) for image in (lazyvis, equal_time, equal_error)], axis=1)
    return figures, np.concatenate([top, bottom], axis=0)


def compare_command(args, cli) -> int:
    """``lazyvis compare``: open the file, run ``compare_scene``, write the PNG (and JSON), print figures.
    ``cli``: the running command-line module (as ``__main__`` under ``python -m`` it is not the importable
    ``lazyvis_addon.cli``, whose CliError its ``main`` would not catch)."""
    import bpy

    from .core.png import write_png

    blend = cli.checked_blend(args.file)
    unregister = cli._register_addon()
    try:
        try:
            bpy.ops.wm.open_mainfile(filepath=str(blend.resolve()), load_ui=False)
        except RuntimeError as error:
            raise cli.CliError(f"cannot open {args.file}: {cli._error_text(error)}") from None
        scene = bpy.context.scene
        cli.apply_overrides(scene, args)
        if args.frame is not None:
            scene.frame_set(args.frame)
        with tempfile.TemporaryDirectory() as temporary:
            try:
                figures, picture = compare_scene(scene, args.reference_samples, Path(temporary))
            except RuntimeError as error:
                raise cli.CliError(cli._error_text(error)) from None
    finally:
        unregister()
    output = Path(args.output)
    output.parent.mkdir(parents=True, exist_ok=True)
    write_png(output, picture)
    lazyvis, time_, error = figures["lazyvis"], figures["cycles_equal_time"], figures["cycles_equal_error"]
    capped = ", capped at a quarter of the reference" if error["capped"] else ""
    print(f"LazyVis {lazyvis['seconds']:.2f} s, {100 * lazyvis['error']:.2f} % | Cycles in that time "
          f"{100 * time_['error']:.2f} % | Cycles to {100 * error['target']:.2f} %: {error['samples']} samples, "
          f"{error['seconds']:.2f} s ({100 * error['error']:.2f} %{capped}), {figures['speedup']:.1f}x LazyVis' time")
    print(f"Saved: '{output}' (top: LazyVis, Cycles at equal time, at equal error; below: their errors, white at "
          f"{100 * ERROR_MAP_TOP:.0f} % of the mean)")
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=2) + "\n")
    return 0
