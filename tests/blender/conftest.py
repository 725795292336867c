"""Blender tests: bpy (Blender as a Python module) in this process, the add-on registered once per
session, and the factory settings restored (empty scene) before every test.

bpy can be imported once per process and keeps its state, so every test starts with
``read_factory_settings(use_empty=True)``; the core's own tests check in a subprocess that the core
never imports bpy, so bpy being loaded here does not hide a regression there.
"""

from __future__ import annotations

import pytest

bpy = pytest.importorskip("bpy", reason="Blender as a Python module (bpy) is not installed")

import lazyvis_addon  # noqa: E402
from lazyvis_addon.blender import engine as engine_module  # noqa: E402


@pytest.fixture(scope="session")
def addon():
    lazyvis_addon.register()
    yield lazyvis_addon
    lazyvis_addon.unregister()


@pytest.fixture
def scene(addon):
    """An empty scene rendered by LazyVis: 32 x 24 pixels at 100%, black world, one view layer."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = engine_module.ENGINE_ID
    scene.render.resolution_x, scene.render.resolution_y = 32, 24
    scene.render.resolution_percentage = 100
    scene.world = None
    return scene


@pytest.fixture
def reports(monkeypatch):
    """Warnings the engine reports to Blender during a render (still passed on to Blender)."""
    seen: list[str] = []
    original = engine_module.EngineProgress.on_warning

    def record(self, message):
        seen.append(message)
        original(self, message)

    monkeypatch.setattr(engine_module.EngineProgress, "on_warning", record)
    return seen
