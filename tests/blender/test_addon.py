"""Add-on registration, properties -> Settings, panels, packaging as a Blender extension."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

bpy = pytest.importorskip("bpy")

from lazyvis_addon.blender import ui  # noqa: E402
from lazyvis_addon.blender.properties import LazyVisSceneSettings, settings_from_scene  # noqa: E402
from lazyvis_addon.core.settings import Settings  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


def test_engine_is_registered_and_in_the_engine_enum(scene):
    assert scene.render.engine == "LAZYVIS"
    with pytest.raises(TypeError) as error:
        scene.render.engine = "NOT_AN_ENGINE"
    assert "'LAZYVIS'" in str(error.value)  # Blender lists the valid engines
    engine = next(cls for cls in bpy.types.RenderEngine.__subclasses__()
                  if getattr(cls, "bl_idname", None) == "LAZYVIS")
    assert engine.bl_label == "Lazy Visibility"
    assert engine.bl_use_shading_nodes_custom is False


@pytest.mark.parametrize("panel", ["RENDER_PT_format", "RENDER_PT_frame_range", "RENDER_PT_output",
                                   "RENDER_PT_color_management", "DATA_PT_lens", "DATA_PT_camera",
                                   "VIEWLAYER_PT_layer", "EEVEE_MATERIAL_PT_context_material"])
def test_builtin_panels_are_adopted(scene, panel):
    assert "LAZYVIS" in getattr(bpy.types, panel).COMPAT_ENGINES


@pytest.mark.parametrize("panel", ["DATA_PT_light", "DATA_PT_spot", "RENDER_PT_freestyle"])
def test_replaced_panels_are_not_adopted(scene, panel):
    assert "LAZYVIS" not in getattr(bpy.types, panel).COMPAT_ENGINES


def test_own_panels_are_registered(scene):
    for cls in ui.classes:
        assert hasattr(bpy.types, cls.__name__), cls.__name__


def test_property_defaults_are_the_settings_defaults(scene):
    assert settings_from_scene(scene) == Settings(frame=scene.frame_current)


def test_every_setting_has_a_property_and_reaches_settings(scene):
    """scene.lazyvis maps 1:1 onto Settings (frame, transparency, threads come from Blender's own settings)."""
    from_blender = {"frame", "transparent_background", "threads", "filter_width", "filter_type"}
    properties = set(LazyVisSceneSettings.__annotations__)
    assert set(Settings.field_names()) - from_blender <= properties
    props = scene.lazyvis
    props.integrator = "reduced_mc"
    props.glossy_integrator = "phong"
    props.visibility = "blocker_map"
    props.shadow_rays = 7
    props.mc_samples = 33
    props.connectivity = "4"
    props.umbra_detection = False
    props.seed = 12
    props.memory_budget_mb = 512.0
    props.pixel_batch = 4096
    props.window_margin = 5
    props.merge_quads = False
    scene.frame_current = 42
    scene.render.film_transparent = True
    scene.render.threads_mode, scene.render.threads = "FIXED", 3
    scene.cycles.filter_width = 0.75
    scene.cycles.pixel_filter_type = "GAUSSIAN"
    scene.render.filter_size = 2.0  # EEVEE's, not read
    props.aa_samples = 4
    props.aa_coverage_rays = 8
    assert settings_from_scene(scene) == Settings(
        integrator="reduced_mc", glossy_integrator="phong", visibility="blocker_map",
        shadow_rays=7, mc_samples=33, connectivity=4, umbra_detection=False, seed=12,
        frame=42, transparent_background=True, memory_budget_mb=512.0, pixel_batch=4096,
        window_margin=5, threads=3, merge_quads=False, filter_width=0.75, filter_type="GAUSSIAN",
        aa_samples=4, aa_coverage_rays=8)


def run_python(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)


def test_importing_the_package_and_core_never_imports_bpy():
    result = run_python("""
        import sys
        import lazyvis_addon, lazyvis_addon.core
        assert 'bpy' not in sys.modules, 'bpy was imported'
        print('ok')
    """)
    assert result.returncode == 0, result.stderr
    assert "ok" in result.stdout


def test_repository_root_works_as_a_blender_extension_package(tmp_path):
    """Blender imports the extension as bl_ext.<repository>.lazyvis; the root must only use relative imports.
    (``bl_ext`` itself belongs to bpy, so the test mounts the repository under another package name.)"""
    repository = tmp_path / "extensions" / "user_default"
    repository.mkdir(parents=True)
    (tmp_path / "extensions" / "__init__.py").write_text("")
    (repository / "__init__.py").write_text("")
    (repository / "lazyvis").symlink_to(ROOT, target_is_directory=True)
    result = subprocess.run([sys.executable, "-c", textwrap.dedent("""
        import sys
        sys.path.insert(0, sys.argv[1])
        import bpy
        import extensions.user_default.lazyvis as extension
        extension.register()
        bpy.context.scene.render.engine = 'LAZYVIS'
        assert 'lazyvis_addon' not in sys.modules, 'the extension must not import the top-level package'
        assert bpy.context.scene.lazyvis.shadow_rays >= 1
        extension.unregister()
        print('ok')
    """), str(tmp_path)], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "ok" in result.stdout


def test_manifest_declares_the_extension():
    import tomllib

    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    assert manifest["id"] == "lazyvis"
    assert manifest["name"] == "Lazy Visibility"
    assert manifest["license"] == ["SPDX:GPL-3.0-or-later"]
    assert manifest["blender_version_min"] == "4.2.0"
    wheels = manifest["wheels"]
    assert any("embreex" in w for w in wheels) and any(w.lower().split("/")[-1].startswith("openexr") for w in wheels)
    # Python 3.11 for Blender 4.2-5.0 and 3.13 for 5.1+, for the compiled packages; pure Python wheels fit both.
    assert all("-cp311-" in w or "-cp313-" in w or w.endswith("-py3-none-any.whl") for w in wheels)
    assert any("threadpoolctl" in w for w in wheels)
    for package in ("embreex", "openexr", "numba", "llvmlite"):
        for abi in ("-cp311-", "-cp313-"):
            assert any(package in w.lower() and abi in w for w in wheels), (package, abi)
    excluded = manifest["build"]["paths_exclude_pattern"]
    for path in ("/tests/", "/bench/", "/.venv/", "/tools/"):
        assert path in excluded
