"""The extension zip, end to end: built by tools/build_extension.py, installed into bpy with Blender's own
extension installer, enabled, and rendering a scene, all in fresh processes.

Building downloads the 19 wheels of blender_manifest.toml from PyPI into wheels/ once (about 360 MB, most
of it llvmlite, Numba's LLVM; later runs reuse them). Without network access the test fails and says so: it does not skip, because a zip
without its wheels is not an extension anyone can install.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import textwrap
import zipfile

import pytest

pytest.importorskip("bpy")

from blender_helpers import ROOT  # noqa: E402

# Runs in a fresh bpy whose user resources (extensions, preferences) live in a temporary folder.
INSTALL_AND_RENDER = textwrap.dedent("""
    import importlib, json, math, sys
    from pathlib import Path
    import bpy

    zip_path, exr_path = sys.argv[1], sys.argv[2]
    bpy.ops.wm.read_factory_settings(use_empty=True)  # before installing: it also resets the add-ons
    repo = next(r for r in bpy.context.preferences.extensions.repos if r.module == "user_default")
    site = Path(repo.directory).parent / ".local" / "lib" / f"python{sys.version_info[0]}.{sys.version_info[1]}" \\
        / "site-packages"
    # Import the bundled wheels, not this environment's copies, as a Blender install without them would:
    # their folder goes first on the path before enabling imports any of them (a package imported from
    # two places at once, numba from here and llvmlite from there, breaks).
    site.mkdir(parents=True, exist_ok=True)  # a missing folder on the path is remembered as missing
    sys.path.insert(0, str(site))
    for name in [m for m in sys.modules if m.split(".")[0] in ("embreex", "OpenEXR", "Imath", "numba", "llvmlite",
                                                                 "threadpoolctl")]:
        del sys.modules[name]
    importlib.invalidate_caches()
    result = bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default",
                                                      enable_on_install=True)
    report = {"install": sorted(result), "addons": sorted(bpy.context.preferences.addons.keys())}
    report["wheels"] = sorted(p.name for p in site.iterdir()) if site.is_dir() else []

    scene = bpy.context.scene
    scene.render.engine = "LAZYVIS"
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 33, 33, 100
    scene.world = None
    bpy.ops.object.camera_add(location=(0.0, 0.0, 5.0))
    scene.camera = bpy.context.object
    bpy.context.object.data.type = "ORTHO"
    bpy.context.object.data.ortho_scale = 4.0
    bpy.ops.mesh.primitive_plane_add(size=4.0)
    bpy.ops.object.light_add(type="AREA", location=(0.0, 0.0, 1.0))
    bpy.context.object.data.size = 1.0
    bpy.context.object.data.energy = math.pi  # radiance 1 (Blender: colour P / (pi A))
    settings = scene.render.image_settings
    settings.file_format, settings.color_depth = "OPEN_EXR", "32"
    scene.render.use_file_extension = False
    scene.render.filepath = exr_path
    bpy.ops.render.render(write_still=True)

    import embreex, numba, OpenEXR, threadpoolctl
    engine = next(c for c in bpy.types.RenderEngine.__subclasses__() if getattr(c, "bl_idname", "") == "LAZYVIS")
    report.update(engine_module=engine.__module__, embreex=embreex.__file__, openexr=OpenEXR.__file__,
                  numba=numba.__file__, threadpoolctl=threadpoolctl.__file__,
                  top_level_package_imported="lazyvis_addon" in sys.modules)
    with OpenEXR.File(exr_path) as exr:
        pixels = exr.parts[0].channels["RGBA"].pixels
    report["centre"] = [float(v) for v in pixels[16, 16, :3]]
    print("REPORT " + json.dumps(report))
""")


@pytest.mark.slow
def test_extension_zip_installs_enables_and_renders(tmp_path):
    dist = tmp_path / "dist"
    build = subprocess.run([sys.executable, str(ROOT / "tools" / "build_extension.py"), "--output-dir", str(dist)],
                           cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert build.returncode == 0, (
        "tools/build_extension.py failed; it downloads the wheels of blender_manifest.toml from PyPI into "
        "wheels/, so check the network (or put the wheels there by hand):\n" + build.stdout[-3000:]
        + build.stderr[-3000:])
    packages = sorted(dist.glob("lazyvis-*.zip"))
    assert len(packages) == 1, build.stdout
    # Only the add-on, its manifest and the wheels: no build leftovers (an editable install's egg-info,
    # bytecode) and nothing of the repository's tests, benchmarks or tools.
    with zipfile.ZipFile(packages[0]) as archive:
        names = archive.namelist()
    leftovers = [name for name in names if ".egg-info" in name or "__pycache__" in name or name.endswith(".pyc")
                 or name.split("/")[0] in ("tests", "bench", "tools", "docs", "sample_blends", "farm", ".venv", ".git")]
    assert not leftovers, leftovers[:10]
    assert "blender_manifest.toml" in names and "lazyvis_addon/core/render.py" in names, names[:20]
    assert "lazyvis_addon/tiles.py" in names and "lazyvis_addon/blender/operators.py" in names  # farm tiles

    user = tmp_path / "blender_user"  # never the real ~/.config/blender
    env = {key: value for key, value in os.environ.items() if not key.startswith("BLENDER_USER")}
    env.update(BLENDER_USER_RESOURCES=str(user), PYTHONNOUSERSITE="1")
    env.pop("PYTHONPATH", None)
    exr = tmp_path / "render.exr"
    run = subprocess.run([sys.executable, "-c", INSTALL_AND_RENDER, str(packages[0]), str(exr)], cwd=tmp_path,
                         env=env, capture_output=True, text=True, timeout=600)
    lines = [line for line in run.stdout.splitlines() if line.startswith("REPORT ")]
    assert run.returncode == 0 and lines, run.stdout[-3000:] + run.stderr[-3000:]
    report = json.loads(lines[-1][len("REPORT "):])

    assert report["install"] == ["FINISHED"]
    assert "bl_ext.user_default.lazyvis" in report["addons"]
    assert report["engine_module"].startswith("bl_ext.user_default.lazyvis.")  # the installed copy
    assert not report["top_level_package_imported"], "the extension must not import the repository's package"
    for wheel in ("embreex", "OpenEXR", "numba", "llvmlite", "threadpoolctl"):
        assert any(name.startswith(wheel) for name in report["wheels"]), report["wheels"]
    for module in ("embreex", "openexr", "numba", "threadpoolctl"):
        assert str(user) in report[module], report  # the bundled wheels
    # The centre pixel sees the plane (grey 0.8, no material) straight below the centre of a square light
    # of side 2a = 1 m at h = 1 m with radiance 1: E = 4 s atan(s), s = a / sqrt(a^2 + h^2).
    a, h = 0.5, 1.0
    s = a / math.hypot(a, h)
    assert report["centre"] == pytest.approx([0.8 / math.pi * 4.0 * s * math.atan(s)] * 3, rel=1e-4)
