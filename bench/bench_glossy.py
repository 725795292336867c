"""Glossy benchmark (issue 4): time and error of each glossy integrator, and of Cycles at equal time.

    .venv/bin/python bench/bench_glossy.py [--resolution 512] [--reference-samples 2048]

Scene: ``sample_blends/glossy.blend`` (the floating boxes before a glossy wall on a glossy floor, gold,
glossy and varnished boxes, two area lights), rendered through Blender (bpy) as a user would.

Truth: Cycles, direct light only, point-sampled (filter 0.01), ``--reference-samples`` split over two seeds.
Their mean is the truth; their difference measures its remaining noise, which is taken out of every error
below (error² - truth noise², so a converged truth is not needed). Cached in ``bench/cache/``.

Each LazyVis glossy integrator (``--integrators``: LTC with its correction, the default; LTC; Phong; MC with
``--mc-samples``) renders point-sampled like the truth
(anti-aliasing off), and Cycles then renders with its time limit set to that wall time: the error of
each against the truth is printed, with the bias (mean difference) separately.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
BLEND = ROOT / "sample_blends" / "glossy.blend"
CACHE = ROOT / "bench" / "cache"


def load_tools():
    import importlib.util

    spec = importlib.util.spec_from_file_location("make_cycles_reference", ROOT / "tools" / "make_cycles_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def open_scene(resolution: int):
    import bpy

    bpy.ops.wm.open_mainfile(filepath=str(BLEND), load_ui=False)
    scene = bpy.context.scene
    scene.render.resolution_x = scene.render.resolution_y = resolution
    scene.render.resolution_percentage = 100
    return scene


def render_rgb(scene, path: Path) -> tuple[np.ndarray, float]:
    """Render ``scene`` with its engine to a float EXR; (H, W, 3) RGB and wall seconds."""
    import bpy

    from lazyvis_addon.core.exr import read_exr

    tools = load_tools()
    tools.configure_output(scene, str(path))
    started = time.perf_counter()
    bpy.ops.render.render(write_still=True, scene=scene.name)
    seconds = time.perf_counter() - started
    channels = read_exr(str(path))
    return np.stack([channels[c] for c in "RGB"], axis=2).astype(np.float64), seconds


def cycles_render(resolution: int, samples: int, seed: int, path: Path, time_limit: float = 0.0):
    scene = open_scene(resolution)
    load_tools().configure_cycles(scene, samples, seed)
    scene.cycles.time_limit = time_limit
    return render_rgb(scene, path)


def truth(resolution: int, samples: int, scratch: Path) -> tuple[np.ndarray, float]:
    """The mean of two Cycles seeds (cached) and its relative noise (RMS of the mean's error / mean)."""
    CACHE.mkdir(parents=True, exist_ok=True)
    key = f"glossy_{resolution}_{samples}"
    cached = CACHE / f"{key}.npz"
    source = BLEND.read_bytes()
    digest = __import__("hashlib").sha256(source).hexdigest()
    if cached.exists():
        data = np.load(cached)
        if str(data["digest"]) == digest:
            return data["mean"], float(data["noise"])
    images = []
    for seed in (1, 2):
        image, seconds = cycles_render(resolution, samples // 2, seed, scratch / f"truth{seed}.exr")
        print(f"  truth seed {seed}: {samples // 2} samples in {seconds:.0f} s", flush=True)
        images.append(image)
    mean = 0.5 * (images[0] + images[1])
    # Each seed's noise is rms(a - b) / sqrt(2); the mean of two has 1 / sqrt(2) of that.
    noise = math.sqrt(np.mean((images[0] - images[1]) ** 2)) / 2.0 / mean.mean()
    np.savez_compressed(cached, mean=mean, noise=noise, digest=digest)
    return mean, noise


def error(image: np.ndarray, reference: np.ndarray, reference_noise: float) -> tuple[float, float]:
    """(relative RMSE with the truth's own noise taken out, relative bias)."""
    scale = reference.mean()
    raw = np.mean((image - reference) ** 2) / scale ** 2
    return math.sqrt(max(raw - reference_noise ** 2, 0.0)), float((image.mean() - scale) / scale)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, default=512)
    parser.add_argument("--reference-samples", type=int, default=2048)
    parser.add_argument("--mc-samples", type=int, default=16)
    parser.add_argument("--integrators", nargs="+", default=["ltc_cv", "ltc", "phong", "mc"],
                        help="glossy integrators to run (default: all; ltc_cv is the default)")
    args = parser.parse_args()

    import bpy  # noqa: F401  (Blender as a module)

    import lazyvis_addon

    lazyvis_addon.register()
    results = {}
    with tempfile.TemporaryDirectory() as scratch:
        scratch = Path(scratch)
        print(f"Cycles truth, {args.reference_samples} samples, {args.resolution}^2 ...", flush=True)
        reference, reference_noise = truth(args.resolution, args.reference_samples, scratch)
        print(f"  its remaining noise: {100 * reference_noise:.3f}% relative RMS")
        print(f"\n{'renderer':34s} {'seconds':>8s} {'rel. RMSE':>10s} {'bias':>8s}")
        for integrator in args.integrators:  # the glossy integrators: a handful
            scene = open_scene(args.resolution)
            scene.render.engine = "LAZYVIS"
            scene.lazyvis.glossy_integrator = integrator
            scene.lazyvis.mc_samples = args.mc_samples
            scene.lazyvis.aa_samples = 1  # point-sampled, like the truth
            image, seconds = render_rgb(scene, scratch / f"lazyvis_{integrator}.exr")
            rmse, bias = error(image, reference, reference_noise)
            label = f"LazyVis {integrator}" + (f" ({args.mc_samples} samples)" if integrator == "mc" else "")
            print(f"{label:34s} {seconds:8.1f} {100 * rmse:9.2f}% {100 * bias:+7.2f}%", flush=True)
            cycles_image, cycles_seconds = cycles_render(args.resolution, 1 << 20, 7, scratch / "cycles.exr",
                                                         time_limit=seconds)
            cycles_rmse, cycles_bias = error(cycles_image, reference, reference_noise)
            label = f"  Cycles in the same time"
            print(f"{label:34s} {cycles_seconds:8.1f} {100 * cycles_rmse:9.2f}% {100 * cycles_bias:+7.2f}%",
                  flush=True)
            results[integrator] = dict(seconds=round(seconds, 2), relative_rmse=round(rmse, 5), bias=round(bias, 5),
                                       cycles_seconds=round(cycles_seconds, 2),
                                       cycles_relative_rmse=round(cycles_rmse, 5))
    print(json.dumps(results))
    lazyvis_addon.unregister()
    return 0


if __name__ == "__main__":
    sys.exit(main())
