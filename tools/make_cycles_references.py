"""Render the Cycles references LazyVis is tested against: every scene of tests/blender/agreement_scenes.py
(the sample .blend files and small built scenes), twice with different seeds, into tests/references/.

    .venv/bin/python tools/make_cycles_references.py                      # all, 8192 samples (~30 min)
    .venv/bin/python tools/make_cycles_references.py suzanne --samples 1024 --output-dir /tmp/refs
    .venv/bin/python tools/make_cycles_references.py --restamp HEAD~1       # see below

``--restamp COMMIT``: a sample .blend re-saved with a change its cases override (the shipped pixel filter:
every case sets its own) keeps its references: each case whose recorded digest no longer matches is rendered
at a few samples (``--samples``, default 16 here) from the file as it is and as it was at COMMIT, and only if
the two images are the same bit for bit is its digest updated (noted in ``restamped``); else it says to
render the reference anew.

Cycles settings are the direct-light reference of tools/make_cycles_reference.py (radiometry note):
max_bounces 0, filter_width 0.01 (a point sample at each pixel centre, as LazyVis shades; a case with its
own ``filter_width``, e.g. Blender's default 1.5, uses that), no denoiser, no adaptive sampling,
light_sampling_threshold 0, no clamping, fixed seeds, CPU. Each scene is rendered at
its own low resolution (the tests render LazyVis at the same one) with seeds 1 and 2: the difference
between the two is the noise floor the tests measure LazyVis against.

Files: ``<scene>.seed<N>.exr``, single-part EXR, channels R, G, B as 32-bit float (ZIP), rows top first.
Float32, not half: at 96 x 96 the files are ~100 KB anyway, and half floats (11-bit mantissa, relative
rounding error up to 2^-11 ~ 0.05%) would add a rounding error of the order of the noise in bright, well
converged regions (the summary prints the noise floor both ways). ``references.json`` records the Blender
version, samples, seeds, resolution, render time, the noise floor and a digest of each scene's source, so
that a test can tell a reference made from an older version of its scene.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SEEDS = (1, 2)


def _load_module(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def relative_noise_floor(first, second):
    """Per-seed relative RMS noise: RMS(first - second) / sqrt(2) / mean(first), over all RGB values."""
    import numpy as np

    a, b = np.asarray(first, np.float64), np.asarray(second, np.float64)
    return float(np.sqrt(np.mean((a - b) ** 2) / 2.0) / max(np.mean(a), 1e-30))


def read_rgb(path: Path):
    """(H, W, 3) float32 of a reference EXR, row 0 at the top."""
    import numpy as np
    import OpenEXR

    with OpenEXR.File(str(path), separate_channels=True) as exr:
        channels = exr.channels()
        return np.stack([np.array(channels[c].pixels, np.float32) for c in "RGB"], axis=2)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help="scenes to render (default: all)")
    parser.add_argument("--samples", type=int, default=8192, help="Cycles samples per pixel (default 8192)")
    parser.add_argument("--output-dir", type=Path, help="where to write (default: tests/references)")
    parser.add_argument("--threads", type=int, default=0, help="render threads (default 0 = all cores)")
    parser.add_argument("--list", action="store_true", help="list the scenes and exit")
    parser.add_argument("--restamp", metavar="COMMIT", help="update the digests of cases whose .blend changed only "
                        "in what the case overrides, checked by rendering both versions (see the docstring)")
    args = parser.parse_args(argv)

    for path in (ROOT, ROOT / "tests" / "blender"):
        if str(path) not in sys.path:
            sys.path.insert(0, str(path))
    import bpy
    import numpy as np

    import agreement_scenes
    import lazyvis_addon

    if args.list:
        for case in agreement_scenes.CASES:
            print(f"{case.name:20s} {case.resolution[0]} x {case.resolution[1]}  {case.blend or 'built in tests'}")
        return 0
    unknown = [name for name in args.names if name not in agreement_scenes.CASES_BY_NAME]
    if unknown:
        parser.error(f"unknown scene(s) {', '.join(unknown)}; --list shows them")
    output_dir = args.output_dir or agreement_scenes.REFERENCES
    output_dir.mkdir(parents=True, exist_ok=True)
    reference = _load_module("make_cycles_reference", ROOT / "tools" / "make_cycles_reference.py")

    index_path = output_dir / "references.json"
    index = json.loads(index_path.read_text()) if index_path.exists() else {}
    if args.restamp:
        lazyvis_addon.register()
        try:
            return restamp(args, index, index_path, agreement_scenes, reference, bpy, np)
        finally:
            lazyvis_addon.unregister()
    index.update(blender=bpy.app.version_string, seeds=list(SEEDS),
                 settings="tools/make_cycles_reference.py configure_cycles: max_bounces 0, filter_width 0.01 "
                          "(Blackman-Harris; a scene's own filter_width where recorded), no denoising, "
                          "no adaptive sampling, light_sampling_threshold 0, no clamping")
    scenes = index.setdefault("scenes", {})

    lazyvis_addon.register()  # the sample files use the LAZYVIS engine and scene.lazyvis settings
    try:
        for case in agreement_scenes.CASES:
            if args.names and case.name not in args.names:
                continue
            seconds, paths = [], []
            samples = args.samples * case.samples_factor
            for seed, path in zip(SEEDS, case.reference_paths(SEEDS)):
                path = output_dir / path.name
                scene = agreement_scenes.load(case)
                reference.configure_cycles(scene, samples, seed, args.threads, case.filter_width)
                reference.configure_output(scene, str(path))
                scene.render.image_settings.color_mode = "RGB"
                started = time.perf_counter()
                bpy.ops.render.render(write_still=True, scene=scene.name)
                seconds.append(round(time.perf_counter() - started, 1))
                paths.append(path)
                print(f"{case.name} seed {seed}: {path} ({seconds[-1]} s)", flush=True)
            first, second = (read_rgb(p) for p in paths)
            floor = relative_noise_floor(first, second)
            floor_half = relative_noise_floor(first.astype(np.float16), second.astype(np.float16))
            scenes[case.name] = dict(
                source=case.blend or f"tests/blender/agreement_scenes.py:{case.build.__name__}",
                source_sha256=case.source_digest(), resolution=list(case.resolution), samples=samples,
                filter_width=case.filter_width,
                files=[p.name for p in paths], seconds=seconds, relative_noise_floor=round(floor, 6),
                relative_noise_floor_if_half=round(floor_half, 6), mean=round(float(first.mean()), 6),
                kilobytes=[round(p.stat().st_size / 1024) for p in paths])
            print(f"{case.name}: noise floor {100 * floor:.4f}% (half floats: {100 * floor_half:.4f}%), "
                  f"{'/'.join(str(k) for k in scenes[case.name]['kilobytes'])} KB", flush=True)
            index_path.write_text(json.dumps(index, indent=2, sort_keys=True) + "\n")
    finally:
        lazyvis_addon.unregister()
    return 0


def restamp(args, index, index_path, agreement_scenes, reference, bpy, np) -> int:
    """``--restamp``: see the module docstring. Returns the exit status (1 if any case must be rendered anew)."""
    import dataclasses
    import subprocess
    import tempfile

    samples = args.samples if args.samples != 8192 else 16
    status = 0
    with tempfile.TemporaryDirectory() as temporary:
        for case in agreement_scenes.CASES:
            entry = index.get("scenes", {}).get(case.name)
            if (args.names and case.name not in args.names) or not case.blend or entry is None \
                    or entry["source_sha256"] == case.source_digest():
                continue
            old_blend = Path(temporary) / f"{case.name}.blend"
            old_blend.write_bytes(subprocess.run(["git", "show", f"{args.restamp}:{case.blend}"], cwd=ROOT,
                                                 capture_output=True, check=True).stdout)
            images = []
            for source in (case, dataclasses.replace(case, blend=str(old_blend))):
                path = Path(temporary) / f"{case.name}.{len(images)}.exr"
                scene = agreement_scenes.load(source)
                reference.configure_cycles(scene, samples, SEEDS[0], args.threads, case.filter_width)
                reference.configure_output(scene, str(path))
                scene.render.image_settings.color_mode = "RGB"
                bpy.ops.render.render(write_still=True, scene=scene.name)
                images.append(read_rgb(path))
            if np.array_equal(images[0], images[1]):
                entry["restamped"] = (f"{case.blend} changed only in what this case overrides: the same Cycles image "
                                      f"bit for bit at {samples} samples as at {args.restamp} "
                                      f"(digest {entry['source_sha256'][:12]})")
                entry["source_sha256"] = case.source_digest()
                print(f"{case.name}: same image at {samples} samples, digest updated", flush=True)
            else:
                status = 1
                print(f"{case.name}: the image differs from {args.restamp}'s: render its reference anew", flush=True)
    index_path.write_text(json.dumps(index, indent=2, sort_keys=True) + "\n")
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
