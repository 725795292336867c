"""tools/make_cycles_reference.py renders a .blend to a small float EXR with the reference settings."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from blender_helpers import ROOT, add_area_light, add_camera, cycles_reference_tool, read_exr  # noqa: E402


def test_make_cycles_reference_writes_a_float_exr(scene, tmp_path):
    add_camera(scene)
    bpy.ops.mesh.primitive_plane_add(size=6.0)
    add_area_light(location=(0.0, 0.0, 2.0), size=1.0, energy=50.0)
    scene.render.engine = "CYCLES"
    blend = tmp_path / "tiny.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    output = tmp_path / "reference.exr"
    result = subprocess.run([sys.executable, str(ROOT / "tools" / "make_cycles_reference.py"), str(blend),
                             str(output), "--samples", "4", "--resolution", "12", "8", "--threads", "1"],
                            cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "12 x 8, 4 samples" in result.stdout
    pixels = read_exr(output)["RGBA"]
    assert pixels.shape == (8, 12, 4) and pixels.dtype == np.float32
    assert pixels[..., :3].max() > 0.0 and np.isfinite(pixels).all()


def test_reference_settings_are_the_radiometry_note(scene, tmp_path):
    cycles_reference_tool().configure_cycles(scene, samples=32, seed=5)
    cycles = scene.cycles
    assert scene.render.engine == "CYCLES" and cycles.device == "CPU"
    assert (cycles.max_bounces, cycles.samples, cycles.seed) == (0, 32, 5)
    assert cycles.filter_width == pytest.approx(0.01)
    assert not cycles.use_denoising and not cycles.use_adaptive_sampling and not cycles.use_animated_seed
    assert cycles.light_sampling_threshold == 0.0
    assert cycles.sample_clamp_direct == 0.0 and cycles.sample_clamp_indirect == 0.0
