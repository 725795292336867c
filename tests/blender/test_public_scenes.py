"""The public corpus (issue 17's first check, run here since issue 14's lights and emitters meet it): every
.blend in ``../shared/scenes/`` (written by other people for other renderers; read from there, never copied
into the repository) opens, renders headless through the LazyVis engine at 128 px wide at the default
settings, and gives a finite, non-negative image with some light in it, each warning once.

Skipped, with a message, where that folder is absent (a clone without the shared folder beside it)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from blender_helpers import ROOT, render_to_exr  # noqa: E402

from lazyvis_addon.blender import engine as engine_module  # noqa: E402

CORPUS = ROOT.parent / "shared" / "scenes"
FILES = sorted(CORPUS.glob("*.blend")) if CORPUS.is_dir() else []
WIDTH = 128


@pytest.mark.skipif(not FILES, reason=f"no public scenes at {CORPUS} (the shared folder beside the clone)")
@pytest.mark.parametrize("path", FILES, ids=[p.stem for p in FILES])
def test_public_scene_renders_at_default_settings(addon, path, reports, tmp_path, monkeypatch):
    bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False)
    scene = bpy.context.scene
    scene.render.engine = engine_module.ENGINE_ID  # several were saved for engines not installed here
    render = scene.render
    render.resolution_y = max(1, round(WIDTH * render.resolution_y / render.resolution_x))
    render.resolution_x, render.resolution_percentage = WIDTH, 100
    render.use_border = False
    render.image_settings.color_mode = "RGBA"  # some files save RGB only
    sizes = []
    core_render = engine_module.core_render

    def measured(core_scene, settings, progress):  # what the README's corpus table reports
        sizes.append((len(core_scene.triangles), len(core_scene.lights), len(core_scene.facing),
                      len(core_scene.hulls.radiance)))
        return core_render(core_scene, settings, progress)

    monkeypatch.setattr(engine_module, "core_render", measured)
    started = time.perf_counter()
    pixels = render_to_exr(scene, tmp_path / f"{path.stem}.exr")["RGBA"]
    seconds = time.perf_counter() - started
    triangles, polygons, lamps, emitters = sizes[0] if sizes else (0, 0, 0, 0)
    print(f"\n| {path.name} | {pixels.shape[1]} x {pixels.shape[0]} | {triangles:,} | {polygons} + {lamps} + {emitters} | "
          f"{seconds:.1f} s | {'; '.join(reports) or '-'} |")
    assert pixels.shape[1] == WIDTH and np.isfinite(pixels).all()
    assert (pixels >= 0.0).all() and pixels[..., :3].max() > 0.0
    assert len(reports) == len(set(reports)), "a warning was given twice"
